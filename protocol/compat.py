"""MicroPython's names where CPython has none, defined once for the code that runs on both: ``const``
(MicroPython's compiler folds ``_X = const(n)`` whichever module the name is imported from), the ``time``
module's tick counters (they wrap on a board; CPython's are monotonic and never wrap) and ``crc32``
(binascii's C implementation, or the protocol's own where a port has none).

The modules the fine-pointing controller's board imports (firmware/ad5664r.py, hal/stdio.py, upload.py,
protocol/hblob.py) keep their own two-line shims: on the 32 KB micro:bit this module's few hundred bytes leave
the 11 x 11 H table no room (MemoryError in hinv when it is uploaded, measured under QEMU)."""

try:
    from micropython import const
except ImportError:                      # CPython
    def const(x):
        return x

try:
    from time import ticks_add, ticks_diff, ticks_ms, ticks_us
except ImportError:                      # CPython: monotonic counters
    def ticks_add(a, b):
        return a + b

    def ticks_diff(a, b):
        return a - b

    try:
        from time import monotonic as _monotonic
    except ImportError:                  # a board's build without a time module: its HAL keeps the time
        pass
    else:
        def ticks_ms():
            return int(_monotonic() * 1000)

        def ticks_us():
            return int(_monotonic() * 1e6)

try:
    from binascii import crc32
except ImportError:                      # pragma: no cover - a port without binascii.crc32
    from protocol.core import crc32
