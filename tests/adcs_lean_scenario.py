"""A pointing scenario for the lean flight ADCS tests and bench: the emulator's spacecraft (true inertia, wheel
misalignment and inertias, gravity gradient; RK4; the residual dipole at 1/20 of Sec. 4.8's: with no
magnetorquer to dump momentum the thesis's 0.28 A m^2 saturates the wheels at 20 000 rpm within ~800 s of
inertial hold, the rate then passes the star tracker's 0.1 deg/s and it goes blind) held in an inertial attitude by a PD on the truth,
with the star tracker (20/20/60 arcsec) and tachometers (10 rpm) sampled at 1 Hz.

``scenario(seconds, seed)`` returns a dict of per-second lists: ``wp`` (tachometer read-outs, rad/s),
``qm`` (star-tracker quaternion or None), ``env`` ((r_i unit, 3 mu/r^3, b_i) at mid-step), ``q``, ``w`` (truth),
and ``params`` (the parameter file a perfect calibration would write, ground/adcs/bps.py format)."""

import numpy as np

from emulator.spacecraft import environment as env
from emulator.spacecraft.environment import M_DIPOLE_THESIS
from emulator.spacecraft.devices import StarTracker
from emulator.spacecraft.dynamics import Spacecraft, quat_mul
from emulator.spacecraft.scenario import SCENARIO_WHEELS, truth_params  # noqa: F401 (used by the tests)
from emulator.spacecraft.wheels import Wheels, WheelParams

RPM = 2 * np.pi / 60


def scenario(seconds, seed=0, dt_truth=0.25, ts=33.0):
    rng = np.random.default_rng(seed)
    wheels = Wheels(WheelParams(**SCENARIO_WHEELS), rng=np.random.default_rng(seed + 1))
    q0 = rng.standard_normal(4)
    q0 /= np.linalg.norm(q0)
    sc = Spacecraft(wheels=wheels, dt=dt_truth, q=q0, omega=(0.0, 0.0, 0.0), dipole=np.asarray(M_DIPOLE_THESIS) / 20,
                    omega_rw=(800 * RPM, -600 * RPM, 700 * RPM, -900 * RPM))
    st = StarTracker(np.random.default_rng(seed + 2))
    wn = 4.0 / ts
    K, D = 2 * wn * wn * sc.j, 2 * wn * sc.j
    c = sc.wheels.c
    out = {"wp": [], "qm": [], "env": [], "q": [], "w": [], "params": truth_params(sc)}
    n_sub = int(round(1.0 / dt_truth))
    for k in range(int(seconds) + 1):
        t = float(k)
        out["wp"].append((wheels.read_speed_rpm(sc.omega_rw_rel) * RPM).tolist())
        qm, ok = st.measure(sc.q, sc.omega)
        out["qm"].append(qm.tolist() if ok else None)
        out["q"].append(sc.q.tolist())
        out["w"].append(sc.omega.tolist())
        r = sc.orbit.position(t + 0.5)
        rn = np.linalg.norm(r)
        out["env"].append(((r / rn).tolist(), float(3 * env.MU_EARTH / rn ** 3),
                           sc.field.field(r, t + 0.5).tolist()))
        # truth PD holding q0 (the scenario's controller has perfect q, w as in Sec. 4.8)
        qe = quat_mul(sc.q, np.array([-q0[0], -q0[1], -q0[2], q0[3]]))
        e = qe[0:3] if qe[3] >= 0 else -qe[0:3]
        tau = -K @ e - D @ sc.omega
        u = -c.T @ np.linalg.solve(c @ c.T, tau)
        wheels.command_all(u)
        for _ in range(n_sub):
            sc.step()
    return out
