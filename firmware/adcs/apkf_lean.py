"""The lean APKF for pointing (flight code, MicroPython): 9 error states, parameters from the calibration file.

Grounds (Yoon 2017): the remark after Case 1 (Sec. 4.8.1) that once the maneuvers have calibrated the inertia,
wheel alignment and wheel inertias they can be held, and the Ch. 6 parameter file that carries them to the
pointing phase. The full 41-state filter is ``ground/adcs/apkf.py``; this one keeps

    x = [q (4), w (3) rad/s, tau_d (3) N m]          dx = [dq (3), dw (3), dtau_d (3)]   (Eq. 4.76-4.78, cut)

and takes J (Jxx reference + J5), C = C0 + C1 D(d1) + C2 D(d2) (Eq. 4.60), Jrw and the dipole m from the
calibration parameter file (``protocol.paramfile``, "fps-bps-params/1", checked by its checker), all in the
file's (filter-scaled) units.

Dynamics (Eq. 4.67, 4.83), RK4 over the step with the wheel momentum C Jrw W(s) = hw + s hd (Eq. 4.95's
linear W(s); hw = C Jrw W- from the read-out at the step's start):
    Jm w_dot = -w x (J w + hw + s hd) - hd + 3 mu/r^3 r x J r + m x b + tau_d
The momentum rate hd (``momentum_rate``) comes by default ("filtered", what app.py flies) from the difference
of two wheel speeds that each wheel's own scalar Kalman filter (``wheel_speeds``) estimates from its 10 rpm
read-outs and the torques the flight software commanded, through the rotor equation Jrw W_dot = tau_motor -
tau_f (absolute W; the thesis has the reaction torque -C Jrw W_dot, Eq. 4.56, but no rotor equation: derived,
as the emulator integrates it). This is what the 41-state filter does with its wheel-speed states (Eq. 4.78,
4.98), kept outside the 9 states: Jm = J, hd = C Jrw (W+ - W-)/dt with the filtered speeds, and the rate noise
G var G^T with var the variance of each speed change's error. It keeps the read-outs' hold on the momentum the
wheels really exchanged (a slew's large torques, whose 5 % error exceeds the read-out noise, follow the
read-outs) and smooths their noise where the commands are well known (pointing). Over 600 s CAN sessions with
the calibrated parameter file it gives stability 3 sigma ~14 arcsec/s where the raw read-out difference gives
~47 (bench_adcs_can). The two other inputs are kept for that comparison:
- "torque": hd = s C (sat(u) - f(W-)), with u the motor torques commanded over the step, sat the datasheet
  torque limit, f the friction model (viscous + Coulomb, tanh-smoothed; the same datasheet figures the
  controller compensates with), s the file's torque scale and C the unit axes (Eq. 4.54). The read-outs'
  W_rel = W - C^T w turns Eq. 4.67's J into Jm = J - C D(Jrw) C^T (derived: C Jrw W_rel_dot = C (u - f) -
  C Jrw C^T w_dot). The 10 rpm read-outs then enter only hw (the gyroscopic term), where their noise is
  negligible. The commanded torque's own error, a fraction torque_rel (assumed 5 %: the wheel's torque
  constant and the file's torque scale; measured over CAN with a calibrated file: ~2 % between s C (u - f)
  and the read-outs' momentum change) gives r = (torque_rel s u dt)^2. Each wheel takes whichever input has
  the smaller variance, so a slew's large torques (|u| > ~1e-4 N m) take the read-out difference. What the
  commands cannot tell is taken from the read-outs too, with its noise (Q_ww += G r G^T, the Eq. 4.135
  construction for a white input, G = Jm^-1 times the wheel's column): a wheel near zero speed (|W-| <
  3 sigma_tach + dt s (|u| + f_c)/Jrw), where the friction's sign is unknown and the rotor sticks while
  |u| < f_c: its read-out difference, r = 2 R_rw (conservative: consecutive steps share a read-out); a wheel
  whose u is NaN (the caller did not hear it, so what it did is unknown): nothing, and r = (s f_c dt)^2, a
  coasting rotor's friction (derived). Before app.py's first-acquisition rule it lost the star tracker for
  good in the first slew with seed 0's calibrated file (the file's parameter errors leave a rate error that
  nothing but the modelled torques carries while the tracker is blind, and the body rate stayed above its
  0.1 deg/s limit); with the rule, 102.6 arcsec / 14.4 arcsec/s on that file (bench_adcs_can).
- "tach": differencing two read-outs per step (Eq. 4.62, Jm = J, hd = C Jrw (W+ - W-)/dt, the ground
  filter's input) is a white torque of sqrt(2) 10 rpm Jrw per wheel, ~4x the disturbance torque.
Not modelled: the driver's speed limit cut (only near the datasheet's top speed), a late command (the emulator's
wheels then hold the previous one); motor-torque errors beyond friction are absent in the emulator, and a slow
friction drift is tau_d's (its random walk q_d). The orbit direction r, 3 mu/r^3 and the field b (inertial)
are inputs (from the STKF and the field model).

F (Eq. 4.98-4.101, the 9 x 9 corner of ground/adcs/apkf.py's derivation, Jm^-1 for its J^-1):
    F11 = -[w x], F12 = I/2, F21 = Jm^-1 {3 mu/r^3 ([r x] J - [(J r) x]) 2[r x] + [m x] 2[b x]},
    F22 = Jm^-1 (-[w x] J + [H x]), H = J w + hw, F23 = Jm^-1, the tau_d rows zero.
Phi = sum_{n<=4} (F dt)^n / n! (App. A.2's series; |F dt| ~ 0.03). Q (Eq. 4.135-4.136) for q_d:
    Q_tt = q_d dt I, Q_wt = Jm^-1 q_d dt^2/2, Q_ww = Jm^-1 Jm^-T q_d dt^3/3 (+ the read-out terms above).
Star-tracker update (Eq. 4.139-4.142): z = vec(q_meas (x) q_hat^-1), H = [I3 0 0], R = diag(sigma^2)/4, Joseph
form, P kept symmetric (linalg.joseph_select). Every buffer is allocated once, in ``LeanApkf``.
"""

