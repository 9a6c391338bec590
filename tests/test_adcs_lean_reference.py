"""The flight STKF's and the Joseph update's restructured loops (instruction budget: slices, one
triangle, only the nodes an update touches, buffers read once) against plain dense numpy computations of the
same equations, call by call; and linalg's written-out sums (m = 3, 6) against the element-by-element loops, bit
for bit."""

import numpy as np
import pytest

from firmware.adcs import linalg
from firmware.adcs import stkf_lean as S
from ground.adcs.lean_scenario import stkf_scenario

N = 6


def _joseph_ref(P, r0, R):
    n, m = P.shape[0], R.shape[0]
    H = np.zeros((m, n))
    H[:, r0:r0 + m] = np.eye(m)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    IKH = np.eye(n) - K @ H
    return IKH @ P @ IKH.T + K @ R @ K.T, K


@pytest.mark.parametrize("n,r0,m", [(9, 0, 3), (6, 0, 6), (9, 3, 4), (5, 4, 1)])
def test_joseph_select_equals_the_dense_joseph_form(n, r0, m):
    """linalg.joseph_select (Eq. 4.140, 4.142 with H = [0 I 0]) against K = P H^T S^-1, (I - K H) P (.)^T + K R K^T."""
    rng = np.random.default_rng(n * 10 + m)
    A, B = rng.normal(size=(n, n)), rng.normal(size=(m, m))
    P0, R0 = A @ A.T + 0.1 * np.eye(n), B @ B.T + 0.1 * np.eye(m)
    P, R = list(P0.ravel()), list(R0.ravel())
    Kt, L, W, RK = [0.0] * (m * n), [0.0] * (m * m), [0.0] * (n * n), [0.0] * (m * n)
    assert linalg.joseph_select(P, n, r0, m, R, Kt, L, W, RK)
    Pr, K = _joseph_ref(P0, r0, R0)
    P = np.reshape(P, (n, n))
    assert np.array_equal(P, P.T)
    assert np.allclose(P, Pr, rtol=1e-10, atol=1e-12 * np.abs(Pr).max())
    assert np.allclose(np.reshape(Kt, (m, n)).T, K, rtol=1e-10, atol=1e-12)
    bad = list(P0.ravel())
    assert not linalg.joseph_select(bad, n, r0, m, list((-R0).ravel() - 1e3 * np.eye(m).ravel()), Kt, L, W, RK)
    assert bad == list(P0.ravel())                          # refused: P untouched


def test_row_kernels_equal_dense_products():
    """rows_mul_mirror (P0j = F P_src,j, mirrored), sandwich from another block, and _shift (a node slot opened,
    the others moved one place older) against numpy on a 30 x 30 buffer."""
    rng = np.random.default_rng(3)
    ld = 30
    A = rng.normal(size=(ld, ld))
    P0 = A @ A.T
    F, Q = rng.normal(size=(6, 6)), np.diag(rng.uniform(1, 2, 6))
    for src in (0, 6):
        P = list(P0.ravel())
        S.rows_mul_mirror(P, ld, src, 6, 24, list(F.ravel()))
        P = np.reshape(P, (ld, ld))
        ref = F @ P0[src:src + 6, 6:24]
        assert np.allclose(P[0:6, 6:24], ref, rtol=1e-12) and np.array_equal(P[6:24, 0:6], P[0:6, 6:24].T)
        assert np.array_equal(P[6:, 6:], P0[6:, 6:]) and np.array_equal(P[24:, :6], P0[24:, :6])
        P = list(P0.ravel())
        S.sandwich(P, ld, 0, list(F.ravel()), list(Q.ravel()), [0.0] * 36, src)
        P = np.reshape(P, (ld, ld))
        assert np.allclose(P[0:6, 0:6], F @ P0[src:src + 6, src:src + 6] @ F.T + Q, rtol=1e-12)
        assert np.array_equal(P[0:6, 0:6], P[0:6, 0:6].T)
    f = S.LeanStkf([7e6, 0, 0, 0, 7.5e3, 0] * 2, [1.0] * 12, 0.0, 4.0, cap=5, qa=0.01)
    for k, pos in ((3, 0), (3, 1), (4, 2), (5, 0)):
        P0 = rng.normal(size=(f.ld, f.ld))
        f.P, f.k, f.X, f.t = list(P0.ravel()), k, list(range(f.ld)), list(range(f.cap))
        f._shift(pos)
        kk = min(k, f.cap - 1)
        old = list(range(kk * N))
        new = [i if i < pos * N else i + N for i in old]
        P = np.reshape(f.P, (f.ld, f.ld))
        assert f.k == kk + 1 and np.array_equal(P[np.ix_(new, new)], P0[np.ix_(old, old)])
        assert f.X[:pos * N] == old[:pos * N] and f.X[(pos + 1) * N:(kk + 1) * N] == old[pos * N:]


