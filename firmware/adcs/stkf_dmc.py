"""The lean STKF with dynamic model compensation (flight code, MicroPython): the acceleration the gravity model
leaves out carried as a first-order Gauss-Markov state per satellite and axis (Tapley, Schutz & Born,
Statistical Orbit Determination, 2004, Sec. 4.9), in place of the white acceleration noise of Eq. 5.8.

State per satellite [r, v, w] (9): r' = v, v' = a_grav(r) + w, w' = -beta w + u, beta = 1/tau, u white with
density q_u = 2 sigma_a^2 beta (w's steady variance sigma_a^2). F of Eq. 5.4 extended, per satellite:
F = [[0, I, 0], [G, 0, I], [0, 0, -beta I]] (G the gravity gradient, ``stkf_kernels.phi``).

Phi (Eq. 3.30's series, extended; derived here): F^2 = [[G, 0, I], [0, G, -beta I], [0, 0, beta^2 I]] and
F^3 = [[0, G, -beta I], [G^2, 0, G + beta^2 I], [0, 0, -beta^3 I]], so to third order but G^2 (as Eq. 3.30's
lean form) the r, v blocks are ``phi``'s and the w columns are

    Phi_rw = dt^2 g2(x) I,  Phi_vw = dt g1(x) I + G dt^3/6,  Phi_ww = e^-x I,   x = beta dt,

with the series in beta summed (g1 = (1 - e^-x)/x, g2 = (x - 1 + e^-x)/x^2; Tapley's Eq. 4.9.18-4.9.20
with G = 0); G enters Phi_rw at dt^4.

Q (Tapley Sec. 4.9's closed forms, G left out): per axis Q_ij = q_u int_0^dt phi_i(t) phi_j(t) dt over
phi = (Phi_rw, Phi_vw, Phi_ww)(t), i.e. with E1 = e^-x, E2 = e^-2x:

    Q_ww = q dt (1 - E2)/(2x)                      Q_vw = q dt^2/x^2 [(1 - E1) - (1 - E2)/2]
    Q_vv = q dt^3/x^2 [1 - 2(1 - E1)/x + (1 - E2)/(2x)]
    Q_rw = q dt^3/x^3 [(1 - E2)/2 - x E1]          Q_rv = q dt^4/x^2 [1/2 - 1/x + (1 - E1 + x E1 - (1 - E2)/2)/x^2]
    Q_rr = q dt^5/x^2 [1/3 - 1/x + 1/x^2 + ((1 - E2)/2 - 2 x E1)/x^3]

These cancel to rounding for small x (Q_rr's terms are ~1/x^5 of it), so below x = 0.5 each is its power
series, q dt^(i+j+1) sum_k (-x)^k c_ij(k), c_ij(k) = sum_{a+b=k} 1/((a+i)! (b+j)! (k+i+j+1)) (i, j = 2, 1, 0 for
r, v, w), summed to k = 15 (its remainder < 1e-12 of the sum).

``DmcStkf`` is ``stkf_lean.LeanStkf`` with nodes of 9 states: SatA's EKF 9 x 9 (float32), SatB's smoother nodes
[rB, vB, wB]; GNSS measures r, v (Eq. 5.12 with H = [I6 0]), the beacon rB (Eq. 5.16-5.17). The 9-state products
(``KERNELS``) run in C when the kernels are built (``linalg.kernels``, firmware/adcs/native/adcsk.c), with the
Python forms' results bit for bit; the smoother's update of Eq. 5.24 is LeanStkf's (in C as well).
"""

import math

from firmware.adcs import linalg, stkf_lean
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators
from firmware.adcs.stkf_kernels import MU, _finite, phi, zeros_d

NA = 9                     # states per satellite: r, v, w
X_SERIES = 0.5             # beta dt below which Phi's and Q's w terms are their power series
K_SERIES = 16


