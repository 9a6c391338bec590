"""The thesis world of the body pointing simulator (``fps adcs bps``, Sec. 6.4): the flight app in process
(``app_host.fly``), in its thesis world (``firmware/adcs/modes.py``: a hold of rate damping while the APKF
converges, then quaternion PD on the command at SatB, Eq. 6.3-6.7, with the first acquisition's rate damping until
the star tracker answers), on the ground's estimators by default (the 41-state APKF and the full STKF with its
AFLS, ``ground/adcs/estimators.py``; ``estimator="lean"`` flies the lean filters instead).

The world is Sec. 6.4.1-6.4.2's (``scenario.pointing_world``): the thesis's spacecraft or a spacecraft file's, its
wheels without a speed limit in effect (``wheel_speed_limit_rpm``), from q = [0, 0, 0, 1] at rest. The figures are
collected at 10 Hz after the hold and 4 t_s of settling (``settle_ts``), over ``duration_s`` seconds, less the
samples where the Earth blocks the line of sight to the partner (``pointing.line_of_sight``: a run without line of
sight in its window is marked "no line of sight", never budgets met).
"""

import numpy as np

from emulator.spacecraft import scenario
from emulator.spacecraft.scenario import HOLD_S, laser_axis
from ground.adcs import app_host
from ground.adcs.pointing import TS_THESIS, add_statistics, check_ts, close_history, error_budget, line_of_sight


def simulate(ts=TS_THESIS, satb_gnss=False, duration_s=4000.0, seed=0, params=None, truth="two-body",
             cache_dir=None, progress=False, settle_ts=4.0, hold_s=HOLD_S, on_second=None,
             wheel_speed_limit_rpm=scenario.POINTING_WHEEL_RPM, spacecraft=None, estimator="ground", faults=None,
             zeta=None):
    """One thesis-world run; the arguments and the result as ``body_pointing.simulate``'s (which checks them and
    calls this). Returns (result, history): the history's 10 Hz truth and its 1 Hz rows ``fsw_*`` the app's state
    after cycle k (NaN before the APKF starts, and at the last row, which no cycle reaches)."""
    d = spacecraft or scenario.thesis_3u()
    t_settle = hold_s + settle_ts * ts
    K = int(np.ceil(t_settle + duration_s))
    s, rec, hist, k_done, complete, wall_s = app_host.fly(
        K, "bps ts=%g s%s" % (ts, " +SatB GNSS" if satb_gnss else ""), progress, on_second,
        satb_gnss=satb_gnss, seed=seed, ts=ts, params=params, truth=truth, cache_dir=cache_dir, hold_s=hold_s,
        spacecraft=d, world="thesis", wheel_speed_limit_rpm=wheel_speed_limit_rpm, faults=faults,
        estimation=app_host.estimation_for(estimator, d), zeta=zeta)
    lb = laser_axis(d)
    rate = scenario.WORLD_RATE_HZ
    dth, dom, rows = close_history(hist, rec.fsw, s.xg, rate, k_done, lb)
    sel = hist["t"] >= t_settle
    res = app_host.run_result(s, rec, k_done, K, complete, wall_s, "thesis", estimator, t_settle, ts_s=check_ts(ts),
                              satb_gnss=satb_gnss, seed=seed, truth=truth, duration_s=duration_s, zeta=s.zeta)
    res["max_wheel_speed_rpm"] = float(np.abs(hist["w_rel"]).max() * 60 / (2 * np.pi))
    res["wheel_speed_limit_rpm"] = float(wheel_speed_limit_rpm)
    secs = np.arange(k_done + 1) >= t_settle         # the star tracker's blind share after the settling
    res["star_tracker_blind_share"] = float(1.0 - np.nanmean(rows["st_ok"][secs, 0])) if secs.any() else None
    occ, los = line_of_sight(hist, s.xg, rate, sel)        # occulted samples leave the pointing figures
    add_statistics(res, dth, dom, sel & ~occ)
    res["budget"] = error_budget(hist, s.xg[:(k_done + 1) * rate:rate], t_settle, laser_axis=lb, clear=~occ[::10])
    res.update(los)
    res["consistency"] = app_host.consistency(rows, int(np.ceil(t_settle)))
    return res, hist