import math

from firmware.adcs import linalg
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators

# the model, re-exported here for the filter's users
from firmware.adcs.apkf_lean_model import (ALL, FRICTION, MOMENTUM, N, TORQUE_MAX, TORQUE_REL,  # noqa: F401
                                           Model, Work, _add_rate_noise, _mirror3, friction, initial_covariance)


@micropython.native
def _dcm_apply2(out, q, a, b):
    """out[0:3] = A(q) a, out[3:6] = A(q) b (inertial to body, scalar-last q, Eq. 4.7), A formed once."""
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    a00 = q1 * q1 - q2 * q2 - q3 * q3 + q4 * q4
    a01 = 2.0 * (q1 * q2 + q3 * q4)
    a02 = 2.0 * (q1 * q3 - q2 * q4)
    a10 = 2.0 * (q1 * q2 - q3 * q4)
    a11 = -q1 * q1 + q2 * q2 - q3 * q3 + q4 * q4
    a12 = 2.0 * (q2 * q3 + q1 * q4)
    a20 = 2.0 * (q1 * q3 + q2 * q4)
    a21 = 2.0 * (q2 * q3 - q1 * q4)
    a22 = -q1 * q1 - q2 * q2 + q3 * q3 + q4 * q4
    for o, v in ((0, a), (3, b)):
        x, y, z = v[0], v[1], v[2]
        out[o] = a00 * x + a01 * y + a02 * z
        out[o + 1] = a10 * x + a11 * y + a12 * z
        out[o + 2] = a20 * x + a21 * y + a22 * z


