"""``fps adcs campaign``: the flight world over a population of vehicles drawn from one spacecraft file, as a flight
team verifies a vehicle by Monte Carlo over its dispersions.

Run i flies seed ``--seed`` + i: its vehicle drawn from that seed within the file's ``uncertainty`` (or the file's
truth block, ``--vehicle``; ``emulator.spacecraft.dispersion``), the nine calibration sets through the APKF on
that vehicle, then ``--orbits`` orbits of the flight world (``fps adcs bps --world flight``, the same code),
judged by the same checks (``bps_cli.flight_checks``). The runs go on local worker processes or a Dask cluster
(``ground.adcs.campaign``). The folder is resumable: ``campaign.json`` names the campaign, and a campaign run
again into its folder keeps every finished run (its ``run_NNNN/result.json``) and runs only the others; a
folder of another campaign is refused.

The folder: ``run_NNNN/`` (result.json, history.npz, params.json) per vehicle; ``summary.json`` (``complete``
false until every run is in); ``report.md``: the share of vehicles meeting each check with its 95 % Wilson
interval, the distributions of the figures, the filters' NEES over the population and the worst vehicles with
the seed that replays each and the checks it missed; ``population_cdf.png``: each figure's CDF over the vehicles
against its budget.
"""

import json
import os
import sys

import numpy as np

from ground.fileio import write_atomic, write_json
from ground.verdict import close, table as verdict_table

FIGURE = "population_cdf.png"
CONFIDENCE = 0.95
NEES_GOAL = 0.90          # a filter's NEES in its 95 % band this share of the time or more: consistent
WORST = 5
# the figures per vehicle: (key, unit, budget from the checks or None, what)
FIGURES = (("pointing_3sigma_arcsec", "arcsec", "pointing", "worst pass's 3σ pointing"),
           ("stability_3sigma_arcsec_s", "arcsec/s", "stability", "worst pass's 3σ stability"),
           ("max_wheel_speed_rpm", "rpm", "wheels", "largest wheel speed after the first orbit"),
           ("mtq_duty", "1", None, "magnetorquers' duty"),
           ("apkf_nees_in_band_share", "1", None, "APKF attitude NEES in its band"),
           ("stkf_nees_in_band_share", "1", None, "STKF NEES (12 states) in its band"))


def wilson(k, n, confidence=CONFIDENCE):
    """(low, high): the Wilson score interval of a share k / n (scipy's binomial test)."""
    from scipy.stats import binomtest
    if n == 0:
        return (None, None)
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return (float(ci.low), float(ci.high))


def figures_of(res):
    """The population's figures of one flight-world result (None where the run has none)."""
    passes = [p for p in res.get("passes") or [] if p.get("pointing_3sigma_arcsec") is not None]
    c = res.get("consistency") or {}
    s = res.get("stkf_consistency") or {}
    att, n12 = c.get("apkf_attitude"), s.get("nees12_full_cov")
    return {"pointing_3sigma_arcsec": max((p["pointing_3sigma_arcsec"] for p in passes), default=None),
            "stability_3sigma_arcsec_s": max((p["stability_3sigma_arcsec_s"] for p in passes), default=None),
            "max_wheel_speed_rpm": res.get("max_wheel_speed_rpm"), "mtq_duty": res.get("mtq_duty"),
            "apkf_nees_in_band_share": att.get("nees_in_band_share") if att else None,
            "stkf_nees_in_band_share": n12["nees_in_band_share"] if n12 else None}


