"""The body pointing simulator (BPS) of Yoon 2017, Sec. 6.4: calibration, parameter file, pointing and tracking.

Truth (the spacecraft simulator of Fig. 6-1): ``emulator.spacecraft.Spacecraft`` (Eq. 4.16, 4.56; true J, wheel
inertias and misalignments, residual dipole of Sec. 4.8) by RK4 at 0.1 s, sampled at 10 Hz. The orbits of SatA
and SatB are the STKF's truth (``emulator.orbits.truth_samples``: brahe "hpop" or "two-body", 1 s samples)
interpolated by 10th-order Lagrange (Sec. 6.4.1) onto a 20 Hz grid; the spacecraft's gravity gradient and
magnetic field use SatA's interpolated position. The field's dipole turns with the Earth from GMST at Eq. 5.53's
epoch (139.40 deg), the orbits' t = 0. Sensors (their own time tags): the
star tracker (20/20/60 arcsec, none at |w| >= 0.1 deg/s) and the tachometers (10 rpm) at each 1 s tick, SatA's
GNSS and the beacon (60 arcsec) at each tick, SatB's GNSS on SatB's clock (random phase) relayed 2-3 s late.

Flight software at 1 Hz, from the sensor outputs and wheel read-outs only: the flight app itself
(``firmware/adcs/app.py``, in process: ``thesis_world``), its modes, command (from the STKF's rA, vA, rB), PD
(Eq. 6.5-6.7, the parameter file's J, C, Jrw), saturation and minimum-norm wheel torques (Eq. 6.11), held 1 s;
its estimators the ground's by default (``ground.adcs.estimators``: the 41-state APKF started from the parameter
file, the STKF with the EAFLS taking the attitude covariance 4 P_qq from the APKF as in Sec. 5.3.3), or the lean
ones that fly. The orbit and field inputs of the APKF's model and of the external-torque feed-forward come from
the STKF's rA, not from the truth.

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
   pointing error (dtheta1, dtheta2, Eq. 6.12-6.17) and the stability (domega1, domega2, Eq. 6.18-6.21) are collected at 10 Hz.

Parameter file: ``protocol.paramfile`` ("fps-bps-params/1", its keys and the one checker the flight firmware
uses too); ``torque_scale`` comes from ``absolute_jrw``, ``calibration`` is {seed, sets, duration_s, ...}.

Units in the outputs: arcsec and arcsec/s; J (Eq. 6.22) in rad^2, like Fig. 6-2's axis.
"""

import io
import os
import zipfile

import numpy as np

from emulator.adcs_session import SPAN_MARGIN_S   # the orbit truth's span beyond a run (``truth_span``)
from emulator.spacecraft import scenario
from emulator.spacecraft.scenario import HOLD_S
from emulator.spacecraft.wheels import WheelParams
from ground.adcs import apkf, control, flight_world, runs, thesis_world
from ground.adcs.flight_world import FLIGHT, flight_settle_s                      # noqa: F401 (re-exported)
from ground.adcs.pointing import (BUDGET_POINTING_3SIGMA, BUDGET_STABILITY_3SIGMA, EST_COLS,  # noqa: F401
                                  MAX_TS_S, SLOW_S, SUMMARY_KEYS, THESIS, TS_THESIS, W_OBJ, add_statistics,
                                  check_ts, close_history, error_budget, estimate_errors, l_frame, objective,
                                  orbit_period, pointing_errors, statistics, thesis_3sigma)
from ground.adcs.params import (FORMAT, X_PARTS, check_params, load_params, params_from_apkf,  # noqa: F401
                                write_params)
from ground.fileio import write_atomic, write_json

RPM = 2 * np.pi / 60
CAL_SETS = 9
TACH_NOISE_RPM = WheelParams.noise_rpm   # the tachometers' 10 rpm 1 sigma (Sec. 4.8)
WORLDS = ("thesis", "flight")


# --- parameter file ------------------------------------------------------------------------------------------
SATURATION_MARGIN = 0.05     # a read-out within this share of the speed limit: the limit may have cut the torque


