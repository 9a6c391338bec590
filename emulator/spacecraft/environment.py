"""Orbit and environment torques: circular orbit, tilted-dipole field, gravity gradient, residual dipole, and the
flight world's drag and solar radiation pressure torques (``SurfaceTorques``).

Gravity gradient (Eq. 4.69-4.75): with G_i = (mu/r^3)(3 r r^T/r^2 - I) (Eq. 4.75) and G_b = A G_i A^T
(Eq. 4.72), the torque on a body of inertia J is tau_g = (3 mu/r^3) r_b x (J r_b) with r_b the unit vector to
the spacecraft in the body frame (the isotropic part of G gives no torque). The OCR of Eq. 4.69 has lost a sign;
this is the standard form (restoring for the minimum-inertia axis on the local vertical, see the tests).
Magnetic torque (Eq. 4.71, 4.73): tau_m = m x b_b, b_b = A(q) b_i.
"""

import math

import numpy as np

from protocol.units import MU_EARTH

R_EARTH = 6371.2e3             # m, IGRF reference radius
OMEGA_EARTH = 7.2921159e-5     # rad/s
# IGRF-13 degree-1 coefficients at epoch 2020 (nT): g10, g11, h11. The dipole m = (g11, h11, g10) * R^3.
IGRF2020_DIPOLE_NT = (-29404.8, -1450.9, 4652.5)
M_DIPOLE_THESIS = (-0.11, 0.15, 0.20)   # A m^2, residual dipole, Sec. 4.8
P_SUN_N_M2 = 4.56e-6          # solar radiation pressure at 1 au (N/m^2)


class CircularOrbit:
    """Circular Keplerian orbit, analytic: position and velocity in the inertial frame at time t (s).

    Defaults are the thesis's ISS-like orbit (Sec. 5.5: 400 km, 51.65 deg).
    """

    def __init__(self, altitude=400e3, inclination_deg=51.65, raan_deg=0.0, arg_lat_deg=0.0):
        if not (np.isfinite(altitude) and altitude > 0):
            raise ValueError("altitude must be > 0 m, got %r" % (altitude,))
        for name, v in (("inclination_deg", inclination_deg), ("raan_deg", raan_deg), ("arg_lat_deg", arg_lat_deg)):
            if not np.isfinite(v):
                raise ValueError("%s must be a finite angle, got %r" % (name, v))
        self.a = R_EARTH + altitude
        self.n = np.sqrt(MU_EARTH / self.a ** 3)
        i, raan = np.radians(inclination_deg), np.radians(raan_deg)
        # in-plane basis: p toward the ascending node, w 90 deg ahead in the orbit plane
        self.p = np.array([np.cos(raan), np.sin(raan), 0.0])
        self.w = np.array([-np.sin(raan) * np.cos(i), np.cos(raan) * np.cos(i), np.sin(i)])
        self.u0 = np.radians(arg_lat_deg)

    def position(self, t):
        u = self.u0 + self.n * t
        return self.a * (np.cos(u) * self.p + np.sin(u) * self.w)

    def velocity(self, t):
        u = self.u0 + self.n * t
        return self.a * self.n * (-np.sin(u) * self.p + np.cos(u) * self.w)


class TiltedDipoleField:
    """Earth's field as the IGRF-2020 tilted dipole turning with the Earth: b_i(r, t) in tesla, inertial frame.

    b = (R/|r|)^3 [3 (m . r_hat) r_hat - m], m = (g11, h11, g10) rotated by the Earth angle gmst0 + w_E t.
    """

    def __init__(self, gmst0_rad=0.0, coeffs_nt=IGRF2020_DIPOLE_NT):
        g10, g11, h11 = coeffs_nt
        self.m_ecef = 1e-9 * np.array([g11, h11, g10])
        self._m = self.m_ecef.tolist()
        self.gmst0 = gmst0_rad

    def field(self, r_i, t):
        """b_i (T, inertial) at position r_i (m, inertial) and time t (s)."""
        return np.array(self.field_floats(r_i, t))

    def field_floats(self, r_i, t):
        """``field`` as a tuple of Python floats (``r_i`` an array or a 3-sequence), for the truth's derivative."""
        th = self.gmst0 + OMEGA_EARTH * t
        c, s = math.cos(th), math.sin(th)
        mx, my, mz = self._m
        m0, m1, m2 = c * mx - s * my, s * mx + c * my, mz
        x, y, z = r_i.tolist() if isinstance(r_i, np.ndarray) else r_i
        rn = math.sqrt(x * x + y * y + z * z)
        x, y, z = x / rn, y / rn, z / rn
        k = (R_EARTH / rn) ** 3
        d = 3.0 * (m0 * x + m1 * y + m2 * z)
        return k * (d * x - m0), k * (d * y - m1), k * (d * z - m2)


def cross3(a, b):
    """a x b for 3-vectors (np.cross costs ~10x more on single vectors)."""
    return np.array([a[1]*b[2] - a[2]*b[1], a[2]*b[0] - a[0]*b[2], a[0]*b[1] - a[1]*b[0]])


