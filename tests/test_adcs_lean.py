"""The lean flight APKF (firmware/adcs/apkf_lean.py): against the ground filter's model, under micropython
against CPython, and in float32 arithmetic against float64 on a 4000 s emulated scenario; and the flight control
laws (firmware/adcs/control.py) against the ground's, under micropython and CPython. The lean STKF's tests are in
tests/test_adcs_lean_stkf.py."""

import json
from array import array

import numpy as np
import pytest

from firmware.adcs import apkf_lean as L
from firmware.adcs import linalg
from ground.adcs import apkf, quat
from ground.adcs.lean_scenario import scenario
from protocol import paramfile
from tests.adcs_lean_common import F32, positive_definite, run_mp


def _run(sc, zeros, f32=False, start=100):
    old = linalg.zeros
    linalg.zeros = zeros
    try:
        cast = (lambda v: [np.float32(e) for e in v]) if f32 else (lambda v: v)
        f = L.LeanApkf(sc["params"], sc["qm"][0], [0.0, 0.0, 0.0], sc["wp"][0])
        ea, ew, pd = [], [], True
        for k in range(1, len(sc["wp"])):
            env = sc["env"][k - 1]
            env = (cast(env[0]), np.float32(env[1]) if f32 else env[1], cast(env[2]))
            f.step(cast(sc["wp"][k]), None if sc["qm"][k] is None else cast(sc["qm"][k]), env, cast(sc["u"][k - 1]))
            P = np.array(f.P, dtype=float).reshape(9, 9)
            pd = pd and bool(np.array_equal(P, P.T)) and positive_definite(P)
            ea.append(2 * quat.error_vec(np.array(sc["q"][k]), np.array(f.x[0:4], dtype=float)) / quat.RAD_PER_ARCSEC)
            ew.append((np.array(f.x[4:7], dtype=float) - sc["w"][k]) / quat.RAD_PER_ARCSEC)
    finally:
        linalg.zeros = old
    return np.array(ea)[start:], np.array(ew)[start:], pd, f


def test_jacobian_and_propagation_equal_the_ground_filters():
    """F (9 x 9) and the RK4 step are the 41-state ground APKF's, restricted to the lean states (with the
    ground filter's momentum input, the read-out difference)."""
    rng = np.random.default_rng(1)
    model = apkf.Model()
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    w, W = rng.standard_normal(3) * 1e-3, rng.standard_normal(4) * 100
    x = apkf.initial_state(q, w, W)
    x[7:10], x[15:18], x[18:26] = [1e-7, -2e-7, 3e-7], [0.1, 0.2, -0.1], rng.standard_normal(8) * 0.1
    wp = W + rng.standard_normal(4)
    x[38:42] = wp
    m = apkf.terms(x, model, 100.0)
    params = {"format": paramfile.FORMAT, "wheels": 4, "jxx_ref_kgm2": model.jxx,
              "x": {"tau_d_nm": x[7:10].tolist(), "J5_kgm2": x[10:15].tolist(), "dipole_am2": x[15:18].tolist(),
                    "delta1_rad": x[18:22].tolist(), "delta2_rad": x[22:26].tolist(), "jrw_kgm2": x[26:30].tolist()},
              "P": np.eye(paramfile.N_PARAMS).tolist()}
    old = linalg.zeros
    linalg.zeros = lambda n: [0.0] * n
    try:
        f = L.LeanApkf(params, q, w, W, momentum="tach")
        env = (m["r_i"].tolist(), m["k"], m["b_i"].tolist())
        F, hw, hd, Qw = [0.0] * 81, [0.0] * 3, [0.0] * 3, [0.0] * 9
        Qw = np.reshape(list(L.momentum_rate(hw, hd, Qw, f.model, f.wm, wp, None)), (3, 3))
        G = np.linalg.inv(np.reshape(list(f.model.J), (3, 3))) @ np.reshape(list(f.model.CJ), (3, 4))
        assert np.allclose(Qw, 2 * f.model.R_rw * G @ G.T, rtol=1e-12, atol=0)    # Eq. 4.135 for the read-outs
        L.jacobian(F, f.x, f.model, hw, env, f.work)
        Fg = apkf.jacobian(x, model, 100.0, m)[:9, :9]
        assert np.allclose(np.reshape(F, (9, 9)), Fg, rtol=1e-12, atol=1e-12 * np.abs(Fg).max())
        L.propagate(f.x, f.model, hw, hd, env, f.work)
        assert np.allclose(f.x[0:7], apkf.propagate(x, model, 100.0, m)[0:7], rtol=0, atol=1e-15)
    finally:
        linalg.zeros = old


