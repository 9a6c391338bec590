"""Augmented fixed-lag smoother (AFLS, thesis Sec. 5.4, Eq. 5.18-5.42) and its extended form (EAFLS,
Eq. 5.43-5.52), for out-of-sequence measurements (OOSM).

The smoother keeps the nodes (estimate and joint covariance) of the last ``lag`` seconds, newest first:
X = [x_k, x_k-1, ..., x_k-N] with one covariance P over all of them (Eq. 5.18-5.22). Each prediction prepends
the propagated current node (the augmented transition of Eq. 5.21: the old nodes are carried with the
identity and no noise). A measurement at the current time, or at an existing node, updates every node
(Eq. 5.24). A measurement time-tagged between two nodes a (older) and c (newer) first gets its own node b,
interpolated from a and c (Eq. 5.40-5.42; nonlinear Eq. 5.49-5.52), plugged in between them (Fig. 5-2),
and is then applied with Eq. 5.24. Nodes older than the lag are dropped (marginalised: exact), but for the
newest of them (node a for an OOSM at the lag's edge).

Functions (``predict``, ``update``, ``generate_node``) state the algebra; ``Afls`` keeps the node list and
runs its own faster forms of the first two (pruning as it predicts, the update as a downdate), tested against them.
The model is given as callables: ``f(x, dt)`` propagation (negative dt = backward, Eq. 5.51),
``Phi(x, dt)`` its Jacobian at x, ``Q(dt)`` the discrete process noise. For a linear system f(x, dt) is
Phi(dt) x and the EAFLS reduces to the AFLS exactly.
"""

from math import isfinite

import numpy as np
from scipy.linalg.blas import dgemm
from scipy.linalg.lapack import dposv, dpotrf, dtrtri


def predict(X, P, n, x0_new, Phi, Q):
    """Augmented prediction (Eq. 5.20-5.22): prepend x0_new = f(x_k); P_new = A P A^T + diag(Q, 0...).

    Written block-wise: P00 = Phi P00 Phi^T + Q, P0j = Phi P0j, the old block unchanged.
    """
    m = P.shape[0]
    Pn = np.empty((m + n, m + n))
    top = Phi @ P[:n, :]
    p00 = top[:, :n] @ Phi.T + Q
    Pn[:n, :n] = 0.5 * (p00 + p00.T)
    Pn[:n, n:] = top
    Pn[n:, :n] = top.T
    Pn[n:, n:] = P
    return np.concatenate([x0_new, X]), Pn


