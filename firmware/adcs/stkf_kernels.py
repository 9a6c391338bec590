"""The lean STKF's kernels (MicroPython): the two-body propagation of one satellite (Eq. 5.4, 5.7), its
transition matrix and process noise (Eq. 5.8-5.11), and the 6-state block products the filter's covariance
updates are made of, a generated node's rows (``between``) among them (``stkf_lean.LeanStkf`` uses them). Compiled
by the native emitter; the block products run in C when the kernels are built (``linalg.kernels``), with the same
results bit for bit.

Gravity (``GRAVITY``): two-body (Eq. 5.7, the thesis's), or two-body plus the J2 zonal term

    a_J2 = -(3/2) J2 mu R^2 / |r|^5 [x (1 - 5 z^2/|r|^2), y (1 - 5 z^2/|r|^2), z (3 - 5 z^2/|r|^2)]

in J2000 with its z axis taken as the Earth's pole (precession and nutation left out: the pole of date moves
~20 arcsec a year off J2000's, 0.15 deg in 2027, a J2 error of ~5e-3 of the term, which the J2 model's process
noise covers, docs/ADCS.md). ``f`` and ``phi`` take the term's coefficient ``j2`` = (3/2) J2 mu R^2 (m^5/s^2; 0.0: two-body, the
same operations as without it, bit for bit)."""

from array import array
import math

from firmware.adcs import linalg
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators
from protocol.units import MU_EARTH as MU  # Eq. 5.7
from protocol.units import J2_EARTH, R_EARTH_EQ

QA_THESIS = 0.1 ** 2
N = 6                  # states per satellite
J2_TERM = 1.5 * J2_EARTH * MU * R_EARTH_EQ * R_EARTH_EQ      # m^5/s^2, the J2 term's coefficient
GRAVITY = {"two-body": 0.0, "j2": J2_TERM}                      # the model's name -> f's and phi's j2


def zeros_d(n):
    return array("d", bytes(8 * n))


@micropython.native
def f(x, o, dt, j2=0.0):
    """Two-body propagation (Eq. 5.4, 5.7) of one satellite's state x[o:o+6] by dt (negative: backward,
    Eq. 5.51), in place: RK4 steps of at most 1 s; j2 != 0: with the J2 term (module docstring)."""
    n = 1
    while n < abs(dt) - 1e-9:
        n += 1
    h = dt / n
    rx, ry, rz, vx, vy, vz = x[o], x[o + 1], x[o + 2], x[o + 3], x[o + 4], x[o + 5]
    hh, k = 0.5 * h, h / 6.0
    for _ in range(n):
        r2 = rx * rx + ry * ry + rz * rz
        q = r2 * math.sqrt(r2)
        c = cz = -MU / q
        if j2:                                   # + the J2 term: (cxy x, cxy y, cz z)
            e = j2 / (q * r2)
            c = c - e * (1.0 - 5.0 * rz * rz / r2)
            cz = c - 2.0 * e
        a1x, a1y, a1z = c * rx, c * ry, cz * rz
        x2, y2, z2 = rx + hh * vx, ry + hh * vy, rz + hh * vz
        u2, v2, w2 = vx + hh * a1x, vy + hh * a1y, vz + hh * a1z
        r2 = x2 * x2 + y2 * y2 + z2 * z2
        q = r2 * math.sqrt(r2)
        c = cz = -MU / q
        if j2:                                   # + the J2 term: (cxy x, cxy y, cz z)
            e = j2 / (q * r2)
            c = c - e * (1.0 - 5.0 * z2 * z2 / r2)
            cz = c - 2.0 * e
        a2x, a2y, a2z = c * x2, c * y2, cz * z2
        x3, y3, z3 = rx + hh * u2, ry + hh * v2, rz + hh * w2
        u3, v3, w3 = vx + hh * a2x, vy + hh * a2y, vz + hh * a2z
        r2 = x3 * x3 + y3 * y3 + z3 * z3
        q = r2 * math.sqrt(r2)
        c = cz = -MU / q
        if j2:                                   # + the J2 term: (cxy x, cxy y, cz z)
            e = j2 / (q * r2)
            c = c - e * (1.0 - 5.0 * z3 * z3 / r2)
            cz = c - 2.0 * e
        a3x, a3y, a3z = c * x3, c * y3, cz * z3
        x4, y4, z4 = rx + h * u3, ry + h * v3, rz + h * w3
        u4, v4, w4 = vx + h * a3x, vy + h * a3y, vz + h * a3z
        r2 = x4 * x4 + y4 * y4 + z4 * z4
        q = r2 * math.sqrt(r2)
        c = cz = -MU / q
        if j2:                                   # + the J2 term: (cxy x, cxy y, cz z)
            e = j2 / (q * r2)
            c = c - e * (1.0 - 5.0 * z4 * z4 / r2)
            cz = c - 2.0 * e
        rx, ry, rz = rx + k * (vx + 2.0 * (u2 + u3) + u4), ry + k * (vy + 2.0 * (v2 + v3) + v4), \
            rz + k * (vz + 2.0 * (w2 + w3) + w4)
        vx, vy, vz = vx + k * (a1x + 2.0 * (a2x + a3x) + c * x4), vy + k * (a1y + 2.0 * (a2y + a3y) + c * y4), \
            vz + k * (a1z + 2.0 * (a2z + a3z) + cz * z4)
    x[o], x[o + 1], x[o + 2], x[o + 3], x[o + 4], x[o + 5] = rx, ry, rz, vx, vy, vz


