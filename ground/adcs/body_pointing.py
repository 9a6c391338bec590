"""The body pointing simulator (BPS) of Yoon 2017, Sec. 6.4: calibration, parameter file, pointing and tracking.

Truth (the spacecraft simulator of Fig. 6-1): ``emulator.spacecraft.Spacecraft`` (Eq. 4.16, 4.56; true J, wheel
inertias and misalignments, residual dipole of Sec. 4.8) by RK4 at 0.1 s, sampled at 10 Hz. The orbits of SatA
and SatB are the STKF issue's truth (``emulator.orbits.truth_samples``: brahe "hpop" or "two-body", 1 s samples)
interpolated by 10th-order Lagrange (Sec. 6.4.1) onto a 20 Hz grid; the spacecraft's gravity gradient and
magnetic field use SatA's interpolated position. The field's dipole turns with the Earth from GMST at Eq. 5.53's
epoch (139.40 deg), the orbits' t = 0. Sensors (their own time tags): the
star tracker (20/20/60 arcsec, none at |w| >= 0.1 deg/s) and the tachometers (10 rpm) at each 1 s tick, SatA's
GNSS and the beacon (60 arcsec) at each tick, SatB's GNSS on SatB's clock (random phase) relayed 2-3 s late.

Flight software at 1 Hz, from the sensor outputs and wheel read-outs only: the APKF (``ground.adcs.apkf``,
started from the parameter file), the STKF with the EAFLS (``ground.adcs.stkf``/``afls``, the attitude
covariance 4 P_qq from the APKF as in Sec. 5.3.3) and the controller of ``ground.adcs.control`` (command
from the STKF's rA, vA, rB; PD on the APKF's q, w; its J, C, Jrw; minimum-norm wheel torques, held 1 s). The
orbit and field inputs of the APKF's model and of the external-torque feed-forward come from the STKF's rA
(``EstimatedOrbit``), not from the truth.

Sequence (Sec. 6.4.2):
1. ``calibrate``: nine sets of the Sec. 4.7.1 calibration maneuver (the ``emulator.spacecraft.scenario``
   truth at 1 s, whose controller has perfect q and w as in Sec. 4.8) with the APKF; 30 s + 9 x 180 s = 1650 s.
   (Stated: the calibration is not closed through the APKF here; Sec. 6.4.2 does not say it is.)
2. The APKF's final parameters and covariances go to a parameter file (``write_params``; format below).
3. ``simulate``: the pointing-and-tracking run from q = [0, 0, 0, 1] at rest, the APKF started from that
   file (attitude and rate from the first two star-tracker outputs). A 30 s hold while the APKF's rate
   converges on the star tracker (stated: without it the slew starts with the rate still at its (10 deg/s)^2
   prior, the star tracker goes blind above 0.1 deg/s, and the filter never regains it; measured: errors of
   ~10^4 arcsec). In the hold the controller damps the rate on the estimate (q_c = q_hat, w_c = 0, with the
   same gyroscopic, external-torque and friction feed-forward as after it), as the flight app's step 4: with
   idle wheels the residual dipole's torque took the body past the star tracker's 0.1 deg/s ~9 s into the hold
   (measured), and the slew started from a blind, drifting estimate. After the hold and 4 t_s of settling the
   pointing error
   (dtheta1, dtheta2, Eq. 6.12-6.17) and the stability (domega1, domega2, Eq. 6.18-6.21) are collected at 10 Hz.

Parameter file: ``protocol.paramfile`` ("fps-bps-params/1", its keys and the one checker the flight firmware
uses too); ``torque_scale`` comes from ``absolute_jrw``, ``calibration`` is {seed, sets, duration_s, ...}.

Units in the outputs: arcsec and arcsec/s; J (Eq. 6.22) in rad^2, like Fig. 6-2's axis.
"""

import io
import os
import time

import numpy as np

from emulator.spacecraft import scenario
from emulator.spacecraft.devices import Magnetorquers
from emulator.spacecraft.dynamics import dcm
from emulator.spacecraft.scenario import HOLD_S, LAG_S, laser_axis
from emulator.spacecraft.wheels import N_WHEELS, WheelParams
from ground.adcs import apkf, control, modes, quat, runs, stkf
from ground.adcs.afls import Afls
from ground.fileio import write_atomic, write_json
from protocol import paramfile as pf
from protocol.units import RAD_PER_ARCSEC

RPM = 2 * np.pi / 60
FORMAT = pf.FORMAT
CAL_SETS = 9
W_OBJ = np.array([1.0, 1.0, 10.0, 10.0])        # Eq. 6.24
THESIS = {  # Sec. 6.4.4, ts = 33 s: (mean, 1 sigma)
    False: {"theta": ((1.261, 21.456), (18.644, 35.919)), "omega": ((-0.033, 6.764), (-0.031, 8.617))},
    True: {"theta": ((0.955, 20.143), (12.795, 33.945)), "omega": ((-0.024, 7.054), (-0.128, 8.744))},
}
TS_THESIS = 33.0
MAX_TS_S = 21600.0    # t_s at most 6 h: 4 t_s of settling at most a day (the run is held in memory at 10 Hz)
BUDGET_POINTING_3SIGMA = 150.0
BUDGET_STABILITY_3SIGMA = 35.0
SLOW_S = 60       # the error budget's moving average for the tracking part's slow share (s)
TACH_NOISE_RPM = WheelParams.noise_rpm   # the tachometers' 10 rpm 1 sigma (Sec. 4.8)
SPAN_MARGIN_S = 2.0   # the orbit truth's span beyond the run (``truth_span``; part of the truth cache's key)
WORLDS = ("thesis", "flight")
MODE_CODE = {m: float(i) for i, m in enumerate(modes.MODES)}
# The flight world's flight-software options (``simulate(world="flight", flight={...})``); units in the names.
FLIGHT = {
    # the eigenaxis slew's rate and acceleration limits: the star tracker is blind above its 0.1 deg/s, so the slew
    # is short rather than slow (measured: the lean APKF's rate error grew ~5 arcsec/s per blind second; a 90 deg
    # slew at 0.5 deg/s left ~0.1 deg/s, which kept the tracker blind after it; at 2 deg/s, < 0.03 deg/s);
    # 2 deg/s is ~1/2 of what the 3U's wheels hold at 80 % of their speed, 0.2 deg/s^2 ~16 % of their torque
    "slew_rate_deg_s": 2.0,
    "slew_acc_deg_s2": 0.2,
    "reslew_deg": 1.0,             # POINT -> SLEW when the estimate is this far off the command
    "unload_gain_1_s": 2e-3,       # the cross-product law's gain: the wheels' momentum across b decays in ~500 s
    "innovation_gate": 44.84,      # chi-square, 3 dof, 1 - 1e-9: a star-tracker output beyond it resets the attitude
    "beacon_gate_arcsec": 300.0,   # the STKF takes the beacon only while the attitude 1 sigma is within this
    "wheel_bias_share": 0.2,       # the wheels' null-space speed bias, a share of their speed limit
    "wheel_bias_gain_1_s": 0.01,   # and its gain: ~100 s to reach it
}
SUMMARY_KEYS = ("pointing_mean_arcsec", "pointing_sigma_arcsec", "stability_mean_arcsec_s",
                "stability_sigma_arcsec_s", "pointing_3sigma_arcsec", "stability_3sigma_arcsec_s", "complete")


