"""The PIL images at run time (``tools.pil_build`` builds them): ``Board`` drives an image under QEMU through
MicroPython's raw REPL, ``replay_adcs`` replays a recorded ADCS session on the ADCS board, ``read_target`` reads
the controller board's mailbox (its timing and memory figures) through QEMU's monitor."""

import os
import subprocess

from emulator import launcher
from emulator.runtime import child_options, exit_status, last_lines
from tools import pil_mailbox
from tools.pil_build import ADCS_MEM, LAB_MEM, STACK_PAINT, TARGET_MEM, BuildError

def qemu_command(mem=LAB_MEM, serial="stdio", icount=True, monitor=None):
    """``emulator.launcher.qemu_command`` for ``mem``'s image; here the UART on stdio and ``-icount`` by default (the
    tests' board)."""
    return launcher.qemu_command(mem.image, serial, icount, monitor, ram_bytes=mem.ram_bytes, machine=mem.machine)


class Board:
    """The PIL image running under QEMU with its UART on this process's pipes, driven through MicroPython's raw
    REPL: ``run(code)`` executes ``code`` on the board and returns its output (a board-side exception raises
    ``BoardError`` with its traceback). A context manager; ``close()`` ends QEMU, which also dies with this process
    (``emulator.runtime.child_options``)."""

    def __init__(self, mem=LAB_MEM, icount=True, boot_s=30.0):
        import select  # noqa: F401  (POSIX pipes: what _read polls)
        if not os.path.exists(mem.image):
            raise BuildError("no PIL image at %s (make pil)" % mem.image)
        self.proc = subprocess.Popen(qemu_command(mem, "stdio", icount), stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, **child_options())
        self._rx = b""                                # read from the board, not yet taken
        self.banner = self._read(b">>> ", boot_s)
        self._write(b"\r\x01")                        # raw REPL
        self._read(b"raw REPL; CTRL-B to exit\r\n>", 10.0)

    def _write(self, data):
        self.proc.stdin.write(data)
        self.proc.stdin.flush()

    def _fill(self, end, waiting_for):
        """Whatever QEMU's stdout holds now into ``_rx`` (waiting up to 0.5 s); BoardError past ``end`` or at EOF."""
        import select
        import time
        left = end - time.monotonic()
        if left <= 0:
            raise BoardError("the board gave no %s (got %r)" % (waiting_for, self._rx[-300:]))
        r, _, _ = select.select([self.proc.stdout], [], [], min(left, 0.5))
        if r:
            b = os.read(self.proc.stdout.fileno(), 65536)
            if not b:
                try:
                    self.proc.wait(1.0)
                except subprocess.TimeoutExpired:
                    raise BoardError("qemu-system-arm (the PIL board) closed its stdout") from None
                err = last_lines(self.proc.stderr.read()[-2000:].decode(errors="replace"))
                raise BoardError("qemu-system-arm (the PIL board) %s%s" % (
                    exit_status(self.proc.returncode), (": " + err) if err else " and wrote nothing on stderr"))
            self._rx += b

    def _read(self, token, timeout):
        """The board's output up to and with ``token``; what follows it stays in ``_rx``."""
        import time
        end = time.monotonic() + timeout
        while token not in self._rx:
            self._fill(end, "%r within %g s" % (token, timeout))
        head, _, self._rx = self._rx.partition(token)
        return head + token

    def start(self, code):
        """Start ``code`` on the board and return once it runs; its output is then read by ``expect_line``."""
        self._write(code.encode() + b"\x04")
        self._read(b"OK", 10.0)

    def send_line(self, text):
        self._write(text.encode() + b"\n")

    def expect_line(self, word, timeout):
        """The board's next line that starts with ``word``, split on spaces (BoardError with its output if the
        code ended or raised first)."""
        import time
        end = time.monotonic() + timeout
        while True:
            while b"\n" in self._rx:
                line, self._rx = self._rx.split(b"\n", 1)
                f = line.decode(errors="replace").strip().split()
                if f and f[0] == word:
                    return f
            if b"\x04" in self._rx:
                raise BoardError("the board's code ended: %s" % self._rx.decode(errors="replace")[-1500:])
            self._fill(end, "%r line within %g s" % (word, timeout))

    def run(self, code, timeout=300.0):
        """Run ``code`` (text) on the board; its standard output as text."""
        self._write(code.encode() + b"\x04")
        out = self._read(b"\x04>", timeout)
        if not out.startswith(b"OK"):
            raise BoardError("the board refused the code: %r" % out[:300])
        body = out[2:-2]
        res, _, err = body.partition(b"\x04")
        if err.strip():
            raise BoardError(err.decode(errors="replace").strip())
        return res.decode(errors="replace")

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class BoardError(Exception):
    pass


