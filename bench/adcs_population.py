"""Which uncertainty the APKF misses on over a drawn population (``bench_adcs``'s sweep).

``uncertainty_sweep``: the consistent form, Case 1, over vehicles drawn within a spacecraft file's ``uncertainty``
block (``emulator/spacecraft/dispersion.py``) with that block's inertia, wheel-tilt or dipole 1 sigma scaled down
(``scaled_uncertainty``), each population split by whether a wheel reached its speed limit, and some rows' steps by
how many vehicles have a star-tracker output (``blind_by_fix``). The same seed draws the same standard normals in
every row, so a row differs from the file's only in the size of what was scaled.
"""

import copy

import numpy as np

from bench.adcs_disturbance import _fmt, _verdict
from ground.adcs import apkf, runs

# (label, factors on the file's inertia, wheel-tilt and dipole 1 sigma, star-tracker rate limit deg/s or None for
# the file's); the first row is the file's own block
SWEEP_3U = (("the file's", 1.0, 1.0, 1.0, None), ("inertia / 4", 0.24, 1.0, 1.0, None),
            ("inertia / 14", 0.0714, 1.0, 1.0, None), ("tilts / 3.3", 1.0, 0.3, 1.0, None),
            ("tilts / 10", 1.0, 0.1, 1.0, None), ("inertia / 4, tilts / 3.3", 0.24, 0.3, 1.0, None),
            ("inertia / 14, tilts / 10", 0.0714, 0.1, 1.0, None), ("dipole / 3", 1.0, 1.0, 1 / 3, None),
            ("tilts / 3.3, dipole / 3", 1.0, 0.3, 1 / 3, None),
            ("star tracker answering to 1 deg/s (a diagnostic)", 1.0, 1.0, 1.0, 1.0))
TILT_SPLIT_DEG = 20.0       # the file's own population's unlimited vehicles, by their largest true tilt
FIX_ROWS = (0, 6, 8)        # rows whose steps are split by the share of vehicles with a star-tracker output
FIX_SHARES = (0.2, 0.8)     # ... fewer than the first, more than the second


def scaled_uncertainty(d, inertia=1.0, tilt=1.0, dipole=1.0, st_rate=None):
    """A copy of the checked spacecraft file ``d`` with its uncertainty block's inertia, wheel-tilt and dipole
    1 sigma times the factors and, with ``st_rate``, its star tracker's rate limit (deg/s): a population that shows
    which uncertainty a filter misses on, never a file to fly."""
    out = copy.deepcopy(d)
    u = out["uncertainty"]
    u["inertia_sigma_kgm2"] = [v * inertia for v in u["inertia_sigma_kgm2"]]
    u["misalignment_sigma_deg"] *= tilt
    u["residual_dipole_sigma_am2"] *= dipole
    if st_rate is not None:
        out["star_tracker"]["rate_limit_deg_s"] = st_rate
    return out


def clipped(r):
    """A wheel of the run reached its speed limit (its truth's counters)."""
    return sum((r.get("wheel_speed_clips") or {}).get("speed_clip", [0])) > 0


def largest_tilt_deg(d, r):
    """The largest true tilt of the run's wheels (deg): ``population.largest_tilt`` of ``d`` flown with the run's
    drawn truth block."""
    from ground.adcs import population
    return population.largest_tilt(dict(d, truth=r["vehicle"]["truth"]))[0]


def blind_by_fix(d, res):
    """Over the runs ``res`` (vehicles drawn within ``d``'s block) after the first set: each vehicle's share of
    steps without a star-tracker output (its truth flown again), and per group of steps, those where fewer than
    ``FIX_SHARES[0]`` and more than ``FIX_SHARES[1]`` of the vehicles have one: (steps, NEES mean, share in its
    band, share below it)."""
    from emulator.spacecraft import scenario
    ok = [r for r in res if r.get("ok") and "series" in r]
    t0 = int(ok[0]["set_ends_s"][0])
    valid = np.array([scenario.simulate(case=1, seed=r["seed"], spacecraft=runs.fly_vehicle(d, r["seed"],
                                                                                             "drawn")[0])
                      ["st_valid"][t0:] for r in ok])
    mean = np.mean([r["series"]["nees"][t0:] for r in ok], axis=0)
    lo, hi = runs.nees_band(len(ok))
    inside, share = (mean >= lo) & (mean <= hi), valid.mean(axis=0)
    groups = [share < FIX_SHARES[0], share > FIX_SHARES[1]]
    return 1 - valid.mean(axis=1), [(int(g.sum()), float(mean[g].mean()), float(inside[g].mean()),
                                     float(np.mean(mean[g] < lo))) for g in groups]


