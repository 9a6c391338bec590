"""The APKF: gyroless attitude and parameter estimation (Yoon 2017, Sec. 4.5-4.7, Eq. 4.53-4.145, App. A).

State x (42 numbers; the error state dx has 41, Eq. 4.78):

    q (4)        dq (3)     vector part of q (x) q_hat^-1 (Eq. 4.77)
    w (3)        dw (3)     body rate, rad/s
    tau_d (3)    dtau_d     disturbance torque bias, N m (Eq. 4.76)
    J5 (5)       dJ5        [Jyy, Jzz, Jxy, Jxz, Jyz]; Jxx is the fixed reference (Sec. 4.6.2)
    m (3)        dm         residual dipole, A m^2
    d1, d2 (4+4) dd1, dd2   wheel misalignment angles, rad (Eq. 4.58-4.61)
    Jrw (4)      dJrw       wheel inertias, kg m^2
    W (4)        dW         wheel speeds (relative to the body), rad/s
    W- , W+ (4+4)           tachometer read-outs at the start and end of the step (Eq. 4.57, 4.62)

Dynamics (Eq. 4.67, 4.83): J w_dot = -w x (J w + C Jrw W) - C Jrw (W+ - W-)/dt + tau_gg(J) + m x b_b + tau_d with
C = C0 + C1 D(d1) + C2 D(d2) (Eq. 4.60), W(t) = W + (t - t-)(W+ - W-)/dt over the step (Eq. 4.95), J here
includes the rotors' transverse share (Eq. 4.16, J = Ja + Jb). The orbit and field are known (Sec. 4.6.1).

Linearisation F (Eq. 4.98-4.110): written out here from the model above (the OCR of Eq. 4.99-4.110 and of
App. A.1 is partly unreadable; this is our derivation, tested against a finite-difference Jacobian):

    F11 = -[w x], F12 = I/2
    F21 = J^-1 {3 mu/r^3 ([r x] J - [(J r) x]) 2[r x] + [m x] 2[b x]}     (r, b: body-frame unit orbit radius, field)
    F22 = J^-1 {-[w x] J + [H x]},  H = J w + C Jrw W
    F23 = J^-1,  F24[:, k] = J^-1 {-w x (E_k w) + 3 mu/r^3 r x (E_k r) - E_k w_dot},  F25 = -J^-1 [b x]
    F26 = -J^-1 {[w x] C1 D(Jrw W) + C1 D(Jrw a)},  F27 = same with C2,  a = (W+ - W-)/dt
    F28 = -J^-1 {[w x] C D(W) + C D(a)},  F29 = -J^-1 [w x] C D(Jrw),  F2a = J^-1 C D(Jrw)/dt = -F2b
    F9a = -I/dt, F9b = I/dt (wheel speed row, Eq. 4.109-4.110); every other row is zero.

Phi in closed form (Eq. 4.114-4.127, App. A.2): with A = [[F11, F12], [F21, F22]] (attitude and rate), the
parameters constant and W driven linearly by W+- W-, Phi is exactly

    Phi_AA = e^{A dt},  Phi_A,p = G1 F_A,p  (p = tau_d .. Jrw, W),  Phi_A,W+- = G1 F_A,W+- + G2 F_A,W F_W,W+-,
    Phi_W,W+- = F_W,W+- dt,  G1 = int_0^dt e^{A s} ds,  G2 = int_0^dt e^{A s} (dt - s) ds,

which we sum as series in (A dt) to the 4th power (App. A.2 truncates the same series at dt^3; the A dt here is
~0.03, so the truncation is < 1e-8). Tested against expm(F dt).

Q (Eq. 4.135-4.136), from Phi ~ I + F dt: Q_pp = Q_p dt, Q_wp = F2p Q_p dt^2/2, Q_ww = sum F2p Q_p F2p^T dt^3/3,
for p in tau_d, J5, m, d1/d2, Jrw. The tachometer noise enters through W+ (reset to R_rw, uncorrelated, at
each step; the old W+ becomes W-, keeping its correlations).

Update (Eq. 4.139-4.142): z = vec(q_meas (x) q_hat^-1), H = [I3 0 ...], R = diag(sigma_st^2)/4, Joseph form.
Variable fictitious noise (Sec. 4.7.4): Q and R_st x100 until the first maneuver set ends, x10 until the second
ends, then nominal. Adaptive q_d (Eq. 4.152, Case 3): q_d,i = q_d0 + q_d1 |w_i| + q_d2 sum_{j != i} |w_j|.
"""