# --- parameter file ------------------------------------------------------------------------------------------
def absolute_jrw(u, tach, dt=1.0):
    """Each wheel's absolute inertia from the commanded motor torques u[k] (held over step k -> k+1) and the
    tachometer read-outs: least squares of dW_i = u_i dt / Jrw_i (friction and the body's own acceleration,
    < 1 % here, are neglected). Our addition: the APKF's calibration is relative (everything scaled by
    s = Jxx_ref / Jxx, Sec. 4.6.2), and a controller must know the absolute scale to cancel a torque."""
    dW = np.diff(tach, axis=0)
    uu = u[:-1] * dt
    return np.sum(uu * uu, axis=0) / np.sum(uu * dW, axis=0)


def torque_scale(x, jrw_abs, model):
    """s_hat = mean over wheels of Jrw_filter |c_i| / Jrw_abs (|c_i| the unnormalised Eq. 4.60 column)."""
    cn = np.sqrt(1 + x[18:22] ** 2 + x[22:26] ** 2)
    return float(np.mean(x[26:30] * cn / jrw_abs))


# The parameter file's "x" (protocol.paramfile): its parts, in order, and where each sits in the APKF's state x (in
# P, one row lower)
def _x_slices(start=7):
    out = []
    for k, n in pf.X_PARTS:
        out.append((k, slice(start, start + n)))
        start += n
    return tuple(out)


X_PARTS = _x_slices()


def params_from_apkf(x, P, jxx, meta, scale=1.0):
    return {"format": FORMAT, "wheels": N_WHEELS, "jxx_ref_kgm2": float(jxx), "torque_scale": float(scale),
            "x": {k: x[s].tolist() for k, s in X_PARTS},
            "P": P[apkf.PARAMS, apkf.PARAMS].tolist(), "calibration": meta}


def check_params(d, where="parameter file", spacecraft=None):
    """Validate a parameter file dict against the spacecraft (``protocol.paramfile.check``; ``spacecraft`` a
    checked spacecraft file, None: the thesis's 3U); returns (x_params (23), P (23 x 23), jxx, torque_scale)."""
    try:
        c = pf.check(d, spacecraft)
    except ValueError as exc:
        raise ValueError("%s: %s" % (where, exc)) from None
    xp = np.array([v for k, _ in X_PARTS for v in c["x"][k]])
    return xp, np.array(c["P"]), c["jxx_ref_kgm2"], c["torque_scale"]


def load_params(path, spacecraft=None):
    from ground.fileio import read_json
    d = read_json(path, "parameter file")
    return check_params(d, path, spacecraft) + (d,)


def write_params(path, d, spacecraft=None):
    check_params(d, path, spacecraft)
    write_json(path, d)


# --- 1. calibration ----------------------------------------------------------------------------------------
def calibrate(seed=0, sets=CAL_SETS, progress=False, spacecraft=None):
    """Nine calibration maneuver sets through the APKF; returns the parameter-file dict (and the final errors).
    ``spacecraft``: a checked spacecraft file (None: thesis-3u) for the maneuvers' truth and controller
    (``scenario.simulate``) and the APKF's model and priors (``runs.apkf_model``, ``runs.apkf_prior``)."""
    d = spacecraft or scenario.thesis_3u()
    o = scenario.simulate(case=1, seed=seed, maneuver=scenario.Maneuver(sets=sets), spacecraft=d)
    k0, f = runs._start_apkf(o, 1, spacecraft=d)
    n = len(o["t"])
    it = range(k0 + 1, n)
    if progress:
        from tqdm import tqdm
        it = tqdm(it, desc="calibration (%d sets)" % sets, unit="s", leave=False)
    for k in it:
        f.step(o["t"][k - 1], o["tach"][k], o["st_q"][k] if o["st_valid"][k] else None)
        apkf.check_covariance(f.P, o["t"][k])
    tr = o["truth"]
    w = o["spacecraft"].wheels
    u = np.array([control.wheel_torques(o["tau_c"][k], w.c0, 0.1, o["w_rel"][k - 1]) if k > 0 else np.zeros(4)
                  for k in range(n)])                      # what scenario.simulate commanded over step k-1 -> k
    u = np.clip(np.vstack([u[1:], np.zeros((1, 4))]), -w.p.torque_max, w.p.torque_max)
    jabs = absolute_jrw(u, o["tach"])
    scale = torque_scale(f.x, jabs, f.model)
    meta = {"seed": int(seed), "jrw_abs_kgm2": jabs.tolist(), "scale_true": float(tr["scale"]), "sets": int(sets), "duration_s": float(o["t"][-1]),
            "final_error": {"J5_kgm2": (tr["J5"] - f.x[10:15]).tolist(),
                            "delta_deg": np.degrees(np.concatenate([tr["delta1"] - f.x[18:22],
                                                                    tr["delta2"] - f.x[22:26]])).tolist(),
                            "jrw_kgm2": (tr["jrw"] - f.x[26:30]).tolist()}}
    return params_from_apkf(f.x, f.P, f.model.jxx, meta, scale)


