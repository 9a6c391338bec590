"""Attitude control for pointing and tracking, flight version (MicroPython) of ground/adcs/control.py.

Conventions as the APKF (Sec. 4.2): q = [q1, q2, q3, q4] scalar last, A(q) maps inertial to body,
A(q (x) p) = A(q) A(p). Vectors and matrices are flat float buffers (3 x 3 row-major); the vector and matrix
functions write into a destination the caller allocated (firmware/adcs/linalg.zeros); ``natural_frequency``,
``cct_cofactors`` and ``_solve_cct`` return numbers.

- ``orbit_frame``: T_o<-j2k of Eq. 6.1-6.2 (rows: v/|v|, r x v/|r x v|, their cross product).
- ``attitude_command``: the minimum rotation putting the laser axis on the line of sight (Eq. 6.3), composed
  with the Orbit Frame (Eq. 6.4).
- ``gains`` / ``pd_torque``: quaternion feedback PD (Eq. 6.5-6.7), K = 2 wn^2 J, D = 2 zeta wn J,
  wn = 8 / t_s (Eq. 6.7 as printed; see ground/adcs/control.py), with the command rate, the gyroscopic
  term w x H and the external-torque feed-forward as the ground version adds them.
- ``wheel_torques``: minimum-norm motor torques u = -C^T (C C^T)^-1 tau_c (Eq. 6.11; the body feels -C u).
- ``saturate``: tau_c scaled down, direction kept, so that no motor torque passes its limit.
"""

import math

from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators

LASER_AXIS = (1.0, 0.0, 0.0)
ZETA = 1.0
RANK_TOL = 1e-9        # C C^T singular to working precision below this fraction of its diagonal's product


@micropython.native
def _unit(out, o, x, y, z):
    n = math.sqrt(x * x + y * y + z * z)
    if not n > 0.0:
        raise ValueError("zero-length vector")
    out[o], out[o + 1], out[o + 2] = x / n, y / n, z / n


@micropython.native
def orbit_frame(T, r, v):
    """T (3 x 3) = T_o<-j2k (Eq. 6.1-6.2)."""
    _unit(T, 0, v[0], v[1], v[2])
    _unit(T, 3, r[1] * v[2] - r[2] * v[1], r[2] * v[0] - r[0] * v[2], r[0] * v[1] - r[1] * v[0])
    T[6] = T[1] * T[5] - T[2] * T[4]
    T[7] = T[2] * T[3] - T[0] * T[5]
    T[8] = T[0] * T[4] - T[1] * T[3]


@micropython.native
def dcm_to_quat(q, T):
    """q (q4 >= 0) with A(q) = T, Shepperd's method (as ground/adcs/control.py)."""
    tr = T[0] + T[4] + T[8]
    i = 3
    best = tr
    for k in range(3):
        if T[4 * k] > best:
            best = T[4 * k]
            i = k
    if i == 3:
        q4 = 0.5 * math.sqrt(1.0 + tr)
        d = 4.0 * q4
        q[0], q[1], q[2], q[3] = (T[5] - T[7]) / d, (T[6] - T[2]) / d, (T[1] - T[3]) / d, q4
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        qi = 0.5 * math.sqrt(1.0 + 2.0 * T[4 * i] - tr)
        d = 4.0 * qi
        q[i] = qi
        q[j] = (T[i * 3 + j] + T[j * 3 + i]) / d
        q[k] = (T[i * 3 + k] + T[k * 3 + i]) / d
        q[3] = (T[j * 3 + k] - T[k * 3 + j]) / d
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    s = 1.0 / n if q[3] >= 0 else -1.0 / n
    for m in range(4):
        q[m] = q[m] * s


@micropython.native
def dcm(A, q):
    """A(q) (3 x 3 flat), inertial to body (Eq. 4.7)."""
    e1, e2, e3, q4 = q[0], q[1], q[2], q[3]
    A[0] = q4 * q4 + e1 * e1 - e2 * e2 - e3 * e3
    A[1] = 2 * (e1 * e2 + q4 * e3)
    A[2] = 2 * (e1 * e3 - q4 * e2)
    A[3] = 2 * (e1 * e2 - q4 * e3)
    A[4] = q4 * q4 - e1 * e1 + e2 * e2 - e3 * e3
    A[5] = 2 * (e2 * e3 + q4 * e1)
    A[6] = 2 * (e1 * e3 + q4 * e2)
    A[7] = 2 * (e2 * e3 - q4 * e1)
    A[8] = q4 * q4 - e1 * e1 - e2 * e2 + e3 * e3