def dipole_beyond_rods(d):
    """The rods' shares (A m^2, one per rod: least squares on their axes) that cancelling the flown vehicle's
    residual dipole (the file's figure plus its truth block's error) takes, and the rods' limit; a share beyond
    the limit is a dipole the magnetorquers cannot cancel, whose torque the wheels then absorb. None without
    magnetorquers."""
    from emulator.spacecraft.devices import Magnetorquers
    rods = Magnetorquers.from_spacecraft(d)
    if rods is None:
        return None
    err = ((d.get("truth") or {}).get("residual_dipole_error_am2")) or [0.0, 0.0, 0.0]
    m = np.asarray(d["residual_dipole_am2"], float) + np.asarray(err, float)
    shares = rods.shares(m)
    return {"dipole_am2": m.tolist(), "shares_am2": shares.tolist(), "limit_am2": rods.limit,
            "beyond": bool(np.any(np.abs(shares) > rods.limit))}


def largest_tilt(d):
    """(the flown vehicle's largest wheel tilt in degrees, the file's 1 sigma of each tilt angle or None): per
    wheel the hypotenuse of its two angles, its figures plus its truth block's errors."""
    w, t = d["wheels"], d.get("truth") or {}
    n = len(w["delta1_deg"])
    a = [x + e for x, e in zip(w["delta1_deg"], t.get("delta1_error_deg") or [0.0] * n)]
    b = [x + e for x, e in zip(w["delta2_deg"], t.get("delta2_error_deg") or [0.0] * n)]
    return float(max(np.hypot(a, b))), (d.get("uncertainty") or {}).get("misalignment_sigma_deg")


def held_in_acquire(res, d, share=0.5):
    """A named cause for a vehicle held in ACQUIRE more than ``share`` of the run: the time there, the star
    tracker's blindness, the wheels, and the vehicle's largest wheel tilt against the file's 1 sigma (None when the
    vehicle is not)."""
    t = res.get("time_in_mode_s") or {}
    total = sum(t.values())
    if not total or t.get("ACQUIRE", 0.0) <= share * total:
        return None
    tilt, sigma = largest_tilt(d)
    blind = res.get("star_tracker_blind_share")
    wheels = res["checks"].get("wheels", {}).get("ok", True)
    return ("held in ACQUIRE %.0f %% of the run (POINT %.0f s)%s, the wheels %s: the attitude loop did not bring the "
            "body back under the star tracker's rate limit; the vehicle's largest wheel tilt %.1f deg%s" % (
                100 * t["ACQUIRE"] / total, t.get("POINT", 0.0),
                "" if blind is None else ", the star tracker blind %.0f %% of the time" % (100 * blind),
                "within their limit" if wheels else "beyond their limit", tilt,
                " (the file's 1 sigma %g deg an angle)" % sigma if sigma else ""))


def miss_causes(res, d):
    """The named causes of a vehicle's missed checks that the vehicle itself shows (beyond the checks' own words):
    a residual dipole beyond the rods' authority when the wheels' check missed with the rods saturated; else a
    vehicle held in ACQUIRE (``held_in_acquire``)."""
    out = []
    rods = dipole_beyond_rods(d)
    wheels = res["checks"].get("wheels", {}).get("ok", True)
    if rods is not None and rods["beyond"] and not wheels:
        out.append("the residual dipole (%s) A m^2 needs rod shares (%s) beyond the rods' ±%g A m^2: the "
                   "magnetorquers cannot cancel it, the wheels absorb its torque (duty %s)" % (
                       ", ".join("%.2f" % v for v in rods["dipole_am2"]),
                       ", ".join("%.2f" % v for v in rods["shares_am2"]), rods["limit_am2"],
                       _fmt(res.get("mtq_duty"), "%.2f")))
    held = None if out or res.get("ok") else held_in_acquire(res, d)
    return out + ([held] if held else [])


