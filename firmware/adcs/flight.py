"""The flight world's laws of the lean ADCS (MicroPython, plain floats; ``app.App`` flies them on a board and in
the ground's analysis alike): the rate-limited eigenaxis slew, the magnetorquers' cross-product unloading law with
the estimated residual dipole cancelled (m = k (h x b) / |b|^2 - m_res: its torque m x b removes the wheels'
momentum across the field), the wheels' null-space speed bias (held off zero speed, where Coulomb friction flips
sign with every tachometer sample), the star-tracker innovation gate with its attitude reset. None of this is in
the thesis (its Ch. 6 has no momentum management and no slew limit). All angles rad, rates rad/s, dipoles A m^2,
torques N m.
"""

import math

from firmware.adcs import control


# The flight world's options (configuration key "flight"; units in the names) and their defaults. The eigenaxis
# slew is short rather than slow: the star tracker is blind above its 0.1 deg/s, and the lean APKF's rate error
# grows ~5 arcsec/s per blind second (a 90 deg slew at 0.5 deg/s left ~0.1 deg/s, which kept the tracker blind;
# at 2 deg/s, < 0.03 deg/s); 2 deg/s is ~1/2 of what the 3U's wheels hold at 80 % of their speed, 0.2 deg/s^2 ~16 %
# of their torque.
FLIGHT = {
    "slew_rate_deg_s": 2.0,
    "slew_acc_deg_s2": 0.2,
    "reslew_deg": 1.0,             # POINT -> SLEW when the estimate is this far off the command
    "unload_gain_1_s": 2e-3,       # the cross-product law's gain: the wheels' momentum across b decays in ~500 s
    "innovation_gate": 44.84,      # chi-square, 3 dof, 1 - 1e-9: a star-tracker fix beyond it resets the attitude
    "beacon_gate_arcsec": 300.0,   # the STKF takes the beacon only while the attitude 1 sigma is within this
    "wheel_bias_share": 0.2,       # the wheels' null-space speed bias, a share of their speed limit
    "wheel_bias_gain_1_s": 0.01,   # and its gain: ~100 s to reach it
}


def options(cfg):
    """The flight world's options of a configuration (``FLIGHT``'s defaults under its key "flight"), or None in
    the thesis world (``world`` other than "flight"). An unknown option is refused (ValueError)."""
    if cfg.get("world", "thesis") != "flight":
        return None
    fo = cfg.get("flight") or {}
    for k in fo:
        if k not in FLIGHT:
            raise ValueError("unknown flight option %r (the options: %s)" % (k, ", ".join(sorted(FLIGHT))))
    opts = dict(FLIGHT)
    opts.update(fo)
    return opts


def _exp(out, e, a):
    """out = the quaternion of rotation a about the unit axis e."""
    s = math.sin(0.5 * a)
    out[0], out[1], out[2], out[3] = e[0] * s, e[1] * s, e[2] * s, math.cos(0.5 * a)


def rotvec(out, q):
    """out[0:3] = the rotation vector of q (the short way round)."""
    s = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    if s < 1e-300:
        out[0] = out[1] = out[2] = 0.0
        return
    k = 2.0 * math.atan2(s, abs(q[3])) / s
    if q[3] < 0:
        k = -k
    out[0], out[1], out[2] = q[0] * k, q[1] * k, q[2] * k


def propagate(out, q, w, dt):
    """out = q after dt at the constant body rate w (exact)."""
    wn = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if wn * dt < 1e-12:
        for i in range(4):
            out[i] = q[i]
        return
    d = [0.0] * 4
    _exp(d, (w[0] / wn, w[1] / wn, w[2] / wn), wn * dt)
    control.quat_mul(out, d, q)


