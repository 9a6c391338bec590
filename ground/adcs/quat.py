"""Quaternion helpers for the filters (Yoon 2017, Sec. 4.2-4.3): q = [e, q4], scalar last, inertial to body,
q (x) p with A(q (x) p) = A(q) A(p) (Eq. 4.5). Re-exported from the spacecraft model so truth and filters agree."""

import numpy as np

from emulator.spacecraft.dynamics import dcm, quat_mul
from protocol.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC  # noqa: F401  (quat.RAD_PER_ARCSEC, where the filters use it)

__all__ = ["dcm", "quat_mul", "conj", "skew", "error_vec", "from_small", "rotvec", "propagate", "angle_arcsec"]



def conj(q):
    return np.array([-q[0], -q[1], -q[2], q[3]])


def skew(v):
    """[v x] (cross-product matrix)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def error_vec(q, q_hat):
    """Vector part of dq = q (x) q_hat^-1 with dq4 >= 0 (Eq. 4.25): half the small rotation angle."""
    d = quat_mul(q, conj(q_hat))
    return d[:3] if d[3] >= 0 else -d[:3]


def from_small(dq_vec, q_hat):
    """q = dq (x) q_hat with dq = [dq_vec, sqrt(1 - |dq_vec|^2)] (Eq. 4.51), normalised."""
    n2 = dq_vec @ dq_vec
    dq = np.concatenate([dq_vec, [np.sqrt(1.0 - n2) if n2 < 1.0 else 0.0]])
    q = quat_mul(dq, q_hat)
    return q / np.linalg.norm(q)


def rotvec(q):
    """Rotation vector (rad) of q."""
    s = np.linalg.norm(q[:3])
    if s < 1e-300:
        return np.zeros(3)
    return q[:3] * (2.0 * np.arctan2(s, abs(q[3])) / s) * np.sign(q[3] if q[3] != 0 else 1.0)


def angle_arcsec(a, b):
    """The rotation between two attitude quaternions a, b (scalar last), in arcsec: ``rotvec`` of a b^-1, whose
    atan2 does not care that float32 quaternions are not unit to 1e-7 (acos of their dot product would)."""
    d = quat_mul(np.asarray(a, float), conj(np.asarray(b, float)))
    return float(np.linalg.norm(rotvec(d))) * ARCSEC_PER_RAD


def propagate(q, w, dt):
    """q after dt at constant body rate w (exact solution of Eq. 4.10)."""
    wn = np.linalg.norm(w)
    if wn * dt < 1e-12:
        return q
    ax = w / wn
    s, c = np.sin(0.5 * wn * dt), np.cos(0.5 * wn * dt)
    return quat_mul(np.array([ax[0] * s, ax[1] * s, ax[2] * s, c]), q)