def test_torque_input_equals_the_realised_momentum_change():
    """With noise-free read-outs, the momentum rate taken from the commanded torques less the friction model
    (Eq. 4.56 with Jrw W_dot = tau_motor - tau_f) equals C Jrw (W+ - W-)/dt of the emulator's wheels, friction
    and all, wherever no wheel is near zero speed; near zero the filter takes the read-out difference itself."""
    sc = scenario(300, tach_rpm=0.0)
    old = linalg.zeros
    linalg.zeros = lambda n: [0.0] * n
    try:
        mt, mr = L.Model(sc["params"], momentum="torque"), L.Model(sc["params"], momentum="tach")
        hw, hd, hr, Qw = [0.0] * 3, [0.0] * 3, [0.0] * 3, [0.0] * 9
        err, ref, near = [], [], 0
        for k in range(1, len(sc["wp"])):
            wm, wp = sc["wp"][k - 1], sc["wp"][k]
            u = sc["u"][k - 1]
            L.momentum_rate(hw, hd, Qw, mt, wm, wp, u)
            L.momentum_rate(hw, hr, Qw, mr, wm, wp, None)
            if any(abs(wm[i]) < mt.tach_3sigma + (abs(u[i]) + mt.friction[0]) / mt.jrw[i]
                   or (mt.torque_rel * u[i]) ** 2 >= 2 * mt.R_rw * mt.jrw[i] ** 2 for i in range(4)):
                near += 1                 # a wheel on the read-out difference
                continue
            err.append(np.subtract(hd, hr))
            ref.append(hr)
    finally:
        linalg.zeros = old
    err, ref = np.array(err), np.array(ref)
    assert len(err) > 100 and near > 0
    assert np.abs(err).max() < 0.01 * np.sqrt((ref ** 2).mean()), (np.abs(err).max(), np.sqrt((ref ** 2).mean()))


def test_filtered_and_torque_inputs_beat_the_readout_difference():
    """The same 600 s (10 rpm read-outs): the lean filter with the filtered wheel speeds or the commanded
    torques points better than with the read-out difference (measured: 0.54x and 0.60x its pointing RMS), and
    its P stays symmetric PD."""
    sc = scenario(600, seed=5)
    z = lambda n: [0.0] * n                                   # noqa: E731
    rms = {}
    for mode in ("filtered", "torque", "tach"):
        old = linalg.zeros
        linalg.zeros = z
        try:
            f = L.LeanApkf(sc["params"], sc["qm"][0], [0.0, 0.0, 0.0], sc["wp"][0], momentum=mode)
            ea = []
            for k in range(1, len(sc["wp"])):
                f.step(sc["wp"][k], sc["qm"][k], sc["env"][k - 1], sc["u"][k - 1])
                ea.append(2 * quat.error_vec(np.array(sc["q"][k]), np.array(f.x[0:4])) / quat.RAD_PER_ARCSEC)
        finally:
            linalg.zeros = old
        P = np.reshape(f.P, (9, 9))
        assert np.array_equal(P, P.T) and positive_definite(P)
        ea = np.array(ea)[200:]
        rms[mode] = np.sqrt(np.mean(ea[:, 1] ** 2 + ea[:, 2] ** 2))
    assert rms["torque"] < 0.8 * rms["tach"] and rms["filtered"] < 0.8 * rms["tach"], rms


def test_unknown_wheel_torque_adds_noise_and_none_is_refused():
    """u NaN for a wheel (its read-out missed): the step runs, the rate covariance grows by that wheel's
    coasting friction; u None with the torque input is a ValueError that leaves the filter as it was."""
    sc = scenario(3)
    old = linalg.zeros
    linalg.zeros = lambda n: [0.0] * n
    try:
        fs = [L.LeanApkf(sc["params"], sc["qm"][0], [0.0, 0.0, 0.0], sc["wp"][0], momentum="torque") for _ in range(2)]
        u = list(sc["u"][0])
        un = [float("nan")] + u[1:]
        fs[0].step(sc["wp"][1], None, sc["env"][0], u)
        fs[1].step(sc["wp"][1], None, sc["env"][0], un)
        P0, P1 = np.reshape(fs[0].P, (9, 9)), np.reshape(fs[1].P, (9, 9))
        assert np.all(np.isfinite(fs[1].x)) and np.all(np.isfinite(P1))
        assert np.all(np.linalg.eigvalsh(P1[3:6, 3:6] - P0[3:6, 3:6]) > -1e-14 * np.trace(P0[3:6, 3:6]))
        assert np.trace(P1[3:6, 3:6]) > np.trace(P0[3:6, 3:6])
        before = (list(fs[0].x), list(fs[0].P))
        with pytest.raises(ValueError, match="wheel torques"):
            fs[0].step(sc["wp"][2], None, sc["env"][1], None)
        assert (list(fs[0].x), list(fs[0].P)) == before
    finally:
        linalg.zeros = old


