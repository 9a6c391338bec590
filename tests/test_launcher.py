"""emulator.launcher: the one firmware launcher (the controller's runtimes and the ADCS session start theirs
through it): the command lines per runtime, stderr kept after the process is gone, the exit note naming the
status or the signal and the last lines, and a stop that ends a process that ignores its link closing; every child
dies with the process that started it."""

import subprocess
import sys

import pytest

from emulator import launcher


def test_command_lines_put_the_repository_on_each_interpreters_path():
    argv, env = launcher.command("cpython", "firmware.main", ["controller", "--rate", 637.8])
    assert argv[:3] == [sys.executable, "-m", "firmware.main"] and argv[-1] == "637.8"
    assert env["PYTHONPATH"].split(":")[0] == launcher.ROOT
    try:
        argv, env = launcher.command("micropython", "/x/main_can.py", [3], micropython_opts=("-X", "heapsize=64M"))
    except ValueError:                      # no unix port installed: the message says how to get it
        pytest.skip("no micropython binary")
    assert argv[1:5] == ["-X", "heapsize=64M", "/x/main_can.py", "3"]
    assert env["MICROPYPATH"].startswith(launcher.ROOT + ":")
    q = launcher.qemu_command("img.elf", "pty", icount=True)
    assert q[0] == "qemu-system-arm" and q[q.index("-kernel") + 1] == "img.elf" and q[-2:] == ["-icount", "shift=0"]
    with pytest.raises(ValueError, match="qemu_command"):
        launcher.command("qemu", "firmware.main")


def test_a_process_that_fails_is_reported_with_its_status_and_last_lines():
    p = launcher.FirmwareProcess([sys.executable, "-c", "import sys; print('a', file=sys.stderr); "
                                  "print('link failed: EIO', file=sys.stderr); sys.exit(3)"],
                                 name="the controller (cpython)")
    note = p.exit_note(wait_s=10)
    assert note == "; the controller (cpython) exited with status 3: a / link failed: EIO"
    assert p.exit_note() == ""                               # told once
    p.stop()
    assert "link failed: EIO" in p.stderr_tail() and p.errlog.closed and not p.stopped_by_us


def test_a_process_killed_by_a_signal_is_reported_by_the_signals_name():
    p = launcher.FirmwareProcess([sys.executable, "-c", "import time; time.sleep(30)"], name="the controller (cpython)")
    p.terminate()
    assert p.death(wait_s=10, when=" at t = 3 s") == ("the controller (cpython) was killed by SIGTERM at t = 3 s and "
                                                     "wrote nothing on stderr")
    p.stop()


def test_a_child_dies_with_its_parent_however_the_parent_dies():
    """A parent started with a firmware process, then SIGKILLed (none of its code runs): the kernel ends the child
    (``runtime.child_options``: PR_SET_PDEATHSIG), which is in a process group of its own."""
    import os
    import signal
    import time
    from emulator import runtime
    if runtime._PRCTL is None:
        pytest.skip("no prctl (not Linux): a child outlives a parent that is killed")
    code = ("import sys, time; from emulator import launcher; "
            "p = launcher.FirmwareProcess([sys.executable, '-c', 'import time; time.sleep(60)']); "
            "print(p.pid, flush=True); time.sleep(60)")
    parent = subprocess.Popen([sys.executable, "-c", code], cwd=launcher.ROOT, stdout=subprocess.PIPE)
    child = int(parent.stdout.readline())
    assert os.getpgid(child) == child
    parent.send_signal(signal.SIGKILL)
    parent.wait(10)
    parent.stdout.close()
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and _alive(child):
        time.sleep(0.02)
    assert not _alive(child)


def _alive(pid):
    """True while ``pid`` runs (a zombie, dead but not yet reaped by init, does not)."""
    try:
        with open("/proc/%d/stat" % pid) as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_stop_ends_a_process_that_does_not_leave_and_says_nothing_of_it():
    p = launcher.FirmwareProcess([sys.executable, "-c", "import signal, time; "
                                  "signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); "
                                  "time.sleep(60)"], stdout=subprocess.PIPE, name="qemu-system-arm")
    assert p.stdout.readline().strip() == b"up"
    p.stop(grace_s=0.2)                     # SIGTERM ignored: SIGKILL
    assert p.returncode is not None and p.stopped_by_us and p.exit_note() == ""


def test_a_board_whose_firmware_stopped_is_told_by_its_last_console_lines():
    """A QEMU board runs on after its firmware raised (firmware.pil_main halts): the traceback it printed on its UART
    (``console``: the bench link's last bytes) is what the note says, frames around it ignored."""
    p = launcher.FirmwareProcess([sys.executable, "-c", "import time; time.sleep(30)"],
                                 name="qemu-system-arm (a PIL board)")
    try:
        assert p.exit_note(wait_s=0.1) == ""                  # running, nothing printed: nothing to tell
        p.console = lambda: (b"\x05\x01\x01\x10\xff\x00Traceback (most recent call last):\r\n  File \"a.py\", line 3, "
                             b"in f\r\n  File \"b.py\", line 9, in g\r\nMemoryError: memory allocation failed\r\n")
        note = p.exit_note(wait_s=0.1)
        assert note.startswith("; the firmware on qemu-system-arm (a PIL board) stopped: ")
        assert note.endswith("MemoryError: memory allocation failed")
        assert 'File "b.py", line 9, in g' in note and "Traceback" not in note     # its last three lines
    finally:
        p.kill()
        p.stop()


def test_fps_calibrate_quotes_what_a_stopped_firmware_said(tmp_path, monkeypatch, capsys):
    """A calibration whose firmware stopped (a QEMU board's traceback, a process's last line) says so beside the
    link's error, as fps hil does."""
    import contextlib
    from ground import calibrate, cli, runtime

    class Proc:
        def exit_note(self, wait_s):
            return "; the firmware on qemu-system-arm (a PIL board) stopped: MemoryError: memory allocation failed"

    class Rig:
        process = Proc()

    @contextlib.contextmanager
    def rig(*a, **k):
        yield Rig()

    def fails(*a, **k):
        raise OSError("no answer to HTABLE_END after 40 tries")
    monkeypatch.setattr(runtime, "open_rig", rig)
    monkeypatch.setattr(calibrate, "run_calibration", fails)
    assert cli.main(["calibrate", "--runtime", "micropython", "--grid", "3", "-o", str(tmp_path / "c.json")]) != 0
    err = capsys.readouterr().err
    assert "no answer to HTABLE_END" in err and "PIL board) stopped: MemoryError" in err and "Traceback" not in err
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_stop_inside_an_uncut_step_lands_where_the_step_ends(sig):
    """Ctrl-C or SIGTERM during ``interrupts_between`` finishes the step, then raises KeyboardInterrupt; outside
    one it raises at once. In a child interpreter, whose main thread owns the signals."""
    code = """
import os, signal
from emulator.runtime import sigterm_as_interrupt, interrupts_between
steps = []
try:
    with sigterm_as_interrupt():
        with interrupts_between():
            os.kill(os.getpid(), signal.%s)
            for _ in range(1000):
                pass
            steps.append("finished")
        steps.append("after")
except KeyboardInterrupt:
    steps.append("interrupted")
try:
    with sigterm_as_interrupt():
        os.kill(os.getpid(), signal.%s)
        for _ in range(1000):
            pass
        steps.append("not cut")
except KeyboardInterrupt:
    steps.append("cut")
print(",".join(steps))
""" % (sig, sig)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         cwd=launcher.ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "finished,interrupted,cut"
