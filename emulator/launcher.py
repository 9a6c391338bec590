"""One launcher for the firmware in every runtime: CPython, MicroPython's unix port, and the PIL image under QEMU
(``make pil``). The fine-pointing controller (``ground.runtime``) and the ADCS (``emulator.adcs_session``) start
theirs here, so each runtime has the same process group, stderr capture, shutdown and error report. (A board on a
serial port has no process: its runtime opens the port.) Here, not in ground, because nothing below ground imports
ground.

``FirmwareProcess`` is a ``subprocess.Popen`` whose stderr goes to a temporary file (a pipe nobody reads during a
run would fill and stall the firmware), in a process group of its own (a terminal's Ctrl-C reaches only the tool),
killed by the kernel if the tool dies (``runtime.child_options``); ``stderr_tail``, ``death`` and ``exit_note``
(the process named, how it ended, its last stderr lines) and ``stop`` (wait for it to leave, as it does when its
link closes; then SIGTERM, then SIGKILL) are the same for all. ``command(runtime, target, args)`` builds the command
line and environment of a CPython or MicroPython firmware; ``qemu_command`` that of a PIL image, ``start_board``
boots one and starts its firmware through the raw REPL.
"""

import os
import shutil
import subprocess
import sys
import tempfile

from emulator.runtime import child_options, exit_status, last_lines, micropython_binary

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUNTIMES = ("cpython", "micropython", "qemu")
PIL_IMAGE = os.path.join(ROOT, "build", "pil", "MICROBIT", "firmware.elf")
PIL_RAM_BYTES = 32 * 1024         # the thesis's SAMD21G18 has 32 KB of SRAM; the image is linked for it
ADCS_IMAGE = os.path.join(ROOT, "build", "pil", "MPS2-AN500-ADCS", "firmware.elf")   # tools.pil_build's ADCS_MEM
ADCS_MACHINE = "mps2-an500"
QEMU_ARGS = ("-nographic", "-semihosting")
# ISO-TP's N_Bs and N_Cr on the host's side of a PIL board's CAN, in wall ms: the board sends a flow control or its
# next consecutive frame only between its computations, whose longest (the filters' start, 11.6 M instructions)
# takes a few hundred ms of wall time under QEMU's -icount; ISO 15765-2's own 1000 ms (the board keeps its own
# timeouts in its virtual time: its timer counts instructions)
PIL_ISOTP_TIMEOUT_MS = 1000.0


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


class PilUnavailable(ValueError):
    """A ``--runtime qemu`` run that cannot start: QEMU missing, or the PIL image missing or not built from the
    tree's sources (bad input: exit 2, the message naming ``make pil``)."""


def qemu_command(image=PIL_IMAGE, serial="pty", icount=False, monitor=None, ram_bytes=PIL_RAM_BYTES,
                 machine="microbit"):
    """qemu-system-arm's command line for a PIL image on QEMU's ``machine``: for the microbit, ``ram_bytes`` of SRAM
    (the image's linker script's) and 1 MB of flash; its UART on ``serial`` (pty or stdio), deterministic
    instruction counting (``-icount shift=0``: one virtual ns per instruction) when ``icount``, QEMU's monitor on
    the unix socket ``monitor`` (None: none), through which the host reads the board's RAM."""
    mon = "null" if monitor is None else "unix:%s,server=on,wait=off" % monitor
    cmd = ["qemu-system-arm", "-machine", machine] + list(QEMU_ARGS)
    if machine == "microbit":
        cmd += ["-global", "nrf51-soc.flash-size=1048576", "-global", "nrf51-soc.sram-size=%d" % ram_bytes]
    cmd += ["-monitor", mon, "-serial", serial, "-kernel", image]
    if icount:
        cmd += ["-icount", "shift=0"]
    return cmd


