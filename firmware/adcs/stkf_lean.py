"""The lean STKF with the AFLS (flight code, MicroPython): ground/adcs/stkf.py and afls.py over flat buffers.

State x = [rA, vA, rB, vB] (12, m and m/s, J2000; Eq. 5.6); two-body dynamics with white acceleration noise qa
(Eq. 5.7-5.9), Phi to third order (Eq. 3.30, closed form per satellite), GNSS updates (Eq. 5.10-5.12).
SatB's delayed GNSS goes through the augmented fixed-lag smoother (Sec. 5.4): the nodes of the last ``lag``
seconds are kept, newest first, with one joint covariance (Eq. 5.18-5.22); a prediction prepends the
propagated node (Eq. 5.21); a measurement of node i updates every node (Eq. 5.24); a measurement time-tagged
between nodes a (older) and c (newer) first gets its own node b (EAFLS, Eq. 5.46-5.52), plugged in between.

Storage: float64 buffers (``zeros_d``, array('d')) for the node states (a LEO position needs ~1e-7 relative,
below float32's 0.5 m at 7000 km) and for the joint covariance: with P in float32 the update P - K S K^T of
Eq. 5.24 loses positive definiteness within the first 14 s of the test sequence ((4 km)^2 prior against 10 m
GNSS; measured, tests/test_adcs_lean.py). A square-root (UD) form of the smoother would be the float32 fix;
it is not built. The joint covariance has a fixed leading dimension (capacity x 12), so adding or dropping a
node moves blocks but allocates no buffer.
"""

from array import array
import math

from firmware.adcs import linalg

MU = 398600.4415e9
QA_THESIS = 0.1 ** 2
N = 12


def zeros_d(n):
    return array("d", bytes(8 * n))


def _acc(d, o, x, i):
    """d[o:o+3] = -mu r/|r|^3 for r = x[i:i+3]."""
    r0, r1, r2 = x[i], x[i + 1], x[i + 2]
    r2s = r0 * r0 + r1 * r1 + r2 * r2
    c = -MU / (r2s * math.sqrt(r2s))
    d[o], d[o + 1], d[o + 2] = c * r0, c * r1, c * r2


def f(x, o, dt, work):
    """Two-body propagation (Eq. 5.4, 5.7) of the node at x[o:o+12] by dt (negative: backward, Eq. 5.51), in
    place: RK4 steps of at most 1 s."""
    n = max(1, int(math.ceil(abs(dt) - 1e-9)))
    h = dt / n
    k, y = work.k, work.y
    for _ in range(n):
        for s in range(4):
            src = x if s == 0 else y
            so = o if s == 0 else 0
            ko = s * N
            for j in (0, 6):
                for i in range(3):
                    k[ko + j + i] = src[so + j + 3 + i]
                _acc(k, ko + j + 3, src, so + j)
            if s < 3:
                c = h if s == 2 else 0.5 * h
                for i in range(N):
                    y[i] = x[o + i] + c * k[ko + i]
        for i in range(N):
            x[o + i] = x[o + i] + h / 6.0 * (k[i] + 2.0 * (k[N + i] + k[2 * N + i]) + k[3 * N + i])


def phi(Phi, x, o, dt):
    """Phi (12 x 12) over dt at the node x[o:o+12] (Eq. 3.30 with F of Eq. 5.9): per satellite
    [[I + G dt^2/2, I dt + G dt^3/6], [G dt, I + G dt^2/2]], G = -mu/|r|^3 (I - 3 r r^T/|r|^2)."""
    linalg.fill(Phi, N * N, 0.0)
    h2, h3 = 0.5 * dt * dt, dt * dt * dt / 6.0
    for b in (0, 6):
        r0, r1, r2 = x[o + b], x[o + b + 1], x[o + b + 2]
        rr = r0 * r0 + r1 * r1 + r2 * r2
        c = -MU / (rr * math.sqrt(rr))
        r = (r0, r1, r2)
        for i in range(3):
            for j in range(3):
                g = c * ((1.0 if i == j else 0.0) - 3.0 * r[i] * r[j] / rr)
                e = 1.0 if i == j else 0.0
                Phi[(b + i) * N + b + j] = e + h2 * g
                Phi[(b + 3 + i) * N + b + 3 + j] = e + h2 * g
                Phi[(b + i) * N + b + 3 + j] = e * dt + h3 * g
                Phi[(b + 3 + i) * N + b + j] = dt * g


