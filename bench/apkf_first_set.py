"""Where the APKF's first maneuver set is linearised, over drawn populations (``bench_adcs``'s cause-and-remedy
table for ``ground/adcs/apkf_iterated.py``).

Three filters on the same vehicles (Case 1, the consistent form, vehicle n drawn from seed n within a preset's
``uncertainty`` block), which differ only in where the first set's steps are linearised:

- "once": each step about the filter's own running estimate, the set filtered once (the EKF as it runs; the thesis's
  fictitious noise in both sets);
- "filtered again" (the default): then the set filtered again from x0, P0 with the parameters linearised at the
  first pass's end-of-set estimate, twice, and no fictitious noise (``apkf_iterated``);
- "at the truth" (a diagnostic no filter can fly): filtered once, the parameters linearised at the vehicle's true
  ones (in the filter's terms) through the first set, as "once" otherwise.

Per row: the attitude + rate NEES over the population after the first set (share of steps in its 95 % band, mean),
RMS error / 1 sigma per attitude and rate axis, the parameters' NEES (J5, m, the tilts, Jrw: 20 dof) at the first
set's end (mean and median over the vehicles), over the 23 parameters (tau_d too) the smallest share of vehicles
whose final error is within 3 sigma (as ``runs.aggregate``'s), and the runs that stopped (P not positive definite).
"""

import tempfile

import numpy as np

from bench.adcs_disturbance import _fmt
from ground.adcs import apkf, campaign, runs

VARIANTS = ("once", "filtered again", "at the truth")
NAMES = ("thesis-3u", "generic-6u", "generic-12u")
PARAMS = np.r_[9:29]


def run_first_set(seed, run_dir=None, name="thesis-3u", variant="filtered again"):
    """One drawn vehicle of ``name`` under ``variant`` (module docstring): {"seed", "nees" (per step, 6 dof),
    "z" (errors / 1 sigma, attitude and rate), "params_nees_first_set", "final_z_params"} or {"seed", "error"}."""
    from protocol import spacecraft as sf
    d = runs.fly_vehicle(sf.load(name), seed, "drawn")[0]
    o = runs._simulate(1, seed, None, gyro=False, spacecraft=d)
    k0, f = runs._start_apkf(o, 1, spacecraft=d)
    end = int(o["set_ends"][0])
    if variant != "filtered again":
        f.first_set_passes = 0
    if variant == "at the truth":
        tr = o["truth"]
        f.model.p_lin = np.concatenate([tr["J5"], tr["m"], tr["delta1"], tr["delta2"], tr["jrw"]])
    n = len(o["t"])
    nees, z, pn = np.full(n, np.nan), np.full((n, 6), np.nan), np.nan
    try:
        for k in range(k0, n):
            if k > k0:
                f.step(o["t"][k - 1], o["tach"][k], o["st_q"][k] if o["st_valid"][k] else None)
                apkf.check_covariance(f.P, o["t"][k])
            if k == end:
                f.model.p_lin = None
            e = runs.apkf_error(o, k, f.x, 1)
            nees[k] = runs._nees(e[0:6], f.P[0:6, 0:6])
            z[k] = e[0:6] / np.sqrt(np.diag(f.P)[0:6])
            if k == end:
                pn = runs._nees(e[PARAMS], f.P[np.ix_(PARAMS, PARAMS)])
    except FloatingPointError as exc:
        return {"seed": seed, "error": str(exc)}
    finally:
        f.model.p_lin = None
    return {"seed": seed, "end": end, "nees": nees, "z": z, "params_nees_first_set": pn,
            "final_z_params": e[6:29] / np.sqrt(np.diag(f.P)[6:29])}


def row_figures(results):
    """The row's figures (module docstring) from ``run_first_set``'s results."""
    ok = [r for r in results if "error" not in r]
    out = {"vehicles": len(results), "stopped": len(results) - len(ok)}
    if not ok:
        return out
    t0 = ok[0]["end"]
    mean = np.mean([r["nees"][t0:] for r in ok], axis=0)
    lo, hi = runs.nees_band(len(ok))
    z = np.concatenate([r["z"][t0:] for r in ok])
    out.update(in_band=float(np.mean((mean >= lo) & (mean <= hi))), nees_mean=float(mean.mean()), band=(lo, hi),
               rms=np.sqrt(np.mean(z ** 2, axis=0)), params_nees=[r["params_nees_first_set"] for r in ok],
               params_3sigma=float((np.abs(np.array([r["final_z_params"] for r in ok])) <= 3.0).mean(axis=0).min()))
    return out


def first_set_table(population, names=NAMES, variants=VARIANTS, workers=2):
    """The table (module docstring) over ``population`` vehicles per preset. Returns it as text."""
    lines = ["\nAPKF case 1 over %d drawn vehicles per preset, by where the first maneuver set is linearised:\n"
             % population,
             "| preset | first set | NEES in band (goal >= 0.90) | NEES mean (band) | RMS / 1 sigma, attitude; rate "
             "(goal 0.7-1.3) | parameters' NEES at the first set's end, mean (median; 20 dof) | parameters within "
             "3 sigma at the end (goal >= 0.95) | stopped (goal 0) |", "|---|---|---|---|---|---|---|---|"]
    for name in names:
        for v in variants:
            with tempfile.TemporaryDirectory() as tmp:
                res = campaign.run_campaign(run_first_set, list(range(population)), tmp, workers=workers,
                                            progress=False, name=name, variant=v)
            s = row_figures(res)
            if "in_band" not in s:
                lines.append("| %s | %s | — | — | — | — | — | %d |" % (name, v, s["stopped"]))
                continue
            lines.append("| %s | %s | %.2f | %.2f (%.2f-%.2f) | %s; %s | %.1f (%.1f) | %.2f | %d |" % (
                name, v, s["in_band"], s["nees_mean"], s["band"][0], s["band"][1],
                "-".join(_fmt(a) for a in (s["rms"][0:3].min(), s["rms"][0:3].max())),
                "-".join(_fmt(a) for a in (s["rms"][3:6].min(), s["rms"][3:6].max())), np.mean(s["params_nees"]),
                np.median(s["params_nees"]),
                s["params_3sigma"], s["stopped"]))
    return "\n".join(lines)
