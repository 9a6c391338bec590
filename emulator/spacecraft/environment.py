"""Orbit and environment torques: circular orbit, tilted-dipole field, gravity gradient, residual dipole.

Gravity gradient (Eq. 4.69-4.75): with G_i = (mu/r^3)(3 r r^T/r^2 - I) (Eq. 4.75) and G_b = A G_i A^T
(Eq. 4.72), the torque on a body of inertia J is tau_g = (3 mu/r^3) r_b x (J r_b) with r_b the unit vector to
the spacecraft in the body frame (the isotropic part of G gives no torque). The OCR of Eq. 4.69 has lost a sign;
this is the standard form (restoring for the minimum-inertia axis on the local vertical, see the tests).
Magnetic torque (Eq. 4.71, 4.73): tau_m = m x b_b, b_b = A(q) b_i.
"""

import math

import numpy as np

MU_EARTH = 3.986004418e14      # m^3/s^2
R_EARTH = 6371.2e3             # m, IGRF reference radius
OMEGA_EARTH = 7.2921159e-5     # rad/s
# IGRF-13 degree-1 coefficients at epoch 2020 (nT): g10, g11, h11. The dipole m = (g11, h11, g10) * R^3.
IGRF2020_DIPOLE_NT = (-29404.8, -1450.9, 4652.5)
M_DIPOLE_THESIS = (-0.11, 0.15, 0.20)   # A m^2, residual dipole, Sec. 4.8


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