# --- pointing error (Eq. 6.12-6.21) ------------------------------------------------------------------------
def l_frame(laser_axis=control.LASER_AXIS):
    """T_b of Eq. 6.17: body to the l frame whose z axis is l_b (minimum rotation of l_b onto z; for l_b = -z,
    where it is not unique, the half turn about x)."""
    lb = np.asarray(laser_axis, float)
    if lb[2] < -1 + 1e-12:
        return dcm(np.array([1.0, 0.0, 0.0, 0.0]))
    return dcm(control.min_rotation(np.array([0.0, 0.0, 1.0]), lb))



def pointing_errors(q, w, ra, va, rb, vb, laser_axis=control.LASER_AXIS):
    """(dtheta (n, 2) rad, domega (n, 2) rad/s) for arrays of true q, w and orbit states (Eq. 6.12-6.21).

    p = rB - rA, p_b = A(q) p, p_l = T_b p_b / |p|, dtheta = asin(p_l[0:2]); v = vB - vA, v_b = A(q) v - w x p_b
    (the line of sight's rate seen from the turning body), domega = (T_b v_b)[0:2] / |p|.
    """
    Tb = l_frame(laser_axis)
    A = np.array([dcm(qq) for qq in q])
    p = rb - ra
    rho = np.linalg.norm(p, axis=1)
    pb = np.einsum("nij,nj->ni", A, p)
    pl = pb @ Tb.T / rho[:, None]
    vb_ = np.einsum("nij,nj->ni", A, vb - va) - np.cross(w, pb)
    vl = vb_ @ Tb.T / rho[:, None]
    return np.arcsin(np.clip(pl[:, 0:2], -1, 1)), vl[:, 0:2]


def estimate_errors(q_hat, w_hat, ra_hat, rb_hat, q, w, ra, rb):
    """Estimate minus truth: attitude (arcsec, 3 axes: 2 x the vector part of q_hat (x) q^-1, Eq. 4.25), rate (arcsec/s) and the
    orbit position errors |rA_hat - rA|, |rB_hat - rB| (m) of one flight-software estimate (``EST_COLS``)."""
    att = 2.0 * quat.error_vec(np.asarray(q_hat, float), np.asarray(q, float)) / RAD_PER_ARCSEC
    return np.concatenate([att, (np.asarray(w_hat, float) - w) / RAD_PER_ARCSEC,
                           [np.linalg.norm(np.asarray(ra_hat, float) - ra),
                            np.linalg.norm(np.asarray(rb_hat, float) - rb)]])


EST_COLS = ("att_x", "att_y", "att_z", "rate_x", "rate_y", "rate_z", "ra_m", "rb_m")


def loop_response(att_err, rate_err, ts=TS_THESIS, zeta=control.ZETA, dt=1.0, sub=10):
    """The pointing error one body axis's PD (Eq. 6.5-6.7) leaves from its estimate's errors alone: a linear
    model to explain a run by, not part of the simulator.

    ``att_err``, ``rate_err``: the estimate's errors about that axis at the dt ticks (estimate minus truth, e.g.
    ``fsw_est_err`` columns; any unit, the result has the attitude's). Derived (the thesis gives no such model):
    small angles, the torque in units of J, K = 2 wn^2 J on the half-angle vector part; the controller sees
    theta + d_k and theta' + n_k and holds its torque over the tick, so with x = (theta, theta'):
    u_k = -wn^2 (theta_k + d_k) - 2 zeta wn (theta'_k + n_k), theta(t_k + tau) = theta_k + theta'_k tau +
    u_k tau^2 / 2. Returns theta at the ``sub`` instants of each tick (the 10 Hz history's), from rest."""
    d = np.asarray(att_err, float)
    n = np.asarray(rate_err, float)
    if d.shape != n.shape or d.ndim != 1 or not (np.all(np.isfinite(d)) and np.all(np.isfinite(n))):
        raise ValueError("att_err and rate_err must be finite 1-d series of one length")
    wn = control.natural_frequency(ts)
    tau = np.arange(sub) * (dt / sub)
    th = np.empty(d.size)
    om = np.empty(d.size)
    u = np.empty(d.size)
    a = b = 0.0
    for k in range(d.size):
        th[k], om[k] = a, b
        u[k] = c = -wn * wn * (a + d[k]) - 2 * zeta * wn * (b + n[k])
        a, b = a + b * dt + c * dt * dt / 2, b + c * dt
    return (th[:, None] + om[:, None] * tau + u[:, None] * tau ** 2 / 2).ravel()


def objective(dtheta, domega):
    """J = E[eps^T W eps] (Eq. 6.22-6.24), eps in rad and rad/s."""
    e = np.column_stack([dtheta, domega])
    return float(np.mean(e ** 2 @ W_OBJ))


def thesis_3sigma(satb_gnss):
    """Sec. 6.4.4's figures as 3 sigma of the two axes in total, (pointing arcsec, stability arcsec/s), as
    ``statistics`` gives ours."""
    th = THESIS[bool(satb_gnss)]
    return (float(3 * np.hypot(th["theta"][0][1], th["theta"][1][1])),
            float(3 * np.hypot(th["omega"][0][1], th["omega"][1][1])))


def statistics(dtheta, domega):
    """The summary figures (arcsec, arcsec/s) of the collected samples."""
    th, om = dtheta / RAD_PER_ARCSEC, domega / RAD_PER_ARCSEC
    sth, som = th.std(axis=0), om.std(axis=0)
    return {"pointing_mean_arcsec": th.mean(axis=0).tolist(), "pointing_sigma_arcsec": sth.tolist(),
            "stability_mean_arcsec_s": om.mean(axis=0).tolist(), "stability_sigma_arcsec_s": som.tolist(),
            "pointing_3sigma_arcsec": float(3 * np.hypot(*sth)),
            "stability_3sigma_arcsec_s": float(3 * np.hypot(*som)),
            "pointing_max_arcsec": float(np.abs(th).max()), "J_rad2": objective(dtheta, domega),
            "samples": int(len(th))}