def test_model_use_switches_input_inertia_and_q_as_a_fresh_model():
    params = scenario(1)["params"]
    m = L.Model(params, momentum="torque")
    t = L.Model(params, momentum="tach")
    f = L.Model(params)                                   # "filtered": the read-outs' J, as "tach"
    assert f.filtered and list(f.Ji) == list(t.Ji) and list(f.Q) == list(t.Q)
    assert list(m.Ji) != list(t.Ji) and list(m.Q) != list(t.Q)   # Jm = J - C D(Jrw) C^T differs from J
    m.use("tach")
    assert not m.torque and list(m.Ji) == list(t.Ji) and list(m.Q) == list(t.Q)
    m.use("torque")
    ref = L.Model(params, momentum="torque")
    assert m.torque and not m.filtered and list(m.Ji) == list(ref.Ji) and list(m.Q) == list(ref.Q)
    with pytest.raises(ValueError, match="momentum"):
        m.use("gyro")


def test_bad_parameter_file_is_refused():
    sc = scenario(1)
    d = json.loads(json.dumps(sc["params"]))
    d["x"]["jrw_kgm2"][0] = -1.0
    with pytest.raises(ValueError, match=r"x.jrw_kgm2\[0\] = -1: must be from 3e-07 to 3e-05 kg m\^2"):
        L.Model(d)
    with pytest.raises(ValueError, match="format"):
        L.Model({"format": "x"})


def test_micropython_gives_cpython_results_and_heap_per_cycle_is_bounded(tmp_path):
    """Under micropython the same 30 s of inputs give CPython's state and P (float32 storage both sides) within
    float32 tolerance; P stays PD; the heap allocated per 1 Hz cycle stays under 1 MB (measured: ~0.8 MB on the
    unix x64 port, where every float result is a 16-byte heap object)."""
    sc = scenario(30)
    p = tmp_path / "sc.json"
    p.write_text(json.dumps({k: sc[k] for k in ("params", "wp", "qm", "u", "env")}))
    res = run_mp("firmware_adcs.py", p)
    f = L.LeanApkf(sc["params"], sc["qm"][0], [0.0, 0.0, 0.0], sc["wp"][0])
    for k in range(1, len(sc["wp"])):                  # the inputs pass through array('f') on both sides
        qm = sc["qm"][k]
        f.step(array("f", sc["wp"][k]), None if qm is None else array("f", qm), sc["env"][k - 1],
               array("f", sc["u"][k - 1]))
    assert res["pd"] and res["skipped"] == 0
    assert np.allclose(res["x"], list(f.x), rtol=1e-5, atol=1e-9)
    P, Pm = np.array(list(f.P)), np.array(res["P"])
    assert np.allclose(Pm, P, rtol=1e-4, atol=1e-6 * np.abs(P).max())
    assert 0 < res["heap_max"] < 1_000_000


@pytest.mark.parametrize("seconds", [
    1000, pytest.param(4000, marks=pytest.mark.slow(reason="the 4000 s run takes ~45 s: FPS_SLOW=1 runs it"))])
def test_float32_stable_and_within_10_percent_of_float64(seconds):
    """Same code, float32 scalars vs float64 lists, over the emulated scenario (4000 s in the slow run):
    P symmetric and PD at every step, and the attitude and rate 1 sigma within 10 % of the float64 run's."""
    sc = scenario(seconds, dt_truth=0.5)
    ea64, ew64, pd64, _ = _run(sc, lambda n: [0.0] * n)
    ea32, ew32, pd32, f = _run(sc, lambda n: F32([np.float32(0.0)] * n), f32=True)
    assert isinstance(f.P[0], np.float32)
    assert pd64 and pd32
    s64, s32 = ea64.std(0), ea32.std(0)
    r64, r32 = ew64.std(0), ew32.std(0)
    assert np.all(np.isfinite(s32)) and np.all(s64 < 100)                # arcsec: the filter works
    assert np.all(np.abs(s32 / s64 - 1) < 0.10), (s32, s64)
    assert np.all(np.abs(r32 / r64 - 1) < 0.10), (r32, r64)


