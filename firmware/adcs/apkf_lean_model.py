"""The lean APKF's model (MicroPython): the vehicle as its parameter file states it (Sec. 4.6-4.7: J, the wheel
axes with their misalignments, Jrw, the residual dipole; the momentum input and the wheels' datasheet friction),
its initial covariance and the filter's work buffers; ``apkf_lean`` is the filter over it."""

import math

from firmware.adcs import linalg
from protocol import paramfile
from protocol.units import RAD_PER_ARCSEC

N = 9
HOUR = 3600.0
RPM = 2.0 * math.pi / 60.0
QD_CASE1 = (2.0e-7) ** 2 / HOUR            # Sec. 4.8, Case 1, (N m)^2/s
NW = 4
FRICTION = (2e-6, 2e-10, 1.0 * RPM)        # wheel datasheet: Coulomb N m, viscous N m s/rad, smoothing rad/s
TORQUE_MAX = 1e-3                          # wheel datasheet: motor torque limit, N m
TORQUE_REL = 0.05                          # realised / commanded torque in the file's units, 1 sigma (assumed)
MOMENTUM = ("torque", "tach", "filtered")   # the momentum inputs (Model)
ALL = (True, True, True, True)              # every wheel heard


def axes(c0=None):
    """(C0, C1, C2), 3 x 4 nested lists (rows x, y, z; a column per wheel): the nominal unit axes ``c0`` (a
    spacecraft file's, default the pyramid of Eq. 4.147) and their misalignment axes (Eq. 4.148)."""
    if c0 is None:
        s = 1.0 / math.sqrt(3.0)
        c0 = [[-s, -s, s, s], [-s, s, s, -s], [s, s, s, s]]
    c1 = [[0.0] * 4 for _ in range(3)]
    c2 = [[0.0] * 4 for _ in range(3)]
    for i in range(4):
        a = [c0[r][i] for r in range(3)]
        b = [c0[r][(i + 1) % 4] for r in range(3)]
        v = _cross(a, b)
        n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        v = [v[0] / n, v[1] / n, v[2] / n]
        u = _cross(a, v)
        n = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
        for r in range(3):
            c1[r][i] = v[r]
            c2[r][i] = u[r] / n
    return c0, c1, c2


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