def gravity_gradient_torque(j, r_b):
    """Eq. 4.69-4.75: tau_g = 3 mu/|r|^3 * r_hat x (J r_hat), r_b = position in the body frame (m)."""
    rn = np.sqrt(r_b @ r_b)
    rh = r_b / rn
    return (3.0 * MU_EARTH / rn ** 3) * cross3(rh, j @ rh)


def magnetic_torque(m_dipole, b_b):
    """Eq. 4.71: tau_m = m x b_b (A m^2 x T = N m)."""
    return cross3(m_dipole, b_b)


def _norms(a):
    """|a_k| of each row as a column, by ``np.linalg.norm`` row by row (the same rounding as a single vector's)."""
    return np.array([np.linalg.norm(row) for row in a]).reshape(-1, 1)


class SurfaceTorques:
    """Aerodynamic drag and solar radiation pressure torques of a flat-plate spacecraft whose centre of pressure
    sits ``cp_offset_m`` (body frame) from its centre of mass: tau = r_cp x (F_drag + F_srp), with
    F_drag = -1/2 rho Cd A_d |v_r| v_r (v_r = v - w_E x r, the velocity against an atmosphere turning with the
    Earth) and F_srp = -nu P_sun Cr A_s s (s the unit vector to the Sun, nu the sunlit fraction). Not in the
    thesis (its spacecraft feels gravity gradient, the residual dipole and Sec. 4.8's tau_d only); this is the
    flight world's. Stated simplifications: the projected areas do not change with attitude (the file's
    figures, as the orbit truth's cannonball), and the inertial forces are taken once per second.

    ``t_s`` (n,) s and ``x`` (n, 6) the orbit's [r (m), v (m/s)] (EME2000) at 1 s steps from t = 0;
    ``epoch_utc`` the orbits' t = 0 (a 6-tuple). Density: brahe's Harris-Priester model; the Sun: brahe's
    low-precision ephemeris; the shadow: brahe's conical model (the orbit truth's, ``emulator.orbits``)."""

    def __init__(self, t_s, x, epoch_utc, surface, cp_offset_m):
        from emulator.orbits import _brahe
        bh = _brahe()
        y, mo, d, h, mi, s = epoch_utc
        e0 = bh.Epoch(y, mo, d, h, mi, s, time_system=bh.UTC)
        x = np.asarray(x, float)
        r, v = x[:, 0:3], x[:, 3:6]
        self.cp = tuple(float(c) for c in cp_offset_m)
        r_sun = np.array([bh.sun_position(e0 + float(tk)) for tk in t_s], dtype=float).reshape(-1, 3)
        self.rho = np.array([bh.density_harris_priester(a, b) for a, b in zip(r, r_sun)], dtype=float)
        self.sunlit = np.array([bh.eclipse_conical(a, b) for a, b in zip(r, r_sun)], dtype=float)
        vr = v - np.cross(np.array([0.0, 0.0, OMEGA_EARTH]), r)
        s_hat = (r_sun - r) / _norms(r_sun - r)
        f = ((-0.5 * self.rho[:, None] * surface["cd"] * surface["drag_area_m2"] * _norms(vr)) * vr
             - (self.sunlit[:, None] * P_SUN_N_M2 * surface["cr"] * surface["srp_area_m2"]) * s_hat)
        self.t0, self.force_i = float(t_s[0]), f
        self._f = f.tolist()

    def __call__(self, t, q, w=None):
        """tau (body frame, N m) at time t (s) and attitude q (inertial to body, scalar last)."""
        k = min(max(int(t - self.t0), 0), len(self._f) - 1)
        f0, f1, f2 = self._f[k]
        e1, e2, e3, q4 = (float(c) for c in q)
        b0 = (q4*q4 + e1*e1 - e2*e2 - e3*e3) * f0 + 2*(e1*e2 + q4*e3) * f1 + 2*(e1*e3 - q4*e2) * f2
        b1 = 2*(e1*e2 - q4*e3) * f0 + (q4*q4 - e1*e1 + e2*e2 - e3*e3) * f1 + 2*(e2*e3 + q4*e1) * f2
        b2 = 2*(e1*e3 + q4*e2) * f0 + 2*(e2*e3 - q4*e1) * f1 + (q4*q4 - e1*e1 - e2*e2 + e3*e3) * f2
        c0, c1, c2 = self.cp
        return np.array([c1 * b2 - c2 * b1, c2 * b0 - c0 * b2, c0 * b1 - c1 * b0])


class GridOrbit:
    """An orbit given on a uniform time grid (rate_hz samples from t0): ``position(t)`` is the nearest
    sample (the caller interpolated the grid finely enough, as ``scenario.pointing_world`` does at 20 Hz)."""

    def __init__(self, t0, rate_hz, r):
        self.t0, self.rate, self.r = float(t0), float(rate_hz), r

    def position(self, t):
        i = int(round((t - self.t0) * self.rate))
        return self.r[min(max(i, 0), len(self.r) - 1)]