def test_phi_series_matches_the_matrix_exponential():
    """Phi (the 4th-order series of App. A.2, built on 6 rows) equals expm(F dt) of the same F to 1e-7."""
    from scipy.linalg import expm
    sc = scenario(1)
    old = linalg.zeros
    linalg.zeros = lambda n: [0.0] * n
    try:
        f = L.LeanApkf(sc["params"], sc["q"][0], [1e-3, -2e-3, 5e-4], [300.0, -200.0, 100.0, 50.0])
        L.momentum_rate(f.work.hw, f.work.hd, f.work.Qw, f.model, f.wm, f.wm, sc["u"][0], f.work.var)
        L.jacobian(f.work.F, f.x, f.model, f.work.hw, sc["env"][0], f.work)
        L.phi(f.work.Phi, f.work.F, 1.0, f.work)
        Fm = np.reshape(f.work.F, (9, 9))
        assert np.abs(Fm[6:]).max() == 0
        assert np.allclose(np.reshape(f.work.Phi, (9, 9)), expm(Fm), rtol=0, atol=1e-7 * np.abs(Fm).max())
    finally:
        linalg.zeros = old


def _control_cases(n=5):
    from emulator.spacecraft.wheels import misaligned_c, pyramid_c0
    rng = np.random.default_rng(3)
    out = []
    for _ in range(n):
        ra = rng.standard_normal(3) * 7e6
        va = np.cross([0, 0, 1.0], ra) / np.linalg.norm(ra) * 7.6e3 + rng.standard_normal(3) * 100
        rb = ra + rng.standard_normal(3) * 1e5
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        A = rng.standard_normal((3, 3)) * 1e-3
        out.append({"ra": ra.tolist(), "va": va.tolist(), "rb": rb.tolist(), "q": q.tolist(),
                    "w": (rng.standard_normal(3) * 1e-3).tolist(), "wc": (rng.standard_normal(3) * 1e-3).tolist(),
                    "J": (np.diag([0.012, 0.05, 0.048]) + A @ A.T).ravel().tolist(), "ts": 33.0,
                    "H": (rng.standard_normal(3) * 1e-4).tolist(), "tff": (rng.standard_normal(3) * 1e-7).tolist(),
                    "C": misaligned_c(pyramid_c0(), rng.standard_normal(4) * 0.1,
                                      rng.standard_normal(4) * 0.1).ravel().tolist()})
    return out


def test_flight_control_equals_ground_control_and_runs_the_same_under_micropython(tmp_path):
    """attitude_command, gains, pd_torque and the minimum-norm wheel torques equal ground/adcs/control.py's
    (CPython, float64 lists) and the micropython run of the same code (array('f') buffers, float32 tolerance)."""
    from firmware.adcs import control as fc
    from ground.adcs import control as gc
    cases = _control_cases()
    p = tmp_path / "cases.json"
    p.write_text(json.dumps(cases))
    mp = run_mp("firmware_adcs_control.py", p)["cases"]
    z = lambda n: [0.0] * n                       # noqa: E731
    w = fc.Work(z)
    for c, m in zip(cases, mp):
        qc, K, D, tau, u = z(4), z(9), z(9), z(3), z(4)
        fc.attitude_command(qc, c["ra"], c["va"], c["rb"], w)
        fc.gains(K, D, c["J"], c["ts"])
        fc.pd_torque(tau, c["q"], c["w"], qc, c["wc"], K, D, c["H"], c["tff"])
        fc.wheel_torques(u, tau, c["C"])
        qg = gc.attitude_command(np.array(c["ra"]), np.array(c["va"]), np.array(c["rb"]))
        Kg, Dg = gc.gains(np.reshape(c["J"], (3, 3)), c["ts"])
        tg = gc.pd_torque(np.array(c["q"]), np.array(c["w"]), qg, np.array(c["wc"]), Kg, Dg, np.array(c["H"]),
                          np.array(c["tff"]))
        ug = gc.wheel_torques(tg, np.reshape(c["C"], (3, 4)), null_fraction=0.0)
        assert np.allclose(qc, qg, atol=1e-12)
        assert np.allclose(tau, tg, rtol=1e-9, atol=1e-15)
        assert np.allclose(u, ug, rtol=1e-9, atol=1e-15)
        assert np.allclose(m["qc"], qc, atol=1e-6)
        assert np.allclose(m["tau"], tau, rtol=1e-5, atol=1e-6 * np.abs(tau).max())
        assert np.allclose(m["u"], u, rtol=1e-5, atol=1e-6 * np.abs(u).max())
    with pytest.raises(ValueError, match="opposite"):
        fc.min_rotation(z(4), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0))