@micropython.native
def quat_mul(out, q, p):
    """out = q (x) p with A(q (x) p) = A(q) A(p) (Eq. 4.5); out must not alias q or p."""
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    p1, p2, p3, p4 = p[0], p[1], p[2], p[3]
    out[0] = q4 * p1 + p4 * q1 - (q2 * p3 - q3 * p2)
    out[1] = q4 * p2 + p4 * q2 - (q3 * p1 - q1 * p3)
    out[2] = q4 * p3 + p4 * q3 - (q1 * p2 - q2 * p1)
    out[3] = q4 * p4 - (q1 * p1 + q2 * p2 + q3 * p3)


@micropython.native
def min_rotation(q, a, b):
    """q with A(q) b = a for unit a, b (Eq. 6.3): q4 = sqrt((1 + a.b)/2), q_vec = a x b / (2 q4)."""
    c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    if c < -1.0 + 1e-12:
        raise ValueError("laser axis and line of sight are opposite: the minimum rotation is not unique")
    q4 = math.sqrt(0.5 * (1.0 + c))
    d = 2.0 * q4
    q[0] = (a[1] * b[2] - a[2] * b[1]) / d
    q[1] = (a[2] * b[0] - a[0] * b[2]) / d
    q[2] = (a[0] * b[1] - a[1] * b[0]) / d
    q[3] = q4


class Work:
    def __init__(self, zeros):
        self.T = zeros(9)
        self.p = zeros(3)
        self.q1 = zeros(4)
        self.q2 = zeros(4)


@micropython.native
def attitude_command(qc, ra, va, rb, work, laser_axis=LASER_AXIS):
    """q_c (Eq. 6.3-6.4): p_o = T_o (rB - rA)/|rB - rA|, Pq = min_rotation(l_b, p_o), q_c = Pq (x) q(T_o)."""
    T, p = work.T, work.p
    orbit_frame(T, ra, va)
    dx, dy, dz = rb[0] - ra[0], rb[1] - ra[1], rb[2] - ra[2]
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    for i in range(3):
        p[i] = (T[i * 3] * dx + T[i * 3 + 1] * dy + T[i * 3 + 2] * dz) / n
    min_rotation(work.q1, laser_axis, p)
    dcm_to_quat(work.q2, T)
    quat_mul(qc, work.q1, work.q2)


def natural_frequency(ts):
    """wn of Eq. 6.7: 8 / t_s, rad/s."""
    if not ts > 0:
        raise ValueError("settling time ts must be > 0 s, got %r" % (ts,))
    return 8.0 / ts


def check_zeta(zeta):
    """The PD's damping ratio zeta (Eq. 6.6) as a float; ValueError unless finite and > 0."""
    try:
        z = float(zeta)
    except (TypeError, ValueError):
        z = 0.0
    if not 0.0 < z < float("inf"):
        raise ValueError("PD damping ratio zeta must be finite and > 0, got %r" % (zeta,))
    return z


def gains(K, D, J, ts, zeta=ZETA):
    """K = 2 wn^2 J, D = 2 zeta wn J (Eq. 6.6), 3 x 3 flat."""
    zeta = check_zeta(zeta)
    wn = natural_frequency(ts)
    for i in range(9):
        K[i] = 2.0 * wn * wn * J[i]
        D[i] = 2.0 * zeta * wn * J[i]


@micropython.native
def pd_torque(tau, q, w, qc, wc, K, D, H=None, tau_ff=None):
    """tau = -K q_e,vec - D (w - A(q_e) w_c) (Eq. 6.5) + w x H - tau_ff (None leaves a term out);
    q_e = q (x) q_c^-1 with q_e4 >= 0."""
    c1, c2, c3, c4 = -qc[0], -qc[1], -qc[2], qc[3]
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    e1 = q4 * c1 + c4 * q1 - (q2 * c3 - q3 * c2)
    e2 = q4 * c2 + c4 * q2 - (q3 * c1 - q1 * c3)
    e3 = q4 * c3 + c4 * q3 - (q1 * c2 - q2 * c1)
    e4 = q4 * c4 - (q1 * c1 + q2 * c2 + q3 * c3)
    if e4 < 0:
        e1, e2, e3, e4 = -e1, -e2, -e3, -e4
    x, y, z = wc[0], wc[1], wc[2]                   # A(q_e) w_c (Eq. 4.7)
    a0 = (e1 * e1 - e2 * e2 - e3 * e3 + e4 * e4) * x + 2.0 * (e1 * e2 + e3 * e4) * y + 2.0 * (e1 * e3 - e2 * e4) * z
    a1 = 2.0 * (e1 * e2 - e3 * e4) * x + (-e1 * e1 + e2 * e2 - e3 * e3 + e4 * e4) * y + 2.0 * (e2 * e3 + e1 * e4) * z
    a2 = 2.0 * (e1 * e3 + e2 * e4) * x + 2.0 * (e2 * e3 - e1 * e4) * y + (-e1 * e1 - e2 * e2 + e3 * e3 + e4 * e4) * z
    we0, we1, we2 = w[0] - a0, w[1] - a1, w[2] - a2
    for i in range(3):
        tau[i] = -(K[i * 3] * e1 + K[i * 3 + 1] * e2 + K[i * 3 + 2] * e3) \
            - (D[i * 3] * we0 + D[i * 3 + 1] * we1 + D[i * 3 + 2] * we2)
    if H is not None:
        t0 = w[1] * H[2] - w[2] * H[1]
        t1 = w[2] * H[0] - w[0] * H[2]
        t2 = w[0] * H[1] - w[1] * H[0]
        tau[0], tau[1], tau[2] = tau[0] + t0, tau[1] + t1, tau[2] + t2
    if tau_ff is not None:
        for i in range(3):
            tau[i] = tau[i] - tau_ff[i]