@micropython.native
def _slope(ks, o, y, x, model, hw, hd, s, env, v):
    """RK4 slope at stage state y = [q, w] and s seconds into the step into ks[o:o+7] (Eq. 4.10, 4.83):
    the wheel momentum C Jrw W(s) = hw + hd s, its rate hd (3 each, from ``momentum_rate``)."""
    J, m = model.J, model.m
    r_i, kgg, b_i = env
    _dcm_apply2(v, y, r_i, b_i)                   # r_b in v[0:3], b_b in v[3:6]
    w0, w1, w2 = y[4], y[5], y[6]
    for i in range(3):
        v[6 + i] = J[i * 3] * w0 + J[i * 3 + 1] * w1 + J[i * 3 + 2] * w2 + hw[i] + hd[i] * s     # H
        v[12 + i] = J[i * 3] * v[0] + J[i * 3 + 1] * v[1] + J[i * 3 + 2] * v[2]   # J r
    h0, h1, h2 = v[6], v[7], v[8]
    r0, r1, r2 = v[0], v[1], v[2]
    jr0, jr1, jr2 = v[12], v[13], v[14]
    b0, b1, b2 = v[3], v[4], v[5]
    t0 = -(w1 * h2 - w2 * h1) - hd[0] + kgg * (r1 * jr2 - r2 * jr1) + (m[1] * b2 - m[2] * b1) + x[7]
    t1 = -(w2 * h0 - w0 * h2) - hd[1] + kgg * (r2 * jr0 - r0 * jr2) + (m[2] * b0 - m[0] * b2) + x[8]
    t2 = -(w0 * h1 - w1 * h0) - hd[2] + kgg * (r0 * jr1 - r1 * jr0) + (m[0] * b1 - m[1] * b0) + x[9]
    e0, e1, e2, q4 = y[0], y[1], y[2], y[3]
    ks[o] = 0.5 * (q4 * w0 - (w1 * e2 - w2 * e1))
    ks[o + 1] = 0.5 * (q4 * w1 - (w2 * e0 - w0 * e2))
    ks[o + 2] = 0.5 * (q4 * w2 - (w0 * e1 - w1 * e0))
    ks[o + 3] = -0.5 * (w0 * e0 + w1 * e1 + w2 * e2)
    Ji = model.Ji
    for i in range(3):
        ks[o + 4 + i] = Ji[i * 3] * t0 + Ji[i * 3 + 1] * t1 + Ji[i * 3 + 2] * t2


