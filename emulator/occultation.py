"""Whether the Earth blocks the crosslink (and the beacon camera's view of the partner): the straight segment from
SatA to SatB against a spherical Earth.

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
