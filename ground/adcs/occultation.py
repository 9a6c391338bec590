"""A run's line of sight to the partner: the occulted stretches and figures of a run from its true orbits (the
geometry, a segment against the Earth plus an atmosphere margin, is ``emulator.occultation``'s: the emulated beacon
camera loses the partner by the same test).

Units: m and s.
"""

import numpy as np

from emulator.occultation import (ATMOSPHERE_MARGIN_M, R_EARTH_M, clearance, closest_distance,  # noqa: F401
                                  occulted)


def intervals(t, mask):
    """The stretches where ``mask`` is true, as [(start_s, length_s)]: each starts at its first true sample and
    ends at the first false one after it; a stretch still running at the last sample ends there (a single true
    last sample has length 0)."""
    t, m = np.asarray(t, float), np.asarray(mask, bool)
    if t.shape != m.shape or t.ndim != 1:
        raise ValueError("t and mask must be 1-D and of one length, got %s and %s" % (t.shape, m.shape))
    edges = np.diff(np.concatenate([[False], m, [False]]).astype(np.int8))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    return [(float(t[i]), float(t[min(j, len(t) - 1)] - t[i])) for i, j in zip(starts, ends)]


def summary(t, ra, rb, window=None, margin_m=ATMOSPHERE_MARGIN_M):
    """A run's line of sight from its true orbits at the times ``t``: (mask, figures) with mask the occulted
    samples and figures {"intervals", "share" (of the run's samples), "margin_km", "earth_radius_km",
    "min_clearance_km" (the lowest the line of sight came above the sphere), "window_share" (of the samples in
    ``window``, the pointing window; None without one), "line_of_sight" (False when every sample of the window
    is occulted, or, with an empty window, every sample of the run)}."""
    mask = occulted(ra, rb, margin_m)
    low = clearance(ra, rb)
    n_win = 0 if window is None else int(np.count_nonzero(window))
    win_share = float(np.mean(mask[window])) if n_win else None
    blocked = (win_share == 1.0) if n_win else bool(len(mask) and mask.all())
    return mask, {"intervals": [list(iv) for iv in intervals(t, mask)],
                  "share": float(mask.mean()) if len(mask) else 0.0, "margin_km": margin_m / 1e3,
                  "earth_radius_km": R_EARTH_M / 1e3,
                  "min_clearance_km": float(low.min()) / 1e3 if len(low) else None,
                  "window_share": win_share, "line_of_sight": not blocked}