def process_noise(Q, dt, qa=QA_THESIS):
    """Q of Eq. 5.8-5.9: per axis [[qa dt^3/3, qa dt^2/2], [qa dt^2/2, qa dt]] for each satellite."""
    dt = abs(dt)
    linalg.fill(Q, N * N, 0.0)
    for b in (0, 6):
        for i in range(3):
            Q[(b + i) * N + b + i] = qa * dt ** 3 / 3.0
            Q[(b + i) * N + b + 3 + i] = Q[(b + 3 + i) * N + b + i] = qa * dt * dt / 2.0
            Q[(b + 3 + i) * N + b + 3 + i] = qa * dt


class Work:
    def __init__(self, cap):
        z = zeros_d
        M = cap * N
        self.k = zeros_d(4 * N)
        self.y = zeros_d(N)
        self.xb = zeros_d(N)
        self.xc = zeros_d(N)
        self.Phi = z(N * N)
        self.Fa = z(N * N)
        self.Fb = z(N * N)
        self.Qa = z(N * N)
        self.Qb = z(N * N)
        self.A = z(N * N)
        self.B = z(N * N)
        self.T = z(N * N)
        self.L = z(N * N)
        self.row = z(N * M)             # also Phi P[0:12, :] in predict
        self.PCt = z(M * 6)
        self.Kt = z(6 * M)
        self.S = z(36)
        self.Ls = z(36)
        self.r = zeros_d(6)


