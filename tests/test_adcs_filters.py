"""ground/adcs: the APKF's F and closed-form Phi against finite differences and expm, Joseph vs standard update,
P symmetric and positive definite over the scenarios, the MEKF's Phi."""

import numpy as np
import pytest
from scipy.linalg import expm

from ground.adcs import apkf, mekf, quat

DEG = np.pi / 180


def _state(seed=0):
    """An APKF estimate away from the nominal: rates, torques, misalignments and wheel accelerations all nonzero."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    x = apkf.initial_state(q / np.linalg.norm(q), np.radians([0.8, -0.5, 1.2]),
                           np.array([900.0, -1200.0, 400.0, 1500.0]) * apkf.RPM)
    x[7:10] = [3e-7, -2e-7, 5e-7]
    x[10:15] += [3e-3, -2e-3, 5e-4, -7e-4, 1e-3]
    x[15:18] = [-0.11, 0.15, 0.2]
    x[18:26] = np.radians(rng.uniform(-10, 10, 8))
    x[26:30] += [4e-7, -3e-7, 2e-7, 5e-7]
    x[34:38] = x[30:34] - [20.0, -10.0, 5.0, 30.0]        # W-: the wheels accelerate over the step
    x[38:42] = x[30:34] + [20.0, -10.0, 5.0, 30.0]
    return x


def _error_rate(x_hat, dx, model, t):
    """d/dt of the error state when the truth is x_hat (+) dx: the nonlinear model, no linearisation."""
    x = apkf.correct(x_hat, dx)
    dt = model.dt

    def der(y):
        acc = (y[38:42] - y[34:38]) / dt
        qd, wd = apkf.rates(y, model, t, y[30:34], acc)
        return qd, wd, acc

    qd, wd, acc = der(x)
    qdh, wdh, acch = der(x_hat)
    dq_dot = quat.quat_mul(qd, quat.conj(x_hat[:4])) + quat.quat_mul(x[:4], quat.conj(qdh))
    out = np.zeros(apkf.N)
    out[0:3] = dq_dot[:3]
    out[3:6] = wd - wdh
    out[apkf.IWR] = acc - acch
    return out


def finite_difference_F(x_hat, model, t):
    steps = np.ones(apkf.N)
    steps[0:3], steps[3:6], steps[6:9], steps[9:14], steps[14:17] = 1e-6, 1e-7, 1e-9, 1e-6, 1e-4
    steps[17:25], steps[25:29], steps[29:41] = 1e-5, 1e-9, 1e-3
    F = np.zeros((apkf.N, apkf.N))
    for j in range(apkf.N):
        e = np.zeros(apkf.N)
        e[j] = steps[j]
        F[:, j] = (_error_rate(x_hat, e, model, t) - _error_rate(x_hat, -e, model, t)) / (2 * steps[j])
    return F


@pytest.mark.parametrize("seed", [0, 1])
def test_jacobian_matches_finite_differences(seed):
    model = apkf.Model()
    x = _state(seed)
    F = apkf.jacobian(x, model, 123.0)
    Ffd = finite_difference_F(x, model, 123.0)
    scale = np.abs(Ffd).max(axis=0) + 1e-300
    bad = np.abs(F - Ffd) > 1e-5 * scale + 1e-12
    assert not bad.any(), "F differs at %s" % (np.argwhere(bad)[:10].tolist(),)


def test_closed_form_phi_matches_expm_of_finite_difference_F():
    """Phi (App. A.2 construction) vs expm(F dt), F from finite differences of the nonlinear model; dt = 1 s
    (the filter's step) and 0.1 s. Tolerance: 1e-6 relative to each column's largest entry."""
    for dt in (1.0, 0.1):
        model = apkf.Model(dt=dt)
        x = _state(2)
        Ffd = finite_difference_F(x, model, 50.0)
        ref = expm(Ffd * dt)
        Phi = apkf.phi(apkf.jacobian(x, model, 50.0), dt)
        scale = np.abs(ref - np.eye(apkf.N)).max(axis=0) + 1e-30
        err = np.abs(Phi - ref).max(axis=0) / scale
        assert err.max() < 1e-6, (dt, err.argmax(), err.max())


def test_phi_series_order_matters():
    """A 1st-order Phi is visibly worse than the closed form (the comparison above can fail)."""
    model = apkf.Model()
    x = _state(3)
    x[4:7] = np.radians([1.5, -1.5, 1.5])
    F = apkf.jacobian(x, model, 0.0)
    ref = expm(F)
    assert np.abs(apkf.phi(F, 1.0, order=1) - ref).max() > 100 * np.abs(apkf.phi(F, 1.0) - ref).max()


def test_propagate_matches_phi_for_small_errors():
    """The nonlinear propagation of x_hat (+) dx minus that of x_hat is Phi dx to first order."""
    model = apkf.Model()
    x = _state(4)
    F = apkf.jacobian(x, model, 10.0)
    Phi = apkf.phi(F, 1.0)
    rng = np.random.default_rng(5)
    dx = np.concatenate([1e-6 * rng.normal(size=6), 1e-10 * rng.normal(size=3), 1e-6 * rng.normal(size=5),
                         1e-4 * rng.normal(size=3), 1e-5 * rng.normal(size=8), 1e-10 * rng.normal(size=4),
                         1e-3 * rng.normal(size=12)])
    x1 = apkf.propagate(apkf.correct(x, dx), model, 10.0)
    x0 = apkf.propagate(x, model, 10.0)
    d = np.concatenate([quat.error_vec(x1[:4], x0[:4]), x1[4:] - x0[4:]])
    pred = Phi @ dx
    # F is taken at the start of the step while q and W move over it (1.2 deg, 40 rad/s here): ~1 % apart
    assert np.abs(d[:6] - pred[:6]).max() < 3e-2 * np.abs(pred[:6]).max()
    assert np.abs(d[6:] - pred[6:]).max() < 1e-9 * np.abs(dx).max()


def _update_standard(x, P, q_meas, R):
    """``apkf.update`` with the textbook P+ = (I - K H) P."""
    z = quat.error_vec(q_meas, x[0:4])
    K = np.linalg.solve(P[0:3, 0:3] + R, P[0:3, :]).T
    H = np.zeros((3, len(P)))
    H[:, 0:3] = np.eye(3)
    return apkf.correct(x, K @ z), (np.eye(len(P)) - K @ H) @ P


def test_joseph_equals_standard_update_when_well_conditioned():
    x = _state(6)
    rng = np.random.default_rng(7)
    L = rng.normal(size=(apkf.N, apkf.N)) * 1e-2
    P = L @ L.T + np.diag(np.full(apkf.N, 1e-3))
    q_meas = quat.from_small(np.array([1e-4, -2e-4, 3e-4]), x[:4])
    R = np.diag([1e-3, 2e-3, 3e-3])
    xj, Pj = apkf.update(x, P, q_meas, R)
    xs, Ps = _update_standard(x, P, q_meas, R)
    assert np.allclose(xj, xs, rtol=0, atol=1e-14)
    assert np.allclose(Pj, Ps, rtol=1e-9, atol=1e-12 * np.abs(P).max())
    assert np.abs(Pj - P).max() > 1e-6
    # the fast form in apkf.update is the textbook Joseph form (Eq. 4.142) with H = [I3 0]
    H = np.zeros((3, apkf.N))
    H[:, :3] = np.eye(3)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    assert np.allclose(Pj, mekf.joseph(P, H, R, K), rtol=1e-10, atol=1e-14)


def test_mekf_phi_is_the_exponential():
    w = np.radians([2.0, -1.0, 3.0])
    F = np.zeros((6, 6))
    F[:3, :3] = -quat.skew(w)
    F[:3, 3:] = -0.5 * np.eye(3)
    assert np.allclose(mekf.phi(w, 1.0), expm(F), rtol=0, atol=1e-13)
    assert np.allclose(mekf.phi(w * 1e-9, 1.0), expm(F * 1e-9 * 0 + np.block([[-quat.skew(w * 1e-9),
                       -0.5 * np.eye(3)], [np.zeros((3, 6))]])), atol=1e-13)
