"""The STKF step's speed work (the preallocated smoother, per-satellite node interpolation, fewer numpy
calls) computes what the code before it computed.

1. ``tests/data/stkf_step_reference.npz`` was written by the code of commit b2c87c3 (before the speed work):
   ``stkf_sim.simulate(case, 60.0, seed=4, truth="two-body", ...)`` for the runs in ``RUNS`` below, keeping
   the history (error, 1 sigma, pointing error and 1 sigma at every step) and the smoother's final nodes
   (times, X, joint P). The runs cover every update path of a step: SatA's GNSS with the beacon, each alone
   (outages), and SatB's delayed GNSS between nodes.
2. The per-satellite OOSM path (``Afls(parts=...)``, ``update(part=...)``, ``keep_generated=False``) against
   the module's textbook functions on the full 12-state node: generate node b (Eq. 5.46-5.52), plug it in,
   update every node (Eq. 5.24), then marginalise b out (delete its rows and columns).
"""

import os

import numpy as np
import pytest

from emulator import orbits
from ground.adcs import afls, stkf, stkf_sim

REF = os.path.join(os.path.dirname(__file__), "data", "stkf_step_reference.npz")
RUNS = {"c1": dict(case=1, duration_s=60.0, seed=4),
        "c2": dict(case=2, duration_s=60.0, seed=4, outages=("beacon:20:25", "gnss_a:30:34", "relay:40:46"))}


@pytest.mark.parametrize("name", sorted(RUNS))
def test_simulation_equals_the_recorded_run_of_the_code_before(name, monkeypatch):
    got = []

    class Rec(afls.Afls):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            got.append(self)

    monkeypatch.setattr(stkf_sim, "Afls", Rec)
    r, h = stkf_sim.simulate(truth="two-body", **RUNS[name])
    flt = got[0]
    with np.load(REF) as ref:
        ref = {k[len(name) + 1:]: ref[k] for k in ref.files if k.startswith(name + "_")}
    assert flt.t == ref["t"].tolist()
    # measured: Case 1 equal to the last bit; Case 2 (a different but equal algebra for the OOSM) within 1e-8 m,
    # 1e-9 relative on the sigmas and 3e-12 of sqrt(P_ii P_jj) on the joint P: the tolerances leave ~100x margin
    np.testing.assert_allclose(h["err"], ref["err"], rtol=0, atol=1e-6)            # m, m/s
    np.testing.assert_allclose(h["sig"], ref["sig"], rtol=1e-7, atol=0)
    np.testing.assert_allclose(h["perr"], ref["perr"], rtol=0, atol=1e-6)          # arcsec
    np.testing.assert_allclose(h["psig"], ref["psig"], rtol=1e-7, atol=0)
    np.testing.assert_allclose(flt.X, ref["X"], rtol=0, atol=1e-6)
    d = np.sqrt(np.diag(ref["P"]))
    assert np.all(np.abs(flt.P - ref["P"]) <= 1e-9 * np.outer(d, d))
    assert r["oosm_nodes_generated"] == (0 if name == "c1" else 52)


def _kf_update(X, P, cols, z, R):
    """Eq. 5.24 with C = [0 .. I .. 0] on ``cols``: K = P C^T S^-1, X + K (z - C X), P - K S K^T."""
    S = P[np.ix_(cols, cols)] + R
    K = P[:, cols] @ np.linalg.inv(S)
    return X + K @ (z - X[cols]), P - K @ S @ K.T


