"""Small dense float routines for the flight filters, over preallocated flat row-major buffers.

A matrix is a flat buffer (``array('f')`` on the flight computer) with its dimensions passed alongside:
element (i, j) of an n x m matrix A is ``A[i * m + j]``. Every routine writes into a destination the caller
allocated once. Floats are still boxed objects on most MicroPython ports, so the arithmetic itself allocates a
bounded amount per call (measured per 1 Hz cycle by tests/mp/firmware_adcs.py); so does every read of a float
from an array, which is why an input read many times is read once into a short list (same values, the same
products in the same order: results equal to the element-by-element form, bit for bit). A loop iteration costs
MicroPython about as much as a float operation, so the hot sizes have their inner sums written out (the Joseph
update and the column solve for m = 3 and 6, the Cholesky factor for n = 3, the products with an inner size of
6), and the routines are compiled by the native emitter (``@micropython.native``; ``micropython`` here
is CPython's no-op stand-in for the other flight modules too). Native code is larger than bytecode: frozen into
flash on a board (bench/bench_adcs_can.py reports both sizes). A port built without the native emitter refuses
the decorator at compile time; there the decorator lines are dropped (bench_adcs_can's bytecode-only figure).
The element-by-element forms (``_*_loops``) serve the other sizes and are what the written-out paths equal,
bit for bit (tests/test_adcs_lean_reference.py).

``zeros(n)`` is the only constructor; a test may replace it (``linalg.zeros = ...``) with a buffer of
numpy.float32 scalars to run the same code in float32 arithmetic under CPython.
"""

from array import array
import math

try:
    import micropython
except ImportError:                     # CPython: no native emitter
    class micropython:
        native = staticmethod(lambda fn: fn)


def zeros(n):
    """A float32 buffer of n zeros (the storage the flight code uses)."""
    return array("f", bytes(4 * n))


def fill(A, n, v=0.0):
    for i in range(n):
        A[i] = v


@micropython.native
def matmul(C, A, B, n, m, p):
    """C (n x p) = A (n x m) B (m x p); C must not alias A or B."""
    A, B = list(A[0:n * m]), list(B[0:m * p])    # read once (a buffer read is a new float on MicroPython)
    if m == 6:                                   # the STKF's 6 x 6 blocks: the inner sum written out
        _dot6(C, A, [B[j::p] for j in range(p)], n, p)        # (B's columns)
        return
    _matmul_loops(C, A, B, n, m, p)


@micropython.native
def _dot6(C, A, V, n, p):
    """C[i, j] = A[i, 0:6] . V[j] for i < n, j < p (A n x 6 and V p vectors of 6, lists): ``matmul`` and
    ``matmul_bt`` with m = 6, the inner sum written out."""
    for i in range(n):
        a0, a1, a2, a3, a4, a5 = A[i * 6:i * 6 + 6]
        ic = i * p
        for j in range(p):
            b0, b1, b2, b3, b4, b5 = V[j]
            C[ic + j] = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 + a4 * b4 + a5 * b5


@micropython.native
def _matmul_loops(C, A, B, n, m, p):
    """matmul element by element (any m; the written-out paths give exactly this)."""
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


@micropython.native
def matmul_bt(C, A, B, n, m, p):
    """C (n x p) = A (n x m) B^T, B being p x m; C must not alias A or B."""
    A, B = list(A[0:n * m]), list(B[0:p * m])
    if m == 6:                                   # the inner sum written out
        _dot6(C, A, [B[j * 6:j * 6 + 6] for j in range(p)], n, p)    # (B's rows)
        return
    _matmul_bt_loops(C, A, B, n, m, p)


@micropython.native
def _matmul_bt_loops(C, A, B, n, m, p):
    """matmul_bt element by element."""
    for i in range(n):
        ia = i * m
        ic = i * p
        for j in range(p):
            s = 0.0
            jb = j * m
            for k in range(m):
                s += A[ia + k] * B[jb + k]
            C[ic + j] = s


@micropython.native
def symmetrize(P, n):
    """P = (P + P^T) / 2."""
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i * n + j] + P[j * n + i])
            P[i * n + j] = v
            P[j * n + i] = v


@micropython.native
def cholesky(L, A, n):
    """Lower Cholesky factor L (n x n) of the symmetric A; returns False (L undefined) unless A is positive
    definite. L may alias nothing."""
    if n == 3:                                   # written out: the same operations, stored values read back
        a00, _, _, a10, a11, _, a20, a21, a22 = A[0:9]
        if not a00 > 0.0:                        # also catches NaN
            return False
        d = math.sqrt(a00)
        L[0] = d
        L[1] = L[2] = L[5] = 0.0
        L[3] = a10 / d
        L[6] = a20 / d
        l10, l20 = L[3], L[6]
        s = a11 - l10 * l10
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        L[4] = d
        L[7] = (a21 - l20 * l10) / d
        l21 = L[7]
        s = a22 - l20 * l20 - l21 * l21
        if not s > 0.0:
            return False
        L[8] = math.sqrt(s)
        return True
    return _cholesky_loops(L, A, n)


