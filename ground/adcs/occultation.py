"""Whether the Earth blocks the crosslink: the straight segment from SatA to SatB against a spherical Earth.

The Earth is a sphere of the WGS-84 equatorial radius, 6378.137 km (the polar radius is 21.4 km less, so at high
latitudes the sphere blocks a little more than the real Earth: on the safe side, and within the margin). A line of
sight is taken as blocked when it passes within ``margin_m`` of that sphere: ``ATMOSPHERE_MARGIN_M``, 100 km, the
Kármán line, by default. Below it a grazing optical path crosses enough air to be refracted, absorbed and
scintillated; 100 km is a convention for where the atmosphere starts, not a computed link budget, and a
designer may take a larger one (the argument).

Units: m and s. Positions are arrays (..., 3) in any Earth-centred frame (EME2000 here).
"""

import numpy as np

R_EARTH_M = 6378137.0               # WGS-84 equatorial radius, taken as a sphere
ATMOSPHERE_MARGIN_M = 100e3         # the Kármán line: below it the beam grazes the atmosphere


def closest_distance(ra, rb):
    """Distance (m) from the Earth's centre to the nearest point of each segment ra -> rb (..., 3): the segment,
    not the infinite line, so two satellites on the same side of the Earth are never blocked by the far side."""
    a, b = np.asarray(ra, float), np.asarray(rb, float)
    d = b - a
    dd = np.einsum("...i,...i->...", d, d)
    s = np.clip(-np.einsum("...i,...i->...", a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(a + s[..., None] * d, axis=-1)


def clearance(ra, rb):
    """Height (m) of each segment's lowest point above the sphere (negative: the segment goes through it)."""
    return closest_distance(ra, rb) - R_EARTH_M


def occulted(ra, rb, margin_m=ATMOSPHERE_MARGIN_M):
    """True for each sample whose segment ra -> rb passes within R_EARTH_M + margin_m of the Earth's centre."""
    if not (np.isfinite(margin_m) and margin_m >= 0):
        raise ValueError("occultation margin must be >= 0 m, got %r" % (margin_m,))
    return closest_distance(ra, rb) < R_EARTH_M + margin_m


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