def _coefficients():
    """c_ij(k) for (i, j) = (2, 2), (2, 1), (2, 0), (1, 1), (1, 0), (0, 0) (Q_rr, Q_rv, Q_rw, Q_vv, Q_vw,
    Q_ww), k < K_SERIES, and 1/(k + 1)!, 1/(k + 2)! (g1's and g2's)."""
    fact = [1.0]
    for k in range(1, K_SERIES + 4):
        fact.append(fact[-1] * k)
    c = []
    for i, j in ((2, 2), (2, 1), (2, 0), (1, 1), (1, 0), (0, 0)):
        c.append([sum(1.0 / (fact[a + i] * fact[k - a + j]) for a in range(k + 1)) / (k + i + j + 1)
                  for k in range(K_SERIES)])
    return c, [1.0 / fact[k + 1] for k in range(K_SERIES)], [1.0 / fact[k + 2] for k in range(K_SERIES)]


_C, _G1, _G2 = _coefficients()


@micropython.native
def _series(c, x):
    """sum_k (-x)^k c[k] (Horner)."""
    s = 0.0
    for k in range(K_SERIES - 1, -1, -1):
        s = c[k] - x * s
    return s


def gm_phi(dt, beta):
    """(Phi_rw, Phi_vw without G, Phi_ww) per axis over dt: (dt^2 g2(x), dt g1(x), e^-x), x = beta |dt| signed
    as dt."""
    x = beta * dt
    e = math.exp(-x)
    if abs(x) < X_SERIES:
        return dt * dt * _series(_G2, x), dt * _series(_G1, x), e
    return (x - 1.0 + e) / (beta * beta), (1.0 - e) / beta, e


def gm_q(dt, sigma_a, beta):
    """Q per axis over |dt| (module docstring): (Q_rr, Q_rv, Q_rw, Q_vv, Q_vw, Q_ww)."""
    dt = abs(dt)
    q, x = 2.0 * sigma_a * sigma_a * beta, beta * dt
    d2 = dt * dt
    d3 = d2 * dt
    pw = (d3 * d2, d2 * d2, d3, d3, d2, dt)
    if x < X_SERIES:
        return [q * pw[i] * _series(_C[i], x) for i in range(6)]
    e1, e2 = math.exp(-x), math.exp(-2.0 * x)
    h, xx = 0.5 * (1.0 - e2), x * x
    s = ((1.0 / 3.0 - 1.0 / x + 1.0 / xx + (h - 2.0 * x * e1) / (xx * x)) / xx,
         (0.5 - 1.0 / x + (1.0 - e1 + x * e1 - h) / xx) / xx, (h - x * e1) / (xx * x),
         (1.0 - 2.0 * (1.0 - e1) / x + h / x) / xx, ((1.0 - e1) - h) / xx, h / x)
    return [q * pw[i] * s[i] for i in range(6)]


def process_noise_gm(Q, dt, sigma_a, beta):
    """Q (9 x 9 flat) of one satellite's [r, v, w] over dt (``gm_q`` per axis, no cross-axis terms)."""
    linalg.fill(Q, 81, 0.0)
    qrr, qrv, qrw, qvv, qvw, qww = gm_q(dt, sigma_a, beta)
    for i in range(3):
        r, v, w = 9 * i + i, 9 * (3 + i) + i, 9 * (6 + i) + i
        Q[r], Q[r + 3], Q[r + 6] = qrr, qrv, qrw
        Q[v], Q[v + 3], Q[v + 6] = qrv, qvv, qvw
        Q[w], Q[w + 3], Q[w + 6] = qrw, qvw, qww


def phi_gm(Phi, x, o, dt, j2, beta, T):
    """Phi (9 x 9 flat) of one satellite's [r, v, w] at x[o:o+3] over dt (module docstring); T (36) work for
    ``stkf_kernels.phi``'s 6 x 6."""
    phi(T, x, o, dt, j2)
    linalg.fill(Phi, 81, 0.0)
    for i in range(6):
        for j in range(6):
            Phi[9 * i + j] = T[6 * i + j]
    prw, pvw, pww = gm_phi(dt, beta)
    h = dt * dt / 6.0
    for i in range(3):
        for j in range(3):                       # G dt^3 / 6 = Phi_vr dt^2 / 6
            Phi[9 * (3 + i) + 6 + j] = T[6 * (3 + i) + j] * h
        Phi[9 * i + 6 + i] = prw
        Phi[9 * (3 + i) + 6 + i] += pvw
        Phi[9 * (6 + i) + 6 + i] = pww