@micropython.native
def phi(Phi, x, o, dt, j2=0.0):
    """Phi (6 x 6) of one satellite over dt at x[o:o+3] (Eq. 3.30 with F of Eq. 5.4):
    [[I + G dt^2/2, I dt + G dt^3/6], [G dt, I + G dt^2/2]], G = -mu/|r|^3 (I - 3 r r^T/|r|^2), plus with
    j2 != 0 the J2 term's gradient -e [diag(b) + (2 w - 5 b_i) r_i r_j/|r|^2 - 10 z r_i dz_j/|r|^2],
    e = j2/|r|^5, w = 5 z^2/|r|^2, b = (1 - w, 1 - w, 3 - w)."""
    r0, r1, r2 = x[o], x[o + 1], x[o + 2]
    rr = r0 * r0 + r1 * r1 + r2 * r2
    c = -MU / (rr * math.sqrt(rr))
    d = -3.0 * c / rr
    h2, h3 = 0.5 * dt * dt, dt * dt * dt / 6.0
    r = (r0, r1, r2)
    e = w = b = ei = 0.0
    if j2:
        e = j2 / (rr * rr * math.sqrt(rr))
        w = 5.0 * r2 * r2 / rr
    for i in range(3):
        di, o = d * r[i], 6 * i
        if j2:
            b = 3.0 - w if i == 2 else 1.0 - w
            ei = -e * (2.0 * w - 5.0 * b) * r[i] / rr
        for j in range(3):
            g = di * r[j]
            if j2:
                g = g + ei * r[j]
                if j == 2:
                    g = g + 10.0 * e * r2 * r[i] / rr
            if i == j:
                g += c
                if j2:
                    g = g - e * b
                Phi[o + j] = Phi[o + 21 + j] = 1.0 + h2 * g
                Phi[o + 3 + j] = dt + h3 * g
            else:
                Phi[o + j] = Phi[o + 21 + j] = h2 * g
                Phi[o + 3 + j] = h3 * g
            Phi[o + 18 + j] = dt * g


@micropython.native
def process_noise(Q, dt, qa=QA_THESIS):
    """Q of Eq. 5.8-5.9 for one satellite: per axis [[qa dt^3/3, qa dt^2/2], [qa dt^2/2, qa dt]]."""
    dt = abs(dt)
    linalg.fill(Q, 36, 0.0)
    q3, q2, q1 = qa * dt * dt * dt / 3.0, qa * dt * dt / 2.0, qa * dt
    for i in range(3):
        Q[i * 6 + i] = q3
        Q[i * 6 + 3 + i] = Q[(3 + i) * 6 + i] = q2
        Q[(3 + i) * 6 + 3 + i] = q1


@micropython.native
def _mirror6(P, ld, c, v0, v1, v2, v3, v4, v5):
    """P[0:6, c] = v and P[c, 0:6] = v (the column first; adcsk.c's mirror6)."""
    P[c] = v0
    P[ld + c] = v1
    P[2 * ld + c] = v2
    P[3 * ld + c] = v3
    P[4 * ld + c] = v4
    P[5 * ld + c] = v5
    b = c * ld
    P[b] = v0
    P[b + 1] = v1
    P[b + 2] = v2
    P[b + 3] = v3
    P[b + 4] = v4
    P[b + 5] = v5


