"""The APKF's structured predict/update compute what the textbook forms compute.

1. A recorded 930 s Case 3 run (tests/data/apkf_reference.npz: the filter's inputs, and x, P at three points,
   F, Phi, Q at one state, all written by the APKF before the speed-up, see tests/data/make_apkf_reference.py)
   is replayed through ``APKF.step``: x and P agree to ~1e-12 of P's scale.
2. Each predict and update of a stretch of that run against a dense reference written here: full F, Phi,
   Q and Phi P Phi^T + Q, and the Joseph update with the full 41 x 41 I - K H.
"""

import os

import numpy as np
import pytest

from ground.adcs import apkf, mekf, quat

DATA = os.path.join(os.path.dirname(__file__), "data", "apkf_reference.npz")


@pytest.fixture(scope="module")
def ref():
    return dict(np.load(DATA))


@pytest.fixture(autouse=True)
def recorded_mu(monkeypatch):
    """The reference was recorded with the gravity-gradient torque's mu of its time, 3.986004418e14 m^3/s^2
    (protocol.units.MU_EARTH, one value for every part since, is 398600.4415e9): the replay uses the same, as it
    uses the recorded inputs."""
    from emulator.spacecraft import environment
    monkeypatch.setattr(environment, "MU_EARTH", 3.986004418e14)


def _close(x, P, x_ref, P_ref, tol):
    """x and P agree with the reference to tol of P's 1 sigma (x) and of sigma_i sigma_j (P)."""
    s = np.sqrt(np.diag(P_ref))
    ex = np.abs(x - x_ref)
    assert (ex[1:] / s).max() < tol and ex[0:4].max() < tol, (ex[1:] / s).max()   # x[1:] aligns with dx (41)
    assert (np.abs(P - P_ref) / np.outer(s, s)).max() < tol, (np.abs(P - P_ref) / np.outer(s, s)).max()


def test_recorded_run_is_reproduced(ref):
    f = apkf.APKF(ref["x0"], case=int(ref["case"]), set_ends=list(ref["set_ends"]), form="thesis")
    checks = list(ref["checks"])
    got = []
    for i in range(1, len(ref["t"])):
        f.step(ref["t"][i - 1], ref["tach"][i], ref["st_q"][i] if ref["st_valid"][i] else None)
        if i in checks:
            got.append((f.x.copy(), f.P.copy()))
    assert len(got) == 3
    for (x, P), x_ref, P_ref in zip(got, ref["x"], ref["P"]):
        _close(x, P, x_ref, P_ref, 1e-10)
        assert np.abs(P - P_ref).max() < 1e-12 * np.abs(P_ref).max()
        assert np.abs(x - x_ref).max() < 1e-12 * np.abs(x_ref).max()


def test_jacobian_phi_and_q_equal_the_recorded_ones(ref):
    model = apkf.Model()
    x, t = ref["F_x"], float(ref["F_t"])
    F = apkf.jacobian(x, model, t, apkf.terms(x, model, t + 0.5 * model.dt))
    scale = np.abs(ref["F"]).max(axis=0) + 1e-300
    assert (np.abs(F - ref["F"]).max(axis=0) / scale).max() < 1e-13
    assert np.abs(apkf.phi(F, model.dt) - ref["Phi"]).max() < 1e-13 * np.abs(ref["Phi"]).max()
    Q = apkf.process_noise(F, apkf.noise_density(x, int(ref["case"]), 10.0), model.dt)
    assert np.abs(Q - ref["Q"]).max() < 1e-13 * np.abs(ref["Q"]).max()


