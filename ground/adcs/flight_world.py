"""The flight world of the body pointing simulator (``fps adcs bps --world flight``): the flight software that flies,
``firmware.adcs.app.App`` with its lean APKF and lean STKF, steering the emulated spacecraft in this process.

One flight stack: the run is ``emulator.adcs_session.AdcsSession`` with runtime ``inproc``, so the app gets the
very packets' bytes that ``fps adcs can`` puts on the CAN bus and its history is that command's, bit for bit,
for the same seed, vehicle and parameter file. The mode machine, the gates, the eigenaxis slew, the unloading
law and the wheel allocation are the app's (``firmware/adcs/app.py`` and ``flight.py``); nothing of them is
restated here. What this module adds is the analysis: the truth at 10 Hz, the flight software's state each
second (read from the app after its cycle), the pointing error against the true line of sight (Eq. 6.12-6.21),
the passes, the wheels' and magnetorquers' figures and the error budget; the STKF's full covariance each second
(``StkfLog``) for its NEES; and whether the Earth blocks the line of sight (``pointing.line_of_sight``), whose
occulted samples the pointing figures leave out.

The world: the spacecraft file's wheels at their speed and torque limits, drag and solar pressure torques about
``surface.cp_offset_m``, the magnetorquers and magnetometer on the bus (``scenario.pointing_world(flight=True)``).
``duration_s`` is the whole run from t = 0; the figures are over the POINT samples of the orbits after the first.
"""

import numpy as np

from emulator.spacecraft import scenario
from emulator.spacecraft.scenario import HOLD_S, laser_axis
from firmware.adcs.estimation import Estimation
from firmware.adcs.flight import FLIGHT, options
from ground.adcs import app_host, control
from ground.adcs.app_host import ESTIMATORS  # noqa: F401  (flight_world.ESTIMATORS, the CLI's choices)
from ground.adcs.modes import MODE_CODE
from ground.adcs.pointing import (TS_THESIS, add_statistics, check_ts, close_history, error_budget, line_of_sight, nees,
                                  orbit_period, statistics, stkf_consistency)

DEG = np.pi / 180.0
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
    w, a = fo["slew_rate_deg_s"] * DEG, fo["slew_acc_deg_s2"] * DEG
    t_slew = theta / w + w / a if theta > w * w / a else 2.0 * np.sqrt(theta / a)
    return float(np.ceil(hold_s + t_slew + ACQUIRE_MARGIN_S + 4.0 * check_ts(ts)))


def check_flight(flight):
    """The flight options ``flight`` over ``FLIGHT``'s defaults (the app's own check: ``firmware.adcs.flight.options``);
    ValueError naming an unknown one."""
    return options({"world": "flight", "flight": flight})



def require_magnetorquers(d):
    """The checked spacecraft file ``d``; ValueError when it has no magnetorquers, with which this world unloads
    the wheels."""
    if d["magnetorquers"] is None:
        raise ValueError("magnetorquers = null: the flight world unloads the wheels with magnetorquers; give "
                         "the spacecraft file a magnetorquers block (or fly --world thesis)")
    return d

def simulate(ts=TS_THESIS, satb_gnss=False, duration_s=4000.0, seed=0, params=None, truth="two-body",
             cache_dir=None, progress=False, hold_s=HOLD_S, on_second=None, tach_noise_rpm=None, spacecraft=None,
             flight=None, faults=None, estimator="lean", zeta=None, stkf_accel="white"):
    """One flight-world run (the module docstring): the app in process for ``duration_s`` seconds. ``params``:
    the parameter-file dict (checked against the vehicle); ``flight``: options over ``FLIGHT``; ``faults``: the
    session's device faults; ``on_second(k, hist, fsw, x)`` as ``body_pointing.simulate``'s. Returns (result,
    history) as ``body_pointing.simulate`` does, the history's 1 Hz rows ``fsw_*`` the app's state after cycle k
    (NaN before the APKF starts, and at the last row, which no cycle reaches). A KeyboardInterrupt returns what
    was collected so far with ``complete`` false. ``estimator``: "lean" (the lean APKF and STKF that fly) or
    "ground" (the 41-state APKF and the full STKF, ``ground.adcs.estimators``, for analysis: the same modes,
    command and allocation on other estimates). ``stkf_accel``: the lean STKF's form over the hpop truth
    (``AdcsSession``'s; "markov" with the lean estimator and truth hpop only). The result's ``stkf`` records the
    form flown (``AdcsSession.stkf_form``)."""
    ts = check_ts(ts)
    if stkf_accel != "white" and estimator != "lean":
        raise ValueError("stkf_accel %s is the lean STKF's form: the ground's estimators fly the full STKF, "
                         "two-body" % (stkf_accel,))
    app_host.estimation_for(estimator, None)            # a known estimator, before anything runs
    fo = check_flight(flight)
    if params is None:
        raise ValueError("simulate needs the parameter file (run calibrate first)")
    if not (np.isfinite(duration_s) and duration_s >= 1):
        raise ValueError("duration must be >= 1 s, got %r" % (duration_s,))
    d = require_magnetorquers(spacecraft or scenario.thesis_3u())
    if tach_noise_rpm is not None:
        if not (np.isfinite(tach_noise_rpm) and tach_noise_rpm > 0):
            raise ValueError("tach_noise_rpm must be > 0 (the APKF's R), got %r" % (tach_noise_rpm,))
        d = dict(d, wheels=dict(d["wheels"], tach_noise_rpm=float(tach_noise_rpm)))
    K = int(np.ceil(duration_s))
    log = StkfLog(K, app_host.estimation_for(estimator, d))
    s, rec, hist, k_done, complete, wall_s = app_host.fly(
        K, "bps flight ts=%g s%s" % (ts, " +SatB GNSS" if satb_gnss else ""), progress, on_second,
        satb_gnss=satb_gnss, seed=seed, ts=ts, params=params, faults=faults, truth=truth, cache_dir=cache_dir,
        hold_s=hold_s, spacecraft=d, world="flight", flight=fo, estimation=log, zeta=zeta,
        stkf_accel=stkf_accel)
    lb = laser_axis(d)
    return _result(s, rec, hist, k_done, K, complete, d, lb, fo, ts, satb_gnss, seed, truth, duration_s, wall_s,
                   estimator, log)


