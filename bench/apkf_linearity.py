"""Does the APKF's linear prediction hold its own P over a blind stretch, and where does a drawn vehicle's
overconfidence start? ``bench_adcs``'s diagnostics on thesis-3u's drawn population (Case 1, the consistent form).

``stretch_check``: the filter's own (x, P) at the start of a blind stretch, drawn ``n`` times and each carried over
the stretch through the nonlinear model (``apkf.propagate_window``, the stretch's own tachometer read-outs, no process
noise), against the filter's linear prediction M P M^T over the same steps: the samples' attitude + rate NEES (6 dof:
mean, median, 90th percentile) and their RMS over the predicted 1 sigma per axis. The draws are made in P's
correlation coordinates: P's entries span some 20 orders of magnitude (a wheel's inertia against its speed), and
a factorisation of P itself loses the small parameters' covariances to rounding, which shows as a spread several
times the linear one that is not there.

``reacquisitions``: at each star-tracker output that ends a stretch of 3 steps or more, the filter's prior at the fix
(its prediction over the stretch, before the update) against the truth: the attitude + rate NEES, the star tracker's
NIS, the attitude error against its 1 sigma, and the parameters' NEES after the update.

``by_set``: one vehicle's attitude + rate NEES (mean over each maneuver set) and its parameters' NEES (J5, m, the
tilts, Jrw: 20 dof) at each set's end, with the largest |error| / 1 sigma of its tilts and Jrw.
"""

import numpy as np

from ground.adcs import apkf, runs

NAME = "thesis-3u"
PARAMS = np.r_[9:29]            # J5, m, delta1, delta2, Jrw in the error state


def _flown(seed, name=NAME):
    """(the drawn vehicle's file, its simulated Case 1 run, the started filter, its first step)."""
    from protocol import spacecraft as sf
    d = runs.fly_vehicle(sf.load(name), seed, "drawn")[0]
    o = runs._simulate(1, seed, None, gyro=False, spacecraft=d)
    k0, f = runs._start_apkf(o, 1, spacecraft=d)
    return d, o, f, k0


def _draws(P, n, rng):
    """n draws of N(0, P) as rows, factored in P's correlation coordinates."""
    s = np.sqrt(np.diag(P))
    s[s == 0] = 1.0
    L = np.linalg.cholesky(P / np.outer(s, s)) * s[:, None]
    return rng.standard_normal((n, len(P))) @ L.T


def nees(E, P):
    """Each row of E against P: e^T P^-1 e."""
    return np.einsum("ij,ij->i", E, np.linalg.solve(P, E.T).T)


GROUPS = (("tau_d", np.r_[6:9]), ("J5", np.r_[9:14]), ("m", np.r_[14:17]), ("tilts", np.r_[17:25]),
          ("Jrw", np.r_[25:29]), ("W, W-, W+", np.r_[29:41]))


def stretch_check(seed, after, min_steps, n=400, keep=None, name=NAME):
    """The first blind stretch of at least ``min_steps`` steps that starts after ``after`` s (its start: the last
    star-tracker output before it), as the module docstring says; ``keep``: the error-state indices left uncertain
    (the rest of P zeroed, on both sides; None: all); ``name``: the spacecraft file drawn from. Returns a dict, or
    None without such a stretch."""
    _, o, f, k0 = _flown(seed, name)
    v, t = o["st_valid"], o["t"]
    k = k0
    while True:
        k += 1
        if k + min_steps >= len(t):
            return None
        f.step(t[k - 1], o["tach"][k], o["st_q"][k] if v[k] else None)
        if v[k] and t[k] > after and not v[k + 1:k + 1 + min_steps].any():
            break
    rest = v[k + 1:]
    L = int(np.argmax(rest)) if rest.any() else len(rest)
    steps = [(t[j - 1], np.array(o["tach"][j], float)) for j in range(k + 1, k + 1 + L)]
    x0, P0 = f.x.copy(), f.P[:apkf.N, :apkf.N].copy()
    kept = np.ones(apkf.N, bool) if keep is None else np.isin(np.arange(apkf.N), keep)
    P0[~kept] = 0.0
    P0[:, ~kept] = 0.0
    xb, M = apkf.propagate_window(x0, steps, f.model)
    Pb = (M @ P0 @ M.T)[0:6, 0:6]
    D = np.zeros((n, apkf.N))
    D[:, kept] = _draws(P0[np.ix_(kept, kept)], n, np.random.default_rng(seed))
    E = np.array([apkf.difference(apkf.propagate_window(apkf.correct(x0, dx), steps, f.model)[0], xb)[0:6]
                  for dx in D])
    ne = nees(E, Pb)
    return {"seed": seed, "t_s": float(t[k]), "steps": L, "nees_mean": float(ne.mean()),
            "nees_median": float(np.median(ne)), "nees_p90": float(np.percentile(ne, 90)),
            "rms_over_sigma": np.sqrt(np.mean(E ** 2, axis=0) / np.diag(Pb)).tolist()}


