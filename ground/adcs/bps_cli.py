"""``fps adcs bps`` and ``fps adcs sweep``: the body pointing simulator of Sec. 6.4 (``ground.adcs.body_pointing``).

``bps``: one pointing-and-tracking run. Without ``--params`` the nine calibration maneuver sets run first (or
come from the cache) and their parameter file is written to ``DIR/params.json``. Run folder (atomic writes):
``summary.json`` (pointing_mean_arcsec [2], pointing_sigma_arcsec [2], stability_mean_arcsec_s [2],
stability_sigma_arcsec_s [2], pointing_3sigma_arcsec, stability_3sigma_arcsec_s, complete; plus the thesis's
figures, the budgets and J), ``history.npz`` (10 Hz: t, q, w, w_rel, dtheta_arcsec, domega_arcsec_s; 1 Hz
fsw_*), ``report.md`` (thesis table beside ours), ``fig6-3_pointing.png`` (``fig6-4`` with SatB's GNSS).
The 3 sigma figures are 3 sqrt(s1^2 + s2^2) (the two axes in total) against 150 arcsec and 35 arcsec/s; a run
that misses them exits 3. Ctrl-C leaves the folder with complete=false (exit 130). Both worlds add ``world``,
``wheel_speed_limit_rpm``, ``star_tracker_blind_share`` and ``mode_changes`` [{t_s, from, to, reason}]. With
``--world flight`` the 3 sigma figures are over the POINT samples of the orbits after the first (``passes``
gives each orbit's), ``max_wheel_speed_rpm`` is over the same span (``max_wheel_speed_rpm_run``: the whole
run's), and ``checks`` (each pass within the budgets, the wheels within 80 % of their limit, the star tracker
blind < 10 % of the time after the first slew) decide the exit status; report.md and ``flight_pointing.png``,
``flight_wheels.png`` show them. A run whose line of sight to the partner the Earth blocks throughout its pointing
window (``line_of_sight`` false in the result: ``ground.adcs.occultation``) exits 3 whatever its figures.

``sweep``: J = E[eps^T W eps] (Eq. 6.22-6.24) for each t_s, the calibration computed once and shared; with
SatB's GNSS as Sec. 6.4.3 (``--no-satb-gnss`` to leave it out). ``summary.json``: ts_s, J, ts_best_s,
complete; ``fig6-2_sweep.png``; ``run_NNNN/result.json`` per t_s. ``--objective terminal`` (Sec. 8.3): the same
runs, each body error also passed through the fine loop's sensitivity |S| (``--rejection``: its model, or an ``fps
response`` summary.json), t_s chosen by the residual's 3 sigma (arcsec) after the fine loop
(``ground.adcs.terminal_tuning``); the summary adds residual_sigma_arcsec, residual_3sigma_arcsec, the body 3 sigma
figures per t_s, ts_best_body_s, ts_best_terminal_s (= ts_best_s), ts_best_terminal_in_budget_s (among the t_s
within the body budgets); ``fig6-2_objectives.png`` shows both objectives. ``--zeta Z1,Z2,...``: the PD's
damping ratios (Eq. 6.6; default the thesis's 1 alone), the sweep over the (t_s, zeta) grid (``ts_s`` and ``zeta``
per point, ``zeta_values``, each best's zeta beside its t_s; with the terminal objective ``by_zeta``), one curve
per zeta in the figures.
"""

import hashlib
import json
import os
import sys
import time

import numpy as np

from emulator.spacecraft import scenario
from ground import verdict
from ground.adcs import body_pointing as bps, campaign, flight_world, runs, terminal_tuning
from ground.adcs.bps_report import (FIGURES_FLIGHT, plot_flight, plot_history, plot_objectives, plot_sweep,
                                    report_flight_md, report_md)
from ground.adcs.options import (add_satb_gnss_option, add_session_option, add_spacecraft_option,
                                add_stkf_accel_option, check_session, check_stkf_accel, fly, load_spacecraft)
from ground.adcs.params import check_params
from ground.fileio import cache_folder, output_folder, run_folder, write_atomic, write_json
from protocol import spacecraft as sf