@micropython.native
def _cholesky_loops(L, A, n):
    """cholesky element by element."""
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


@micropython.native
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


@micropython.native
def joseph_select(P, n, r0, m, R, Kt, L, W, RK):
    """Kalman gain and Joseph-form covariance update for a measurement of the error states r0 .. r0+m-1,
    H = [0 I_m 0] (the star tracker's H of Eq. 4.139, the GNSS's of Eq. 5.12):

        S = H P H^T + R,  K = P H^T S^-1,  P+ = (I - K H) P (I - K H)^T + K R K^T     (Eq. 4.140, 4.142)

    with R (m x m, symmetric). Writes K^T into Kt (m x n) and returns False (P untouched) when S is not
    positive definite. L (m x m), W (n x n) and RK (m x n) are work buffers. P is kept exactly symmetric."""
    for i in range(m):                           # S = P[r0:, r0:] + R into W's first m*m slots
        for j in range(m):
            W[i * m + j] = P[(r0 + i) * n + r0 + j] + R[i * m + j]
    if not cholesky(L, W, m):
        return False
    Kt[0:m * n] = P[r0 * n:(r0 + m) * n]         # Kt = S^-1 H P = S^-1 P[r0:r0+m, :]
    _solve_cols(Kt, L, n, m)
    # Buffers read many times are read once into lists (each buffer read makes a new float on MicroPython);
    # a list holds what the buffer holds, so every product below is the one the buffers gave.
    if m == 3:
        _joseph3(P, n, r0, R, Kt, W, RK)
        return True
    if m == 6:
        _joseph6(P, n, r0, R, Kt, W, RK)
        return True
    _joseph_loops(P, n, r0, m, R, Kt, W, RK)
    return True


@micropython.native
def _joseph_loops(P, n, r0, m, R, Kt, W, RK):
    """joseph_select's last two steps element by element (any m)."""
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