# --- 3. pointing and tracking -------------------------------------------------------------------------------
def truth_span(seconds):
    """The truth's span for a run of ``seconds`` (``simulate``'s: ``scenario.truth_span`` with ``SPAN_MARGIN_S``)."""
    return scenario.truth_span(seconds, SPAN_MARGIN_S)


def check_ts(ts):
    """``ts`` (the settling time t_s of Eq. 6.7, s) as a float in (0, MAX_TS_S]; ValueError naming --ts."""
    try:
        v = float(ts)
    except (TypeError, ValueError):
        raise ValueError("--ts (settling time t_s) must be a number of seconds, got %r" % (ts,)) from None
    if not 0 < v <= MAX_TS_S:
        raise ValueError("--ts (settling time t_s) must be in (0, %g] s, got %r" % (MAX_TS_S, ts))
    return control.natural_frequency(v) and v


def orbit_period(x):
    """The Keplerian period (s) of the orbit whose [r (m), v (m/s)] is x (vis-viva: a = 1 / (2/r - v^2/mu))."""
    r, v = np.linalg.norm(x[0:3]), np.linalg.norm(x[3:6])
    a = 1.0 / (2.0 / r - v * v / stkf.MU)
    return float(2 * np.pi * np.sqrt(a ** 3 / stkf.MU))


ACQUIRE_MARGIN_S = 60.0     # flight_settle_s: the re-acquisition after the blind slew and a short second slew


def flight_settle_s(d, ts=TS_THESIS, flight=None, hold_s=HOLD_S):
    """When the flight world's pointing can be taken as settled, planned from the start (s): the hold, the first
    slew's trapezoid (its angle from the attitude at rest, q = [0, 0, 0, 1], to the command at the orbits'
    initial states; its rate and acceleration limits ``FLIGHT``'s or ``flight``'s), ``ACQUIRE_MARGIN_S`` for the
    re-acquisition and 4 t_s of settling. ``fps system --world flight`` starts its play there."""
    fo = dict(FLIGHT, **(flight or {}))
    x0a, x0b = scenario.orbit_setup(d)["x0s"]
    qc = control.attitude_command(x0a[0:3], x0a[3:6], x0b[0:3], laser_axis(d))
    theta = 2.0 * np.arccos(min(1.0, abs(float(qc[3]))))
    w, a = fo["slew_rate_deg_s"] * modes.DEG, fo["slew_acc_deg_s2"] * modes.DEG
    t_slew = theta / w + w / a if theta > w * w / a else 2.0 * np.sqrt(theta / a)
    return float(np.ceil(hold_s + t_slew + ACQUIRE_MARGIN_S + 4.0 * check_ts(ts)))


def with_partner(d, behind_deg=10.0, relay_delay_s=(2.0, 3.0)):
    """A copy of the checked spacecraft file ``d`` with a partner satellite in its own orbit ``behind_deg``
    behind it (its orbit.state turned about the orbit normal): for a vehicle shipped without one (generic-12u
    points at a ground station) to fly the partner-tracking worlds. The name gets "+partner"."""
    s = d["orbit"]["state"]
    r, v = np.array(s["position_m"], float), np.array(s["velocity_m_s"], float)
    k = np.cross(r, v)
    k /= np.linalg.norm(k)
    a = -np.radians(behind_deg)

    def turn(x):                                   # Rodrigues' formula about k
        return x * np.cos(a) + np.cross(k, x) * np.sin(a) + k * (k @ x) * (1 - np.cos(a))
    return dict(d, name=d["name"] + "+partner",
                partner={"position_m": turn(r).tolist(), "velocity_m_s": turn(v).tolist(),
                         "relay_delay_s": list(relay_delay_s)})


def _flight_command(log, t, q_hat, qc, wc, fo, box, st_ok, blind_s):
    """The flight world's command at t (after the hold), by mode: SLEW, a rate-limited eigenaxis slew
    (``modes.EigenaxisSlew``, held in ``box[0]``) from the estimate toward the tracking command, until its
    reference reaches it; ACQUIRE, rate damping on the estimate (q_c = q_hat, w_c = 0) while the star tracker is
    still blind (the blind slew leaves a rate error; the command's own turn on top of it could keep the tracker
    blind); on its first output
    (this second, ``st_ok``, after ``blind_s`` s without one) POINT if the estimate is within ``reslew_deg`` of the
    command, else another slew from the estimate; POINT, the command, back to SLEW when the estimate is more than
    ``reslew_deg`` off it."""
    err = 2.0 * np.degrees(np.arcsin(min(1.0, np.linalg.norm(quat.error_vec(q_hat, qc)))))
    if log.mode == "POINT":
        if err <= fo["reslew_deg"]:
            return qc, wc
        log.set("SLEW", t, "the estimate is %.2f deg off the command (> %g deg)" % (err, fo["reslew_deg"]))
    elif log.mode == "ACQUIRE":
        if not st_ok:                   # rate damping on the estimate until the star tracker answers
            return q_hat, np.zeros(3)
        why = "the star tracker is back after %d s blind, the estimate %.2f deg off the command" % (blind_s, err)
        if err <= fo["reslew_deg"]:
            log.set("POINT", t, why)
            return qc, wc
        log.set("SLEW", t, why)
    if box[0] is None:
        box[0] = modes.EigenaxisSlew(q_hat, qc, fo["slew_rate_deg_s"] * modes.DEG, fo["slew_acc_deg_s2"] * modes.DEG)
        log.set("SLEW", t, "a slew of %.1f deg to the partner's line of sight" % np.degrees(box[0].theta0))
    q_ref, w_ref = box[0].reference(qc, wc)
    if box[0].done:
        box[0] = None
        log.set("ACQUIRE", t + 1.0, "the slew's reference reached the command")
    return q_ref, w_ref


class EstimatedOrbit:
    """SatA's orbit as the flight software knows it, for the APKF's model (``apkf.Model.orbit``): the STKF's
    latest rA, vA (at ``t0``) carried along vA, ``position(t)`` = rA + (t - t0) vA. The APKF asks for the
    mid-step, half a second on, where the orbit's curvature leaves ~1 m (as the flight app's ``_env``)."""

    def __init__(self, t0, x):
        self.set(t0, x)

    def set(self, t0, x):
        self.t0, self.r, self.v = float(t0), np.array(x[0:3], dtype=float), np.array(x[3:6], dtype=float)

    def position(self, t):
        return self.r + (t - self.t0) * self.v