@micropython.native
def rows_mul_mirror(P, ld, src, c_lo, c_hi, F):
    """P[0:6, c] = F P[src:src+6, c] and P[c, 0:6] = its transpose for c_lo <= c < c_hi (F 6 x 6): the cross
    covariance of the current node with the older ones after a transition F (Eq. 5.21's P0j = Phi P0j, or the
    beacon's (I - K H) P0j), written symmetric. src = 0 works in place (column by column)."""
    f00, f01, f02, f03, f04, f05, f10, f11, f12, f13, f14, f15, f20, f21, f22, f23, f24, f25, \
        f30, f31, f32, f33, f34, f35, f40, f41, f42, f43, f44, f45, f50, f51, f52, f53, f54, f55 = F
    l2, l3, l4, l5 = 2 * ld, 3 * ld, 4 * ld, 5 * ld      # (F read once, into locals)
    s = src * ld
    for c in range(c_lo, c_hi):
        b = s + c
        p0, p1, p2, p3, p4, p5 = P[b], P[b + ld], P[b + l2], P[b + l3], P[b + l4], P[b + l5]
        v0 = f00 * p0 + f01 * p1 + f02 * p2 + f03 * p3 + f04 * p4 + f05 * p5
        v1 = f10 * p0 + f11 * p1 + f12 * p2 + f13 * p3 + f14 * p4 + f15 * p5
        v2 = f20 * p0 + f21 * p1 + f22 * p2 + f23 * p3 + f24 * p4 + f25 * p5
        v3 = f30 * p0 + f31 * p1 + f32 * p2 + f33 * p3 + f34 * p4 + f35 * p5
        v4 = f40 * p0 + f41 * p1 + f42 * p2 + f43 * p3 + f44 * p4 + f45 * p5
        v5 = f50 * p0 + f51 * p1 + f52 * p2 + f53 * p3 + f54 * p4 + f55 * p5
        _mirror6(P, ld, c, v0, v1, v2, v3, v4, v5)


@micropython.native
def sandwich(P, ld, r0, F, Q, T, src=None):
    """P[r0:r0+6, r0:r0+6] = F P[src:src+6, src:src+6] F^T + Q (Eq. 3.31; src defaults to r0), symmetric:
    T = F P (work, 6 x 6, in T's precision), then the upper triangle of T F^T + Q, mirrored."""
    if src is None:
        src = r0
    f00, f01, f02, f03, f04, f05, f10, f11, f12, f13, f14, f15, f20, f21, f22, f23, f24, f25, \
        f30, f31, f32, f33, f34, f35, f40, f41, f42, f43, f44, f45, f50, f51, f52, f53, f54, f55 = F
    l2, l3, l4, l5 = 2 * ld, 3 * ld, 4 * ld, 5 * ld
    s = src * ld + src
    for c in range(6):                                   # T = F P, column by column
        b = s + c
        p0, p1, p2, p3, p4, p5 = P[b], P[b + ld], P[b + l2], P[b + l3], P[b + l4], P[b + l5]
        T[c] = f00 * p0 + f01 * p1 + f02 * p2 + f03 * p3 + f04 * p4 + f05 * p5
        T[6 + c] = f10 * p0 + f11 * p1 + f12 * p2 + f13 * p3 + f14 * p4 + f15 * p5
        T[12 + c] = f20 * p0 + f21 * p1 + f22 * p2 + f23 * p3 + f24 * p4 + f25 * p5
        T[18 + c] = f30 * p0 + f31 * p1 + f32 * p2 + f33 * p3 + f34 * p4 + f35 * p5
        T[24 + c] = f40 * p0 + f41 * p1 + f42 * p2 + f43 * p3 + f44 * p4 + f45 * p5
        T[30 + c] = f50 * p0 + f51 * p1 + f52 * p2 + f53 * p3 + f54 * p4 + f55 * p5
    Fr = ((f00, f01, f02, f03, f04, f05), (f10, f11, f12, f13, f14, f15), (f20, f21, f22, f23, f24, f25),
          (f30, f31, f32, f33, f34, f35), (f40, f41, f42, f43, f44, f45), (f50, f51, f52, f53, f54, f55))
    for i in range(6):
        o = 6 * i
        t0, t1, t2, t3, t4, t5 = T[o], T[o + 1], T[o + 2], T[o + 3], T[o + 4], T[o + 5]
        a = (r0 + i) * ld + r0
        b = a                                            # P[j, i] = P[b + i], j = i, i + 1, ..
        for j in range(i, 6):
            g0, g1, g2, g3, g4, g5 = Fr[j]
            s = Q[o + j] + t0 * g0 + t1 * g1 + t2 * g2 + t3 * g3 + t4 * g4 + t5 * g5
            P[a + j] = s
            P[b + i] = s
            b += ld


_INF = float("inf")


@micropython.native
def _finite(v, n):
    lo, hi = -_INF, _INF
    for i in range(n):
        if not lo < v[i] < hi:                  # NaN and +-inf fail (a comparison makes no new float)
            return False
    return True


