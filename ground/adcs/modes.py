"""The flight world's flight-software modes (``fps adcs bps --world flight``). None of this is in the thesis: its
Ch. 6 simulator points from rest with the PD of Eq. 6.5-6.7 alone, with wheels that have no speed limit and no
momentum management. A spacecraft with datasheet wheels and a star tracker that goes blind above its rate limit
needs more:

- ``EigenaxisSlew``: a rate- and acceleration-limited reference from the attitude at the slew's start to the
  moving tracking command, about one axis (the remaining rotation shrinks along a trapezoidal profile, braking as
  sqrt(2 a theta)); the PD of Eq. 6.5 tracks it, so the body rate and the wheel torque stay bounded.
- ``unloading_dipole``: the cross-product law m = k (h x b) / |b|^2 on the magnetorquers (with the estimated
  residual dipole cancelled), clipped per rod; its torque m x b removes the wheels' momentum across the field.
- ``null_bias_torque``: the wheels held off zero speed by their null-space motion (no torque on the body), so
  that the unloading law, which drives the wheels' momentum toward zero, does not park them where their Coulomb
  friction flips sign with every tachometer sample.
- ``beacon_gate``: the STKF's beacon update only while the attitude is known well enough (the beacon's body
  frame vector is rotated to inertial through the attitude estimate, Eq. 5.16).
- ``ModeLog``: the mode (INIT: no estimate yet; HOLD: rate damping while the APKF converges; SLEW; ACQUIRE: the
  slew is over and the star tracker, blind above its rate limit, has not answered yet: rate damping on the
  estimate; POINT: the PD of Eq. 6.5 on the command), its changes with time and reason, and the time spent in
  each.
"""

import numpy as np

from ground.adcs import quat

MODES = ("INIT", "HOLD", "SLEW", "ACQUIRE", "POINT")
DEG = np.pi / 180.0


class ModeLog:
    """The flight software's mode and its history: ``changes`` holds one {"t_s", "from", "to", "reason"} per
    change; ``time_in(t_end)`` the seconds spent in each mode up to ``t_end``."""

    def __init__(self, mode="INIT", t=0.0):
        self.mode = mode
        self.t0 = float(t)
        self.changes = []

    def set(self, mode, t, reason):
        if mode not in MODES:
            raise ValueError("unknown mode %r (modes: %s)" % (mode, ", ".join(MODES)))
        if mode != self.mode:
            self.changes.append({"t_s": float(t), "from": self.mode, "to": mode, "reason": reason})
            self.mode = mode

    def time_in(self, t_end):
        out = dict.fromkeys(MODES, 0.0)
        t, mode = self.t0, self.changes[0]["from"] if self.changes else self.mode
        for c in self.changes:
            out[mode] += c["t_s"] - t
            t, mode = c["t_s"], c["to"]
        out[mode] += float(t_end) - t
        return out


def _exp(phi):
    """The quaternion of rotation vector phi (rad)."""
    a = float(np.linalg.norm(phi))
    if a < 1e-15:
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.concatenate([phi / a * np.sin(0.5 * a), [np.cos(0.5 * a)]])


class EigenaxisSlew:
    """A rate-limited eigenaxis slew toward a moving command. At the start phi = rotvec(q_c (x) q_start^-1), the
    rotation that takes the start to the command (body frame); the reference is q_ref = exp(-theta e) (x) q_c,
    with e = phi / |phi| fixed and theta shrinking from |phi| at a speed s that rises by at most ``acc_max`` per
    second, never exceeds ``rate_max`` and brakes as sqrt(2 acc_max theta), so the reference reaches q_c at
    rest relative to it. The reference rate is the difference of consecutive references over one step, with the
    command carried forward by its own rate w_c (``control.command_rate``, command frame), so it holds both the
    slew and the command's own turn. Units: rad, rad/s, rad/s^2, s."""

    def __init__(self, q_start, q_c, rate_max, acc_max):
        if not (rate_max > 0 and acc_max > 0):
            raise ValueError("the slew's rate and acceleration limits must be > 0, got %r, %r" % (rate_max, acc_max))
        phi = quat.rotvec(quat.quat_mul(q_c, quat.conj(q_start)))
        self.theta0 = self.theta = float(np.linalg.norm(phi))
        self.e = phi / self.theta if self.theta > 0 else np.array([1.0, 0.0, 0.0])
        self.rate_max, self.acc_max = float(rate_max), float(acc_max)
        self.s = 0.0

    @property
    def done(self):
        return self.theta <= 0.0

    def reference(self, q_c, w_c, dt=1.0):
        """(q_ref, w_ref) at this step for the command (q_c, w_c), and the profile advanced by dt."""
        q_ref = quat.quat_mul(_exp(-self.theta * self.e), q_c)
        s = min(self.s + self.acc_max * dt, self.rate_max, np.sqrt(2.0 * self.acc_max * self.theta))
        theta = max(self.theta - s * dt, 0.0)
        if theta == 0.0:
            s = self.theta / dt
        q_next = quat.quat_mul(_exp(-theta * self.e), quat.propagate(q_c, w_c, dt))
        w_ref = quat.rotvec(quat.quat_mul(q_next, quat.conj(q_ref))) / dt
        self.s, self.theta = s, theta
        return q_ref, w_ref


def unloading_dipole(b_body, h_body, gain, limit, m_residual=None, axes=None):
    """The magnetorquers' command (A m^2, body frame): m = gain (h x b) / |b|^2 - m_residual, each rod's share
    (least squares on ``axes``, rows, unit) clipped to +-limit. With m_residual = 0 its torque m x b =
    -gain h_perp (h's part across the field); the wheels take up the external torque while the body holds its
    attitude, so their momentum h decays at ``gain`` (1/s) across b. Returns (m applied, rods saturated (bool
    per rod))."""
    b = np.asarray(b_body, float)
    m = gain * np.cross(np.asarray(h_body, float), b) / float(b @ b)
    if m_residual is not None:
        m = m - np.asarray(m_residual, float)
    A = np.eye(3) if axes is None else np.asarray(axes, float)
    rods = np.linalg.lstsq(A.T, m, rcond=None)[0]
    sat = np.abs(rods) > limit
    rods = np.clip(rods, -limit, limit)
    return A.T @ rods, sat


def null_bias_torque(C, w_rel, jrw, bias_rad_s, gain):
    """Motor torques (N m, per wheel) along the null vector n of C (C n = 0, |n| = 1, sign chosen so that its
    largest entry is positive) that bring the null-space speed s = n . W_rel to ``bias_rad_s`` / mean |n_i| (each
    wheel then near +-``bias_rad_s``) at ``gain`` (1/s): u = -gain Jrw (s - s_target) n. They change no body
    momentum."""
    _, _, vt = np.linalg.svd(np.asarray(C, float))
    n = vt[-1]
    if n[np.argmax(np.abs(n))] < 0:
        n = -n
    s = float(n @ np.asarray(w_rel, float))
    target = bias_rad_s / float(np.mean(np.abs(n)))
    return -gain * np.asarray(jrw, float) * (s - target) * n


def beacon_gate(P_att, limit_rad):
    """True when the attitude 1 sigma, sqrt(trace P_att) (rad; P_att the attitude covariance of Eq. 5.16's
    4 P_qq), is within ``limit_rad``: the STKF takes the beacon then and only then."""
    return bool(np.isfinite(P_att).all() and np.sqrt(np.trace(P_att)) <= limit_rad)
