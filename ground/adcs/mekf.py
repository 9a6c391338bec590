"""The 6-state MEKF with a gyroscope (Yoon 2017, Sec. 4.4, Eq. 4.23-4.52; Lefferts, Markley and Shuster).

State x = [q (4), b (3)] (Eq. 4.23); error state dx = [dq (3, vector part of q (x) q_hat^-1), db (3)] (Eq. 4.24-4.26).

- predict (Eq. 4.29-4.38): w_hat = w_meas - b_hat; q by the exact constant-rate solution of Eq. 4.10;
  F = [[-[w x], -1/2 I], [0, 0]] (Eq. 4.31); Phi in closed form for constant w (the series of Eq. 4.34 summed:
  Phi11 = I - [w x] sin(w dt)/w + [w x]^2 (1 - cos)/w^2, Phi12 = -1/2 (I dt - [w x] (1 - cos)/w^2
  + [w x]^2 (w dt - sin)/w^3), the standard form; the OCR of Eq. 4.35 is unreadable);
  Q of Eq. 4.38 with sigma_v (ARW, rad/sqrt(s)) and sigma_u (rate random walk, rad/s/sqrt(s)).
- update (Eq. 4.45-4.52): the star tracker gives a quaternion, so the measurement is the attitude error itself
  (as in the APKF's Eq. 4.139): z = vec(q_meas (x) q_hat^-1) = dq + v/2, H = [I 0], R = diag(sigma^2)/4;
  K (Eq. 4.48); P in the Joseph form (the thesis's Eq. 4.50 is P = (I - K H) P; Joseph as its APKF update,
  Eq. 4.142); q = dq (x) q_hat (Eq. 4.51), b = b + db (Eq. 4.52).
"""

import numpy as np

from ground.adcs import quat
from ground.adcs.quat import skew

N = 6


def phi(w, dt):
    """Closed-form Phi(dt) for constant w (sum of Eq. 4.34)."""
    wx = skew(w)
    wn = np.linalg.norm(w)
    i3 = np.eye(3)
    if wn * dt < 1e-6:
        p11 = i3 - wx * dt + 0.5 * wx @ wx * dt * dt
        p12 = -0.5 * (i3 * dt - 0.5 * wx * dt * dt + wx @ wx * dt ** 3 / 6.0)
    else:
        s, c = np.sin(wn * dt), np.cos(wn * dt)
        p11 = i3 - wx * (s / wn) + wx @ wx * ((1 - c) / wn ** 2)
        p12 = -0.5 * (i3 * dt - wx * ((1 - c) / wn ** 2) + wx @ wx * ((wn * dt - s) / wn ** 3))
    out = np.eye(N)
    out[:3, :3], out[:3, 3:] = p11, p12
    return out


def process_noise(sigma_v, sigma_u, dt):
    """Eq. 4.38 (for the error quaternion dq = dtheta/2)."""
    qv, qu = sigma_v ** 2, sigma_u ** 2
    q = np.zeros((N, N))
    q[:3, :3] = 0.25 * (qv * dt + qu * dt ** 3 / 3.0) * np.eye(3)
    q[:3, 3:] = q[3:, :3] = -0.25 * qu * dt ** 2 * np.eye(3)
    q[3:, 3:] = qu * dt * np.eye(3)
    return q


def predict(x, P, w_meas, dt, sigma_v, sigma_u):
    """(x, P) at k from k-1 with the gyro reading over the step (Eq. 4.29-4.38)."""
    w = w_meas - x[4:7]
    Phi = phi(w, dt)
    x = np.concatenate([quat.propagate(x[:4], w, dt), x[4:7]])
    P = Phi @ P @ Phi.T + process_noise(sigma_v, sigma_u, dt)
    return x, 0.5 * (P + P.T)


def joseph(P, H, R, K):
    """P+ = (I - K H) P (I - K H)^T + K R K^T (Eq. 4.142; the Joseph form of Eq. 4.50's (I - K H) P)."""
    A = np.eye(P.shape[0]) - K @ H
    P = A @ P @ A.T + K @ R @ K.T
    return 0.5 * (P + P.T)


def update(x, P, q_meas, R):
    """Star-tracker update (Eq. 4.45-4.52); R is the 3 x 3 covariance of the error-quaternion measurement."""
    H = np.zeros((3, N))
    H[:, :3] = np.eye(3)
    z = quat.error_vec(q_meas, x[:4])
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T                       # P H^T S^-1 (Eq. 4.48)
    dx = K @ z                                            # Eq. 4.49 (dx^- = 0)
    P = joseph(P, H, R, K)
    x = np.concatenate([quat.from_small(dx[:3], x[:4]), x[4:7] + dx[3:]])
    return x, P


class MEKF:
    """The MEKF over a recorded run: ``step(w_meas, q_meas or None)`` per 1 s."""

    def __init__(self, q0, P0_att_rad=np.radians(10.0), P0_bias=np.radians(1.0) / 3600.0,
                 sigma_v=np.radians(3.0) / 60.0, sigma_u=np.radians(0.05) / 3600.0 / 60.0,
                 sigma_st_rad=np.array([20.0, 20.0, 60.0]) * quat.RAD_PER_ARCSEC, dt=1.0):
        self.x = np.concatenate([np.asarray(q0, float), np.zeros(3)])
        self.P = np.diag([(P0_att_rad / 2) ** 2] * 3 + [P0_bias ** 2] * 3)
        self.sigma_v, self.sigma_u, self.dt = sigma_v, sigma_u, dt
        self.R = np.diag(np.asarray(sigma_st_rad) ** 2) / 4.0

    def step(self, w_meas, q_meas=None):
        self.x, self.P = predict(self.x, self.P, w_meas, self.dt, self.sigma_v, self.sigma_u)
        if q_meas is not None:
            self.x, self.P = update(self.x, self.P, q_meas, self.R)
        return self.x, self.P