# --- a dense reference, written as the textbook does -----------------------------------------------------------
def _phi_dense(F, dt, order=4):
    """Phi of App. A.2: the exponential of F dt, with the attitude-rate block and its integrals as series."""
    A = F[0:6, 0:6] * dt
    E, G1, G2 = np.eye(6), np.eye(6) * dt, np.eye(6) * dt * dt / 2
    term, fact = np.eye(6), 1.0
    for n in range(1, order + 1):
        term = term @ A
        fact *= n
        E = E + term / fact
        G1 = G1 + term * dt / (fact * (n + 1))
        G2 = G2 + term * dt * dt / (fact * (n + 1) * (n + 2))
    Phi = np.eye(apkf.N)
    Phi[0:6, 0:6] = E
    Phi[0:6, 6:] = G1 @ F[0:6, 6:]
    Phi[0:6, 33:41] += G2 @ F[0:6, 29:33] @ F[29:33, 33:41]           # G2 F_A,W F_W,W+-
    Phi[29:33, 33:41] = F[29:33, 33:41] * dt
    return Phi


def _predict_dense(x, P, w_plus, model, t, case, scale):
    x, P = apkf.shift_tach(x, P, w_plus, model.R_rw)
    m = apkf.terms(x, model, t + 0.5 * model.dt)
    F = apkf.jacobian(x, model, t, m)
    Phi = _phi_dense(F, model.dt)
    Q = apkf.process_noise(F, apkf.noise_density(x, case, scale), model.dt)
    P = Phi @ P @ Phi.T + Q
    return apkf.propagate(x, model, t, m), 0.5 * (P + P.T)


def _update_dense(x, P, q_meas, R):
    z = quat.error_vec(q_meas, x[0:4])
    H = np.zeros((3, apkf.N))
    H[:, 0:3] = np.eye(3)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    P = mekf.joseph(P, H, R, K)
    return apkf.correct(x, K @ z), 0.5 * (P + P.T)


def test_each_step_equals_the_dense_textbook_form(ref):
    """Per step, from the same (x, P): the fast predict and update against the dense forms, over the first
    maneuver set (x100 noise, the adaptive q_d of Case 3) and a stretch of nominal noise."""
    model, case = apkf.Model(), int(ref["case"])
    f = apkf.APKF(ref["x0"], model, case=case, set_ends=list(ref["set_ends"]))
    worst = 0.0
    for i in list(range(1, 40)) + list(range(600, 640)):
        if i == 600:
            f.x, f.P = ref["x"][1], ref["P"][1]             # step 400's state, here at t ~ 600 s (x1 noise)
        t = float(ref["t"][i - 1])
        s = apkf.fictitious_scale(t, f.set_ends)
        x1, P1 = apkf.predict(f.x, f.P, ref["tach"][i], model, t, case, s)
        x2, P2 = _predict_dense(f.x, f.P, ref["tach"][i], model, t, case, s)
        sg = np.sqrt(np.diag(P2))
        worst = max(worst, (np.abs(P1 - P2) / np.outer(sg, sg)).max())
        assert np.array_equal(P1, P1.T)
        assert (np.abs(x1 - x2)[1:] / sg).max() < 1e-11 and np.abs(P1 - P2).max() < 1e-13 * np.abs(P2).max()
        if ref["st_valid"][i]:
            R = model.R_st * apkf.fictitious_scale(t + model.dt, f.set_ends)
            xu, Pu = apkf.update(x1, P1, ref["st_q"][i], R)
            xd, Pd = _update_dense(x1, P1, ref["st_q"][i], R)
            sg = np.sqrt(np.diag(Pd))
            worst = max(worst, (np.abs(Pu - Pd) / np.outer(sg, sg)).max())
            assert np.array_equal(Pu, Pu.T)
            assert (np.abs(xu - xd)[1:] / sg).max() < 1e-10 and np.abs(Pu - Pd).max() < 1e-12 * np.abs(Pd).max()
            x1, P1 = xu, Pu
        f.x, f.P = x1, P1
    assert worst < 1e-10, worst


def test_the_fast_pieces_are_not_trivially_equal(ref):
    """The comparison above can fail: a wrong sign in one block of F shows."""
    model = apkf.Model()
    x = ref["F_x"]
    t = float(ref["F_t"])
    m = apkf.terms(x, model, t + 0.5)
    F = apkf.jacobian(x, model, t, m)
    F[3:6, 17:21] *= -1
    assert np.abs(apkf.phi(F, 1.0) - ref["Phi"]).max() > 1e-9 * np.abs(ref["Phi"]).max()
