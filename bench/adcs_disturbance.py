"""The APKF's disturbance models against each other (``bench_adcs``'s rows; ``ground/adcs/apkf_disturbance.py``).

``disturbance_models``: Cases 1-3, the thesis's white model beside each shaping filter the case has figures for,
``RUNS`` seeds each through ``fps adcs apkf``'s own run function (the thesis-3U default, consistent form).
``known_disturbance``: the bound a disturbance model can reach, Case 2's harmonic and Case 3's gradient filters
started at the true disturbance. ``consistency_over``: the consistent form's figures over seeds in this process (also
``bench_adcs.disturbance_noise_sweep``'s).
"""

import numpy as np

from emulator.spacecraft import scenario
from ground.adcs import apkf, quat, runs
from ground.adcs.apkf_disturbance import shaping

# (case, tau_d's model): white is the thesis's random walk; the others ``apkf_disturbance.shaping``'s
DISTURBANCE_ROWS = ((1, "white"), (1, "markov"), (2, "white"), (2, "markov"), (2, "harmonic"), (3, "white"),
                    (3, "markov"), (3, "gradient"))
GOALS = {"nees_in_band_share": 0.90, "rms": (0.7, 1.3), "params_within_3sigma_share": 0.95}


def band(n, dof=6):
    """The 95 % band of the mean NEES over n runs (``runs.nees_band``)."""
    return runs.nees_band(n, dof)


def consistency_over(case, seeds, disturbance="white", setup=None):
    """The consistent form over ``seeds`` in this process, after the first maneuver set: (mean NEES per step over
    the seeds, attitude + rate, 6 dof; RMS over runs and steps of the rate error / its 1 sigma, per axis; the least,
    over the 23 parameters, share of runs ending within 3 sigma). ``setup(o, k0, f)`` changes each run's filter
    before it runs (a diagnostic)."""
    nees, z, zp = [], [], []
    for seed in seeds:
        o = scenario.simulate(case=case, seed=seed)
        k0, f = runs._start_apkf(o, case, disturbance=disturbance)
        if setup is not None:
            setup(o, k0, f)
        t0 = int(o["set_ends"][0])
        for kk in range(k0 + 1, len(o["t"])):
            f.step(o["t"][kk - 1], o["tach"][kk], o["st_q"][kk] if o["st_valid"][kk] else None)
            if kk >= t0:
                e = runs.apkf_error(o, kk, f.x, case)
                nees.append((kk, runs._nees(e[0:6], f.P[0:6, 0:6])))
                z.append(e[3:6] / np.sqrt(np.diag(f.P)[3:6]))
        zp.append(np.abs(e[apkf.PARAMS] / np.sqrt(np.diag(f.P)[apkf.PARAMS])) <= 3.0)
    steps = np.array(nees)
    mean = np.array([steps[steps[:, 0] == kk, 1].mean() for kk in np.unique(steps[:, 0])])
    return mean, np.sqrt(np.mean(np.array(z) ** 2, axis=0)), float(np.mean(zp, axis=0).min())


def disturbance_models(campaign, runs_n, rows=DISTURBANCE_ROWS):
    """{(case, model): ``runs.aggregate`` summary} of ``runs_n`` seeds each; ``campaign`` is ``bench_adcs
    ._campaign`` (2 local workers)."""
    return {(case, d): runs.aggregate(campaign(runs.run_apkf, case, workers=2, runs_n=runs_n, disturbance=d)[0],
                                      "apkf", case) for case, d in rows}


def _true_shaping_state(o, k0, case):
    """The truth's shaping-filter state at step k0, in the filter's units (scaled as ``scenario.filter_truth``):
    Case 1 and 2 [tau_d, d tau_d / dt] (the rate by central differences of the 1 Hz torque), Case 3 [tau_d, vec(G)]
    with Eq. 4.151's G = d tau_d / d theta = -(A/2)(q4 I + [e x]) at the true attitude (q = [e, q4])."""
    tau = o["tau_d"][k0]
    if case != 3:
        z = np.concatenate([tau, 0.5 * (o["tau_d"][k0 + 1] - o["tau_d"][k0 - 1])])
    else:
        e, q4 = o["q"][k0][0:3], o["q"][k0][3]
        G = -0.5 * scenario.TAU_MAG * (q4 * np.eye(3) + quat.skew(e))
        z = np.concatenate([tau, G.ravel()])
    return z * o["truth"]["scale"]


