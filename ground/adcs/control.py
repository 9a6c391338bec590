"""Attitude control for pointing and tracking (Yoon 2017, Ch. 6) in numpy: the reference of the flight app's laws
(``firmware/adcs/control.py``, held equal to these by tests/test_adcs_lean.py), and the forms the ground's analyses
and the calibration maneuvers use.

Conventions as the APKF (Sec. 4.2): q = [q1, q2, q3, q4] scalar last, A(q) maps inertial (J2000) to body,
A(q (x) p) = A(q) A(p).

- ``orbit_frame``: the Orbit Frame of Eq. 6.1-6.2 (x along SatA's velocity, y the orbit normal, z = x cross y).
- ``attitude_command``: the minimum rotation that puts the laser axis l_b on the line of sight to SatB
  (Eq. 6.3), composed with the Orbit Frame (Eq. 6.4).
- ``gains`` / ``pd_torque``: the quaternion feedback PD of Eq. 6.5-6.7,
  tau_c = -K q_e - D w_e, K = 2 wn^2 J, D = 2 zeta wn J (zeta = 1).
  Eq. 6.7 as printed: wn = 8 / t_s (the OCR: "8 Wn - (6.7) ts"), independent of zeta. Read with a 2 zeta in the
  denominator (wn = 4 / t_s, Wie's t_s = 8 / c with c = 2 zeta wn) it would give ~30 % less than the thesis's Sec.
  6.4.4 stability 1σ (6.764, 8.617) arcsec/s at t_s = 33 s and a J sweep whose minimum falls below the thesis's
  33 s, where the printed form reproduces the stability to about 1 % (bench/bench_bps.py measures both).
  Tested: the closed-loop poles are a double pole at -8 / t_s.
  Beyond Eq. 6.5 (the thesis is silent; a flight team would add them): w_e = w - w_c
  with the command rate w_c (the tracking attitude turns at about the orbit rate: without it the PD lags by
  2 zeta |w_c| / wn, ~30 arcmin), the gyroscopic term w x H, and the feed-forward of the known external torques
  the APKF estimates (gravity gradient with its J, residual dipole m x b, tau_d).
- ``wheel_torques``: minimum-norm wheel torques (Eq. 6.11) and, during calibration maneuvers, the null-space
  torque of Eq. 4.145 (a = 10 % of the largest minimum-norm torque). This is the Sec. 4.8 code of
  ``emulator.spacecraft.scenario`` (one copy; the emulator does not import ground). Sign: the body feels -C u,
  so the motor torques are u = -C^T (C C^T)^-1 tau_c (+ a N).
- ``friction_compensation``: wheel friction feed-forward from the datasheet model (our addition).
- ``saturate``: scales tau_c down (direction kept) so that no wheel torque passes its limit.
"""

import numpy as np

from emulator.spacecraft import environment as env
from emulator.spacecraft.wheels import WheelParams, pyramid_c0  # noqa: F401
from emulator.spacecraft.scenario import null_vector, wheel_torques  # noqa: F401  (Eq. 4.144-4.145, 6.11)
from ground.adcs import quat

WHEEL_DATASHEET = WheelParams()           # what the flight software knows of its wheels (datasheet)
LASER_AXIS = np.array([1.0, 0.0, 0.0])    # l_b: the 3U's long axis (stated; the thesis does not give it)
ZETA = 1.0


def orbit_frame(r_a, v_a):
    """T_o<-j2k (Eq. 6.1-6.2): rows x_o = v/|v|, y_o = r x v/|r x v|, z_o = x_o x y_o."""
    x = v_a / np.linalg.norm(v_a)
    y = env.cross3(r_a, v_a)
    y = y / np.linalg.norm(y)
    return np.vstack([x, y, env.cross3(x, y)])


