"""The APKF: gyroless attitude and parameter estimation (Yoon 2017, Sec. 4.5-4.7, Eq. 4.53-4.145, App. A).

The state, the dynamics and F are ``ground.adcs.apkf_model``'s (re-exported here).

Phi in closed form (Eq. 4.114-4.127, App. A.2): with A = [[F11, F12], [F21, F22]] (attitude and rate), the
parameters constant and W driven linearly by W+- W-, Phi is exactly

    Phi_AA = e^{A dt},  Phi_A,p = G1 F_A,p  (p = tau_d .. Jrw, W),  Phi_A,W+- = G1 F_A,W+- + G2 F_A,W F_W,W+-,
    Phi_W,W+- = F_W,W+- dt,  G1 = int_0^dt e^{A s} ds,  G2 = int_0^dt e^{A s} (dt - s) ds,

which we sum as series in (A dt) to the 4th power (App. A.2 truncates the same series at dt^3). |A dt| is
dominated by J^-1 [H x]: ~0.5 with the Sec. 4.8 wheels near 12 000 rpm (measured: up to 0.55 over the 930 s
run), where the truncation is < 1e-6 of e^{A dt}. Tested against expm(F dt).

Q (Eq. 4.135-4.136), from Phi ~ I + F dt: Q_pp = Q_p dt, Q_wp = F2p Q_p dt^2/2, Q_ww = sum F2p Q_p F2p^T dt^3/3,
for p in tau_d, J5, m, d1/d2, Jrw. The tachometer noise enters through W+ (reset to R_rw, uncorrelated, at
each step; the old W+ becomes W-, keeping its correlations).

Update (Eq. 4.139-4.142): z = vec(q_meas (x) q_hat^-1), H = [I3 0 ...], R = diag(sigma_st^2)/4, Joseph form.
Variable fictitious noise (Sec. 4.7.4): Q and R_st x100 until the first maneuver set ends, x10 until the second
ends, then nominal. Adaptive q_d (Eq. 4.152, Case 3): q_d,i = q_d0 + q_d1 |w_i| + q_d2 sum_{j != i} |w_j|.

That is the thesis's filter (``APKF(form="thesis")``); its 1 sigma is overconfident on its own scenario. The
default ``form="consistent"`` keeps the model and adds an iterated update over each blind stretch
(``update_window``) faded when its fix fails a chi-square test (``apkf_fading``), the second-order terms of the
wheels' C(d) Jrw (``second_order_noise``) and of the dipole's torque with an attitude error
(``dipole_attitude_noise``), R inflated in the
first set only, that set filtered again at its end about its own estimate (``apkf_iterated``), and Case 2's q_d
matched to its disturbance: see ``APKF``. Either form takes tau_d as the thesis's
random walk or as a shaping filter's output (``APKF(disturbance=...)``, ``apkf_disturbance``; Sec. 8.3).
"""

from functools import lru_cache
from math import sqrt

import numpy as np

from ground.adcs import quat
from ground.adcs.apkf_disturbance import DISTURBANCES, QD1, QD2, shaping  # QD1, QD2: Eq. 4.152's q_d1, q_d2
from ground.adcs.apkf_fading import faded
from ground.adcs.apkf_iterated import PASSES, refilter
from ground.adcs.apkf_model import (DEG, EYE6, EYE_N, EYE_W, HOUR, ID1, ID2, IJR, IQ, IW, IWM, IWP, IWR, Model, N,
                                    NW, PARAMS, _cross, _f2, _inv3_f, _propagate, _rates_f, _terms_f,
                                    initial_covariance)
from ground.adcs.apkf_second_order import dipole_attitude_noise, second_order_noise  # noqa: F401
# the model's names the filter's users take from here
from ground.adcs.apkf_model import (IJ, IM, ITD, RPM, c_rw, inertia, initial_state, jacobian, propagate,  # noqa: F401
                                    rates, terms)



@lru_cache(maxsize=4)
def _indices(n):
    """For an n x n P (41, or more with a shaping filter's states after the thesis's): P.take(shift) copies W+'s
    rows and columns into W-'s (``shift_tach``); diag: PARAMS' diagonal in P.ravel()."""
    rows = np.r_[0:33, 37:41, 37:41, 41:n]
    return (rows[:, None] * n + rows[None, :]).ravel(), np.arange(PARAMS.start, PARAMS.stop) * (n + 1)

