"""The controller on the PIL board (tools/pil_build.py's image; ``--runtime qemu``): what ``firmware.main
controller`` does on the unix port, on the console UART (``firmware.hal.stdio``). Started by importing it through
the raw REPL; Ctrl-C (0x03, a byte like any other in the frames) is turned off first.

The board has 32 KB of RAM: the H-table upload's buffer and the table's integers are allocated first, once, for
the thesis's 11x11 grid (``TABLE_GRID``; a larger table is refused with TOO_LARGE), while the heap still has a free
block that large.

What the host reads back after a run (through QEMU's monitor, as a debugger reads a board's RAM), at the bottom
of the stack region (``pil_board``): a mailbox (``tools.pil_mailbox``): ``MAGIC``, one clock read's own cost, then
for each kind of TICK exchange (``firmware.hal.stdio._K_*``: common, a new H^-1 bin, CTRL_STATUS, a resend
answered from the cache, other) its count, sum, largest and a histogram by bit length, in ticks of the nRF51's
TIMER0 at 16 MHz (16-bit mode), then the wire's words (``Meter.wire``); above it, the stack painted with
``pil_board.STACK_PAINT`` here at start, whose first overwritten word is the stack's high-water mark. An exchange
is a TICK's frame, read whole from the UART by ``firmware.hal.nrf51.read_frame`` (machine code), decoded, then its
FSM_SPI (and the CTRL_STATUS after it, when due) computed and framed: the decoding, the step and the framing, less the UART's own byte moves
(``firmware.hal.stdio``) and the clock reads. Under QEMU's ``-icount shift=0`` one instruction takes one virtual
ns, so a tick is 62.5 instructions."""

import machine
import micropython
import sys

import pil_board
from micropython import const

_KINDS = const(5)                 # firmware.hal.stdio's _K_COMMON .. _K_OTHER
_K_STATUS = const(2)
_K_RESEND = const(3)
_BUCKETS = const(18)              # a histogram bucket per bit length of a duration in timer ticks (0..17)
_KIND_WORDS = const(21)           # count, sum, largest, _BUCKETS
_WIRE = const(107)                # the wire's words: byte, cpu, tx, worst, late, n (``Meter.wire``)
_BOX_WORDS = const(113)           # MAGIC, a clock read's cost, _KINDS * _KIND_WORDS, the wire's (tools.pil_mailbox)
_CYCLES_PER_TICK = const(100)     # a timer tick's 62.5 instructions at CPI 1.6 (the SAMD21's one flash wait state)
_PERIOD = const(75259)            # the tick in cycles: 48 MHz / 637.8 Hz
WIRE_BAUD = const(2000000)        # the UART the wire is modelled at (8N1: 10 bits a byte)


def paint_stack():
    """``STACK_PAINT`` over the free stack: from above the mailbox to 64 bytes below what is in use now."""
    m = machine.mem32
    a = pil_board.STACK_BOTTOM + 4 * _BOX_WORDS
    top = pil_board.STACK_TOP - micropython.stack_use() - 64
    v = pil_board.STACK_PAINT
    while a < top:
        m[a] = v
        a += 4


# The stack is painted before the firmware is imported, so the high-water mark counts the imports too; and the
# modules are imported leaves first, so that each import nests one level only: a nested import takes about 0.9 KB
# of C stack, and the chain controller_viper, controller, hinv, htable, consts ran past a 5.5 KB stack (measured).
paint_stack()
import protocol.consts  # noqa: E402
import protocol.fast  # noqa: E402,F401
import protocol.hblob  # noqa: E402,F401
import firmware.ad5664r  # noqa: E402,F401
import firmware.upload  # noqa: E402,F401
import firmware.hinv  # noqa: E402,F401
import firmware.controller  # noqa: E402,F401
from firmware.controller_viper import ViperController  # noqa: E402
from firmware.hal.link import serve_controller  # noqa: E402
from firmware.hal.stdio import StdioLink, frame_bytes  # noqa: E402
from firmware.hal import nrf51  # noqa: E402
from firmware.hal import fast_tick  # noqa: E402
from firmware.hal import fast_status  # noqa: E402

TABLE_GRID = 11
MAGIC = const(0x0C0FFEE)