def run_vehicle(seed, run_dir, spacecraft, vehicle="file", orbits=3.0, truth="two-body", ts=33.0,
                satb_gnss=False, cache_dir=None, stkf_accel="white"):
    """One vehicle of the campaign (top level, picklable): drawn from ``seed``, calibrated, flown ``orbits``
    orbits in the flight world (its STKF's form ``stkf_accel``, ``flight_world.simulate``'s); returns its result
    with ``vehicle``, ``checks``, ``ok`` (``budgets_met``: every check met, as ``fps adcs bps --world flight``
    judges it) and ``figures`` (``figures_of``), and writes ``run_dir``."""
    from emulator.spacecraft import dispersion
    from ground.adcs import body_pointing as bps, bps_cli
    from protocol import spacecraft as sf
    d, vrec = dispersion.flown(spacecraft, seed, vehicle)
    params = bps_cli.calibration(seed, cache_dir, False, d)
    res, hist = bps.simulate(ts=ts, satb_gnss=satb_gnss, duration_s=bps_cli.orbits_duration(d, orbits), seed=seed,
                             params=params, truth=truth, cache_dir=cache_dir, progress=False, spacecraft=d,
                             world="flight", stkf_accel=stkf_accel)
    if not res["complete"]:
        raise KeyboardInterrupt
    res["vehicle"] = vrec
    res["requirements"] = sf.requirements(d)
    res["ok"] = bps_cli.judge_flight(res)["budgets_met"]
    res["figures"] = figures_of(res)
    res["causes"] = miss_causes(res, d)
    if run_dir:
        os.makedirs(run_dir, exist_ok=True)
        bps.write_params(os.path.join(run_dir, "params.json"), params, d)
        bps.save_history(os.path.join(run_dir, "history.npz"), hist)
        write_json(os.path.join(run_dir, "result.json"), res)
    return res


def _share(results, ok):
    n = len(results)
    k = sum(1 for r in results if ok(r))
    lo, hi = wilson(k, n)
    return {"met": k, "of": n, "share": k / n if n else None, "ci95": [lo, hi]}


def aggregate(results, identity):
    """summary.json: the shares meeting each check (and all of them) with their 95 % intervals, each figure's
    distribution (min, median, 95th percentile, max), the worst vehicles and the runs that failed."""
    flown = [r for r in results if r]
    good = [r for r in flown if "error" not in r]
    failed = [{"seed": r["seed"], "error": r["error"]} for r in flown if "error" in r]
    names = sorted({k for r in good for k in r["checks"]})
    # a vehicle whose run failed (its filters diverged, its calibration left the file's range) met no check: a
    # miss with its cause, never left out of the shares
    out = dict(identity, runs_done=len(good), runs_failed=len(failed), failures=failed,
               all_checks=_share(flown, lambda r: "error" not in r and r["ok"]),
               checks={k: dict(_share(flown, lambda r, k=k: "error" not in r and r["checks"][k]["ok"]),
                               what=next(r["checks"][k]["what"] for r in good)) for k in names})
    dist = {}
    for key, unit, _, what in FIGURES:
        v = np.array([r["figures"][key] for r in good if r["figures"].get(key) is not None], float)
        dist[key] = ({"unit": unit, "what": what, "n": int(len(v)), "min": float(v.min()),
                      "median": float(np.median(v)), "mean": float(v.mean()), "p95": float(np.percentile(v, 95)),
                      "max": float(v.max())}
                     if len(v) else {"unit": unit, "what": what, "n": 0})
    out["figures"] = dist
    worst = sorted(good, key=lambda r: (r["ok"], -(r["figures"].get("pointing_3sigma_arcsec") or np.inf)))[:WORST]
    out["worst"] = [{"seed": r["seed"], "ok": r["ok"], "figures": r["figures"],
                     "missed": [c["what"] for c in r["checks"].values() if not c["ok"]]
                     + ([] if r.get("line_of_sight", True) else ["no line of sight"]) + r.get("causes", []),
                     "vehicle": r["vehicle"]} for r in worst]
    return out


def _fmt(v, f="%.3g"):
    return "—" if v is None else f % v