def absolute_jrw(u, tach, dt=1.0, friction=None, speed_max=None):
    """Each wheel's absolute inertia from the commanded motor torques u[k] (held over step k -> k+1) and the
    tachometer read-outs: least squares of dW_i = (u_i - f_i) dt / Jrw_i, f_i the wheel's datasheet friction
    (``friction`` = (Coulomb N m, viscous N m s/rad, smoothing rad/s), at the step's mean read-out speed; None:
    none) (the body's own acceleration, < 1 % here, is neglected). ``speed_max`` (rad/s, None: no limit): the
    steps with a read-out within ``SATURATION_MARGIN`` of the wheels' speed limit are left out, for there the
    drivers cut the torque (a wheel at its limit reads dW = 0 under a commanded torque, which would make its
    inertia look larger). Our addition: the APKF's calibration is relative (everything scaled by s = Jxx_ref /
    Jxx, Sec. 4.6.2), and a controller must know the absolute scale to cancel a torque."""
    dW = np.diff(tach, axis=0)
    uu = u[:-1] * dt
    if friction is not None:
        c, v, sm = friction
        wm = 0.5 * (tach[:-1] + tach[1:])
        uu = uu - control.friction_compensation(wm, c, v, sm) * dt
    if speed_max is not None:
        free = np.maximum(np.abs(tach[:-1]), np.abs(tach[1:])) < (1.0 - SATURATION_MARGIN) * speed_max
        uu, dW = np.where(free, uu, 0.0), np.where(free, dW, 0.0)
    return np.sum(uu * uu, axis=0) / np.sum(uu * dW, axis=0)


def torque_scale(x, jrw_abs, model):
    """s_hat = mean over wheels of Jrw_filter |c_i| / Jrw_abs (|c_i| the unnormalised Eq. 4.60 column)."""
    cn = np.sqrt(1 + x[18:22] ** 2 + x[22:26] ** 2)
    return float(np.mean(x[26:30] * cn / jrw_abs))


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
    u = np.array([control.wheel_torques(o["tau_c"][k], o["pd_c0"], 0.1, o["w_rel"][k - 1]) if k > 0 else np.zeros(4)
                  for k in range(n)])                      # what scenario.simulate commanded over step k-1 -> k
    u = np.clip(np.vstack([u[1:], np.zeros((1, 4))]), -w.p.torque_max, w.p.torque_max)
    ds = d["wheels"]                                       # the datasheet's friction, not the truth's
    jabs = absolute_jrw(u, o["tach"], friction=(ds["friction_coulomb_nm"], ds["friction_viscous_nms_rad"],
                                                 ds["friction_smooth_rpm"] * 2 * np.pi / 60), speed_max=w.speed_max)
    scale = torque_scale(f.x, jabs, f.model)
    meta = {"seed": int(seed), "jrw_abs_kgm2": jabs.tolist(), "scale_true": float(tr["scale"]), "sets": int(sets), "duration_s": float(o["t"][-1]),
            "final_error": {"J5_kgm2": (tr["J5"] - f.x[10:15]).tolist(),
                            "delta_deg": np.degrees(np.concatenate([tr["delta1"] - f.x[18:22],
                                                                    tr["delta2"] - f.x[22:26]])).tolist(),
                            "jrw_kgm2": (tr["jrw"] - f.x[26:30]).tolist()}}
    return params_from_apkf(f.x, f.P, f.model.jxx, meta, scale)


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


# --- 3. pointing and tracking -------------------------------------------------------------------------------
def truth_span(seconds):
    """The truth's span for a run of ``seconds`` (``simulate``'s: ``scenario.truth_span`` with ``SPAN_MARGIN_S``)."""
    return scenario.truth_span(seconds, SPAN_MARGIN_S)


def with_partner(d, behind_deg=10.0, relay_delay_s=(2.0, 3.0)):
    """A copy of the checked spacecraft file ``d`` with a partner satellite in its own orbit ``behind_deg``
    behind it (its orbit.state turned about the orbit normal): for a vehicle shipped without one (generic-12u
    points at a ground station) to fly the partner-tracking worlds. The name gets "-partner" (still a valid name:
    the copy can be written to a file and loaded again)."""
    s = d["orbit"]["state"]
    r, v = np.array(s["position_m"], float), np.array(s["velocity_m_s"], float)
    k = np.cross(r, v)
    k /= np.linalg.norm(k)
    a = -np.radians(behind_deg)

    def turn(x):                                   # Rodrigues' formula about k
        return x * np.cos(a) + np.cross(k, x) * np.sin(a) + k * (k @ x) * (1 - np.cos(a))
    return dict(d, name=d["name"] + "-partner",
                partner={"position_m": turn(r).tolist(), "velocity_m_s": turn(v).tolist(),
                         "relay_delay_s": list(relay_delay_s)})