def stkf_text(form):
    """The STKF's dynamics flown (``AdcsSession.stkf_form``, a result's ``stkf``) in words, for report.md."""
    if form is None:
        return "the STKF's dynamics: not recorded"
    accel = ("a first-order Gauss-Markov acceleration per axis, σ_a %g m/s², τ %g s" % (form["sigma_a"], form["tau"])
             if "tau" in form else "white acceleration noise, qa %g m²/s³" % form["qa"])
    return "the STKF's dynamics: %s gravity with %s (`--stkf-accel %s`)" % (
        "J2" if form["gravity"] == "j2" else form["gravity"], accel, form["accel"])


class StkfLog:
    """The app's estimation factory (``App(cfg, estimation=...)``) wrapped to record the STKF after each cycle's
    update: its 1 sigma ``sig`` (12) and its full covariance ``P`` (12 x 12) of [rA, vA, rB, vB], per second
    (NaN where no cycle ran). It builds the very filters the app would (``make``; None: the lean ones that fly)
    and only reads them, so the run is the same bit for bit."""

    def __init__(self, K, make=None):
        self.make = make or Estimation
        self.sig = np.full((K + 1, 12), np.nan)
        self.P = np.full((K + 1, 12, 12), np.nan)

    def __call__(self, cfg, rd, health, fo=None):
        est = self.make(cfg, rd, health, fo)
        run = est.run_stkf

        def run_stkf(t, q):                          # the app's call, then a copy of what it left
            run(t, q)
            k = int(round(t))
            if 0 <= k < len(self.sig):
                self.sig[k], self.P[k] = est.sig, stkf_covariance(est.stkf)
        est.run_stkf = run_stkf
        return est


def stkf_covariance(f):
    """The full 12 x 12 covariance of [rA, vA, rB, vB] held by the STKF ``f``: the full STKF's joint ``Pk``
    (``ground.adcs.estimators``), or the lean STKF's SatA block ``Pa`` and its newest SatB node's block of ``P``
    (``firmware.adcs.stkf_lean``: separate filters, so its cross covariance is zero)."""
    if hasattr(f, "Pk"):
        return np.array(f.Pk, float)
    P = np.zeros((12, 12))
    P[0:6, 0:6] = np.reshape(np.asarray(f.Pa, float), (6, 6))
    P[6:12, 6:12] = np.reshape(np.asarray(f.P, float), (f.ld, f.ld))[0:6, 0:6]
    return P


def stkf_history(hist, fsw, log, x1):
    """The STKF's record added to the history (new keys only): ``fsw_stkf_x_err`` (estimate minus truth of
    [rA, vA, rB, vB], m and m/s; ``fsw_stkf_err`` is its positions), ``fsw_stkf_sig`` (the filter's 1 sigma),
    ``fsw_stkf_P`` (its full covariance, 144 = 12 x 12 row by row) and ``fsw_stkf_nees12_full_cov`` (the NEES
    of the 12 states against that covariance), one row a second as the other ``fsw_*``. ``x1``: the orbit truth
    at the rows' seconds (n, 2, 6). Returns (x_err, P)."""
    n = len(fsw["x_stkf"])
    x_err = np.asarray(fsw["x_stkf"], float) - np.reshape(x1[:n], (n, 12))
    P = log.P[:n]
    hist.update(fsw_stkf_x_err=x_err, fsw_stkf_sig=log.sig[:n], fsw_stkf_P=P.reshape(n, 144),
                fsw_stkf_nees12_full_cov=nees(x_err, P)[:, None])
    return x_err, P


