"""Helpers the benchmarks share: timing a call, a goal's "(missed)" mark."""

import time


def timed(fn, *args, **kw):
    """``fn(*args, **kw)`` and its wall time (s): (result, seconds)."""
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t0


def missed(value, goal):
    """' (missed)' when ``value`` is above ``goal``, else ''."""
    return "" if value <= goal else " (missed)"