from math import sqrt

import numpy as np

from emulator.spacecraft import environment as env
from emulator.spacecraft.dynamics import J0_THESIS
from emulator.spacecraft.wheels import J_RW_NOMINAL, misalignment_axes, pyramid_c0
from ground.adcs import quat
from ground.adcs.quat import skew

HOUR = 3600.0
DEG = np.pi / 180.0
RPM = 2 * np.pi / 60.0
NW = 4
N = 41
# error-state slices
IQ, IW, ITD, IJ, IM = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 14), slice(14, 17)
ID1, ID2, IJR, IWR, IWM, IWP = (slice(17, 21), slice(21, 25), slice(25, 29), slice(29, 33), slice(33, 37),
                                slice(37, 41))
PARAMS = slice(6, 29)            # tau_d .. Jrw (constant)
EYE3, EYE6, EYE_N = np.eye(3), np.eye(6), np.eye(N)
EYE_W = np.eye(NW)
# the symmetric basis E_k of J5 = [Jyy, Jzz, Jxy, Jxz, Jyz]
_E = np.zeros((5, 3, 3))
for _k, (_i, _j) in enumerate(((1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
    _E[_k, _i, _j] = _E[_k, _j, _i] = 1.0

# nominal process noise (Sec. 4.8), per second
Q_NOMINAL = {
    "qd": (2.0e-7) ** 2 / HOUR,                 # Case 1, (N m)^2/s
    "qJm": (4.7e-5) ** 2 / HOUR, "qJp": (4.7e-6) ** 2 / HOUR,
    "qm": (1e-3) ** 2 / HOUR, "qdelta": (0.01 * DEG) ** 2 / HOUR, "qJrw": (3e-9) ** 2 / HOUR,
}
QD_CASE = {1: (2.0e-7) ** 2 / HOUR, 2: (4.0e-6) ** 2 / HOUR, 3: (2.0e-7) ** 2 / HOUR}
# Eq. 4.152: q_d1 per rad/s. The OCR reads "2.0 10^-? Nm/sqrt(h)"; we take 2.0e-5, which makes q_d1 |w| during a
# 1.4 deg/s rotation comparable with Case 2's q_d (the thesis's stated intent); q_d2 = 0.1 q_d1.
QD1 = (2.0e-5) ** 2 / HOUR
QD2 = 0.1 * QD1


class Model:
    """What the filter knows: nominal geometry, the Jxx reference, the orbit and field, noise levels."""

    def __init__(self, dt=1.0, jxx=J0_THESIS[0], orbit=None, field=None,
                 sigma_st_arcsec=(20.0, 20.0, 60.0), tach_rpm=10.0):
        self.dt = float(dt)
        self.jxx = float(jxx)
        self.c0 = pyramid_c0()
        self.c1, self.c2 = misalignment_axes(self.c0)
        self.orbit = orbit or env.CircularOrbit()
        self.field = field or env.TiltedDipoleField()
        self.R_st = np.diag((np.asarray(sigma_st_arcsec) * quat.ARCSEC) ** 2) / 4.0
        self.R_rw = (tach_rpm * RPM) ** 2

    def env_inertial(self, t):
        """(unit orbit radius, 3 mu/r^3, field) in the inertial frame at t."""
        r = self.orbit.position(t)
        rn = np.linalg.norm(r)
        return r / rn, 3 * env.MU_EARTH / rn ** 3, self.field.field(r, t)


# --- state helpers ---------------------------------------------------------------------------------------
def inertia(x, model):
    j5 = x[10:15]
    return np.array([[model.jxx, j5[2], j5[3]], [j5[2], j5[0], j5[4]], [j5[3], j5[4], j5[1]]])


def inv3(J):
    """Inverse of a symmetric 3 x 3 (the inertia) by cofactors, on Python floats (np.linalg.inv costs
    ~10 us a call here in per-call overhead)."""
    (a, b, c), (_, d, e), (_, _, f) = J.tolist()
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    r = 1.0 / (a * A + b * B + c * C)
    return np.array([[A * r, B * r, C * r], [B * r, D * r, E * r], [C * r, E * r, F * r]])


def c_rw(x, model):
    """C = C0 + C1 D(d1) + C2 D(d2) (Eq. 4.60)."""
    return model.c0 + model.c1 * x[18:22] + model.c2 * x[22:26]


def initial_state(q, w, w_rw, j5=J0_THESIS[1:], jrw=J_RW_NOMINAL):
    """x0 (Sec. 4.8): q, w from the star tracker, W = W- = W+ from the tachometers, the rest nominal/zero."""
    x = np.zeros(N + 1)
    x[0:4], x[4:7] = q, w
    x[10:15] = j5
    x[26:30] = jrw
    x[30:34] = x[34:38] = x[38:42] = w_rw
    return x


def initial_covariance(model):
    """P0 (Sec. 4.8): (10 deg)^2 attitude, (10 deg/s)^2 rate, J (5e-3)^2 / (2e-3)^2, m 0.3^2, d (10 deg)^2,
    Jrw (1e-6)^2, wheel speeds R_rw; tau_d is not given: (1e-6 N m)^2, the thesis's disturbance size."""
    d = np.zeros(N)
    d[IQ] = (10 * DEG / 2) ** 2
    d[IW] = (10 * DEG) ** 2
    d[ITD] = 1e-6 ** 2
    d[IJ] = [5e-3 ** 2] * 2 + [2e-3 ** 2] * 3
    d[IM] = 0.3 ** 2
    d[ID1] = d[ID2] = (10 * DEG) ** 2
    d[IJR] = 1e-6 ** 2
    d[IWR] = d[IWM] = d[IWP] = model.R_rw
    return np.diag(d)


# --- dynamics ------------------------------------------------------------------------------------------
def omega5(v):
    """[E_k v] for the J5 basis (the Omega_5 of Eq. 4.111): d(J v)/dJ5, 3 x 5."""
    return np.array([[0.0, 0.0, v[1], v[2], 0.0], [v[1], 0.0, v[0], 0.0, v[2]], [0.0, v[2], 0.0, v[0], v[1]]])


def terms(x, model, t):
    """What one step's model needs, computed once: J, J^-1, C, Jrw, W, a = (W+ - W-)/dt, orbit and field."""
    J = inertia(x, model)
    C = c_rw(x, model)
    r_i, k, b_i = model.env_inertial(t)
    m = {"J": J, "Ji": inv3(J), "C": C, "jrw": x[26:30], "W": x[30:34],
         "acc": (x[38:42] - x[34:38]) / model.dt, "r_i": r_i, "k": k, "b_i": b_i}
    _wheel_terms(m)
    return m


def _wheel_terms(m):
    cj = m["C"] * m["jrw"]
    m["cjW"], m["cja"] = cj @ m["W"], cj @ m["acc"]              # C Jrw W, C Jrw a


def _rates(q, w, x, m, s):
    """(q_dot, w_dot, r_b, b_b, H, T) at s seconds into the step (Eq. 4.10, 4.83)."""
    A = quat.dcm(q)
    r, b = A @ m["r_i"], A @ m["b_i"]
    J = m["J"]
    h = J @ w + m["cjW"] + m["cja"] * s
    T = -env.cross3(w, h) - m["cja"] + m["k"] * env.cross3(r, J @ r) + env.cross3(x[15:18], b) + x[7:10]
    e, q4 = q[0:3], q[3]
    q_dot = 0.5 * np.array([q4 * w[0] - (w[1] * e[2] - w[2] * e[1]), q4 * w[1] - (w[2] * e[0] - w[0] * e[2]),
                            q4 * w[2] - (w[0] * e[1] - w[1] * e[0]), -(w @ e)])
    return q_dot, m["Ji"] @ T, r, b, h, T


def rates(x, model, t, w_rw, acc, env_i=None):
    """(q_dot, w_dot) of Eq. 4.10 and 4.83 at wheel speed w_rw and acceleration acc."""
    m = terms(x, model, t)
    if env_i is not None:
        m["r_i"], m["k"], m["b_i"] = env_i
    m["W"], m["acc"] = w_rw, acc
    _wheel_terms(m)
    return _rates(x[0:4], x[4:7], x, m, 0.0)[:2]


def _rates_f(q, w, s, c):
    """(q_dot, w_dot, r_b, b_b, H) of ``_rates`` on Python floats (the same equations; ~4x fewer instructions
    than the numpy form on 3-vectors). ``c`` = (J, J^-1, C Jrw W, C Jrw a, r_i, b_i, 3 mu/r^3, m, tau_d)."""
    J, Ji, cjW, cja, ri, bi, k, mm, td = c
    e1, e2, e3, q4 = q
    w1, w2, w3 = w
    # A(q) of Eq. 4.7 applied to the inertial orbit radius and field
    s11, s22, s33, s44 = e1 * e1, e2 * e2, e3 * e3, q4 * q4
    a11, a22, a33 = s44 + s11 - s22 - s33, s44 - s11 + s22 - s33, s44 - s11 - s22 + s33
    a12, a13 = 2 * (e1 * e2 + q4 * e3), 2 * (e1 * e3 - q4 * e2)
    a21, a23 = 2 * (e1 * e2 - q4 * e3), 2 * (e2 * e3 + q4 * e1)
    a31, a32 = 2 * (e1 * e3 + q4 * e2), 2 * (e2 * e3 - q4 * e1)
    r1 = a11 * ri[0] + a12 * ri[1] + a13 * ri[2]
    r2 = a21 * ri[0] + a22 * ri[1] + a23 * ri[2]
    r3 = a31 * ri[0] + a32 * ri[1] + a33 * ri[2]
    b1 = a11 * bi[0] + a12 * bi[1] + a13 * bi[2]
    b2 = a21 * bi[0] + a22 * bi[1] + a23 * bi[2]
    b3 = a31 * bi[0] + a32 * bi[1] + a33 * bi[2]
    (j11, j12, j13), (j21, j22, j23), (j31, j32, j33) = J
    h1 = j11 * w1 + j12 * w2 + j13 * w3 + cjW[0] + cja[0] * s
    h2 = j21 * w1 + j22 * w2 + j23 * w3 + cjW[1] + cja[1] * s
    h3 = j31 * w1 + j32 * w2 + j33 * w3 + cjW[2] + cja[2] * s
    jr1 = j11 * r1 + j12 * r2 + j13 * r3
    jr2 = j21 * r1 + j22 * r2 + j23 * r3
    jr3 = j31 * r1 + j32 * r2 + j33 * r3
    T1 = -(w2 * h3 - w3 * h2) - cja[0] + k * (r2 * jr3 - r3 * jr2) + (mm[1] * b3 - mm[2] * b2) + td[0]
    T2 = -(w3 * h1 - w1 * h3) - cja[1] + k * (r3 * jr1 - r1 * jr3) + (mm[2] * b1 - mm[0] * b3) + td[1]
    T3 = -(w1 * h2 - w2 * h1) - cja[2] + k * (r1 * jr2 - r2 * jr1) + (mm[0] * b2 - mm[1] * b1) + td[2]
    (i11, i12, i13), (i21, i22, i23), (i31, i32, i33) = Ji
    q_dot = (0.5 * (q4 * w1 - (w2 * e3 - w3 * e2)), 0.5 * (q4 * w2 - (w3 * e1 - w1 * e3)),
             0.5 * (q4 * w3 - (w1 * e2 - w2 * e1)), -0.5 * (w1 * e1 + w2 * e2 + w3 * e3))
    w_dot = (i11 * T1 + i12 * T2 + i13 * T3, i21 * T1 + i22 * T2 + i23 * T3, i31 * T1 + i32 * T2 + i33 * T3)
    return q_dot, w_dot, (r1, r2, r3), (b1, b2, b3), (h1, h2, h3)


def _consts(x, m):
    """The per-step constants of ``_rates_f`` as Python floats."""
    return (m["J"].tolist(), m["Ji"].tolist(), m["cjW"].tolist(), m["cja"].tolist(), m["r_i"].tolist(),
            m["b_i"].tolist(), float(m["k"]), x[15:18].tolist(), x[7:10].tolist())


def propagate(x, model, t, m=None):
    """x from t to t + dt: RK4 of q and w with W(s) linear from W to W + (W+ - W-) (Eq. 4.95); the wheel speed
    state moves by W+ - W-; parameters constant. The orbit and field are taken at mid-step (``m``) unless given:
    they turn by < 0.1 deg over a step."""
    dt = model.dt
    if m is None:
        m = terms(x, model, t + 0.5 * dt)
    c = _consts(x, m)
    q, w = x[0:4].tolist(), x[4:7].tolist()
    h = 0.5 * dt

    def add(a, b, f):
        return [u + f * v for u, v in zip(a, b)]

    k1q, k1w = _rates_f(q, w, 0.0, c)[:2]
    k2q, k2w = _rates_f(add(q, k1q, h), add(w, k1w, h), h, c)[:2]
    k3q, k3w = _rates_f(add(q, k2q, h), add(w, k2w, h), h, c)[:2]
    k4q, k4w = _rates_f(add(q, k3q, dt), add(w, k3w, dt), dt, c)[:2]
    f = dt / 6.0
    qn = [q[i] + f * (k1q[i] + 2 * (k2q[i] + k3q[i]) + k4q[i]) for i in range(4)]
    nq = sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    out = x.copy()
    out[0:4] = [v / nq for v in qn]
    out[4:7] = [w[i] + f * (k1w[i] + 2 * (k2w[i] + k3w[i]) + k4w[i]) for i in range(3)]
    out[30:34] = m["W"] + m["acc"] * dt
    return out


def jacobian(x, model, t, m=None):
    """F (41 x 41) of Eq. 4.98 at x (see the module docstring for each block)."""
    dt = model.dt
    if m is None:
        m = terms(x, model, t)
    w = x[4:7]
    _, w_dot, r, b, h = _rates_f(x[0:4].tolist(), w.tolist(), 0.0, _consts(x, m))
    J, Ji, C, jrw, wr, acc, k = m["J"], m["Ji"], m["C"], m["jrw"], m["W"], m["acc"], m["k"]
    wx, rx, bx = skew(w.tolist()), skew(r), skew(b)
    jw, ja = jrw * wr, jrw * acc
    # J F2. = [...]: the -[w x] terms of every block in one product, then J^-1 once
    B = np.empty((3, 24))
    B[:, 0:3], B[:, 3:8], B[:, 8:12], B[:, 12:16] = J, omega5(w.tolist()), model.c1 * jw, model.c2 * jw
    B[:, 16:20], B[:, 20:24] = C * wr, C * jrw
    WB = wx @ B
    M = np.empty((3, N))
    M[:, 0:3] = k * (rx @ J - skew((J @ r).tolist())) @ (2 * rx) + skew(x[15:18].tolist()) @ (2 * bx)
    M[:, 3:6] = skew(h) - WB[:, 0:3]
    M[:, 6:9] = EYE3
    M[:, 9:14] = k * rx @ omega5(r) - omega5(w_dot) - WB[:, 3:8]
    M[:, 14:17] = -bx
    M[:, 17:21] = -(WB[:, 8:12] + model.c1 * ja)
    M[:, 21:25] = -(WB[:, 12:16] + model.c2 * ja)
    M[:, 25:29] = -(WB[:, 16:20] + C * acc)
    M[:, 29:33] = -WB[:, 20:24]
    M[:, 33:37] = C * (jrw / dt)
    M[:, 37:41] = -M[:, 33:37]
    F = np.zeros((N, N))
    F[0:3, 0:3] = -wx
    F[0:3, 3:6] = 0.5 * EYE3
    F[3:6, :] = Ji @ M
    F[29:33, 33:37] = EYE_W * (-1.0 / dt)
    F[29:33, 37:41] = EYE_W * (1.0 / dt)
    return F


def phi(F, dt, order=4):
    """Closed-form Phi (App. A.2 construction; see the module docstring). Phi = I except in the attitude
    and rate rows (0:6) and the wheel-speed rows (29:33, columns W-, W+): ``propagate_covariance`` uses that."""
    Ad = F[0:6, 0:6] * dt
    E, G1, G2 = EYE6 + Ad, EYE6 * dt + Ad * (dt / 2), EYE6 * (dt * dt / 2) + Ad * (dt * dt / 6)
    term = Ad
    fact = 1.0
    for n in range(2, order + 1):
        term = term @ Ad
        fact *= n
        E += term * (1.0 / fact)
        G1 += term * (dt / (fact * (n + 1)))
        G2 += term * (dt * dt / (fact * (n + 1) * (n + 2)))
    Phi = EYE_N.copy()
    Phi[0:6, 0:6] = E
    Phi[0:6, 6:] = G1 @ F[0:6, 6:]
    Phi[0:6, 33:41] += G2 @ (F[0:6, IWR] @ F[IWR, 33:41])
    Phi[IWR, 33:41] = F[IWR, 33:41] * dt
    return Phi


def propagate_covariance(Phi, P, Q):
    """Phi P Phi^T + Q (Eq. 4.128) using Phi's structure (see ``phi``): only rows and columns 0:6 and 29:33
    change, ~6x fewer flops than the dense 41 x 41 products. Symmetrised."""
    T = P.copy()
    T[0:6] = Phi[0:6] @ P
    T[IWR] += Phi[IWR, 33:41] @ P[33:41]
    out = T.copy()
    out[:, 0:6] = T @ Phi[0:6].T
    out[:, IWR] += T[:, 33:41] @ Phi[IWR, 33:41].T
    out += Q
    return 0.5 * (out + out.T)


def noise_density(x, case, scale=1.0):
    """Diagonal q (per second) of the parameter noises: tau_d (3), J5 (5), m (3), d1/d2 (8), Jrw (4)."""
    if case == 3:
        aw = np.abs(x[4:7])
        qd = Q_NOMINAL["qd"] + QD1 * aw + QD2 * (aw.sum() - aw)          # Eq. 4.152
    else:
        qd = np.full(3, QD_CASE.get(case, Q_NOMINAL["qd"]))
    q = Q_NOMINAL
    return scale * np.concatenate([qd, [q["qJm"]] * 2 + [q["qJp"]] * 3, [q["qm"]] * 3, [q["qdelta"]] * 8,
                                   [q["qJrw"]] * 4])


def process_noise(F, qp, dt):
    """Q of Eq. 4.135-4.136 for the parameter noise densities qp (23)."""
    Q = np.zeros((N, N))
    F2p = F[IW, PARAMS]
    Q[PARAMS, PARAMS] = np.diag(qp * dt)
    Q[IW, PARAMS] = F2p * (qp * dt * dt / 2)
    Q[PARAMS, IW] = Q[IW, PARAMS].T
    Q[IW, IW] = (F2p * qp) @ F2p.T * (dt ** 3 / 3)
    return Q


def shift_tach(x, P, w_plus, R_rw):
    """New step: W- <- W+ (with its correlations), W+ <- the new read-out (variance R_rw, uncorrelated)."""
    x = x.copy()
    x[34:38] = x[38:42]
    x[38:42] = w_plus
    P = P.copy()
    P[IWM, :] = P[IWP, :]
    P[:, IWM] = P[:, IWP]
    P[IWM, IWM] = P[IWP, IWP]
    P[IWP, :] = 0.0
    P[:, IWP] = 0.0
    P[IWP, IWP] = EYE_W * R_rw
    return x, P


def predict(x, P, w_plus, model, t, case=1, scale=1.0):
    """(x, P) at t + dt from t, with the tachometer read-out w_plus at t + dt (rad/s)."""
    x, P = shift_tach(x, P, w_plus, model.R_rw)
    m = terms(x, model, t + 0.5 * model.dt)           # orbit and field at mid-step for F and the propagation
    F = jacobian(x, model, t, m)
    Phi = phi(F, model.dt)
    Q = process_noise(F, noise_density(x, case, scale), model.dt)
    x = propagate(x, model, t, m)
    return x, propagate_covariance(Phi, P, Q)


def update(x, P, q_meas, R):
    """Star-tracker update, Eq. 4.139-4.142, Joseph form."""
    z = quat.error_vec(q_meas, x[0:4])
    S = P[IQ, IQ] + R                                    # H P H^T + R, H = [I3 0]
    K = np.linalg.solve(S, P[IQ, :]).T                   # P H^T S^-1 (Eq. 4.140)
    dx = K @ z                                           # Eq. 4.141
    # Eq. 4.142 with H = [I3 0]: (I - K H) P (I - K H)^T + K R K^T, without forming the 41 x 41 I - K H
    AP = P - K @ P[IQ, :]
    P = AP - AP[:, IQ] @ K.T + K @ R @ K.T
    return correct(x, dx), 0.5 * (P + P.T)


def update_standard(x, P, q_meas, R):
    """The same update with P+ = (I - K H) P (for the tests)."""
    z = quat.error_vec(q_meas, x[0:4])
    K = np.linalg.solve(P[IQ, IQ] + R, P[IQ, :]).T
    H = np.zeros((3, N))
    H[:, IQ] = np.eye(3)
    return correct(x, K @ z), (np.eye(N) - K @ H) @ P


def correct(x, dx):
    """Apply an error-state correction: q = dq (x) q_hat, the rest additive."""
    out = x.copy()
    out[0:4] = quat.from_small(dx[0:3], x[0:4])
    out[4:] = x[4:] + dx[3:]
    return out


def fictitious_scale(t, set_ends):
    """Sec. 4.7.4: x100 until the first maneuver set ends, x10 until the second, then 1."""
    if len(set_ends) > 0 and t < set_ends[0]:
        return 100.0
    if len(set_ends) > 1 and t < set_ends[1]:
        return 10.0
    return 1.0


def check_covariance(P, t):
    """Divergence check: FloatingPointError naming the time unless P is finite and positive definite."""
    if not np.all(np.isfinite(P)):
        raise FloatingPointError("APKF diverged at t = %.0f s: P is not finite" % t)
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise FloatingPointError("APKF diverged at t = %.0f s: P is not positive definite" % t) from None


class APKF:
    """The APKF over a recorded run: ``step(t, w_plus, q_meas or None)`` per dt."""

    def __init__(self, x0, model=None, case=1, set_ends=()):
        self.model = model or Model()
        self.x = np.array(x0, dtype=float)
        self.P = initial_covariance(self.model)
        self.case = case
        self.set_ends = list(set_ends)

    def step(self, t, w_plus, q_meas=None):
        """Propagate from t to t + dt with the read-out at t + dt, then update if a star-tracker output came."""
        m = self.model
        s = fictitious_scale(t, self.set_ends)
        self.x, self.P = predict(self.x, self.P, w_plus, m, t, self.case, s)
        if q_meas is not None:
            self.x, self.P = update(self.x, self.P, q_meas, m.R_st * fictitious_scale(t + m.dt, self.set_ends))
        return self.x, self.P