def _result(s, rec, hist, k_done, K, complete, d, lb, fo, ts, satb_gnss, seed, truth, duration_s, wall_s, estimator,
            log):
    """The run's result and history from the session and the recorder (``simulate``)."""
    rate = scenario.WORLD_RATE_HZ
    dth, dom, fsw = close_history(hist, rec.fsw, s.xg, rate, k_done, lb)
    mode_s = fsw["mode"][:, 0]
    mode10 = mode_s[np.minimum(hist["t"].astype(int), max(k_done - 1, 0))]    # each step flown under its cycle
    period = orbit_period(s.xg[0, 0])
    window = (hist["t"] >= period) & (mode10 == MODE_CODE["POINT"])
    occ, los = line_of_sight(hist, s.xg, rate, window)
    sel = window & ~occ
    x1 = s.xg[:(k_done + 1) * rate:rate]
    budget = error_budget(hist, x1, period, laser_axis=lb, clear=~occ[::10])
    first_point = next((c["t_s"] for c in s.mode_changes if c["to"] == "POINT"), None)
    blind = s.blind_share(first_point) if first_point is not None else None
    res = app_host.run_result(s, rec, k_done, K, complete, wall_s, "flight", estimator, period, ts_s=ts,
                              satb_gnss=satb_gnss, seed=seed, truth=truth, duration_s=duration_s, zeta=s.zeta)
    res.update(wheel_speed_limit_rpm=float(d["wheels"]["speed_limit_rpm"]), star_tracker_blind_share=blind,
               faults=s.faults, fault_log=s.fault_log)
    mtq = d["magnetorquers"]
    axes = np.array([np.asarray(a, float) / np.linalg.norm(a) for a in mtq["axes"]])
    flog = {k: fsw[k] for k in ("m_cmd", "h_w", "mtq_sat", "beacon_used")}
    res.update(flight_statistics(hist, dth, dom, mode10, period, flog, mtq["dipole_limit_am2"], axes, occ))
    res["flight_options"] = fo
    res["stkf"] = s.stkf_form()                     # the STKF's dynamics flown: its form and keywords
    res["truth_form"] = s.sc.truth_form             # the truth's RK4 step: "kernel" (C) or "python"
    add_statistics(res, dth, dom, sel)
    res["budget"] = budget
    res["consistency"] = app_host.consistency(fsw, int(np.ceil(period)))
    x_err, P = stkf_history(hist, fsw, log, x1)
    res["stkf_consistency"] = stkf_consistency(x_err, P, int(np.ceil(period)))
    res.update(los)
    return res, hist


def flight_statistics(hist, dth, dom, mode10, period, flog, dipole_limit, axes, occ=None):
    """The flight world's figures: per pointing pass (pass p = the POINT samples of orbit p, p >= 1, of those the
    run holds whole, less those ``occ`` marks occulted; orbit 0 is the slew and settling) its 3 sigma pointing
    and stability (as ``statistics``) and
    largest wheel speed; the largest wheel speed after the first orbit (``max_wheel_speed_rpm`` then means that span, and
    ``max_wheel_speed_rpm_run`` the whole run's); the magnetorquers' duty (mean of the largest rod's |m| over
    its limit) and saturated share; the wheels' momentum |h| (N m s) at most and at the end."""
    t = hist["t"]
    rpm = np.abs(hist["w_rel"]) * 60 / (2 * np.pi)
    passes = []
    n_orbits = int(np.floor(t[-1] / period + 0.01))           # whole orbits (1 % short still counts)
    for p in range(1, n_orbits):
        span = (t >= p * period) & (t < (p + 1) * period)
        sel = span & (mode10 == MODE_CODE["POINT"])
        n_occ = 0 if occ is None else int(np.count_nonzero(sel & occ))
        if occ is not None:
            sel &= ~occ
        if sel.sum() < 2:
            passes.append({"orbit": p, "samples": int(sel.sum()), "occulted_samples": n_occ})
            continue
        st = statistics(dth[sel], dom[sel])
        passes.append({"orbit": p, "t_from_s": float(t[span][0]), "t_to_s": float(t[span][-1]),
                       "samples": st["samples"], "pointing_3sigma_arcsec": st["pointing_3sigma_arcsec"],
                       "stability_3sigma_arcsec_s": st["stability_3sigma_arcsec_s"],
                       "max_wheel_speed_rpm": float(rpm[span].max()), "occulted_samples": n_occ})
    after = t >= period
    rods = np.abs(np.linalg.lstsq(axes.T, np.nan_to_num(flog["m_cmd"]).T, rcond=None)[0]).max(axis=0)
    h = np.linalg.norm(flog["h_w"], axis=1)
    return {"passes": passes, "max_wheel_speed_rpm": float(rpm[after].max()) if after.any() else None,
            "max_wheel_speed_rpm_run": float(rpm.max()),
            "mtq_duty": float(np.mean(rods / dipole_limit)),
            "mtq_saturated_share": float(np.nanmean(flog["mtq_sat"])),
            "wheel_momentum_max_nms": float(np.nanmax(h)) if np.isfinite(h).any() else None,
            "wheel_momentum_end_nms": float(h[np.isfinite(h)][-1]) if np.isfinite(h).any() else None,
            "beacon_used_share": float(np.nanmean(flog["beacon_used"]))}