@micropython.native
def _ikh_rows(P, ld, c_lo, c_hi, G):
    """rows_mul_mirror(P, ld, 0, c_lo, c_hi, F) for F = I - K H whose columns 3 .. 5 are the identity's
    (H = [H_r 0] on the position): F's first three columns G (6 x 3) are multiplied, the rest adds p_i.
    The terms left out are exact zeros, so the sums are the full product's."""
    g00, g01, g02, g10, g11, g12, g20, g21, g22, g30, g31, g32, g40, g41, g42, g50, g51, g52 = G
    l2, l3, l4, l5 = 2 * ld, 3 * ld, 4 * ld, 5 * ld
    for c in range(c_lo, c_hi):
        p0, p1, p2 = P[c], P[ld + c], P[l2 + c]
        v0 = g00 * p0 + g01 * p1 + g02 * p2
        v1 = g10 * p0 + g11 * p1 + g12 * p2
        v2 = g20 * p0 + g21 * p1 + g22 * p2
        v3 = g30 * p0 + g31 * p1 + g32 * p2 + P[l3 + c]
        v4 = g40 * p0 + g41 * p1 + g42 * p2 + P[l4 + c]
        v5 = g50 * p0 + g51 * p1 + g52 * p2 + P[l5 + c]
        _mirror6(P, ld, c, v0, v1, v2, v3, v4, v5)


@micropython.native
def _ikh_sandwich(P, ld, G, Q, T):
    """sandwich(P, ld, 0, F, Q, T) for F = I - K H as in ``_ikh_rows``: P00 = F P00 F^T + Q (Q's upper
    triangle read), upper triangle mirrored; T (36, a list) work."""
    g00, g01, g02, g10, g11, g12, g20, g21, g22, g30, g31, g32, g40, g41, g42, g50, g51, g52 = G
    l2, l3, l4, l5 = 2 * ld, 3 * ld, 4 * ld, 5 * ld
    for c in range(6):                                   # T = F P00, column by column
        p0, p1, p2 = P[c], P[ld + c], P[l2 + c]
        T[c] = g00 * p0 + g01 * p1 + g02 * p2
        T[6 + c] = g10 * p0 + g11 * p1 + g12 * p2
        T[12 + c] = g20 * p0 + g21 * p1 + g22 * p2
        T[18 + c] = g30 * p0 + g31 * p1 + g32 * p2 + P[l3 + c]
        T[24 + c] = g40 * p0 + g41 * p1 + g42 * p2 + P[l4 + c]
        T[30 + c] = g50 * p0 + g51 * p1 + g52 * p2 + P[l5 + c]
    for i in range(6):
        o = 6 * i
        t0, t1, t2 = T[o], T[o + 1], T[o + 2]
        a = b = i * ld                                   # P[i, j] = P[a + j], P[j, i] = P[b + i]
        for j in range(i, 6):
            q = 3 * j
            s = Q[o + j] + t0 * G[q] + t1 * G[q + 1] + t2 * G[q + 2]
            if j >= 3:
                s = s + T[o + j]
            P[a + j] = s
            P[b + i] = s
            b += ld


