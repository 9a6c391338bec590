"""The APKF's disturbance models (``ground/adcs/apkf_disturbance.py``): the thesis's white model kept to the bit,
the shaping filters' Phi and Q against their closed forms and the augmented model's exponential, a smooth torque
followed better, and the option's bad values."""

import hashlib
from math import cos, exp, pi, sin, sqrt

import numpy as np
import pytest
from scipy.linalg import expm

from emulator.spacecraft import scenario
from ground.adcs import apkf, apkf_disturbance as ad, quat, runs
from ground.cli import main as fps

# sha256 of x and P after ``_synthetic_run()`` with the thesis's random walk (the consistent form): a shaping filter
# left out must leave the walk's numbers as they are, to the bit
WHITE_DIGEST = "75d9204a70de7e6a819a37492187717068156e0902e3151dc0094b8d7a343026"


def _synthetic_run(**kw):
    """40 steps of the APKF on seeded synthetic read-outs, with a 5-step blind stretch (an iterated update)."""
    rng = np.random.default_rng(7)
    q0 = np.array([0.1, -0.2, 0.05, 1.0]) / np.linalg.norm([0.1, -0.2, 0.05, 1.0])
    x0 = apkf.initial_state(q0, np.array([0.002, -0.001, 0.0005]), np.full(4, 300.0))
    f = apkf.APKF(x0, case=2, set_ends=(20.0,), **kw)
    for k in range(40):
        w_plus = np.full(4, 300.0) + rng.normal(0, 1.0, 4)
        q = quat.from_small(rng.normal(0, 1e-4, 3), f.x[0:4]) if not 15 <= k < 20 else None
        f.step(float(k), w_plus, q)
    return f


def test_white_is_the_thesis_model_to_the_bit():
    f, g = _synthetic_run(), _synthetic_run(disturbance="white")
    assert f.model.disturbance is None and len(f.reacquisitions) == 1
    assert np.array_equal(f.x, g.x) and np.array_equal(f.P, g.P)
    assert hashlib.sha256(f.x.tobytes() + f.P.tobytes()).hexdigest() == WHITE_DIGEST
    h = _synthetic_run(disturbance="markov")                   # Case 2's markov: a different model, other numbers
    assert h.x.shape == f.x.shape and not np.array_equal(h.x[7:10], f.x[7:10])


def test_gauss_markov_phi_and_q_closed_form():
    T, sigma, dt = np.array([15.2, 13.8, 15.7]), 7.07e-7, 1.0
    ix, Phi, half, Q, Fd = ad.gauss_markov(T, sigma).step(dt)
    assert list(ix) == [6, 7, 8]
    assert np.allclose(Phi, np.diag(np.exp(-dt / T)), rtol=1e-13, atol=0)
    assert np.allclose(half, np.diag(np.exp(-0.5 * dt / T)), rtol=1e-13, atol=0)
    assert np.allclose(Q, np.diag(sigma ** 2 * (1 - np.exp(-2 * dt / T))), rtol=1e-9, atol=0)
    assert np.allclose(Fd, -np.diag(1 / T))
    # the random walk is its limit: T -> inf with 2 sigma^2 / T = q_d
    q_d = (2e-7) ** 2 / 3600
    Q_long = ad.gauss_markov(1e9, sqrt(q_d * 1e9 / 2)).step(dt)[3]
    assert np.allclose(np.diag(Q_long), q_d * dt, rtol=1e-6)


def test_harmonic_phi_and_q_closed_form():
    period, sigma, zeta, dt = 72.7, 7.07e-7, 0.05, 1.0
    sf = ad.harmonic(period, sigma, zeta)
    ix, Phi, _, Q, _ = sf.step(dt)
    assert list(ix) == [6, 7, 8, 41, 42, 43] and sf.n == 44
    w0 = 2 * pi / period
    wd, a = w0 * sqrt(1 - zeta ** 2), zeta * w0
    e = exp(-a * dt)
    closed = e * np.array([[cos(wd * dt) + a / wd * sin(wd * dt), sin(wd * dt) / wd],
                           [-w0 ** 2 / wd * sin(wd * dt), cos(wd * dt) - a / wd * sin(wd * dt)]])
    for k in range(3):                                       # axis k: tau_d k and its rate k
        i = np.ix_([k, k + 3], [k, k + 3])
        assert np.allclose(Phi[i], closed, rtol=1e-10, atol=1e-14)
    P_inf = sf.prior()
    assert np.allclose(Q, P_inf - Phi @ P_inf @ Phi.T, rtol=1e-7, atol=1e-12 * sigma ** 2)
    assert np.all(np.linalg.eigvalsh(Q) > 0)