class Afls:
    """The node list: ``predict(t)``, ``update_gnss(z6, R6 (6 x 6 flat), sat, t=None)``; the current node is
    x[0:12], P[0:12, 0:12] (leading dimension ``ld``). ``cap`` nodes at most (the lag's nodes, the one before
    it and the generated ones); a full list drops its oldest node (marginalising, exact)."""

    def __init__(self, x0, P0diag, t0, lag_s, cap=12, qa=QA_THESIS, tol=1e-9):
        if not lag_s >= 0:
            raise ValueError("smoother lag must be >= 0 s, got %r" % (lag_s,))
        self.cap, self.ld, self.qa, self.tol, self.lag = cap, cap * N, qa, tol, float(lag_s)
        self.X = zeros_d(cap * N)
        self.P = zeros_d(self.ld * self.ld)
        self.t = zeros_d(cap)
        for i in range(N):
            self.X[i] = x0[i]
            self.P[i * self.ld + i] = P0diag[i]
        self.t[0] = t0
        self.k = 1
        self.generated = 0
        self.work = Work(cap)

    @property
    def now(self):
        return self.t[0]

    def _shift(self, pos):
        """Open an empty node slot at position pos: nodes pos .. k-1 move one place older (state, time,
        covariance blocks). The caller fills slot pos."""
        ld, P, X = self.ld, self.P, self.X
        k = self.k
        if k == self.cap:                       # drop the oldest: marginalising is exact
            k -= 1
        m = k * N
        p = pos * N
        for i in range(m - 1, p - 1, -1):
            X[i + N] = X[i]
        for i in range(k - 1, pos - 1, -1):
            self.t[i + 1] = self.t[i]
        # P: rows/cols >= p move by N; iterate from the bottom-right so nothing is overwritten before it moves
        for i in range(m - 1, -1, -1):
            ni = i + N if i >= p else i
            for j in range(m - 1, -1, -1):
                nj = j + N if j >= p else j
                if ni != i or nj != j:
                    P[ni * ld + nj] = P[i * ld + j]
        self.k = k + 1

    def _prune(self):
        horizon = self.t[0] - self.lag - self.tol
        for i in range(self.k):
            if self.t[i] < horizon:
                self.k = i + 1
                return

    def predict(self, t_new):
        """Augmented prediction (Eq. 5.20-5.22): prepend f(x_k); P00 = Phi P00 Phi^T + Q, P0j = Phi P0j."""
        dt = t_new - self.t[0]
        if not dt > 0:
            raise ValueError("prediction time %.6f s is not after the current %.6f s" % (t_new, self.t[0]))
        w, ld = self.work, self.ld
        phi(w.Phi, self.X, 0, dt)
        self._shift(0)
        X, P = self.X, self.P
        for i in range(N):
            X[i] = X[N + i]
        f(X, 0, dt, w)
        self.t[0] = t_new
        m = self.k * N
        Phi, T = w.Phi, w.row
        for i in range(N):                      # T = Phi P[old node 0 rows, all old columns]
            for j in range(N, m):
                s = 0.0
                for a in range(N):
                    s += Phi[i * N + a] * P[(N + a) * ld + j]
                T[i * m + j] = s
        for i in range(N):
            for j in range(N, m):
                v = T[i * m + j]
                P[i * ld + j] = v
                P[j * ld + i] = v
        Q = w.Qa
        process_noise(Q, dt, self.qa)
        for i in range(N):                      # P00 = (Phi P_old00) Phi^T + Q, symmetric
            for j in range(i, N):
                s = Q[i * N + j]
                for a in range(N):
                    s += T[i * m + N + a] * Phi[j * N + a]
                P[i * ld + j] = s
                P[j * ld + i] = s
        self._prune()

    def update_gnss(self, z, R, sat, t=None):
        """GNSS of SatA (sat 0) or SatB (sat 1), position and velocity (Eq. 5.10-5.12, H = [I6] on its six
        states), at node time t (None: now; between nodes: a node is generated first)."""
        t = self.t[0] if t is None else t
        if t > self.t[0] + self.tol:
            raise ValueError("measurement time-tagged in the future")
        if t < self.t[0] - self.lag - self.tol:
            raise ValueError("measurement delayed %.3f s, longer than the smoother's lag of %.3f s"
                             % (self.t[0] - t, self.lag))
        idx = self._node_at(t)
        self._update_select(idx * N + 6 * sat, z, R)

    def _update_select(self, c0, z, R):
        """Eq. 5.24 for H selecting the six states from column c0 of the joint state: K = P C^T S^-1,
        X += K (z - X[c0:c0+6]), P -= K S K^T (= P - K C P; computed on the upper triangle and mirrored)."""
        w, ld, P, X = self.work, self.ld, self.P, self.X
        m = self.k * N
        PCt, S, Kt = w.PCt, w.S, w.Kt
        for i in range(m):
            for j in range(6):
                PCt[i * 6 + j] = P[i * ld + c0 + j]
        for i in range(6):
            for j in range(6):
                S[i * 6 + j] = PCt[(c0 + i) * 6 + j] + R[i * 6 + j]
        if not linalg.cholesky(w.Ls, S, 6):
            raise ValueError("innovation covariance is not positive definite")
        for i in range(m):                      # Kt rows = S^-1 applied to each row of PCt (S symmetric)
            for j in range(6):
                Kt[i * 6 + j] = PCt[i * 6 + j]
        linalg.chol_solve_rows(Kt, w.Ls, Kt, 6, m)     # Kt[i, :] = K[i, :]
        r = w.r
        for j in range(6):
            r[j] = z[j] - X[c0 + j]
        for i in range(m):
            s = 0.0
            for j in range(6):
                s += Kt[i * 6 + j] * r[j]
            X[i] = X[i] + s
        for i in range(m):
            for j in range(i, m):
                s = 0.0
                for a in range(6):
                    s += Kt[i * 6 + a] * PCt[j * 6 + a]
                v = P[i * ld + j] - s
                P[i * ld + j] = v
                P[j * ld + i] = v

    def _node_at(self, t):
        for i in range(self.k):
            ti = self.t[i]
            if abs(ti - t) <= self.tol:
                return i
            if ti < t:
                self._generate(i - 1, i, t - ti, self.t[i - 1] - t)
                self.t[i] = t
                self.generated += 1
                return i
        raise ValueError("measurement time %.3f s is before the oldest node" % t)

    def _generate(self, ic, ia, dt_a, dt_b):
        """Node b between a (older, index ia) and c (newer, ic) and plug it in at position ia (Eq. 5.46-5.52):
        Fa = Phi(x_a, dt_a), Fb = Phi(f(x_a, dt_a), dt_b), Qca = Fb Qa Fb^T + Qb, B = Qa Fb^T Qca^-1,
        A = (I - B Fb) Fa, x_b = f(x_a, dt_a) + B Fb (f(x_c, -dt_b) - f(x_a, dt_a)),
        P_bj = A P_aj + B P_cj, P_bb = P_ba A^T + P_bc B^T + (I - B Fb) Qa."""
        w, ld, P, X = self.work, self.ld, self.P, self.X
        if self.k == self.cap:                  # make room: drop the oldest node unless it is node a
            if ia == self.k - 1:
                raise ValueError("smoother full: raise its capacity")
            self.k -= 1
        m = self.k * N
        xb, xc = w.xb, w.xc
        for i in range(N):
            xb[i] = X[ia * N + i]
            xc[i] = X[ic * N + i]
        phi(w.Fa, xb, 0, dt_a)
        f(xb, 0, dt_a, w)
        phi(w.Fb, xb, 0, dt_b)
        f(xc, 0, -dt_b, w)
        process_noise(w.Qa, dt_a, self.qa)
        process_noise(w.Qb, dt_b, self.qa)
        Fa, Fb, Qa, A, B, T, L = w.Fa, w.Fb, w.Qa, w.A, w.B, w.T, w.L
        linalg.matmul(T, Fb, Qa, N, N, N)                 # T = Fb Qa
        linalg.matmul_bt(A, T, Fb, N, N, N)               # A = Fb Qa Fb^T (work)
        for i in range(N * N):
            A[i] = A[i] + w.Qb[i]                         # Qca
        linalg.symmetrize(A, N)
        if not linalg.cholesky(L, A, N):
            raise ValueError("Qca is not positive definite")
        # row i of B = Qca^-1 (row i of Qa Fb^T = (Fb Qa)^T), Qca and Qa symmetric
        linalg.chol_solve_rows(B, L, _transpose_into(B, T), N, N)
        # IBF = I - B Fb into T; A = IBF Fa
        linalg.matmul(T, B, Fb, N, N, N)
        for i in range(N * N):
            T[i] = -T[i]
        for i in range(N):
            T[i * N + i] = T[i * N + i] + 1.0
        linalg.matmul(A, T, Fa, N, N, N)
        # x_b = f(x_a) + B Fb (f(x_c, -dt_b) - f(x_a, dt_a))  (Fb d first, then B)
        r = w.k
        for i in range(N):
            s = 0.0
            for j in range(N):
                s += Fb[i * N + j] * (xc[j] - xb[j])
            r[i] = s
        for i in range(N):
            s = 0.0
            for j in range(N):
                s += B[i * N + j] * r[j]
            r[N + i] = xb[i] + s
        # row = A P[sa, :] + B P[sc, :]  (12 x m)
        row = w.row
        sa, sc = ia * N, ic * N
        for i in range(N):
            for j in range(m):
                s = 0.0
                for a in range(N):
                    s += A[i * N + a] * P[(sa + a) * ld + j] + B[i * N + a] * P[(sc + a) * ld + j]
                row[i * m + j] = s
        # P_bb = row[:, sa] A^T + row[:, sc] B^T + IBF Qa (symmetric part kept)
        Pbb = w.Fb                                        # Fb no longer needed
        for i in range(N):
            for j in range(N):
                s = 0.0
                for a in range(N):
                    s += row[i * m + sa + a] * A[j * N + a] + row[i * m + sc + a] * B[j * N + a] \
                        + T[i * N + a] * Qa[a * N + j]
                Pbb[i * N + j] = s
        linalg.symmetrize(Pbb, N)
        # plug in at position ia: shift, then write (old column index j maps to j + N if j >= ia * N)
        self._shift(ia)
        p = ia * N
        for i in range(N):
            X[p + i] = r[N + i]
        for i in range(N):
            for j in range(m):
                v = row[i * m + j]
                jj = j + N if j >= p else j
                P[(p + i) * ld + jj] = v
                P[jj * ld + p + i] = v
            for j in range(N):
                P[(p + i) * ld + p + j] = Pbb[i * N + j]


def _transpose_into(D, S):
    """D = S^T (12 x 12); returns D."""
    for i in range(N):
        for j in range(N):
            D[j * N + i] = S[i * N + j]
    return D