# nominal process noise (Sec. 4.8), per second
Q_NOMINAL = {
    "qd": (2.0e-7) ** 2 / HOUR,                 # Case 1, (N m)^2/s
    "qJm": (4.7e-5) ** 2 / HOUR, "qJp": (4.7e-6) ** 2 / HOUR,
    "qm": (1e-3) ** 2 / HOUR, "qdelta": (0.01 * DEG) ** 2 / HOUR, "qJrw": (3e-9) ** 2 / HOUR,
}
QD_CASE = {1: (2.0e-7) ** 2 / HOUR, 2: (4.0e-6) ** 2 / HOUR, 3: (2.0e-7) ** 2 / HOUR}
# Case 2's disturbance (Eq. 4.150) is a sine of amplitude A = 1e-6 N m and period T >= 72.7 s. A random walk of
# density q has increments of variance q L over a lag L, the sine (random phase) A^2 (1 - cos(w L)); the
# smallest q at or above it at every lag is max_L A^2 (1 - cos(w L)) / L = 0.7246 A^2 w (at w L = 2.33), w =
# 2 pi / 72.7 s: 6.3e-14 (N m)^2/s, 1.5e-5 N m/sqrt(h), 14x the thesis's 4e-6 N m/sqrt(h). With the thesis's
# value the filter's rate error is 1.4-2.4x its 1 sigma on Case 2 (measured, 4 runs).
QD_CASE2_MATCHED = 0.7246 * 1e-6 ** 2 * 2 * np.pi / 72.7
QD_CONSISTENT = {1: QD_CASE[1], 2: QD_CASE2_MATCHED, 3: QD_CASE[3]}
FORMS = ("consistent", "thesis")
ITER_MAX = 8           # passes of ``update_window`` (measured: 1-3 on Sec. 4.8's runs, 2.1 on average)
ITER_TOL = 0.1         # of the start's 1 sigma per axis: a smaller change no longer moves the fix's linearisation
_QP_FIXED = np.array([Q_NOMINAL["qJm"]] * 2 + [Q_NOMINAL["qJp"]] * 3 + [Q_NOMINAL["qm"]] * 3
                     + [Q_NOMINAL["qdelta"]] * 8 + [Q_NOMINAL["qJrw"]] * 4)


@lru_cache(maxsize=16)
def _series_coefficients(dt, order):
    """Rows: the coefficients of (A dt)^n, n = 0..order, in e^{A dt}, G1 and G2 (see ``phi``)."""
    c = np.zeros((3, order + 1))
    fact = 1.0
    for n in range(order + 1):
        fact *= max(n, 1)
        c[:, n] = 1.0 / fact, dt / (fact * (n + 1)), dt * dt / (fact * (n + 1) * (n + 2))
    c.flags.writeable = False
    return c


def _series(Ad, dt, order):
    """(e^{A dt}, G1, G2) of ``phi`` for the 6 x 6 Ad = A dt, summed to (A dt)^order."""
    powers = np.empty((order + 1, 6, 6))
    powers[0] = EYE6
    powers[1] = Ad
    for n in range(2, order + 1):
        np.matmul(powers[n - 1], Ad, out=powers[n])
    E, G1, G2 = (_series_coefficients(dt, order) @ powers.reshape(order + 1, 36)).reshape(3, 6, 6)
    return E, G1, G2


def phi(F, dt, order=4):
    """Closed-form Phi (App. A.2 construction; see the module docstring). Phi = I except in the attitude
    and rate rows (0:6) and the wheel-speed rows (29:33, columns W-, W+); ``predict`` builds only those rows
    (``_phi_rows``)."""
    E, G1, G2 = _series(F[0:6, 0:6] * dt, dt, order)
    Phi = EYE_N.copy()
    Phi[0:6, 0:6] = E
    Phi[0:6, 6:] = G1 @ F[0:6, 6:]
    Phi[0:6, 33:41] += G2 @ (F[0:6, IWR] @ F[IWR, 33:41])
    Phi[IWR, 33:41] = F[IWR, 33:41] * dt
    return Phi


@lru_cache(maxsize=16)
def _phi_wheel_rows(dt, n=N):
    """Rows 29:33 of ``phi``: W + F9a dt W- + F9b dt W+ (Eq. 4.109-4.110), n columns."""
    R = np.zeros((NW, n))
    R[:, IWR] = EYE_W
    R[:, IWM] = EYE_W * (-1.0 / dt) * dt
    R[:, IWP] = EYE_W * (1.0 / dt) * dt
    R.flags.writeable = False
    return R