def test_phi_and_the_covariance_prediction_equal_the_plain_products_bit_for_bit(monkeypatch):
    """The written-out Phi series (F's structural zeros skipped) and P = Phi P Phi^T (rows 6-8 the identity's,
    columns read as rows of the symmetric P) give exactly what the full 9 x 9 loops give, on float64 buffers
    where any reordering would show in the last bit. F and Phi are random with the lean filter's structure
    (F: -[w x]-like rows 0-2 with a zero diagonal, F12 = I/2, F13 = 0, rows 6-8 zero; Phi: rows 6-8 the
    identity's), so that no term is negligible beside another."""
    monkeypatch.setattr(linalg, "zeros", lambda n: [0.0] * n)
    rng = np.random.default_rng(5)
    Fm = np.zeros((9, 9))
    Fm[0:3, 0:3] = rng.normal(size=(3, 3)) * 0.3
    np.fill_diagonal(Fm[0:3, 0:3], 0.0)
    Fm[0:3, 3:6] = 0.5 * np.eye(3)
    Fm[3:6] = rng.normal(size=(3, 9)) * 0.3
    F, dt = Fm.ravel().tolist(), 0.9
    w = L.Work()
    Phi = [0.0] * 81
    L.phi(Phi, F, dt, w)
    term = [v * dt for v in F]
    ref = [(1.0 if i % 10 == 0 else 0.0) + term[i] for i in range(81)]
    for n in (2, 3, 4):                                  # term = term F dt / n, full loops
        term = [sum_ordered([term[i * 9 + k] * F[k * 9 + j] for k in range(9)]) * (dt / n)
                for i in range(9) for j in range(9)]
        ref = [ref[i] + term[i] for i in range(81)]
    assert Phi == ref
    Phm = np.eye(9)
    Phm[0:6] = rng.normal(size=(6, 9))
    Ph = Phm.ravel().tolist()
    A = rng.normal(size=(9, 9))
    P0 = (A @ A.T).ravel().tolist()
    P = list(P0)
    L.covariance_predict(P, Ph, w.T1)
    T = [sum_ordered([Ph[i * 9 + k] * P0[k * 9 + j] for k in range(9)]) for i in range(9) for j in range(9)]
    ref = [sum_ordered([T[i * 9 + k] * Ph[j * 9 + k] for k in range(9)]) for i in range(9) for j in range(9)]
    for i in range(9):
        for j in range(i):
            ref[i * 9 + j] = ref[j * 9 + i]              # the upper triangle, mirrored
    assert P == ref


def sum_ordered(terms):
    """Left-to-right float sum (what a loop with s += t does; Python's sum starts at 0 the same way)."""
    s = 0.0
    for t in terms:
        s += t
    return s


def _wheel_truth(n, seed, u_nm=2e-5, rel=L.TORQUE_REL):
    """One wheel over n 1 s steps (finely integrated rotor equation with the datasheet friction), its realised
    torque off the command by a white fraction rel (the filter's assumed 5 %), read out with 10 rpm noise."""
    rng = np.random.default_rng(seed)
    m = L.Model(scenario(1)["params"])
    jr = m.jrw[0]
    W, u, z, Wt = 300.0, np.zeros(n), np.zeros(n + 1), np.zeros(n + 1)
    Wt[0], z[0] = W, W + rng.normal(0.0, np.sqrt(m.R_rw))
    for k in range(n):
        u[k] = u_nm * np.sin(2 * np.pi * k / 200.0) + 0.5 * u_nm
        ur = u[k] * (1.0 + rel * rng.normal())
        for _ in range(100):
            W += (ur - L.friction(m, W)) * 0.01 / jr
        Wt[k + 1] = W
        z[k + 1] = W + rng.normal(0.0, np.sqrt(m.R_rw))
    return m, u, z, Wt