def start_board(cmd, start, connect, first_line=None, name="qemu-system-arm (a PIL board)", boot_s=60.0,
                console_log=True, speaks_first_s=None):
    """A PIL board: QEMU (``cmd``, a ``qemu_command`` with ``serial="pty"``) started, the pty it made opened raw,
    MicroPython's raw REPL entered and ``start`` (a statement, e.g. ``import firmware.pil_main``) run; then
    ``first_line`` (text, a newline added) written to the board if given, and ``connect(path)`` called, which opens
    the caller's link on the pty (while this side still holds it open: QEMU drops what a board writes to a pty
    nobody holds). ``name``: the process as messages call it. ``console_log``: what the UART sends also written to
    a file, the process's ``console`` (its last bytes: a traceback at boot, ``FirmwareProcess.crashed``).
    ``speaks_first_s``: a firmware that frames a packet unasked once it runs (the controller's HELLO) is waited
    for that long, and one that prints a traceback instead is reported at once (``_first_words``). Returns (the
    ``FirmwareProcess``, what ``connect`` returned). OSError saying what the board did instead; PilUnavailable
    without QEMU."""
    import re
    import select
    import time
    import tty
    if shutil.which(cmd[0]) is None:
        raise PilUnavailable("runtime qemu needs %s (make pil says how to install it)" % cmd[0])
    log_dir = tempfile.mkdtemp(prefix="fps-board-") if console_log else None
    if log_dir:                    # what the board's UART sends, also to a file: its console (a traceback)
        log = os.path.join(log_dir, "uart.log")
        k = cmd.index("-serial")
        cmd = cmd[:k] + ["-chardev", "pty,id=uart0,logfile=%s,logappend=on" % log, "-serial", "chardev:uart0"] + \
            cmd[k + 2:]
    proc = FirmwareProcess(cmd, stdout=subprocess.PIPE, name=name, leaves_on_close=False)
    if log_dir:
        proc.cleanup_dirs.append(log_dir)
        proc.console = lambda: _file_tail(log)
    fd = None
    try:
        line, t0 = b"", time.monotonic()
        while b"/dev/pts/" not in line:
            if time.monotonic() - t0 > 10 or proc.poll() is not None:
                raise OSError("%s gave no pty (%s)" % (name, proc.death(0.0) or proc.stderr_tail().strip()))
            line = proc.stdout.readline()
        path = re.search(rb"(/dev/pts/\d+)", line).group(1).decode()
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(fd)

        def until(token, wait_s):
            buf, end = b"", time.monotonic() + wait_s
            while token not in buf:
                if time.monotonic() > end:
                    raise OSError("the PIL board gave no %r in %g s (got %r)" % (token, wait_s, buf[-200:]))
                if select.select([fd], [], [], 0.2)[0]:
                    buf += os.read(fd, 4096)
            return buf
        os.write(fd, b"\r")
        until(b">>> ", boot_s)
        os.write(fd, b"\x01")
        until(b"raw REPL; CTRL-B to exit\r\n>", 10.0)
        os.write(fd, start.encode() + b"\x04")
        after = until(b"OK", 10.0).partition(b"OK")[2]
        if first_line is not None:
            data = first_line.encode() + b"\n"
            while data:
                data = data[os.write(fd, data):]
        if speaks_first_s:
            _first_words(fd, after, speaks_first_s, name)
        link = connect(path)
    except BaseException:
        proc.kill()
        proc.stop()
        raise
    finally:
        if fd is not None:
            os.close(fd)
    return proc, link


def _first_words(fd, got, wait_s, name):
    """The board's first output after its start (``got``: what came with the raw REPL's OK), for up to ``wait_s``:
    a frame's delimiter (0x00) says the firmware runs (the frame itself is dropped: the host's HELLO is answered
    again); a traceback, read until the UART is quiet for 0.3 s, raises OSError quoting it."""
    import select
    import time
    end = time.monotonic() + wait_s
    while b"\x00" not in got and b"Traceback (most recent call last)" not in got:
        left = end - time.monotonic()
        if left <= 0:
            return
        if select.select([fd], [], [], min(left, 0.2))[0]:
            got += os.read(fd, 4096)
    if b"\x00" in got:
        return
    while select.select([fd], [], [], 0.3)[0]:
        got += os.read(fd, 4096)
    text = got[got.find(b"Traceback"):].decode(errors="replace")
    raise OSError("the firmware on %s stopped at boot: %s" % (name, last_lines(text).replace("\x04>", "")))