def reacquisitions(seed, until_s, name=NAME):
    """``reacquisitions`` of the module docstring up to ``until_s`` s: a list of (t s, stretch steps, prior NEES
    (6 dof), NIS (3 dof), attitude error deg, its largest 1 sigma deg, the parameters' NEES after)."""
    from ground.adcs import quat
    _, o, f, k0 = _flown(seed, name)
    v, t, out = o["st_valid"], o["t"], []
    for k in range(k0 + 1, len(t)):
        if t[k] > until_s:
            break
        prior = None
        if v[k] and f._stretch is not None and len(f._stretch[2]) >= 2:
            s_q, s_r = apkf.fictitious_scales(t[k - 1], f.set_ends, f.form, f.model.dt)
            x, P = apkf.predict(f.x, f.P, o["tach"][k], f.model, t[k - 1], f.case, s_q, qd=f.qd,
                                second_order=f.second_order)
            e, z = runs.apkf_error(o, k, x, 1), quat.error_vec(o["st_q"][k], x[0:4])
            prior = (len(f._stretch[2]) + 1, nees(e[None, 0:6], P[0:6, 0:6])[0],
                     float(z @ np.linalg.solve(P[0:3, 0:3] + f.model.R_st * s_r, z)),
                     np.degrees(2 * np.linalg.norm(e[0:3])), np.degrees(2 * np.sqrt(np.max(np.diag(P)[0:3]))))
        f.step(t[k - 1], o["tach"][k], o["st_q"][k] if v[k] else None)
        if prior is not None:
            e, P = runs.apkf_error(o, k, f.x, 1), f.P[:apkf.N, :apkf.N]
            out.append((float(t[k]),) + prior + (nees(e[None, PARAMS], P[np.ix_(PARAMS, PARAMS)])[0],))
    return out


def by_set(seed, name=NAME):
    """The vehicle's figures per maneuver set (``by_set`` in the module docstring): a list of (from s, to s,
    attitude + rate NEES mean, parameters' NEES at the set's end, largest |z| of the tilts, of Jrw, share of steps
    with a star-tracker output)."""
    _, o, f, k0 = _flown(seed, name)
    v, t, n = o["st_valid"], o["t"], len(o["t"])
    rows, out = [], []
    for k in range(k0, n):
        if k > k0:
            f.step(t[k - 1], o["tach"][k], o["st_q"][k] if v[k] else None)
        e, P = runs.apkf_error(o, k, f.x, 1), f.P[:apkf.N, :apkf.N]
        s = np.sqrt(np.diag(P))
        rows.append((t[k], nees(e[None, 0:6], P[0:6, 0:6])[0], nees(e[None, PARAMS], P[np.ix_(PARAMS, PARAMS)])[0],
                     np.max(np.abs(e[17:25] / s[17:25])), np.max(np.abs(e[25:29] / s[25:29])), v[k]))
    rows = np.array(rows, dtype=float)
    edges = [rows[0, 0]] + [e for e in o["set_ends"] if e < rows[-1, 0]] + [rows[-1, 0] + 1]
    for a, b in zip(edges[:-1], edges[1:]):
        r = rows[(rows[:, 0] >= a) & (rows[:, 0] < b)]
        out.append((a, b, float(r[:, 1].mean()), float(r[-1, 2]), float(r[-1, 3]), float(r[-1, 4]),
                    float(r[:, 5].mean())))
    return out


