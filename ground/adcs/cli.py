"""``fps adcs``: the ADCS: attitude filter campaigns (APKF, MEKF; Yoon 2017, Ch. 4), the STKF (Ch. 5), the body
pointing simulator and its settling-time sweep (Ch. 6; --world thesis or flight) and the flight firmware on CAN.

Each sub-command is registered by one small function in ``SUBCOMMANDS`` (add yours there); the options they
share are in ``ground.adcs.options``.

A campaign runs
``--runs`` seeds (``--seed``, ``--seed``+1, ...) of the Sec. 4.8 scenario over local worker processes
(``--workers``, default all cores; 1 = in-process) or an existing Dask cluster (``--scheduler tcp://host:port``),
and writes to ``-o DIR``: ``run_NNNN/`` per seed (series.npz, result.json), ``summary.json`` (physical units
named in each key: arcsec, deg, kg m^2, A m^2; ``complete`` is false until the campaign ends, and stays false
after Ctrl-C; a run that diverged has ``ok`` false and null figures and is counted in ``runs_diverged``),
``report.md`` (the verdict: the runs; the thesis's table beside ours, a reference), ``fig4-5_errors.png`` (one
run's errors with +-3 sigma) and ``monte_carlo.png`` (spread over runs and the NEES against its 95 % band). Exit 1
if a run failed or diverged; the thesis's figures are a reference, not a requirement (exit 0 within them or not).
"""

import os
import sys

from ground import verdict
from ground.adcs import apkf, campaign, runs
from ground.adcs.apkf_disturbance import DISTURBANCES, shaping
from ground.adcs.options import add_campaign_options, load_spacecraft
from ground.fileio import output_folder, write_json


def run_filter_campaign(fn, name, case, a, dof=6, options=None):
    """Run the campaign, write the folder, print the table; returns the exit code. ``options``: further keyword
    arguments of ``fn`` (recorded in config.json and summary.json)."""
    options = options or {}
    seeds = campaign.seeds_for(a.seed, a.runs)
    n = len(seeds)
    if a.scheduler is None:
        campaign.check_workers(a.workers)
    params = runs.load_params(a.params) if a.params else None
    spacecraft, source = load_spacecraft(a.spacecraft, params)
    out = a.output
    campaign.check_scheduler(a.scheduler)
    from ground.adcs import report
    campaign.campaign_folder(out, report.FIGURES, {"filter": name, "case": case, "runs": 0, "complete": False,
                                                   "seeds": seeds})
    write_json(os.path.join(out, "config.json"), {"filter": name, "case": case, "runs": n, "seed": a.seed,
                                                  "workers": a.workers, "scheduler": a.scheduler, "params": params,
                                                  "spacecraft": runs.spacecraft_record(spacecraft, source), **options})
    interrupted = False
    try:
        results = campaign.run_campaign(fn, seeds, out, workers=a.workers, scheduler=a.scheduler,
                                        progress=not a.quiet, desc="%s case %d" % (name, case),
                                        case=case, params=params, spacecraft=spacecraft, **options)
    except KeyboardInterrupt:
        interrupted = True
        results = [runs.load_run(campaign.run_dir_for(out, i)) for i in range(n)]
    summary = runs.aggregate(results, name, case, dof=dof)
    summary["complete"] = not interrupted
    summary["seeds"] = seeds
    summary["runs_requested"] = n
    summary["spacecraft"] = runs.spacecraft_record(spacecraft, source)
    summary.update(options)
    summary["per_run"] = [runs.run_record(r) for r in results if r]
    write_json(os.path.join(out, "summary.json"), summary)
    report.write_all(out, results, summary, plots=not a.no_plots)
    if interrupted:
        print("interrupted: %d of %d runs done, partial campaign in %s (summary complete=false)"
              % (summary["runs"], n, out), file=sys.stderr)
        return 130
    print(report.table(summary))
    print()
    verdict.close(out)
    for f in summary["failures"]:
        print("fps adcs %s: run seed %d failed: %s" % (name, f["seed"], f["error"]), file=sys.stderr)
    for f in summary["diverged"]:
        if not any(g["seed"] == f["seed"] for g in summary["failures"]):
            print("fps adcs %s: run seed %d diverged: %s" % (name, f["seed"], f["why"]), file=sys.stderr)
    return 1 if summary["runs_failed"] or summary["runs_diverged"] else 0