@micropython.native
def momentum_rate(hw, hd, Qw, model, wm, wp, u, var=None):
    """The wheel momentum at the step's start hw = C Jrw W- (Eq. 4.55, from the read-out) and its rate over the
    step hd (3 each, the file's torque units). Returns the rate noise (3 x 3) the inputs add: with "tach" the
    constant ``model.Qw_tach`` (formed once in ``Model.use``), with "torque" and "filtered" the buffer Qw, filled
    here.

    "tach" (Eq. 4.62, 4.95): hd = C Jrw (W+ - W-)/dt for every wheel, Qw = G (2 R_rw) G^T with G = Jm^-1 C
    D(Jrw) (the Eq. 4.135 construction; conservative: consecutive steps share a read-out).
    "filtered": the same with wm, wp the filtered speeds of ``wheel_speeds`` and, per wheel, the variance var[k]
    of their difference's error in place of 2 R_rw (conservative over more steps in the same way).
    "torque" (Eq. 4.56 with the rotor equation Jrw W_dot = tau_motor - tau_f, derived): wheel k adds
    s c_k (sat(u_k) - f(W-_k)), u the motor torques commanded over the step (N m, sat: the datasheet limit),
    f the friction model, s the file's torque scale. Near zero speed the friction's sign is not known from a
    10 rpm read-out (and the rotor sticks while |u| < the Coulomb torque): a wheel with |W-| < 3 sigma_tach +
    dt s (|u| + f_c)/Jrw (it may reach zero within the step), or one whose torque error (torque_rel s u dt)^2
    exceeds its read-out difference's 2 R_rw Jrw^2, adds the read-out difference instead, and its share of the
    tachometer noise to Qw; the others add their torque error to Qw. A wheel whose u is NaN (its read-out
    missed: what it did is not known) adds nothing, and as noise the Coulomb torque a coasting rotor exerts,
    (s f_c dt)^2 (derived)."""
    CJ, Ji = model.CJ, model.Ji
    for i in range(3):
        h = 0.0
        for k in range(4):
            h += CJ[i * 4 + k] * wm[k]
        hw[i] = h
        hd[i] = 0.0
    dt = model.dt
    if not model.torque:                           # every wheel on its speed difference
        for k in range(4):
            a = (wp[k] - wm[k]) / dt
            for i in range(3):
                hd[i] += CJ[i * 4 + k] * a
        if not model.filtered:                     # the read-outs': Qw is constant
            return model.Qw_tach
        v0, v1, v2, v3 = var
        a, b, c, d = model.GG
        Qw[0] = v0 * a[0] + v1 * b[0] + v2 * c[0] + v3 * d[0]
        Qw[1] = Qw[3] = v0 * a[1] + v1 * b[1] + v2 * c[1] + v3 * d[1]
        Qw[2] = Qw[6] = v0 * a[2] + v1 * b[2] + v2 * c[2] + v3 * d[2]
        Qw[4] = v0 * a[3] + v1 * b[3] + v2 * c[3] + v3 * d[3]
        Qw[5] = Qw[7] = v0 * a[4] + v1 * b[4] + v2 * c[4] + v3 * d[4]
        Qw[8] = v0 * a[5] + v1 * b[5] + v2 * c[5] + v3 * d[5]
        return Qw
    C, sc, tm = model.C, model.scale, model.torque_max
    linalg.fill(Qw, 9, 0.0)
    for k in range(4):
        M, r = CJ, 2.0 * model.R_rw                # the read-out difference and its noise
        uk = u[k]
        if uk != uk:                               # not known (no read-out): nothing added, a coasting rotor's
            M, r = C, (sc * model.friction[0] * dt) ** 2           # friction as the noise
        else:
            uk = tm if uk > tm else (-tm if uk < -tm else uk)
            rt = (model.torque_rel * sc * uk * dt) ** 2          # the torque's error over the step
            if (abs(wm[k]) >= model.tach_3sigma + dt * sc * (abs(uk) + model.friction[0]) / model.jrw[k]
                    and rt < r * model.jrw[k] ** 2):
                t = sc * (uk - friction(model, wm[k]))
                for i in range(3):
                    hd[i] += C[i * 4 + k] * t
                M, r = C, rt
        if M is CJ:
            a = (wp[k] - wm[k]) / dt
            for i in range(3):
                hd[i] += CJ[i * 4 + k] * a
        _add_rate_noise(Qw, Ji, M, k, r)
    _mirror3(Qw)
    return Qw


@micropython.native
def propagate(x, model, hw, hd, env, work):
    """x over one step (RK4, Eq. 4.95) with the wheel momentum hw + hd s (``momentum_rate``)."""
    dt = model.dt
    ks, y, v = work.k, work.y, work.v
    for i in range(7):
        y[i] = x[i]
    _slope(ks, 0, y, x, model, hw, hd, 0.0, env, v)
    for st in range(1, 4):
        h = dt if st == 3 else 0.5 * dt
        o = (st - 1) * 7
        for i in range(7):
            y[i] = x[i] + h * ks[o + i]
        _slope(ks, st * 7, y, x, model, hw, hd, h, env, v)
    for i in range(7):
        x[i] = x[i] + dt / 6.0 * (ks[i] + 2.0 * (ks[7 + i] + ks[14 + i]) + ks[21 + i])
    n = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
    for i in range(4):
        x[i] = x[i] / n