def _phi_rows(w, F2, dt, order=4, shaping=None):
    """The rows of ``phi`` that differ from I, 10 x 41: rows 0:6 (attitude, rate) from w (F11 = -[w x],
    F12 = I/2) and the rate rows F2 = F[3:6] alone (F's attitude rows are zero beyond column 6, and
    F[0:6, W] F[W, W-:W+] = [-F2W, F2W]/dt), then the wheel-speed rows 29:33. With a shaping filter's step
    ``shaping`` (``_linearise``; F2 then has its states' columns too) the columns of its states are G1 F_A,d -
    (dt G1 - G2) F_A,d Fd, on their values at the step's end."""
    w1, w2, w3 = (v * dt for v in w)
    h = 0.5 * dt
    Ad = np.empty((6, 6))
    Ad[0:3] = [[0.0, w3, -w2, h, 0.0, 0.0], [-w3, 0.0, w1, 0.0, h, 0.0], [w2, -w1, 0.0, 0.0, 0.0, h]]
    np.multiply(F2[:, 0:6], dt, out=Ad[3:6])
    E, G1, G2 = _series(Ad, dt, order)
    PhiR = np.empty((10, F2.shape[1]))
    PhiR[0:6, 0:6] = E
    np.matmul(G1[:, 3:6], F2[:, 6:], out=PhiR[0:6, 6:])
    if shaping is not None:
        ix = shaping[0]
        PhiR[0:6, ix] -= (dt * G1[:, 3:6] - G2[:, 3:6]) @ (F2[:, ix] @ shaping[4])
    Y = G2[:, 3:6] @ (F2[:, IWR] * (1.0 / dt))
    PhiR[0:6, 33:37] -= Y
    PhiR[0:6, 37:41] += Y
    PhiR[6:10] = _phi_wheel_rows(dt, F2.shape[1])
    return PhiR


def _predict_covariance(P, PhiR, F2, qp, dt, R_rw):
    """``shift_tach`` on P, then Phi P Phi^T + Q (Eq. 4.128, 4.135-4.136) from the rows of Phi that differ from
    I (``_phi_rows``), the rate rows F2 of F and the noise densities qp: only rows and columns 0:6 and 29:33
    of P change, and Q's nonzero blocks are (w, w), (w, p), (p, w) and diag(p). Symmetrised."""
    n = len(P)
    shift, diag = _indices(n)
    Pn = P.take(shift).reshape(n, n)         # W- <- W+ (W+'s correlations kept)
    Pn[IWP] = 0.0
    Pn[:, IWP] = 0.0
    Pn[IWP, IWP] = EYE_W * R_rw              # W+ <- the new read-out
    T = PhiR @ Pn                            # the changed rows of Phi P
    Pn[0:6] = T[0:6]
    Pn[IWR] = T[6:10]
    T = Pn @ PhiR.T                          # the changed columns of (Phi P) Phi^T
    Pn[:, 0:6] = T[:, 0:6]
    Pn[:, IWR] = T[:, 6:10]
    F2p = F2[:, PARAMS]                      # + Q, as ``process_noise``
    Qwp = F2p * (qp * dt * dt / 2)
    Pn[IW, PARAMS] += Qwp
    Pn[PARAMS, IW] += Qwp.T
    Pn[IW, IW] += (F2p * qp) @ F2p.T * (dt ** 3 / 3)
    Pn.ravel()[diag] += qp * dt
    out = Pn + Pn.T
    out *= 0.5
    return out


def noise_density(x, case, scale=1.0, qd=QD_CASE):
    """Diagonal q (per second) of the parameter noises: tau_d (3), J5 (5), m (3), d1/d2 (8), Jrw (4); tau_d's
    from the table ``qd`` (by case), Case 3's by Eq. 4.152."""
    q = np.empty(23)
    if case == 3:
        a1, a2, a3 = (abs(v) for v in x[4:7].tolist())
        s = a1 + a2 + a3
        q0 = Q_NOMINAL["qd"]
        q[0:3] = [q0 + QD1 * a1 + QD2 * (s - a1), q0 + QD1 * a2 + QD2 * (s - a2),
                  q0 + QD1 * a3 + QD2 * (s - a3)]                           # Eq. 4.152
    else:
        q[0:3] = qd.get(case, Q_NOMINAL["qd"])
    q[3:] = _QP_FIXED
    q *= scale
    return q


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


