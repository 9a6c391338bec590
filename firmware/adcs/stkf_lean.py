"""The lean STKF with the AFLS (flight code, MicroPython): thesis Sec. 5.3-5.4 over preallocated flat buffers.

State [rA, vA, rB, vB] (12, m and m/s, J2000; Eq. 5.6); two-body dynamics (Eq. 5.7; or with the J2 term,
``gravity="j2"``, stkf_kernels' docstring) with white acceleration noise qa (Eq. 5.8-5.9), Phi to third order but
its G^2 dt^3/6 term (Eq. 3.30 with F of Eq. 5.4), GNSS updates (Eq. 5.10-5.12), the beacon (Eq. 5.13-5.17, the
attitude error as measurement noise as in Sec. 5.3.3), SatB's delayed GNSS through the augmented fixed-lag smoother
(AFLS, Eq. 5.18-5.24) with node generation between nodes (EAFLS, Eq. 5.46-5.52).

What this flight form chooses, and why (the ground form is ground/adcs/stkf.py + afls.py, 12 states per node):

1. Two 6-state blocks, A and B, with no cross covariance. F, Q (Eq. 5.9) and the GNSS H (Eq. 5.12) are
   block-diagonal, so without the beacon SatA's and SatB's states never couple: the joint covariance stays
   block-diagonal and this split is exact (tested against the ground smoother). SatA's GNSS comes on time,
   so A is a plain EKF (no nodes); only B carries the smoother's nodes.
2. The beacon (Eq. 5.13-5.17) is the one coupling. It updates B only, with rA's covariance taken as extra
   measurement noise (a "consider" update: R + (A Hb,A) P_rA (A Hb,A)^T, the same way Sec. 5.3.3 takes the
   attitude error), and the gain on B's older smoother nodes is set to zero (Schmidt form: their states are
   left, their cross covariance with the current node becomes (I - K H) P_0j, which is exact for that gain).
   Approximation: the A-B cross covariance the beacon would create is dropped, and the beacon does not
   refine B's older nodes. SatA's GNSS gives rA to ~9 m, which is ~0.8 arcsec at 2300 km beside the beacon's
   60 arcsec, so little is lost; bench/bench_adcs_lean.py measures it against the ground filter.
3. A short lag, and the generated node as a measurement. The smoother keeps the nodes within ``lag``
   (default 4 s: the relay's delay is U(2, 3) s, Sec. 5.5.1, and a solution waits up to 1 s more for the next
   1 Hz cycle) and the anchor (node a of the oldest admissible tag); older nodes are marginalised out, which
   is exact. SatB's solutions come at 1 Hz and the relay delivers them in order (its delay spread of 1 s does
   not exceed their spacing), so no tag can come before the newest one applied: that node is the anchor when
   newer, and an out-of-order tag is refused and counted. A tag between nodes a and c generates node b
   (EAFLS, Eq. 5.46-5.52): x_b = A x_a + B x_c + e with e ~ N(0, (I - B Fb) Qa). Plugging b in, updating all
   nodes (Eq. 5.24) and marginalising b out again gives the other nodes exactly what one update with
   H = [.. A .. B ..] and R + (I - B Fb) Qa gives, which is what this form does; b is not kept (no later tag
   falls between a and c). At 1 Hz: 4-5 nodes of 6 states (24-30), where the ground form keeps 12 states per
   node and every generated node. Equal to the ground smoother without the beacon (tested). The update
   touches nodes 0 .. a only: the nodes older than a are pruned right after it (a is then the anchor), and
   marginalising them out first changes nothing in the others' update (tests/test_adcs_lean_reference.py
   checks every call against the dense update of the whole node list).
4. Floats. States and times are float64 (``zeros_d``, array('d')): a LEO position is ~7e6 m, which float32 holds to
   0.5 m only. SatA's covariance and its work buffers (but the innovation) are float32 (``linalg.zeros``,
   array('f')): stored full, written symmetric (upper triangle computed and mirrored), GNSS update in the Joseph form
   (Eq. 4.142 via ``linalg.joseph_select``); its condition number stays below 1e3. SatB's smoother is float64: its
   joint covariance over nodes 1 s apart is nearly singular (consecutive nodes differ by 1 s of process noise): its
   condition number reaches 1e11-1e12 in Case 1 and 3e7-3e11 in Case 2 (measured over 600 s), beyond float32's 1/eps
   = 1.7e7. Rounding the exact (float64) P to float32 alone makes it indefinite in 596 of 601 steps of Case 1, so no
   update form (Joseph included) keeps a float32 P of it positive definite (measured, tests/test_adcs_lean_stkf.py). A
   square-root (QR) form would hold it but costs O(m^3), ~3e4 multiply-adds per step at m = 30, tens of times this
   whole filter. So the design needs a port with float64 floats (the unix port; STM32 builds with double floats). On
   a float32-only port (SAMD21) array('d') reads back float32: not supported by this design.

Cost. On MicroPython every float result, and every float read from a buffer, is a new heap object (~400-500
x86-64 instructions each on the unix x64 port, its allocation and collection included), and a loop iteration, an
index sum or a global lookup costs about as much. So the loops read a buffer that is used many times once (into a
list or locals), the 6 x 6 kernels hold the small matrix in locals and write its sums out, terms that are exact
zeros by structure are left out (Qa, Qb, [y x], I - K H's identity columns: an exact zero term changes no nonzero
sum), symmetric blocks are computed as one triangle, nodes move by slices (no float is boxed), only the nodes a
measurement reaches are updated, and the hot kernels are compiled with @micropython.native (~10 % fewer
instructions; a no-op under CPython). Every product is the one of the plain form in the same order (bitwise equal
results, checked on recorded sessions). With SatB's GNSS the smoother update dominates: ~8,000 float operations
(Hp = C P, 6 x m, and P -= V^T V over m = 24-30 states), their floor in this form, besides linalg's 6 x 6
products and solves for the generated node's Qca, B, A. bench/bench_adcs_can.py measures the whole cycle and
splits it by part. That floor is the interpreter's: with the C kernels built (firmware/adcs/native/adcsk.c,
``make natmod``) the block products, the generated node's rows and the update of Eq. 5.24 run in C on the same
buffers, with the same results bit for bit, and none of their floats is boxed.
"""

