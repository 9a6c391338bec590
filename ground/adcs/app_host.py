"""The ground's worlds flying the flight app in process: ``fly`` runs ``emulator.adcs_session.AdcsSession`` with
runtime ``inproc`` (the very packets' bytes ``fps adcs can`` puts on the CAN bus), records the truth at 10 Hz and
the flight software's state after each 1 Hz cycle (``Recorder``, read from the app's components). The thesis world
(``thesis_world``) and the flight world (``flight_world``) add their statistics; nothing of the modes, the
command, the control law or the wheel allocation is restated on the ground.
"""

import time

import numpy as np

from emulator.adcs_session import AdcsSession
from emulator.spacecraft import scenario
from ground.adcs.pointing import EST_COLS, estimate_errors
from protocol.units import RAD_PER_ARCSEC

# the flight software's state recorded each second (history ``fsw_<name>``; NaN before the APKF starts)
FSW = (("q_hat", 4), ("w_hat", 3), ("qc", 4), ("tau_c", 3), ("u", 4), ("tau_ff", 3), ("tau_ext_true", 3),
       ("wc", 3), ("x_stkf", 12), ("est_err", len(EST_COLS)), ("m_cmd", 3), ("h_w", 3), ("mode", 1),
       ("st_ok", 1), ("beacon_used", 1), ("mtq_sat", 1), ("att_sigma", 1), ("att_cov", 9), ("stkf_err", 6),
       ("stkf_cov", 18))
ESTIMATORS = ("lean", "ground")
SOFTWARE = {"ground": "firmware/adcs/app.py in process with the ground's estimators (41-state APKF, full STKF with "
                      "its AFLS: ground/adcs/estimators.py)",
            "lean": "firmware/adcs/app.py in process (lean APKF, lean STKF with its AFLS)"}


class Recorder:
    """The flight software's state after each cycle (``AdcsSession``'s probe): the app's own arrays, copied."""

    def __init__(self, K):
        self.s = None                        # the session, set once it exists
        self.fsw = {k: np.full((K + 1, m), np.nan) for k, m in FSW}
        self.resets = []
        self._n_resets = 0

    def __call__(self, tick, t, u):
        s, app, f, k = self.s, self.s.app, self.fsw, tick
        sc = s.sc
        f["tau_ext_true"][k] = sc.external_torque(sc.t, sc.x)          # truth, for the record only
        f["mode"][k] = app.mode
        f["st_ok"][k] = s.st_valid_log[k]
        est = app.est
        f["beacon_used"][k] = est.beacon_used
        f["x_stkf"][k] = est.xs
        a = est.apkf
        if a is None:
            return
        f["q_hat"][k], f["w_hat"][k] = a.x[0:4], a.x[4:7]
        f["att_sigma"][k] = est.sigma_att()                              # rad, the attitude's 1 sigma (rss)
        md, act = app.modes, app.act
        f["qc"][k], f["wc"][k], f["tau_c"][k], f["u"][k], f["tau_ff"][k] = md.qc, md.wc, act.tau, u, act.tff
        f["m_cmd"][k], f["mtq_sat"][k] = act.m_cmd, act.mtq_sat
        f["h_w"][k] = np.reshape(act.cjrw, (3, 4)) @ np.asarray(app.rd.wp)
        x = s.xg[k * scenario.WORLD_RATE_HZ]
        f["est_err"][k] = estimate_errors(f["q_hat"][k], f["w_hat"][k], est.xs[0:3], est.xs[6:9], sc.q, sc.omega,
                                          x[0, 0:3], x[1, 0:3])
        f["att_cov"][k] = est.Patt                                        # rad^2, the attitude's (4 P_qq)
        f["stkf_err"][k] = np.concatenate([np.asarray(est.xs[0:3]) - x[0, 0:3], np.asarray(est.xs[6:9]) - x[1, 0:3]])
        pa, pb = np.zeros(9), np.zeros(9)
        est.position_cov(pa, pb)
        f["stkf_cov"][k] = np.concatenate([pa, pb])
        hl = app.health
        if hl.n_resets != self._n_resets:
            self._n_resets = hl.n_resets
            self.resets.append((t, hl.reset_nis, hl.reset_arcsec))


def consistency(fsw, k_from, p=0.95):
    """Whether each estimator's 1 sigma holds over the seconds k_from .. of the recorded flight software: for the
    attitude (the APKF; error 2 x the vector part of q_hat (x) q^-1 against 4 P_qq), SatA's and SatB's positions
    (the STKF), each second's NEES (3 dof) and the share of seconds within its two-sided ``p`` band (a consistent
    filter has ~``p`` of them inside), the mean NEES (3 when consistent), and per axis the RMS error over the RMS
    1 sigma (1 when consistent). None for a part with no second recorded."""
    from ground.adcs.pointing import nees, nees_band
    lo, hi = nees_band(3, p)
    att = np.asarray(fsw["est_err"][:, 0:3], float) * RAD_PER_ARCSEC
    parts = {"apkf_attitude": (att, fsw["att_cov"]), "stkf_ra": (fsw["stkf_err"][:, 0:3], fsw["stkf_cov"][:, 0:9]),
             "stkf_rb": (fsw["stkf_err"][:, 3:6], fsw["stkf_cov"][:, 9:18])}
    out = {"band": [lo, hi], "p": p, "from_s": float(k_from)}
    for name, (e, c) in parts.items():
        e, c = e[k_from:], c[k_from:]
        ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(c), axis=1)
        if not ok.any():
            out[name] = None
            continue
        e, C = e[ok], c[ok].reshape(-1, 3, 3)
        n = nees(e, C)
        with np.errstate(invalid="ignore"):         # a diverged filter's negative variance: NaN, said as such
            sig = np.sqrt(np.einsum("kii->ki", C))
        out[name] = {"seconds": int(ok.sum()), "nees_mean": float(n.mean()),
                     "nees_in_band_share": float(np.mean((n >= lo) & (n <= hi))),
                     "rms_over_sigma": (np.sqrt((e ** 2).mean(axis=0)) / np.sqrt((sig ** 2).mean(axis=0))).tolist()}
    return out