@micropython.native
def jacobian(F, x, model, hw, env, work):
    """F (9 x 9) of Eq. 4.98-4.101 at x (see the module docstring), with C Jrw W = hw. Only the entries that
    can be non-zero are written: F's structural zeros must be zero on entry (``Work.F`` is, and stays so)."""
    J, Ji, m = model.J, model.Ji, model.m
    v = work.v
    r_i, kgg, b_i = env
    _dcm_apply2(v, x, r_i, b_i)
    w = (x[4], x[5], x[6])
    for i in range(3):
        v[6 + i] = J[i * 3] * w[0] + J[i * 3 + 1] * w[1] + J[i * 3 + 2] * w[2] + hw[i]
        v[9 + i] = J[i * 3] * v[0] + J[i * 3 + 1] * v[1] + J[i * 3 + 2] * v[2]
    F[1], F[2], F[9], F[11], F[18], F[19] = w[2], -w[1], -w[2], w[0], w[1], -w[0]     # -[w x]
    F[3], F[13], F[23] = 0.5, 0.5, 0.5
    # M = kgg ([r x] J - [(J r) x]) 2[r x] + [m x] 2[b x]  (3 x 3) into T1[0:9], then F21 = Ji M
    T = work.T1
    r0, r1, r2 = v[0], v[1], v[2]
    b0, b1, b2 = v[3], v[4], v[5]
    jr = (v[9], v[10], v[11])
    rx = (0.0, -r2, r1, r2, 0.0, -r0, -r1, r0, 0.0)
    bx = (0.0, -b2, b1, b2, 0.0, -b0, -b1, b0, 0.0)
    mx = (0.0, -m[2], m[1], m[2], 0.0, -m[0], -m[1], m[0], 0.0)
    jrx = (0.0, -jr[2], jr[1], jr[2], 0.0, -jr[0], -jr[1], jr[0], 0.0)
    # the sums over k are written out (same operations, same order); T (float32) holds each product
    J0, J1, J2 = J[0:3], J[3:6], J[6:9]               # (model constants: lists)
    for i in range(3):
        a0, a1, a2 = rx[i * 3:i * 3 + 3]
        for j in range(3):
            T[9 + i * 3 + j] = a0 * J0[j] + a1 * J1[j] + a2 * J2[j] - jrx[i * 3 + j]   # [r x] J - [(J r) x]
    M1 = list(T[9:18])
    for i in range(3):
        t0, t1, t2 = M1[i * 3:i * 3 + 3]
        m0, m1, m2 = mx[i * 3:i * 3 + 3]
        for j in range(3):
            T[i * 3 + j] = ((kgg * t0 * 2.0 * rx[j] + m0 * 2.0 * bx[j])
                            + (kgg * t1 * 2.0 * rx[3 + j] + m1 * 2.0 * bx[3 + j])
                            + (kgg * t2 * 2.0 * rx[6 + j] + m2 * 2.0 * bx[6 + j]))
    wx = (0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0)
    hh = (v[6], v[7], v[8])
    hx = (0.0, -hh[2], hh[1], hh[2], 0.0, -hh[0], -hh[1], hh[0], 0.0)
    for i in range(3):
        a0, a1, a2 = wx[i * 3:i * 3 + 3]
        for j in range(3):
            T[18 + i * 3 + j] = hx[i * 3 + j] - a0 * J0[j] - a1 * J1[j] - a2 * J2[j]
    M, G, Jil = list(T[0:9]), list(T[18:27]), Ji
    for i in range(3):
        j0, j1, j2 = Jil[i * 3:i * 3 + 3]
        o = (3 + i) * 9
        for j in range(3):
            F[o + j] = j0 * M[j] + j1 * M[3 + j] + j2 * M[6 + j]
            F[o + 3 + j] = j0 * G[j] + j1 * G[3 + j] + j2 * G[6 + j]
            F[o + 6 + j] = Jil[i * 3 + j]