def _fix_row(label, res, blind, groups):
    ok = [r for r in res if r.get("ok") and "series" in r]
    lim = np.array([clipped(r) for r in ok])
    return "| %s | %.2f / %.2f | %d: %.2f, %.2f, %.2f | %d: %.2f, %.2f, %.2f |" % (
        (label, np.median(blind[~lim]) if (~lim).any() else np.nan, np.median(blind[lim]) if lim.any() else np.nan)
        + groups[0] + groups[1])


def _subsets(first, d):
    out = [("", lambda r: True), (", no wheel at its limit", lambda r: not clipped(r)),
           (", a wheel at its limit", clipped)]
    if first:
        out += [(", no wheel at its limit, largest tilt < %g deg" % TILT_SPLIT_DEG,
                 lambda r: not clipped(r) and largest_tilt_deg(d, r) < TILT_SPLIT_DEG),
                (", no wheel at its limit, largest tilt >= %g deg" % TILT_SPLIT_DEG,
                 lambda r: not clipped(r) and largest_tilt_deg(d, r) >= TILT_SPLIT_DEG)]
    return out


def _row(label, d, s):
    u, ne = d["uncertainty"], s.get("nees") or {"mean_after": None, "band": (np.nan, np.nan)}
    met = s["runs"] and s["nees_in_band_share"] is not None and _verdict(s) and not s["runs_diverged"]
    return "| %s: %.0f; %.3g; %.3g | %d | %s | %s (%.2f-%.2f) | %s | %s; %s | %s | %d / %d | %s |" % (
        label, 100 * u["inertia_sigma_kgm2"][0] / d["inertia_kgm2"][0], u["misalignment_sigma_deg"],
        u["residual_dipole_sigma_am2"], s["runs"], _fmt(s["nees_in_band_share"]), _fmt(ne["mean_after"]),
        ne["band"][0], ne["band"][1], _fmt(ne.get("variance_ratio_after")), _fmt(s["rms_over_sigma_attitude"]),
        _fmt(s["rms_over_sigma_rate"]), _fmt(s["params_within_3sigma_share"]), s["runs_diverged"], s["runs_failed"],
        "met" if met else "missed")


def uncertainty_sweep(campaign, population, name="thesis-3u", rows=SWEEP_3U, workers=2, fix_rows=FIX_ROWS,
                      tilt_split=True):
    """``population`` vehicles drawn within ``name``'s uncertainty block for each row (``campaign``:
    ``bench_adcs._campaign``), each split by whether a wheel reached its speed limit, and (``tilt_split``) the first
    row's unlimited vehicles by their largest true tilt; the ``fix_rows`` by the star tracker's outputs
    (``blind_by_fix``). Returns the tables."""
    from protocol import spacecraft as sf
    d0 = sf.load(name)
    lines = ["\nAPKF case 1 (consistent form) over %d vehicles drawn within %s's uncertainty block, the block scaled "
             "(vehicle n = seed n in every row, its draws scaled):\n" % (population, name),
             "| population, 1 sigma: Jxx %; tilts deg; dipole A m^2 | vehicles | NEES in band (goal >= 0.90) | "
             "NEES mean (its band) | NEES variance over the vehicles / chi-square's (the band assumes 1) | RMS / 1 "
             "sigma, attitude x, y, z; rate x, y, z (goal 0.7-1.3) | parameters within 3 sigma (goal >= 0.95) | "
             "diverged / failed (goal 0) | every goal |",
             "|---|---|---|---|---|---|---|---|---|"]
    fix = ["\nThe same populations by the star tracker's outputs, after the first set:\n",
           "| population | share of steps blind, median over the vehicles: no wheel at its limit / a wheel at its "
           "limit | steps where < %g of the vehicles have an output: steps, NEES mean, in band, below it | steps "
           "where > %g have one: the same |" % FIX_SHARES, "|---|---|---|---|"]
    for i, (label, fi, ft, fm, st) in enumerate(rows):
        d = scaled_uncertainty(d0, fi, ft, fm, st)
        res = campaign(runs.run_apkf, 1, workers=workers, runs_n=population, spacecraft=d, vehicle="drawn")[0]
        for sub, sel in _subsets(tilt_split and i == 0, d):
            lines.append(_row(label + sub, d, runs.aggregate([r for r in res if "error" in r or sel(r)], "apkf", 1)))
        if i in fix_rows:
            fix.append(_fix_row(label, res, *blind_by_fix(d, res)))
    lines.append("A smaller population has a wider band (its NEES in band is not comparable across sizes; its NEES "
                 "mean and RMS / 1 sigma are).")
    return "\n".join(lines + fix)


