"""The clock of the ADCS PIL board (QEMU's mps2-an500, tools/pil_build.py's ADCS image), which has no ``time``
module: the CMSDK APB timer TIMER0, counting down at the 25 MHz peripheral clock from a 30-bit reload (so a read is
a small int: nothing allocated), extended in software and turned into MicroPython's ``ticks_ms``/``ticks_us``/
``ticks_diff`` (values modulo 2^30, as ``time``'s); and UART0's receive flag (``rx_ready``). Under QEMU's ``-icount shift=0`` one instruction is one virtual
ns: a timer tick is 40 instructions. Reads must come at least every 42.9 s (one reload period)."""

import machine

TIMER0 = 0x40000000
UART0_STATE = 0x40004004          # CMSDK APB UART: bit 1, a received byte waits
HZ = 25000000
_MASK = 0x3FFFFFFF
_last = 0
_wraps = 0


def start():
    """Stop, load and start TIMER0 (counting down from 2^30 - 1, reloading)."""
    global _last, _wraps
    m = machine.mem32
    m[TIMER0] = 0                   # CTRL: stopped
    m[TIMER0 + 8] = _MASK           # RELOAD
    m[TIMER0 + 4] = _MASK           # VALUE
    m[TIMER0] = 1                   # CTRL: enabled
    _last = 0
    _wraps = 0


def count():
    """Timer ticks since ``start`` (an int that grows past 2^30 after 42.9 s)."""
    global _last, _wraps
    v = _MASK - machine.mem32[TIMER0 + 4]
    if v < _last:
        _wraps += 1
    _last = v
    return (_wraps << 30) | v


def ticks_us():
    return (count() // (HZ // 1000000)) & _MASK


def ticks_ms():
    return (count() // (HZ // 1000)) & _MASK


def ticks_diff(a, b):
    return ((a - b + 0x20000000) & _MASK) - 0x20000000


def rx_ready():
    """A byte waits in UART0 (the console: MicroPython's own driver reads it)."""
    return machine.mem32[UART0_STATE] & 2
