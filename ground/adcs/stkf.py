"""Satellite Tracking Kalman Filter (STKF), thesis Sec. 5.3 and 5.5.2.

State x = [rA, vA, rB, vB] (12, SI units, J2000; Eq. 5.6). Two-body dynamics with white acceleration noise
of spectral density Qa (Eq. 5.7-5.9); GNSS updates (Eq. 5.10-5.12); the beacon unit-vector update in SatA's
body frame (Eq. 5.13-5.17), with the attitude covariance as extra measurement noise (Sec. 5.3.3). SatB's
delayed GNSS goes through the smoother in ``ground.adcs.afls`` (Eq. 5.18-5.52). The pointing vector, its
error and covariance, and the two angles perpendicular to it: Eq. 5.54-5.60. The beacon camera's misalignment
(Sec. 8.3 leaves its calibration to a mission): x augmented by its three angles, ``beacon_m`` (end of the module).

Attitude errors: the true attitude is A(q) = A(dq) A(q_hat) with the small rotation d_alpha = 2 dq_vec
(Eq. 4.77); ``P_att`` is the covariance of d_alpha (rad^2), so 4 Pqq of Eq. 5.59 is ``P_att``.
"""

from math import ceil, sqrt

import numpy as np

from protocol.units import MU_EARTH as MU  # Eq. 5.7

QA_THESIS = 0.1 ** 2  # m^2/s^3 per axis, Sec. 5.5.1
N = 12
IA = slice(0, 3)
VA = slice(3, 6)
IB = slice(6, 9)
VB = slice(9, 12)
SAT_A = slice(0, 6)
SAT_B = slice(6, 12)
PARTS = (SAT_A, SAT_B)   # the model separates per satellite (Eq. 5.9): f, Phi, Q act on each on its own


I3 = np.eye(3)
I6 = np.eye(6)
I12 = np.eye(N)


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


# ---- dynamics (Eq. 5.4, 5.7, 5.9) ----

def _rk4_sat(rx, ry, rz, vx, vy, vz, h):
    """One RK4 step of one satellite's two-body motion on Python floats: the same equations as the 12-state
    numpy form, ~3x faster (numpy's per-call cost dominated that form)."""
    def acc(x, y, z):
        r2 = x * x + y * y + z * z
        c = -MU / (r2 * sqrt(r2))
        return c * x, c * y, c * z

    hh = 0.5 * h
    a1 = acc(rx, ry, rz)
    x2, y2, z2 = rx + hh * vx, ry + hh * vy, rz + hh * vz
    u2, v2, w2 = vx + hh * a1[0], vy + hh * a1[1], vz + hh * a1[2]
    a2 = acc(x2, y2, z2)
    x3, y3, z3 = rx + hh * u2, ry + hh * v2, rz + hh * w2
    u3, v3, w3 = vx + hh * a2[0], vy + hh * a2[1], vz + hh * a2[2]
    a3 = acc(x3, y3, z3)
    x4, y4, z4 = rx + h * u3, ry + h * v3, rz + h * w3
    u4, v4, w4 = vx + h * a3[0], vy + h * a3[1], vz + h * a3[2]
    a4 = acc(x4, y4, z4)
    k = h / 6.0
    return (rx + k * (vx + 2 * (u2 + u3) + u4), ry + k * (vy + 2 * (v2 + v3) + v4),
            rz + k * (vz + 2 * (w2 + w3) + w4),
            vx + k * (a1[0] + 2 * (a2[0] + a3[0]) + a4[0]), vy + k * (a1[1] + 2 * (a2[1] + a3[1]) + a4[1]),
            vz + k * (a1[2] + 2 * (a2[2] + a3[2]) + a4[2]))


def f(x, dt):
    """Two-body propagation over ``dt`` (s; negative runs backward, Eq. 5.51) of both satellites (x of 12) or
    of one (x of 6, ``SAT_A`` or ``SAT_B`` of the state: each satellite propagates on its own): one RK4 step
    for |dt| <= 1 s (local error ~1e-8 m in LEO), more for longer spans."""
    n = max(1, ceil(abs(dt) - 1e-9))
    h = float(dt) / n
    out = []
    for k in range(0, x.shape[0], 6):
        s = x[k:k + 6].tolist()
        for _ in range(n):
            s = _rk4_sat(*s, h)
        out += s
    return np.array(out)


def gravity_gradient(r):
    """d(-mu r/|r|^3)/dr = -mu/|r|^3 (I - 3 r r^T/|r|^2): the lower-left block of F_2-body (Eq. 5.4)."""
    r2 = r @ r
    return (-MU / r2 ** 1.5) * (I3 - (3.0 / r2) * np.outer(r, r))