def simulate(ts=TS_THESIS, satb_gnss=False, duration_s=4000.0, seed=0, params=None, truth="two-body",
             cache_dir=None, progress=False, settle_ts=4.0, feedforward=True, hold_s=HOLD_S, on_second=None,
             wheel_speed_limit_rpm=scenario.POINTING_WHEEL_RPM, tach_noise_rpm=None, spacecraft=None,
             world="thesis", flight=None):
    """One pointing-and-tracking run. ``params``: the parameter-file dict. ``duration_s`` is the collection time after
    the 4 t_s of settling (the thesis's 4000 s). Returns (result dict, history dict: 10 Hz arrays, fsw_* at 1 Hz). A
    KeyboardInterrupt returns what was collected so far with ``complete`` false. ``fsw["est_err"]`` (history
    ``fsw_est_err``) holds each second's ``estimate_errors`` against the truth at that second. ``on_second(k, hist,
    fsw, x)``, if given, is called after each second's ten truth steps (rows up to 10 (k + 1) of ``hist``, k of
    ``fsw``, are final; it must only read them), ``x`` (10, 2, 6) being the orbit truth (SatA, SatB [r, v]) at
    ``hist`` rows 10 k + 1 .. 10 k + 10: a live consumer (``fps system``) follows the run as it goes.
    ``wheel_speed_limit_rpm``: the true wheels' speed limit (default: none in effect, as the thesis; see
    ``scenario.POINTING_WHEEL_RPM``); the result's ``max_wheel_speed_rpm`` and ``wheel_speed_clips`` say whether a
    limit was reached. ``tach_noise_rpm``: the tachometers' read-out noise (1 sigma), in the truth and in the APKF's
    model alike; other than the file's (the scenario's 10 rpm) only as a diagnostic. ``spacecraft``: a checked
    spacecraft file (None: thesis-3u) for the world (``scenario.pointing_world``: the true vehicle, orbits and
    sensors) and the flight software: the APKF's model (``runs.apkf_model``; the Jxx reference the parameter
    file's), the STKF's P0, the wheels' nominal torque limit and friction, the star tracker's noise before the
    APKF starts and the laser axis of the command and of the pointing error; the parameter file is checked
    against it.

    ``world``: "thesis" (Sec. 6.4 as above) or "flight" (``FLIGHT``; ``flight`` overrides its options): the
    wheels at the file's speed and torque limits, drag and solar pressure torques about ``surface.cp_offset_m``,
    the magnetorquers with the cross-product unloading law (``modes.unloading_dipole``; their dipole a known
    input of the APKF and of the feed-forward), a rate-limited eigenaxis slew before pointing
    (``modes.EigenaxisSlew``), the APKF's innovation gate (``apkf.APKF.gate``), the STKF's beacon gate
    (``modes.beacon_gate``) and the mode log. There ``duration_s`` is the whole run from t = 0 (no settling is
    added) and the figures are over the pointing passes after the first orbit (``flight_statistics``)."""
    ts = check_ts(ts)
    if world not in WORLDS:
        raise ValueError("world must be one of %s, got %r" % (", ".join(WORLDS), world))
    fo = dict(FLIGHT, **(flight or {}))
    unknown = sorted(set(fo) - set(FLIGHT))
    if unknown:
        raise ValueError("unknown flight option(s) %s (the options: %s)" % (", ".join(unknown), ", ".join(FLIGHT)))
    fly, world_name = world == "flight", world
    if params is None:
        raise ValueError("simulate needs the parameter file (run calibrate first)")
    d = spacecraft or scenario.thesis_3u()
    xp, Pp, jxx, scale = check_params(params, spacecraft=d)
    if not (np.isfinite(duration_s) and duration_s >= 1):
        raise ValueError("duration must be >= 1 s, got %r" % (duration_s,))
    t_settle = hold_s + settle_ts * ts
    K = int(np.ceil(t_settle + duration_s))
    if fly:
        if d["magnetorquers"] is None:
            raise ValueError("magnetorquers = null: the flight world unloads the wheels with magnetorquers; give "
                             "the spacecraft file a magnetorquers block (or fly --world thesis)")
        wheel_speed_limit_rpm = d["wheels"]["speed_limit_rpm"]
        K = int(np.ceil(duration_s))
    if tach_noise_rpm is not None:
        if not (np.isfinite(tach_noise_rpm) and tach_noise_rpm > 0):
            raise ValueError("tach_noise_rpm must be > 0 (the APKF's R), got %r" % (tach_noise_rpm,))
        d = dict(d, wheels=dict(d["wheels"], tach_noise_rpm=float(tach_noise_rpm)))
    world = scenario.pointing_world(K, seed, satb_gnss, truth, cache_dir, SPAN_MARGIN_S, n_tags=K,   # Sec. 6.4.1
                                    wheel_speed_limit_rpm=wheel_speed_limit_rpm, spacecraft=d, flight=fly)
    rate, xg, wheels, sc, st = world.rate, world.xg, world.wheels, world.sc, world.st
    log = modes.ModeLog("INIT", 0.0)
    period = orbit_period(xg[0, 0])
    if fly:
        t_settle = period                               # the figures: pointing passes after the first orbit
        m_res_true = sc.dipole
        mtq = d["magnetorquers"]
        rods = Magnetorquers.from_spacecraft(d)         # the truth's rods (the session's device model)
        mtq_axes = np.array([np.asarray(a, float) / np.linalg.norm(a) for a in mtq["axes"]])
        slew = None
        gate_rad = fo["beacon_gate_arcsec"] * RAD_PER_ARCSEC
    m_cmd = np.zeros(3)
    slew_box = [None]
    t_st_last = 0.0
    use_beacon = True
    flog = {k: np.full((K + 1, m), np.nan) for k, m in (("m_cmd", 3), ("h_w", 3), ("mode", 1), ("st_ok", 1),
                                                        ("beacon_used", 1), ("mtq_sat", 1))}
    gnss_a, beacon, relay, tb, xb_tb = world.gnss_a, world.beacon, world.relay, world.tb, world.xb_tb
    # flight software state
    orb = EstimatedOrbit(0.0, world.stkf_x0)
    model = runs.apkf_model(d)
    model.jxx, model.orbit, model.field = jxx, orb, world.field
    ds = d["wheels"]                                 # the wheels' torque limit and friction: nominal, not truth
    lb = laser_axis(d)
    P_st = np.diag((np.array(d["star_tracker"]["sigma_arcsec"]) * RAD_PER_ARCSEC) ** 2)
    f_stkf = Afls(world.stkf_x0, np.diag(world.stkf_P0_diag), 0.0, LAG_S,
                  stkf.f, stkf.Phi, lambda dt: stkf.Q(dt), keep_generated=False, parts=stkf.PARTS)
    I6 = np.eye(6)
    flt = None
    q_prev = None
    u = np.zeros(N_WHEELS)
    n10 = K * 10 + 1
    hist = {"t": np.arange(n10) / 10.0, "q": np.zeros((n10, 4)), "w": np.zeros((n10, 3)),
            "w_rel": np.zeros((n10, 4))}
    fsw = {k: np.full((K + 1, m), np.nan) for k, m in (("q_hat", 4), ("w_hat", 3), ("qc", 4), ("tau_c", 3),
                                                        ("u", 4), ("tau_ff", 3), ("tau_ext_true", 3),
                                                        ("wc", 3), ("x_stkf", 12), ("est_err", len(EST_COLS)))}
    sub = rate // 10                                 # the grid's rows at the 10 Hz truth steps
    hist["q"][0], hist["w"][0], hist["w_rel"][0] = sc.q, sc.omega, sc.omega_rw_rel
    jb = 0
    complete = True
    k_done = 0
    t_wall = time.perf_counter()
    it = range(K + 1)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=K, desc="bps ts=%g s%s" % (ts, " +SatB GNSS" if satb_gnss else ""), unit="s",
                   leave=False)
    try:
        for k in it:
            t = float(k)
            # sensors at t (own time tags: t, SatB's tb)
            tach = wheels.read_speed_rpm(sc.omega_rw_rel) * (2 * np.pi / 60)
            q_st, st_ok = st.measure(sc.q, sc.omega)
            x_true = xg[k * rate].ravel()
            zg = gnss_a.measure(x_true[0:6])
            y = beacon.measure_dcm(x_true[0:3], x_true[6:9], dcm(sc.q))
            due = []
            if relay is not None:
                while jb < tb.size and tb[jb] <= t:
                    relay.sample(tb[jb], xb_tb[jb])
                    jb += 1
                due = relay.due(t)
            # flight software (sensor outputs and wheel read-outs only)
            if flt is None:
                if st_ok and q_prev is not None:
                    w0 = quat.rotvec(quat.quat_mul(q_st, quat.conj(q_prev)))
                    x0 = apkf.initial_state(q_st, w0, tach)
                    x0[7:30] = xp
                    flt = apkf.APKF(x0, model=model, case=1)
                    flt.P[apkf.PARAMS, apkf.PARAMS] = Pp
                    if fly:
                        flt.gate = fo["innovation_gate"]
                    log.set("HOLD", t, "the APKF started from two star-tracker outputs")
                q_prev = q_st if st_ok else None
            else:
                orb.set(t - 1.0, f_stkf.x)                 # the STKF's rA, vA at t - 1 (not yet predicted to t)
                model.m_ctrl = m_cmd * scale if fly else None   # the magnetorquers' dipole over t - 1 .. t
                flt.step(t - 1.0, tach, q_st if st_ok else None)
                if not np.all(np.isfinite(flt.x)):
                    raise FloatingPointError("APKF diverged at t = %.0f s" % t)
            if flt is not None:
                q_hat, w_hat, P_att = flt.x[0:4], flt.x[4:7], 4.0 * flt.P[0:3, 0:3]
            else:
                q_hat, w_hat = (q_st if st_ok else np.array([0, 0, 0, 1.0])), np.zeros(3)
                P_att = P_st
            A_hat = dcm(q_hat)
            if k > 0:
                f_stkf.predict(t)
            use_beacon = not fly or (flt is not None and modes.beacon_gate(P_att, gate_rad))
            try:
                if use_beacon:
                    R_gb = stkf.R_gnss_beacon(gnss_a.R, stkf.h_beacon(f_stkf.x, A_hat), beacon.sigma, P_att)
                    f_stkf.update(np.concatenate([zg, y]), R_gb, lambda x: stkf.gnss_beacon(x, A_hat))
                else:                                   # the attitude is not known well enough for the beacon
                    f_stkf.update(zg, gnss_a.R, lambda x: (x, I6), part=stkf.SAT_A)
                for tm, z in due:                       # SatB's GNSS: H = I on SatB's part (Eq. 5.12)
                    f_stkf.update(z, relay.gnss.R, lambda x: (x, I6), t=tm, part=stkf.SAT_B)
            except np.linalg.LinAlgError as exc:        # S not positive definite: the filter has diverged
                raise FloatingPointError("STKF diverged at t = %.0f s: %s" % (t, exc))
            xh = f_stkf.x
            if not np.all(np.isfinite(xh)):
                raise FloatingPointError("STKF diverged at t = %.0f s" % t)
            if flt is not None:
                x = flt.x
                J = apkf.inertia(x, model) / scale          # physical units (see ``absolute_jrw``)
                C = apkf.c_rw(x, model)
                if t >= hold_s:
                    qc, wc = control.command_rate(xh, stkf.f, lb)
                    if fly:
                        qc, wc = _flight_command(log, t, q_hat, qc, wc, fo, slew_box, st_ok, t - t_st_last)
                    elif log.mode == "HOLD":
                        log.set("POINT", t, "the hold is over")
                else:                                       # the hold: rate damping (q_c = q_hat, w_c = 0)
                    qc, wc = q_hat, np.zeros(3)
                Kp, Dd = control.gains(J, ts)
                h_w = (C * x[26:30] / scale) @ x[38:42]     # the wheels' momentum (body frame, N m s)
                H = J @ w_hat + h_w if feedforward else None
                tff = None
                b_i = model.field.field(xh[0:3], t)
                if fly:                                     # unloading: this second's dipole, known to the APKF
                    m_cmd, rods_sat = modes.unloading_dipole(A_hat @ b_i, h_w, fo["unload_gain_1_s"],
                                                             mtq["dipole_limit_am2"], x[15:18] / scale, mtq_axes)
                    sc.dipole = m_res_true + rods.command(m_cmd)[0]
                    flog["m_cmd"][k], flog["h_w"][k], flog["mtq_sat"][k] = m_cmd, h_w, float(rods_sat.any())
                if feedforward:
                    tff = control.external_torque(J, x[15:18] / scale + m_cmd, x[7:10] / scale, q_hat, xh[0:3],
                                                  b_i)
                tau_c = control.pd_torque(q_hat, w_hat, qc, wc, Kp, Dd, H, tff)
                tau_c = control.saturate(tau_c, C, ds["torque_limit_nm"])
                u = control.wheel_torques(tau_c, C, null_fraction=0.0)        # Eq. 6.11 (no null torque)
                if fly:                                     # the wheels held off zero speed (null space)
                    u = u + modes.null_bias_torque(C, tach, np.asarray(ds["rotor_inertia_kgm2"], float),
                                                   fo["wheel_bias_share"] * ds["speed_limit_rpm"] * RPM,
                                                   fo["wheel_bias_gain_1_s"])
                if feedforward:
                    u = u + control.friction_compensation(tach, ds["friction_coulomb_nm"],
                                                          ds["friction_viscous_nms_rad"],
                                                          ds["friction_smooth_rpm"] * 2 * np.pi / 60)
                fsw["qc"][k], fsw["tau_c"][k], fsw["wc"][k] = qc, tau_c, wc
                if tff is not None:
                    fsw["tau_ff"][k] = tff
            fsw["tau_ext_true"][k] = sc.external_torque(sc.t, sc.x)        # truth, for the record only
            flog["mode"][k], flog["st_ok"][k], flog["beacon_used"][k] = MODE_CODE[log.mode], st_ok, use_beacon
            if st_ok:
                t_st_last = t
            fsw["q_hat"][k], fsw["w_hat"][k], fsw["u"][k] = q_hat, w_hat, u
            fsw["x_stkf"][k] = xh                                          # rA, vA, rB, vB estimated
            if np.all(np.isfinite(q_hat)):
                fsw["est_err"][k] = estimate_errors(q_hat, w_hat, xh[0:3], xh[6:9], hist["q"][10 * k],
                                                    hist["w"][10 * k], x_true[0:3], x_true[6:9])
            if k == K:
                k_done = k
                break
            wheels.command_all(u)
            for j in range(1, 11):
                sc.step()
                i = k * 10 + j
                hist["q"][i], hist["w"][i], hist["w_rel"][i] = sc.q, sc.omega, sc.omega_rw_rel
            if not np.all(np.isfinite(sc.x)):
                raise FloatingPointError("truth diverged at t = %.0f s" % sc.t)
            k_done = k + 1
            if on_second is not None:
                on_second(k, hist, fsw, xg[(10 * k + 1) * sub:(10 * k + 10) * sub + 1:sub])
            if bar is not None:
                bar.update(1)
    except KeyboardInterrupt:
        complete = False
    finally:
        if bar is not None:
            bar.close()
    n_ok = k_done * 10 + 1
    for key in ("q", "w", "w_rel", "t"):
        hist[key] = hist[key][:n_ok]
    for key in fsw:
        fsw[key] = fsw[key][:k_done + 1]
    xs10 = xg[:n_ok * sub:sub]
    dth, dom = pointing_errors(hist["q"], hist["w"], xs10[:, 0, 0:3], xs10[:, 0, 3:6], xs10[:, 1, 0:3],
                               xs10[:, 1, 3:6], lb)
    hist["dtheta_arcsec"], hist["domega_arcsec_s"] = dth / RAD_PER_ARCSEC, dom / RAD_PER_ARCSEC
    hist.update({"fsw_" + k: v for k, v in fsw.items()})
    for key in flog:
        flog[key] = flog[key][:k_done + 1]
    hist.update({"fsw_" + k: v for k, v in flog.items()})
    mode_s = flog["mode"][:, 0]
    mode10 = mode_s[np.minimum(hist["t"].astype(int), k_done)]
    sel = hist["t"] >= t_settle
    if fly:
        sel &= mode10 == MODE_CODE["POINT"]
    budget = error_budget(hist, xg[:(k_done + 1) * rate:rate], t_settle, laser_axis=lb)
    res = {"ts_s": ts, "satb_gnss": bool(satb_gnss), "seed": int(seed), "truth": truth,
           "duration_s": float(duration_s), "settle_s": float(t_settle), "simulated_s": float(k_done),
           "complete": bool(complete and k_done == K), "feedforward": bool(feedforward),
           "wall_s": time.perf_counter() - t_wall, "wheel_speed_clips": wheels.counters(),
           "max_wheel_speed_rpm": float(np.abs(hist["w_rel"]).max() * 60 / (2 * np.pi)),
           "wheel_speed_limit_rpm": float(wheel_speed_limit_rpm), "tach_noise_rpm": d["wheels"]["tach_noise_rpm"],
           "wheel_datasheet_rpm": d["wheels"]["speed_limit_rpm"], "spacecraft": d["name"], "world": world_name,
           "orbit_period_s": period, "mode_changes": log.changes, "time_in_mode_s": log.time_in(k_done),
           "apkf_attitude_resets": [] if flt is None else [list(r) for r in flt.resets]}
    # the star tracker's blind share: after the first slew (flight: the first POINT; thesis: the settling)
    first_point = next((c["t_s"] for c in log.changes if c["to"] == "POINT"), None)
    t_from = (first_point if fly else t_settle)
    secs = np.arange(k_done + 1) >= (np.inf if t_from is None else t_from)
    res["star_tracker_blind_share"] = float(1.0 - flog["st_ok"][secs, 0].mean()) if secs.any() else None
    if fly:
        res.update(flight_statistics(hist, dth, dom, mode10, period, flog, mtq["dipole_limit_am2"], mtq_axes))
        res["flight_options"] = fo
    if sel.sum() >= 2:
        res.update(statistics(dth[sel], dom[sel]))
    else:
        res.update({k: None for k in SUMMARY_KEYS if k != "complete"})
        res["J_rad2"] = None
    res["budget"] = budget
    return res, hist