import math

from firmware.adcs import control, linalg
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators
# the kernels, re-exported here for the filter's users
from firmware.adcs.stkf_kernels import (GRAVITY, MU, N, QA_THESIS, _add_gain, _finite, _ikh_rows,  # noqa: F401
                                        _ikh_sandwich, between, f, phi, process_noise, rows_mul_mirror, sandwich,
                                        zeros_d)

LAG_S = 4.0            # the relay delay U(2, 3) s (Sec. 5.5.1) + up to 1 s until the next 1 Hz cycle
MAX_STEP_S = 600.0     # one predict() at most (RK4 substeps of 1 s)


class WorkA:
    """SatA's EKF work buffers: float32 (``linalg.zeros``), like its covariance, but for the innovation r
    (float64, like the states)."""

    def __init__(self):
        z = linalg.zeros
        self.Phi, self.Q, self.T, self.L, self.W, self.RK, self.Kt = z(36), z(36), z(36), z(36), z(36), z(36), z(36)
        self.r = zeros_d(6)


class Work:
    """SatB's smoother work buffers: float64 (``zeros_d``), like its joint covariance."""

    def __init__(self, cap):
        z, m = zeros_d, cap * N
        self.Phi = z(36)
        self.Fb = z(36)
        self.Q = z(36)
        self.Qb = z(36)
        self.A = z(36)
        self.B = z(36)
        self.T = z(36)
        self.L = z(36)
        self.hp = [[0.0] * m for _ in range(N)]     # Hp = C P (6 x m) by rows, then V = L^-1 Hp: plain lists,
        if linalg.kernels is not None:               # (float64 buffers for the C kernels: the same values)
            self.hp = [zeros_d(m) for _ in range(N)]
        self.ar = [[0.0] * N for _ in range(N)]      # read without a new float per read; A, B by rows
        self.br = [[0.0] * N for _ in range(N)]
        self.l6 = [0.0] * N
        self.S = z(36)
        self.xb = zeros_d(N)
        self.xc = zeros_d(N)
        self.r = zeros_d(6)
        self.d = zeros_d(12)
        self.H = [0.0] * 9            # the beacon's: H_B, R, K^T, I - K H's columns 0 .. 2, R K^T, K R K^T, T
        self.R3 = [0.0] * 9
        self.Kt = [0.0] * 18
        self.G = [0.0] * 18
        self.RK = [0.0] * 18
        self.KRK = [0.0] * 36
        self.t36 = [0.0] * 36