class Model:
    """What the lean filter holds fixed: J, the inverse inertia of the rate equation, C Jrw (3 x 4), the unit
    axes C (3 x 4), m, noise levels; flat lists of float32 values.

    ``momentum``: where each step's wheel momentum change comes from. "filtered" (the default, flown): the
    difference of two wheel speeds from ``wheel_speeds``, the read-outs filtered on the commanded torques;
    for comparison, "torque": the motor torques the flight software commanded over the step, less its
    friction model, and "tach": the difference of the two tachometer read-outs (Eq. 4.62, 4.95; the
    41-state filter's input)."""

    def __init__(self, params, dt=1.0, sigma_st_arcsec=(20.0, 20.0, 60.0), tach_rpm=10.0, qd=QD_CASE1,
                 momentum="filtered", friction=FRICTION, torque_max=TORQUE_MAX, torque_rel=TORQUE_REL, c0=None,
                 p0=(10.0, 10.0, 1e-6), wheels=None):
        """``c0``: the nominal wheel axes (``axes``); ``p0``: the initial 1 sigma of the attitude (deg), the rate
        (deg/s) and tau_d (N m) (``initial_covariance``); ``wheels``: a spacecraft file's wheels block, what the
        parameter file is checked against (``protocol.paramfile``); the defaults are the thesis's 3U."""
        params = paramfile.check(params, None if wheels is None else {"wheels": wheels})
        self.p0 = (float(p0[0]), float(p0[1]), float(p0[2]))
        x = params["x"]
        j5 = x["J5_kgm2"]
        jxx = float(params["jxx_ref_kgm2"])
        self.dt = float(dt)
        self.scale = params["torque_scale"]
        self.friction = (float(friction[0]), float(friction[1]), float(friction[2]))
        self.torque_max = float(torque_max)
        self.torque_rel = float(torque_rel)
        self.J = linalg.zeros(9)
        for i, v in enumerate((jxx, j5[2], j5[3], j5[2], j5[0], j5[4], j5[3], j5[4], j5[1])):
            self.J[i] = v
        c0, c1, c2 = axes(c0)
        self.CJ = linalg.zeros(12)
        self.C = linalg.zeros(12)
        self.jrw = linalg.zeros(4)
        d1, d2, jrw = x["delta1_rad"], x["delta2_rad"], x["jrw_kgm2"]
        for r in range(3):
            for i in range(4):
                self.CJ[r * 4 + i] = (c0[r][i] + c1[r][i] * d1[i] + c2[r][i] * d2[i]) * jrw[i]
        for i in range(4):      # unit axes (Eq. 4.54) and the rotor inertias: C Jrw's column norms
            n = math.sqrt(self.CJ[i] ** 2 + self.CJ[4 + i] ** 2 + self.CJ[8 + i] ** 2)
            self.jrw[i] = n
            for r in range(3):
                self.C[r * 4 + i] = self.CJ[r * 4 + i] / n
        # the rate equation's inertia: J itself with the read-out difference (Eq. 4.67); with the torques,
        # Jm = J - C D(Jrw) C^T (see the module docstring). Both inverses are kept: ``use`` switches input.
        Jm = linalg.zeros(9)
        for i in range(9):
            Jm[i] = self.J[i]
        for r in range(3):
            for c in range(3):
                s = 0.0
                for k in range(4):
                    s += self.CJ[r * 4 + k] * self.C[c * 4 + k]
                Jm[r * 3 + c] -= s
        self.Ji_tach, self.Ji_torque = linalg.zeros(9), linalg.zeros(9)
        if not (_inv3(self.Ji_tach, self.J) and _inv3(self.Ji_torque, Jm)):
            raise ValueError("parameter file: inertia is not positive definite")
        self.m = linalg.zeros(3)
        for i in range(3):
            self.m[i] = x["dipole_am2"][i]
        self.tau_d0 = [float(v) for v in x["tau_d_nm"]]
        self.R = linalg.zeros(9)
        for i in range(3):
            self.R[i * 4] = (sigma_st_arcsec[i] * RAD_PER_ARCSEC) ** 2 / 4.0
        self.R_rw = (tach_rpm * RPM) ** 2
        self.tach_3sigma = 3.0 * tach_rpm * RPM
        self.qd = qd
        # read every step: kept as lists of their float32 values (a list read makes no new float on MicroPython)
        self.J, self.CJ, self.C, self.jrw = list(self.J), list(self.CJ), list(self.C), list(self.jrw)
        self.Ji_tach, self.Ji_torque, self.m, self.R = list(self.Ji_tach), list(self.Ji_torque), list(self.m), \
            list(self.R)
        self.use(momentum)

    def use(self, momentum):
        """Take the wheel momentum change from one of MOMENTUM (see the class docstring) from now on."""
        if momentum not in MOMENTUM:
            raise ValueError("momentum must be one of %s, got %r" % (", ".join(MOMENTUM), momentum))
        self.torque = momentum == "torque"
        self.filtered = momentum == "filtered"
        self.Ji = self.Ji_torque if self.torque else self.Ji_tach
        if self.filtered:        # each wheel's g g^T (upper triangle), g = J^-1 times its column of C Jrw,
            self.GG = []         # and s dt/Jrw: what momentum_rate and wheel_speeds take per step
            for k in range(4):
                Qw = linalg.zeros(9)
                _add_rate_noise(Qw, self.Ji, self.CJ, k, 1.0)
                self.GG.append((Qw[0], Qw[1], Qw[2], Qw[4], Qw[5], Qw[8]))
            self.g_rw = [self.scale * self.dt / self.jrw[k] for k in range(4)]
        if momentum == "tach":   # the read-out differences' rate noise is then constant (momentum_rate)
            Qw = linalg.zeros(9)
            for k in range(4):
                _add_rate_noise(Qw, self.Ji, self.CJ, k, 2.0 * self.R_rw)
            _mirror3(Qw)
            self.Qw_tach = list(Qw)
        # the constant part of Q: tau_d's (Eq. 4.135-4.136); the read-out differences add theirs per step
        dt, qd, Ji = self.dt, self.qd, self.Ji
        Q = linalg.zeros(81)
        for i in range(3):
            Q[(6 + i) * 9 + 6 + i] = qd * dt
            for j in range(3):
                jj = 0.0
                for k in range(3):
                    jj += Ji[i * 3 + k] * Ji[j * 3 + k]
                Q[(3 + i) * 9 + 3 + j] = qd * jj * dt ** 3 / 3.0
                v = Ji[i * 3 + j] * qd * dt * dt / 2.0
                Q[(3 + i) * 9 + 6 + j] = v
                Q[(6 + j) * 9 + 3 + i] = v
        self.Q = list(Q)


