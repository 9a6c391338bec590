"""A pointing scenario for the lean flight ADCS tests and bench: the emulator's spacecraft (true inertia, wheel
misalignment and inertias, gravity gradient; RK4; the residual dipole at 1/20 of Sec. 4.8's: with no
magnetorquer to dump momentum the thesis's 0.27 A m^2 saturates the wheels at 20 000 rpm within ~800 s of
inertial hold, the rate then passes the star tracker's 0.1 deg/s and it goes blind) held in an inertial attitude by a PD on the truth,
with the star tracker (20/20/60 arcsec) and tachometers (10 rpm) sampled at 1 Hz.

``scenario(seconds, seed)`` returns a dict of per-second lists: ``wp`` (tachometer read-outs, rad/s),
``qm`` (star-tracker quaternion or None), ``u`` (the wheel torques commanded over [k, k + 1], N m), ``env`` ((r_i unit, 3 mu/r^3, b_i) at mid-step), ``q``, ``w`` (truth),
and ``params`` (the parameter file a perfect calibration would write, ground/adcs/body_pointing.py format)."""

import numpy as np

from emulator.spacecraft import environment as env
from emulator.spacecraft.environment import M_DIPOLE_THESIS
from emulator.spacecraft.devices import StarTracker
from emulator.spacecraft.dynamics import Spacecraft, quat_mul
from emulator.spacecraft.scenario import SCENARIO_WHEELS, truth_params  # noqa: F401 (used by the tests)
from emulator.spacecraft.wheels import Wheels, WheelParams
from ground.adcs.control import natural_frequency

RPM = 2 * np.pi / 60


def scenario(seconds, seed=0, dt_truth=0.25, ts=33.0, tach_rpm=None):
    """``tach_rpm``: the tachometer read-out 1 sigma (None: the scenario's 10 rpm; the truth is the same)."""
    rng = np.random.default_rng(seed)
    wp = dict(SCENARIO_WHEELS) if tach_rpm is None else dict(SCENARIO_WHEELS, noise_rpm=float(tach_rpm))
    wheels = Wheels(WheelParams(**wp), rng=np.random.default_rng(seed + 1))
    q0 = rng.standard_normal(4)
    q0 /= np.linalg.norm(q0)
    sc = Spacecraft(wheels=wheels, dt=dt_truth, q=q0, omega=(0.0, 0.0, 0.0), dipole=np.asarray(M_DIPOLE_THESIS) / 20,
                    omega_rw=(800 * RPM, -600 * RPM, 700 * RPM, -900 * RPM))
    st = StarTracker(np.random.default_rng(seed + 2))
    wn = natural_frequency(ts)                   # Eq. 6.7, as the flight and ground controllers read it
    K, D = 2 * wn * wn * sc.j, 2 * wn * sc.j
    c = sc.wheels.c
    out = {"wp": [], "qm": [], "u": [], "env": [], "q": [], "w": [], "params": truth_params(sc)}
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
        out["u"].append(u.tolist())
        for _ in range(n_sub):
            sc.step()
    return out


def stkf_scenario(seconds, case=2, seed=0, delay_s=(2.0, 3.0), att_sigma_arcsec=(9.81, 8.01, 19.70)):
    """The STKF inputs of Sec. 5.5 (ground/adcs/stkf_sim.py's sensors, two-body truth, stated attitude: body
    on J2000, the attitude estimate off by a white error of the APKF's Case 1 1 sigma) as per-second lists:
    ``za`` (SatA GNSS), ``y`` (beacon unit vector), ``q`` (attitude estimate, scalar last), ``zb`` (SatB GNSS
    due at that second through the relay: [[tag, z6], ...]; Case 2 only), ``x`` (truth, 12); and ``x0``
    (initial estimate), ``P0``, ``R`` (GNSS, 6 x 6 flat), ``P_att`` (3 x 3 flat, rad^2), ``sigma_b`` (rad)."""
    from emulator import orbits
    from emulator.navsensors import Beacon, Gnss, Relay
    from protocol.units import RAD_PER_ARCSEC
    from emulator.spacecraft.scenario import STKF_P0_DIAG
    from ground.adcs.stkf_sim import small_rotation
    from emulator.interp import lagrange
    K = int(seconds)
    t_s, xs = orbits.truth_samples("two-body", float(K))
    r_init, r_ga, r_gb, r_bc, r_att, r_rel = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(6)]
    x0 = xs[0].ravel() + np.sqrt(STKF_P0_DIAG) * r_init.standard_normal(12)
    gnss_a, beacon = Gnss(r_ga), Beacon(r_bc)
    relay = Relay(r_rel, Gnss(r_gb), delay_s)
    tb = r_rel.uniform(0.0, 1.0) + np.arange(0, K)
    xb_at = lagrange(t_s, xs[:, 1, :], tb, order=10)
    sd = np.asarray(att_sigma_arcsec, float) * RAD_PER_ARCSEC
    out = {"x0": x0.tolist(), "P0": list(STKF_P0_DIAG), "R": gnss_a.R.ravel().tolist(),
           "P_att": np.diag(sd ** 2).ravel().tolist(), "sigma_b": float(beacon.sigma), "steps": []}
    jb = 0
    for k in range(K + 1):
        x = xs[k].ravel()
        A_hat = small_rotation(sd * r_att.standard_normal(3)).T
        s = {"t": float(k), "x": x.tolist(), "za": gnss_a.measure(x[:6]).tolist(),
             "y": beacon.measure_dcm(x[0:3], x[6:9], np.eye(3)).tolist(), "q": _dcm_to_quat(A_hat).tolist(),
             "zb": []}
        if case == 2:
            while jb < tb.size and tb[jb] <= k:
                relay.sample(tb[jb], xb_at[jb])
                jb += 1
            s["zb"] = [[float(tm), z.tolist()] for tm, z in relay.due(float(k))]
        out["steps"].append(s)
    return out