def replay_adcs(cfg, rec, progress=None, timeout_s=120.0):
    """A recorded ADCS session (``emulator.adcs_session.AdcsSession(record=True)``: its ``config()`` and
    ``recorded``) replayed on the ADCS board (``ADCS_MEM``, ``tests/mp/pil_adcs_probe.py``), cycle by cycle through
    its UART. Returns {"cycles": [(tick, instructions, heap bytes allocated)...], "insn_per_timer_tick", "kernels"
    (the C kernels ran),
    "heap_bytes" (in use at the end), "stack_high_water_bytes", "status" (the last ADCS_STATUS payload)}.
    ``progress``: called after each cycle."""
    import json
    with Board(mem=ADCS_MEM) as b:
        b.start("import pil_adcs_probe\npil_adcs_probe.replay()")
        b.send_line(json.dumps(cfg, separators=(",", ":")))
        _, k, kernels = b.expect_line("ready", timeout_s)
        cycles = []
        for c in rec:
            b.send_line(json.dumps(c, separators=(",", ":")))
            _, tick, insn, heap = b.expect_line("c", timeout_s)
            cycles.append((int(tick), int(insn), int(heap)))
            if progress is not None:
                progress()
        b.send_line("end")
        _, heap, hw, status = b.expect_line("end", timeout_s)
    return {"cycles": cycles, "insn_per_timer_tick": float(k), "kernels": kernels == "1", "heap_bytes": int(heap),
            "stack_high_water_bytes": int(hw), "status": bytes.fromhex(status)}


# the target the PIL image stands for, as a qemu run's summary.json states it
TARGET = {"board": "QEMU microbit (nRF51822) standing for the thesis's SAMD21G18 (CtrlArduino)",
          "core": "ARM Cortex-M0 (ARMv6-M; the SAMD21's Cortex-M0+ runs the same Thumb code)",
          "clock_hz": 48e6, "cpi_range": [1.2, 1.6]}


INSN_PER_TIMER_TICK = 62.5        # firmware.hal.nrf51.INSN_PER_TICK (-icount shift=0, TIMER0 at 16 MHz)


MAILBOX_MAGIC = pil_mailbox.MAGIC


MAILBOX_WORDS = pil_mailbox.WORDS


class Monitor:
    """QEMU's human monitor on a unix socket (``launcher.qemu_command(monitor=...)``): ``words(addr, n)`` reads n
    32-bit words of the guest's memory, as a debugger reads a board's."""

    def __init__(self, path, timeout_s=5.0):
        import socket
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(timeout_s)
        self.sock.connect(path)
        self._until_prompt()

    def _until_prompt(self):
        buf = b""
        while not buf.endswith(b"(qemu) "):
            b = self.sock.recv(65536)
            if not b:
                raise BoardError("QEMU's monitor closed")
            buf += b
        return buf.decode(errors="replace")

    def words(self, addr, n):
        out = []
        while len(out) < n:
            k = min(1024, n - len(out))
            self.sock.sendall(b"xp /%dwx 0x%08x\n" % (k, addr + 4 * len(out)))
            text = self._until_prompt()
            got = []
            for line in text.splitlines():
                head, sep, rest = line.partition(":")
                if sep and head.strip().startswith("0000") and "x" not in head.strip()[:2]:
                    got.extend(int(w, 16) for w in rest.split())
            if len(got) != k:
                raise BoardError("QEMU's monitor gave %d words for %d at 0x%08x" % (len(got), k, addr))
            out.extend(got)
        return out

    def close(self):
        self.sock.close()


def read_target(monitor_path, mem=TARGET_MEM):
    """What a ``--runtime qemu`` run's summary.json states of the target (``TARGET``, the memory map, the stack's
    high-water mark, the instructions per TICK exchange from ``firmware.pil_main``'s mailbox), read from the board's
    RAM through QEMU's monitor while it still runs. None for a part the board did not write (no mailbox)."""
    mon = Monitor(monitor_path)
    try:
        box = mon.words(mem.stack_bottom, MAILBOX_WORDS)
        painted = mon.words(mem.stack_bottom + 4 * MAILBOX_WORDS, mem.stack_bytes // 4 - MAILBOX_WORDS)
    finally:
        mon.close()
    out = dict(TARGET, ram_bytes=mem.ram_bytes, heap_bytes=mem.heap_bytes, stack_bytes=mem.stack_bytes,
               stack_high_water_bytes=None, instructions_per_step=None)
    if box[0] != MAILBOX_MAGIC:
        return out
    k = 0
    while k < len(painted) and painted[k] == STACK_PAINT:
        k += 1
    out["stack_high_water_bytes"] = mem.stack_bytes - 4 * (MAILBOX_WORDS + k)
    out["instructions_per_step"] = pil_mailbox.decode(box)
    return out