def F(x):
    """F of Eq. 5.9: blockdiag(F_2-body,A, F_2-body,B), each [[0, I], [G(r), 0]] (Eq. 5.4)."""
    out = np.zeros((N, N))
    for k in (0, 6):
        out[k:k + 3, k + 3:k + 6] = I3
        out[k + 3:k + 6, k:k + 3] = gravity_gradient(x[k:k + 3])
    return out


def _phi_entries(x, dt):
    """The entries of Phi (Eq. 3.30 with Eq. 5.4) of each satellite in x (12 or 6 states), on Python floats,
    in the order of ``_PHI_IDX``: per satellite the 3x3 blocks rr, rv, vr, vv, each row-major."""
    h2, h3 = 0.5 * dt * dt, dt ** 3 / 6.0
    vals = []
    for k in range(0, x.shape[0], 6):
        rx, ry, rz = x[k:k + 3].tolist()
        r2 = rx * rx + ry * ry + rz * rz
        c = -MU / r2 ** 1.5
        d = -3.0 * c / r2
        gxy, gxz, gyz = d * rx * ry, d * rx * rz, d * ry * rz            # G = c (I - 3 r r^T / r^2)
        gxx, gyy, gzz = c + d * rx * rx, c + d * ry * ry, c + d * rz * rz
        axy, axz, ayz = h2 * gxy, h2 * gxz, h2 * gyz
        diag = [1.0 + h2 * gxx, axy, axz, axy, 1.0 + h2 * gyy, ayz, axz, ayz, 1.0 + h2 * gzz]
        bxy, bxz, byz = h3 * gxy, h3 * gxz, h3 * gyz
        cxy, cxz, cyz = dt * gxy, dt * gxz, dt * gyz
        vals += diag                                                                          # r r
        vals += [dt + h3 * gxx, bxy, bxz, bxy, dt + h3 * gyy, byz, bxz, byz, dt + h3 * gzz]    # r v
        vals += [dt * gxx, cxy, cxz, cxy, dt * gyy, cyz, cxz, cyz, dt * gzz]                  # v r
        vals += diag                                                                          # v v
    return vals


def _phi_index(n):
    idx = []
    for k in range(0, n, 6):
        for r0, c0 in ((k, k), (k, k + 3), (k + 3, k), (k + 3, k + 3)):
            idx += [(r0 + i) * n + c0 + j for i in range(3) for j in range(3)]
    return np.array(idx)


_PHI_IDX = {12: _phi_index(12), 6: _phi_index(6)}


def Phi(x, dt):
    """State transition over ``dt`` from F at x (Eq. 3.30): the series I + F dt + (F dt)^2/2 + (F dt)^3/6
    without its G^2 dt^3/6 term, of both satellites (x of 12) or of one (x of 6).

    With F = [[0, I], [G, 0]] per satellite: [[I + G dt^2/2, I dt + G dt^3/6], [G dt, I + G dt^2/2]]; the
    dropped terms (G^2 dt^3/6 and beyond) are ~(n dt)^4 ~ 1e-12 at dt = 1 s in LEO. Block-diagonal (the two
    satellites propagate independently): its nonzero entries are filled in one indexed assignment.
    """
    n = x.shape[0]
    out = np.zeros(n * n)
    out[_PHI_IDX[n]] = _phi_entries(x, float(dt))
    return out.reshape(n, n)


def Q(dt, qa=QA_THESIS):
    """Discrete process noise of white acceleration noise with density ``qa`` (Eq. 5.8-5.9, G = [0 I]^T):
    per axis [[qa dt^3/3, qa dt^2/2], [qa dt^2/2, qa dt]] for each satellite."""
    dt = abs(float(dt))
    key = (dt, float(qa))
    if key in _Q_CACHE:
        return _Q_CACHE[key]
    q = np.zeros((N, N))
    for k in (0, 6):
        i3 = np.eye(3)
        q[k:k + 3, k:k + 3] = qa * dt ** 3 / 3.0 * i3
        q[k:k + 3, k + 3:k + 6] = q[k + 3:k + 6, k:k + 3] = qa * dt ** 2 / 2.0 * i3
        q[k + 3:k + 6, k + 3:k + 6] = qa * dt * i3
    if len(_Q_CACHE) < 4096:
        q.flags.writeable = False
        _Q_CACHE[key] = q
    return q


_Q_CACHE = {}


def predict(x, P, dt, qa=QA_THESIS):
    """EKF prediction (Eq. 3.29-3.31 with Eq. 5.7-5.9): x <- f(x, dt), P <- Phi P Phi^T + Q."""
    ph = Phi(x, dt)
    return f(x, dt), ph @ P @ ph.T + Q(dt, qa)


