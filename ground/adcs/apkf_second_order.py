"""The APKF's second-order covariance terms (the consistent form, ``apkf.predict(second_order=True)``): the
truncated second-order filter's (Gelb, Applied Optimal Estimation, 1974, Ch. 6) rate covariance for the two
products of estimated quantities in the dynamics that the first-order F leaves out."""

from functools import lru_cache

import numpy as np

from ground.adcs import quat
from ground.adcs.apkf_model import ID1, ID2, IJR, IM, IQ, NW

_LEVI = np.zeros((3, 3, 3))                            # the Levi-Civita symbol: (u x v)_a = eps_aic u_i v_c
for _a, _i, _c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI[_a, _i, _c], _LEVI[_a, _c, _i] = 1.0, -1.0


@lru_cache(maxsize=4)
def _so_index(n):
    """Per wheel, the places in an n x n P.ravel() of (d1, d1), (d2, d2), (Jrw, Jrw), (d1, Jrw), (d2, Jrw),
    (d1, d2) (``second_order_noise``)."""
    return np.concatenate([np.arange(a.start, a.stop) * n + np.arange(b.start, b.stop)
                           for a, b in ((ID1, ID1), (ID2, ID2), (IJR, IJR), (ID1, IJR), (ID2, IJR), (ID1, ID2))])


def second_order_noise(x, P, model, Ji):
    """The rate's covariance term of the truncated second-order filter (Gelb, Applied Optimal Estimation, 1974,
    Ch. 6) for the one product of two estimated parameters in the dynamics that matters: the wheel momentum axes
    C_i Jrw_i = (c0_i + c1_i d1_i + c2_i d2_i) Jrw_i (Eq. 4.60). Its second-order part g_i = (c1_i e_d1 + c2_i
    e_d2) e_Jrw has, for Gaussian errors, Cov(g_i) = sum_uv u v^T (P_du,dv P_J + P_du,J P_dv,J) over u, v in
    (c1_i, c2_i), and reaches the body as the torque -(W_i [w x] + a_i) g_i (Eq. 4.83) held over the step:
    Q2 = J^-1 (sum_i M_i Cov(g_i) M_i^T) J^-T dt^2 on the rate (3 x 3). x: the state at the step's start after
    ``shift_tach`` (a = (W+ - W-)/dt), P the parameters' covariance, Ji = J^-1. It is ~1/3 of the first-order
    torque uncertainty with the 10 deg misalignment prior of Sec. 4.8 and shrinks with the parameters' P."""
    dt = model.dt
    a = (x[38:42] - x[34:38]) / dt
    W = x[30:34]
    w1, w2, w3 = x[4:7].tolist()
    p11, p22, pj, p1j, p2j, p12 = P.take(_so_index(len(P))).reshape(6, NW)
    s11 = p11 * pj + p1j * p1j
    s22 = p22 * pj + p2j * p2j
    s12 = p12 * pj + p1j * p2j
    c = model.c12                                                 # [c1 | c2], 3 x 8
    m = np.array([w2 * c[2] - w3 * c[1], w3 * c[0] - w1 * c[2], w1 * c[1] - w2 * c[0]])
    m *= np.concatenate([W, W])
    m += c * np.concatenate([a, a])                               # [M_i c1_i | M_i c2_i]
    m1, m2 = m[:, :NW], m[:, NW:]
    A = (m1 * s12) @ m2.T
    Q = (m1 * s11) @ m1.T + (m2 * s22) @ m2.T + A + A.T
    Q = Ji @ Q @ Ji.T
    Q *= 0.5 * dt * dt
    return Q + Q.T


def dipole_attitude_noise(P, b, Ji, dt):
    """The rate's covariance term of the truncated second-order filter (Gelb 1974, Ch. 6) for the dipole's torque
    m x b_b (Eq. 4.83) with b_b = A(dq) b_hat ~ b_hat + 2 [b_hat x] dq (our derivation; F21's [m x] 2 [b x] is its
    first-order part): the product of the two errors, g = 2 e_m x (b_hat x dq), has for Gaussian errors Cov(g)_ab
    = sum B_aij B_bkl (P_mm,ik P_qq,jl + P_mq,il P_mq,kj) with g_a = sum B_aij e_m,i dq_j, held over the step as
    ``second_order_noise``'s: J^-1 Cov(g) J^-T dt^2 (3 x 3). While the estimated dipole is small against its 1 sigma
    (a file's prior is often zero), F21's term is too, and this is how P sees the field's torque turn with an
    attitude error; it grows with the attitude's P over a blind stretch. b: the field in the body (T), Ji = J^-1."""
    B = 2.0 * np.einsum("aic,cj->aij", _LEVI, quat.skew(b))        # B_aij = 2 (e_i x (b x e_j))_a
    Pmm, Pqq, Pmq = P[IM, IM], P[IQ, IQ], P[IM, IQ]
    C = np.einsum("aij,bkl,ik,jl->ab", B, B, Pmm, Pqq) + np.einsum("aij,bkl,il,kj->ab", B, B, Pmq, Pmq)
    return Ji @ (0.5 * (C + C.T)) @ Ji.T * (dt * dt)
