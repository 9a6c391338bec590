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