def _snap(f):
    m = f.k * N
    return (list(f.t[:f.k]), np.array(f.X[:m]), np.array(f.P).reshape(f.ld, f.ld)[:m, :m].copy(),
            np.array(f.xa), np.array(f.Pa).reshape(6, 6))


def _phi(x, dt):
    F = [0.0] * 36
    S.phi(F, list(x), 0, dt)
    return np.reshape(F, (6, 6))


def _f(x, dt):
    x = list(x)
    S.f(x, 0, dt)
    return np.array(x)


def _q(dt, qa):
    Q = [0.0] * 36
    S.process_noise(Q, dt, qa)
    return np.reshape(Q, (6, 6))


def _ref_predict(b, dt, qa, k_after):
    t, X, P, xa, Pa = b
    Fa = _phi(xa, dt)
    F = _phi(X[0:6], dt)
    keep = (k_after - 1) * N
    Pn = np.zeros((keep + N, keep + N))
    Pn[N:, N:] = P[:keep, :keep]
    Pn[0:N, N:] = F @ P[0:N, :keep]
    Pn[N:, 0:N] = Pn[0:N, N:].T
    Pn[0:N, 0:N] = F @ P[0:N, 0:N] @ F.T + _q(dt, qa)
    return (np.concatenate([_f(X[0:6], dt), X[:keep]]), Pn, _f(xa, dt), Fa @ Pa @ Fa.T + _q(dt, qa))


def _ref_satb(b, z, R, tm, qa, tol):
    """Eq. 5.24 on every node with the generated node b as a measurement of a and c (Eq. 5.46-5.52), dense."""
    t, X, P, _, _ = b
    m = len(X)
    i = next(i for i in range(len(t)) if abs(t[i] - tm) <= tol or t[i] < tm)
    H = np.zeros((N, m))
    if abs(t[i] - tm) <= tol:
        H[:, i * N:(i + 1) * N] = np.eye(N)
        h, Re = X[i * N:(i + 1) * N], R
    else:
        a, c = i, i - 1
        dt_a, dt_b = tm - t[a], t[c] - tm
        Fa, xb = _phi(X[a * N:a * N + N], dt_a), _f(X[a * N:a * N + N], dt_a)
        Fb, xc = _phi(xb, dt_b), _f(X[c * N:c * N + N], -dt_b)
        Qa, Qb = _q(dt_a, qa), _q(dt_b, qa)
        B = Qa @ Fb.T @ np.linalg.inv(Fb @ Qa @ Fb.T + Qb)
        H[:, a * N:a * N + N] = (np.eye(N) - B @ Fb) @ Fa
        H[:, c * N:c * N + N] = B
        h, Re = xb + B @ Fb @ (xc - xb), R + (np.eye(N) - B @ Fb) @ Qa
    Sm = H @ P @ H.T + Re
    K = P @ H.T @ np.linalg.inv(Sm)
    return X + K @ (np.asarray(z) - h), P - K @ Sm @ K.T


def _ref_beacon(b, y, q, P_att, sigma_b):
    """Eq. 5.13-5.17 on SatB's current node, rA and the attitude error as noise (Sec. 5.3.3), zero gain on the
    older nodes (Joseph form on node 0, (I - K H) P0j)."""
    from emulator.spacecraft.dynamics import dcm
    t, X, P, xa, Pa = b
    q = np.asarray(q) / np.linalg.norm(q)
    A = dcm(q)
    d = X[0:3] - xa[0:3]
    rho = np.linalg.norm(d)
    u = d / rho
    Hb = A @ (np.eye(3) - np.outer(u, u)) / rho
    yx = np.array([[0, -y[2], y[1]], [y[2], 0, -y[0]], [-y[1], y[0], 0]])
    R = sigma_b ** 2 * np.eye(3) + yx @ np.reshape(P_att, (3, 3)) @ yx.T + Hb @ Pa[0:3, 0:3] @ Hb.T
    H = np.zeros((3, N))
    H[:, 0:3] = Hb
    K = P[0:N, 0:N] @ H.T @ np.linalg.inv(H @ P[0:N, 0:N] @ H.T + R)
    IKH = np.eye(N) - K @ H
    Xn, Pn = X.copy(), P.copy()
    Xn[0:N] += K @ (np.asarray(y) - A @ u)
    Pn[0:N, N:] = IKH @ P[0:N, N:]
    Pn[N:, 0:N] = Pn[0:N, N:].T
    Pn[0:N, 0:N] = IKH @ P[0:N, 0:N] @ IKH.T + K @ R @ K.T
    return Xn, Pn


def _close(a, b, what):
    scale = np.abs(b).max()
    assert np.allclose(a, b, rtol=1e-8, atol=1e-9 * scale), (what, np.abs(a - b).max(), scale)