class Slew:
    """A rate- and acceleration-limited eigenaxis slew toward a moving command. At the start
    phi = rotvec(q_c (x) q_start^-1), the rotation that takes the start to the command (body frame); the reference
    is q_ref = exp(-theta e) (x) q_c with e = phi / |phi| fixed and theta shrinking from |phi| at a speed s that
    rises by at most ``acc_max`` per second, never exceeds ``rate_max`` and brakes as sqrt(2 acc_max theta), so
    the reference reaches q_c at rest relative to it. Its rate is the difference of consecutive references over
    one step, the command carried forward by its own rate w_c, so it holds both the slew and the command's own
    turn. Units: rad, rad/s, rad/s^2, s. Not in the thesis (its Ch. 6 points from rest with the PD alone)."""

    def __init__(self, rate_max, acc_max):
        self.rate_max, self.acc_max = float(rate_max), float(acc_max)
        self.e = [1.0, 0.0, 0.0]
        self.theta = self.theta0 = self.s = 0.0
        self.active = False
        self._a, self._b, self._c, self._d = [0.0] * 4, [0.0] * 4, [0.0] * 4, [0.0] * 4
        self._v = [0.0] * 3

    def start(self, q_start, q_c):
        d = self._a
        control.quat_mul(d, q_c, (-q_start[0], -q_start[1], -q_start[2], q_start[3]))
        rotvec(self._v, d)
        v = self._v
        th = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if th > 0:
            self.e[0], self.e[1], self.e[2] = v[0] / th, v[1] / th, v[2] / th
        self.theta = self.theta0 = th
        self.s = 0.0
        self.active = True

    def reference(self, q_ref, w_ref, q_c, w_c, dt=1.0):
        """q_ref (4), w_ref (3) for the command (q_c, w_c); the profile advanced by dt; ``active`` False once it
        has reached the command."""
        _exp(self._a, self.e, -self.theta)
        control.quat_mul(q_ref, self._a, q_c)
        s = self.s + self.acc_max * dt
        if s > self.rate_max:
            s = self.rate_max
        brake = math.sqrt(2.0 * self.acc_max * self.theta)
        if s > brake:
            s = brake
        th = self.theta - s * dt
        if th <= 0.0:
            th = 0.0
            s = self.theta / dt
        propagate(self._b, q_c, w_c, dt)
        _exp(self._a, self.e, -th)
        control.quat_mul(self._c, self._a, self._b)                 # the next reference
        control.quat_mul(self._d, self._c, (-q_ref[0], -q_ref[1], -q_ref[2], q_ref[3]))
        rotvec(w_ref, self._d)
        for i in range(3):
            w_ref[i] = w_ref[i] / dt
        self.s, self.theta = s, th
        if th == 0.0:
            self.active = False


def angle(q, p):
    """The rotation angle (rad) between q and p."""
    d = abs(q[0] * p[0] + q[1] * p[1] + q[2] * p[2] + q[3] * p[3])
    return 2.0 * math.acos(d if d < 1.0 else 1.0)


def unloading(m, b, h, gain, limit, m_res, out=0):
    """m (3) = gain (h x b) / |b|^2 - m_res (b the body field, T; h the wheels' momentum, N m s; m_res the
    estimated residual dipole), for three rods along body x, y, z, each clipped to +-limit; returns the clipped
    rods as bits. With rods ``out`` (bits: their driver dead) the rods left give the least-squares torque of that
    dipole instead (``rods_left``)."""
    bb = b[0] * b[0] + b[1] * b[1] + b[2] * b[2]
    if not bb > 0:
        m[0] = m[1] = m[2] = 0.0
        return 0
    k = gain / bb
    m[0] = k * (h[1] * b[2] - h[2] * b[1]) - m_res[0]
    m[1] = k * (h[2] * b[0] - h[0] * b[2]) - m_res[1]
    m[2] = k * (h[0] * b[1] - h[1] * b[0]) - m_res[2]
    if out:
        return rods_left(m, b, bb, out, limit)
    sat = 0
    for i in range(3):
        if m[i] > limit:
            m[i], sat = limit, sat | (1 << i)
        elif m[i] < -limit:
            m[i], sat = -limit, sat | (1 << i)
    return sat


def _clip(v, limit):
    return limit if v > limit else (-limit if v < -limit else v)


def _edge(a, d, c, rj, rl, p, limit):
    """(p, q, cost): rod j held at p, rod l at its best within +-limit, for the quadratic
    0.5 (a p^2 + 2 d p q + c q^2) - rj p - rl q."""
    q = _clip((rl - d * p) / c, limit) if c > 0 else 0.0
    return p, q, 0.5 * (a * p * p + 2.0 * d * p * q + c * q * q) - rj * p - rl * q