@micropython.native
def _joseph3(P, n, r0, R, Kt, W, RK):
    """joseph_select's last two steps for m = 3 (the star tracker), the sums over k written out:
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


@micropython.native
def _joseph6(P, n, r0, R, Kt, W, RK):
    """joseph_select's last two steps for m = 6 (SatA's GNSS), written out as ``_joseph3``."""
    K0, K1, K2, K3, K4, K5 = [list(Kt[k * n:(k + 1) * n]) for k in range(6)]
    H0, H1, H2, H3, H4, H5 = [list(P[(r0 + k) * n:(r0 + k + 1) * n]) for k in range(6)]
    for i in range(n):                           # A = (I - K H) P = P - K P[r0:, :]  into W
        k0, k1, k2, k3, k4, k5 = K0[i], K1[i], K2[i], K3[i], K4[i], K5[i]
        o = i * n
        row = list(P[o:o + n])
        for j in range(n):
            W[o + j] = (row[j] - k0 * H0[j] - k1 * H1[j] - k2 * H2[j] - k3 * H3[j] - k4 * H4[j]
                        - k5 * H5[j])
    matmul(RK, R, Kt, 6, 6, n)                   # R K^T into RK
    R0, R1, R2, R3, R4, R5 = [list(RK[k * n:(k + 1) * n]) for k in range(6)]
    Wl = list(W[0:n * n])
    for i in range(n):                           # P+ = A - A[:, r0:] K^T + K R K^T, upper triangle mirrored
        k0, k1, k2, k3, k4, k5 = K0[i], K1[i], K2[i], K3[i], K4[i], K5[i]
        o = i * n
        w0, w1, w2, w3, w4, w5 = Wl[o + r0:o + r0 + 6]
        for j in range(i, n):
            s = (Wl[o + j] + (k0 * R0[j] - w0 * K0[j]) + (k1 * R1[j] - w1 * K1[j]) + (k2 * R2[j] - w2 * K2[j])
                 + (k3 * R3[j] - w3 * K3[j]) + (k4 * R4[j] - w4 * K4[j]) + (k5 * R5[j] - w5 * K5[j]))
            P[o + j] = s
            P[j * n + i] = s


@micropython.native
def _solve_cols(X, L, n, m):
    """X (m x n) = S^-1 X for S = L L^T (m x m), column by column."""
    L = list(L[0:m * m])
    if m == 3:                                   # the same, each stored (float32) value read back once
        l00, _, _, l10, l11, _, l20, l21, l22 = L
        n2 = 2 * n
        for c in range(n):
            i1, i2 = n + c, n2 + c
            X[c] = X[c] / l00
            x0 = X[c]
            X[i1] = (X[i1] - l10 * x0) / l11
            x1 = X[i1]
            X[i2] = (X[i2] - l20 * x0 - l21 * x1) / l22
            X[i2] = X[i2] / l22
            x2 = X[i2]
            X[i1] = (x1 - l21 * x2) / l11
            x1 = X[i1]
            X[c] = (x0 - l10 * x1 - l20 * x2) / l00
        return
    if m == 6:                                   # the same, each stored (float32) value read back once
        l00, _, _, _, _, _, l10, l11, _, _, _, _, l20, l21, l22, _, _, _ = L[0:18]
        l30, l31, l32, l33, _, _, l40, l41, l42, l43, l44, _, l50, l51, l52, l53, l54, l55 = L[18:36]
        for c in range(n):
            i1, i2, i3, i4, i5 = n + c, 2 * n + c, 3 * n + c, 4 * n + c, 5 * n + c
            X[c] = X[c] / l00
            x0 = X[c]
            X[i1] = (X[i1] - l10 * x0) / l11
            x1 = X[i1]
            X[i2] = (X[i2] - l20 * x0 - l21 * x1) / l22
            x2 = X[i2]
            X[i3] = (X[i3] - l30 * x0 - l31 * x1 - l32 * x2) / l33
            x3 = X[i3]
            X[i4] = (X[i4] - l40 * x0 - l41 * x1 - l42 * x2 - l43 * x3) / l44
            x4 = X[i4]
            X[i5] = (X[i5] - l50 * x0 - l51 * x1 - l52 * x2 - l53 * x3 - l54 * x4) / l55
            x5 = X[i5]
            X[i5] = x5 / l55
            x5 = X[i5]
            X[i4] = (x4 - l54 * x5) / l44
            x4 = X[i4]
            X[i3] = (x3 - l43 * x4 - l53 * x5) / l33
            x3 = X[i3]
            X[i2] = (x2 - l32 * x3 - l42 * x4 - l52 * x5) / l22
            x2 = X[i2]
            X[i1] = (x1 - l21 * x2 - l31 * x3 - l41 * x4 - l51 * x5) / l11
            x1 = X[i1]
            X[c] = (x0 - l10 * x1 - l20 * x2 - l30 * x3 - l40 * x4 - l50 * x5) / l00
        return
    _solve_cols_loops(X, L, n, m)


@micropython.native
def _solve_cols_loops(X, L, n, m):
    """_solve_cols element by element (L a list)."""
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


# The C kernels (firmware/adcs/native/adcsk.c, built by ``make natmod`` into firmware/adcs/adcsk.mpy): these
# functions and the filters' hot loops, the same operations in the same order over the same buffers, so the
# results are equal bit for bit (tests/test_adcs_natmod.py), and no float is boxed. Where the module is not
# there (MicroPython without it) the Python forms above run; so they do where it was built for another arch or
# MicroPython version (the import raises ValueError: "incompatible .mpy"), the safe state. On CPython the same
# C is the extension firmware.adcs._adcsk (native/adcsk_cpython.c, built on install when a C compiler is there;
# tests/test_kernels_cpython.py), each kernel through ``either``; ``FPS_ADCS_KERNELS=python`` in the environment
# leaves the Python forms.
_cpython = False
try:
    from firmware.adcs import adcsk as kernels
except (ImportError, ValueError):
    try:
        import adcsk as kernels                   # a board's image: built in (tools/pil_build.py's ADCS board)
    except ImportError:
        try:
            from firmware.adcs import _adcsk as kernels
            _cpython = True
        except ImportError:
            kernels = None
if _cpython:
    import os
    if os.environ.get("FPS_ADCS_KERNELS", "").lower() == "python":     # the Python forms asked for (a bench)
        kernels, _cpython = None, False


def either(kernel, python):
    """The C ``kernel``, or its Python form ``python`` for a call the kernel refuses with a TypeError before it
    writes anything: an argument that is no float buffer, float or int (a test's ``zeros`` giving lists of
    floats or of numpy.float32, whose arithmetic only the Python form does). Under MicroPython the kernel itself."""
    if not _cpython:
        return kernel

    def run(*args):
        try:
            return kernel(*args)
        except TypeError:
            return python(*args)
    run.python = python
    return run


if kernels is not None:
    matmul, matmul_bt = either(kernels.matmul, matmul), either(kernels.matmul_bt, matmul_bt)
    symmetrize, cholesky = either(kernels.symmetrize, symmetrize), either(kernels.cholesky, cholesky)
    chol_solve_rows = either(kernels.chol_solve_rows, chol_solve_rows)
    joseph_select = either(kernels.joseph_select, joseph_select)