def flight_statistics(hist, dth, dom, mode10, period, flog, dipole_limit, axes):
    """The flight world's figures: per pointing pass (pass p = the POINT samples of orbit p, p >= 1, of those the
    run holds whole; orbit 0 is the slew and settling) its 3 sigma pointing and stability (as ``statistics``) and largest wheel
    speed; the largest wheel speed after the first orbit (``max_wheel_speed_rpm`` then means that span, and
    ``max_wheel_speed_rpm_run`` the whole run's); the magnetorquers' duty (mean of the largest rod's |m| over
    its limit) and saturated share; the wheels' momentum |h| (N m s) at most and at the end."""
    t = hist["t"]
    rpm = np.abs(hist["w_rel"]) * 60 / (2 * np.pi)
    passes = []
    n_orbits = int(np.floor(t[-1] / period + 0.01))           # whole orbits (1 % short still counts)
    for p in range(1, n_orbits):
        span = (t >= p * period) & (t < (p + 1) * period)
        sel = span & (mode10 == MODE_CODE["POINT"])
        if sel.sum() < 2:
            passes.append({"orbit": p, "samples": int(sel.sum())})
            continue
        st = statistics(dth[sel], dom[sel])
        passes.append({"orbit": p, "t_from_s": float(t[span][0]), "t_to_s": float(t[span][-1]),
                       "samples": st["samples"], "pointing_3sigma_arcsec": st["pointing_3sigma_arcsec"],
                       "stability_3sigma_arcsec_s": st["stability_3sigma_arcsec_s"],
                       "max_wheel_speed_rpm": float(rpm[span].max())})
    after = t >= period
    rods = np.abs(np.linalg.lstsq(axes.T, np.nan_to_num(flog["m_cmd"]).T, rcond=None)[0]).max(axis=0)
    h = np.linalg.norm(flog["h_w"], axis=1)
    return {"passes": passes, "max_wheel_speed_rpm": float(rpm[after].max()) if after.any() else None,
            "max_wheel_speed_rpm_run": float(rpm.max()),
            "mtq_duty": float(np.mean(rods / dipole_limit)),
            "mtq_saturated_share": float(np.nanmean(flog["mtq_sat"])),
            "wheel_momentum_max_nms": float(np.nanmax(h)) if np.isfinite(h).any() else None,
            "wheel_momentum_end_nms": float(h[-1]) if np.isfinite(h[-1]) else None,
            "beacon_used_share": float(np.nanmean(flog["beacon_used"]))}


