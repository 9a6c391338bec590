"""The flight world (``fps adcs bps --world flight``): 3 orbits per shipped spacecraft, brahe truth, seed 0, against
the goals: every pointing pass after the first orbit within 150 arcsec / 35 arcsec/s (3 sigma, two axes),
no wheel above 80 % of its speed limit after the first orbit, the STKF never diverging, the star tracker blind
less than 10 % of the time after the first slew, and a 3-orbit run within 3 min. generic-12u is shipped without a
partner satellite (it points at a ground station); it flies here with one 10 deg behind it in its own orbit
(``bps.with_partner``), as a team with a crosslink would enter it."""

import time

import numpy as np

from ground.adcs import body_pointing as bps
from protocol import spacecraft as sf

SPACECRAFT = ("thesis-3u", "generic-6u", "generic-12u")
ORBITS = 3


def _ok(v):
    return "met" if v else "**missed**"


def run(name, seed=0, truth="hpop"):
    d = sf.load(name)
    if d["partner"] is None:
        d = bps.with_partner(d)
    s = d["orbit"]["state"]
    T = bps.orbit_period(np.array(s["position_m"] + s["velocity_m_s"]))
    t0 = time.perf_counter()
    p = bps.calibrate(seed=seed, spacecraft=d)
    t_cal = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        res, _ = bps.simulate(params=p, duration_s=ORBITS * T, world="flight", truth=truth, spacecraft=d, seed=seed)
        res["error"] = None
    except FloatingPointError as exc:               # a filter diverged: the goal is missed, said so
        res = {"error": str(exc), "passes": []}
    res["wall_run_s"], res["wall_cal_s"], res["name"] = time.perf_counter() - t0, t_cal, d["name"]
    return res


def main():
    rows = [run(n) for n in SPACECRAFT]
    print("Flight world, %d orbits, brahe truth, seed 0; per pass (orbit 1, 2; orbit 0 is the slew and settling): "
          "3 sigma pointing / stability, largest wheel speed\n" % ORBITS)
    print("| spacecraft | pass | 3σ pointing (arcsec; goal < 150) | 3σ stability (arcsec/s; goal < 35) | largest "
          "wheel speed (rpm) |")
    print("|---|---|---|---|---|")
    for r in rows:
        for p in r["passes"]:
            if p.get("pointing_3sigma_arcsec") is None:
                continue
            print("| %s | %d | %.1f (%s) | %.1f (%s) | %.0f |" % (
                r["name"], p["orbit"], p["pointing_3sigma_arcsec"], _ok(p["pointing_3sigma_arcsec"] < 150),
                p["stability_3sigma_arcsec_s"], _ok(p["stability_3sigma_arcsec_s"] < 35), p["max_wheel_speed_rpm"]))
    print("\n| spacecraft | largest wheel speed after orbit 0 / limit (goal <= 80 %) | star tracker blind after the "
          "first slew (goal < 10 %) | STKF / APKF diverged (goal: never) | slews; APKF resets | magnetorquer duty; "
          "saturated | time in SLEW / ACQUIRE / POINT (s) | wall: 3 orbits (goal <= 3 min); calibration |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if r["error"]:
            print("| %s | — | — | **%s** | — | — | — | %.0f s |" % (r["name"], r["error"], r["wall_run_s"]))
            continue
        share = r["max_wheel_speed_rpm"] / r["wheel_speed_limit_rpm"]
        tm = r["time_in_mode_s"]
        slews = sum(1 for c in r["mode_changes"] if c["to"] == "SLEW")
        print("| %s | %.0f / %.0f rpm = %.0f %% (%s) | %.2f %% (%s) | no (met) | %d; %d | %.2f; %.1f %% | %.0f / %.0f "
              "/ %.0f | %.0f s (%s); %.1f s |" % (
                  r["name"], r["max_wheel_speed_rpm"], r["wheel_speed_limit_rpm"], 100 * share, _ok(share <= 0.8),
                  100 * r["star_tracker_blind_share"], _ok(r["star_tracker_blind_share"] < 0.1), slews,
                  len(r["apkf_attitude_resets"]), r["mtq_duty"], 100 * r["mtq_saturated_share"], tm["SLEW"],
                  tm["ACQUIRE"], tm["POINT"], r["wall_run_s"], _ok(r["wall_run_s"] <= 180), r["wall_cal_s"]))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