def _linearise(x, w_plus, model, t):
    """``shift_tach`` on x (in place), then the step's model at its start with the orbit and field at mid-step:
    (q, w, c, wheels, r0, F2, PhiR, sd): ``_terms_f``'s constants, ``_rates_f`` at s = 0 (F's point and RK4's
    first stage), the rate rows F2 of F, the rows of Phi that differ from I (``_phi_rows``) and the step of
    tau_d's shaping filter (``model.disturbance``; None: the random walk), sd = (its states' places in the error
    state, Phi_dd, e^{Fd dt/2}, Q_dd, Fd) at x. With one, its states in x move to the step's end
    (Phi = Phi_b S, S = I but Phi_dd on those states; ``_phi_rows``' Phi_b takes them at the end) and the
    dynamics hold tau_d at mid-step (``apkf_disturbance``)."""
    x[34:38] = x[38:42]
    x[38:42] = w_plus
    d = getattr(model, "disturbance", None)
    sd = None
    if d is not None:
        sd = d.step(model.dt, x)
        z = x[sd[0] + 1]
        x[sd[0] + 1] = sd[1] @ z
    c, wheels, _ = _terms_f(x, model, t + 0.5 * model.dt)
    if d is not None:
        c = c[:8] + ((sd[2][0:3] @ z).tolist(),)
    q, w = x[0:4].tolist(), x[4:7].tolist()
    r0 = _rates_f(q, w, 0.0, c)
    F2 = _f2(w, c, wheels, r0, model)
    if d is not None and d.n > N:
        F2 = np.hstack([F2, np.zeros((3, d.n - N))])
    return q, w, c, wheels, r0, F2, _phi_rows(w, F2, model.dt, shaping=sd), sd


def _carry(M, PhiR, sd=None):
    """M <- Phi S M in place: S is ``shift_tach``'s map (W- takes W+'s rows; the new read-out W+ does not
    depend on the stretch's start), Phi the step's (``_phi_rows``: only rows 0:6 and 29:33 differ from I;
    with a shaping filter's step ``sd`` (``_linearise``), its states' rows first moved by its Phi_dd)."""
    if sd is not None:
        M[sd[0]] = sd[1] @ M[sd[0]]
    M[IWM] = M[IWP]
    M[IWP] = 0.0
    T = PhiR @ M
    M[0:6] = T[0:6]
    M[IWR] = T[6:10]


def _shaped(P, ix, Phi_dd):
    """S P S^T, S = I but Phi_dd on the shaping filter's states ``ix`` (``_linearise``)."""
    P = P.copy()
    P[ix] = Phi_dd @ P[ix]
    P[:, ix] = P[:, ix] @ Phi_dd.T
    return P


def _add_shaping_noise(P, ix, Q, F2, dt):
    """P += the shaping filter's Q_dd on its states ``ix`` and its cross terms with the rate, in place (the order
    of Eq. 4.135-4.136: Q_w,d = F_w,d Q_dd dt/2, Q_ww = F_w,d Q_dd F_w,d^T dt^2/3)."""
    F = F2[:, ix]
    Qw = F @ Q * (0.5 * dt)
    P[IW, ix] += Qw
    P[ix, IW] += Qw.T
    P[IW, IW] += F @ Q @ F.T * (dt * dt / 3)
    P[np.ix_(ix, ix)] += Q


def _at_lin_point(x, model):
    """Put ``model.p_lin`` (J5, m, d1, d2, Jrw: x[10:30]), if set, in x; returns the estimate's own (or None)."""
    if model.p_lin is None:
        return None
    p = x[10:30].copy()
    x[10:30] = model.p_lin
    return p


def _from_lin_point(x, p, PhiR, model):
    """x after a step taken at ``model.p_lin`` (``_at_lin_point``) with the estimate's parameters p back: the
    attitude and rate moved by Phi's parameter columns times p - p_lin, to first order."""
    dx = np.zeros(len(x) - 1)
    dx[0:6] = PhiR[0:6, 9:29] @ (p - model.p_lin)
    x[10:30] = p
    return correct(x, dx)