CACHE_DEFAULT = os.path.join("out", "bps_cache")
FIGURES_BPS = ("fig6-3_pointing.png", "fig6-4_pointing.png")    # without / with SatB's GNSS, as the thesis's
FIGURE_SWEEP = "fig6-2_sweep.png"
BLIND_MAX = 0.10        # and the star tracker is blind less than this share of the time after the first slew
VERSION = 8          # bump when the simulator's results change: old cache entries stop matching


MAX_SWEEP_POINTS = 1000


def parse_ts_range(text):
    """'10:100:5' -> [10, 15, ..., 100]; a single number -> [x]. Every t_s in (0, bps.MAX_TS_S], at most
    ``MAX_SWEEP_POINTS`` of them."""
    parts = str(text).split(":")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise ValueError("--ts must be START:STOP:STEP or a number (s), got %r" % (text,)) from None
    if len(vals) == 1:
        out = vals
    elif len(vals) == 3 and vals[2] > 0 and vals[1] >= vals[0]:
        for v in vals[:2]:
            bps.check_ts(v)
        n = int(np.floor((vals[1] - vals[0]) / vals[2] + 1e-9)) + 1
        if n > MAX_SWEEP_POINTS:
            raise ValueError("--ts %r gives %d t_s values; at most %d (raise STEP)" % (text, n, MAX_SWEEP_POINTS))
        out = list(np.arange(vals[0], vals[1] + 1e-9 * max(1.0, vals[2]), vals[2]))
    else:
        raise ValueError("--ts must be START:STOP:STEP with STEP > 0 and STOP >= START, got %r" % (text,))
    for v in out:
        bps.check_ts(v)
    return [float(v) for v in out]


def check_run_args(a):
    if a.duration is None:
        a.duration = 4000.0
    campaign.check_duration(a.duration)
    campaign.check_seed(a.seed)


def _key(d):
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def spacecraft_key(d):
    """What a cache key holds of the checked spacecraft file ``d``: {"spacecraft": its hash}, nothing for thesis-3u
    (so that the keys, and the bps distfiles' headers, stay what they were before the file)."""
    h = runs.spacecraft_record(d, None)["sha256"]
    return {} if h == runs.spacecraft_record(scenario.thesis_3u(), None)["sha256"] else {"spacecraft": h}


def calibration(seed, cache_dir, progress=True, spacecraft=None):
    """The parameter-file dict of the nine calibration sets for ``seed`` flown by the checked spacecraft file
    ``spacecraft`` (None: thesis-3u), from ``cache_dir`` when present (keyed by the file's hash too; written
    atomically: the cache holds whole entries only; a damaged entry, not ours or edited, is computed again and
    replaced). ValueError naming the key when the calibration's result is outside the parameter file's ranges."""
    d = spacecraft or scenario.thesis_3u()
    key = _key(dict(spacecraft_key(d), kind="calibration", seed=int(seed), sets=bps.CAL_SETS, version=VERSION))
    path = os.path.join(cache_dir, "calibration_%s.json" % key) if cache_dir else None
    if path and os.path.exists(path):
        try:
            return bps.load_params(path, d)[-1]
        except ValueError as exc:                 # unreadable, not JSON, or not a parameter file
            print("calibration cache %s is damaged (%s): computing it again" % (path, exc), file=sys.stderr)
    if progress:
        print("calibration: %d maneuver sets through the APKF (seed %d) ..." % (bps.CAL_SETS, seed),
              file=sys.stderr)
    p = bps.calibrate(seed=seed, progress=progress, spacecraft=d)
    check_params(p, "the calibration of seed %d left the parameter file's ranges (it failed on this vehicle)"
                 % seed, d)
    if path:
        os.makedirs(cache_dir, exist_ok=True)
        write_json(path, p)
    return p


def prepare_truth(a, duration, out, spacecraft):
    """``--truth hpop``: the orbit truth for a run of ``duration`` s computed once into ``out``, before workers."""
    if a.truth == "hpop":                             # once, before workers
        scenario.orbit_truth("hpop", bps.truth_span(int(np.ceil(duration))), scenario.orbit_setup(spacecraft), out)


def _vehicle(a):
    """(checked spacecraft file with the vehicle flown, its record, the --params dict or None) of the command's
    options (``--vehicle``: the file's truth block, or drawn from ``--seed``)."""
    d, source = load_spacecraft(a.spacecraft, partner=True, flight=getattr(a, "world", None) == "flight")
    d, record = fly(d, source, a.seed, a.vehicle)
    return d, record, bps.load_params(a.params, d)[-1] if a.params else None


