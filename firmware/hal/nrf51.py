"""The nRF51's peripherals the PIL board (QEMU's microbit machine) uses beyond MicroPython's: TIMER0 as a clock
(``start(bits)`` runs it at 16 MHz as a 16- or 32-bit counter, ``mark()`` clears it, ``now()`` captures and reads
it; under QEMU's ``-icount shift=0``, one instruction a virtual ns, a tick is 62.5 instructions; a 16-bit count is a
small int on the board, so reading it allocates nothing) and UART0 (``read_frame`` and ``write_frame``, viper)."""

import machine
import micropython

from micropython import const

T0 = const(0x40008000)
_CAPTURE0 = const(0x40008040)        # TASKS_CAPTURE[0]
_CC0 = const(0x40008540)             # CC[0]
INSN_PER_TICK = 62.5                 # 1e9 instructions a virtual second / 16 MHz


def start(bits=16):
    """Stop, set up (timer mode, 16 or 32 bits, no prescaler: 16 MHz), clear and start TIMER0."""
    m = machine.mem32
    m[T0 + 0x004] = 1                # TASKS_STOP
    m[T0 + 0x504] = 0                # MODE: timer
    m[T0 + 0x508] = 0 if bits == 16 else 3
    m[T0 + 0x510] = 0                # PRESCALER
    m[T0 + 0x00C] = 1                # TASKS_CLEAR
    m[T0 + 0x000] = 1                # TASKS_START


def now():
    """The count now (mask it to the width ``start`` set)."""
    m = machine.mem32
    m[_CAPTURE0] = 1
    return m[_CC0]


@micropython.viper
def mark() -> int:
    """Clear TIMER0 (TASKS_CLEAR, the count to 0 from this store) and return 0: a duration read from here counts
    the instructions run since this store, to a tick, whatever ran before it (under ``-icount`` QEMU's timer takes
    the clear's virtual time at the store itself), so the same instructions always read the same ticks."""
    base = 0x4000
    base <<= 16
    clear = ptr32(base + 0x800C)     # TASKS_CLEAR
    clear[0] = 1
    return 0


@micropython.viper
def read_frame(buf: ptr8, n: int) -> int:
    """UART0's bytes into buf up to and with the next 0x00, polling its RXDRDY event as the port's own driver does
    (``mp_hal_stdin_rx_chr``; the two never run at once); returns the bytes read (more than n: a frame longer than
    buf, the bytes beyond n dropped). Machine code: the per-byte work of a UART driver, not a Python loop's."""
    base = 0x4000
    base <<= 16                      # 0x40000000 built at run time: as a literal it would be an object, not an int
    rdy = ptr32(base + 0x2108)       # EVENTS_RXDRDY
    rxd = ptr32(base + 0x2518)       # RXD
    i = 0
    while True:
        if rdy[0]:
            rdy[0] = 0
            x = rxd[0] & 0xFF
            if i < n:
                buf[i] = x
            i += 1
            if x == 0:
                return i


@micropython.viper
def write_frame(buf: ptr8, n: int):
    """buf[0:n] to UART0's TXD, as the port's own driver does (``uart_tx_strn``: QEMU's UART takes each byte at
    once)."""
    base = 0x4000
    base <<= 16
    txd = ptr32(base + 0x251C)       # TXD
    i = 0
    while i < n:
        txd[0] = buf[i]
        i += 1
