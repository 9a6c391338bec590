"""The APKF's model (Yoon 2017, Sec. 4.5-4.6, Eq. 4.53-4.110): its state, the dynamics it propagates and their
linearisation F; ``ground.adcs.apkf`` is the filter over it.

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


class Model:
    """What the filter knows: nominal geometry, the Jxx reference, the orbit and field, noise levels."""

    def __init__(self, dt=1.0, jxx=J0_THESIS[0], orbit=None, field=None,
                 sigma_st_arcsec=(20.0, 20.0, 60.0), tach_rpm=10.0, c0=None, uncertainty=None, scale_var=None):
        """``c0``: the nominal wheel axes (3 x 4 unit columns; default Eq. 4.147's pyramid), C1, C2 from them by
        Eq. 4.148. ``uncertainty``: a spacecraft file's block of 1 sigma priors (``initial_covariance``);
        ``scale_var``: E[(s - 1)^2] of the Jxx-relative scale s over the vehicles the file admits (None: the
        first order, (sigma_Jxx / Jxx)^2)."""
        self.dt = float(dt)
        self.jxx = float(jxx)
        self.c0 = pyramid_c0() if c0 is None else np.array(c0, dtype=float)
        self.uncertainty = uncertainty
        self.scale_var = scale_var
        self.c1, self.c2 = misalignment_axes(self.c0)
        self.c12 = np.hstack([self.c1, self.c2])
        self.orbit = orbit or env.CircularOrbit()
        self.field = field or env.TiltedDipoleField()
        self.R_st = np.diag((np.asarray(sigma_st_arcsec) * quat.RAD_PER_ARCSEC) ** 2) / 4.0
        self.R_rw = (tach_rpm * RPM) ** 2
        self.m_ctrl = None      # the magnetorquers' dipole over the step (filter units: A m^2 x s), a known input
        self.disturbance = None  # tau_d's shaping filter (``apkf_disturbance.GaussMarkov``); None: a random walk
        self.p_lin = None       # J5, m, d1, d2, Jrw to linearise at instead of the estimate's (``apkf_iterated``)

    def env_inertial(self, t):
        """(unit orbit radius, 3 mu/r^3, field) in the inertial frame at t."""
        r = self.orbit.position(t)
        rn = np.linalg.norm(r)
        return r / rn, 3 * env.MU_EARTH / rn ** 3, self.field.field(r, t)


# --- state helpers ---------------------------------------------------------------------------------------
def inertia(x, model):
    j5 = x[10:15].tolist()
    return np.array([[model.jxx, j5[2], j5[3]], [j5[2], j5[0], j5[4]], [j5[3], j5[4], j5[1]]])


def _inv3_f(a, b, c, d, e, f):
    """Inverse of the symmetric [[a, b, c], [b, d, e], [c, e, f]] by cofactors, as nested lists."""
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    r = 1.0 / (a * A + b * B + c * C)
    return [[A * r, B * r, C * r], [B * r, D * r, E * r], [C * r, E * r, F * r]]


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


def initial_covariance(model, x0=None):
    """P0 (Sec. 4.8): (10 deg)^2 attitude, (10 deg/s)^2 rate, J (5e-3)^2 / (2e-3)^2, m 0.3^2, d (10 deg)^2,
    Jrw (1e-6)^2, wheel speeds R_rw; tau_d is not given: (1e-6 N m)^2, the thesis's disturbance size.
    With ``model.uncertainty`` (a spacecraft file's block) its 1 sigma instead, in the filter's relative units
    with s = Jxx_ref / Jxx = 1 at the nominal (Sec. 4.6.2; the rotors' transverse share, < 1e-3 of Jxx, left
    out): J5 from the sigma of [Jyy, Jzz, Jxy, Jxz, Jyz], the attitude's as the half angle dq.

    Jxx is the filter's fixed reference, but the file gives it a 1 sigma too: a true Jxx = Jxx_ref (1 + e) scales
    every relative parameter by s = 1 / (1 + e), so the scaled states J5, m, Jrw at the prior ``x0`` (their
    values p) are off by (s - 1) p, all together. That adds E[(s - 1)^2] p p^T over those states (our
    derivation; the thesis holds Jxx exact), E[(s - 1)^2] being ``model.scale_var`` (to first order
    (sigma_Jxx / Jxx_ref)^2). Without ``x0`` it is left out."""
    u = model.uncertainty
    if u is not None:
        d = np.zeros(N)
        d[IQ] = (u["attitude_sigma_deg"] * DEG / 2) ** 2
        d[IW] = (u["rate_sigma_deg_s"] * DEG) ** 2
        d[ITD] = u["disturbance_torque_sigma_nm"] ** 2
        d[IJ] = np.asarray(u["inertia_sigma_kgm2"][1:], dtype=float) ** 2
        d[IM] = u["residual_dipole_sigma_am2"] ** 2
        d[ID1] = d[ID2] = (u["misalignment_sigma_deg"] * DEG) ** 2
        d[IJR] = u["rotor_inertia_sigma_kgm2"] ** 2
        d[IWR] = d[IWM] = d[IWP] = model.R_rw
        P = np.diag(d)
        if x0 is not None:
            v = model.scale_var
            v = (u["inertia_sigma_kgm2"][0] / model.jxx) ** 2 if v is None else v
            p = np.zeros(N)
            p[IJ], p[IM], p[IJR] = x0[10:15], x0[15:18], x0[26:30]
            P += v * np.outer(p, p)
        return P
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
def terms(x, model, t):
    """What one step's model needs, computed once: J, J^-1, C, Jrw, W, a = (W+ - W-)/dt, orbit and field
    (``_terms_f`` as numpy arrays)."""
    c, (C, _, _, acc), env_i = _terms_f(x, model, t)
    J, Ji, cjW, cja = c[0:4]
    return {"J": np.array(J), "Ji": np.array(Ji), "C": np.array(C).T, "jrw": x[26:30], "W": x[30:34],
            "acc": np.array(acc), "r_i": env_i[0], "k": c[6], "b_i": env_i[2], "cjW": np.array(cjW),
            "cja": np.array(cja), "m_ctrl": getattr(model, "m_ctrl", None)}


def _terms_f(x, model, t):
    """``terms`` on Python floats: (c, (C, Jrw, W, a), env_i) with c = (J, J^-1, C Jrw W, C Jrw a, r_i, b_i,
    3 mu/r^3, m, tau_d) the constants of ``_rates_f``, C (Eq. 4.60) as 4 wheel columns and env_i the numpy
    (r_i, 3 mu/r^3, b_i) of ``Model.env_inertial``."""
    dt = model.dt
    xl = x.tolist()
    jyy, jzz, jxy, jxz, jyz = xl[10:15]
    jxx = model.jxx
    J = [[jxx, jxy, jxz], [jxy, jyy, jyz], [jxz, jyz, jzz]]
    jrw, W, acc = xl[26:30], xl[30:34], [(p - q) / dt for p, q in zip(xl[38:42], xl[34:38])]
    C = []
    cjW1 = cjW2 = cjW3 = cja1 = cja2 = cja3 = 0.0
    for (a1, a2, a3), (b1, b2, b3), (e1, e2, e3), d1, d2, jr, wr, ac in zip(
            model.c0.T.tolist(), model.c1.T.tolist(), model.c2.T.tolist(), xl[18:22], xl[22:26], jrw, W, acc):
        c1, c2, c3 = a1 + b1 * d1 + e1 * d2, a2 + b2 * d1 + e2 * d2, a3 + b3 * d1 + e3 * d2
        C.append((c1, c2, c3))
        cjW1, cjW2, cjW3 = cjW1 + c1 * jr * wr, cjW2 + c2 * jr * wr, cjW3 + c3 * jr * wr
        cja1, cja2, cja3 = cja1 + c1 * jr * ac, cja2 + c2 * jr * ac, cja3 + c3 * jr * ac
    env_i = model.env_inertial(t)
    c = (J, _inv3_f(jxx, jxy, jxz, jyy, jyz, jzz), [cjW1, cjW2, cjW3], [cja1, cja2, cja3], env_i[0].tolist(),
         env_i[2].tolist(), float(env_i[1]), _dipole(xl[15:18], getattr(model, "m_ctrl", None)), xl[7:10])
    return c, (C, jrw, W, acc), env_i


def _dipole(m, m_ctrl):
    """The dipole the torque sees: the estimated residual m plus the magnetorquers' commanded dipole ``m_ctrl``
    (``Model.m_ctrl``, a known input; filter units; None: none), as a list of floats."""
    return [float(a) for a in m] if m_ctrl is None else [float(a) + float(b) for a, b in zip(m, m_ctrl)]


def _wheel_terms(m):
    cj = m["C"] * m["jrw"]
    m["cjW"], m["cja"] = cj @ m["W"], cj @ m["acc"]              # C Jrw W, C Jrw a


def _rates(q, w, x, m, s):
    """(q_dot, w_dot, r_b, b_b, H, T) at s seconds into the step (Eq. 4.10, 4.83)."""
    A = quat.dcm(q)
    r, b = A @ m["r_i"], A @ m["b_i"]
    J = m["J"]
    h = J @ w + m["cjW"] + m["cja"] * s
    mm = np.array(_dipole(x[15:18], m.get("m_ctrl")))
    T = -env.cross3(w, h) - m["cja"] + m["k"] * env.cross3(r, J @ r) + env.cross3(mm, b) + x[7:10]
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
    """The per-step constants of ``_rates_f`` as Python floats, from ``terms``."""
    return (m["J"].tolist(), m["Ji"].tolist(), m["cjW"].tolist(), m["cja"].tolist(), m["r_i"].tolist(),
            m["b_i"].tolist(), float(m["k"]), _dipole(x[15:18], m.get("m_ctrl")), x[7:10].tolist())


def _wheels(m):
    """(C as 4 wheel columns, Jrw, W, a) as Python floats, from ``terms``."""
    return m["C"].T.tolist(), m["jrw"].tolist(), m["W"].tolist(), m["acc"].tolist()


def propagate(x, model, t, m=None):
    """x from t to t + dt: RK4 of q and w with W(s) linear from W to W + (W+ - W-) (Eq. 4.95); the wheel speed
    state moves by W+ - W-; parameters constant. The orbit and field are taken at mid-step (``m``) unless given:
    they turn by < 0.1 deg over a step."""
    if m is None:
        m = terms(x, model, t + 0.5 * model.dt)
    c = _consts(x, m)
    q, w = x[0:4].tolist(), x[4:7].tolist()
    return _propagate(x.copy(), q, w, model.dt, c, _wheels(m), _rates_f(q, w, 0.0, c)[:2])


def _propagate(out, q, w, dt, c, wheels, k1):
    """``propagate`` into ``out`` (a copy of x) from q, w (lists), the constants ``c``, the wheel terms and the
    first RK4 stage ``k1``."""
    h = 0.5 * dt
    k1q, k1w = k1
    k2q, k2w = _rates_f([a + h * b for a, b in zip(q, k1q)], [a + h * b for a, b in zip(w, k1w)], h, c)[:2]
    k3q, k3w = _rates_f([a + h * b for a, b in zip(q, k2q)], [a + h * b for a, b in zip(w, k2w)], h, c)[:2]
    k4q, k4w = _rates_f([a + dt * b for a, b in zip(q, k3q)], [a + dt * b for a, b in zip(w, k3w)], dt, c)[:2]
    f = dt / 6.0
    qn = [q[i] + f * (k1q[i] + 2 * (k2q[i] + k3q[i]) + k4q[i]) for i in range(4)]
    nq = sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    _, _, W, acc = wheels
    out[0:34] = ([v / nq for v in qn] + [w[i] + f * (k1w[i] + 2 * (k2w[i] + k3w[i]) + k4w[i]) for i in range(3)]
                 + out[7:30].tolist() + [a + b * dt for a, b in zip(W, acc)])
    return out


def _cross(a1, a2, a3, b1, b2, b3):
    return a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1


def _j_f2(w, c, wheels, r0, model):
    """J F2. (J times rows 3:6 of F, the blocks of the module docstring) on Python floats, as a flat list of
    41 columns of 3. w = the rate, ``c`` and ``wheels`` from ``_terms_f``, ``r0`` = ``_rates_f`` at s = 0.
    Written out with [a x] B = (columns a x B_j), A [a x] = (rows A_i x a), [m x][b x] = b m^T - (m . b) I."""
    J, _, _, _, _, _, k, (m1, m2, m3), _ = c
    _, (d1, d2, d3), (r1, r2, r3), (b1, b2, b3), (h1, h2, h3) = r0          # d = w_dot, h = H
    w1, w2, w3 = w
    (j11, j12, j13), (j21, j22, j23), (j31, j32, j33) = J
    # F21: k ([r x] J - [(J r) x]) 2 [r x] + [m x] 2 [b x];  A = [r x] J - [(J r) x]
    u1, u2, u3 = j11 * r1 + j12 * r2 + j13 * r3, j21 * r1 + j22 * r2 + j23 * r3, j31 * r1 + j32 * r2 + j33 * r3
    a11, a21, a31 = r2 * j31 - r3 * j21, r3 * j11 - r1 * j31 - u3, r1 * j21 - r2 * j11 + u2
    a12, a22, a32 = r2 * j32 - r3 * j22 + u3, r3 * j12 - r1 * j32, r1 * j22 - r2 * j12 - u1
    a13, a23, a33 = r2 * j33 - r3 * j23 - u2, r3 * j13 - r1 * j33 + u1, r1 * j23 - r2 * j13
    k2 = 2.0 * k
    mb2 = 2.0 * (m1 * b1 + m2 * b2 + m3 * b3)
    c1, c2, c3 = 2.0 * b1, 2.0 * b2, 2.0 * b3
    out = [k2 * (a12 * r3 - a13 * r2) + c1 * m1 - mb2, k2 * (a22 * r3 - a23 * r2) + c2 * m1,
           k2 * (a32 * r3 - a33 * r2) + c3 * m1,
           k2 * (a13 * r1 - a11 * r3) + c1 * m2, k2 * (a23 * r1 - a21 * r3) + c2 * m2 - mb2,
           k2 * (a33 * r1 - a31 * r3) + c3 * m2,
           k2 * (a11 * r2 - a12 * r1) + c1 * m3, k2 * (a21 * r2 - a22 * r1) + c2 * m3,
           k2 * (a31 * r2 - a32 * r1) + c3 * m3 - mb2,
           # F22: [H x] - [w x] J
           -(w2 * j31 - w3 * j21), h3 - (w3 * j11 - w1 * j31), -h2 - (w1 * j21 - w2 * j11),
           -h3 - (w2 * j32 - w3 * j22), -(w3 * j12 - w1 * j32), h1 - (w1 * j22 - w2 * j12),
           h2 - (w2 * j33 - w3 * j23), -h1 - (w3 * j13 - w1 * j33), -(w1 * j23 - w2 * j13),
           # F23: I
           1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    # F24, column k: k r x (E_k r) - E_k w_dot - w x (E_k w), E_k v = (0,v2,0), (0,0,v3), (v2,v1,0), (v3,0,v1),
    # (0,v3,v2) for Jyy, Jzz, Jxy, Jxz, Jyz
    r12, r13, r23, r11, r22, r33 = r1 * r2, r1 * r3, r2 * r3, r1 * r1, r2 * r2, r3 * r3
    w12, w13, w23, w11, w22, w33 = w1 * w2, w1 * w3, w2 * w3, w1 * w1, w2 * w2, w3 * w3
    out += [-k * r23 + w23, -d2, k * r12 - w12,
            k * r23 - w23, -k * r13 + w13, -d3,
            -k * r13 - d2 + w13, k * r23 - d1 - w23, k * (r11 - r22) - (w11 - w22),
            k * r12 - d3 - w12, k * (r33 - r11) - (w33 - w11), -k * r23 - d1 + w23,
            k * (r22 - r33) - (w22 - w33), -k * r12 - d3 + w12, k * r13 - d2 - w13,
            # F25: -[b x]
            0.0, -b3, b2, b3, 0.0, -b1, -b2, b1, 0.0]
    # F26 .. F2b, wheel by wheel (i): -(Jrw W [w x] c + Jrw a c) for c = C1_i, C2_i; -(W [w x] C_i + a C_i);
    # -Jrw [w x] C_i; C_i Jrw/dt; -C_i Jrw/dt
    C, jrw, W, acc = wheels
    f26, f27, f28, f29, f2a, f2b = [], [], [], [], [], []
    for (p1, p2, p3), (q1, q2, q3), (c1, c2, c3), jr, wr, ac in zip(model.c1.T.tolist(), model.c2.T.tolist(),
                                                                     C, jrw, W, acc):
        jw, ja = jr * wr, jr * ac
        f26 += [-(jw * (w2 * p3 - w3 * p2) + ja * p1), -(jw * (w3 * p1 - w1 * p3) + ja * p2),
                -(jw * (w1 * p2 - w2 * p1) + ja * p3)]
        f27 += [-(jw * (w2 * q3 - w3 * q2) + ja * q1), -(jw * (w3 * q1 - w1 * q3) + ja * q2),
                -(jw * (w1 * q2 - w2 * q1) + ja * q3)]
        v1, v2, v3 = w2 * c3 - w3 * c2, w3 * c1 - w1 * c3, w1 * c2 - w2 * c1
        f28 += [-(wr * v1 + ac * c1), -(wr * v2 + ac * c2), -(wr * v3 + ac * c3)]
        f29 += [-jr * v1, -jr * v2, -jr * v3]
        jd = jr / model.dt
        f2a += [c1 * jd, c2 * jd, c3 * jd]
        f2b += [-c1 * jd, -c2 * jd, -c3 * jd]
    return out + f26 + f27 + f28 + f29 + f2a + f2b


def _f2(w, c, wheels, r0, model):
    """Rows 3:6 of F (F21 .. F2b, Eq. 4.99-4.108), 3 x 41: J^-1 (``_j_f2``)."""
    return np.array(c[1]) @ np.array(_j_f2(w, c, wheels, r0, model)).reshape(N, 3).T


def jacobian(x, model, t, m=None):
    """F (41 x 41) of Eq. 4.98 at x (see the module docstring for each block). Only the attitude rows (F11 =
    -[w x], F12 = I/2), the rate rows (``_f2``) and the wheel-speed rows (F9a, F9b) are nonzero."""
    dt = model.dt
    if m is None:
        m = terms(x, model, t)
    c = _consts(x, m)
    w = x[4:7].tolist()
    F = np.zeros((N, N))
    F[0:3, 0:3] = -skew(w)
    F[0:3, 3:6] = 0.5 * EYE3
    F[3:6, :] = _f2(w, c, _wheels(m), _rates_f(x[0:4].tolist(), w, 0.0, c), model)
    F[29:33, 33:37] = EYE_W * (-1.0 / dt)
    F[29:33, 37:41] = EYE_W * (1.0 / dt)
    return F