def predict(x, P, w_plus, model, t, case=1, scale=1.0, M=None, qd=QD_CASE, second_order=False):
    """(x, P) at t + dt from t, with the tachometer read-out w_plus at t + dt (rad/s): ``shift_tach``, then
    x by ``propagate`` and P = Phi P Phi^T + Q (Eq. 4.128) with Phi of ``phi`` (Eq. 4.114-4.127) and Q of
    ``process_noise`` (Eq. 4.135-4.136, tau_d's density from ``qd``), computed from the nonzero rows of F and Phi
    only; with ``model.p_lin`` set, F, Phi and the propagation at it (``_at_lin_point``). ``M`` (41 x 41, if
    given) is carried through the step in place (``_carry``): the Jacobian of x on a stretch's start.
    ``second_order``: add ``second_order_noise`` and ``dipole_attitude_noise`` to the rate's
    block. With a shaping filter (``model.disturbance``) tau_d's Phi and Q are its (``_linearise``,
    ``_add_shaping_noise``; Q_dd times ``scale`` only if its ``fictitious``) and P, M are n x n with its added
    states."""
    x = x.copy()
    p = _at_lin_point(x, model)
    q, w, c, wheels, r0, F2, PhiR, sd = _linearise(x, w_plus, model, t)
    Q2 = None
    if second_order:
        Ji = np.array(c[1])
        Q2 = second_order_noise(x, P, model, Ji) + dipole_attitude_noise(P, np.array(r0[3]), Ji, model.dt)
    qp = noise_density(x, case, scale, qd)
    if sd is not None:
        qp[0:3] = 0.0
        P = _shaped(P, sd[0], sd[1])
    P = _predict_covariance(P, PhiR, F2, qp, model.dt, model.R_rw)
    if sd is not None:
        _add_shaping_noise(P, sd[0], sd[3] * (scale if model.disturbance.fictitious else 1.0), F2, model.dt)
    if Q2 is not None:
        P[IW, IW] += Q2
    if M is not None:
        _carry(M, PhiR, sd)
    x = _propagate(x, q, w, model.dt, c, wheels, r0[:2])
    return (x if p is None else _from_lin_point(x, p, PhiR, model)), P


def propagate_window(x, steps, model):
    """(x_b, M): the state after a stretch of predictions from x (``steps``: (t, w_plus[, m_ctrl]) per step, as
    ``predict``'s, m_ctrl the model's magnetorquer input then, default the model's own), and M = d x_b / d x, the
    product of the steps' Phi and ``shift_tach`` maps; both at ``model.p_lin`` where set (``_at_lin_point``)."""
    x = np.array(x, dtype=float)
    M = np.eye(len(x) - 1)
    m_now = getattr(model, "m_ctrl", None)
    try:
        for st in steps:
            t, w_plus = st[0], st[1]
            model.m_ctrl = st[2] if len(st) > 2 else m_now
            p = _at_lin_point(x, model)
            q, w, c, wheels, r0, _, PhiR, sd = _linearise(x, w_plus, model, t)
            _carry(M, PhiR, sd)
            _propagate(x, q, w, model.dt, c, wheels, r0[:2])
            if p is not None:
                x = _from_lin_point(x, p, PhiR, model)
    finally:
        model.m_ctrl = m_now
    return x, M


def difference(x, y):
    """x - y in the error coordinates (41, or more with a shaping filter's): dq = vec(q_x (x) q_y^-1) (Eq. 4.77),
    the rest subtracted."""
    d = np.empty(len(x) - 1)
    d[IQ] = quat.error_vec(x[0:4], y[0:4])
    d[3:] = x[4:] - y[4:]
    return d


def update_window(xa, Pa, steps, xb, Pb, M, q_meas, R, model, max_iter=ITER_MAX, tol=ITER_TOL):
    """The star-tracker update after a stretch without outputs, iterated (Gauss-Newton on the stretch's start;
    Bell and Cathey's iterated Kalman filter carried over the stretch as a fixed-interval smoother).

    (xa, Pa): the estimate after the last update; ``steps``: the stretch's predictions (``predict``), which
    took it to (xb, Pb) with M = d xb / d xa (``propagate_window``). Q_s = Pb - M Pa M^T is what the stretch
    added (process noise, read-outs). Pass i linearises about a start x_i (x_0 = xa): with da = xa - x_i,
    the prior at the fix is x_b,i (x_i propagated) + M_i da with P_b,i = M_i Pa M_i^T + Q_s, and the update
    (Eq. 4.139-4.142 at x_b,i) moves the start to x_i + da + Pa M_i^T H^T S^-1 nu. The passes stop when the
    start moves by less than ``tol`` of its 1 sigma on every axis, after ``max_iter``, or when a start cannot be
    carried over the stretch (not finite; the last pass is kept); the first pass alone is the EKF update.
    Returns (x, P, passes)."""
    Qs = Pb - M @ Pa @ M.T
    sa = np.sqrt(np.diag(Pa))
    xi = xa
    for n in range(1, max_iter + 1):
        da = difference(xa, xi)
        db = M @ da
        if n > 1:
            Pb = M @ Pa @ M.T + Qs
        z = quat.error_vec(q_meas, xb[0:4])
        S = Pb[IQ, IQ] + R
        nu = np.linalg.solve(S, z - db[IQ])
        x_next = correct(xi, da + (Pa @ M[IQ].T) @ nu)
        if n == max_iter or np.max(np.abs(difference(x_next, xi)) / sa) < tol:
            break
        xb_next, M_next = propagate_window(x_next, steps, model)
        if not (np.all(np.isfinite(xb_next)) and np.all(np.isfinite(M_next))):
            break                           # a start the model cannot carry: keep the last pass
        xi, xb, M = x_next, xb_next, M_next
    K = Pb[:, IQ] @ np.linalg.inv(S)
    AP = Pb - K @ Pb[IQ, :]
    P = AP - (AP[:, IQ] - K @ R) @ K.T
    out = P + P.T
    out *= 0.5
    return correct(xb, db + Pb[:, IQ] @ nu), out, n