def rods_left(m, b, bb, out, limit):
    """m (3) in place: the dipole of the rods not in ``out`` (bits; rods along body x, y, z) whose torque m' x b
    is the least-squares fit of m x b within the rods' +-limit (b the body field, T, bb = |b|^2); returns the rods
    at the limit as bits. With c_j = e_j x b the normal equations are N_jl = c_j . c_l = |b|^2 d_jl - b_j b_l,
    r_j = c_j . (m x b) = m_j |b|^2 - b_j (b . m): one rod left, m'_j = r_j / N_jj clipped; two, the 2 x 2
    solution (the same torque exactly when the rod out has b_i != 0: a dipole along b gives none) or, beyond the
    limit, the best point on the box's edges. Not in the thesis."""
    bm = b[0] * m[0] + b[1] * m[1] + b[2] * m[2]
    j = l = -1
    for k in range(3):
        if not out & (1 << k):
            if j < 0:
                j = k
            else:
                l = k
    mj = mk = 0.0
    if j >= 0 and l < 0:
        a = bb - b[j] * b[j]
        mj = _clip((m[j] * bb - b[j] * bm) / a, limit) if a > 1e-18 * bb else 0.0
    elif l >= 0:
        a, c, d = bb - b[j] * b[j], bb - b[l] * b[l], -b[j] * b[l]
        rj, rl = m[j] * bb - b[j] * bm, m[l] * bb - b[l] * bm
        det = a * c - d * d
        ok = False
        if det > 1e-12 * bb * bb:
            mj, mk = (c * rj - d * rl) / det, (a * rl - d * rj) / det
            ok = abs(mj) <= limit and abs(mk) <= limit
        if not ok:                          # the box's edges: rod j at +-limit, then rod l
            best = float("inf")
            for e in (limit, -limit):
                p, q, f = _edge(a, d, c, rj, rl, e, limit)
                if f < best:
                    best, mj, mk = f, p, q
                q, p, f = _edge(c, d, a, rl, rj, e, limit)
                if f < best:
                    best, mj, mk = f, p, q
    m[0] = m[1] = m[2] = 0.0
    sat = 0
    for k, v in ((j, mj), (l, mk)):
        if k >= 0:
            m[k] = v
            if abs(v) >= limit:
                sat |= 1 << k
    return sat


def null_vector(C):
    """The unit null vector n of the 3 x 4 C (row major): n_j = (-1)^j det(C without column j), its largest
    entry positive."""
    n = [0.0] * 4
    for j in range(4):
        c = [k for k in range(4) if k != j]
        a = [[C[r * 4 + c[i]] for i in range(3)] for r in range(3)]
        det = (a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
               + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]))
        n[j] = det if j % 2 == 0 else -det
    s = math.sqrt(sum(v * v for v in n))
    big = 0
    for j in range(4):
        if abs(n[j]) > abs(n[big]):
            big = j
    if n[big] < 0:
        s = -s
    return [v / s for v in n]


def null_bias(u, n, w_rel, jrw, bias, gain):
    """u (4) += -gain Jrw (s - s_t) n with s = n . w_rel and s_t = bias / mean |n_i| (each wheel near +-bias):
    the wheels' null-space speed held off zero; no torque on the body."""
    s = n[0] * w_rel[0] + n[1] * w_rel[1] + n[2] * w_rel[2] + n[3] * w_rel[3]
    st = 4.0 * bias / (abs(n[0]) + abs(n[1]) + abs(n[2]) + abs(n[3]))
    for i in range(4):
        u[i] = u[i] - gain * jrw[i] * (s - st) * n[i]


def nis3(z, P, R):
    """z^T (P[0:3, 0:3] + R)^-1 z (P n x n row major with n = 9 or more, R 3 x 3 row major); inf if singular."""
    n = int(math.sqrt(len(P)) + 0.5)
    a, b, c = P[0] + R[0], P[1] + R[1], P[2] + R[2]
    d, e, f = P[n] + R[3], P[n + 1] + R[4], P[n + 2] + R[5]
    g, h, i = P[2 * n] + R[6], P[2 * n + 1] + R[7], P[2 * n + 2] + R[8]
    A, B, C = e * i - f * h, -(d * i - f * g), d * h - e * g
    det = a * A + b * B + c * C
    if not det > 0:
        return float("inf")
    D, E, F = -(b * i - c * h), a * i - c * g, -(a * h - b * g)
    G, H, I = b * f - c * e, -(a * f - c * d), a * e - b * d
    z0, z1, z2 = z[0], z[1], z[2]
    y0 = A * z0 + D * z1 + G * z2
    y1 = B * z0 + E * z1 + H * z2
    y2 = C * z0 + F * z1 + I * z2
    return (z0 * y0 + z1 * y1 + z2 * y2) / det


def reset_attitude(x, P, q_meas, R):
    """The star tracker's attitude as the estimate: x[0:4] = q_meas, its 3 x 3 block of P = R and its
    correlations zero (P n x n row major)."""
    n = int(math.sqrt(len(P)) + 0.5)
    for i in range(4):
        x[i] = q_meas[i]
    for i in range(3):
        for j in range(n):
            P[i * n + j] = 0.0
            P[j * n + i] = 0.0
    for i in range(3):
        for j in range(3):
            P[i * n + j] = R[i * 3 + j]