def _start_at_true_disturbance(case):
    """``consistency_over``'s setup: the shaping filter's states set to the truth's at the start
    (``_true_shaping_state``), their covariance 1e-6 of the filter's prior, uncorrelated, and kept so: no
    fictitious noise on the filter's Q_dd. Case 1 (no disturbance) takes Case 2's harmonic filter, to see what the
    added states cost when the torque is known to be zero."""
    def setup(o, k0, f):
        if f.model.disturbance is None:
            f.model.disturbance = shaping(2, "harmonic")
            f.x, f.P = apkf.shaping_states(f.x, f.P, f.model.disturbance)
        f.model.disturbance.fictitious = False
        ix = f.model.disturbance.ix
        f.x[ix + 1] = _true_shaping_state(o, k0, case)
        f.P[ix] = 0.0
        f.P[:, ix] = 0.0
        f.P[np.ix_(ix, ix)] = f.model.disturbance.prior() * 1e-6
    return setup


KNOWN_ROWS = ((1, "harmonic"), (2, "harmonic"), (3, "gradient"))


def known_disturbance(seeds, rows=KNOWN_ROWS):
    """{(case, model): (NEES in band, RMS / 1 sigma of the rate, parameters within 3 sigma)} with the shaping
    filter started at the true disturbance (``_start_at_true_disturbance``): what is left when the disturbance is
    known at the start and its model is the truth's."""
    lo, hi = band(len(list(seeds)))
    out = {}
    for case, d in rows:
        start = _start_at_true_disturbance(case)
        mean, rms, within = consistency_over(case, seeds, d if case != 1 else "white", start)
        out[(case, d)] = float(np.mean((mean >= lo) & (mean <= hi))), rms, within
    return out


def _fmt(v, f="%.2f"):
    return "—" if v is None else ", ".join(f % x for x in np.atleast_1d(v))


def _verdict(s):
    """Whether a summary meets the three goals (``GOALS``)."""
    rms = np.concatenate([s["rms_over_sigma_attitude"], s["rms_over_sigma_rate"]])
    lo, hi = GOALS["rms"]
    return (s["nees_in_band_share"] >= GOALS["nees_in_band_share"] and bool(np.all((rms >= lo) & (rms <= hi)))
            and s["params_within_3sigma_share"] >= GOALS["params_within_3sigma_share"])


def disturbance_models_table(figs, known=None, known_seeds=0):
    """``disturbance_models``' figures (and ``known_disturbance``'s, if given) as the bench's table."""
    rows = ["\nThe disturbance models (consistent form, thesis-3U, %d seeds each, after the first maneuver set; "
            "white = the thesis's random walk):\n" % next(iter(figs.values()))["runs"],
            "| case | tau_d model | NEES in band (goal >= 0.90) | RMS / 1 sigma, attitude x, y, z | RMS / 1 sigma, "
            "rate x, y, z (goal 0.7-1.3) | parameters within 3 sigma (goal >= 0.95) | runs ok / diverged / failed | "
            "all three goals |", "|---|---|---|---|---|---|---|---|"]
    for (case, d), s in figs.items():
        rows.append("| %d | %s | %s | %s | %s | %s | %d / %d / %d | %s |" % (
            case, d, _fmt(s["nees_in_band_share"]), _fmt(s["rms_over_sigma_attitude"]),
            _fmt(s["rms_over_sigma_rate"]), _fmt(s["params_within_3sigma_share"]), s["runs"],
            s.get("runs_diverged", 0), s["runs_failed"], "met" if _verdict(s) else "missed"))
    for (case, d), (share, rms, within) in (known or {}).items():
        what = " (zero), Case 2's filter" if case == 1 else ""
        rows.append("| %d | %s started at the true disturbance%s (%d seeds; a bound, not a filter) | %.2f | — | %s "
                    "| %.2f | — | — |" % (case, d, what, known_seeds, share, _fmt(rms), within))
    rows.append("Goals (Case 2 and 3 with a shaping filter): NEES in band >= 0.90, RMS / 1 sigma 0.7-1.3 on every "
                "axis, parameters within 3 sigma in >= 95 % of runs; Case 1 no worse than white.")
    return "\n".join(rows)