def test_lean_stkf_calls_equal_dense_references_with_satb_and_the_beacon(monkeypatch):
    """Every predict, GNSS (SatA now, SatB delayed: the update over nodes 0 .. a, then the pruning) and beacon
    call of the lean STKF over 40 s of Case 2 inputs (float64 buffers) against the dense equations on the whole
    node list, marginalised to the nodes the filter keeps."""
    monkeypatch.setattr(linalg, "zeros", lambda n: [0.0] * n)
    sc = stkf_scenario(40, case=2)
    f = S.LeanStkf(sc["x0"], sc["P0"], 0.0)
    R = np.reshape(sc["R"], (6, 6))
    Rl, Patt = list(sc["R"]), list(sc["P_att"])
    n_b = 0
    for k, st in enumerate(sc["steps"]):
        if k > 0:
            b = _snap(f)
            f.predict(st["t"])
            Xr, Pr, xar, Par = _ref_predict(b, st["t"] - b[0][0], f.qa, f.k)
            a = _snap(f)
            _close(a[1], Xr, "predict X")
            _close(a[2], Pr, "predict P")
            _close(a[3], xar, "predict xa")
            _close(a[4], Par, "predict Pa")
        b = _snap(f)
        f.update_gnss(st["za"], Rl, 0)
        Par, K = _joseph_ref(b[4], 0, R)
        a = _snap(f)
        _close(a[4], Par, "gnss A P")
        _close(a[3], b[3] + K @ (np.asarray(st["za"]) - b[3]), "gnss A x")
        b = _snap(f)
        f.update_beacon(st["y"], st["q"], Patt, sc["sigma_b"])
        Xr, Pr = _ref_beacon(b, st["y"], st["q"], Patt, sc["sigma_b"])
        a = _snap(f)
        _close(a[1], Xr, "beacon X")
        _close(a[2], Pr, "beacon P")
        for tm, z in st["zb"]:
            b = _snap(f)
            f.update_gnss(z, Rl, 1, tm)
            Xr, Pr = _ref_satb(b, z, R, tm, f.qa, f.tol)
            a = _snap(f)
            m = f.k * N
            assert a[0] == b[0][:f.k]
            _close(a[1], Xr[:m], "satb X")
            _close(a[2], Pr[:m, :m], "satb P")
            n_b += 1
    assert n_b > 30 and f.generated == n_b


# --- the written-out sums (m = 3, 6) against linalg's element-by-element loops, bit for bit --------------
def _plain_joseph(P, n, r0, m, R, Kt, L, W, RK):
    """joseph_select with the loop forms throughout."""
    for i in range(m):
        for j in range(m):
            W[i * m + j] = P[(r0 + i) * n + r0 + j] + R[i * m + j]
    if not linalg._cholesky_loops(L, W, m):
        return False
    Kt[0:m * n] = P[r0 * n:(r0 + m) * n]
    linalg._solve_cols_loops(Kt, list(L), n, m)
    linalg._joseph_loops(P, n, r0, m, R, Kt, W, RK)
    return True


def _buf(v):
    return [float(x) for x in v]


def _zeros(n):
    return [0.0] * n


@pytest.mark.parametrize("n,r0,m", [(9, 0, 3), (9, 3, 3), (6, 0, 6), (12, 6, 6)])
def test_written_out_sums_equal_the_plain_loops_bit_for_bit(n, r0, m):
    """linalg's m = 3 and m = 6 paths (Joseph update, Cholesky, solve, products) give exactly what the
    element-by-element loops give: the same operations in the same order. Buffers of float64 (lists), so that
    any reordering shows in the last bit (a float32 store would round most of it away)."""
    rng = np.random.default_rng(7 * n + m)
    A, B = rng.normal(size=(n, n)), rng.normal(size=(m, m))
    P0, R0 = A @ A.T + 0.1 * np.eye(n), B @ B.T + 0.1 * np.eye(m)
    out = []
    for joseph in (linalg.joseph_select, _plain_joseph):
        P, Kt = _buf(P0.ravel()), _zeros(m * n)
        assert joseph(P, n, r0, m, _buf(R0.ravel()), Kt, _zeros(m * m), _zeros(n * n), _zeros(m * n))
        out.append((P, Kt))
    assert out[0] == out[1]
    L1, L2 = _zeros(m * m), _zeros(m * m)
    assert linalg.cholesky(L1, _buf(R0.ravel()), m) and linalg._cholesky_loops(L2, _buf(R0.ravel()), m)
    assert L1 == L2
    X1, X2 = _buf(A[:m].ravel()), _buf(A[:m].ravel())
    linalg._solve_cols(X1, L1, n, m)
    linalg._solve_cols_loops(X2, L2, n, m)
    assert X1 == X2
    C1, C2 = _zeros(n * n), _zeros(n * n)
    G = _buf(rng.normal(size=m * n))
    for bt in (False, True):
        (linalg.matmul_bt if bt else linalg.matmul)(C1, _buf(A[:, :m].ravel()), G, n, m, n)
        (linalg._matmul_bt_loops if bt else linalg._matmul_loops)(C2, _buf(A[:, :m].ravel()), G, n, m, n)
        assert C1 == C2