@micropython.native
def _gravity(a, rx, ry, rz, j2):
    """a[0:3] = the gravity model's acceleration at r (``stkf_kernels.f``'s)."""
    r2 = rx * rx + ry * ry + rz * rz
    q = r2 * math.sqrt(r2)
    c = cz = -MU / q
    if j2:
        e = j2 / (q * r2)
        c = c - e * (1.0 - 5.0 * rz * rz / r2)
        cz = c - 2.0 * e
    a[0], a[1], a[2] = c * rx, c * ry, cz * rz


@micropython.native
def f_gm(x, o, dt, j2, beta, s):
    """One satellite's [r, v, w] (x[o:o+9]) propagated by dt in place (negative: backward): RK4 steps of at most
    1 s of r' = v, v' = a_grav(r) + w, w' = -beta w. s: work (``rk_work``)."""
    n = 1
    while n < abs(dt) - 1e-9:
        n += 1
    h = dt / n
    hh = 0.5 * h
    k1, k2, k3, k4, y, a, z = s
    stages = ((k1, k1, 0.0), (k2, k1, hh), (k3, k2, hh), (k4, k3, h))   # (k, the k it starts from, its step)
    for i in range(9):
        y[i] = x[o + i]
    for _ in range(n):
        for k, p, c in stages:
            for i in range(9):
                z[i] = y[i] + c * p[i]
            _gravity(a, z[0], z[1], z[2], j2)
            for i in range(3):
                k[i] = z[3 + i]
                k[3 + i] = a[i] + z[6 + i]
                k[6 + i] = -beta * z[6 + i]
        for i in range(9):
            y[i] = y[i] + h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])
    for i in range(9):
        x[o + i] = y[i]


def rk_work():
    """``f_gm``'s work: k1 .. k4, y, a, z."""
    return [[0.0] * 9 for _ in range(7)]


# Phi's nonzero columns by row (the module docstring's blocks): r rows r, v and their w; v rows all; w rows their w
PHI_NZ = tuple(tuple(range(6)) + (6 + i,) for i in range(3)) + (tuple(range(9)),) * 3 + tuple((6 + i,) for i in range(3))


@micropython.native
def _phi_vec(F, p, v, j0):
    """v[j] = (F p)[j] for j0 <= j < 9, F = Phi (9 x 9) with its zeros (``PHI_NZ``) left out."""
    for j in range(j0, NA):
        o, t = NA * j, 0.0
        for k in PHI_NZ[j]:
            t += F[o + k] * p[k]
        v[j] = t


@micropython.native
def rows_mul_phi(P, ld, src, c_lo, c_hi, F, p, v):
    """P[0:9, c] = F P[src:src+9, c] and P[c, 0:9] = its transpose for c_lo <= c < c_hi (Eq. 5.21's
    P0j = Phi P0j for nodes of 9 states); p, v (9) work."""
    s = src * ld
    for c in range(c_lo, c_hi):
        for k in range(NA):
            p[k] = P[s + k * ld + c]
        _phi_vec(F, p, v, 0)
        b = c * ld
        for k in range(NA):
            P[k * ld + c] = P[b + k] = v[k]


@micropython.native
def sandwich_phi(P, ld, r0, src, F, Q, T, p, v):
    """P[r0:r0+9, r0:r0+9] = F P[src:src+9, src:src+9] F^T + Q (Eq. 3.31; F = Phi), written symmetric: T = F P
    (9 x 9 work, in T's precision), then row i of the result is F T[i, :]^T + Q[i, :] (P symmetric)."""
    s = src * ld + src
    for c in range(NA):
        for k in range(NA):
            p[k] = P[s + k * ld + c]
        _phi_vec(F, p, v, 0)
        for k in range(NA):
            T[NA * k + c] = v[k]
    for i in range(NA):
        for k in range(NA):
            p[k] = T[NA * i + k]
        _phi_vec(F, p, v, i)
        a = (r0 + i) * ld + r0
        for j in range(i, NA):
            t = Q[NA * i + j] + v[j]
            P[a + j] = t
            P[(r0 + j) * ld + r0 + i] = t