def _dcm_to_quat(A):
    """q (x, y, z, w) with emulator.spacecraft.dynamics.dcm(q) = A."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(A.T).as_quat()


def run_stkf_lean(sc, zeros=None, zeros_d=None, every=None):
    """The flight STKF (firmware/adcs/stkf_lean.py) over ``stkf_scenario`` inputs. ``zeros``/``zeros_d``
    replace the float32 covariance / float64 state buffers (a test's numpy.float32 scalars). Returns
    (estimates (K+1, 12), 1 sigma (K+1, 12), filter, refused count); ``every(f)`` is called after each step."""
    from firmware.adcs import linalg
    from firmware.adcs import stkf_lean as S
    old = linalg.zeros, S.zeros_d
    if zeros is not None:
        linalg.zeros = zeros
    if zeros_d is not None:
        S.zeros_d = zeros_d
    try:
        f = S.LeanStkf(sc["x0"], sc["P0"], 0.0)
        R, P_att, sb = linalg.zeros(36), linalg.zeros(9), sc["sigma_b"]
        for i in range(36):
            R[i] = sc["R"][i]
        for i in range(9):
            P_att[i] = sc["P_att"][i]
        xs, sg = np.zeros((len(sc["steps"]), 12)), np.zeros((len(sc["steps"]), 12))
        x, s = [0.0] * 12, [0.0] * 12
        refused = 0
        for k, st in enumerate(sc["steps"]):
            if k > 0:
                f.predict(st["t"])
            if st.get("za") is not None:
                f.update_gnss(st["za"], R, 0)
            if st.get("y") is not None:
                f.update_beacon(st["y"], st["q"], P_att, sb)
            for tm, z in st["zb"]:
                try:
                    f.update_gnss(z, R, 1, tm)
                except ValueError:
                    refused += 1
            f.get(x, s)
            xs[k], sg[k] = x, s
            if every:
                every(f)
    finally:
        linalg.zeros, S.zeros_d = old
    return xs, sg, f, refused


def run_stkf_ground(sc, lag_s=4.0):
    """ground/adcs/stkf.py + afls.py on the same inputs, as ground/adcs/stkf_sim.py runs them (SatA's GNSS and
    the beacon in one stacked update). Returns (estimates, 1 sigma) like ``run_stkf_lean``."""
    from emulator.spacecraft.dynamics import dcm
    from ground.adcs import stkf
    from ground.adcs.afls import Afls
    flt = Afls(np.array(sc["x0"]), np.diag(sc["P0"]), 0.0, lag_s, stkf.f, stkf.Phi, lambda dt: stkf.Q(dt))
    R = np.reshape(sc["R"], (6, 6))
    P_att = np.reshape(sc["P_att"], (3, 3))
    xs, sg = np.zeros((len(sc["steps"]), 12)), np.zeros((len(sc["steps"]), 12))
    for k, st in enumerate(sc["steps"]):
        if k > 0:
            flt.predict(st["t"])
        A_hat = dcm(np.array(st["q"]))
        flt.update(np.concatenate([st["za"], st["y"]]),
                   stkf.R_gnss_beacon(R, stkf.h_beacon(flt.x, A_hat), sc["sigma_b"], P_att),
                   lambda x: stkf.gnss_beacon(x, A_hat)[0], lambda x: stkf.gnss_beacon(x, A_hat)[1])
        for tm, z in st["zb"]:
            flt.update(np.array(z), R, lambda x: x[6:12], lambda x: stkf.H_gnss("B"), t=tm)
        xs[k], sg[k] = flt.x, np.sqrt(np.diag(flt.Pk))
    return xs, sg
