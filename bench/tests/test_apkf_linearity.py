"""``bench/apkf_linearity.py``'s draws of the APKF's own P."""

import numpy as np

from bench import apkf_linearity


def test_draws_in_correlation_coordinates_keep_a_badly_scaled_ps_small_covariances():
    """A P whose 1 sigma span 1e-9 to 1 (a wheel's inertia against its speed) with a strong correlation between its
    smallest pair: the draws' correlation is P's, which a factorisation of P itself rounds away."""
    s = np.array([1.0, 3e-9, 2e-9, 0.5])
    R = np.array([[1.0, 0.02, 0.01, 0.3], [0.02, 1.0, -0.999, 0.0], [0.01, -0.999, 1.0, 0.0], [0.3, 0.0, 0.0, 1.0]])
    P = R * np.outer(s, s)
    D = apkf_linearity._draws(P, 200000, np.random.default_rng(1))
    C = np.corrcoef(D.T)
    assert abs(C[1, 2] + 0.999) < 2e-4 and np.allclose(C, R, atol=0.01)
    assert np.allclose(D.std(axis=0) / s, 1.0, atol=0.01)
