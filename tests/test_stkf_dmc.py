"""The lean STKF with dynamic model compensation (firmware/adcs/stkf_dmc.py): Phi of the augmented state against a
numerical Jacobian of its propagation, Q's blocks against the integral of Phi q Phi^T, the configuration (white: the
lean STKF), the 12-state view, a markov filter's NEES on a short synthetic case, SatA's float32 covariance, the
same results under micropython, and the 9-state C kernels (firmware/adcs/native/adcsk.c): the Python forms' run bit
for bit under CPython and micropython, no allocation under micropython."""

import json
import os
import subprocess
from array import array

import numpy as np
import pytest

from firmware.adcs import estimation, linalg, stkf_dmc, stkf_lean
from firmware.adcs import stkf_kernels as K
from ground.adcs.lean_scenario import stkf_scenario
from tests.adcs_lean_common import run_mp
from tests.test_adcs_natmod import need_module, without_module
from tests.test_firmware_mp import MICROPYTHON, ROOT

X6 = np.array([4.1e6, -3.2e6, 4.2e6, 4.9e3, 5.3e3, 0.3e3])
SIGMA_A, TAU = 9.07e-5, 289.0


def _f9(x9, dt):
    b = array("d", list(x9))
    stkf_dmc.f_gm(b, 0, dt, K.J2_TERM, 1.0 / TAU, stkf_dmc.rk_work())
    return np.array(b)


def _phi9(x9, dt):
    b = array("d", bytes(8 * 81))
    stkf_dmc.phi_gm(b, array("d", list(x9)), 0, dt, K.J2_TERM, 1.0 / TAU, array("d", bytes(8 * 36)))
    return np.array(b).reshape(9, 9)


@pytest.mark.parametrize("dt", [1.0, 0.4, -0.6])
def test_phi_of_the_augmented_state_is_the_numerical_jacobian(dt):
    x9 = np.concatenate([X6, [3e-5, -6e-5, 8e-5]])
    steps = np.array([1.0] * 3 + [1e-2] * 6)              # (central differences of f at |r| ~ 7e6 m: ~1e-8 noise)
    J = np.zeros((9, 9))
    for j in range(9):
        e = np.zeros(9)
        e[j] = steps[j]
        J[:, j] = (_f9(x9 + e, dt) - _f9(x9 - e, dt)) / (2 * steps[j])
    Phi = _phi9(x9, dt)
    assert np.abs(Phi - J).max() < 1e-7
    vw = Phi[3:6, 6:9] - np.diag(np.diag(Phi[3:6, 6:9]))   # Phi_vw's G dt^3/6, |.| ~ 1e-7 over 1 s
    assert np.abs(vw).max() > 2e-8 * abs(dt) ** 3 and np.abs(Phi[3:6, 6:9] - J[3:6, 6:9]).max() < 3e-9
    assert Phi[6, 6] == pytest.approx(np.exp(-abs(dt) / TAU) if dt > 0 else np.exp(-dt / TAU), rel=1e-15)


def test_the_white_filter_is_the_lean_stkf_without_w():
    x = _f9(np.concatenate([X6, np.zeros(3)]), 7.0)[0:6]
    b = array("d", list(X6))
    K.f(b, 0, 7.0, K.J2_TERM)
    assert np.allclose(x, np.array(b), rtol=0, atol=1e-6)
    assert np.allclose(_phi9(X6.tolist() + [0.0] * 3, 1.0)[0:6, 0:6],
                       (lambda P: (K.phi(P, array("d", X6), 0, 1.0, K.J2_TERM), np.array(P).reshape(6, 6))[1])(
                           array("d", bytes(8 * 36))), rtol=0, atol=1e-15)


@pytest.mark.parametrize("dt", [0.05, 1.0, 20.0, 144.5, 600.0])      # beta dt: series below 0.5, closed form above
def test_q_is_the_integral_of_phi_q_phi_t(dt):
    beta = 1.0 / TAU
    q = 2.0 * SIGMA_A ** 2 * beta
    t = np.linspace(0.0, dt, 20001)
    x = beta * t
    phis = np.vstack([(x - 1 + np.exp(-x)) / beta ** 2 if dt > 1 else t * t * (0.5 - x / 6 + x * x / 24 - x ** 3 / 120),
                      (1 - np.exp(-x)) / beta if dt > 1 else t * (1 - x / 2 + x * x / 6 - x ** 3 / 24),
                      np.exp(-x)])
    w = np.full(len(t), t[1] - t[0])                       # Simpson's weights
    w[1:-1:2] *= 4 / 3
    w[2:-1:2] *= 2 / 3
    w[[0, -1]] *= 1 / 3
    brute = q * np.einsum("it,jt,t->ij", phis, phis, w)
    got = stkf_dmc.gm_q(dt, SIGMA_A, beta)
    want = [brute[0, 0], brute[0, 1], brute[0, 2], brute[1, 1], brute[1, 2], brute[2, 2]]
    assert got == pytest.approx(want, rel=1e-9)
    Q = array("d", bytes(8 * 81))
    stkf_dmc.process_noise_gm(Q, dt, SIGMA_A, beta)
    Q = np.array(Q).reshape(9, 9)
    assert np.allclose(Q, Q.T, rtol=0, atol=0) and np.all(np.linalg.eigvalsh(Q) > 0)
    assert Q[1, 4] == got[1] and Q[2, 8] == got[2] and Q[0, 1] == 0.0


