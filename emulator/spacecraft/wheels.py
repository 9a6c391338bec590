"""Reaction wheel assembly: pyramid geometry, misalignment, rotor, limits, friction, read-out, jitter.

Geometry (Yoon 2017, Sec. 4.8): the nominal pyramid C0 (Eq. 4.147) and the true rotation-axis matrix
C = normalise(C0 + C1 D(delta1) + C2 D(delta2)) (Eq. 4.58-4.60 with Eq. 4.148), which reproduces the
thesis's Eq. 4.149 to its five printed digits (tests/test_spacecraft_wheels.py).

Rotor model (Eq. 4.53-4.57): wheel i spins about c_i with inertia Jrw_i; ``omega_rw`` is its spin rate,
H_rw = C Jrw omega_rw (Eq. 4.55) with omega_rw absolute. Friction, the speed limit, the read-out and the
jitter phase take the speed relative to the body, omega_rw - C^T w (``Spacecraft.omega_rw_rel``). The motor torque is clipped to ``torque_max`` and cut so that the speed
cannot pass ``speed_max_rpm`` within a step; friction (viscous + Coulomb, smoothed through zero) is an internal
torque between rotor and body, so it changes wheel speeds but not the total angular momentum.

Jitter: static imbalance U_s [kg m] gives a radial force U_s W^2 at the wheel's location r_i, dynamic
imbalance U_d [kg m^2] a radial torque U_d W^2, both turning with the rotor angle (the "simple jitter" model
of Basilisk's reactionWheelStateEffector). It enters the body as an external disturbance, so it needs a step
that resolves the wheel speed (see ``Spacecraft``).

Parameters beyond the thesis are assumed values for a nano-satellite wheel of this rotor size:
torque 1 mN m, 10 000 rpm (3.1 mN m s), Coulomb friction 2 uN m, viscous 2e-10 N m s/rad. The imbalances
follow ISO 1940 balance grade G2.5 for a ~20 g rotor at 10 000 rpm: e = 2.5 mm/s / 1047 rad/s = 2.4 um,
U_s = 0.02 kg x 2.4 um = 4.8e-8 kg m; U_d = U_s x ~10 mm rotor length = 5e-10 kg m^2 (assumed).
"""

from dataclasses import dataclass, fields

import numpy as np

RPM = 2.0 * np.pi / 60.0          # rad/s per rpm
N_WHEELS = 4
J_RW_NOMINAL = 3e-6               # kg m^2, Sec. 4.8
DJ_RW_THESIS = (0.45e-6, 0.36e-6, -0.75e-6, -0.60e-6)   # kg m^2, Sec. 4.8 (true - nominal)
DELTA1_DEG_THESIS = (11.0, -7.0, -11.0, 8.0)            # Sec. 4.8 misalignment angles
DELTA2_DEG_THESIS = (-12.0, 12.0, 9.0, 10.0)


def pyramid_c0():
    """Nominal symmetric pyramid (Eq. 4.147): column i is wheel i's spin axis in the body frame."""
    return np.array([[-1.0, -1.0, 1.0, 1.0],
                     [-1.0, 1.0, 1.0, -1.0],
                     [1.0, 1.0, 1.0, 1.0]]) / np.sqrt(3.0)


def misalignment_axes(c0):
    """Eq. 4.148: c_i1 = (c_i0 x c_i+1,0)/|.|, c_i2 = c_i0 x c_i1 (wheel n+1 is wheel 1)."""
    c1 = np.cross(c0.T, np.roll(c0, -1, axis=1).T).T
    c1 /= np.linalg.norm(c1, axis=0)
    c2 = np.cross(c0.T, c1.T).T
    c2 /= np.linalg.norm(c2, axis=0)
    return c1, c2


def misaligned_c(c0, delta1_rad, delta2_rad):
    """True axes: Eq. 4.60 (c0 + d1 c1 + d2 c2) normalised to unit columns (Eq. 4.54); gives Eq. 4.149."""
    c1, c2 = misalignment_axes(c0)
    c = c0 + c1 * np.asarray(delta1_rad, float) + c2 * np.asarray(delta2_rad, float)
    return c / np.linalg.norm(c, axis=0)


def _vec4(name, v):
    try:
        a = np.array(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        a = np.array([np.nan])
    if a.shape != (N_WHEELS,) or not np.all(np.isfinite(a)):
        raise ValueError("%s must be %d finite numbers, got %r" % (name, N_WHEELS, v))
    return a


@dataclass
class WheelParams:
    """Reaction wheel assembly parameters; defaults are the thesis's true values (Sec. 4.8) + assumed limits."""

    j_rw: tuple = tuple(J_RW_NOMINAL + d for d in DJ_RW_THESIS)   # kg m^2
    delta1_deg: tuple = DELTA1_DEG_THESIS
    delta2_deg: tuple = DELTA2_DEG_THESIS
    torque_max: float = 1e-3            # N m
    speed_max_rpm: float = 10000.0
    friction_coulomb: float = 2e-6      # N m
    friction_viscous: float = 2e-10     # N m s/rad
    friction_smooth_rpm: float = 1.0    # Coulomb term = c tanh(W / this): no chatter through zero
    noise_rpm: float = 10.0             # speed read-out 1 sigma (Sec. 4.8)
    imbalance_static: float = 4.8e-8    # U_s, kg m
    imbalance_dynamic: float = 5e-10    # U_d, kg m^2
    arm: float = 0.04                   # m, wheel i sits at arm * c0_i from the centre of mass
    jitter: bool = False                # add imbalance forces/torques to the body

    def __post_init__(self):
        self.j_rw = _vec4("j_rw", self.j_rw)
        self.delta1_deg = _vec4("delta1_deg", self.delta1_deg)
        self.delta2_deg = _vec4("delta2_deg", self.delta2_deg)
        if np.any(self.j_rw <= 0):
            raise ValueError("j_rw must be > 0 kg m^2, got %r" % (self.j_rw,))
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type is float:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v >= 0):
                    raise ValueError("%s must be a finite number >= 0, got %r" % (f.name, v))
                setattr(self, f.name, float(v))
        for name in ("torque_max", "speed_max_rpm", "friction_smooth_rpm"):
            if getattr(self, name) <= 0:
                raise ValueError("%s must be > 0, got %r" % (name, getattr(self, name)))

    @classmethod
    def ideal(cls, **kw):
        """Nominal wheels: no misalignment, Jrw = 3e-6 kg m^2, no friction, no noise, no jitter."""
        base = dict(j_rw=(J_RW_NOMINAL,) * N_WHEELS, delta1_deg=(0.0,) * N_WHEELS,
                    delta2_deg=(0.0,) * N_WHEELS, friction_coulomb=0.0, friction_viscous=0.0,
                    noise_rpm=0.0, imbalance_static=0.0, imbalance_dynamic=0.0)
        base.update(kw)
        return cls(**base)