def orbits_duration(d, orbits):
    """``orbits`` orbits of the checked spacecraft file ``d``'s orbit, in s; ValueError naming --orbits outside
    (0, 100]."""
    if not (np.isfinite(orbits) and 0 < orbits <= 100):
        raise ValueError("--orbits must be in (0, 100], got %r" % (orbits,))
    return orbits * bps.orbit_period(scenario.orbit_setup(d)["x0s"][0])


def _check_length(a):
    """ValueError for a length the world does not take: --duration (the window collected after the settling) in
    the flight world, whose figures are per pointing pass; --session (the whole run) in the thesis world."""
    if a.world == "flight" and a.duration is not None:
        raise ValueError("--duration %g: --duration is the window collected after the settling, and the flight "
                         "world's figures are per pointing pass after the first orbit: give the run's length as "
                         "--orbits N or --session S (the whole run in seconds)" % a.duration)
    if a.world == "thesis" and a.session is not None:
        raise ValueError("--session %g: --session is the flight world's whole run (--world flight); the thesis "
                         "world's length is --duration S, the seconds collected after the 30 s hold and 4 t_s"
                         % a.session)


def judge_flight(s):
    """The flight world's verdict into the result ``s``: its ``checks`` (``flight_checks``) and ``budgets_met``
    (complete, every check met and the partner in sight)."""
    s["checks"] = flight_checks(s)
    s["budgets_met"] = bool(s["complete"] and all(c["ok"] for c in s["checks"].values())
                            and s.get("line_of_sight", True))
    return s


def flight_checks(s):
    """The flight world's requirements of one run (``fps adcs bps --world flight``), each {"ok", "what", "ours",
    "budget"}:
    every pointing pass after the first orbit within the 3 sigma budgets, the wheels within their share of their
    speed limit after the first orbit, the star tracker blind less than ``BLIND_MAX`` of the time after the first
    slew, and at least one pass collected."""
    req = s.get("requirements") or sf.requirements(None)
    pb, wb, band = (req["body_pointing_3sigma_arcsec"], req["body_stability_3sigma_arcsec_s"],
                    req["wheel_speed_share"])
    passes = [p for p in s.get("passes") or [] if p.get("pointing_3sigma_arcsec") is not None]
    lim = s["wheel_speed_limit_rpm"]
    blind = s.get("star_tracker_blind_share")
    wmax = s.get("max_wheel_speed_rpm")
    worst = {k: max((p[k] for p in passes), default=None) for k in ("pointing_3sigma_arcsec",
                                                                     "stability_3sigma_arcsec_s")}
    return {
        "passes": {"ok": bool(passes), "what": "%d pointing pass(es) after the first orbit" % len(passes),
                   "ours": len(passes), "budget": ">= 1"},
        "pointing": {"ok": bool(passes) and all(p["pointing_3sigma_arcsec"] <= pb for p in passes),
                     "what": "every pass's 3σ pointing <= %g arcsec" % pb,
                     "ours": worst["pointing_3sigma_arcsec"], "budget": pb},
        "stability": {"ok": bool(passes) and all(p["stability_3sigma_arcsec_s"] <= wb for p in passes),
                      "what": "every pass's 3σ stability <= %g arcsec/s" % wb,
                      "ours": worst["stability_3sigma_arcsec_s"], "budget": wb},
        "wheels": {"ok": wmax is not None and wmax <= band * lim,
                   "what": "wheels <= %.0f %% of %.0f rpm after the first orbit" % (100 * band, lim),
                   "ours": wmax, "budget": band * lim},
        "star_tracker": {"ok": blind is not None and blind < BLIND_MAX,
                         "what": "star tracker blind < %.0f %% of the time after the first slew"
                         % (100 * BLIND_MAX), "ours": blind, "budget": BLIND_MAX},
    }