def error_budget(hist, x1, t_settle, slow_s=SLOW_S, laser_axis=control.LASER_AXIS):
    """Where the pointing error comes from, at the 1 Hz flight-software instants after settling (arcsec, 1σ per
    axis): with e(q) the Eq. 6.12-6.16 pointing error of attitude q against the true line of sight,
    ``estimation`` = e(q) - e(q_hat), ``tracking`` = e(q_hat) - e(q_c) (the controller's), ``command`` = e(q_c)
    (the STKF's and the command law's); ``total`` = e(q) is their sum. ``tracking_slow`` is the tracking part's
    ``slow_s`` moving average: the bias a PD leaves against a torque it does not model. Each part's mean is
    given too (``*_mean_arcsec``)."""
    k = np.arange(len(x1))
    keep = (k >= t_settle) & np.all(np.isfinite(hist["fsw_qc"][:len(x1)]), axis=1)
    if keep.sum() < 2 * slow_s:
        return None
    k = k[keep]
    q, w = hist["q"][k * 10], hist["w"][k * 10]
    ra, va, rb, vb = x1[k, 0, 0:3], x1[k, 0, 3:6], x1[k, 1, 0:3], x1[k, 1, 3:6]

    def e(qq):
        return pointing_errors(qq, w, ra, va, rb, vb, laser_axis)[0] / RAD_PER_ARCSEC

    tot, est, cmd = e(q), e(hist["fsw_q_hat"][k]), e(hist["fsw_qc"][k])
    parts = {"total": tot, "estimation": tot - est, "tracking": est - cmd, "command": cmd}
    box = np.ones(slow_s) / slow_s
    slow = np.column_stack([np.convolve(parts["tracking"][:, i], box, mode="valid") for i in range(2)])
    out = {name + "_sigma_arcsec": v.std(axis=0).tolist() for name, v in parts.items()}
    out["tracking_slow_sigma_arcsec"] = slow.std(axis=0).tolist()
    out.update({name + "_mean_arcsec": v.mean(axis=0).tolist() for name, v in parts.items()})
    out["samples"] = int(len(k))
    return out


def save_history(path, hist):
    buf = io.BytesIO()
    np.savez_compressed(buf, **hist)
    write_atomic(path, buf.getvalue())


def run_one(seed, run_dir, params=None, **kw):
    """Campaign entry (top level, picklable): one pointing run; writes run_dir/result.json (and history)."""
    res, hist = simulate(seed=seed, params=params, **kw)
    if run_dir:
        os.makedirs(run_dir, exist_ok=True)
        save_history(os.path.join(run_dir, "history.npz"), hist)
        write_json(os.path.join(run_dir, "result.json"), res)
    return res


def sweep_one(seed, run_dir, ts_list=(), params=None, noise_seed=0, **kw):
    """Campaign entry for the sweep: ``seed`` indexes ts_list (one run per t_s, all with ``noise_seed``)."""
    ts = ts_list[seed]
    res, hist = simulate(ts=ts, params=params, seed=noise_seed, **kw)
    if run_dir:
        os.makedirs(run_dir, exist_ok=True)
        write_json(os.path.join(run_dir, "result.json"), res)
    if not res["complete"]:          # simulate caught a Ctrl-C: the sweep stops too (this t_s stays partial)
        raise KeyboardInterrupt
    return res