WALK_ROWS = ((SWEEP_3U[6], False), (SWEEP_3U[6], True), (SWEEP_3U[0], False), (SWEEP_3U[0], True),
             (SWEEP_3U[9], False))


def walk_diagnostic(campaign, population, name="thesis-3u", rows=WALK_ROWS, workers=2):
    """What the filter's random walks cost over the blind stretches where the truth has none (Case 1): each row's
    population with Case 1's q_d (``apkf.QD_CONSISTENT``) at zero, and where its flag says so the walks of the
    constant parameters (Sec. 4.8's Q on J5, m, the tilts and Jrw: ``apkf._QP_FIXED``) at zero too; diagnostics,
    never defaults. Returns ``uncertainty_sweep``'s tables for them."""
    q, qp = apkf.QD_CONSISTENT[1], apkf._QP_FIXED.copy()
    out = []
    try:
        for row, params in rows:
            apkf.QD_CONSISTENT[1] = 0.0               # forked workers inherit both
            apkf._QP_FIXED[:] = 0.0 if params else qp
            label = (", tau_d's and the parameters' walks at zero (a diagnostic)" if params
                     else ", tau_d's walk at zero (a diagnostic)")
            out.append(uncertainty_sweep(campaign, population, name, ((row[0] + label,) + tuple(row[1:]),), workers,
                                         (0,), tilt_split=False))
    finally:
        apkf.QD_CONSISTENT[1] = q
        apkf._QP_FIXED[:] = qp
    return "\n".join(out)


def p0_against_draws(name="thesis-3u", n=1000):
    """The APKF's initial P against the drawing: over ``n`` vehicles drawn within ``name``'s block, each parameter's
    initial error (the truth in the filter's terms, ``scenario.filter_truth``, minus the prior) over its P0 1 sigma,
    RMS, and the parameters' initial NEES (tau_d left out: no vehicle draws one), its mean and share above the 99 %
    point. Returns the table."""
    from types import SimpleNamespace as NS
    from scipy.stats import chi2
    from emulator.spacecraft import dispersion, scenario
    from protocol import spacecraft as sf
    d = sf.load(name)
    model, pr = runs.apkf_model(d), runs.apkf_prior(d)
    x0 = apkf.initial_state(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(4), j5=pr["j5"], jrw=pr["jrw"])
    x0[15:18], x0[18:22], x0[22:26] = pr["m"], pr["delta1"], pr["delta2"]
    P = apkf.initial_covariance(model, x0)[9:29, 9:29]              # J5, m, delta1, delta2, Jrw
    e, scale = [], []
    for seed in range(n):
        v = dispersion.flown(d, seed, "drawn")[0]
        t = sf.true_figures(v)
        wh = NS(c=np.array(sf.wheel_axes(v, True)).T, j=np.array(t["rotor_inertia_kgm2"]),
                p=NS(delta1_deg=np.array(t["delta1_deg"]), delta2_deg=np.array(t["delta2_deg"])))
        ft = scenario.filter_truth(NS(j=np.array(sf.inertia_matrix(v, True)), wheels=wh,
                                      dipole=np.array(t["residual_dipole_am2"])), model.jxx)
        e.append(np.concatenate([ft["J5"], ft["m"], ft["delta1"], ft["delta2"], ft["jrw"]]) - x0[10:30])
        scale.append(ft["scale"])
    e = np.array(e)
    rms = np.sqrt(np.mean(e ** 2, axis=0) / np.diag(P))
    nees = np.einsum("ij,ij->i", e, np.linalg.solve(P, e.T).T)
    names = runs.PARAM_NAMES[3:]
    return ("\nThe APKF's P0 against %d vehicles drawn within %s's block (initial error RMS / P0 1 sigma; goal 1):\n\n"
            "| %s | parameters' initial NEES, mean (%d dof) | above its 99 %% point (1 %% if Gaussian) | scale s = "
            "Jxx_ref / Jxx, range |\n|%s---|---|---|\n| %s | %.1f | %.3f | %.2f-%.2f |"
            % (n, name, " | ".join(names), len(names), "---|" * len(names), " | ".join("%.2f" % r for r in rms),
               nees.mean(), np.mean(nees > chi2.ppf(0.99, len(names))), min(scale), max(scale)))
