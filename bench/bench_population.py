"""The flight world over populations of drawn vehicles: ``fps adcs campaign`` (3 orbits, brahe's high-fidelity
orbits, each vehicle drawn from its seed within its file's ``uncertainty`` block, calibrated, then flown by the
flight code) for each preset, with the share of vehicles meeting every check and its 95 % interval beside the goal
(at least 95 % of 100 vehicles a preset), each check's share, the filters' NEES over the population and whether
every miss has a named cause (a run's ``causes``, or the error that stopped it).

``BENCH_POPULATION_VEHICLES`` sets the vehicles a preset (default 100: 10-16 min of 2 cores a preset),
``BENCH_POPULATION_PRESETS`` the presets (comma-separated; default all three)."""

import json
import os
import subprocess
import sys
import tempfile

from bench import verdict

PRESETS = tuple(os.environ.get("BENCH_POPULATION_PRESETS", "thesis-3u,generic-6u,generic-12u").split(","))
VEHICLES = int(os.environ.get("BENCH_POPULATION_VEHICLES", "100"))
ORBITS = 3
GOAL = 0.95                       # of the vehicles, every check met
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def spacecraft_file(name, folder):
    """Preset ``name`` as a file in ``folder``, with a partner 10° behind it in its own orbit where it ships
    without one (``bps.with_partner``: generic-12u points at a ground station), as ``bench_flight`` flies it."""
    from ground.adcs import body_pointing as bps
    from protocol import spacecraft as sf
    d = sf.load(name)
    if d["partner"] is None:
        d = bps.with_partner(d)
    path = os.path.join(folder, name + ".json")
    with open(path, "w") as f:
        json.dump(d, f)
    return path


def campaign(name, out, vehicles=VEHICLES):
    """``fps adcs campaign`` of ``vehicles`` drawn from preset ``name`` (``spacecraft_file``) into ``out``: its
    summary.json and each run's result.json (None for a run that wrote none)."""
    os.makedirs(out)
    cmd = [sys.executable, "-m", "ground.cli", "adcs", "campaign", "--spacecraft",
           spacecraft_file(name, out), "--vehicle", "drawn",
           "--runs", str(vehicles), "--orbits", str(ORBITS), "--truth", "hpop", "--quiet", "--no-plots", "-o",
           os.path.join(out, "campaign")]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if p.returncode not in (0, 3):                 # 3: a check missed, the campaign itself ran
        raise RuntimeError("fps adcs campaign (%s) exited %d: %s" % (name, p.returncode, p.stderr[-1500:]))
    with open(os.path.join(out, "campaign", "summary.json")) as f:
        s = json.load(f)
    results = []
    for i in range(vehicles):
        path = os.path.join(out, "campaign", "run_%04d" % i, "result.json")
        results.append(json.load(open(path)) if os.path.exists(path) else None)
    return s, results


def unexplained(results):
    """The seeds of the vehicles that missed with no named cause: neither a run's ``causes`` nor its error."""
    return [r["seed"] for r in results if r and "error" not in r and not r["ok"] and not r.get("causes")]


def row(name, s, results):
    a = s["all_checks"]
    lo, hi = a["ci95"]
    f = s["figures"]
    nees = ["%.3f" % f[k]["mean"] if f.get(k, {}).get("n") else "-"
            for k in ("apkf_nees_in_band_share", "stkf_nees_in_band_share")]
    missing = unexplained(results)
    checks = "; ".join("%s %d" % (k, c["met"]) for k, c in sorted(s["checks"].items()))
    return "| %s | %d of %d (%.2f, 95 %%: %.2f-%.2f) | >= %.2f |%s | %s | %s | %d failed; %s |" % (
        name, a["met"], a["of"], a["share"], lo, hi, GOAL, verdict(a["share"], GOAL, at_most=False), checks,
        " / ".join(nees),
        s["runs_failed"], "every miss named" if not missing else "no cause named for seeds %s" % missing)


def main():
    print("Flight world over drawn vehicles (fps adcs campaign, %d orbits, hpop truth, %d vehicles a preset):\n"
          % (ORBITS, VEHICLES))
    print("| preset | vehicles meeting every check (share, 95 % interval) | goal | met | vehicles meeting each check "
          "| APKF / STKF NEES in band, mean over the vehicles | failed runs; causes |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in PRESETS:
            s, results = campaign(name, os.path.join(tmp, name))
            print(row(name, s, results), flush=True)


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
