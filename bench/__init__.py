"""Benchmarks (``make bench``, ``python -m bench.run NAME``)."""


def verdict(value, goal, at_most=True):
    """' (met)' or ' (missed)' for ``value`` against ``goal`` (``at_most``: value <= goal, else >=); '' when
    ``goal`` is None (no goal)."""
    if goal is None:
        return ""
    ok = value <= goal if at_most else value >= goal
    return " (met)" if ok else " (missed)"