def linearity_tables(seeds=(0, 1, 3, 5), n=400, name=NAME):
    """The diagnostics as markdown tables for vehicles drawn within ``name``'s block: ``stretch_check`` in the
    first set (a stretch of 10 steps or more) and after it (40 or more), by state group for the last vehicle,
    ``by_set`` and ``reacquisitions`` for the same vehicles."""
    from protocol import spacecraft as sf
    first = sf.load(name)
    set1 = runs._simulate(1, seeds[0], None, gyro=False, spacecraft=runs.fly_vehicle(first, seeds[0],
                                                                                     "drawn")[0])["set_ends"][0]
    out = ["\nThe APKF's linear prediction over a blind stretch against its own P carried through the nonlinear "
           "model (%d draws; %s drawn vehicles, case 1):\n" % (n, name),
           "| vehicle | stretch from (s), steps | samples' NEES (6 dof): mean, median, 90th percentile (chi-square: "
           "6, 5.3, 10.6) | RMS / predicted 1 sigma, attitude x, y, z; rate x, y, z |", "|---|---|---|---|"]
    for seed in seeds:
        for after, min_steps in ((0.0, 10), (set1, 40)):
            r = stretch_check(seed, after, min_steps, n, name=name)
            if r is not None:
                out.append("| %d | %.0f, %d | %.2f, %.2f, %.2f | %s |" % (
                    seed, r["t_s"], r["steps"], r["nees_mean"], r["nees_median"], r["nees_p90"],
                    ", ".join("%.2f" % v for v in r["rms_over_sigma"])))
    out += ["\nVehicle %d's first-set stretch with the attitude, the rate and one group of states uncertain (the "
            "rest of P zeroed on both sides):\n" % seeds[-1],
            "| uncertain besides attitude and rate | samples' NEES: mean, median, 90th percentile | RMS / predicted 1 "
            "sigma |", "|---|---|---|"]
    for group, ix in (("none", np.r_[0:0]),) + GROUPS:
        r = stretch_check(seeds[-1], 0.0, 10, n, keep=np.r_[0:6, ix], name=name)
        out.append("| %s | %.2f, %.2f, %.2f | %s |" % (group, r["nees_mean"], r["nees_median"], r["nees_p90"],
                                                        ", ".join("%.2f" % v for v in r["rms_over_sigma"])))
    out += ["\nThe same vehicles by maneuver set (attitude + rate NEES mean over the set, 6 dof; the parameters' "
            "NEES at its end, 20 dof; the largest |error| / 1 sigma of the tilts and of Jrw there):\n",
            "| vehicle | set (s) | attitude + rate NEES | parameters' NEES | tilts |z| | Jrw |z| | star-tracker "
            "outputs |", "|---|---|---|---|---|---|---|"]
    for seed in seeds:
        for a, b, ne, npar, zt, zj, fix in by_set(seed, name):
            out.append("| %d | %.0f-%.0f | %.2f | %.1f | %.1f | %.1f | %.2f |" % (seed, a, b, ne, npar, zt, zj, fix))
    out.append(reacquisition_table(name, seeds, set1))
    return "\n".join(out)


def stretch_table(name, seeds, after, min_steps, n=400):
    """``stretch_check`` of the first stretch of ``min_steps`` steps or more after ``after`` s, for vehicles drawn
    within ``name``'s block: with every state uncertain, and with the attitude, the rate and J5 alone."""
    out = ["\nThe APKF's linear prediction over the first blind stretch of %d steps or more after %g s, %s drawn "
           "vehicles (%d draws; every state uncertain / the attitude, rate and J5 alone):\n" % (min_steps, after,
                                                                                          name, n),
           "| vehicle | its Jxx, Jyy, Jzz / the file's | stretch from (s), steps | samples' NEES: mean, median, 90th "
           "percentile | RMS / predicted 1 sigma | J5 alone: NEES mean, median | J5 alone: RMS / predicted 1 sigma |",
           "|---|---|---|---|---|---|---|"]
    from protocol import spacecraft as sf
    for seed in seeds:
        r = stretch_check(seed, after, min_steps, n, name=name)
        if r is None:
            continue
        j = stretch_check(seed, after, min_steps, n, keep=np.r_[0:6, 9:14], name=name)
        d = runs.fly_vehicle(sf.load(name), seed, "drawn")[0]
        moments = np.diag(sf.inertia_matrix(d, True)) / np.array(d["inertia_kgm2"][:3])
        out.append("| %d | %s | %.0f, %d | %.2f, %.2f, %.2f | %s | %.2f, %.2f | %s |" % (
            seed, ", ".join("%.2f" % v for v in moments), r["t_s"], r["steps"], r["nees_mean"], r["nees_median"],
            r["nees_p90"],
            ", ".join("%.2f" % v for v in r["rms_over_sigma"]), j["nees_mean"], j["nees_median"],
            ", ".join("%.2f" % v for v in j["rms_over_sigma"])))
    return "\n".join(out)


def reacquisition_table(name, seeds, until_s):
    """``reacquisitions`` up to ``until_s`` s for vehicles drawn within ``name``'s block, as a markdown table."""
    out = ["\nThe re-acquisitions up to %g s of %s drawn vehicles (the prior at each fix that ends a stretch of 3 "
           "steps or more, against the truth):\n" % (until_s, name),
           "| vehicle | fix (s) | stretch (steps) | prior NEES (6 dof) | NIS (3 dof) | attitude error (deg) | its "
           "largest 1 sigma (deg) | parameters' NEES after (20 dof) |", "|---|---|---|---|---|---|---|---|"]
    for seed in seeds:
        for r in reacquisitions(seed, until_s, name):
            out.append("| %d | %.0f | %d | %.1f | %.1f | %.2f | %.2f | %.1f |" % ((seed,) + r))
    return "\n".join(out)