class LeanStkf:
    """The lean STKF: SatA's EKF and SatB's AFLS.

    ``LeanStkf(x0, P0diag, t0, lag_s=LAG_S, cap=6, qa=QA_THESIS, gravity="two-body")``: x0 = [rA, vA, rB,
    vB] (12, m, m/s), P0diag its 12 variances, qa the white acceleration noise (m^2/s^3, Eq. 5.8), gravity
    "two-body" (Eq. 5.7) or "j2" (``GRAVITY``; ``j2`` the J2 term's coefficient passed to f and phi).
    ``predict(t)``; ``update_gnss(z6, R (6 x 6 flat), sat, t=None)`` (sat 0 SatA, on time; sat 1 SatB, any
    tag within the lag); ``update_beacon(y, q_hat, P_att, sigma_b)``;
    ``get(x12, sig12)`` writes the current estimate and its 1 sigma into the caller's buffers,
    ``position_cov(PA9, PB9)`` the position covariances (for the pointing covariance, Eq. 5.59).
    Bad input raises ValueError and leaves the filter as it was (``refused`` counts refused measurements).
    ``cap`` must hold the nodes of the lag at the predict rate plus two (6 at 1 Hz with the 4 s lag); a full
    list drops its oldest node, and a tag older than the oldest node left is refused.

    SatA: ``xa`` (6), ``Pa`` (6 x 6). SatB's nodes, newest first: ``X[6 i: 6 i + 6]`` at ``t[i]``, i < ``k``,
    joint covariance ``P`` (leading dimension ``ld``); ``n`` states per satellite."""

    n = N

    def __init__(self, x0, P0diag, t0, lag_s=LAG_S, cap=6, qa=QA_THESIS, tol=1e-9, gravity="two-body"):
        if gravity not in GRAVITY:
            raise ValueError("gravity model must be one of %s, got %r" % (", ".join(sorted(GRAVITY)), gravity))
        if not (qa - qa == 0.0 and qa > 0):
            raise ValueError("process noise qa must be > 0 m^2/s^3, got %r" % (qa,))
        if not (lag_s - lag_s == 0.0 and lag_s >= 0):
            raise ValueError("smoother lag must be >= 0 s, got %r" % (lag_s,))
        if not (_finite(x0, 12) and _finite(P0diag, 12) and t0 - t0 == 0.0):
            raise ValueError("initial state, variances or time has a NaN or infinity")
        for i in range(12):
            if not P0diag[i] > 0:
                raise ValueError("initial variances must be > 0")
        if cap < 3:
            raise ValueError("smoother capacity must be >= 3 nodes")
        self.cap, self.ld, self.qa, self.tol, self.lag = cap, cap * N, qa, tol, float(lag_s)
        self.j2 = GRAVITY[gravity]
        self.xa = zeros_d(N)
        self.Pa = linalg.zeros(36)
        self.X = zeros_d(cap * N)
        self.P = zeros_d(self.ld * self.ld)
        self.t = zeros_d(cap)
        for i in range(N):
            self.xa[i] = x0[i]
            self.Pa[i * 7] = P0diag[i]
            self.X[i] = x0[6 + i]
            self.P[i * self.ld + i] = P0diag[6 + i]
        self.t[0] = t0
        self.t_last = t0 - 2.0 * self.lag - 1.0     # the newest SatB tag applied
        self.k = 1
        self.generated = 0
        self.refused = 0
        self.work = Work(cap)
        self.wa = WorkA()

    @property
    def now(self):
        return self.t[0]

    def get(self, x, sig):
        """x[0:12] = [rA, vA, rB, vB] now, sig[0:12] their 1 sigma (m, m/s)."""
        for i in range(N):
            x[i] = self.xa[i]
            x[6 + i] = self.X[i]
            sig[i] = math.sqrt(self.Pa[i * 7])
            sig[6 + i] = math.sqrt(self.P[i * self.ld + i])

    def position_cov(self, PA, PB):
        """PA[0:9], PB[0:9] = the 3 x 3 covariances of rA and rB now (m^2); their cross covariance is zero in
        this form, so the relative position rB - rA has PA + PB (Eq. 5.59's P_AA + P_BB - P_AB - P_BA)."""
        ld = self.ld
        for i in range(3):
            for j in range(3):
                PA[3 * i + j] = self.Pa[6 * i + j]
                PB[3 * i + j] = self.P[i * ld + j]

    # ---- node list ----

    def _shift(self, pos):
        """Open an empty node slot at pos: nodes pos .. k-1 move one place older (a full list drops its
        oldest node: marginalising is exact). The caller fills the slot (at pos 0 its rows and columns hold
        stale values until then)."""
        ld, P, X, t, n = self.ld, self.P, self.X, self.t, self.n
        k = self.k
        if k == self.cap:
            k -= 1
        m, p = k * n, pos * n
        X[p + n:m + n] = X[p:m]
        for i in range(k - 1, pos - 1, -1):
            t[i + 1] = t[i]
        if pos == 0:                             # the block moves by one slice, (i, j) -> (i + N, j + N); the
            c = (m - 1) * ld + m                 # columns between its rows land in the slot or past the block
            P[n * ld + n:n * ld + n + c] = P[0:c]
            self.k = k + 1
            return
        for i in range(m - 1, -1, -1):          # bottom row first: nothing is overwritten before it moves
            a = i * ld                           # (row slices: no float is read one by one)
            b = a + n * ld if i >= p else a
            if b != a and p:
                P[b:b + p] = P[a:a + p]
            P[b + p + n:b + m + n] = P[a + p:a + m]
        self.k = k + 1

    @micropython.native
    def _prune(self, t_ref):
        """Keep the nodes within the lag of t_ref and the anchor: the newest node at least ``lag`` older than
        t_ref (node a for the oldest admissible time tag). Older nodes are marginalised out (exact)."""
        h = t_ref - self.lag + self.tol
        if self.t_last > h:
            h = self.t_last + self.tol          # in order: nothing older than the newest SatB tag is needed
        for i in range(self.k):
            if self.t[i] <= h:
                self.k = i + 1
                return

    # ---- prediction (Eq. 3.29-3.31, 5.20-5.22) ----

    @micropython.native
    def predict(self, t_new):
        """A: x = f(x), P = Phi P Phi^T + Q. B: prepend f(x_0) as the new current node (Eq. 5.21):
        P00 = Phi P00 Phi^T + Q, P0j = Phi P0j, the older block unchanged."""
        dt = t_new - self.t[0]
        if not dt > 0:
            raise ValueError("prediction time %r s is not after the current %.6f s" % (t_new, self.t[0]))
        if not dt <= MAX_STEP_S:
            raise ValueError("prediction step of %r s is longer than %g s (propagate in steps)" % (dt, MAX_STEP_S))
        wa, w = self.wa, self.work
        process_noise(wa.Q, dt, self.qa)
        phi(wa.Phi, self.xa, 0, dt, self.j2)
        f(self.xa, 0, dt, self.j2)
        sandwich(self.Pa, 6, 0, wa.Phi, wa.Q, wa.T)
        process_noise(w.Q, dt, self.qa)
        phi(w.Phi, self.X, 0, dt, self.j2)
        self._prune(t_new)                      # before the products: dropped nodes cost nothing
        self._shift(0)
        X, P, ld = self.X, self.P, self.ld
        X[0:N] = X[N:2 * N]
        f(X, 0, dt, self.j2)
        self.t[0] = t_new
        m = self.k * N
        rows_mul_mirror(P, ld, N, N, m, w.Phi)   # P0j = Phi P0j from the old node 0's rows (now N .. 2N-1)
        sandwich(P, ld, 0, w.Phi, w.Q, w.T, N)   # P00 = Phi P00 Phi^T + Q from the old P00 (now at N, N)

    # ---- GNSS (Eq. 5.10-5.12, 5.24) ----

    @micropython.native
    def update_gnss(self, z, R, sat, t=None):
        """GNSS position and velocity of SatA (sat 0, time-tagged now) or SatB (sat 1, at time t within the
        lag: between nodes a node is generated first, Eq. 5.46-5.52; then Eq. 5.24 updates every node kept).
        R: 6 x 6 flat, symmetric positive definite."""
        t = self.t[0] if t is None else t
        if sat not in (0, 1):
            raise ValueError("sat must be 0 (SatA) or 1 (SatB), got %r" % (sat,))
        if not (_finite(z, 6) and _finite(R, 36) and t - t == 0.0):
            self.refused += 1
            raise ValueError("GNSS measurement, its R or its time tag has a NaN or infinity")
        if t > self.t[0] + self.tol:
            self.refused += 1
            raise ValueError("measurement time-tagged %.3f s in the future" % (t - self.t[0]))
        if sat == 0:
            if t < self.t[0] - self.tol:
                self.refused += 1
                raise ValueError("SatA's GNSS must be time-tagged now (%.3f s late)" % (self.t[0] - t))
            wa = self.wa
            for j in range(6):
                wa.r[j] = z[j] - self.xa[j]
            if not linalg.joseph_select(self.Pa, self.n, 0, 6, R, wa.Kt, wa.L, wa.W, wa.RK):
                self.refused += 1
                raise ValueError("innovation covariance is not positive definite")
            _add_gain(self.xa, self.n, wa.Kt, wa.r, 6)
            return
        if t < self.t[0] - self.lag - self.tol:
            self.refused += 1
            raise ValueError("measurement delayed %.3f s, longer than the smoother's lag of %.3f s"
                             % (self.t[0] - t, self.lag))
        if t <= self.t_last + self.tol:
            self.refused += 1
            raise ValueError("SatB measurement at %.3f s is out of order or repeated (the newest applied is at "
                             "%.3f s)" % (t, self.t_last))
        between = False
        for i in range(self.k):
            ti = self.t[i]
            if abs(ti - t) <= self.tol:                 # at a node: Eq. 5.24 with C = [0 .. I6 .. 0]
                m = (i + 1) * self.n
                self._hp_node(i, m)
                break
            if ti < t:                                  # between nodes c = i - 1 and a = i
                m = (i + 1) * self.n
                self._hp_between(i - 1, i, t - ti, self.t[i - 1] - t, m)
                between = True
                break
        else:
            self.refused += 1
            raise ValueError("measurement time %.3f s is before the oldest node %.3f s" % (t, self.t[self.k - 1]))
        # Only nodes 0 .. i take part (m states): the older ones are pruned below once the update is applied
        # (the anchor is node i or newer), and marginalising them out first leaves the update of the others
        # exactly as it is. A refused update changes nothing.
        if not self._update_rows(z, R, m):
            self.refused += 1
            raise ValueError("innovation covariance is not positive definite")
        if between:
            self.generated += 1
        self.t_last = t
        self._prune(self.t[0])

    @micropython.native
    def _hp_node(self, i, m):
        """Hp = C P = P[6 i: 6 i + 6, 0:m] (6 x m), its block S0 = P_ii, h = x_i (Eq. 5.24)."""
        w, ld, P, X = self.work, self.ld, self.P, self.X
        c0 = i * N
        Hp, S, d = w.hp, w.S, w.d
        for a in range(6):
            h, o = Hp[a], (c0 + a) * ld
            for j in range(m):
                h[j] = P[o + j]
            for b in range(6):
                S[a * 6 + b] = h[c0 + b]
            d[N + a] = X[c0 + a]

    @micropython.native
    def _hp_between(self, ic, ia, dt_a, dt_b, m):
        """The generated node b between a (older, index ia) and c (newer, ic) of Eq. 5.46-5.52, as a
        measurement of a and c: Fa = Phi(x_a, dt_a), Fb = Phi(f(x_a, dt_a), dt_b), Qca = Fb Qa Fb^T + Qb,
        B = Qa Fb^T Qca^-1, A = (I - B Fb) Fa; x_b = f(x_a, dt_a) + B Fb (f(x_c, -dt_b) - f(x_a, dt_a)),
        P_bj = A P_aj + B P_cj (Hp, 6 x m, nodes 0 .. ia), P_bb = P_ba A^T + P_bc B^T + (I - B Fb) Qa (S0):
        ``_generated_node``, then ``between``.

        A measurement of b is then a measurement of a and c with H = [A .. B], noise R + (I - B Fb) Qa. The
        update of Eq. 5.24 with node b plugged in (Fig. 5-2) and then marginalised out is the same update of
        the other nodes (exact); b is not kept: with in-order tags 1 s apart no later tag falls between a and
        c, and the pruning keeps a as the anchor."""
        w, ld, P = self.work, self.ld, self.P
        if not _generated_node(w, self.X, ia, ic, dt_a, dt_b, self.qa, self.j2):
            self.refused += 1
            raise ValueError("Qca is not positive definite")
        Qa = w.Q
        q = (Qa[0], Qa[3], Qa[21])                        # Qa per axis [[q3, q2], [q2, q1]]
        if _K is not None:                                # ``between`` in C
            try:
                return _K.between(w.hp, w.S, P, ld, ia, ic, w.A, w.B, w.T, q, m)
            except TypeError:                             # no float buffers (linalg.either): the Python form
                pass
        between(w.hp, w.S, P, ld, ia, ic, w.A, w.B, w.T, q, m, w.ar, w.br, w.l6)

    @micropython.native
    def _update_rows(self, z, R, m):
        """Eq. 5.24 over the first m states from Hp = C P (6 x m, rows in ``work.hp``), S0 = C P C^T
        (``work.S``) and h (``work.d[6:12]``): S = S0 + R = L L^T, V = L^-1 Hp, X += V^T L^-1 (z - h),
        P -= V^T V (= K S K^T; upper triangle, mirrored). False (nothing changed) unless S is positive
        definite."""
        w, ld, P, X = self.work, self.ld, self.P, self.X
        S, L, d, r = w.S, w.L, w.d, w.r
        if _K is not None:                                # this method, in C
            try:
                return _K.update_rows(P, ld, X, w.hp, S, R, L, d, r, z, m)
            except TypeError:                             # no float buffers (linalg.either): the Python form
                pass
        for i in range(6):                                # S0 + R, lower triangle: all cholesky reads
            for j in range(i * 6, i * 7 + 1):
                S[j] = S[j] + R[j]
        if not linalg.cholesky(L, S, 6):
            return False
        for j in range(6):
            r[j] = z[j] - d[N + j]
        l00, l10, l11, l20, l21, l22 = L[0], L[6], L[7], L[12], L[13], L[14]
        l30, l31, l32, l33, l40, l41 = L[18], L[19], L[20], L[21], L[24], L[25]
        l42, l43, l44, l50, l51, l52, l53, l54, l55 = L[26], L[27], L[28], L[30], L[31], L[32], L[33], L[34], L[35]
        r0 = r[0] / l00                                   # r = L^-1 (z - h)
        r1 = (r[1] - l10 * r0) / l11
        r2 = (r[2] - l20 * r0 - l21 * r1) / l22
        r3 = (r[3] - l30 * r0 - l31 * r1 - l32 * r2) / l33
        r4 = (r[4] - l40 * r0 - l41 * r1 - l42 * r2 - l43 * r3) / l44
        r5 = (r[5] - l50 * r0 - l51 * r1 - l52 * r2 - l53 * r3 - l54 * r4) / l55
        V0, V1, V2, V3, V4, V5 = w.hp
        for j in range(m):                                # V = L^-1 Hp, column by column, in place
            v0 = V0[j] / l00
            v1 = (V1[j] - l10 * v0) / l11
            v2 = (V2[j] - l20 * v0 - l21 * v1) / l22
            v3 = (V3[j] - l30 * v0 - l31 * v1 - l32 * v2) / l33
            v4 = (V4[j] - l40 * v0 - l41 * v1 - l42 * v2 - l43 * v3) / l44
            v5 = (V5[j] - l50 * v0 - l51 * v1 - l52 * v2 - l53 * v3 - l54 * v4) / l55
            V0[j], V1[j], V2[j], V3[j], V4[j], V5[j] = v0, v1, v2, v3, v4, v5
            X[j] = X[j] + v0 * r0 + v1 * r1 + v2 * r2 + v3 * r3 + v4 * r4 + v5 * r5
        for i in range(m):
            v0, v1, v2, v3, v4, v5 = V0[i], V1[i], V2[i], V3[i], V4[i], V5[i]
            a = i * ld
            b = a + i                                     # P[j, i], j = i, i + 1, ..
            for j in range(i, m):
                v = P[a + j] - (v0 * V0[j] + v1 * V1[j] + v2 * V2[j] + v3 * V3[j] + v4 * V4[j] + v5 * V5[j])
                P[a + j] = v
                P[b] = v
                b += ld
        return True

    # ---- beacon (Eq. 5.13-5.17, Sec. 5.3.3) ----

    @micropython.native
    def update_beacon(self, y, q, P_att, sigma_b, t=None):
        """The beacon's unit vector y (SatA body frame) of rB - rA (Eq. 5.13-5.14), with the attitude
        estimate q (x, y, z, w; A(q) inertial to body, Eq. 4.7), P_att (3 x 3 flat, rad^2) the covariance of
        the attitude error d_alpha = 2 dq_vec (from firmware/adcs/apkf_lean.py, whose error state is dq_vec:
        P_att[3 i + j] = 4 P[9 i + j]) and sigma_b (rad) the beacon's 1 sigma.

        h = A (rB - rA)/rho, H_B = A (I - u u^T)/rho = -A Hb,A (Eq. 5.16-5.17) on B's current node;
        R = sigma_b^2 I + [y x] P_att [y x]^T (Sec. 5.3.3) + (A Hb,A) P_rA (A Hb,A)^T (rA considered).
        Joseph form for B's current node; its older nodes get zero gain: P_0j = (I - K H) P_0j."""
        self._beacon_model(y, q, P_att, sigma_b, t)
        w, P, ld, X = self.work, self.P, self.ld, self.X
        H, r, R3, Kt, T, S = w.H, w.r, w.R3, w.Kt, w.t36, w.S
        _beacon_innovation(Kt, T, S, R3, H, P, ld, self.Pa)    # R += H P_rA H^T, S = R + H P_rB H^T
        if not linalg.cholesky(w.L, S, 3):
            self.refused += 1
            raise ValueError("beacon innovation covariance is not positive definite")
        linalg._solve_cols(Kt, w.L, 6, 3)                     # K^T (3 x 6) = S^-1 H P[0:3, 0:6]
        K, G = Kt, w.G
        r0, r1, r2 = r[0], r[1], r[2]
        for i in range(6):
            X[i] = X[i] + K[i] * r0 + K[6 + i] * r1 + K[12 + i] * r2
        _joseph_terms(G, w.RK, w.KRK, K, H, R3)                # I - K H = [G | I's columns 3 .. 5], K R K^T
        _ikh_rows(P, ld, N, self.k * N, G)                     # P_0j = (I - K H) P_0j
        _ikh_sandwich(P, ld, G, w.KRK, T)                      # Joseph form (Eq. 4.142)

    @micropython.native
    def _beacon_model(self, y, q, P_att, sigma_b, t):
        """The beacon's checks, then H_B (``work.H``), y - h (``work.r``) and R without rA (``work.R3``)."""
        if not (_finite(y, 3) and _finite(q, 4) and _finite(P_att, 9) and sigma_b - sigma_b == 0.0
                and sigma_b > 0):
            self.refused += 1
            raise ValueError("beacon measurement, attitude, its covariance or sigma has a NaN, infinity or "
                             "sigma <= 0")
        if t is not None and abs(t - self.t[0]) > self.tol:
            self.refused += 1
            raise ValueError("the beacon must be time-tagged now (%.3f s off)" % (t - self.t[0]))
        w, X, xa = self.work, self.X, self.xa
        d0, d1, d2 = X[0] - xa[0], X[1] - xa[1], X[2] - xa[2]
        rho = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if not rho > 0:
            self.refused += 1
            raise ValueError("SatA and SatB estimates coincide")
        u0, u1, u2 = d0 / rho, d1 / rho, d2 / rho
        e1, e2, e3, q4 = q[0], q[1], q[2], q[3]
        nq = math.sqrt(e1 * e1 + e2 * e2 + e3 * e3 + q4 * q4)
        if not nq > 0.5:
            self.refused += 1
            raise ValueError("attitude quaternion is not a unit quaternion")
        Am = w.A
        control.dcm(Am, (e1 / nq, e2 / nq, e3 / nq, q4 / nq))      # A(q), Eq. 4.7
        H, r, d = w.H, w.r, w.d                                # (small buffers as lists: read without a new
        for i in range(3):                                     # float per read)
            o = 3 * i                                          # H_B = A (I - u u^T) / rho  (3 x 3 on rB)
            a0, a1, a2 = Am[o], Am[o + 1], Am[o + 2]
            au = d[3 + i] = a0 * u0 + a1 * u1 + a2 * u2        # h = A u
            H[o] = (a0 - au * u0) / rho
            H[o + 1] = (a1 - au * u1) / rho
            H[o + 2] = (a2 - au * u2) / rho
            r[i] = y[i] - au
        _beacon_noise(w.R3, y, P_att, sigma_b)                 # R = sigma^2 I + [y x] P_att [y x]^T