def run_result(s, rec, k_done, K, complete, wall_s, world, estimator, settle_s, **run):
    """What both worlds' results say of a run of the session ``s`` and its recorder: the ``run``'s arguments
    (ts_s, satb_gnss, seed, truth, duration_s; zeta, the PD's damping ratio, as ``pd_zeta`` when not None), how
    far it got, the flight software it flew, the vehicle, the wheels, the modes, the gate's resets and the devices'
    faults (the session's: the schedule, its log, the readings the app missed, the failed wheels and magnetic
    devices); ``health_events`` the magnetic devices out or back with their reasons (``StatusWatch.health_events``)."""
    from ground.adcs.modes import time_in
    from ground.adcs.pointing import orbit_period
    d = s.spacecraft
    out = {"ts_s": run["ts_s"], "satb_gnss": bool(run["satb_gnss"]), "seed": int(run["seed"]), "truth": run["truth"],
           "duration_s": float(run["duration_s"]), "settle_s": float(settle_s), "simulated_s": float(k_done),
           "complete": bool(complete and k_done == K), "feedforward": True, "wall_s": wall_s,
           "flight_software": SOFTWARE[estimator], "estimator": estimator, "world": world, "spacecraft": d["name"],
           "wheel_speed_clips": s.wheels.counters(), "tach_noise_rpm": d["wheels"]["tach_noise_rpm"],
           "wheel_datasheet_rpm": d["wheels"]["speed_limit_rpm"], "orbit_period_s": orbit_period(s.xg[0, 0]),
           "mode_changes": s.mode_changes, "time_in_mode_s": time_in(s.mode_changes, k_done),
           "apkf_attitude_resets": [list(r) for r in rec.resets], "health_events": list(s.watch.health_events)}
    if run.get("zeta") is not None:
        out["pd_zeta"] = float(run["zeta"])
    if s.faults:
        sm = s.summary()
        out["devices"] = {k: sm[k] for k in ("faults", "fault_log", "firmware_missed", "wheels_failed", "last_mode")}
        out["devices"]["magnetic_failed"] = (s.watch.last or {}).get("magnetic_failed")
    return out


def estimation_for(estimator, spacecraft):
    """The app's ``estimation`` for ``estimator`` ("lean": None, the filters that fly; "ground": the 41-state APKF
    and the full STKF, ``ground.adcs.estimators``) on the checked spacecraft file ``spacecraft``."""
    if estimator not in ESTIMATORS:
        raise ValueError("estimator must be one of %s, got %r" % (", ".join(ESTIMATORS), estimator))
    if estimator == "lean":
        return None
    from ground.adcs.estimators import estimation
    return estimation(spacecraft)


def fly(K, desc, progress=False, on_second=None, **session):
    """K cycles of the app in process (``AdcsSession(runtime="inproc", **session)``); returns (session,
    recorder, hist, k_done, complete, wall_s): ``hist`` the truth at 10 Hz (t, q, w, w_rel; rows up to 10 k_done
    filled), ``complete`` False when a KeyboardInterrupt stopped it. ``on_second(k, hist, fsw, x)`` after cycle k
    (``body_pointing.simulate``'s)."""
    rec = Recorder(K)
    s = rec.s = AdcsSession(runtime="inproc", duration_s=float(K), probe=rec, **session)
    n10 = K * 10 + 1
    hist = {"t": np.arange(n10) / 10.0, "q": np.zeros((n10, 4)), "w": np.zeros((n10, 3)),
            "w_rel": np.zeros((n10, 4))}
    hist["q"][0], hist["w"][0], hist["w_rel"][0] = s.sc.q, s.sc.omega, s.sc.omega_rw_rel
    sub = scenario.WORLD_RATE_HZ // 10
    complete, k_done = True, 0
    t_wall = time.perf_counter()
    from tqdm import tqdm
    bar = tqdm(total=K, desc=desc, unit="s", leave=False, disable=not progress)
    try:
        with s:
            for k in range(K):
                c = s.cycle()
                sl = slice(10 * k + 1, 10 * k + 11)
                hist["q"][sl], hist["w"][sl], hist["w_rel"][sl] = c["q"], c["w"], c["w_rel"]
                k_done = k + 1
                if on_second is not None:
                    on_second(k, hist, rec.fsw, s.xg[(10 * k + 1) * sub:(10 * k + 10) * sub + 1:sub])
                bar.update(1)
    except KeyboardInterrupt:
        complete = False
    finally:
        bar.close()
    return s, rec, hist, k_done, complete, time.perf_counter() - t_wall
