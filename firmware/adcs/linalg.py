"""Small dense float routines for the flight filters, over preallocated flat row-major buffers.

A matrix is a flat buffer (``array('f')`` on the flight computer) with its dimensions passed alongside:
element (i, j) of an n x m matrix A is ``A[i * m + j]``. Every routine writes into a destination the caller
allocated once. Floats are still boxed objects on most MicroPython ports, so the arithmetic itself allocates a
bounded amount per call (measured per 1 Hz cycle by tests/mp/firmware_adcs.py); so does every read of a float
from an array, which is why an input read many times is read once into a short list (same values, the same
products in the same order: results equal to the element-by-element form, bit for bit).

``zeros(n)`` is the only constructor; a test may replace it (``linalg.zeros = ...``) with a buffer of
numpy.float32 scalars to run the same code in float32 arithmetic under CPython.
"""

from array import array
import math


def zeros(n):
    """A float32 buffer of n zeros (the storage the flight code uses)."""
    return array("f", bytes(4 * n))


def fill(A, n, v=0.0):
    for i in range(n):
        A[i] = v


def copy(D, S, n):
    for i in range(n):
        D[i] = S[i]


def eye(A, n):
    """A = I (n x n)."""
    for i in range(n * n):
        A[i] = 0.0
    for i in range(n):
        A[i * n + i] = 1.0


def matmul(C, A, B, n, m, p):
    """C (n x p) = A (n x m) B (m x p); C must not alias A or B."""
    A, B = list(A[0:n * m]), list(B[0:m * p])    # read once (a buffer read is a new float on MicroPython)
    for i in range(n):
        ia = i * m
        ic = i * p
        for j in range(p):
            s = 0.0
            k2 = j
            for k in range(ia, ia + m):
                s += A[k] * B[k2]
                k2 += p
            C[ic + j] = s


def matmul_bt(C, A, B, n, m, p):
    """C (n x p) = A (n x m) B^T, B being p x m; C must not alias A or B."""
    A, B = list(A[0:n * m]), list(B[0:p * m])
    for i in range(n):
        ia = i * m
        ic = i * p
        for j in range(p):
            s = 0.0
            jb = j * m
            for k in range(m):
                s += A[ia + k] * B[jb + k]
            C[ic + j] = s


def symmetrize(P, n):
    """P = (P + P^T) / 2."""
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i * n + j] + P[j * n + i])
            P[i * n + j] = v
            P[j * n + i] = v


def cholesky(L, A, n):
    """Lower Cholesky factor L (n x n) of the symmetric A; returns False (L undefined) unless A is positive
    definite. L may alias nothing."""
    for i in range(n * n):
        L[i] = 0.0
    for j in range(n):
        s = A[j * n + j]
        for k in range(j):
            s -= L[j * n + k] * L[j * n + k]
        if not s > 0.0:                          # also catches NaN
            return False
        d = math.sqrt(s)
        L[j * n + j] = d
        for i in range(j + 1, n):
            s = A[i * n + j]
            for k in range(j):
                s -= L[i * n + k] * L[j * n + k]
            L[i * n + j] = s / d
    return True


def chol_solve_rows(X, L, B, n, m):
    """X (m x n) = B (m x n) S^-1 for S = L L^T (n x n): each row b of B solves S x = b (S symmetric).
    X may alias B."""
    L = list(L[0:n * n])
    for r in range(m):
        o = r * n
        for i in range(n):                       # forward: L y = b
            s = B[o + i]
            for k in range(i):
                s -= L[i * n + k] * X[o + k]
            X[o + i] = s / L[i * n + i]
        for i in range(n - 1, -1, -1):           # back: L^T x = y
            s = X[o + i]
            for k in range(i + 1, n):
                s -= L[k * n + i] * X[o + k]
            X[o + i] = s / L[i * n + i]