def _inv3(D, A):
    """D = A^-1 (3 x 3, flat); False if singular."""
    a, b, c, d, e, f, g, h, k = A[0], A[1], A[2], A[3], A[4], A[5], A[6], A[7], A[8]
    c00, c01, c02 = e * k - f * h, c * h - b * k, b * f - c * e
    det = a * c00 + d * c01 + g * c02
    if not abs(det) > 0.0:
        return False
    r = 1.0 / det
    D[0], D[1], D[2] = c00 * r, c01 * r, c02 * r
    D[3], D[4], D[5] = (f * g - d * k) * r, (a * k - c * g) * r, (c * d - a * f) * r
    D[6], D[7], D[8] = (d * h - e * g) * r, (b * g - a * h) * r, (a * e - b * d) * r
    return True


def initial_covariance(P, model, att_deg=10.0, rate_dps=10.0, tau_nm=1e-6):
    """P0 (Sec. 4.8): (10 deg)^2 attitude (as dq: /2), (10 deg/s)^2 rate, tau_d (1e-6 N m)^2 (as the ground)."""
    linalg.fill(P, 81, 0.0)
    d = math.pi / 180.0
    for i in range(3):
        P[i * 10] = (att_deg * d / 2.0) ** 2
        P[(3 + i) * 10] = (rate_dps * d) ** 2
        P[(6 + i) * 10] = tau_nm ** 2


class Work:
    """Every scratch buffer one cycle needs, allocated once."""

    def __init__(self):
        z = linalg.zeros
        self.F = z(81)
        self.Phi = z(81)
        self.T1 = z(81)
        self.W = z(81)
        self.Kt = z(27)
        self.RK = z(27)
        self.L = z(9)
        self.dx = z(9)
        self.k = z(7 * 4)       # RK4 slopes (q 4 + w 3) x 4
        self.y = z(7)           # RK4 stage state
        self.v = z(24)          # small vectors: r_b, b_b, h, J w, J r, torque, ...
        self.hw = z(3)          # C Jrw W at the step's start
        self.hd = z(3)          # its rate over the step
        self.Qw = z(9)          # the inputs' rate noise per step (3 x 3; "tach": model.Qw_tach instead)
        self.var = z(4)         # "filtered": the variance of each wheel's filtered speed change (wheel_speeds)


def friction(model, W):
    """The friction model's torque on a rotor at relative speed W (rad/s), N m (opposes the spin)."""
    c, vis, sm = model.friction
    return vis * W + c * math.tanh(W / sm)


def _add_rate_noise(Qw, Ji, M, k, r):
    """Qw (upper triangle) += r g g^T, g = Jm^-1 times column k of M (3 x 4): a white input's rate noise
    (the Eq. 4.135 construction)."""
    g0 = Ji[0] * M[k] + Ji[1] * M[4 + k] + Ji[2] * M[8 + k]
    g1 = Ji[3] * M[k] + Ji[4] * M[4 + k] + Ji[5] * M[8 + k]
    g2 = Ji[6] * M[k] + Ji[7] * M[4 + k] + Ji[8] * M[8 + k]
    Qw[0] += r * g0 * g0
    Qw[1] += r * g0 * g1
    Qw[2] += r * g0 * g2
    Qw[4] += r * g1 * g1
    Qw[5] += r * g1 * g2
    Qw[8] += r * g2 * g2


def _mirror3(Qw):
    Qw[3], Qw[6], Qw[7] = Qw[1], Qw[2], Qw[5]