def report_md(s):
    """report.md of the summary ``s``."""
    accel = s.get("stkf_accel", "white")
    L = ["# Flight-world campaign over a population of vehicles", "",
         "Spacecraft %s (sha256 %s), %d vehicles (%s), %g orbits each, seeds %d-%d, truth %s, %s; %s." % (
             s["spacecraft"]["name"], s["spacecraft"]["sha256"], s["runs"], s["vehicle_text"], s["orbits"],
             s["seeds"][0], s["seeds"][-1], s["truth"],
             "the STKF's J2 model with its acceleration %s (`--stkf-accel`)" % accel if s["truth"] == "hpop" else
             "the STKF's two-body model (a two-body truth has no J2)",
             "complete" if s["complete"] else "INCOMPLETE (resume to finish)"), ""]
    L += verdict_table([("%s: %s (vehicles meeting it)" % (k, c["what"]), "%d of %d" % (c["met"], c["of"]), "all",
                         c["met"] == c["of"] if c["of"] and s["complete"] else None) for k, c in s["checks"].items()])
    L += ["| check | vehicles meeting it | share | 95 % interval |", "|---|---|---|---|"]
    for k, c in list(s["checks"].items()) + [("every check", dict(s["all_checks"], what="all of the above"))]:
        L.append("| %s: %s | %d of %d | %s | %s-%s |" % (k, c["what"], c["met"], c["of"], _fmt(c["share"], "%.2f"),
                                                        _fmt(c["ci95"][0], "%.2f"), _fmt(c["ci95"][1], "%.2f")))
    L += ["", "| figure | vehicles | min | median | mean | 95th percentile | max |", "|---|---|---|---|---|---|---|"]
    for key, f in s["figures"].items():
        L.append("| %s (%s) | %d | %s | %s | %s | %s | %s |" % (f["what"], f["unit"], f["n"], _fmt(f.get("min")),
                                                               _fmt(f.get("median")), _fmt(f.get("mean")),
                                                               _fmt(f.get("p95")), _fmt(f.get("max"))))
    L += ["", "A filter's NEES share over the population is the mean row (the runs are equally long: the share of "
          "all the vehicles' seconds in the band)."]
    L += ["", "Worst vehicles (replay one with `fps adcs bps --world flight --spacecraft %s --vehicle %s --seed N "
          "--orbits %g --truth %s --ts %g%s%s`):" % (s["spacecraft"]["source"], s["vehicle"], s["orbits"], s["truth"],
                                                     s["ts_s"], " --satb-gnss" if s["satb_gnss"] else "",
                                                     "" if accel == "white" else " --stkf-accel " + accel), "",
          "| seed | every check | worst 3σ pointing (arcsec) | missed |", "|---|---|---|---|"]
    for w in s["worst"]:
        L.append("| %d | %s | %s | %s |" % (w["seed"], "met" if w["ok"] else "MISSED",
                                            _fmt(w["figures"].get("pointing_3sigma_arcsec"), "%.1f"),
                                            "; ".join(w["missed"]) or "—"))
    for f in s["failures"]:
        L.append("\nRun seed %d failed (a miss of every check above): %s" % (f["seed"], f["error"]))
    return "\n".join(L) + "\n"