class Meter:
    """TIMER0 and the mailbox: ``now()`` in ticks (``firmware.hal.nrf51``, 16-bit); ``exchange(t0, work, n,
    kind)`` adds one exchange of that kind and lays it on the wire (``wire``). Neither allocates (small ints
    only), so it runs beside the locked heap."""

    def __init__(self, box):
        self.box = box
        self.now = nrf51.now
        self.start = nrf51.mark         # a machine-code exchange's start: the timer cleared (``nrf51.mark``)
        nrf51.start(16)
        m = machine.mem32
        for k in range(1, _BOX_WORDS):
            m[box + 4 * k] = 0
        t = self.start()
        m[box + 4] = (self.now() - t) & 0xFFFF     # one read's own cost, taken off each exchange
        byte = m[box + 4 * _WIRE] = 10 * 48000000 // WIRE_BAUD
        s = protocol.consts.SIZES
        # each frame's cycles on the wire: a TICK in, an FSM_SPI out, a CTRL_STATUS out
        self.frames = (byte * frame_bytes(s[protocol.consts.P_TICK]), byte * frame_bytes(s[protocol.consts.P_FSM_SPI]),
                       byte * frame_bytes(s[protocol.consts.P_CTRL_STATUS]))
        m[box] = MAGIC

    def exchange(self, t0, work, n, kind, first=-1):
        """One exchange of ``kind``: ``work`` ticks, then from t0 to now, in ``n`` timed intervals; less a clock
        read's own cost for each. ``first``: the ticks until its FSM_SPI was framed, where a status followed
        (else the whole exchange), for ``wire``."""
        d = work + ((nrf51.now() - t0) & 0xFFFF)
        m = machine.mem32
        c = m[self.box + 4]
        d -= n * c
        if d < 0:
            d = 0
        a = self.box + 8 + 4 * _KIND_WORDS * kind
        m[a] += 1
        m[a + 4] += d
        if d > m[a + 8]:
            m[a + 8] = d
        k = 0
        while d >> k and k < _BUCKETS - 1:
            k += 1
        m[a + 12 + 4 * k] += 1
        if kind != _K_RESEND:
            f = d if first < 0 else max(first - c, 0)
            self.wire(f * _CYCLES_PER_TICK, (d - f) * _CYCLES_PER_TICK, kind == _K_STATUS)

    def wire(self, first, rest, status):
        """The tick on the wire, in cycles from its start on the bench's 637.8 Hz grid: the TICK's bytes in at
        ``WIRE_BAUD``, the computation (``first`` until the FSM_SPI is framed) once they are in and the CPU is free,
        the FSM_SPI's bytes out once it is framed and the UART has sent what was before it (a DMA channel or an
        interrupt sends them, full duplex: the next TICK comes in meanwhile); a status tick's CTRL_STATUS packed
        after it (``rest``) and queued behind it. Keeps the latest FSM_SPI's end (``worst``) and the ticks whose
        FSM_SPI ended after the tick (``late``)."""
        m = machine.mem32
        a = self.box + 4 * _WIRE
        r, f, s = self.frames
        ready = max(r, m[a + 4]) + first
        end = max(ready, m[a + 8]) + f
        if end > m[a + 12]:
            m[a + 12] = end
        if end > _PERIOD:
            m[a + 16] += 1
        m[a + 20] += 1
        cpu = ready + rest
        tx = max(cpu, end) + s if status else end
        m[a + 4] = max(cpu - _PERIOD, 0)
        m[a + 8] = max(tx - _PERIOD, 0)


def main():
    """Serve the bench until the link ends; on an error, print its traceback on the UART and halt (the host tells
    it: ``emulator.launcher.FirmwareProcess.exit_note``), never back to the REPL, which would answer the bench's
    frames as keystrokes."""
    micropython.kbd_intr(-1)
    table_bytes = protocol.hblob.blob_size(TABLE_GRID, TABLE_GRID)
    try:
        serve_controller(ViperController(max_table_bytes=table_bytes, static=True),
                         StdioLink(protocol.consts.NODE_CONTROLLER, meter=Meter(pil_board.STACK_BOTTOM),
                                   read_frame=nrf51.read_frame, write_frame=nrf51.write_frame,
                                   fast=fast_tick.answer, status=fast_status.status),
                         rate_hz=637.8)
    except Exception as exc:            # MemoryError included
        sys.print_exception(exc)
        while True:
            machine.idle()


main()