def test_one_satellite_oosm_equals_generating_updating_and_dropping_the_full_node():
    """SatB's delayed GNSS through ``update(part=SAT_B)`` (node b interpolated for SatB alone, never stored)
    equals the textbook sequence on the whole 12-state node, written out here: node b from Eq. 5.46-5.52
    (x_b, P_bb of Eq. 5.41, P_bj of Eq. 5.42), plugged in, Eq. 5.24 on every node, then b marginalised out."""
    t_s, xs = orbits.truth_samples("two-body", 30.0)
    rng = np.random.default_rng(11)
    R = np.diag([30.0 ** 2] * 3 + [1.0] * 3)
    P0 = np.diag(np.repeat([100.0 ** 2, 0.5 ** 2, 100.0 ** 2, 0.5 ** 2], 3))
    x0 = xs[0].ravel() + np.sqrt(np.diag(P0)) * rng.standard_normal(12)
    lag, n = 4.0, 12
    flt = afls.Afls(x0, P0, 0.0, lag, stkf.f, stkf.Phi, stkf.Q, keep_generated=False, parts=stkf.PARTS)
    X, P, t = x0.copy(), P0.copy(), [0.0]
    I6 = np.eye(6)
    A_cols, B_cols = np.arange(0, 6), np.arange(6, 12)
    for k in range(1, 26):
        flt.predict(float(k))
        ph = stkf.Phi(X[:n], 1.0)                                   # Eq. 5.20-5.22
        Pn = np.zeros((P.shape[0] + n,) * 2)
        Pn[:n, :n] = ph @ P[:n, :n] @ ph.T + stkf.Q(1.0)
        Pn[:n, n:] = ph @ P[:n, :]
        Pn[n:, :n] = Pn[:n, n:].T
        Pn[n:, n:] = P
        X, P, t = np.concatenate([stkf.f(X[:n], 1.0), X]), Pn, [float(k)] + t
        keep = next((i + 1 for i, ti in enumerate(t) if ti < k - lag - 1e-9), len(t))
        X, P, t = X[:keep * n], P[:keep * n, :keep * n], t[:keep]
        za = xs[k, 0] + np.sqrt(np.diag(R)) * rng.standard_normal(6)
        flt.update(za, R, lambda x: (x, I6), part=stkf.SAT_A)
        X, P = _kf_update(X, P, A_cols, za, R)
        if k < 4:
            continue
        tm = k - 2.0 - rng.uniform(0.05, 0.95)                       # between nodes, 2-3 s late
        zb = stkf.f(xs[int(tm), 1], tm - int(tm)) + np.sqrt(np.diag(R)) * rng.standard_normal(6)
        flt.update(zb, R, lambda x: (x, I6), t=tm, part=stkf.SAT_B)
        i = next(i for i, ti in enumerate(t) if ti < tm)            # a = i (older), c = i - 1
        dt_a, dt_b = tm - t[i], t[i - 1] - tm
        sa, sc = slice(i * n, (i + 1) * n), slice((i - 1) * n, i * n)
        xa, xc = X[sa], X[sc]
        Fa, Fb = stkf.Phi(xa, dt_a), stkf.Phi(stkf.f(xa, dt_a), dt_b)           # Eq. 5.46-5.48
        Qa = stkf.Q(dt_a)
        B = Qa @ Fb.T @ np.linalg.inv(Fb @ Qa @ Fb.T + stkf.Q(dt_b))
        A = (np.eye(n) - B @ Fb) @ Fa
        N = (np.eye(n) - B @ Fb) @ Qa
        xb = stkf.f(xa, dt_a) + B @ Fb @ (stkf.f(xc, -dt_b) - stkf.f(xa, dt_a))  # Eq. 5.49-5.52
        row = A @ P[sa, :] + B @ P[sc, :]                                        # Eq. 5.42
        Pbb = A @ P[sa, sa] @ A.T + B @ P[sc, sc] @ B.T + A @ P[sa, sc] @ B.T + B @ P[sc, sa] @ A.T + N
        k0 = i * n                                                               # plug b in at index i
        X = np.concatenate([X[:k0], xb, X[k0:]])
        P = np.block([[P[:k0, :k0], row[:, :k0].T, P[:k0, k0:]],
                      [row[:, :k0], Pbb, row[:, k0:]],
                      [P[k0:, :k0], row[:, k0:].T, P[k0:, k0:]]])
        X, P = _kf_update(X, P, k0 + B_cols, zb, R)
        X, P = np.delete(X, np.s_[k0:k0 + n]), np.delete(np.delete(P, np.s_[k0:k0 + n], 0), np.s_[k0:k0 + n], 1)
        assert flt.t == t
        d = np.sqrt(np.diag(P))
        np.testing.assert_allclose(flt.X, X, rtol=1e-12, atol=1e-7)
        assert np.all(np.abs(flt.P - P) <= 1e-9 * np.outer(d, d))
    assert flt.generated == 22
    # the delayed data acted: SatB's position is known far better than from the prior alone
    assert np.sqrt(flt.P[6, 6]) < 0.2 * np.sqrt(P0[6, 6])


def test_parts_checked():
    x0, P0 = np.arange(12.0) * 1e6 + 7e6, np.eye(12)
    with pytest.raises(ValueError, match="overlap"):
        afls.Afls(x0, P0, 0.0, 4.0, stkf.f, stkf.Phi, stkf.Q, parts=(slice(0, 6), slice(3, 12)))
    with pytest.raises(ValueError, match="inside"):
        afls.Afls(x0, P0, 0.0, 4.0, stkf.f, stkf.Phi, stkf.Q, parts=(slice(6, 13),))
    flt = afls.Afls(x0, P0, 0.0, 4.0, stkf.f, stkf.Phi, stkf.Q, parts=stkf.PARTS)
    with pytest.raises(ValueError, match="not one of the model's parts"):
        flt.update(np.zeros(3), np.eye(3), lambda x: (x, np.eye(3)), part=slice(0, 3))
    np.testing.assert_array_equal(flt.x, x0)                  # refused: nothing changed


def test_the_reference_is_written_again_by_its_script(tmp_path):
    """tests/data/make_stkf_reference.py writes the recorded runs from the code as it is: the same keys and shapes,
    Case 1 to the bit, Case 2 within the tolerances above."""
    from tests.data import make_stkf_reference
    path = str(tmp_path / "ref.npz")
    make_stkf_reference.main(path)
    with np.load(REF) as ref, np.load(path) as new:
        assert sorted(ref.files) == sorted(new.files)
        for k in ref.files:
            assert ref[k].shape == new[k].shape, k
            if k.startswith("c1_"):
                assert np.array_equal(ref[k], new[k]), k
            else:
                np.testing.assert_allclose(new[k], ref[k], rtol=1e-7, atol=1e-6, err_msg=k)