def plot_cdf(path, results, s):
    """Each figure's CDF over the vehicles with its budget as a vertical line where the checks give one (the
    requirement holds for every vehicle where the curve reaches 1 left of it; the NEES's goal: where it is still
    0 left of it), the count within it in the panel's title."""
    from ground import plots as gp
    req = s["requirements"]
    budgets = {"pointing": req["body_pointing_3sigma_arcsec"], "stability": req["body_stability_3sigma_arcsec_s"]}
    good = [r for r in results if r and "error" not in r]
    fig, axs = gp.subplots(2, 3, width=13, row_height=3.0)
    for ax, (key, unit, check, what) in zip(axs.ravel(), FIGURES):
        v = np.sort([r["figures"][key] for r in good if r["figures"].get(key) is not None])
        if len(v):
            ax.step(np.concatenate([[v[0]], v]), np.arange(0, len(v) + 1) / len(v), where="post",
                    label="CDF over %d vehicles" % len(v))
        ax.set_ylim(0, 1.02)
        lim = budgets.get(check)
        if check == "wheels" and good:
            lim = req["wheel_speed_share"] * good[0]["wheel_speed_limit_rpm"]
        if key.endswith("nees_in_band_share"):
            ax.axvline(NEES_GOAL, color="g", ls=":", label="consistent: >= %.2f" % NEES_GOAL)
            ax.set_title("%d of %d at or above the goal" % (np.sum(v >= NEES_GOAL), len(v)), fontsize=8)
        if lim is not None:
            ax.axvline(lim, color=gp.REQUIREMENT_COLOR, ls="--", label="budget %g %s" % (lim, unit))
            ax.set_xlim(min(ax.get_xlim()[0], 0), max(ax.get_xlim()[1], 1.1 * lim))
            ax.set_title("%d of %d within the budget" % (np.sum(v <= lim), len(v)), fontsize=8)
        ax.set_xlabel("%s (%s)" % (what, unit), fontsize=8)
        ax.set_ylabel("share of vehicles (-)")
        gp.legend(ax, loc="lower right", fontsize=7)
    fig.suptitle("%s: %d vehicles, %g orbits; each requirement holds where its CDF reaches 1 left of the red "
                 "budget" % (s["spacecraft"]["name"], len(good), s["orbits"]), fontsize=10)
    fig.tight_layout()
    gp.save_png(fig, path, dpi=90)


def run(a):
    """The command (``register``); returns the exit code: 0 every vehicle met every check, 3 some missed (a vehicle
    whose run failed, its cause in the report, misses every check), 130 interrupted (the finished runs kept: run
    it again to resume)."""
    from ground.adcs import bps_cli, campaign
    from ground.adcs.options import check_stkf_accel, load_spacecraft
    from ground.adcs.runs import spacecraft_record
    from protocol import spacecraft as sf
    seeds = campaign.seeds_for(a.seed, a.runs)
    if a.scheduler is None:
        campaign.check_workers(a.workers)
    campaign.check_scheduler(a.scheduler)
    stkf_accel = check_stkf_accel(a.stkf_accel, "flight", a.truth)
    d, source = load_spacecraft(a.spacecraft, partner=True, flight=True)
    duration = bps_cli.orbits_duration(d, a.orbits)
    out = a.output
    identity = {"format": "fps-adcs-campaign/1", "spacecraft": spacecraft_record(d, source), "vehicle": a.vehicle,
                "seeds": seeds, "orbits": float(a.orbits), "truth": a.truth, "ts_s": float(a.ts),
                "satb_gnss": bool(a.satb_gnss), "stkf_accel": stkf_accel, "requirements": sf.requirements(d)}
    _open_folder(out, identity)
    kept = _finished(out, seeds)
    todo = [i for i, r in enumerate(kept) if r is None]
    if kept and len(todo) < len(seeds):
        print("resuming: %d of %d vehicles already flown in %s" % (len(seeds) - len(todo), len(seeds), out),
              file=sys.stderr)
    results, interrupted = list(kept), False
    kw = dict(spacecraft=d, vehicle=a.vehicle, orbits=a.orbits, truth=a.truth, ts=a.ts, satb_gnss=a.satb_gnss,
              cache_dir=os.path.abspath(os.path.join(out, "cache")), stkf_accel=stkf_accel)
    bps_cli.prepare_truth(a, duration, kw["cache_dir"], d)
    try:
        if todo:
            part = campaign.run_campaign(run_vehicle, [seeds[i] for i in todo], out, workers=a.workers,
                                         scheduler=a.scheduler, progress=not a.quiet, desc="vehicles",
                                         dirs=[campaign.run_dir_for(out, i) for i in todo], **kw)
            for i, r in zip(todo, part):
                results[i] = r
    except KeyboardInterrupt:
        interrupted = True
        results = _finished(out, seeds)
    vt = {"file": "its truth block, or drawn from each seed without one", "drawn": "drawn from each seed",
          "nominal": "the file's figures"}[a.vehicle]
    s = aggregate(results, dict(identity, runs=len(seeds), vehicle_text=vt))
    s["complete"] = not interrupted and all(r is not None for r in results)
    write_json(os.path.join(out, "summary.json"), s)
    if not a.no_plots and s["runs_done"]:
        plot_cdf(os.path.join(out, FIGURE), results, s)
    text = report_md(s)
    write_atomic(os.path.join(out, "report.md"), text)
    print(text)
    close(out)
    if interrupted:
        print("interrupted: %d of %d vehicles flown; run the same command again to resume" % (s["runs_done"],
                                                                                             len(seeds)),
              file=sys.stderr)
        return 130
    return 0 if s["all_checks"]["met"] == s["all_checks"]["of"] else 3      # a failed vehicle is a miss