def simulate(ts=TS_THESIS, satb_gnss=False, duration_s=4000.0, seed=0, params=None, truth="two-body",
             cache_dir=None, progress=False, settle_ts=4.0, feedforward=True, hold_s=HOLD_S, on_second=None,
             wheel_speed_limit_rpm=scenario.POINTING_WHEEL_RPM, tach_noise_rpm=None, spacecraft=None,
             world="thesis", flight=None, estimator=None, faults=None, zeta=None, stkf_accel="white"):
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

    ``world``: "thesis" (Sec. 6.4 as above; ``thesis_world.simulate``; ``flight``'s options are checked, not used)
    or "flight" (``flight_world.simulate``: ``flight`` overrides its options, ``wheel_speed_limit_rpm`` and
    ``settle_ts`` do not apply: the file's limits, and the figures over the pointing passes after the first orbit).
    Both fly the flight app in process, which always feeds its modelled torques forward (``feedforward`` must stay
    on). ``estimator``: its filters, "ground" (the thesis world's default: the 41-state APKF and the full STKF) or
    "lean" (the flight world's default: those that fly). ``faults``: the spacecraft's device faults
    (``emulator.adcs_bus``: wheel_silent, startracker_blind, gnss_outage, beacon_lost; seconds from the run's
    start), in either world. ``zeta``: the PD's damping ratio (Eq. 6.6; None: the firmware's, 1; the result's
    ``pd_zeta`` when given). ``stkf_accel``: the flight world's STKF form over the hpop truth
    (``flight_world.simulate``'s; the thesis world flies "white")."""
    ts = check_ts(ts)
    if world not in WORLDS:
        raise ValueError("world must be one of %s, got %r" % (", ".join(WORLDS), world))
    if not feedforward:
        raise ValueError("the flight app always feeds its modelled torques forward (feedforward)")
    if world == "flight":
        return flight_world.simulate(ts=ts, satb_gnss=satb_gnss, duration_s=duration_s, seed=seed, params=params,
                                     truth=truth, cache_dir=cache_dir, progress=progress, hold_s=hold_s,
                                     on_second=on_second, tach_noise_rpm=tach_noise_rpm, spacecraft=spacecraft,
                                     flight=flight, estimator=estimator or "lean", faults=faults, zeta=zeta,
                                     stkf_accel=stkf_accel)
    if stkf_accel != "white":
        raise ValueError("stkf_accel %s is the flight world's STKF form: the thesis world flies the thesis's STKF"
                         % (stkf_accel,))
    flight_world.check_flight(flight)                  # known options, which the thesis world does not use
    if params is None:
        raise ValueError("simulate needs the parameter file (run calibrate first)")
    d = spacecraft or scenario.thesis_3u()
    check_params(params, spacecraft=d)
    if not (np.isfinite(duration_s) and duration_s >= 1):
        raise ValueError("duration must be >= 1 s, got %r" % (duration_s,))
    if tach_noise_rpm is not None:
        if not (np.isfinite(tach_noise_rpm) and tach_noise_rpm > 0):
            raise ValueError("tach_noise_rpm must be > 0 (the APKF's R), got %r" % (tach_noise_rpm,))
        d = dict(d, wheels=dict(d["wheels"], tach_noise_rpm=float(tach_noise_rpm)))
    return thesis_world.simulate(ts=ts, satb_gnss=satb_gnss, duration_s=duration_s, seed=seed, params=params,
                                 truth=truth, cache_dir=cache_dir, progress=progress, settle_ts=settle_ts,
                                 hold_s=hold_s, on_second=on_second, wheel_speed_limit_rpm=wheel_speed_limit_rpm,
                                 spacecraft=d, estimator=estimator or "ground", faults=faults, zeta=zeta)


def save_history(path, hist):
    """history.npz as np.savez_compressed writes it (one .npy per array, deflated; np.load reads it), at zlib
    level 1: half the CPU of the default level for an archive 0.5 % larger (a 1-orbit flight-world run's)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for name, a in hist.items():
            with zf.open(name + ".npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(a))
    write_atomic(path, buf.getvalue())


def run_one(seed, run_dir, params=None, **kw):
    """Campaign entry (top level, picklable): one pointing run; writes run_dir/result.json (and history)."""
    res, hist = simulate(seed=seed, params=params, **kw)
    if run_dir:
        os.makedirs(run_dir, exist_ok=True)
        save_history(os.path.join(run_dir, "history.npz"), hist)
        write_json(os.path.join(run_dir, "result.json"), res)
    return res


def sweep_one(seed, run_dir, ts_list=(), params=None, noise_seed=0, finish=None, **kw):
    """Campaign entry for the sweep: ``seed`` indexes ts_list (one run per t_s, all with ``noise_seed``);
    ``finish(res, hist)``, when given, adds to the result before it is written."""
    ts = ts_list[seed]
    res, hist = simulate(ts=ts, params=params, seed=noise_seed, **kw)
    if finish is not None:
        finish(res, hist)
    if run_dir:
        os.makedirs(run_dir, exist_ok=True)
        write_json(os.path.join(run_dir, "result.json"), res)
    if not res["complete"]:          # simulate caught a Ctrl-C: the sweep stops too (this t_s stays partial)
        raise KeyboardInterrupt
    return res