class Work:
    """DmcStkf's work buffers: float64 (SatB's, like its joint covariance), SatA's 9 x 9 EKF in ``a`` (float32
    but the innovation, as ``stkf_lean.WorkA``)."""

    def __init__(self, cap):
        z, m = zeros_d, cap * NA
        self.Phi, self.Fb, self.Q, self.Qb, self.A, self.B, self.T = z(81), z(81), z(81), z(81), z(81), z(81), z(81)
        self.L, self.S, self.T6 = z(81), z(36), z(36)
        self.hp = [zeros_d(m) for _ in range(6)]      # Hp = C P (6 x m), as stkf_lean.Work's
        self.xb, self.xc, self.v, self.p = z(NA), z(NA), [0.0] * NA, [0.0] * NA
        self.r, self.d = z(6), z(12)
        self.H, self.R3, self.A3, self.Kt, self.U = [0.0] * 9, [0.0] * 9, z(9), z(3 * NA), z(3 * NA)
        self.rk = rk_work()
        self.AB, self.pq = [[0.0] * (2 * NA) for _ in range(6)], [0.0] * (2 * NA)
        a = self.a = stkf_lean.WorkA()
        a.Kt, a.W, a.RK, a.Pd = linalg.zeros(6 * NA), linalg.zeros(81), linalg.zeros(6 * NA), linalg.zeros(81)