def _qmul(q, p):
    """``quat.quat_mul`` on 4 Python floats."""
    q1, q2, q3, q4 = q
    p1, p2, p3, p4 = p
    c1, c2, c3 = _cross(q1, q2, q3, p1, p2, p3)
    return (q4 * p1 + p4 * q1 - c1, q4 * p2 + p4 * q2 - c2, q4 * p3 + p4 * q3 - c3,
            q4 * p4 - (q1 * p1 + q2 * p2 + q3 * p3))


def update(x, P, q_meas, R):
    """Star-tracker update, Eq. 4.139-4.142, Joseph form, with H = [I3 0 ...] as slicing."""
    e1, e2, e3, e4 = x[0:4].tolist()
    d = _qmul(q_meas.tolist() if hasattr(q_meas, "tolist") else q_meas, (-e1, -e2, -e3, e4))
    z = d[0:3] if d[3] >= 0 else (-d[0], -d[1], -d[2])                      # quat.error_vec (Eq. 4.139)
    (a, b, c), (_, d, e), (_, _, f) = (P[IQ, IQ] + R).tolist()
    Si = np.array(_inv3_f(a, b, c, d, e, f))                                 # (H P H^T + R)^-1, symmetric
    K = P[:, IQ] @ Si                                                        # P H^T S^-1 (Eq. 4.140)
    dx = K @ z                                                               # Eq. 4.141
    # Eq. 4.142: (I - K H) P (I - K H)^T + K R K^T = A P - (A P H^T - K R) K^T with A P = P - K H P
    AP = P - K @ P[IQ, :]
    P = AP - (AP[:, IQ] - K @ R) @ K.T
    out = P + P.T
    out *= 0.5
    return correct(x, dx), out


def correct(x, dx):
    """Apply an error-state correction: q = dq (x) q_hat (``quat.from_small``, Eq. 4.51), the rest additive."""
    out = np.empty_like(x)
    np.add(x[4:], dx[3:], out=out[4:])
    d1, d2, d3 = dx[0:3].tolist()
    n2 = d1 * d1 + d2 * d2 + d3 * d3
    q = _qmul((d1, d2, d3, sqrt(1.0 - n2) if n2 < 1.0 else 0.0), x[0:4].tolist())
    nq = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    out[0:4] = [v / nq for v in q]
    return out


def fictitious_scale(t, set_ends):
    """Sec. 4.7.4: x100 until the first maneuver set ends, x10 until the second, then 1."""
    if len(set_ends) > 0 and t < set_ends[0]:
        return 100.0
    if len(set_ends) > 1 and t < set_ends[1]:
        return 10.0
    return 1.0


def fictitious_scales(t, set_ends, form="consistent", dt=1.0):
    """(Q scale over the step from t, R scale of the output at t + dt): ``fictitious_scale``'s for the thesis's
    form (Sec. 4.7.4); the consistent form keeps x100 on both in the first set and x10 on Q alone in the second
    (R at x10 there left the filter under-confident in the holds, NEES 3.4 against 6, while the iterated
    update handles what the inflated R was for: measured, 20 runs of Case 1). ``APKF`` drops the second set's
    x10 where its first set was filtered again (``apkf_iterated``)."""
    if form == "thesis":
        return fictitious_scale(t, set_ends), fictitious_scale(t + dt, set_ends)
    return fictitious_scale(t, set_ends), 100.0 if len(set_ends) > 0 and t + dt < set_ends[0] else 1.0