def _cmd_bps(a):
    ts = bps.check_ts(a.ts)
    zeta = None if a.zeta is None else terminal_tuning.check_zeta(a.zeta)
    if a.estimator is not None and a.world != "flight":
        raise ValueError("--estimator is the flight world's (--world flight); the thesis world flies the ground's "
                         "41-state APKF and full STKF")
    stkf_accel = check_stkf_accel(a.stkf_accel, a.world, a.truth, a.estimator)
    _check_length(a)
    d, record, params = _vehicle(a)
    if a.world == "flight":                  # the whole run, not a collected window: --session or --orbits
        a.duration = orbits_duration(d, a.orbits) if a.session is None else check_session(a.session)
    check_run_args(a)
    out = a.output
    run_folder(out, FIGURES_BPS + FIGURES_FLIGHT)
    args_text = "fps adcs bps " + " ".join(sys.argv[3:])
    summary = {k: None for k in bps.SUMMARY_KEYS}
    summary.update(complete=False, ts_s=ts, satb_gnss=a.satb_gnss, spacecraft=record, world=a.world,
                   **({"stkf": {"accel": stkf_accel}} if a.world == "flight" else {}))
    write_json(os.path.join(out, "summary.json"), summary)
    try:
        if params is None:
            params = calibration(a.seed, a.cache_dir, not a.quiet, d)
        bps.write_params(os.path.join(out, "params.json"), params, d)
        prepare_truth(a, a.duration if a.world == "flight" else 30 + 4 * ts + a.duration, os.path.abspath(a.cache_dir),
                      d)
    except KeyboardInterrupt:
        print("interrupted before the pointing run: %s has complete=false" % out, file=sys.stderr)
        return 130
    try:
        res, hist = bps.simulate(ts=ts, satb_gnss=a.satb_gnss, duration_s=a.duration, seed=a.seed, params=params,
                                 truth=a.truth, cache_dir=os.path.abspath(a.cache_dir), progress=not a.quiet,
                                 spacecraft=d, world=a.world, estimator=a.estimator, zeta=zeta,
                                 stkf_accel=stkf_accel)
        res["requirements"] = sf.requirements(d)             # the budgets the verdict reads
        if a.world == "flight":
            return _finish_flight(a, out, res, hist, record, args_text)
    except FloatingPointError as exc:              # a filter or the truth diverged: the run ends, the folder says so
        summary["error"] = str(exc)
        write_json(os.path.join(out, "summary.json"), summary)
        print("fps adcs bps: the run failed: %s (%s has complete=false)" % (exc, out), file=sys.stderr)
        return 1
    bps.save_history(os.path.join(out, "history.npz"), hist)
    s = dict(res, spacecraft=record)
    s["thesis"] = {"pointing_sigma_arcsec": [v[1] for v in bps.THESIS[a.satb_gnss]["theta"]],
                   "stability_sigma_arcsec_s": [v[1] for v in bps.THESIS[a.satb_gnss]["omega"]],
                   "ts_s": bps.TS_THESIS}
    req = s["requirements"]
    pb, wb = req["body_pointing_3sigma_arcsec"], req["body_stability_3sigma_arcsec_s"]
    met = (s["pointing_3sigma_arcsec"] is not None and s["pointing_3sigma_arcsec"] <= pb
           and s["stability_3sigma_arcsec_s"] <= wb)
    s["budgets_met"] = bool(met and s["complete"] and s.get("line_of_sight", True))
    plots = []
    if not a.no_plots and len(hist["t"]) > 1:
        name = FIGURES_BPS[1 if a.satb_gnss else 0]
        plot_history(os.path.join(out, name), hist, s["settle_s"],
                     "Pointing error and stability, t_s = %g s, %s SatB's GNSS"
                     % (ts, "with" if a.satb_gnss else "without"), s)
        plots.append(name)
    s["plots"] = plots
    write_atomic(os.path.join(out, "report.md"), report_md(s, args_text))
    write_json(os.path.join(out, "summary.json"), s)
    print(report_md(s, args_text))
    verdict.close(out)
    if not s["complete"]:
        print("interrupted: partial run in %s (summary complete=false)" % out, file=sys.stderr)
        return 130
    if _no_line_of_sight(s):
        return 3
    if not s["budgets_met"]:
        print("BUDGET MISSED: 3σ pointing %.1f arcsec (limit %g), stability %.1f arcsec/s (limit %g)"
              % (s["pointing_3sigma_arcsec"], pb, s["stability_3sigma_arcsec_s"], wb), file=sys.stderr)
        return 3
    print("budgets met: 3σ pointing %.1f ≤ %g arcsec, stability %.1f ≤ %g arcsec/s"
          % (s["pointing_3sigma_arcsec"], pb, s["stability_3sigma_arcsec_s"], wb))
    return 0