def test_gradient_phi_and_q_against_van_loan():
    sf = ad.shaping(3, "gradient")
    x = np.zeros(42)
    x[4:7] = [0.02, -0.005, 0.001]
    dt = 1.0
    ix, Phi, half, Q, Fd = sf.step(dt, x)
    assert Phi.shape == (12, 12) and sf.n == 50 and list(ix[3:]) == list(range(41, 50))
    assert np.allclose(Phi, expm(Fd * dt)) and np.allclose(half, expm(Fd * 0.5 * dt))
    assert np.allclose(Fd[0:3, 3:12] @ np.arange(9.0), np.arange(9.0).reshape(3, 3) @ x[4:7])     # W vec(G) = G w
    q_g = sf.q_g + sf.q_g_angle * np.linalg.norm(x[4:7])
    Gq = np.diag([sf.q_tau] * 3 + [q_g] * 9)
    V = expm(np.block([[-Fd, Gq], [np.zeros((12, 12)), Fd.T]]) * dt)
    assert np.allclose(Q, V[12:, 12:].T @ V[:12, 12:], rtol=1e-9, atol=1e-30)


@pytest.mark.parametrize("form", ["markov", "harmonic"])
def test_augmented_phi_against_the_exponential(form):
    """The attitude and rate rows of Phi on the shaping filter's states (first order in Fd dt) against
    expm(F_aug dt) of the augmented continuous model."""
    model = apkf.Model()
    model.disturbance = sf = ad.shaping(2, form)
    q0 = np.array([0.1, -0.2, 0.05, 1.0]) / np.linalg.norm([0.1, -0.2, 0.05, 1.0])
    x = apkf.initial_state(q0, np.array([0.01, -0.004, 0.002]), np.full(4, 800.0))
    x, _ = apkf.shaping_states(x, apkf.initial_covariance(model), sf)
    *_, F2, PhiR, sd = apkf._linearise(x.copy(), np.full(4, 810.0), model, 100.0)
    n = sf.n
    F = np.zeros((n, n))
    F[0:3, 0:3] = -quat.skew(x[4:7])
    F[0:3, 3:6] = 0.5 * np.eye(3)
    F[3:6] = F2
    F[29:33, 33:37], F[29:33, 37:41] = -np.eye(4), np.eye(4)
    F[np.ix_(sf.ix, sf.ix)] = sf.Fd
    E = expm(F)
    S = np.eye(n)
    S[np.ix_(sf.ix, sf.ix)] = sd[1]
    Phi = np.eye(n)
    Phi[0:6], Phi[29:33] = PhiR[0:6], PhiR[6:10]
    Phi = Phi @ S
    block = np.ix_(range(6), sf.ix)
    assert np.max(np.abs(Phi[block] - E[block])) < 2e-3 * np.max(np.abs(E[block]))
    assert np.allclose(Phi[np.ix_(sf.ix, sf.ix)], E[np.ix_(sf.ix, sf.ix)], rtol=1e-10, atol=1e-12)


def test_harmonic_follows_case2_sine_better_than_white():
    o = scenario.simulate(case=2, seed=0, duration=330.0)
    err = {}
    for form in ("white", "harmonic"):
        k0, f = runs._start_apkf(o, 2, disturbance=form)
        e = []
        for k in range(k0 + 1, len(o["t"])):
            f.step(o["t"][k - 1], o["tach"][k], o["st_q"][k] if o["st_valid"][k] else None)
            if o["t"][k] >= 210:
                e.append(runs.apkf_error(o, k, f.x, 2)[6:9])
        err[form] = np.sqrt(np.mean(np.square(e)))
    assert err["harmonic"] < 0.5 * err["white"], err


def test_disturbance_option_bad_values_exit_2(tmp_path, capsys):
    out = tmp_path / "o"
    with pytest.raises(SystemExit) as exc:
        fps(["adcs", "apkf", "--case", "2", "--disturbance", "pink", "-o", str(out)])
    assert exc.value.code == 2
    assert "invalid choice: 'pink'" in capsys.readouterr().err
    for case, form in (("1", "harmonic"), ("3", "harmonic"), ("2", "gradient")):
        assert fps(["adcs", "apkf", "--case", case, "--disturbance", form, "--runs", "1", "-o", str(out)]) == 2
        assert "--disturbance %s" % form in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(ValueError, match="disturbance must be one of"):
        apkf.APKF(apkf.initial_state([0, 0, 0, 1.0], np.zeros(3), np.zeros(4)), disturbance="Markov")