class Wheels:
    """Four wheels: commands, limits (with counters), friction, read-out and jitter; numpy over the wheels."""

    def __init__(self, params=None, rng=None, c0=None, c=None):
        """``c0``, ``c`` (3 x 4, unit columns): the nominal and true spin axes instead of the pyramid of Eq. 4.147
        and its misalignment by ``params``' angles (Eq. 4.149), e.g. from a spacecraft file."""
        self.p = params if params is not None else WheelParams()
        p = self.p
        self.c0 = pyramid_c0() if c0 is None else np.array(c0, dtype=float)
        self.c = (misaligned_c(self.c0, np.radians(p.delta1_deg), np.radians(p.delta2_deg)) if c is None
                  else np.array(c, dtype=float))                                             # Eq. 4.149
        self.j = p.j_rw.copy()
        self.cj = self.c * self.j                     # C Jrw, 3 x 4 (Eq. 4.55)
        self.speed_max = p.speed_max_rpm * RPM
        self.rng = rng if rng is not None else np.random.default_rng(0)
        # radial axes g1, g2 of each rotor (for the jitter phase) and wheel locations
        g1, g2 = misalignment_axes(self.c)
        self.g1, self.g2 = g1, g2
        self.r = p.arm * self.c0
        self.cmd = np.zeros(N_WHEELS)                 # commanded motor torque, N m
        self.enable = np.ones(N_WHEELS, dtype=bool)
        self.n_torque_clip = np.zeros(N_WHEELS, dtype=np.int64)
        self.n_speed_clip = np.zeros(N_WHEELS, dtype=np.int64)

    def command(self, i, torque, enable=True):
        """Set wheel i's motor torque command (N m); ValueError on a bad index or non-finite torque."""
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < N_WHEELS:
            raise ValueError("wheel index %r is not an integer in 0..%d" % (i, N_WHEELS - 1))
        if not np.isfinite(torque):
            raise ValueError("torque for wheel %d must be finite, got %r" % (i, torque))
        self.cmd[i] = torque
        self.enable[i] = bool(enable)

    def command_all(self, torques, enable=True):
        self.cmd[:] = _vec4("torques", torques)
        self.enable[:] = enable

    def limit(self, omega_rw, dt):
        """Motor torque the drivers apply over the next step: (torque, torque_clipped, speed_clipped).

        Clipped to +-torque_max; then, in the direction of the spin, cut so that the motor alone cannot
        carry |W| past speed_max within dt (friction only slows the wheel further).
        """
        u = np.where(self.enable, self.cmd, 0.0)
        tq = np.clip(u, -self.p.torque_max, self.p.torque_max)
        t_clip = tq != u
        room = self.j * (self.speed_max - np.abs(omega_rw)) / dt      # torque that reaches the limit in dt
        room = np.maximum(room, 0.0)
        push = tq * np.sign(omega_rw) > room
        tq = np.where(push, np.sign(tq) * room, tq)
        return tq, t_clip, push

    def apply_limits(self, omega_rw, dt):
        """``limit`` plus counting: call once per step."""
        tq, t_clip, s_clip = self.limit(omega_rw, dt)
        self.n_torque_clip += t_clip
        self.n_speed_clip += s_clip
        return tq

    def friction(self, omega_rw):
        """Viscous + Coulomb friction torque on each rotor (opposes the spin), N m."""
        p = self.p
        return (p.friction_viscous * omega_rw
                + p.friction_coulomb * np.tanh(omega_rw / (p.friction_smooth_rpm * RPM)))

    def read_speed_rpm(self, omega_rw):
        """Speed read-out with Gaussian noise (Eq. 4.57), rpm."""
        return omega_rw / RPM + self.p.noise_rpm * self.rng.standard_normal(N_WHEELS)

    def jitter(self, omega_rw, angle):
        """Imbalance force (N) and torque about the centre of mass (N m) on the body, body frame, summed."""
        w2 = omega_rw * omega_rw
        u = self.g1 * np.cos(angle) + self.g2 * np.sin(angle)          # 3 x 4 rotating radial direction
        f = u * (self.p.imbalance_static * w2)
        tq = np.cross(self.r.T, f.T).T + u * (self.p.imbalance_dynamic * w2)
        return f.sum(axis=1), tq.sum(axis=1)

    def counters(self):
        return {"torque_clip": self.n_torque_clip.tolist(), "speed_clip": self.n_speed_clip.tolist()}