def test_wheel_speed_filter_is_consistent_and_its_change_variance_is_what_momentum_rate_takes():
    """wheel_speeds on a wheel whose truth matches its model (2e-5 N m, a pointing torque): the error over 3000
    steps is under half the read-out noise (measured 0.41x), consistent with Pw (normalised error squared
    0.8-1.2; measured 1.01), and var is the variance of the step's speed-change error (within 10 %; 1.04)."""
    m, u, z, Wt = _wheel_truth(3000, seed=1)
    W, Pw, var = [z[0]] * 4, [m.R_rw] * 4, [0.0] * 4
    e, p, d, v = [], [], [], []
    for k in range(len(u)):
        e0 = W[0] - Wt[k]
        L.wheel_speeds(W, Pw, var, [z[k + 1]] * 4, L.ALL, [u[k]] * 4, m)
        if k >= 100:
            e.append(W[0] - Wt[k + 1])
            p.append(Pw[0])
            d.append(W[0] - Wt[k + 1] - e0)
            v.append(var[0])
    e, p, d, v = map(np.array, (e, p, d, v))
    assert np.std(e) < 0.5 * np.sqrt(m.R_rw), (np.std(e), np.sqrt(m.R_rw))
    assert 0.8 < np.mean(e ** 2 / p) < 1.2, np.mean(e ** 2 / p)
    assert abs(np.var(d) / np.mean(v) - 1.0) < 0.1, (np.var(d), np.mean(v))


def test_wheel_speed_filter_predicts_an_unheard_wheel_and_takes_it_back():
    """A wheel not heard for 20 steps: its speed follows the rotor equation alone (no read-out taken, not even
    a stale one), its variance grows by at least its torque's square each step, and once heard again it is
    back within 3 sigma of the truth."""
    m, u, z, Wt = _wheel_truth(200, seed=2)
    W, Pw, var = [z[0]] * 4, [m.R_rw] * 4, [0.0] * 4
    for k in range(100):
        L.wheel_speeds(W, Pw, var, [z[k + 1]] * 4, L.ALL, [u[k]] * 4, m)
    g = m.scale / m.jrw[0]
    for k in range(100, 120):
        W0, P0 = W[0], Pw[0]
        L.wheel_speeds(W, Pw, var, [1e9] + [z[k + 1]] * 3, (False, True, True, True), [u[k]] * 4, m)
        assert W[0] == pytest.approx(W0 + g * (u[k] - L.friction(m, W0)), rel=0, abs=1e-9)
        assert Pw[0] >= P0 + (g * abs(u[k])) ** 2 and var[0] == pytest.approx(Pw[0] - P0)
        assert Pw[1] < 0.2 * m.R_rw                              # the heard wheels took their read-out
        assert abs(W[1] - Wt[k + 1]) < 3 * np.sqrt(m.R_rw)
    for k in range(120, 199):
        L.wheel_speeds(W, Pw, var, [z[k + 1]] * 4, L.ALL, [u[k]] * 4, m)
    assert abs(W[0] - Wt[199]) < 3 * np.sqrt(Pw[0]) and Pw[0] < 0.5 * m.R_rw


def test_filtered_input_rate_noise_is_g_var_g_transpose():
    """With "filtered", momentum_rate's hd is C Jrw (W+ - W-)/dt of the filtered speeds and Qw = G D(var) G^T
    (G = J^-1 C D(Jrw), Eq. 4.135's construction), for the variances wheel_speeds left."""
    params = scenario(1)["params"]
    old = linalg.zeros
    linalg.zeros = lambda n: [0.0] * n
    try:
        m = L.Model(params)
        hw, hd, Qw = [0.0] * 3, [0.0] * 3, [0.0] * 9
        wm, wp, var = [100.0, -50.0, 20.0, 300.0], [101.0, -52.0, 20.5, 298.0], [0.3, 0.05, 1.1, 0.0]
        out = L.momentum_rate(hw, hd, Qw, m, wm, wp, [0.0] * 4, var)
    finally:
        linalg.zeros = old
    CJ = np.reshape(list(m.CJ), (3, 4))
    G = np.linalg.inv(np.reshape(list(m.J), (3, 3))) @ CJ
    assert np.allclose(np.reshape(out, (3, 3)), G @ np.diag(var) @ G.T, rtol=1e-12, atol=0)
    assert np.allclose(hd, CJ @ (np.subtract(wp, wm) / m.dt), rtol=1e-12, atol=0)
    assert np.allclose(hw, CJ @ np.array(wm), rtol=1e-12, atol=0)