def _finished(out, seeds):
    """Each run's result.json in the folder ``out`` where it is that seed's, None where the run is still to fly."""
    from ground.adcs import campaign
    return [r if r is not None and r.get("seed") == s else None
            for r, s in zip(campaign.finished_results(out, len(seeds)), seeds)]


def _open_folder(out, identity):
    """Make the campaign folder, or reopen it to resume the same campaign; ValueError for another's."""
    from ground.adcs import campaign
    path = os.path.join(out, "campaign.json")
    if os.path.exists(path):
        try:
            with open(path) as f:
                old = json.load(f)
        except (OSError, ValueError) as exc:
            raise ValueError("%s: cannot read the campaign it holds (%s): use a new -o" % (path, exc)) from None
        if isinstance(old, dict):
            old.setdefault("stkf_accel", "white")           # a campaign.json without the key flew white
        if old != json.loads(json.dumps(identity)):
            diff = sorted(k for k in set(old) | set(identity) if old.get(k) != json.loads(json.dumps(identity)).get(k))
            raise ValueError("-o %s holds another campaign (it differs in %s): use a new -o, or the same options "
                             "to resume it" % (out, ", ".join(diff)))
        return
    campaign.campaign_folder(out, (FIGURE,), {"complete": False})
    write_json(path, identity)


def register(sub):
    from emulator.spacecraft.dispersion import VEHICLES
    from ground.adcs.options import _presets, add_satb_gnss_option, add_stkf_accel_option, add_workers_options
    from ground.fileio import output_folder
    p = sub.add_parser("campaign", help="the flight world over a population of vehicles drawn from one spacecraft "
                                        "file", description=__doc__.split("\n\n")[0] + "\n\n" + __doc__.split("\n\n")[1])
    p.add_argument("--spacecraft", default=None, metavar="NAME|FILE",
                   help="a preset (%s) or a spacecraft file with a partner and magnetorquers (default thesis-3u)"
                        % ", ".join(_presets()))
    p.add_argument("--vehicle", default="drawn", choices=VEHICLES,
                   help="each run's vehicle: drawn (default) = drawn from its seed within the file's uncertainty "
                        "block; file = the file's truth block (drawn without one); nominal = the figures")
    p.add_argument("--runs", type=int, default=20, help="vehicles, >= 1 (default 20)")
    p.add_argument("--seed", type=int, default=0, help="first seed; vehicle i is seed + i (default 0)")
    p.add_argument("--orbits", type=float, default=3.0, help="orbits flown per vehicle, (0, 100] (default 3; the "
                   "checks count the passes after the first)")
    p.add_argument("--ts", type=float, default=33.0, help="settling time t_s of the attitude loop, s (default 33)")
    add_satb_gnss_option(p, False)
    p.add_argument("--truth", choices=("two-body", "hpop"), default="two-body",
                   help="orbit truth: two-body (default) or hpop (brahe's high-fidelity orbits, computed once)")
    add_stkf_accel_option(p, "with --truth hpop")
    add_workers_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("-o", "--output", required=True, type=output_folder,
                   help="campaign folder (run it again with the same options to resume)")
    p.set_defaults(func=run)