def cct_cofactors(C):
    """(c00, c01, c02, c11, c12, c22, det): the cofactors and determinant of the symmetric C C^T (C 3 x 4,
    flat), for (C C^T)^-1 = cofactors / det (Cramer's rule). They depend on the axes only: a caller may
    compute them once per set of axes and pass them to ``wheel_torques`` and ``saturate``.
    ValueError when the axes do not span 3 axes: det <= RANK_TOL m00 m11 m22 (Hadamard: det <= the diagonal's
    product; two wheels left of four give a rank-2 C C^T whose det is ~1e-17 by rounding, not 0)."""
    m00 = C[0] * C[0] + C[1] * C[1] + C[2] * C[2] + C[3] * C[3]
    m01 = C[0] * C[4] + C[1] * C[5] + C[2] * C[6] + C[3] * C[7]
    m02 = C[0] * C[8] + C[1] * C[9] + C[2] * C[10] + C[3] * C[11]
    m11 = C[4] * C[4] + C[5] * C[5] + C[6] * C[6] + C[7] * C[7]
    m12 = C[4] * C[8] + C[5] * C[9] + C[6] * C[10] + C[7] * C[11]
    m22 = C[8] * C[8] + C[9] * C[9] + C[10] * C[10] + C[11] * C[11]
    c00 = m11 * m22 - m12 * m12
    c01 = m02 * m12 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    det = m00 * c00 + m01 * c01 + m02 * c02
    if not det > RANK_TOL * m00 * m11 * m22:
        raise ValueError("wheel axes do not span 3 axes")
    c11 = m00 * m22 - m02 * m02
    c12 = m01 * m02 - m00 * m12
    c22 = m00 * m11 - m01 * m01
    return (c00, c01, c02, c11, c12, c22, det)


@micropython.native
def _solve_cct(C, tau, cof=None):
    """(y0, y1, y2) = (C C^T)^-1 tau for C 3 x 4 (flat), by Cramer's rule on the symmetric 3 x 3 (``cof``:
    ``cct_cofactors(C)`` if the caller has them)."""
    c00, c01, c02, c11, c12, c22, det = cct_cofactors(C) if cof is None else cof
    t0, t1, t2 = tau[0], tau[1], tau[2]
    return ((c00 * t0 + c01 * t1 + c02 * t2) / det, (c01 * t0 + c11 * t1 + c12 * t2) / det,
            (c02 * t0 + c12 * t1 + c22 * t2) / det)


@micropython.native
def wheel_torques(u, tau_c, C, cof=None):
    """Minimum-norm motor torques (Eq. 6.11): u = -C^T (C C^T)^-1 tau_c, C the 3 x 4 axes (flat); ``cof``:
    ``cct_cofactors(C)``, computed here if not given."""
    y0, y1, y2 = _solve_cct(C, tau_c, cof)
    for i in range(4):
        u[i] = -(C[i] * y0 + C[4 + i] * y1 + C[8 + i] * y2)


@micropython.native
def saturate(tau_c, C, torque_max, cof=None):
    """Scale tau_c (in place) so that max |u_i| <= torque_max, direction kept (``cof`` as wheel_torques)."""
    y0, y1, y2 = _solve_cct(C, tau_c, cof)
    peak = 0.0
    for i in range(4):
        v = abs(C[i] * y0 + C[4 + i] * y1 + C[8 + i] * y2)
        if v > peak:
            peak = v
    if peak > torque_max:
        s = torque_max / peak
        for i in range(3):
            tau_c[i] = tau_c[i] * s