@micropython.native
def _beacon_noise(R, y, P_att, sigma_b):
    """The beacon's R (3 x 3 flat) = sigma_b^2 I + [y x] P_att [y x]^T: the attitude error as measurement
    noise (Sec. 5.3.3), [y x]'s zeros left out."""
    y0, y1, y2 = y[0], y[1], y[2]
    n0, n1, n2, sb2 = -y0, -y1, -y2, sigma_b * sigma_b
    p00, p01, p02, p10, p11, p12 = P_att[0], P_att[1], P_att[2], P_att[3], P_att[4], P_att[5]
    p20, p21, p22 = P_att[6], P_att[7], P_att[8]
    t00, t01, t02 = n2 * p10 + y1 * p20, n2 * p11 + y1 * p21, n2 * p12 + y1 * p22     # [y x] P_att
    t10, t11, t12 = y2 * p00 + n0 * p20, y2 * p01 + n0 * p21, y2 * p02 + n0 * p22
    t20, t21 = n1 * p00 + y0 * p10, n1 * p01 + y0 * p11
    R[0] = t01 * n2 + t02 * y1 + sb2
    R[1] = R[3] = t00 * y2 + t02 * n0
    R[2] = R[6] = t00 * n1 + t01 * y0
    R[4] = t10 * y2 + t12 * n0 + sb2
    R[5] = R[7] = t10 * n1 + t11 * y0
    R[8] = t20 * n1 + t21 * y0 + sb2