@micropython.native
def phi(Phi, F, dt, work, order=4):
    """Phi = sum_{n<=order} (F dt)^n / n! (App. A.2's series). F's tau_d rows are zero, so every power's
    rows 6-8 are zero and row i of F^n is sum over k < 6 of F^(n-1)[i, k] F[k, :]; of rows 0-2 of F only
    -[w x]'s off-diagonal and F12 = I/2 are non-zero (Eq. 4.98), and their zeros are skipped (adding an exact
    zero changes no sum). Each power is stored in T1 (float32) and read once."""
    term = work.T1
    Fl = list(F[0:54])
    for i in range(54):                     # Phi = I + F dt (rows 0-5; the diagonal is i = 0, 10, .., 50)
        t = Fl[i] * dt
        term[i] = t
        Phi[i] = 1.0 + t if i % 10 == 0 else t
    for i in range(54, 81):                 # rows 6-8: the identity's
        Phi[i] = 1.0 if i % 10 == 0 else 0.0
    f01, f02, f10, f12, f20, f21 = Fl[1], Fl[2], Fl[9], Fl[11], Fl[18], Fl[19]
    f30, f31, f32, f33, f34, f35, f36, f37, f38 = Fl[27:36]       # rows 3-5 (F21 F22 F23) in locals:
    f40, f41, f42, f43, f44, f45, f46, f47, f48 = Fl[36:45]       # the inner sums below are written out
    f50, f51, f52, f53, f54, f55, f56, f57, f58 = Fl[45:54]
    tl = list(term[0:54])
    for n in range(2, order + 1):
        c = dt / n
        for o in range(0, 54, 9):
            t0, t1, t2, t3, t4, t5 = tl[o:o + 6]
            term[o] = (t1 * f10 + t2 * f20 + t3 * f30 + t4 * f40 + t5 * f50) * c
            term[o + 1] = (t0 * f01 + t2 * f21 + t3 * f31 + t4 * f41 + t5 * f51) * c
            term[o + 2] = (t0 * f02 + t1 * f12 + t3 * f32 + t4 * f42 + t5 * f52) * c
            term[o + 3] = (t0 * 0.5 + t3 * f33 + t4 * f43 + t5 * f53) * c
            term[o + 4] = (t1 * 0.5 + t3 * f34 + t4 * f44 + t5 * f54) * c
            term[o + 5] = (t2 * 0.5 + t3 * f35 + t4 * f45 + t5 * f55) * c
            term[o + 6] = (t3 * f36 + t4 * f46 + t5 * f56) * c
            term[o + 7] = (t3 * f37 + t4 * f47 + t5 * f57) * c
            term[o + 8] = (t3 * f38 + t4 * f48 + t5 * f58) * c
        tl = list(term[0:54])
        for i in range(54):
            Phi[i] += tl[i]


@micropython.native
def covariance_predict(P, Phi, T):
    """P = Phi P Phi^T (Eq. 4.128 without Q) for the lean Phi, whose tau_d rows 6-8 are [0 I]: only rows 0-5
    of Phi P (into T, float32) and the blocks they touch are computed; the upper triangle is mirrored. P is
    symmetric, so column j of P is its row j. The 9-term dot products are written out (a loop iteration
    costs MicroPython as much as a float operation)."""
    Pr = [list(P[k:k + 9]) for k in range(0, 81, 9)]
    Phr = [list(Phi[k:k + 9]) for k in range(0, 54, 9)]
    for i in range(6):                      # T[0:6] = Phi[0:6] P
        a0, a1, a2, a3, a4, a5, a6, a7, a8 = Phr[i]
        o = i * 9
        for j in range(9):
            b0, b1, b2, b3, b4, b5, b6, b7, b8 = Pr[j]
            T[o + j] = (a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 + a4 * b4 + a5 * b5 + a6 * b6 + a7 * b7
                        + a8 * b8)
    Tr = [list(T[k:k + 9]) for k in range(0, 54, 9)]
    for i in range(6):                      # P[0:6, 0:6] = T[0:6] Phi[0:6]^T; P[0:6, 6:] = T[0:6, 6:]
        a0, a1, a2, a3, a4, a5, a6, a7, a8 = Tr[i]
        for j in range(i, 6):
            b0, b1, b2, b3, b4, b5, b6, b7, b8 = Phr[j]
            v = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 + a4 * b4 + a5 * b5 + a6 * b6 + a7 * b7 + a8 * b8
            P[i * 9 + j] = v
            P[j * 9 + i] = v
        for j, v in ((6, a6), (7, a7), (8, a8)):
            P[i * 9 + j] = v
            P[j * 9 + i] = v