def _no_line_of_sight(s):
    """True (and says so) when the Earth blocks the line of sight to the partner throughout the pointing window:
    the run's budgets cannot be met, whatever its figures."""
    o = s.get("occultation")
    if s.get("line_of_sight", True) or not o:
        return False
    print("NO LINE OF SIGHT: the line of sight to the partner passes within %g km of the Earth's surface throughout "
          "the %s; no budget is reported as met" % (o["margin_km"], "pointing window" if o["window_share"] is not None
                                                    else "run"), file=sys.stderr)
    return True


def _finish_flight(a, out, res, hist, record, args_text):
    bps.save_history(os.path.join(out, "history.npz"), hist)
    s = judge_flight(dict(res, spacecraft=record))
    plots = []
    if not a.no_plots and len(hist["t"]) > 10:
        plot_flight(out, hist, s)
        plots = list(FIGURES_FLIGHT)
    s["plots"] = plots
    text = report_flight_md(s, args_text)
    write_atomic(os.path.join(out, "report.md"), text)
    write_json(os.path.join(out, "summary.json"), s)
    print(text)
    verdict.close(out)
    if not s["complete"]:
        print("interrupted: partial run in %s (summary complete=false)" % out, file=sys.stderr)
        return 130
    if _no_line_of_sight(s):
        return 3
    missed = [c["what"] for c in s["checks"].values() if not c["ok"]]
    if missed:
        print("REQUIREMENT MISSED: " + "; ".join(missed), file=sys.stderr)
        return 3
    print("requirements met: " + "; ".join(c["what"] for c in s["checks"].values()))
    return 0


def sweep_summary(ts_list, results, complete, satb_gnss, zeta_list=None, zetas=None):
    """The sweep's summary: J per point (t_s, with a grid its ``zeta``: ``zeta_list`` per point, ``zetas`` the
    values) and its minimum."""
    J = [None if (r is None or "error" in r or r.get("J_rad2") is None or not r.get("complete", False))
         else r["J_rad2"] for r in results]
    i = terminal_tuning.best_index(J)
    s = {"ts_s": list(ts_list), "J": J, "ts_best_s": None if i is None else ts_list[i], "complete": bool(complete),
         "satb_gnss": satb_gnss, "ts_thesis_s": bps.TS_THESIS, "J_unit": "rad^2",
         "failures": [dict({"ts_s": t, "error": r["error"]}, **({} if zeta_list is None else {"zeta": zeta_list[n]}))
                      for n, (t, r) in enumerate(zip(ts_list, results)) if r is not None and "error" in r]}
    if zeta_list is not None:
        s.update(zeta=list(zeta_list), zeta_values=list(zetas), zeta_best_s=None if i is None else zeta_list[i])
    return s