def joseph_select(P, n, r0, m, R, Kt, L, W, RK):
    """Kalman gain and Joseph-form covariance update for a measurement of the error states r0 .. r0+m-1,
    H = [0 I_m 0] (the star tracker's H of Eq. 4.139, the GNSS's of Eq. 5.31):

        S = H P H^T + R,  K = P H^T S^-1,  P+ = (I - K H) P (I - K H)^T + K R K^T     (Eq. 4.140, 4.142)

    with R (m x m, symmetric). Writes K^T into Kt (m x n) and returns False (P untouched) when S is not
    positive definite. L (m x m), W (n x n) and RK (m x n) are work buffers. P is kept exactly symmetric."""
    for i in range(m):                           # S = P[r0:, r0:] + R into W's first m*m slots
        for j in range(m):
            W[i * m + j] = P[(r0 + i) * n + r0 + j] + R[i * m + j]
    if not cholesky(L, W, m):
        return False
    for i in range(m):                           # Kt = S^-1 H P = S^-1 P[r0:r0+m, :]
        for j in range(n):
            Kt[i * n + j] = P[(r0 + i) * n + j]
    _solve_cols(Kt, L, n, m)
    # Buffers read many times are read once into lists (each buffer read makes a new float on MicroPython);
    # a list holds what the buffer holds, so every product below is the one the buffers gave.
    if m == 3:
        _joseph3(P, n, r0, R, Kt, W, RK)
        return True
    K = list(Kt)
    Hp = list(P[r0 * n:(r0 + m) * n])             # H P = P[r0:r0+m, :]
    # A = (I - K H) P = P - K P[r0:, :]  into W
    for i in range(n):
        for j in range(n):
            s = P[i * n + j]
            for k in range(m):
                s -= K[k * n + i] * Hp[k * n + j]
            W[i * n + j] = s
    matmul(RK, R, K, m, m, n)                    # R K^T into RK (K holds Kt, m x n)
    Wl, RKl = list(W), list(RK)
    # P+ = A (I - K H)^T + K R K^T = A - A[:, r0:] K^T + K R K^T, upper triangle mirrored
    for i in range(n):
        for j in range(i, n):
            s = Wl[i * n + j]
            for k in range(m):
                s += K[k * n + i] * RKl[k * n + j] - Wl[i * n + r0 + k] * K[k * n + j]
            P[i * n + j] = s
            P[j * n + i] = s
    return True


def _joseph3(P, n, r0, R, Kt, W, RK):
    """joseph_select's last two steps for m = 3 (the star tracker, the beacon), the sums over k written out:
    the same operations in the same order (a loop iteration costs MicroPython as much as a float operation)."""
    K0, K1, K2 = list(Kt[0:n]), list(Kt[n:2 * n]), list(Kt[2 * n:3 * n])
    H0, H1, H2 = list(P[r0 * n:(r0 + 1) * n]), list(P[(r0 + 1) * n:(r0 + 2) * n]), list(P[(r0 + 2) * n:(r0 + 3) * n])
    for i in range(n):                           # A = (I - K H) P = P - K P[r0:, :]  into W
        k0, k1, k2 = K0[i], K1[i], K2[i]
        o = i * n
        row = list(P[o:o + n])
        for j in range(n):
            W[o + j] = row[j] - k0 * H0[j] - k1 * H1[j] - k2 * H2[j]
    matmul(RK, R, Kt, 3, 3, n)                   # R K^T into RK
    R0, R1, R2 = list(RK[0:n]), list(RK[n:2 * n]), list(RK[2 * n:3 * n])
    Wl = list(W[0:n * n])
    for i in range(n):                           # P+ = A - A[:, r0:] K^T + K R K^T, upper triangle mirrored
        k0, k1, k2 = K0[i], K1[i], K2[i]
        o = i * n
        w0, w1, w2 = Wl[o + r0], Wl[o + r0 + 1], Wl[o + r0 + 2]
        for j in range(i, n):
            s = Wl[o + j] + (k0 * R0[j] - w0 * K0[j]) + (k1 * R1[j] - w1 * K1[j]) + (k2 * R2[j] - w2 * K2[j])
            P[o + j] = s
            P[j * n + i] = s


def _solve_cols(X, L, n, m):
    """X (m x n) = S^-1 X for S = L L^T (m x m), column by column."""
    L = list(L[0:m * m])
    if m == 3:                                   # the same operations and float32 stores, written out
        l00, _, _, l10, l11, _, l20, l21, l22 = L
        n2 = 2 * n
        for c in range(n):
            X[c] = X[c] / l00
            X[n + c] = (X[n + c] - l10 * X[c]) / l11
            X[n2 + c] = (X[n2 + c] - l20 * X[c] - l21 * X[n + c]) / l22
            X[n2 + c] = X[n2 + c] / l22
            X[n + c] = (X[n + c] - l21 * X[n2 + c]) / l11
            X[c] = (X[c] - l10 * X[n + c] - l20 * X[n2 + c]) / l00
        return
    for c in range(n):
        for i in range(m):
            s = X[i * n + c]
            for k in range(i):
                s -= L[i * m + k] * X[k * n + c]
            X[i * n + c] = s / L[i * m + i]
        for i in range(m - 1, -1, -1):
            s = X[i * n + c]
            for k in range(i + 1, m):
                s -= L[k * m + i] * X[k * n + c]
            X[i * n + c] = s / L[i * m + i]