class DmcStkf(stkf_lean.LeanStkf):
    """The lean STKF with dynamic model compensation (module docstring).

    ``DmcStkf(x0, P0diag, t0, lag_s=LAG_S, cap=6, sigma_a=1e-4, tau=300.0, tol=1e-9, gravity="j2")``: x0, P0diag
    as LeanStkf's ([rA, vA, rB, vB], 12); sigma_a (m/s^2) and tau (s) the residual acceleration's steady 1 sigma
    per axis and correlation time, its states starting at 0 with variance sigma_a^2. ``get``,
    ``position_cov`` and ``Pk`` give the 12 states [rA, vA, rB, vB] (``Pk`` their 12 x 12 covariance, the
    cross covariance zero as LeanStkf's); ``xa``, ``Pa`` (9, 9 x 9) and the nodes of ``X``, ``P`` hold 9
    states each."""

    n = NA

    def __init__(self, x0, P0diag, t0, lag_s=stkf_lean.LAG_S, cap=6, sigma_a=1e-4, tau=300.0, tol=1e-9,
                 gravity="j2"):
        if not (_finite((sigma_a, tau), 2) and sigma_a > 0 and tau > 0):
            raise ValueError("sigma_a (m/s^2) and tau (s) must be > 0, got %r, %r" % (sigma_a, tau))
        stkf_lean.LeanStkf.__init__(self, x0, P0diag, t0, lag_s, cap, 2.0 * sigma_a * sigma_a * tau, tol, gravity)
        self.sigma_a, self.beta = float(sigma_a), 1.0 / tau
        self.ld = ld = cap * NA
        self.xa, self.Pa, self.X, self.P = zeros_d(NA), linalg.zeros(81), zeros_d(ld), zeros_d(ld * ld)
        s2 = sigma_a * sigma_a
        for i in range(NA):
            self.xa[i] = x0[i] if i < 6 else 0.0
            self.X[i] = x0[6 + i] if i < 6 else 0.0
            self.Pa[i * 10] = P0diag[i] if i < 6 else s2
            self.P[i * ld + i] = P0diag[6 + i] if i < 6 else s2
        self.work = Work(cap)
        self.wa = self.work.a

    def get(self, x, sig):
        """x[0:12] = [rA, vA, rB, vB] now, sig[0:12] their 1 sigma (m, m/s)."""
        for i in range(6):
            x[i], x[6 + i] = self.xa[i], self.X[i]
            sig[i], sig[6 + i] = math.sqrt(self.Pa[i * 10]), math.sqrt(self.P[i * self.ld + i])

    def position_cov(self, PA, PB):
        """PA[0:9], PB[0:9] = the 3 x 3 covariances of rA and rB now (m^2; LeanStkf's)."""
        for i in range(3):
            for j in range(3):
                PA[3 * i + j], PB[3 * i + j] = self.Pa[9 * i + j], self.P[i * self.ld + j]

    @property
    def Pk(self):
        """The 12 x 12 covariance of [rA, vA, rB, vB] now (lists; the ground recorder's, not the flight loop's)."""
        out = [[0.0] * 12 for _ in range(12)]
        for i in range(6):
            for j in range(6):
                out[i][j], out[6 + i][6 + j] = self.Pa[9 * i + j], self.P[i * self.ld + j]
        return out

    @micropython.native
    def predict(self, t_new):
        """Both satellites over dt = t_new - now with Phi and Q of the module docstring (A: x = f(x),
        P = Phi P Phi^T + Q; B: a new current node, Eq. 5.20-5.22, as LeanStkf.predict)."""
        dt = t_new - self.t[0]
        if not (dt > 0 and dt <= stkf_lean.MAX_STEP_S):
            raise ValueError("prediction time %r s is not within (0, %g] s after the current %.6f s"
                             % (t_new, stkf_lean.MAX_STEP_S, self.t[0]))
        w, wa, b, j2 = self.work, self.wa, self.beta, self.j2
        process_noise_gm(w.Q, dt, self.sigma_a, b)
        phi_gm(w.Phi, self.xa, 0, dt, j2, b, w.T6)
        f_gm(self.xa, 0, dt, j2, b, w.rk)
        sandwich_phi(self.Pa, NA, 0, 0, w.Phi, w.Q, wa.Pd, w.p, w.v)
        phi_gm(w.Phi, self.X, 0, dt, j2, b, w.T6)
        self._prune(t_new)
        self._shift(0)
        X, P, ld = self.X, self.P, self.ld
        X[0:NA] = X[NA:2 * NA]
        f_gm(X, 0, dt, j2, b, w.rk)
        self.t[0] = t_new
        rows_mul_phi(P, ld, NA, NA, self.k * NA, w.Phi, w.p, w.v)
        sandwich_phi(P, ld, 0, NA, w.Phi, w.Q, w.T, w.p, w.v)

    def _hp_node(self, i, m):
        """Hp = C P = P[9 i: 9 i + 6, 0:m] (r, v of node i), S0 = its 6 x 6 block, h = x_i's r, v (Eq. 5.24)."""
        w, ld, P, c0 = self.work, self.ld, self.P, i * NA
        for a in range(6):
            h, o = w.hp[a], (c0 + a) * ld
            for j in range(m):
                h[j] = P[o + j]
            for b in range(6):
                w.S[a * 6 + b] = h[c0 + b]
            w.d[6 + a] = self.X[c0 + a]

    @micropython.native
    def _hp_between(self, ic, ia, dt_a, dt_b, m):
        """LeanStkf._hp_between with nodes of 9 states (Eq. 5.46-5.52; ``_generated_node``): the generated node
        b's r, v as a measurement of a and c, Hp = A[0:6] P[a rows, 0:m] + B[0:6] P[c rows, 0:m] and S0 = its
        6 x 6 P_bb = Hp_a A^T + Hp_c B^T + (I - B Fb) Qa."""
        w, ld, P = self.work, self.ld, self.P
        if not self._generated_node(ia, ic, dt_a, dt_b):
            self.refused += 1
            raise ValueError("Qca is not positive definite")
        _hp_rows(w.hp, P, ld, ia, ic, m, w.AB, w.pq, w.A, w.B)
        _s_between(w.S, w.hp, ia, ic, w.A, w.B, w.T, w.Q)

    @micropython.native
    def _generated_node(self, ia, ic, dt_a, dt_b):
        """stkf_lean._generated_node with nodes of 9 states (Eq. 5.46-5.52): Fa = Phi(x_a, dt_a) (``Phi``),
        Fb = Phi(f(x_a, dt_a), dt_b), Qa, Qb, Qca = Fb Qa Fb^T + Qb, B = Qa Fb^T Qca^-1, T = I - B Fb,
        A = T Fa, and x_b's r, v = (f(x_a, dt_a) + B Fb (f(x_c, -dt_b) - f(x_a, dt_a)))[0:6] (``d[6:12]``).
        False if Qca is not positive definite."""
        w, X, j2, beta, sa = self.work, self.X, self.j2, self.beta, self.sigma_a
        xb, xc, v, d = w.xb, w.xc, w.v, w.d
        for i in range(NA):
            xb[i], xc[i] = X[ia * NA + i], X[ic * NA + i]
        Fa, Fb, Qa, Qb, A, B, T, L = w.Phi, w.Fb, w.Q, w.Qb, w.A, w.B, w.T, w.L
        phi_gm(Fa, xb, 0, dt_a, j2, beta, w.T6)
        f_gm(xb, 0, dt_a, j2, beta, w.rk)
        phi_gm(Fb, xb, 0, dt_b, j2, beta, w.T6)
        f_gm(xc, 0, -dt_b, j2, beta, w.rk)
        process_noise_gm(Qa, dt_a, sa, beta)
        process_noise_gm(Qb, dt_b, sa, beta)
        linalg.matmul(T, Fb, Qa, NA, NA, NA)            # T = Fb Qa
        linalg.matmul_bt(A, T, Fb, NA, NA, NA)          # A = Fb Qa Fb^T + Qb = Qca (work)
        for i in range(81):
            A[i] = A[i] + Qb[i]
        linalg.symmetrize(A, NA)
        if not linalg.cholesky(L, A, NA):
            return False
        for i in range(NA):                             # B = (Fb Qa)^T Qca^-1, by rows
            for j in range(NA):
                B[NA * i + j] = T[NA * j + i]
        linalg.chol_solve_rows(B, L, B, NA, NA)
        linalg.matmul(T, B, Fb, NA, NA, NA)             # T = I - B Fb
        for i in range(81):
            T[i] = (1.0 if i % 10 == 0 else 0.0) - T[i]
        linalg.matmul(A, T, Fa, NA, NA, NA)             # A = (I - B Fb) Fa
        for i in range(NA):                             # v = Fb (f(x_c, -dt_b) - f(x_a, dt_a))
            s = 0.0
            for k in range(NA):
                s += Fb[NA * i + k] * (xc[k] - xb[k])
            v[i] = s
        for i in range(6):
            s = xb[i]
            for k in range(NA):
                s += B[NA * i + k] * v[k]
            d[6 + i] = s
        return True

    @micropython.native
    def update_beacon(self, y, q, P_att, sigma_b, t=None):
        """LeanStkf.update_beacon (Eq. 5.13-5.17, Sec. 5.3.3; rA considered, the Joseph form on B's current
        node, zero gain on its older nodes) with nodes of 9 states: K = P[0:9, 0:3] H_B^T S^-1."""
        self._beacon_model(y, q, P_att, sigma_b, t)
        w, P, ld, X, Pa = self.work, self.P, self.ld, self.X, self.Pa
        H, r, R, Kt, S, T3 = w.H, w.r, w.R3, w.Kt, w.S, w.A3
        for i in range(3):
            for j in range(3):                          # T = H P_rA
                T3[3 * i + j] = H[3 * i] * Pa[j] + H[3 * i + 1] * Pa[9 + j] + H[3 * i + 2] * Pa[18 + j]
            for j in range(NA):                         # H P[0:3, 0:9]
                Kt[NA * i + j] = H[3 * i] * P[j] + H[3 * i + 1] * P[ld + j] + H[3 * i + 2] * P[2 * ld + j]
        for i in range(3):                              # R += H P_rA H^T; S = R + H P_rB H^T
            for j in range(i, 3):
                v = R[3 * i + j]
                for k in range(3):
                    v += T3[3 * i + k] * H[3 * j + k]
                R[3 * i + j] = R[3 * j + i] = v
                for k in range(3):
                    v += Kt[NA * i + k] * H[3 * j + k]
                S[3 * i + j] = S[3 * j + i] = v
        if not linalg.cholesky(w.L, S, 3):
            self.refused += 1
            raise ValueError("beacon innovation covariance is not positive definite")
        U = w.U
        U[0:3 * NA] = Kt[0:3 * NA]                      # U = H P[0:3, 0:9]
        linalg._solve_cols(Kt, w.L, NA, 3)              # K^T (3 x 9) = S^-1 U
        for i in range(NA):
            X[i] = X[i] + Kt[i] * r[0] + Kt[NA + i] * r[1] + Kt[2 * NA + i] * r[2]
        _joseph_dmc(P, ld, self.k * NA, Kt, U, H, R, w.T, w.p)