def check_covariance(P, t, name="APKF"):
    """Divergence check: FloatingPointError naming the filter and the time unless P is finite and positive
    definite."""
    if not np.all(np.isfinite(P)):
        raise FloatingPointError("%s diverged at t = %.0f s: P is not finite" % (name, t))
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise FloatingPointError("%s diverged at t = %.0f s: P is not positive definite" % (name, t)) from None


def shaping_states(x, P, sf):
    """(x, P) with a shaping filter's states (``apkf_disturbance``): a second order's appended at zero; the
    prior of all, tau_d's too, its stationary covariance (``ShapingFilter.prior``), uncorrelated with the rest."""
    x = np.concatenate([x, np.zeros(sf.n - N)])
    Pn = np.zeros((sf.n, sf.n))
    Pn[:N, :N] = P
    Pn[ITD] = Pn[:, ITD] = 0.0
    Pn[np.ix_(sf.ix, sf.ix)] = sf.prior()
    return x, Pn


class APKF:
    """The APKF over a recorded run: ``step(t, w_plus, q_meas or None)`` per dt.

    ``form``: "consistent" (default) or "thesis", the filter as the thesis writes it (Eq. 4.139-4.142 at every
    output, Sec. 4.7.4's fictitious noise, Case 2's q_d of Sec. 4.8). The consistent form differs in six
    places, each for a measured reason (20 runs of Case 1 unless said):
    - the first star-tracker output after a stretch of two or more steps without one goes through
      ``update_window``: after a blind rotation the attitude can be tens of degrees off (45 deg after the first
      set's second rotation), and one linear update then moves the parameters by the wrong amount and locks
      them outside their 3 sigma (seed 0: the parameters' NEES went from 30 to 990 at that fix);
    - R is inflated in the first maneuver set only (``fictitious_scales``);
    - Case 2's q_d is the one matched to its disturbance (``QD_CASE2_MATCHED``);
    - the rate's P takes the second-order term of the wheels' C(d) Jrw (``second_order_noise``): without it the
      parameters' NEES was 45 for 23 dof in the second set (31 with it), and the attitude + rate NEES left its
      band in the blind stretches (in band 0.69 / 0.87 of the second / third set's steps; 0.79 / 0.96 with it);
      and the term of the dipole's torque with an attitude error (``dipole_attitude_noise``): without it vehicles
      drawn within thesis-3u's block (0.3 A m^2 dipole) were overconfident over the blind stretches (100 vehicles:
      NEES mean 9.4 against 8.3 with it, RMS / 1 sigma 1.29-1.31 against 1.20-1.26);
    - a fix after a stretch whose innovation fails a chi-square test against the prior scales the stretch's start
      P up until it passes (``apkf_fading``; ``fadings``: one (t, lambda) each);
    - at the first set's end the set is filtered again from its start with the parameters linearised at its
      end-of-set estimate, ``first_set_passes`` times, the second set then without fictitious noise
      (``apkf_iterated``; ``iterations``: (t, passes)): filtered once, 100 vehicles drawn within thesis-3u's
      block ended the set with the parameters' NEES at 78 for 20 dof (18.5 filtered again), NEES 7.15 after.
    ``gate``: a chi-square bound (3 dof) on the star tracker's normalised innovation; an output beyond it is not
    fused but resets the attitude (``reset_attitude``; ``resets``: one (t, NIS, angle arcsec) each). None (the
    default, the thesis's filter): every output is fused.
    ``reacquisitions``: one (t, steps, passes) per iterated update; ``qd`` and ``second_order`` (both terms) are
    the form's (a diagnostic may change them).
    ``disturbance``: tau_d's model, "white" (the thesis's random walk, default), "markov" or "harmonic" (the
    shaping filters of ``apkf_disturbance``, first and second order, for the case by its rules), set on
    ``model.disturbance``; a second-order one appends its states to x and P (``shaping_states``)."""

    def __init__(self, x0, model=None, case=1, set_ends=(), form="consistent", disturbance="white"):
        if form not in FORMS:
            raise ValueError("form must be one of %s, got %r" % (", ".join(FORMS), form))
        if disturbance not in DISTURBANCES:
            raise ValueError("disturbance must be one of %s, got %r" % (", ".join(DISTURBANCES), disturbance))
        self.model = model or Model()
        sf = self.model.disturbance = None if disturbance == "white" else shaping(case, disturbance)
        self.x = np.array(x0, dtype=float)
        # the consistent form's P0 holds the spread of the Jxx-relative scale; the thesis's holds Jxx exact
        self.P = initial_covariance(self.model, self.x if form == "consistent" else None)
        if sf is not None:
            self.x, self.P = shaping_states(self.x, self.P, sf)
        self.case = case
        self.set_ends = list(set_ends)
        self.form = form
        self.qd = QD_CASE if form == "thesis" else QD_CONSISTENT
        self.second_order = form == "consistent"
        self.fading, self.fadings = form == "consistent", []
        self.reacquisitions = []
        self._stretch = None            # (x, P, steps, M) since the last star-tracker output
        self.gate = None                # NIS above which a star-tracker output resets the attitude (None: never)
        self.resets = []
        # the consistent form's first set: its start, then its steps, filtered again at its end (``apkf_iterated``)
        self._first = [] if form == "consistent" and self.set_ends else None
        self.iterations = []            # (t, passes) of ``apkf_iterated.refilter``
        self.first_set_passes = PASSES  # its passes (0: the first set is not filtered again)

    def reset_attitude(self, q_meas, R):
        """Take the star tracker's attitude as the estimate (a re-acquisition after a loss): q = q_meas, its
        covariance R and its correlations with the rest zero; the rate and parameters keep theirs."""
        self.x[0:4] = np.asarray(q_meas, float) / np.linalg.norm(q_meas)
        self.P[IQ, :] = 0.0
        self.P[:, IQ] = 0.0
        self.P[IQ, IQ] = R
        self._stretch = None

    def step(self, t, w_plus, q_meas=None):
        """Propagate from t to t + dt with the read-out at t + dt, then update if a star-tracker output came; in
        the consistent form, at the first set's end the set is filtered again (``apkf_iterated.refilter``)."""
        if self._first is None:
            return self._step(t, w_plus, q_meas)
        if not self._first:
            self._first.append((self.x.copy(), self.P.copy()))      # the start as the first step finds it
        self._first.append((t, np.array(w_plus, dtype=float), None if q_meas is None else np.array(q_meas, float),
                            self.model.m_ctrl))
        self._step(t, w_plus, q_meas)
        if t + self.model.dt >= self.set_ends[0]:
            if self.first_set_passes:
                refilter(self, self.first_set_passes, check_covariance)
            self._first = None
        return self.x, self.P

    def _step(self, t, w_plus, q_meas):
        m = self.model
        s_q, s_r = fictitious_scales(t, self.set_ends, self.form, m.dt)
        if self.iterations and self.iterations[-1][1]:
            s_q = 1.0                   # the first set filtered again: no fictitious noise left to add
        M = None
        if self.form == "consistent":
            if self._stretch is None:
                self._stretch = (self.x, self.P, [], np.eye(len(self.P)))
            self._stretch[2].append((t, np.array(w_plus, dtype=float), getattr(m, "m_ctrl", None)))
            M = self._stretch[3]
        self.x, self.P = predict(self.x, self.P, w_plus, m, t, self.case, s_q, M=M, qd=self.qd,
                                 second_order=self.second_order)
        if q_meas is None:
            return self.x, self.P
        R = m.R_st * s_r
        stretch, self._stretch = self._stretch, None
        if self.gate is not None:
            z = quat.error_vec(np.asarray(q_meas, float), self.x[0:4])
            nis = float(z @ np.linalg.solve(self.P[IQ, IQ] + R, z))
            if not nis <= self.gate:
                self.reset_attitude(q_meas, R)
                self.resets.append((t + m.dt, nis, 2.0 * float(np.linalg.norm(z)) / quat.RAD_PER_ARCSEC))
                return self.x, self.P
        if stretch is not None and len(stretch[2]) >= 2:
            xa, Pa, steps, M = stretch
            if self.fading:
                Pa, self.P, lam = faded(Pa, self.P, M, quat.error_vec(q_meas, self.x[0:4]), R)
                if lam > 1.0:
                    self.fadings.append((t + m.dt, lam))
            self.x, self.P, n = update_window(xa, Pa, steps, self.x, self.P, M, q_meas, R, m)
            self.reacquisitions.append((t + m.dt, len(steps), n))
        else:
            self.x, self.P = update(self.x, self.P, q_meas, R)
        return self.x, self.P
