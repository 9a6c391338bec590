"""Navigation sensors of the STKF study (thesis Sec. 5.3.2-5.3.3, 5.5.1).

* ``Gnss``: navigation solution y = [r; v] + n, n ~ N(0, diag(30 m, 30 m, 30 m, 1, 1, 1 m/s)^2) (Eq. 5.10-5.11).
* ``Beacon``: unit vector from SatA to SatB in SatA's body frame with additive noise (Eq. 5.13-5.15),
  y = A(q) (rB - rA) / |rB - rA| + n, n ~ N(0, (60 arcsec)^2 I3); a misaligned camera (``misalignment_deg``,
  the spacecraft file's rotation vector) measures in its own frame, y = C A(q) (rB - rA) / |rB - rA| + n with
  C = A(dq), dq = [delta/2, 1] normalised (Eq. 4.77).
* ``Relay``: SatB's GNSS sent through the ground. SatB's receiver samples at 1 Hz on its own clock (a phase
  offset from SatA's filter ticks, so the measurement times fall between filter nodes); each solution keeps
  its time tag and arrives U(2, 3) s later. ``due(t)`` returns what has arrived by t, oldest first.
"""

import numpy as np

from emulator.spacecraft.dynamics import dcm
from protocol.units import RAD_PER_ARCSEC

def _nonneg(name, v):
    v = float(v)
    if not (np.isfinite(v) and v >= 0):
        raise ValueError("%s must be a number >= 0, got %r" % (name, v))
    return v


class Gnss:
    """GNSS navigation solution, Eq. 5.10-5.11 (30 m, 1 m/s 1 sigma per axis)."""

    def __init__(self, rng, sigma_r_m=30.0, sigma_v_m_s=1.0):
        self.rng = rng
        self.sigma = np.array([_nonneg("sigma_r_m", sigma_r_m)] * 3 + [_nonneg("sigma_v_m_s", sigma_v_m_s)] * 3)

    @property
    def R(self):
        return np.diag(self.sigma ** 2)

    def measure(self, x):
        return np.asarray(x, dtype=float) + self.sigma * self.rng.standard_normal(6)


class Beacon:
    """Beacon camera: SatA->SatB unit vector in SatA's body frame, Eq. 5.13 (60 arcsec 1 sigma per axis)."""

    def __init__(self, rng, sigma_arcsec=60.0, misalignment_deg=None):
        self.rng = rng
        self.sigma = _nonneg("sigma_arcsec", sigma_arcsec) * RAD_PER_ARCSEC
        self.C = None                                   # aligned: y in the body frame
        if misalignment_deg is not None:
            g = 0.5 * np.radians(np.asarray(misalignment_deg, dtype=float))
            if g.shape != (3,) or not np.all(np.isfinite(g)):
                raise ValueError("misalignment_deg must be 3 finite angles (deg), got %r" % (misalignment_deg,))
            if np.any(g != 0):
                self.C = dcm(np.append(g, 1.0) / np.sqrt(1.0 + g @ g))

    @property
    def R(self):
        return self.sigma ** 2 * np.eye(3)

    def measure(self, r_a, r_b, q):
        return self.measure_dcm(r_a, r_b, dcm(q))

    def measure_dcm(self, r_a, r_b, A):
        """The same with the attitude as its matrix A (inertial to body)."""
        d = np.asarray(r_b, dtype=float) - np.asarray(r_a, dtype=float)
        rho = np.linalg.norm(d)
        if not (np.isfinite(rho) and rho > 0):
            raise ValueError("beacon: SatA and SatB coincide (or a position is not finite): |rB - rA| = %r m" % rho)
        if self.C is not None:
            A = self.C @ A
        return A @ (d / rho) + self.sigma * self.rng.standard_normal(3)


class Relay:
    """SatB's GNSS through the ground: time-tagged solutions delivered ``U(delay_min, delay_max)`` s late.

    ``sample(t_meas, x_true)`` records a solution taken at ``t_meas``; ``due(t)`` pops every one with
    arrival time <= t as (t_meas, z), in order of arrival.
    """

    def __init__(self, rng, gnss, delay_s=(2.0, 3.0)):
        lo, hi = (_nonneg("delay_min_s", delay_s[0]), _nonneg("delay_max_s", delay_s[1]))
        if hi < lo:
            raise ValueError("relay delay range must be min <= max, got %r" % (delay_s,))
        self.rng, self.gnss, self.delay = rng, gnss, (lo, hi)
        self.queue = []

    def sample(self, t_meas, x_true):
        z = self.gnss.measure(x_true)
        arrive = t_meas + self.rng.uniform(*self.delay)
        self.queue.append((arrive, t_meas, z))

    def due(self, t):
        out = sorted((q for q in self.queue if q[0] <= t + 1e-12), key=lambda q: q[0])
        self.queue = [q for q in self.queue if q[0] > t + 1e-12]
        return [(tm, z) for _, tm, z in out]
