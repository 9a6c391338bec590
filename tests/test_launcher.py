"""emulator.launcher: the one firmware launcher (the controller's runtimes and the ADCS session start theirs
through it): the command lines per runtime, stderr kept after the process is gone, the exit note naming the
status and the last line, and a stop that ends a process that ignores its link closing."""

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


def test_a_process_that_fails_is_reported_with_its_status_and_last_line():
    p = launcher.FirmwareProcess([sys.executable, "-c", "import sys; print('a', file=sys.stderr); "
                                  "print('link failed: EIO', file=sys.stderr); sys.exit(3)"], name="controller")
    note = p.exit_note(wait_s=10)
    assert note == "; the controller process exited with status 3: link failed: EIO"
    p.stop()
    assert "link failed: EIO" in p.stderr_tail() and p.errlog.closed and not p.stopped_by_us


def test_stop_ends_a_process_that_does_not_leave_and_says_nothing_of_it():
    p = launcher.FirmwareProcess([sys.executable, "-c", "import signal, time; "
                                  "signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); "
                                  "time.sleep(60)"], stdout=subprocess.PIPE, name="QEMU")
    assert p.stdout.readline().strip() == b"up"
    p.stop(grace_s=0.2)                     # SIGTERM ignored: SIGKILL
    assert p.returncode is not None and p.stopped_by_us and p.exit_note() == ""


def test_a_board_whose_firmware_stopped_is_told_by_its_last_console_lines():
    """A QEMU board runs on after its firmware raised (firmware.pil_main halts): the traceback it printed on its UART
    (``console``: the bench link's last bytes) is what the note says, frames around it ignored."""
    p = launcher.FirmwareProcess([sys.executable, "-c", "import time; time.sleep(30)"], name="QEMU")
    try:
        assert p.exit_note(wait_s=0.1) == ""                  # running, nothing printed: nothing to tell
        p.console = lambda: (b"\x05\x01\x01\x10\xff\x00Traceback (most recent call last):\r\n  File \"a.py\", line 3, "
                             b"in f\r\n  File \"b.py\", line 9, in g\r\nMemoryError: memory allocation failed\r\n")
        note = p.exit_note(wait_s=0.1)
        assert note.startswith("; the QEMU board's firmware stopped: ") and note.endswith("MemoryError: memory "
                                                                                        "allocation failed")
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
            return "; the QEMU board's firmware stopped: MemoryError: memory allocation failed"

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
    assert "no answer to HTABLE_END" in err and "firmware stopped: MemoryError" in err and "Traceback" not in err
    assert not (tmp_path / "c.json").exists()