class FirmwareProcess(subprocess.Popen):
    """A firmware process (see the module docstring). ``stdout``: None (its own output to the same file as its
    stderr), ``subprocess.PIPE`` (read by the caller, e.g. QEMU's pty line) or ``subprocess.DEVNULL``. ``name``:
    the process as messages call it, e.g. "the controller (micropython)". ``leaves_on_close``: it exits when its
    link closes (a firmware process; QEMU does not: ``stop`` then ends it at once)."""

    def __init__(self, argv, env=None, stdout=None, pass_fds=(), name="the firmware", leaves_on_close=True):
        self.errlog = tempfile.TemporaryFile()
        self.name = name
        self.leaves_on_close = leaves_on_close
        self.stopped_by_us = False
        self.told = False              # its end is in an error already: exit_note says it no more
        self.stderr_text = ""
        self.console = None            # a board's: a callable giving the last bytes its UART sent
        self.cleanup_dirs = []         # removed by stop
        super().__init__(argv, cwd=ROOT, env=env, stdin=subprocess.DEVNULL,
                         stdout=self.errlog if stdout is None else stdout, stderr=self.errlog, pass_fds=pass_fds,
                         **child_options(own_group=True))

    def stderr_tail(self, n_chars=2000):
        """The last ``n_chars`` it wrote to stderr (kept after ``stop``)."""
        if self.errlog.closed:
            return self.stderr_text[-n_chars:]
        self.errlog.flush()
        self.errlog.seek(0, os.SEEK_END)
        self.errlog.seek(max(0, self.errlog.tell() - n_chars))
        return self.errlog.read().decode(errors="replace")

    def death(self, wait_s=1.0, when=""):
        """``"<name> exited with status N<when>: <its last stderr lines>"`` (or ``was killed by SIGTERM``, ``...
        and wrote nothing on stderr``; ``when`` e.g. " at t = 3 s") once it has ended (waiting up to ``wait_s``: a
        process whose link failed is on its way out), else ``""`` (still running). Marks it told (``exit_note``
        then says it no more)."""
        if self.poll() is None:
            try:
                self.wait(wait_s)
            except subprocess.TimeoutExpired:
                return ""
        self.told = True
        tail = last_lines(self.stderr_tail())
        return "%s %s%s%s" % (self.name, exit_status(self.returncode), when,
                              (": " + tail) if tail else " and wrote nothing on stderr")

    def exit_note(self, wait_s=1.0):
        """``"; " + death()`` once it has ended of itself (waiting up to ``wait_s``), else ``""`` (still
        running, stopped by this side, or its end already told); for a board whose ``console`` shows a traceback,
        its last lines."""
        said = self.crashed()
        if said:                     # a board (QEMU) runs on after its firmware stopped: what it printed
            return "; " + said
        if self.stopped_by_us or self.told:
            return ""
        said = self.death(wait_s)
        return "; " + said if said else ""

    def crashed(self):
        """A board's firmware that stopped with a traceback on its UART (QEMU runs on): ``"the firmware on <name>
        stopped: <its last lines>"``; else ``""``."""
        text = self.console() if self.console is not None else b""
        k = text.rfind(b"Traceback (most recent call last)")
        if k < 0:
            return ""
        return "the firmware on %s stopped: %s" % (
            self.name, last_lines(text[k:].decode(errors="replace")).replace("\x04>", ""))

    def stop(self, grace_s=2.0):
        """Wait ``grace_s`` for it to leave (it does when its link closes; not for one that does not,
        ``leaves_on_close`` false), then SIGTERM, then SIGKILL; its stderr is kept in ``stderr_text``."""
        self.stopped_by_us = self.poll() is None
        if not self.leaves_on_close:
            grace_s = 0.0
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
        if self.cleanup_dirs and self.console is not None:
            kept = self.console()          # read from a file removed now
            self.console = lambda: kept
        for d in self.cleanup_dirs:
            shutil.rmtree(d, ignore_errors=True)


def _file_tail(path, n_bytes=4096):
    """The last ``n_bytes`` of a file (b"" if it cannot be read)."""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - n_bytes))
            return f.read()
    except OSError:
        return b""