def _cmd_sweep(a):
    zetas = terminal_tuning.parse_zeta_list(a.zeta)                  # None: the thesis's zeta = 1, no grid
    ts_list, zeta_list = terminal_tuning.grid(parse_ts_range(a.ts), zetas, MAX_SWEEP_POINTS)
    check_run_args(a)
    table = terminal_tuning.check_args(a.objective, a.rejection)     # None: the body objective
    if a.scheduler is None:
        campaign.check_workers(a.workers)
    d, record, params = _vehicle(a)
    out = a.output
    campaign.check_scheduler(a.scheduler)
    satb = a.satb_gnss
    campaign.campaign_folder(out, (FIGURE_SWEEP, terminal_tuning.FIGURE),
                             dict(sweep_summary(ts_list, [None] * len(ts_list), False, satb, zeta_list, zetas),
                                  spacecraft=record))
    t0 = time.perf_counter()
    complete = True
    try:
        if params is None:
            params = calibration(a.seed, a.cache_dir, not a.quiet, d)
        bps.write_params(os.path.join(out, "params.json"), params, d)
        prepare_truth(a, 30 + 4 * max(ts_list) + a.duration, os.path.abspath(a.cache_dir), d)
        fn, extra = (bps.sweep_one, {}) if table is None else (terminal_tuning.sweep_one, {"rejection": table})
        if zeta_list is not None:
            fn, extra = terminal_tuning.sweep_one, dict(extra, zeta_list=zeta_list)
        results = campaign.run_campaign(fn, list(range(len(ts_list))), out, workers=a.workers,
                                        scheduler=a.scheduler, progress=not a.quiet, desc="sweep t_s",
                                        ts_list=ts_list, params=params, satb_gnss=satb, duration_s=a.duration,
                                        noise_seed=a.seed, truth=a.truth, cache_dir=os.path.abspath(a.cache_dir),
                                        spacecraft=d, **extra)
    except KeyboardInterrupt:
        complete = False
        results = campaign.finished_results(out, len(ts_list))
    if any(r is not None and "error" not in r and not r.get("complete", True) for r in results):
        complete = False                                # a t_s cut short by Ctrl-C (in a worker)
    s = sweep_summary(ts_list, results, complete, satb, zeta_list, zetas)
    s["wall_s"] = time.perf_counter() - t0
    s["duration_s"] = a.duration
    s["spacecraft"] = record
    if table is not None:
        terminal_tuning.add_summary(s, results, table, sf.requirements(d))
    if not a.no_plots:
        plot_sweep(os.path.join(out, FIGURE_SWEEP), s)
        if table is not None:
            plot_objectives(os.path.join(out, terminal_tuning.FIGURE), s)
    lines = sweep_lines(s, record, a.duration, satb, complete)
    if table is not None:
        lines += terminal_tuning.report_lines(s)
    write_atomic(os.path.join(out, "report.md"), "\n".join(lines))
    write_json(os.path.join(out, "summary.json"), s)
    print("\n".join(lines))
    verdict.close(out)
    if not complete:
        print("interrupted: partial sweep in %s (summary complete=false)" % out, file=sys.stderr)
        return 130
    if s["failures"]:
        for f in s["failures"]:
            print("fps adcs sweep: t_s = %g s%s failed: %s" % (f["ts_s"], "" if "zeta" not in f else ", ζ = %g"
                                                              % f["zeta"], f["error"]), file=sys.stderr)
        return 1
    return 0


def sweep_lines(s, record, duration, satb, complete):
    """report.md's verdict (every t_s computed), the J table of the sweep (a ζ column on a grid) and its
    minimum."""
    zs = s.get("zeta")
    row = verdict.runs_row(sum(j is not None for j in s["J"]), len(s["J"]), "t_s points computed (none failed)")
    lines = ["# Settling-time sweep (Sec. 6.4.3)", "", "Spacecraft %s." % record["name"], ""]
    lines += verdict.table([row[:3] + (row[3] if complete else None,)]) + [
             "| t_s (s) |%s J (rad²) |" % ("" if zs is None else " ζ |"),
             "|---|---|" + ("" if zs is None else "---|")]
    lines += ["| %g |%s %s |" % (t, "" if zs is None else " %g |" % zs[n], "—" if j is None else "%.4e" % j)
              for n, (t, j) in enumerate(zip(s["ts_s"], s["J"]))]
    best = s.get("ts_best_body_s", s["ts_best_s"])
    if zs is not None and best is not None:
        best = "%s s, ζ = %g" % (best, s.get("zeta_best_body", s["zeta_best_s"]))
    else:
        best = "%s s" % best
    lines += ["", "minimum at t_s = %s (thesis: 33 s%s); %g s collected per t_s, %s SatB's GNSS; complete: %s"
              % (best, "" if zs is None else ", ζ = 1", duration, "with" if satb else "without", complete), ""]
    return lines


def _common(p, duration_help):
    """The options bps and sweep share; ``duration_help``: what --duration collects (its --help, %g the range)."""
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help=duration_help % campaign.MAX_DURATION_S)
    p.add_argument("--seed", type=int, default=0, help="noise seed, also the calibration's, 0 to "
                   "2**32 - 1 (default 0)")
    p.add_argument("--params", default=None, help="parameter file (JSON) from an earlier run's params.json, "
                   "checked against --spacecraft; default: run the nine calibration sets (cached)")
    add_spacecraft_option(p, "the true vehicle (inertia, dipole, wheels, star tracker), the orbits, epoch and "
                          "sensors of the world, the calibration maneuvers, the APKF's model and priors, the STKF's "
                          "P0, the controller's wheel limits and the laser axis from it")
    p.add_argument("--truth", choices=("hpop", "two-body"), default="hpop",
                   help="true orbits: brahe high-fidelity (default) or two-body (fast)")
    p.add_argument("--cache-dir", default=CACHE_DEFAULT, type=cache_folder,
                   help="calibration and truth cache (default %s)" % CACHE_DEFAULT)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("-o", "--output", required=True, type=output_folder, help="run folder")