def test_q_is_continuous_where_the_series_meets_the_closed_form():
    beta, x0 = 1.0 / TAU, stkf_dmc.X_SERIES
    below = stkf_dmc.gm_q(x0 * TAU * (1 - 1e-12), SIGMA_A, beta)
    above = stkf_dmc.gm_q(x0 * TAU * (1 + 1e-12), SIGMA_A, beta)
    assert below == pytest.approx(above, rel=1e-10)


def test_the_configuration_picks_the_filter_and_refuses_bad_values():
    assert estimation.stkf_model({}) == {"gravity": "two-body", "qa": K.QA_THESIS}
    assert estimation.stkf_model({"stkf_gravity": "j2", "stkf_qa": 5e-6, "stkf_accel": "white"}) == \
        {"gravity": "j2", "qa": 5e-6}
    kw = estimation.stkf_model({"stkf_gravity": "j2", "stkf_accel": "markov", "stkf_sigma_a": 9e-5, "stkf_tau": 290})
    assert kw == {"gravity": "j2", "sigma_a": 9e-5, "tau": 290.0}
    assert estimation.stkf_filter(kw) is stkf_dmc.DmcStkf
    assert estimation.stkf_filter(estimation.stkf_model({"stkf_qa": 1e-3})) is stkf_lean.LeanStkf
    for bad in ({"stkf_accel": "pink"}, {"stkf_accel": "markov", "stkf_sigma_a": 0.0, "stkf_tau": 300.0},
                {"stkf_accel": "markov", "stkf_sigma_a": 1e-4}, {"stkf_accel": "markov", "stkf_sigma_a": 1e-4,
                                                                 "stkf_tau": float("nan")}):
        with pytest.raises(ValueError, match="stkf_"):
            estimation.stkf_model(bad)
    with pytest.raises(ValueError, match="sigma_a"):
        stkf_dmc.DmcStkf([0.0] * 12, [1.0] * 12, 0.0, sigma_a=-1.0)


def _truth(n, seed):
    """SatA and SatB 1 s apart over n s under J2 plus a Gauss-Markov acceleration (the filter's model)."""
    rng = np.random.default_rng(seed)
    x = np.array([np.concatenate([X6, np.zeros(3)]),
                  np.concatenate([[4.3e6, -1.4e6, 5.0e6, 5.3e3, 5.0e3, -3.1e3], np.zeros(3)])])
    x[:, 6:9] = SIGMA_A * rng.standard_normal((2, 3))
    e, out = np.exp(-1.0 / TAU), [x.copy()]
    for _ in range(n):
        for s in range(2):
            w0 = x[s, 6:9].copy()
            x[s] = _f9(x[s], 1.0)
            x[s, 6:9] = e * w0 + SIGMA_A * np.sqrt(1 - e * e) * rng.standard_normal(3)
        out.append(x.copy())
    return np.array(out)


def test_a_markov_filter_stays_consistent_on_a_short_synthetic_case():
    n, rng = 300, np.random.default_rng(3)
    xt = _truth(n, 2)
    R = [0.0] * 36
    for i in range(6):
        R[i * 7] = (10.0 if i < 3 else 0.1) ** 2
    P0 = [100.0 ** 2] * 3 + [1.0] * 3 + [100.0 ** 2] * 3 + [1.0] * 3
    x0 = np.concatenate([xt[0, 0, :6], xt[0, 1, :6]]) + np.sqrt(P0) * rng.standard_normal(12)
    f = stkf_dmc.DmcStkf(x0.tolist(), P0, 0.0, sigma_a=SIGMA_A, tau=TAU)
    x, sig, nees = array("d", bytes(96)), array("d", bytes(96)), []
    for k in range(1, n + 1):
        f.predict(float(k))
        f.update_gnss((xt[k, 0, :6] + np.sqrt(np.array(R[::7])) * rng.standard_normal(6)).tolist(), R, 0)
        if k >= 3:                                   # SatB's, 2 s late, through the smoother
            f.update_gnss((xt[k - 2, 1, :6] + np.sqrt(np.array(R[::7])) * rng.standard_normal(6)).tolist(), R, 1,
                          t=float(k - 2))
        f.get(x, sig)
        e = np.array(x) - np.concatenate([xt[k, 0, :6], xt[k, 1, :6]])
        nees.append(e @ np.linalg.solve(np.array(f.Pk), e))
    assert f.refused == 0 and np.allclose(np.sqrt(np.diag(np.array(f.Pk))), np.array(sig), rtol=1e-6)
    mean = float(np.mean(nees[100:]))
    assert 8.0 < mean < 16.5                       # 12 states: chi^2(12)'s mean, 200 correlated seconds