@micropython.native
def _hp_rows(Hp, P, ld, ia, ic, m, AB, pq, A, B):
    """Hp[a][j] = A[a, :] P[a rows, j] + B[a, :] P[c rows, j] for a < 6, j < m (nodes ia, ic of 9 states); AB
    (6 lists of 18: A's and B's rows side by side) and pq (18: the two columns) work."""
    for a in range(6):
        r = AB[a]
        for k in range(NA):
            r[k], r[NA + k] = A[NA * a + k], B[NA * a + k]
    sa, sc = ia * NA * ld, ic * NA * ld
    for j in range(m):
        for k in range(NA):
            pq[k], pq[NA + k] = P[sa + k * ld + j], P[sc + k * ld + j]
        for a in range(6):
            r, t = AB[a], 0.0
            for k in range(2 * NA):
                t += r[k] * pq[k]
            Hp[a][j] = t


@micropython.native
def _s_between(S, Hp, ia, ic, A, B, T, Qa):
    """S (6 x 6) = P_bb = Hp_a A^T + Hp_c B^T + T Qa (Eq. 5.46-5.52; Hp of ``_hp_rows``, nodes ia, ic of 9 states,
    T = I - B Fb), upper triangle mirrored."""
    ca, cc = ia * NA, ic * NA
    for a in range(6):
        h, ao = Hp[a], a * NA
        for b in range(a, 6):
            bo, v = b * NA, 0.0
            for k in range(NA):
                v += h[ca + k] * A[bo + k] + h[cc + k] * B[bo + k] + T[ao + k] * Qa[k * NA + b]
            S[a * 6 + b] = S[b * 6 + a] = v