@micropython.native
def between(Hp, S, P, ld, ia, ic, A, B, T, qa3, m, Ar, Br, W):
    """The rows of the generated node b between nodes a (index ia) and c (ic) of the joint covariance P (Eq.
    5.46-5.52, ``LeanStkf._hp_between``): Hp (6 rows of m) = A P[a rows, :] + B P[c rows, :], and S (6 x 6)
    = P_bb = Hp_a A^T + Hp_c B^T + (I - B Fb) Qa, upper triangle mirrored (T = I - B Fb; qa3 = (q3, q2, q1),
    Qa per axis [[q3, q2], [q2, q1]]). Ar, Br (6 lists of 6) and W (6) are work: A and B by rows."""
    q3, q2, q1 = qa3
    for i in range(N):                                # A, B by rows (each read once)
        ra, rb, o = Ar[i], Br[i], 6 * i
        for k in range(N):
            ra[k], rb[k] = A[o + k], B[o + k]
    a00, a01, a02, a03, a04, a05 = Ar[0]
    a10, a11, a12, a13, a14, a15 = Ar[1]
    a20, a21, a22, a23, a24, a25 = Ar[2]
    a30, a31, a32, a33, a34, a35 = Ar[3]
    a40, a41, a42, a43, a44, a45 = Ar[4]
    a50, a51, a52, a53, a54, a55 = Ar[5]
    b00, b01, b02, b03, b04, b05 = Br[0]
    b10, b11, b12, b13, b14, b15 = Br[1]
    b20, b21, b22, b23, b24, b25 = Br[2]
    b30, b31, b32, b33, b34, b35 = Br[3]
    b40, b41, b42, b43, b44, b45 = Br[4]
    b50, b51, b52, b53, b54, b55 = Br[5]
    H0, H1, H2, H3, H4, H5 = Hp
    l2, l3, l4, l5 = 2 * ld, 3 * ld, 4 * ld, 5 * ld
    sa, sc = ia * N * ld, ic * N * ld
    for j in range(m):                                # Hp = A P[a rows, :] + B P[c rows, :]  (6 x m)
        o, q = sa + j, sc + j
        p0, p1, p2, p3, p4, p5 = P[o], P[o + ld], P[o + l2], P[o + l3], P[o + l4], P[o + l5]
        c0, c1, c2, c3, c4, c5 = P[q], P[q + ld], P[q + l2], P[q + l3], P[q + l4], P[q + l5]
        H0[j] = a00 * p0 + a01 * p1 + a02 * p2 + a03 * p3 + a04 * p4 + a05 * p5 \
            + b00 * c0 + b01 * c1 + b02 * c2 + b03 * c3 + b04 * c4 + b05 * c5
        H1[j] = a10 * p0 + a11 * p1 + a12 * p2 + a13 * p3 + a14 * p4 + a15 * p5 \
            + b10 * c0 + b11 * c1 + b12 * c2 + b13 * c3 + b14 * c4 + b15 * c5
        H2[j] = a20 * p0 + a21 * p1 + a22 * p2 + a23 * p3 + a24 * p4 + a25 * p5 \
            + b20 * c0 + b21 * c1 + b22 * c2 + b23 * c3 + b24 * c4 + b25 * c5
        H3[j] = a30 * p0 + a31 * p1 + a32 * p2 + a33 * p3 + a34 * p4 + a35 * p5 \
            + b30 * c0 + b31 * c1 + b32 * c2 + b33 * c3 + b34 * c4 + b35 * c5
        H4[j] = a40 * p0 + a41 * p1 + a42 * p2 + a43 * p3 + a44 * p4 + a45 * p5 \
            + b40 * c0 + b41 * c1 + b42 * c2 + b43 * c3 + b44 * c4 + b45 * c5
        H5[j] = a50 * p0 + a51 * p1 + a52 * p2 + a53 * p3 + a54 * p4 + a55 * p5 \
            + b50 * c0 + b51 * c1 + b52 * c2 + b53 * c3 + b54 * c4 + b55 * c5
    sa, sc = ia * N, ic * N
    for i in range(N):                                # S0 = P_bb, upper triangle mirrored
        h, o = Hp[i], 6 * i
        p0, p1, p2, p3, p4, p5 = h[sa], h[sa + 1], h[sa + 2], h[sa + 3], h[sa + 4], h[sa + 5]
        c0, c1, c2, c3, c4, c5 = h[sc], h[sc + 1], h[sc + 2], h[sc + 3], h[sc + 4], h[sc + 5]
        for j in range(i, N):
            a, b = Ar[j], Br[j]
            W[0] = p0 * a[0] + c0 * b[0]
            W[1] = p1 * a[1] + c1 * b[1]
            W[2] = p2 * a[2] + c2 * b[2]
            W[3] = p3 * a[3] + c3 * b[3]
            W[4] = p4 * a[4] + c4 * b[4]
            W[5] = p5 * a[5] + c5 * b[5]
            g, qg, qh = (j, q3, q2) if j < 3 else (j - 3, q2, q1)    # + (I - B Fb) Qa: Qa's column j
            W[g] = W[g] + T[o + g] * qg                               # has rows g and g + 3 only
            W[g + 3] = W[g + 3] + T[o + g + 3] * qh
            s = W[0] + W[1] + W[2] + W[3] + W[4] + W[5]
            S[o + j] = s
            S[j * N + i] = s


def _add_gain(x, n, Kt, r, m):
    """x += K r with K^T stored m x n."""
    for i in range(n):
        s = 0.0
        for a in range(m):
            s += Kt[a * n + i] * r[a]
        x[i] = x[i] + s


_K = linalg.kernels          # the C kernels, when built (linalg's comment): the same results, bit for bit
if _K is not None:
    rows_mul_mirror = linalg.either(_K.rows_mul_mirror, rows_mul_mirror)
    sandwich = linalg.either(_K.sandwich, sandwich)
    _ikh_rows, _ikh_sandwich = linalg.either(_K.ikh_rows, _ikh_rows), linalg.either(_K.ikh_sandwich, _ikh_sandwich)