def _run(sc, zeros=None, lag=0.0, cap=3):
    """DmcStkf (sigma_a 1e-4 m/s^2, tau 300 s) over the lean scenario ``sc``: the estimate and 1 sigma of every
    second, and the filter; ``zeros`` SatA's covariance buffers (linalg.zeros: float32)."""
    orig = linalg.zeros
    if zeros is not None:
        linalg.zeros = zeros
    try:
        f = stkf_dmc.DmcStkf(sc["x0"], sc["P0"], 0.0, lag, cap, sigma_a=1e-4, tau=300.0)
    finally:
        linalg.zeros = orig
    out, x, s = [], [0.0] * 12, [0.0] * 12
    for k, st in enumerate(sc["steps"]):
        if k:
            f.predict(st["t"])
        f.update_gnss(st["za"], sc["R"], 0)
        f.update_beacon(st["y"], st["q"], sc["P_att"], sc["sigma_b"])
        for tm, v in st["zb"]:
            f.update_gnss(v, sc["R"], 1, tm)
        f.get(x, s)
        out.append(x + s)
    return np.array(out), f


def test_satas_float32_covariance_holds_and_gives_the_float64_estimate():
    sc = stkf_scenario(300, case=1)
    x64, _ = _run(sc, zeros=lambda n: array("d", bytes(8 * n)))
    x32, f = _run(sc)
    Pa = np.array(f.Pa, float).reshape(9, 9)
    d = np.sqrt(np.diag(Pa))
    assert f.Pa.typecode == "f" and np.array_equal(Pa, Pa.T) and np.linalg.cond(Pa / np.outer(d, d)) < 1e3
    assert np.abs(x32 - x64).max(axis=0)[[0, 3, 6, 9]] == pytest.approx([0, 0, 0, 0], abs=1e-3)
    assert np.allclose(x32[:, 12:], x64[:, 12:], rtol=1e-5)


def test_the_markov_filter_runs_the_same_under_micropython(tmp_path):
    """30 s with SatB's GNSS 2-3 s late (nodes generated): micropython's estimate and 1 sigma are CPython's."""
    sc = stkf_scenario(30, case=2)
    p = tmp_path / "sc.json"
    p.write_text(json.dumps(sc))
    res = run_mp("stkf_dmc.py", p, "markov")
    x, f = _run(sc, lag=4.0, cap=6)
    assert res["refused"] == f.refused == 0 and res["generated"] == f.generated > 20
    assert np.abs(np.array(res["x"]) - x[:, :12]).max() < 1e-3
    assert np.allclose(res["sig"], x[:, 12:], rtol=1e-5, atol=0)




@pytest.mark.skipif(not linalg._cpython, reason="the C kernels are not built for CPython (firmware.adcs._adcsk)")
@pytest.mark.parametrize("case, lag, cap", [(1, 0.0, 3), (2, 4.0, 6)])
def test_the_c_kernels_give_the_python_forms_run_bit_for_bit(monkeypatch, case, lag, cap):
    """60 s of the lean scenario (case 2: SatB's GNSS late, nodes generated) with the 9-state kernels in C, then
    with their Python forms: every estimate, 1 sigma and the final covariances equal bit for bit."""
    sc = stkf_scenario(60, case=case)
    xc, fc = _run(sc, lag=lag, cap=cap)
    for name in stkf_dmc.KERNELS:
        monkeypatch.setattr(stkf_dmc, name, getattr(stkf_dmc, name).python)
    xp, fp = _run(sc, lag=lag, cap=cap)
    assert fc.generated == fp.generated == (57 if case == 2 else 0)
    assert np.array_equal(xc, xp) and bytes(fc.P) == bytes(fp.P) and bytes(fc.Pa) == bytes(fp.Pa)


def _mp_at(path, script, *args):
    """tests/mp/<script> under micropython with ``path`` first on its module path (``run_mp``'s, elsewhere)."""
    env = dict(os.environ, MICROPYPATH=str(path) + ":.frozen")
    p = subprocess.run([MICROPYTHON, "-X", "heapsize=64M", os.path.join(ROOT, "tests", "mp", script)]
                       + [str(a) for a in args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_the_c_kernels_run_the_markov_filter_bit_for_bit_and_allocate_nothing_under_micropython(tmp_path):
    """The natmod's 9-state kernels: 30 s with nodes generated give the Python forms' bits under micropython, and
    each kernel on the filter's buffers runs with the heap locked (a Python loop of the module does not)."""
    need_module()
    sc = tmp_path / "sc.json"
    sc.write_text(json.dumps(stkf_scenario(30, case=2)))
    c = _mp_at(ROOT, "stkf_dmc.py", sc, "markov")
    py = _mp_at(without_module(tmp_path), "stkf_dmc.py", sc, "markov")
    assert c["kernels"] is True and py["kernels"] is False and c["generated"] == py["generated"] > 20
    assert c["bits"] == py["bits"]
    assert _mp_at(ROOT, "stkf_dmc_alloc.py") == {"kernels": True, "nodes": 5, "locked": "ok",
                                                 "python loop": "MemoryError"}
