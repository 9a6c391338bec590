"""The ``jitter`` distfile source: reaction wheel imbalance jitter (emulator.spacecraft.wheels) as pointing error.

The spacecraft (emulator.spacecraft.dynamics, RK4) is held at a set of wheel speeds: wheels with the thesis's
geometry and inertias, the static and dynamic imbalances of ``WheelParams`` (times ``--jitter-scale``), friction
and environment torques off, so the speeds stay put and only the imbalance moves the body. The wheel angles
start at phases drawn from the seed. The pointing error is the body's small rotation about its X and Y axes
(the terminal's boresight taken along body +Z), 2 e of the attitude quaternion, in arcsec, with its mean and
linear drift removed (a body-pointing controller holds that part; the FSM loop sees the oscillation). Each
wheel i adds a harmonic at its spin frequency rpm_i / 60 Hz.

The step must be <= 0.6 ms (``Spacecraft``: 10 steps per turn at 10 000 rpm); the distfile then takes a 1 ms
step or finer (``fps distfile generate --source jitter --step-us 1000``), the source being low-pass filtered
before resampling. ``--jitter-base SOURCE`` adds another source's history (resampled to the jitter's times).
A sidecar ``F.jitter.json`` beside the distfile keeps the wheel frequencies and their amplitudes for the
``fps hil`` report (the harmonics before and after the FSM loop).
"""

import numpy as np

from ground import resample
from ground.source_registry import get_source
from protocol.units import ARCSEC_PER_RAD

class WheelJitter:
    name = "jitter"

    def __init__(self, rpm=(3000.0, 4000.0, 5000.0, 6000.0), step_s=5e-4, scale=1.0, base=None):
        from emulator.spacecraft.wheels import N_WHEELS
        rpm = np.asarray(rpm, float).reshape(-1)
        if rpm.shape != (N_WHEELS,) or not np.all(np.isfinite(rpm)) or np.any(np.abs(rpm) > 10000.0):
            raise ValueError("--jitter-rpm: need %d wheel speeds within +-10000 rpm, got %s"
                             % (N_WHEELS, ",".join("%g" % v for v in rpm)))
        if not 0 < step_s <= 6e-4:
            raise ValueError("--jitter-step-us %g: need 0 < step <= 600 us (10 steps per wheel turn at 10000 rpm)"
                             % (step_s * 1e6))
        if not 0 <= scale <= 1e4:
            raise ValueError("--jitter-scale %g: need 0 <= scale <= 1e4" % scale)
        self.rpm, self.step_s, self.scale, self.base = rpm, float(step_s), float(scale), base
        self.rate_hz = 1.0 / self.step_s

    @property
    def wheel_hz(self):
        return np.abs(self.rpm) / 60.0

    @staticmethod
    def add_arguments(p):
        p.add_argument("--jitter-rpm", default="3000,4000,5000,6000",
                       help="the four wheel speeds held, rpm (each adds a harmonic at rpm/60 Hz)")
        p.add_argument("--jitter-step-us", type=float, default=500.0,
                       help="spacecraft integration step, us (<= 600; default 500)")
        p.add_argument("--jitter-scale", type=float, default=1.0,
                       help="multiply the wheels' static and dynamic imbalances (default 1: ISO G2.5)")
        p.add_argument("--jitter-base", default="none",
                       help="another source to add under the jitter: stat, sine, csv, bps or none (its options apply)")

    @staticmethod
    def bases(a):
        """The source under the jitter (``--jitter-base``), whose options this run uses."""
        return [] if a.jitter_base in ("none", "") else [a.jitter_base]

    @classmethod
    def from_args(cls, a):
        try:
            rpm = [float(v) for v in str(a.jitter_rpm).split(",")]
        except ValueError:
            raise ValueError("--jitter-rpm: expected 4 numbers, got %r" % a.jitter_rpm) from None
        base = None
        if a.jitter_base not in ("none", ""):
            if a.jitter_base == "jitter":
                raise ValueError("--jitter-base jitter: the base must be another source")
            base = get_source(a.jitter_base).from_args(a)
        return cls(rpm, a.jitter_step_us * 1e-6, a.jitter_scale, base)

    def check_rate(self, period_us):
        if self.base is not None and hasattr(self.base, "check_rate"):
            self.base.check_rate(period_us)
        top = float(self.wheel_hz.max())
        if top >= 0.5e6 / period_us:
            raise ValueError("jitter harmonic %g Hz is at or above the distfile's Nyquist frequency %g Hz (step %d "
                             "us): use a finer --step-us" % (top, 0.5e6 / period_us, period_us))

    def jitter(self, duration_s, seed):
        """(t, x, y): the jitter alone, arcsec, at the integration step."""
        from emulator.spacecraft.dynamics import Spacecraft
        from emulator.spacecraft.wheels import RPM, WheelParams, Wheels
        d = WheelParams()
        p = WheelParams(jitter=True, friction_coulomb=0.0, friction_viscous=0.0, noise_rpm=0.0,
                        imbalance_static=d.imbalance_static * self.scale,
                        imbalance_dynamic=d.imbalance_dynamic * self.scale)
        sc = Spacecraft(wheels=Wheels(p), dt=self.step_s, omega_rw=self.rpm * RPM, orbit=None, field=None,
                        dipole=None, gravity_gradient=False)
        sc.x[11:15] = np.random.default_rng(seed).uniform(0.0, 2 * np.pi, 4)
        n = int(np.ceil((duration_s + 0.02) / self.step_s)) + 4
        e = np.empty((n, 2))
        for k in range(n):
            q = sc.q
            e[k] = 2.0 * np.sign(q[3]) * q[0:2]
            sc.step()
        t = np.arange(n) * self.step_s
        e *= ARCSEC_PER_RAD
        for ax in range(2):          # the body controller's share: mean and drift
            e[:, ax] -= np.polyval(np.polyfit(t, e[:, ax], 1), t)
        return t, e[:, 0], e[:, 1]

    def generate(self, duration_s, seed):
        t, x, y = self.jitter(duration_s, seed)
        if self.base is not None:
            tb, xb, yb = self.base.generate(duration_s + 0.03, seed)
            xb, yb, _ = resample.antialias(tb, xb, yb, max(1, int(self.step_s * 1e6)), "jitter base")
            keep = t <= tb[-1] - tb[0]
            t, x, y = t[keep], x[keep], y[keep]
            xy = resample.lagrange3(tb - tb[0], np.column_stack([xb, yb]), t)
            x, y = x + xy[:, 0], y + xy[:, 1]
        return t, x, y

    def harmonics(self, t, x, y):
        """Each wheel harmonic's amplitude (X, Y) in arcsec in a history, least squares over all of them."""
        return harmonic_amplitudes(t, np.column_stack([x, y]), self.wheel_hz)


def harmonic_amplitudes(t, xy, freqs):
    """Amplitudes (len(freqs) x columns) of the tones at ``freqs`` in samples xy(t), fitted together with an
    offset."""
    t = np.asarray(t, float)
    cols = [np.ones_like(t)]
    for f in freqs:
        cols += [np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)]
    a = np.column_stack(cols)
    sol, *_ = np.linalg.lstsq(a, np.asarray(xy, float), rcond=None)
    return np.hypot(sol[1::2], sol[2::2])