@micropython.native
def _beacon_innovation(Kt, T, S, R, H, P, ld, Pa):
    """For H = H_B (3 x 3, on rB): Kt = H P[0:3, 0:6] (B's current node; K^T once solved), T = H P_rA,
    R += H P_rA H^T (rA considered, Pa SatA's covariance) and S = R + H P_rB H^T, both symmetric."""
    P0, P1, P2 = list(P[0:6]), list(P[ld:ld + 6]), list(P[2 * ld:2 * ld + 6])
    p00, p01, p02, p10, p11, p12 = Pa[0], Pa[1], Pa[2], Pa[6], Pa[7], Pa[8]
    p20, p21, p22 = Pa[12], Pa[13], Pa[14]
    for i in range(3):
        h0, h1, h2 = H[3 * i], H[3 * i + 1], H[3 * i + 2]
        for j in range(6):
            Kt[6 * i + j] = h0 * P0[j] + h1 * P1[j] + h2 * P2[j]
        o = 3 * i                                          # T = H P_rA
        T[o] = h0 * p00 + h1 * p10 + h2 * p20
        T[o + 1] = h0 * p01 + h1 * p11 + h2 * p21
        T[o + 2] = h0 * p02 + h1 * p12 + h2 * p22
    for i in range(3):                                     # R += H P_rA H^T; S = R + H P_rB H^T
        for j in range(i, 3):
            h0, h1, h2 = H[3 * j], H[3 * j + 1], H[3 * j + 2]
            v = R[3 * i + j] + T[3 * i] * h0 + T[3 * i + 1] * h1 + T[3 * i + 2] * h2
            R[3 * i + j] = R[3 * j + i] = v
            v += Kt[6 * i] * h0 + Kt[6 * i + 1] * h1 + Kt[6 * i + 2] * h2
            S[3 * i + j] = S[3 * j + i] = v