def update(x, P, z, R, H, hx):
    """EKF update in Joseph form: K = P H^T (H P H^T + R)^-1, x + K (z - h(x)), (I-KH) P (I-KH)^T + K R K^T."""
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    ikh = np.eye(P.shape[0]) - K @ H
    return x + K @ (z - hx), ikh @ P @ ikh.T + K @ R @ K.T


# ---- measurements (Eq. 5.10-5.17) ----

def H_gnss(sat):
    """H of Eq. 5.12: [I 0] on SatA's or SatB's 6 states."""
    H = np.zeros((6, N))
    k = 0 if sat == "A" else 6
    H[:, k:k + 6] = np.eye(6)
    return H


def h_gnss(x, sat):
    return x[0:6] if sat == "A" else x[6:12]


def los(x):
    """(u, rho): unit vector rA->rB (J2000) and the range (Eq. 5.14)."""
    d = x[6:9] - x[0:3]
    rho = sqrt(d.dot(d))
    return d / rho, rho


def Hb(x):
    """Hb,A of Eq. 5.17: d u / d rA = -(I - u u^T)/rho; Hb,B = -Hb,A."""
    u, rho = los(x)
    return (u[:, None] * u - I3) / rho


def gnss_beacon(x, A):
    """(h, H) of SatA's GNSS and the beacon stacked (Eq. 5.12, 5.13, 5.16): h = [rA, vA, y_b] (9),
    H = [[I6, 0], [A Hb,A, 0, A Hb,B, 0]] (9 x 12), from one line-of-sight evaluation (A Hb,A = (y u^T - A)/rho
    with y = A u: one 3 x 3 product)."""
    d = x[6:9] - x[0:3]
    rho = sqrt(d.dot(d))
    u = d / rho
    y = A.dot(u)
    hb = (y[:, None] * u - A) / rho
    H = _H_GB.copy()
    H[6:9, IA] = hb
    H[6:9, IB] = -hb
    return np.concatenate((x[0:6], y)), H


_H_GB = np.zeros((9, N))
_H_GB[0:6, 0:6] = I6


def h_beacon(x, A):
    """y_b = A(q) (rB - rA)/rho (Eq. 5.13)."""
    return A.dot(los(x)[0])


def H_beacon(x, A):
    """[A Hb,A, 0, A Hb,B, 0] (Eq. 5.16)."""
    H = np.zeros((3, N))
    hb = A @ Hb(x)
    H[:, IA] = hb
    H[:, IB] = -hb
    return H


def R_beacon(y, sigma_b, P_att):
    """Beacon noise plus attitude knowledge (Eq. 5.15-5.16): sigma_b^2 I + [y x] P_att [y x]^T."""
    sy = skew(np.asarray(y, dtype=float).tolist())
    R = sy.dot(P_att).dot(sy.T)
    R += (sigma_b * sigma_b) * I3
    return R


def R_gnss_beacon(R_gnss, y, sigma_b, P_att):
    """R of SatA's GNSS and the beacon stacked (``gnss_beacon``'s h and H): the two noises independent, so
    blockdiag(R_gnss, ``R_beacon(y, sigma_b, P_att)``) (Eq. 5.12, 5.15-5.16), 9 x 9."""
    R = np.zeros((9, 9))
    R[0:6, 0:6] = R_gnss
    R[6:9, 6:9] = R_beacon(y, sigma_b, P_att)
    return R


# ---- pointing vector (Eq. 5.54-5.60) ----

def T_b2z(p):
    """A DCM whose 3rd row is p (Eq. 5.57: T_b2z p = [0, 0, 1]); the other rows any orthonormal pair."""
    p = p / np.sqrt(p @ p)
    e1 = skew(p) @ I3[int(np.argmin(np.abs(p)))]
    e1 /= np.sqrt(e1 @ e1)
    return np.vstack([e1, skew(p) @ e1, p])


def pointing(x, A):
    """p_body = A(q) (rB - rA)/rho (Eq. 5.54-5.55)."""
    return h_beacon(x, A)


def pointing_covariance(x, P, A, P_att):
    """2x2 covariance of the two angles perpendicular to p_body (rad^2), Eq. 5.59-5.60.

    Pz = T_i2z (Hb PAA Hb^T + Hb PBB Hb^T - Hb PAB Hb^T - Hb PBA Hb^T) T_i2z^T + T_b2z [p x] P_att [p x]^T T_b2z^T
    with Hb,B = -Hb,A and T_i2z = T_b2z A(q).
    """
    p = pointing(x, A)
    T = T_b2z(p)
    hb = Hb(x)
    Ti = T @ A
    Pr = P[IA, IA] + P[IB, IB] - P[IA, IB] - P[IB, IA]
    sp = skew(p)
    Pz = Ti @ hb @ Pr @ hb.T @ Ti.T + T @ sp @ P_att @ sp.T @ T.T
    return Pz[:2, :2]


