"""The APKF's second-order terms (the consistent form): each against a sampled covariance of the product it
stands for, and the prediction's rate block carrying both."""

import numpy as np

from ground.adcs import apkf

B_BODY = np.array([2.1e-5, -0.9e-5, 3.3e-5])          # a LEO field in the body, T


def _correlated_p(rng, ix, scale):
    """A 41 x 41 P with a random correlated block on the indices ``ix`` (1 sigma ``scale`` each)."""
    A = rng.standard_normal((len(ix), len(ix)))
    S = A @ A.T
    d = np.sqrt(np.diag(S))
    S = S / np.outer(d, d) * np.outer(scale, scale)
    P = np.eye(apkf.N) * 1e-12
    P[np.ix_(ix, ix)] = S
    return P


def test_the_dipole_attitude_term_is_the_covariance_of_the_product_it_stands_for():
    """g = 2 e_m x (b x dq) for correlated Gaussian errors: the closed form against 400,000 draws, within 2 %."""
    rng = np.random.default_rng(3)
    ix = np.r_[0:3, 14:17]
    P = _correlated_p(rng, ix, np.r_[[0.05] * 3, [0.3] * 3])       # attitude error ~6 deg, dipole 0.3 A m^2
    Q = apkf.dipole_attitude_noise(P, B_BODY, np.eye(3), 1.0)
    X = rng.multivariate_normal(np.zeros(6), P[np.ix_(ix, ix)], 400000)
    g = 2.0 * np.cross(X[:, 3:6], np.cross(B_BODY, X[:, 0:3]))
    C = np.cov(g.T)
    assert np.allclose(Q, C, rtol=0.02, atol=0.02 * np.abs(C).max())
    # through J^-1 and held over the step
    Ji = np.diag([1 / 0.012, 1 / 0.03, 1 / 0.033])
    assert np.allclose(apkf.dipole_attitude_noise(P, B_BODY, Ji, 2.0), 4.0 * Ji @ Q @ Ji.T)
    # no attitude or no dipole uncertainty: no product
    P0 = P.copy()
    P0[0:3, :] = P0[:, 0:3] = 0.0
    assert np.abs(apkf.dipole_attitude_noise(P0, B_BODY, np.eye(3), 1.0)).max() == 0.0


def test_the_consistent_prediction_adds_both_second_order_terms_to_the_rate_only():
    rng = np.random.default_rng(5)
    q0 = np.array([0.1, -0.2, 0.05, 1.0]) / np.linalg.norm([0.1, -0.2, 0.05, 1.0])
    x = apkf.initial_state(q0, np.array([0.002, -0.001, 0.0005]), np.array([300.0, -250.0, 400.0, 120.0]))
    x[15:18] = [0.05, -0.02, 0.1]
    model = apkf.Model()
    P = apkf.initial_covariance(model, x)
    P[0:3, 0:3] += np.eye(3) * 0.03 ** 2                   # an attitude error of degrees, as after a blind stretch
    w_plus = x[38:42] + rng.normal(0, 0.5, 4)
    x1, P1 = apkf.predict(x, P, w_plus, model, 100.0, second_order=True)
    x2, P2 = apkf.predict(x, P, w_plus, model, 100.0, second_order=False)
    assert np.array_equal(x1, x2)
    D = P1 - P2
    assert np.abs(np.delete(np.delete(D, np.s_[3:6], 0), np.s_[3:6], 1)).max() == 0.0
    xs = x.copy()
    _, _, c, _, r0, _, _, _ = apkf._linearise(xs, w_plus, model, 100.0)
    Ji = np.array(c[1])
    want = apkf.second_order_noise(xs, P, model, Ji) + apkf.dipole_attitude_noise(P, np.array(r0[3]), Ji, model.dt)
    assert np.abs(D[3:6, 3:6] - want).max() < 1e-14 * np.abs(P1[3:6, 3:6]).max()      # P's rounding
    assert np.abs(want).max() > 1e-8 * np.abs(P1[3:6, 3:6]).max()
    assert np.abs(apkf.dipole_attitude_noise(P, np.array(r0[3]), Ji, model.dt)).max() > 0.0