def dcm_to_quat(T):
    """q with A(q) = T (scalar last, q4 >= 0), Shepperd's method."""
    tr = np.trace(T)
    d = np.array([T[0, 0], T[1, 1], T[2, 2], tr])
    i = int(np.argmax(d))
    if i == 3:
        q4 = 0.5 * np.sqrt(1 + tr)
        q = np.array([T[1, 2] - T[2, 1], T[2, 0] - T[0, 2], T[0, 1] - T[1, 0], 0.0]) / (4 * q4)
        q[3] = q4
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        qi = 0.5 * np.sqrt(1 + 2 * T[i, i] - tr)
        q = np.zeros(4)
        q[i] = qi
        q[j] = (T[i, j] + T[j, i]) / (4 * qi)
        q[k] = (T[i, k] + T[k, i]) / (4 * qi)
        q[3] = (T[j, k] - T[k, j]) / (4 * qi)
    q = q / np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def min_rotation(a, b):
    """q with A(q) b = a for unit vectors a, b, the smallest rotation (Eq. 6.3, 6.17):
    q4 = sqrt((1 + a.b)/2), q_vec = a x b / (2 q4)."""
    c = float(a @ b)
    if c < -1 + 1e-12:
        raise ValueError("laser axis and line of sight are opposite: the minimum rotation is not unique")
    q4 = np.sqrt(0.5 * (1.0 + c))
    v = env.cross3(a, b) / (2 * q4)
    return np.array([v[0], v[1], v[2], q4])


def attitude_command(r_a, v_a, r_b, laser_axis=LASER_AXIS):
    """q_c (Eq. 6.3-6.4): p_o = T_o p, Pq = min_rotation(l_b, p_o), q_c = Pq (x) q_j2k."""
    T = orbit_frame(r_a, v_a)
    p = r_b - r_a
    p_o = T @ (p / np.linalg.norm(p))
    return quat.quat_mul(min_rotation(np.asarray(laser_axis, float), p_o), dcm_to_quat(T))


def natural_frequency(ts):
    """wn of Eq. 6.7: wn = 8 / t_s (rad/s)."""
    ts = float(ts)
    if not (np.isfinite(ts) and ts > 0):
        raise ValueError("settling time ts must be > 0 s, got %r" % (ts,))
    return 8.0 / ts


def gains(J, ts, zeta=ZETA):
    """(K, D) of Eq. 6.6: K = 2 wn^2 J, D = 2 zeta wn J."""
    wn = natural_frequency(ts)
    return 2 * wn * wn * J, 2 * zeta * wn * J


def attitude_error(q, qc):
    """q_e = q (x) q_c^-1 with q4 >= 0 (the short way round); its vector part is used in Eq. 6.5."""
    qe = quat.quat_mul(q, quat.conj(qc))
    return qe if qe[3] >= 0 else -qe


def pd_torque(q, w, qc, wc, K, D, H=None, tau_ff=None):
    """tau_c = -K q_e,vec - D (w - A(q_e) w_c) (Eq. 6.5) + w x H - tau_ff (our additions; None leaves out;
    tau_ff is the known external torque, cancelled).
    w_c is in the command frame; A(q_e) brings it to the body frame."""
    qe = attitude_error(q, qc)
    we = w - quat.dcm(qe) @ wc
    tau = -K @ qe[0:3] - D @ we
    if H is not None:
        tau = tau + env.cross3(w, H)
    if tau_ff is not None:
        tau = tau - tau_ff
    return tau


def friction_compensation(w_rw, coulomb=WHEEL_DATASHEET.friction_coulomb,
                          viscous=WHEEL_DATASHEET.friction_viscous,
                          smooth_rad_s=WHEEL_DATASHEET.friction_smooth_rpm * 2 * np.pi / 60):
    """Motor torque that cancels the wheels' friction at the read-out speeds w_rw (rad/s): the datasheet
    model (Coulomb + viscous, smoothed through zero; the defaults are ``WheelParams``'). Our addition: without
    it the ~2 uN m per spinning wheel reaches the body and the PD holds it with a steady error of ~10^3 arcsec."""
    return viscous * w_rw + coulomb * np.tanh(w_rw / smooth_rad_s)


def saturate(tau_c, C, torque_max):
    """tau_c scaled down, direction kept, so that the minimum-norm wheel torques stay within torque_max."""
    u = C.T @ np.linalg.solve(C @ C.T, tau_c)
    peak = float(np.max(np.abs(u)))
    return tau_c if peak <= torque_max else tau_c * (torque_max / peak)