def pointing_error(x_hat, A_hat, x_true, A_true):
    """The two perpendicular angular errors (rad) of the estimated p_body (Eq. 5.56-5.58)."""
    p_hat = pointing(x_hat, A_hat)
    dp = p_hat - pointing(x_true, A_true)
    return (T_b2z(p_hat) @ dp)[:2]


# ---- the beacon camera's misalignment (Sec. 8.3: calibrated on orbit) ----
#
# x = [rA, vA, rB, vB, delta] (15): delta the camera's small rotation from the body frame, a random constant
# (no process noise). The camera measures y = C(delta) A(q) u + n, C(delta) = A(dq) with dq = [delta/2, 1]
# normalised (the small rotation of Eq. 4.77), so C ~ I - [delta x] and Eq. 5.13 is the case delta = 0.

NM = N + 3
IM = slice(N, NM)


def misalignment_dcm(delta):
    """C(delta) = A(dq), dq = [g, 1]/sqrt(1 + g.g), g = delta/2 (Eq. 4.7 with Eq. 4.77):
    C = ((1 - g.g) I + 2 g g^T - 2 [g x]) / (1 + g.g)."""
    g = 0.5 * np.asarray(delta, dtype=float)
    gg = g.dot(g)
    return ((1.0 - gg) * I3 + 2.0 * np.outer(g, g) - 2.0 * skew(g)) / (1.0 + gg)


def H_misalignment(delta, v):
    """d(C(delta) v)/d delta for a fixed body-frame vector v (the delta columns of the beacon's H):
    (1/s) [(g.v) I + g v^T - v g^T + [v x] - (C v) g^T], s = 1 + g.g, g = delta/2; [v x] at delta = 0
    (C v ~ v + v x delta)."""
    g = 0.5 * np.asarray(delta, dtype=float)
    Cv = misalignment_dcm(delta).dot(v)
    return ((g.dot(v)) * I3 + np.outer(g, v) - np.outer(v, g) + skew(v) - np.outer(Cv, g)) / (1.0 + g.dot(g))


def f_m(x, dt):
    """``f`` with delta held constant: x of 15 (both satellites and delta), 12 or 6 (as ``f``)."""
    if x.shape[0] != NM:
        return f(x, dt)
    return np.concatenate((f(x[:N], dt), x[IM]))


def Phi_m(x, dt):
    """blockdiag(``Phi`` of the satellites, I3): delta a random constant. x of 15, 12 or 6."""
    if x.shape[0] != NM:
        return Phi(x, dt)
    out = np.zeros((NM, NM))
    out[:N, :N] = Phi(x[:N], dt)
    out[IM, IM] = I3
    return out


def Q_m(dt, qa=QA_THESIS):
    """blockdiag(``Q(dt, qa)``, 0): no process noise on delta."""
    out = np.zeros((NM, NM))
    out[:N, :N] = Q(dt, qa)
    return out


def beacon_m(x, A):
    """(h, H) of the misaligned beacon (Eq. 5.13 and 5.16 with C(delta)): h = C A u, and with the camera's
    attitude C A in Eq. 5.16's place, H = [C A Hb,A, 0, C A Hb,B, 0, d(C A u)/d delta] (3 x 15)."""
    delta = x[IM]
    C = misalignment_dcm(delta)
    u, rho = los(x)
    v = A.dot(u)
    y = C.dot(v)
    hb = (y[:, None] * u - C.dot(A)) / rho            # C A Hb,A (Eq. 5.17)
    H = np.zeros((3, NM))
    H[:, IA] = hb
    H[:, IB] = -hb
    H[:, IM] = H_misalignment(delta, v)
    return y, H


def gnss_beacon_m(x, A):
    """(h, H) of SatA's GNSS and the misaligned beacon stacked (Eq. 5.12 and ``beacon_m``): 9 and 9 x 15."""
    y, Hb_ = beacon_m(x, A)
    H = np.zeros((9, NM))
    H[0:6, 0:6] = I6
    H[6:9] = Hb_
    return np.concatenate((x[0:6], y)), H


def R_beacon_m(x, A, sigma_b, P_att):
    """R of the misaligned beacon (Eq. 5.15-5.16): the attitude error d_alpha enters before the camera,
    y = C (I - [d_alpha x]) A u, so sigma_b^2 I + [y x] C P_att C^T [y x]^T with y = C A u (``R_beacon``)."""
    C = misalignment_dcm(x[IM])
    return R_beacon(C.dot(A.dot(los(x)[0])), sigma_b, C.dot(P_att).dot(C.T))
