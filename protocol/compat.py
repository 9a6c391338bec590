"""MicroPython's names where CPython has none, defined once for the code that runs on both: ``const``
(MicroPython's compiler folds ``_X = const(n)`` whichever module the name is imported from), the heap lock, the
``time`` module's tick counters (they wrap on a board; CPython's are monotonic and never wrap) and ``crc32``
(binascii's C implementation, or the protocol's own where a port has none)."""

try:
    from micropython import const
except ImportError:                      # CPython
    def const(x):
        return x

try:
    from micropython import heap_lock, heap_unlock
except ImportError:                      # CPython: nothing to lock
    def heap_lock():
        return 0

    def heap_unlock():
        return 0

try:
    from time import ticks_add, ticks_diff, ticks_ms, ticks_us
except ImportError:                      # CPython: monotonic counters
    import time

    def ticks_ms():
        return int(time.monotonic() * 1000)

    def ticks_us():
        return int(time.monotonic() * 1e6)

    def ticks_add(a, b):
        return a + b

    def ticks_diff(a, b):
        return a - b

try:
    from binascii import crc32
except ImportError:                      # pragma: no cover - a port without binascii.crc32
    from protocol.core import crc32