def chol_inv(S):
    """L^-1 with S = L L^T (LAPACK dpotrf + dtrtri: ~2 us for the 6-12 dimensional S here, where
    numpy.linalg.solve costs ~15-40 us in per-call overhead). LinAlgError unless S is positive definite."""
    c, info = dpotrf(S, lower=1)
    if info == 0:
        c, info = dtrtri(c, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError("innovation covariance is not positive definite (LAPACK info %d)" % info)
    return c


def downdate(P, W):
    """P <- P - W W^T in place (the covariance update of Eq. 5.24 in square-root form, below). For a
    C-contiguous P one BLAS dgemm on P^T (= P, symmetric) does it without a temporary; else numpy."""
    if P.flags.c_contiguous:
        dgemm(-1.0, W, W, beta=1.0, c=P.T, trans_b=True, overwrite_c=True)
    else:
        np.subtract(P, W @ W.T, out=P)


def update(X, P, n, idx, z, R, H, hx):
    """FLS update with a measurement of node ``idx`` (Eq. 5.24): C = [0 .. H .. 0],
    K = P C^T (H P_ii H^T + R)^-1, X + K (z - h(x_i)), P - K S K^T (= P - K C P).

    In square-root form with S = L L^T: W = P C^T L^-T, K = W L^-1, P - W W^T. (W W^T is formed as the
    product with a contiguous copy of W^T: numpy's syrk path for ``W @ W.T`` is ~2x slower at this size.)"""
    s = slice(idx * n, (idx + 1) * n)
    PCt = P[:, s] @ H.T
    Li = chol_inv(H @ PCt[s, :] + R)
    W = PCt @ Li.T
    WWt = W @ np.ascontiguousarray(W.T)
    return X + W @ (Li @ (z - hx)), np.subtract(P, WWt, out=WWt)


def _eye(n, _cache={}):
    if n not in _cache:
        e = np.eye(n)
        e.flags.writeable = False
        _cache[n] = e
    return _cache[n]


def interpolation(xa, xc, dt_a, dt_b, f, Phi, Qa, Qb):
    """(x_b, A, B, N) of node b between a (state xa, older) and c (xc, newer), dt_a = t_b - t_a,
    dt_b = t_c - t_b, Qa = Q(dt_a), Qb = Q(dt_b): x_b ~ A x_a + B x_c + w, cov(w) = N = (I - B Fb) Qa.

    Eq. 5.46-5.48: Fa = Phi(x_a, dt_a), Fb = Phi(f(x_a, dt_a), dt_b), Qca = Fb Qa Fb^T + Qb,
    B = Qa Fb^T Qca^-1 (solved with LAPACK dposv), A = (I - B Fb) Fa.
    State (Eq. 5.49-5.52): x_b = f(x_a, dt_a) + B Fb (f(x_c, -dt_b) - f(x_a, dt_a)); for a linear f this
    is A x_a + B x_c (Eq. 5.40). xa and xc may be one part of the node state where the model separates.
    """
    xb_pred = f(xa, dt_a)
    Fa = Phi(xa, dt_a)
    Fb = Phi(xb_pred, dt_b)
    FQ = Fb.dot(Qa)                                # (.dot: half the call cost of @ on these small matrices)
    _, BT, info = dposv(FQ.dot(Fb.T) + Qb, FQ, lower=1)   # Qca B^T = Fb Qa (Qa symmetric), by Cholesky
    if info != 0:
        raise np.linalg.LinAlgError("Qca is not positive definite (LAPACK info %d)" % info)
    B = BT.T
    BF = B.dot(Fb)
    IBF = np.subtract(_eye(BF.shape[0]), BF)
    xb = xb_pred + BF.dot(f(xc, -dt_b) - xb_pred)
    return xb, IBF.dot(Fa), B, IBF.dot(Qa)


def generate_node(X, P, n, ia, ic, dt_a, dt_b, f, Phi, Q):
    """Node b between a (index ia, older) and c (index ic, newer) (``interpolation``, Eq. 5.46-5.52).

    Covariance: P_bb = A Paa A^T + B Pcc B^T + A Pac B^T + B Pca A^T + (I - B Fb) Qa (Eq. 5.41, 5.44),
    P_bj = A P_aj + B P_cj for every other node j (Eq. 5.42, 5.45).
    Returns (x_b, P_bb, row) with row = [P_bj for all current nodes j] (n x m).
    """
    sa = slice(ia * n, (ia + 1) * n)
    sc = slice(ic * n, (ic + 1) * n)
    xb, A, B, N = interpolation(X[sa], X[sc], dt_a, dt_b, f, Phi, Q(dt_a), Q(dt_b))
    if ia == ic + 1:                               # c just before a in the node list: one product (Eq. 5.42)
        BA = np.empty((n, 2 * n))
        BA[:, :n], BA[:, n:] = B, A
        row = BA @ P[sc.start:sa.stop, :]
        Pbb = row[:, sc.start:sa.stop] @ BA.T + N      # = Eq. 5.41 expanded
    else:
        row = A @ P[sa, :] + B @ P[sc, :]
        Pbb = row[:, sa] @ A.T + row[:, sc] @ B.T + N
    Pbb = 0.5 * (Pbb + Pbb.T)
    return xb, Pbb, row


def insert_node(X, P, n, pos, xb, Pbb, row):
    """Plug node b in at node position ``pos`` (Fig. 5-2)."""
    k = pos * n
    m = P.shape[0]
    X = np.concatenate([X[:k], xb, X[k:]])
    Pn = np.empty((m + n, m + n))
    Pn[:k, :k] = P[:k, :k]
    Pn[:k, k + n:] = P[:k, k:]
    Pn[k + n:, :k] = P[k:, :k]
    Pn[k + n:, k + n:] = P[k:, k:]
    Pn[k:k + n, :k] = row[:, :k]
    Pn[k:k + n, k + n:] = row[:, k:]
    Pn[:k, k:k + n] = row[:, :k].T
    Pn[k + n:, k:k + n] = row[:, k:].T
    Pn[k:k + n, k:k + n] = Pbb
    return X, Pn


class Afls:
    """Node list of the (E)AFLS. ``t`` holds node times newest first; ``x``/``Pk`` the current node,
    ``X``/``P`` all nodes.

    ``lag_s``: the longest delay accepted; a measurement older than that is refused (ValueError).
    ``keep_generated``: keep a node generated for an OOSM in the list after its update (Fig. 5-2, default);
    False generates, applies and drops it in one (``_update_between``: the same algebra, with only the
    measured part of node b formed; exact for the nodes kept), so the joint covariance keeps only the
    regular nodes (the STKF with SatB's relay: 6 nodes, 72 rows, instead of up to 8). A later OOSM in the same
    interval is then interpolated from the interval's ends without the dropped node, which loses what the first
    measurement told about the process noise inside the interval; with one OOSM per interval (SatB's relayed
    solutions: one per second, on SatB's own clock) the linear AFLS gives the same kept nodes either way, and
    the in-order Kalman filter's result (tested to 1e-9).
    ``parts``: optional slices of the node state along which the model separates: Phi and Q block-diagonal,
    and f of one part independent of the others (the STKF's two satellites, Eq. 5.9). ``f(x_p, dt)`` and
    ``Phi(x_p, dt)`` must then also take one part's state alone, and ``Q(dt)[p, p]`` is its noise. A
    measurement of one part (``update(..., part=p)``) touches only that part's columns of P, and its OOSM node
    (with ``keep_generated=False``) is interpolated for that part alone: A, B and N are block-diagonal too, so
    the other parts of node b never enter the update.
    """

    def __init__(self, x0, P0, t0, lag_s, f, Phi, Q, tol=1e-9, keep_generated=True, parts=None):
        x0 = np.asarray(x0, dtype=float)
        P0 = np.asarray(P0, dtype=float)
        if not (np.isfinite(lag_s) and lag_s >= 0):
            raise ValueError("smoother lag must be >= 0 s, got %r" % (lag_s,))
        if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(P0))):
            raise ValueError("initial state or covariance has a NaN")
        self.n = x0.size
        self._load(x0, P0)
        self.t = [float(t0)]
        self.lag = float(lag_s)
        self.f, self.Phi, self.Q = f, Phi, Q
        self.tol = tol
        self.generated = 0
        self.keep_generated = bool(keep_generated)
        self.parts = tuple(parts or ())
        used = np.zeros(self.n, dtype=int)
        for p in self.parts:
            if not (isinstance(p, slice) and p.step in (None, 1) and p.start is not None
                    and 0 <= p.start < p.stop <= self.n):
                raise ValueError("model parts must be slices inside the %d node states, got %r" % (self.n, p))
            used[p] += 1
        if used.max(initial=0) > 1:
            raise ValueError("model parts overlap: %r" % (self.parts,))

    # The nodes are newest first in one contiguous vector and one contiguous joint covariance: numpy's
    # elementwise operations on a strided window of a larger buffer cost ~4x those on a contiguous array
    # (measured: P -= W W^T at 72 rows, 7.5 vs 1.8 us), more than the copy a prediction makes anyway.
    def _load(self, X, P):
        self._X = np.array(X, dtype=float)
        self._P = np.array(P, dtype=float)

    @property
    def X(self):
        """All node states, newest first (the filter's own array: read it, do not keep it across steps)."""
        return self._X

    @X.setter
    def X(self, value):
        self._load(value, self._P)

    @property
    def P(self):
        """The joint covariance of all nodes (the filter's own array: read it, do not keep it across steps)."""
        return self._P

    @P.setter
    def P(self, value):
        self._load(self._X, value)

    @property
    def x(self):
        """The current node's state (a copy)."""
        return self._X[:self.n].copy()

    @property
    def Pk(self):
        """The current node's covariance (a copy)."""
        return self._P[:self.n, :self.n].copy()

    @property
    def now(self):
        return self.t[0]

    def predict(self, t_new):
        """Eq. 5.20-5.22: P00 = Phi P00 Phi^T + Q, P0j = Phi P0j, the old block unchanged; the nodes the
        lag drops (``_keep``) are left out as the new arrays are written."""
        t_new = float(t_new)
        dt = t_new - self.t[0]
        if not dt > 0:
            raise ValueError("prediction time %.6f s is not after the current %.6f s" % (t_new, self.t[0]))
        n = self.n
        t = [t_new] + self.t
        keep = self._keep(t)
        k = (keep - 1) * n                  # old rows and columns kept
        X, P = self._X, self._P
        x0 = X[:n]
        ph = self.Phi(x0, dt)
        top = ph @ P[:n, :k]
        p00 = top[:, :n].dot(ph.T) + self.Q(dt)
        Xn = np.empty(k + n)
        Xn[:n] = self.f(x0, dt)
        Xn[n:] = X[:k]
        Pn = np.empty((k + n, k + n))
        Pn[:n, :n] = 0.5 * (p00 + p00.T)          # (ufuncs into a strided block are slow: assign instead)
        Pn[:n, n:] = top
        Pn[n:, :n] = top.T
        Pn[n:, n:] = P[:k, :k]
        self._X, self._P, self.t = Xn, Pn, t[:keep]

    def _keep(self, t):
        """How many of the nodes at times t (newest first) to keep: every node within the lag and the newest
        one older than it (node a for the oldest OOSM)."""
        horizon = t[0] - self.lag - self.tol
        for i, ti in enumerate(t):
            if ti < horizon:
                return i + 1
        return len(t)

    def update(self, z, R, h, H=None, t=None, part=None):
        """Measurement z = h(x(t)) + v, v ~ N(0, R); ``h(x)`` and ``H(x)`` callables of the node state, or
        ``H`` None and ``h(x)`` returning (h, H) from one evaluation.

        ``t`` None means now. A time between nodes creates a node (Eq. 5.40-5.42 / 5.49-5.52). The update
        is the module's ``update`` (Eq. 5.24), done in place. ``part``: one of the model's
        ``parts`` when z depends on that part of the state alone; h and H then take that part's state, and H
        has that part's columns only (C = [0 .. H .. 0] of Eq. 5.24 is never formed).
        """
        z = np.asarray(z, dtype=float)
        if not isfinite(z.dot(z)) and not np.isfinite(z).all():   # z.z finite => every z_i finite (a cheap test)
            raise ValueError("measurement has a NaN or infinite value: %s" % z.tolist())
        now = self.t[0]
        t = now if t is None else float(t)
        if not isfinite(t):
            raise ValueError("measurement time tag is not finite: %r" % (t,))
        if t > now + self.tol:
            raise ValueError("measurement time-tagged %.3f s in the future (tag %.3f s, filter at %.3f s)"
                             % (t - now, t, now))
        if t < now - self.lag - self.tol:
            raise ValueError("measurement delayed %.3f s, longer than the smoother's lag of %.3f s"
                             % (now - t, self.lag))
        if part is None:
            lo, hi = 0, self.n
        elif part in self.parts:
            lo, hi = part.start, part.stop
        else:
            raise ValueError("measurement part %r is not one of the model's parts %r" % (part, self.parts))
        idx, at = self._locate(t)
        if not at:
            if not self.keep_generated:
                self._update_between(idx, t, z, R, h, H, lo, hi)
                return
            self._generate(idx, t)
        n = self.n
        X, P = self.X, self.P
        s = slice(idx * n + lo, idx * n + hi)
        xi = X[s]
        if H is None:
            hx, Hi = h(xi)
        else:
            hx, Hi = h(xi), H(xi)
        PCt = Hi.dot(P[s, :]).T                    # P C^T = (C P)^T: P's rows are contiguous, its columns not
        Li = chol_inv(Hi.dot(PCt[s, :]) + R)
        W = PCt.dot(Li.T)
        X += W.dot(Li.dot(z - hx))
        downdate(P, W)

    def _locate(self, t):
        """(i, True) when t is at node i; (i, False) when it lies between node i - 1 (c) and i (a)."""
        for i, ti in enumerate(self.t):
            if abs(ti - t) <= self.tol:
                return i, True
            if ti < t:  # nodes are newest first: c = i - 1 is newer, a = i older
                return i, False
        raise ValueError("measurement time %.3f s is before the oldest node %.3f s" % (t, self.t[-1]))

    def _update_between(self, ia, t, z, R, h, H, lo=0, hi=None):
        """Generate node b between c = ia - 1 and a = ia, update every node with z = h(x_b) + v and drop b,
        in one: with C the measurement's Jacobian at x_b, cov(z, X) = C [B A] P[c:a, :] (Eq. 5.42) and
        cov(z) = that times [B A]^T C^T + C (I - B Fb) Qa C^T + R (Eq. 5.41), then Eq. 5.24 on the kept
        nodes. Node b's own n x m row and n x n block are never formed. For a measurement of one model part
        [lo, hi) only that part of node b is interpolated (A, B, N are block-diagonal with the model), and
        [B A] is written with zeros in the other parts' columns."""
        n = self.n
        hi = n if hi is None else hi
        X, P = self.X, self.P
        ic = ia - 1
        dt_a, dt_b = t - self.t[ia], self.t[ic] - t
        Qa, Qb = self.Q(dt_a), self.Q(dt_b)
        if hi - lo < n:
            Qa, Qb = Qa[lo:hi, lo:hi], Qb[lo:hi, lo:hi]
        a0, c0 = ia * n, ic * n
        xb, A, B, N = interpolation(X[a0 + lo:a0 + hi], X[c0 + lo:c0 + hi], dt_a, dt_b,
                                    self.f, self.Phi, Qa, Qb)
        if H is None:
            hx, Hi = h(xb)
        else:
            hx, Hi = h(xb), H(xb)
        CBA = np.zeros((Hi.shape[0], 2 * n)) if hi - lo < n else np.empty((Hi.shape[0], 2 * n))
        CBA[:, lo:hi] = Hi.dot(B)
        CBA[:, n + lo:n + hi] = Hi.dot(A)
        s = slice(c0, a0 + n)
        row = CBA @ P[s, :]
        S = row[:, s].dot(CBA.T) + Hi.dot(N).dot(Hi.T) + R
        Li = chol_inv(0.5 * (S + S.T))
        W = row.T.dot(Li.T)
        X += W.dot(Li.dot(z - hx))
        downdate(P, W)
        self.generated += 1

    def _generate(self, i, t):
        """Generate node b between c = i - 1 and a = i and plug it in at index i (Eq. 5.40-5.42 / 5.49-5.52)."""
        ic = i - 1
        xb, Pbb, row = generate_node(self.X, self.P, self.n, i, ic, t - self.t[i], self.t[ic] - t,
                                     self.f, self.Phi, self.Q)
        self._insert(i, xb, Pbb, row)
        self.t.insert(i, t)
        self.generated += 1

    def _node_at(self, t):
        """Index of the node at time t, generated (and kept) when t lies between nodes."""
        i, at = self._locate(t)
        if not at:
            self._generate(i, t)
        return i

    def _insert(self, pos, xb, Pbb, row):
        """``insert_node`` (Fig. 5-2)."""
        self._X, self._P = insert_node(self._X, self._P, self.n, pos, xb, Pbb, row)

    def node(self, t):
        """(x, P) of the node at time t (must exist)."""
        for i, ti in enumerate(self.t):
            if abs(ti - t) <= self.tol:
                s = slice(i * self.n, (i + 1) * self.n)
                return self.X[s].copy(), self.P[s, s].copy()
        raise KeyError(t)