@micropython.native
def wheel_speeds(W, Pw, var, z, got, u, model):
    """One step of each wheel's own Kalman filter (x = W[k], P = Pw[k], rad/s, relative speeds): the read-out z
    smoothed on the torques the flight software commanded, which the 9-state filter has no room for (the
    41-state filter carries the wheel speeds as states, Eq. 4.78, 4.98). In place; var[k] gets the variance
    of the step's speed change error, what ``momentum_rate`` adds as rate noise.

    Predict: the rotor equation Jrw W_dot = s (sat(u) - f(W)) (``momentum_rate``'s "torque", Euler over the
    step), x- = x + s (sat(u) - f(x)) dt/Jrw, P- = P + Q with
        Q = (torque_rel s (sat(u) - f(x)) dt/Jrw)^2        the net torque's error (5 %, as "torque"),
          + (s f_c dt/Jrw)^2    when |x| < 3 sigma_tach + dt s (|u| + f_c)/Jrw: the friction's sign unknown,
          + (s (|u| + f_c) dt/Jrw)^2   when got[k] is false: not heard, so whether it took u is unknown.
    Update (got[k]): K = P-/(P- + R), R = R_rw (the 10 rpm read-out), x = x- + K (z - x-), P = (1 - K) P-.
    With e the error before the step and w, v the model's and the read-out's errors, the change's error is
    -K e - (1 - K) w + K v: var = K^2 P + (1 - K)^2 Q + K^2 R (derived); not heard: var = Q.
    Not modelled: the read-out's speed is relative, W - c^T w, so it also moves by c^T dw (<= 2e-3 rad/s
    per step in a slew, beside 1.05 rad/s of read-out noise). u NaN (not known) is taken as zero torque."""
    tm, R, near, rel, gs = model.torque_max, model.R_rw, model.tach_3sigma, model.torque_rel, model.g_rw
    fc = model.friction[0]
    for k in range(4):
        uk = u[k]
        if uk != uk:
            uk = 0.0
        elif uk > tm:
            uk = tm
        elif uk < -tm:
            uk = -tm
        x, P, g = W[k], Pw[k], gs[k]
        a = g * (uk - friction(model, x))
        Q = rel * a
        Q = Q * Q
        if abs(x) < near + g * (abs(uk) + fc):
            Q += (g * fc) ** 2
        x += a                                      # predict
        if got[k]:
            M = P + Q
            K = M / (M + R)
            L = 1.0 - K
            W[k] = x + K * (z[k] - x)               # update
            Pw[k] = L * M
            var[k] = K * K * (P + R) + L * L * Q
        else:
            Q += (g * (abs(uk) + fc)) ** 2
            W[k] = x
            Pw[k] = P + Q
            var[k] = Q


@micropython.native
def predict(x, P, wm, wp, u, env, model, work):
    """(x, P) from t to t + dt (Eq. 4.95-4.136, cut to 9 states): F and Phi at the step's start, RK4 for x,
    P = Phi P Phi^T + Q (symmetric by construction; Phi's tau_d rows are the identity's). wm, wp: the
    read-outs (with "filtered": ``wheel_speeds``'s speeds) at the step's start and end (rad/s); u: the motor
    torques commanded over it (N m; unused with the read-out difference); env = (r_i unit (3), 3 mu/r^3,
    b_i (3)), mid-step."""
    hw, hd = work.hw, work.hd
    Qw = momentum_rate(hw, hd, work.Qw, model, wm, wp, u, work.var)
    jacobian(work.F, x, model, hw, env, work)
    phi(work.Phi, work.F, model.dt, work)
    propagate(x, model, hw, hd, env, work)
    covariance_predict(P, work.Phi, work.T1)
    Q = model.Q
    for o in range(27, 81, 9):              # Q is zero outside rows and columns 3-8
        for i in range(o + 3, o + 9):
            P[i] += Q[i]
    for i in range(3):
        for j in range(3):
            P[(3 + i) * 9 + 3 + j] += Qw[i * 3 + j]


@micropython.native
def error_vec(out, qm, q):
    """out[0:3] = vector part of q_meas (x) q_hat^-1, sign so that dq4 >= 0 (Eq. 4.25, 4.139)."""
    a1, a2, a3, a4 = qm[0], qm[1], qm[2], qm[3]
    b1, b2, b3, b4 = -q[0], -q[1], -q[2], q[3]
    d1 = a4 * b1 + a1 * b4 - (a2 * b3 - a3 * b2)
    d2 = a4 * b2 + a2 * b4 - (a3 * b1 - a1 * b3)
    d3 = a4 * b3 + a3 * b4 - (a1 * b2 - a2 * b1)
    d4 = a4 * b4 - (a1 * b1 + a2 * b2 + a3 * b3)
    s = 1.0 if d4 >= 0 else -1.0
    out[0], out[1], out[2] = s * d1, s * d2, s * d3