@micropython.native
def _joseph_terms(G, RK, KRK, K, H, R):
    """The beacon's Joseph form (Eq. 4.142) terms from K (as K^T, 3 x 6), H = [H_B 0] and R: G = the first
    three columns of I - K H (its others are the identity's), RK = R K^T (3 x 6) and K R K^T (upper triangle)."""
    for i in range(6):
        k0, k1, k2 = K[i], K[6 + i], K[12 + i]
        for j in range(3):
            G[3 * i + j] = (1.0 if i == j else 0.0) - (k0 * H[j] + k1 * H[3 + j] + k2 * H[6 + j])
    for a in range(3):
        ra0, ra1, ra2 = R[3 * a], R[3 * a + 1], R[3 * a + 2]
        for j in range(6):
            RK[6 * a + j] = ra0 * K[j] + ra1 * K[6 + j] + ra2 * K[12 + j]
    for i in range(6):
        k0, k1, k2 = K[i], K[6 + i], K[12 + i]
        for j in range(i, 6):
            KRK[6 * i + j] = k0 * RK[j] + k1 * RK[6 + j] + k2 * RK[12 + j]


@micropython.native
def _generated_node(w, X, ia, ic, dt_a, dt_b, qa, j2):
    """The generated node b between a (older, X's node ia) and c (newer, node ic) of Eq. 5.46-5.52, dt_a after a
    and dt_b before c, into the work buffers w: Fa = Phi(x_a, dt_a) (``Phi``), Fb = Phi(f(x_a, dt_a), dt_b),
    Qa, Qb (``Q``, ``Qb``), Qca = Fb Qa Fb^T + Qb, B = Qa Fb^T Qca^-1, T = I - B Fb, A = T Fa and
    x_b = f(x_a, dt_a) + B Fb (f(x_c, -dt_b) - f(x_a, dt_a)) (``d[6:12]``). False if Qca is not positive
    definite. j2: the J2 term's coefficient (``GRAVITY``)."""
    xb, xc = w.xb, w.xc
    for i in range(N):
        xb[i] = X[ia * N + i]
        xc[i] = X[ic * N + i]
    Fa, Fb, Qa, Qb, A, B, T, L = w.Phi, w.Fb, w.Q, w.Qb, w.A, w.B, w.T, w.L
    phi(Fa, xb, 0, dt_a, j2)
    f(xb, 0, dt_a, j2)
    phi(Fb, xb, 0, dt_b, j2)
    f(xc, 0, -dt_b, j2)
    process_noise(Qa, dt_a, qa)
    process_noise(Qb, dt_b, qa)
    q3, q2, q1 = Qa[0], Qa[3], Qa[21]                 # Qa per axis [[q3, q2], [q2, q1]], zeros elsewhere
    for i in range(N):                                # T = Fb Qa, B = T^T (Qa's zero terms left out)
        o = 6 * i
        f0, f1, f2, f3, f4, f5 = Fb[o], Fb[o + 1], Fb[o + 2], Fb[o + 3], Fb[o + 4], Fb[o + 5]
        T[o] = B[i] = f0 * q3 + f3 * q2
        T[o + 1] = B[6 + i] = f1 * q3 + f4 * q2
        T[o + 2] = B[12 + i] = f2 * q3 + f5 * q2
        T[o + 3] = B[18 + i] = f0 * q2 + f3 * q1
        T[o + 4] = B[24 + i] = f1 * q2 + f4 * q1
        T[o + 5] = B[30 + i] = f2 * q2 + f5 * q1
    linalg.matmul_bt(A, T, Fb, N, N, N)               # A = Fb Qa Fb^T + Qb = Qca (work)
    for i in range(0, 21, 7):                         # (Qb's nonzeros)
        A[i] = A[i] + Qb[i]
        A[i + 3] = A[i + 3] + Qb[i + 3]
        A[i + 18] = A[i + 18] + Qb[i + 18]
        A[i + 21] = A[i + 21] + Qb[i + 21]
    linalg.symmetrize(A, N)
    if not linalg.cholesky(L, A, N):
        return False
    linalg.chol_solve_rows(B, L, B, N, N)             # B rows: Qca^-1 (Fb Qa)^T rows
    linalg.matmul(T, B, Fb, N, N, N)                  # T = I - B Fb
    for i in range(36):
        T[i] = -T[i]
    for i in range(N):
        T[i * 7] = T[i * 7] + 1.0
    linalg.matmul(A, T, Fa, N, N, N)                  # A = (I - B Fb) Fa
    d = w.d
    e0, e1, e2 = xc[0] - xb[0], xc[1] - xb[1], xc[2] - xb[2]     # f(x_c, -dt_b) - f(x_a, dt_a)
    e3, e4, e5 = xc[3] - xb[3], xc[4] - xb[4], xc[5] - xb[5]
    for i in range(N):                                # d = Fb e, then x_b = f(x_a, dt_a) + B d
        o = 6 * i
        d[i] = Fb[o] * e0 + Fb[o + 1] * e1 + Fb[o + 2] * e2 + Fb[o + 3] * e3 + Fb[o + 4] * e4 + Fb[o + 5] * e5
    e0, e1, e2, e3, e4, e5 = d[0], d[1], d[2], d[3], d[4], d[5]
    for i in range(N):
        o = 6 * i
        d[N + i] = xb[i] + B[o] * e0 + B[o + 1] * e1 + B[o + 2] * e2 + B[o + 3] * e3 + B[o + 4] * e4 \
            + B[o + 5] * e5
    return True


_K = linalg.kernels          # the C kernels, when built (linalg's comment): the same results, bit for bit