@micropython.native
def _joseph_dmc(P, ld, m, Kt, U, H, R, W, u):
    """The beacon's update of B's nodes for I - K H (H = [H_B 0] on rB, K^T 3 x 9, U = H P[0:3, 0:9]): the older
    nodes' P_0j = (I - K H) P_0j (zero gain on them), and the Joseph form (Eq. 4.142) of the current one,
    P00 = W - (W H^T) K^T + K R K^T with W = (I - K H) P00 = P00 - K U. W (81) and u (9) work."""
    for c in range(NA, m):
        b = c * ld
        for a in range(3):
            u[a] = H[3 * a] * P[c] + H[3 * a + 1] * P[ld + c] + H[3 * a + 2] * P[2 * ld + c]
        for i in range(NA):
            t = P[i * ld + c] - (Kt[i] * u[0] + Kt[NA + i] * u[1] + Kt[2 * NA + i] * u[2])
            P[i * ld + c] = P[b + i] = t
    for i in range(NA):
        k0, k1, k2 = Kt[i], Kt[NA + i], Kt[2 * NA + i]
        for j in range(NA):
            W[NA * i + j] = P[i * ld + j] - (k0 * U[j] + k1 * U[NA + j] + k2 * U[2 * NA + j])
    for i in range(NA):
        o = NA * i
        w0, w1, w2 = W[o], W[o + 1], W[o + 2]
        v0 = w0 * H[0] + w1 * H[1] + w2 * H[2]          # W H^T, row i
        v1 = w0 * H[3] + w1 * H[4] + w2 * H[5]
        v2 = w0 * H[6] + w1 * H[7] + w2 * H[8]
        k0, k1, k2 = Kt[i], Kt[NA + i], Kt[2 * NA + i]
        r0 = k0 * R[0] + k1 * R[3] + k2 * R[6]           # (K R), row i
        r1 = k0 * R[1] + k1 * R[4] + k2 * R[7]
        r2 = k0 * R[2] + k1 * R[5] + k2 * R[8]
        for j in range(i, NA):
            g0, g1, g2 = Kt[j], Kt[NA + j], Kt[2 * NA + j]
            t = W[o + j] - (v0 * g0 + v1 * g1 + v2 * g2) + (r0 * g0 + r1 * g1 + r2 * g2)
            P[i * ld + j] = P[j * ld + i] = t


KERNELS = ("rows_mul_phi", "sandwich_phi", "_joseph_dmc", "_hp_rows", "_s_between")   # the ones adcsk.c has
_K = linalg.kernels          # the C kernels, when built (linalg's comment): the same results, bit for bit
if _K is not None:
    rows_mul_phi = linalg.either(_K.rows_mul_phi, rows_mul_phi)
    sandwich_phi = linalg.either(_K.sandwich_phi, sandwich_phi)
    _joseph_dmc, _hp_rows = linalg.either(_K.joseph_dmc, _joseph_dmc), linalg.either(_K.hp_rows, _hp_rows)
    _s_between = linalg.either(_K.s_between, _s_between)