@micropython.native
def update(x, P, q_meas, model, work):
    """Star-tracker update (Eq. 4.139-4.142), Joseph form; returns False (x, P untouched) if S is not PD."""
    z = work.y
    error_vec(z, q_meas, x)
    Kt = work.Kt
    if not linalg.joseph_select(P, N, 0, 3, model.R, Kt, work.L, work.W, work.RK):
        return False
    dx = work.dx
    for i in range(N):
        dx[i] = Kt[i] * z[0] + Kt[N + i] * z[1] + Kt[2 * N + i] * z[2]       # Eq. 4.141
    correct(x, dx)
    return True


@micropython.native
def correct(x, dx):
    """q = dq (x) q_hat with dq = [dx0:3, sqrt(1 - |.|^2)] (Eq. 4.51), normalised; w, tau_d additive."""
    a1, a2, a3 = dx[0], dx[1], dx[2]
    n2 = a1 * a1 + a2 * a2 + a3 * a3
    a4 = math.sqrt(1.0 - n2) if n2 < 1.0 else 0.0
    b1, b2, b3, b4 = x[0], x[1], x[2], x[3]
    q1 = a4 * b1 + a1 * b4 - (a2 * b3 - a3 * b2)
    q2 = a4 * b2 + a2 * b4 - (a3 * b1 - a1 * b3)
    q3 = a4 * b3 + a3 * b4 - (a1 * b2 - a2 * b1)
    q4 = a4 * b4 - (a1 * b1 + a2 * b2 + a3 * b3)
    n = math.sqrt(q1 * q1 + q2 * q2 + q3 * q3 + q4 * q4)
    x[0], x[1], x[2], x[3] = q1 / n, q2 / n, q3 / n, q4 / n
    for i in range(3, 9):
        x[i + 1] = x[i + 1] + dx[i]


class LeanApkf:
    """The lean APKF at 1 Hz: ``step(wp, q_meas or None, env, u, got)`` per dt, the read-out wp at the step's
    end, u the motor torques commanded over the step (N m; needed unless ``momentum="tach"``), got which
    wheels were heard (4 booleans, default ``ALL``; used by "filtered", whose speeds are ``W`` with variances
    ``Pw``)."""

    def __init__(self, params, q0, w0, w_rw0, dt=1.0, **kw):
        self.model = Model(params, dt=dt, **kw)
        self.x = linalg.zeros(10)
        for i in range(4):
            self.x[i] = q0[i]
        for i in range(3):
            self.x[4 + i] = w0[i]
            self.x[7 + i] = self.model.tau_d0[i]
        self.P = linalg.zeros(81)
        initial_covariance(self.P, self.model, *self.model.p0)
        self.wm = linalg.zeros(4)
        self.W, self.Pw = linalg.zeros(4), linalg.zeros(4)
        for i in range(4):
            self.wm[i] = self.W[i] = w_rw0[i]
            self.Pw[i] = self.model.R_rw
        self.work = Work()
        self.skipped = 0           # star-tracker updates refused (S not positive definite)

    def step(self, wp, q_meas, env, u=None, got=ALL):
        if u is None and (self.model.torque or self.model.filtered):
            raise ValueError("the lean APKF needs the wheel torques commanded over the step (momentum=%r)"
                             % ("torque" if self.model.torque else "filtered"))
        if self.model.filtered:
            wheel_speeds(self.W, self.Pw, self.work.var, wp, got, u, self.model)
            wp = self.W
        predict(self.x, self.P, self.wm, wp, u, env, self.model, self.work)
        for i in range(4):
            self.wm[i] = wp[i]
        if q_meas is not None and not update(self.x, self.P, q_meas, self.model, self.work):
            self.skipped += 1


if linalg.kernels is not None:          # the C kernels, when built (linalg's comment): the same results
    def _phi_c(Phi, F, dt, work, order=4):
        """``phi`` above, in C (adcsk.phi9)."""
        linalg.kernels.phi9(Phi, F, dt, work.T1, order)

    phi = linalg.either(_phi_c, phi)
    covariance_predict = linalg.either(linalg.kernels.covariance_predict, covariance_predict)
