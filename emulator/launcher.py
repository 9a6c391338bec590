"""One launcher for the firmware in every runtime: CPython, MicroPython's unix port, and the PIL image under QEMU
(``make pil``). The fine-pointing controller (``ground.runtime``) and the ADCS (``emulator.adcs_session``) start
theirs here, so each runtime has the same process group, stderr capture, shutdown and error report. (A board on a
serial port has no process: its runtime opens the port.) Here, not in ground, because nothing below ground imports
ground.

``FirmwareProcess`` is a ``subprocess.Popen`` whose stderr goes to a temporary file (a pipe nobody reads during a
run would fill and stall the firmware), in a process group of its own (``runtime.OWN_GROUP``: a terminal's Ctrl-C
reaches only the tool); ``stderr_tail``, ``exit_note`` and ``stop`` (wait for it to leave, as it does when its link
closes; then SIGTERM, then SIGKILL) are the same for all. ``command(runtime, target, args)`` builds the command line
and environment of a CPython or MicroPython firmware; ``qemu_command`` that of the PIL image.
"""

import os
import subprocess
import sys
import tempfile

from emulator.runtime import OWN_GROUP, micropython_binary

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUNTIMES = ("cpython", "micropython", "qemu")
PIL_IMAGE = os.path.join(ROOT, "build", "pil", "MICROBIT", "firmware.elf")
QEMU_ARGS = ("-machine", "microbit", "-nographic", "-monitor", "null", "-semihosting",
             "-global", "nrf51-soc.flash-size=1048576", "-global", "nrf51-soc.sram-size=262144")


def command(runtime, target, args=(), micropython_opts=()):
    """(argv, env) of a firmware under ``runtime`` ("cpython" or "micropython"): ``target`` a module name
    (``-m``) or a script's path, the repository on the interpreter's path; ``micropython_opts`` the unix port's
    own options (e.g. ``-X heapsize=64M``)."""
    if runtime not in ("cpython", "micropython"):
        raise ValueError("runtime %r: command() builds cpython and micropython lines (qemu: qemu_command)" % runtime)
    env = dict(os.environ)
    if runtime == "micropython":
        exe = [micropython_binary()] + list(micropython_opts)
        env["MICROPYPATH"] = ROOT + ":" + env.get("MICROPYPATH", ".frozen:~/.micropython/lib")
    else:
        exe = [sys.executable]
        env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    head = [target] if target.endswith(".py") else ["-m", target]
    return exe + head + [str(a) for a in args], env


def qemu_command(image=PIL_IMAGE, serial="pty", icount=False):
    """qemu-system-arm's command line for the PIL image: its UART on ``serial`` (pty or stdio), deterministic
    instruction counting (``-icount shift=0``: one virtual ns per instruction) when ``icount``."""
    cmd = ["qemu-system-arm"] + list(QEMU_ARGS) + ["-serial", serial, "-kernel", image]
    if icount:
        cmd += ["-icount", "shift=0"]
    return cmd


class FirmwareProcess(subprocess.Popen):
    """A firmware process (see the module docstring). ``stdout``: None (its own output to the same file as its
    stderr), ``subprocess.PIPE`` (read by the caller, e.g. QEMU's pty line) or ``subprocess.DEVNULL``."""

    def __init__(self, argv, env=None, stdout=None, pass_fds=(), name="firmware"):
        self.errlog = tempfile.TemporaryFile()
        self.name = name
        self.stopped_by_us = False
        self.stderr_text = ""
        super().__init__(argv, cwd=ROOT, env=env, stdin=subprocess.DEVNULL,
                         stdout=self.errlog if stdout is None else stdout, stderr=self.errlog, pass_fds=pass_fds,
                         **OWN_GROUP)

    def stderr_tail(self, n_chars=2000):
        """The last ``n_chars`` it wrote to stderr (kept after ``stop``)."""
        if self.errlog.closed:
            return self.stderr_text[-n_chars:]
        self.errlog.flush()
        self.errlog.seek(0, os.SEEK_END)
        self.errlog.seek(max(0, self.errlog.tell() - n_chars))
        return self.errlog.read().decode(errors="replace")

    def exit_note(self, wait_s=1.0):
        """``"; the <name> process exited with status N: <its last stderr line>"`` once it has exited of itself
        (waiting up to ``wait_s``: a process whose link failed is on its way out), else ``""`` (still running, or
        stopped by this side)."""
        if self.stopped_by_us:
            return ""
        try:
            self.wait(wait_s)
        except subprocess.TimeoutExpired:
            return ""
        lines = [ln for ln in self.stderr_tail().splitlines() if ln.strip()]
        return "; the %s process exited with status %s%s" % (
            self.name, self.returncode, (": " + lines[-1].strip()) if lines else " and said nothing on stderr")

    def stop(self, grace_s=2.0):
        """Wait ``grace_s`` for it to leave (it does when its link closes), then SIGTERM, then SIGKILL; its stderr
        is kept in ``stderr_text``."""
        self.stopped_by_us = self.poll() is None
        if self.poll() is None:
            try:
                self.wait(grace_s)
            except subprocess.TimeoutExpired:
                self.terminate()
                try:
                    self.wait(2.0)
                except subprocess.TimeoutExpired:
                    self.kill()
                    self.wait(2.0)
        if not self.errlog.closed:
            self.stderr_text = self.stderr_tail(1 << 20)
            self.errlog.close()
        for f in (self.stdout, self.stderr):
            if f is not None:
                f.close()