def _apkf(sub):
    p = sub.add_parser("apkf", help="APKF (gyroless, 41 error states) over the Sec. 4.8 scenario",
                       description="APKF Monte Carlo over the Sec. 4.8 scenario (930 s, 1 Hz star tracker "
                                   "20/20/60 arcsec, tachometers 10 rpm). " + __doc__.split("\n\n")[2])
    add_campaign_options(p)
    p.add_argument("--filter", dest="form", choices=apkf.FORMS, default="consistent",
                   help="consistent (default): the first star-tracker output after a blind stretch through an "
                        "iterated update over the stretch, faded when its innovation fails a chi-square test "
                        "(0.999, 3 dof), the second-order terms of the wheels' axes and of the dipole's torque "
                        "with an attitude error, R inflated in the first maneuver set only, that set filtered "
                        "again at its end with the parameters linearised at its own estimate (no fictitious noise "
                        "after it), Case 2's q_d matched to its disturbance; thesis: Eq. 4.139-4.142 and Sec. 4.7.4 as written "
                        "(reproduces the thesis's tables; its 1 sigma is overconfident: docs/ADCS.md, "
                        "\"Attitude determination\")")
    p.add_argument("--disturbance", choices=DISTURBANCES, default="white",
                   help="the filter's model of the disturbance torque tau_d (N m): white (default), the thesis's "
                        "random walk; markov, a first-order Gauss-Markov state (sigma, N m, and correlation time, "
                        "s, from the case's disturbance); harmonic, a damped oscillator at Case 2's sine periods "
                        "(s; Case 2 only); gradient, the torque's slope on the attitude (N m/rad, 9 states; Case 3 "
                        "only): docs/ADCS.md, \"Disturbance models\"")
    p.set_defaults(func=_run_apkf)


def _run_apkf(a):
    if a.disturbance != "white":
        shaping(a.case, a.disturbance)            # ValueError (exit 2): a form the case has no figures for
    return run_filter_campaign(runs.run_apkf, "apkf", a.case, a,
                               options={"form": a.form, "vehicle": a.vehicle, "disturbance": a.disturbance})


def _mekf(sub):
    p = sub.add_parser("mekf", help="6-state MEKF with a MEMS gyro (baseline, Sec. 4.4.1)",
                       description="MEKF baseline: MEMS gyro (ARW 3 deg/sqrt(h), bias 1 deg/h, instability "
                                   "0.05 deg/h) + star tracker over the Sec. 4.8 scenario. "
                                   + __doc__.split("\n\n")[2])
    add_campaign_options(p)
    p.set_defaults(func=lambda a: run_filter_campaign(runs.run_mekf, "mekf", a.case, a,
                                                      options={"vehicle": a.vehicle}))


def _stkf(sub):
    from ground.adcs import stkf_cli
    stkf_cli.register(sub, "stkf", "satellite tracking KF with the EAFLS for SatB's delayed GNSS (Sec. 5.5)")


def _bps(sub):
    from ground.adcs import bps_cli
    bps_cli.register_bps(sub)


def _sweep(sub):
    from ground.adcs import bps_cli
    bps_cli.register_sweep(sub)


def _can(sub):
    from ground.adcs import can_cli
    can_cli.register(sub)


def _campaign(sub):
    from ground.adcs import population
    population.register(sub)


SUBCOMMANDS = [_apkf, _mekf, _stkf, _bps, _sweep, _can, _campaign]


def register(sub, name, help_):
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0])
    s = p.add_subparsers(dest="adcs_command", metavar="COMMAND")
    for add in SUBCOMMANDS:
        add(s)

    def usage(a):
        p.print_help()
        return 2
    p.set_defaults(func=usage)