def register_bps(sub):
    p = sub.add_parser("bps", help="body pointing simulator: pointing and tracking (Sec. 6.4)",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--ts", type=float, default=bps.TS_THESIS, help="settling time t_s in s, in (0, %g] "
                   "(default 33)" % bps.MAX_TS_S)
    add_satb_gnss_option(p, False)
    p.add_argument("--world", choices=bps.WORLDS, default="thesis",
                   help="thesis (default): Sec. 6.4's world, wheels without a limit in effect, no momentum "
                   "management, pointing from rest after a 30 s hold; flight: the spacecraft file's wheel speed "
                   "and torque limits, drag and solar pressure torques, magnetorquer unloading, a rate-limited "
                   "slew and re-acquisition; its figures are per pointing pass after the first orbit")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--orbits", type=float, default=3.0,
                   help="flight world: the run's length in orbits, (0, 100] (default 3)")
    add_session_option(g, None, "the slew and every orbit flown (flight world only, instead of --orbits), 1 to "
                       "%g (default: --orbits orbits)" % campaign.MAX_DURATION_S)
    p.add_argument("--zeta", type=float, default=None, metavar="Z",
                   help="the PD's damping ratio ζ (Eq. 6.6, dimensionless: D = 2 ζ wn J), finite and > 0 "
                   "(default 1, the thesis's)")
    p.add_argument("--estimator", choices=flight_world.ESTIMATORS, default=None,
                   help="flight world: the app's filters, lean (default: the lean APKF and STKF that fly) or "
                   "ground (the 41-state APKF and the full STKF, for analysis: the same modes, command and "
                   "allocation on their estimates)")
    add_stkf_accel_option(p, "--world flight with --truth hpop and the lean estimator")
    _common(p, "thesis world: the seconds collected at 10 Hz after the 30 s hold and 4 t_s of settling, the window "
            "the verdict judges, 1 to %g (default 4000); the flight world, judged per pointing pass, takes --orbits "
            "or --session instead")
    p.set_defaults(func=_cmd_bps)


def register_sweep(sub):
    p = sub.add_parser("sweep", help="settling-time sweep of the objective J (Sec. 6.4.3, Fig. 6-2)",
                       description=__doc__.split("\n\n")[2])
    p.add_argument("--ts", default="10:100:5", help="START:STOP:STEP in s, each t_s in (0, %g], "
                   "at most %d points (default 10:100:5, 19 points)" % (bps.MAX_TS_S, MAX_SWEEP_POINTS))
    add_satb_gnss_option(p, True)            # Sec. 6.4.3's sweep flies it
    p.add_argument("--objective", choices=terminal_tuning.OBJECTIVES, default="body",
                   help="body (default): t_s by J of the body pointing error (rad², Eq. 6.22); terminal: t_s by "
                   "the 3σ residual (arcsec) the body error leaves after the fine loop's sensitivity |S| "
                   "(Sec. 8.3), J reported beside it")
    p.add_argument("--rejection", default=None, metavar="model|FILE",
                   help="--objective terminal: the fine loop's |S|, model (default: ground.response's loop model "
                   "of the thesis bench, 637.8 Hz, g = 0.5) or an fps response run's summary.json (measured, "
                   "extended as |S| proportional to f below its lowest tone in Hz)")
    p.add_argument("--zeta", default=None, metavar="Z1,Z2,...",
                   help="the PD's damping ratios ζ (Eq. 6.6, dimensionless: D = 2 ζ wn J), each finite and > 0: "
                   "the sweep runs every (t_s, ζ) pair (default: 1 alone, the thesis's)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=None, help="local worker processes (default: CPU count; "
                   "1 = in-process)")
    g.add_argument("--scheduler", default=None, metavar="ADDR", help="Dask scheduler address (tcp://host:port)")
    _common(p, "the seconds collected at 10 Hz for each t_s after the 30 s hold and 4 t_s of settling, the window "
            "J is taken over, 1 to %g (default 4000)")
    p.set_defaults(func=_cmd_sweep)
