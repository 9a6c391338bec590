"""Tuning the attitude loop for the terminal: ``fps adcs sweep --objective terminal`` (Sec. 8.3's recommendation).

The body objective (Sec. 6.4.3, Fig. 6-2) picks the settling time t_s that minimises J = E[eps^T W eps] of the
body pointing error alone (Eq. 6.22-6.24). The fine pointing loop then takes that error out, not equally at every
frequency: what reaches the terminal's output is the body error filtered by the fine loop's sensitivity
S(jw) = 1 / (1 + L(jw)). Here each t_s's pointing run (the same runs as the body sweep's) gives its 10 Hz body
pointing error dtheta1, dtheta2 about the laser line of sight over the collection window; each axis is passed
through |S| of the fine loop's axis that plays it (dtheta1 on the P-FSM's X, dtheta2 on Y, as ``fps system``
plays them), and the residual's 1 sigma per axis and 3 sigma = 3 sqrt(s1^2 + s2^2) (the two axes in total, as
the thesis's budgets) are the terminal objective.

The residual's variance is taken from the spectrum (Parseval): the window's mean is removed, the series is
mirrored (x, then x reversed: a series of 2 n samples without a jump at its ends, so a window's edges add no
broadband leakage that S's high-pass would weigh up), and sigma^2 = sum_k w_k |X_k|^2 |S(f_k)|^2 / (2 n)^2 over
its one-sided FFT (w_k = 2 but at 0 and the Nyquist frequency). S(0) = 0 (the integral law), so the residual has
no mean and its 1 sigma is its RMS. A tone cos(2 pi f0 t) of amplitude A on the mirrored series' bins gives
exactly A |S(f0)| / sqrt(2).

S comes from one of (``rejection``):
- "model": ``ground.response.LoopModel`` of the thesis bench (its default config, 637.8 Hz, g = 0.5), per axis,
  |S| on the continuous truth (``LoopModel.s_truth``), tabulated on a log grid;
- an ``fps response`` summary.json: the measured |S| of X (``s_measured``) and Y (``s_measured_y``) at its tones.
Between the table's frequencies |S| is interpolated in log f, log |S|; below its lowest frequency it is extended
as |S| proportional to f (the integral loop's low-frequency slope: S ~ j w T / g), above its highest held.

The residual is the body error's share only: the fine loop's own floor (the quadcell's and the DACs' noise) adds
to it in quadrature whatever t_s is, so it moves no optimum (``fps system`` measures the whole).

The PD's damping ratio zeta (D = 2 zeta wn J, Eq. 6.6; the firmware's ``ZETA`` = 1 by default) is the flight
config's ``pd_zeta``: ``--zeta Z1,Z2,...`` sweeps the (t_s, zeta) grid (``grid``: zeta outer, t_s inner), each
objective's best pair and, per zeta, its best t_s (``by_zeta``) in the summary; without it the sweep is the
thesis's, zeta = 1, and its summary has no zeta key.
"""

import json
import math
import os

import numpy as np

OBJECTIVES = ("body", "terminal")
MODEL = "model"
FIGURE = "fig6-2_objectives.png"
AXES = ("dtheta1 on X", "dtheta2 on Y")
MODEL_GRID_HZ = (1e-4, 50.0, 600)        # the model's table: from, to, points (log-spaced)


def check_args(objective, rejection):
    """The sweep's ``--objective`` and ``--rejection`` checked: None for the body objective (``--rejection``
    refused with it), else the rejection table (``rejection_table``). ValueError naming the option."""
    if objective not in OBJECTIVES:
        raise ValueError("--objective must be one of %s, got %r" % ("/".join(OBJECTIVES), objective))
    if objective == "body":
        if rejection is not None:
            raise ValueError("--rejection is the terminal objective's (--objective terminal)")
        return None
    return rejection_table(MODEL if rejection is None else rejection)


def check_zeta(zeta, option="--zeta"):
    """A damping ratio as a float (``firmware.adcs.control.check_zeta``); ValueError naming ``option``."""
    from firmware.adcs.control import check_zeta as check
    try:
        return check(zeta)
    except (TypeError, ValueError):
        raise ValueError("%s must be a finite number > 0 (the PD's damping ratio, Eq. 6.6), got %r"
                         % (option, zeta)) from None


def parse_zeta_list(text):
    """``--zeta`` of the sweep: '0.7,1,1.4' -> [0.7, 1.0, 1.4] (each finite and > 0, no repeats); None -> None
    (the thesis's zeta = 1, no grid). ValueError naming --zeta."""
    if text is None:
        return None
    vals = [check_zeta(v.strip()) for v in str(text).split(",")]
    if len(set(vals)) != len(vals):
        raise ValueError("--zeta lists a value twice: %r" % (text,))
    return vals


def grid(ts_list, zetas, max_points):
    """The sweep's points: (t_s per point, zeta per point or None): ``ts_list`` alone when ``zetas`` is None,
    else each zeta (outer) with each t_s (inner). ValueError naming --zeta past ``max_points``."""
    if zetas is None:
        return list(ts_list), None
    if len(ts_list) * len(zetas) > max_points:
        raise ValueError("--ts and --zeta give %d grid points; at most %d" % (len(ts_list) * len(zetas), max_points))
    return [t for _ in zetas for t in ts_list], [z for z in zetas for _ in ts_list]


def rejection_table(source):
    """The fine loop's |S| per axis as a table: {"source", "what", "freq_hz" [n], "s_abs" [2][n]} (plain lists,
    for a worker process and summary.json). ``source``: "model" or an ``fps response`` summary.json path."""
    if source == MODEL:
        from emulator.config import default_config
        from ground.response import LoopModel
        f = np.geomspace(*MODEL_GRID_HZ)
        cfg = default_config()
        s = [np.abs(LoopModel(cfg, 637.8, 0.5, ax).s_truth(f)) for ax in (0, 1)]
        return {"source": MODEL, "what": "the fine loop's model (ground.response.LoopModel: thesis bench, 637.8 Hz, "
                "g = 0.5), |S| on the continuous truth", "freq_hz": f.tolist(), "s_abs": [v.tolist() for v in s]}
    return _measured_table(source)


def _measured_table(path):
    """``rejection_table`` of an ``fps response`` run's summary.json (ValueError naming --rejection)."""
    try:
        with open(path) as fh:
            s = json.load(fh)
    except (OSError, ValueError) as exc:
        raise ValueError("--rejection %s: not model and not a readable fps response summary.json (%s)"
                         % (path, exc)) from None
    keys = ("freq_hz", "s_measured", "s_measured_y")
    if not isinstance(s, dict) or not s.get("complete") or any(not isinstance(s.get(k), list) for k in keys):
        raise ValueError("--rejection %s: need a complete fps response summary.json (with %s)"
                         % (path, ", ".join(keys)))
    try:
        f, sx, sy = (np.asarray(s[k], float) for k in keys)
    except (TypeError, ValueError):
        raise ValueError("--rejection %s: freq_hz, s_measured, s_measured_y must be numbers" % path) from None
    if not (f.ndim == 1 and f.size >= 2 and sx.shape == f.shape and sy.shape == f.shape
            and np.all(np.isfinite(f)) and np.all(np.diff(f) > 0) and f[0] > 0
            and np.all(np.isfinite(sx)) and np.all(np.isfinite(sy)) and np.all(sx > 0) and np.all(sy > 0)):
        raise ValueError("--rejection %s: need >= 2 tones at increasing frequencies > 0 with finite |S| > 0 on "
                         "both axes" % path)
    return {"source": os.path.abspath(path), "what": "measured by fps response (%d tones, %.3g to %.3g Hz; below "
            "%.3g Hz extended as |S| proportional to f)" % (f.size, f[0], f[-1], f[0]),
            "freq_hz": f.tolist(), "s_abs": [sx.tolist(), sy.tolist()]}


def s_abs(table, axis, f_hz):
    """|S| of ``axis`` (0 = X, 1 = Y) at ``f_hz`` from a ``rejection_table``: log-log interpolation within the
    table, proportional to f below it, held above it."""
    f = np.asarray(f_hz, float)
    ft = np.asarray(table["freq_hz"], float)
    st = np.asarray(table["s_abs"][axis], float)
    out = np.exp(np.interp(np.log(np.maximum(f, ft[0])), np.log(ft), np.log(st)))
    low = f < ft[0]
    out[low] = st[0] * f[low] / ft[0]
    return out


def residual_sigma(x, dt, s_of_f):
    """1 sigma of the series ``x`` (n samples every ``dt`` s) after a filter of gain ``s_of_f(f_hz)``, from the
    mirrored series' spectrum (see the module)."""
    x = np.asarray(x, float)
    if x.ndim != 1 or x.size < 2 or not np.all(np.isfinite(x)):
        raise ValueError("the body error must be a finite series of at least 2 samples")
    xe = np.concatenate([x, x[::-1]]) - x.mean()
    m = xe.size
    p = np.abs(np.fft.rfft(xe)) ** 2
    w = np.full(p.size, 2.0)
    w[0] = 1.0
    if m % 2 == 0:
        w[-1] = 1.0
    g = np.asarray(s_of_f(np.fft.rfftfreq(m, dt)), float)
    return float(math.sqrt(np.sum(w * p * g * g)) / m)


def terminal_residual(res, hist, table):
    """The terminal objective of one pointing run (``bps.simulate``'s result and history): the body error's
    residual after the fine loop, {"residual_sigma_arcsec" [X, Y], "residual_3sigma_arcsec", "samples"}, over
    the collection window (t >= settle_s: the samples J is taken over; the spectrum needs the whole window, so
    a sample the Earth occults stays in it). None when the window has fewer than 2 samples."""
    t = np.asarray(hist["t"], float)
    x = np.asarray(hist["dtheta_arcsec"], float)[t >= res["settle_s"]]
    x = x[np.all(np.isfinite(x), axis=1)]
    if len(x) < 2:
        return None
    dt = float(np.median(np.diff(t)))
    sig = [residual_sigma(x[:, ax], dt, lambda f, ax=ax: s_abs(table, ax, f)) for ax in (0, 1)]
    return {"residual_sigma_arcsec": sig, "residual_3sigma_arcsec": float(3 * math.hypot(*sig)),
            "samples": int(len(x))}


def sweep_one(seed, run_dir, ts_list=(), params=None, noise_seed=0, rejection=None, zeta_list=None, **kw):
    """Campaign entry of the terminal sweep and of the (t_s, zeta) grid: ``bps.sweep_one``'s run of point
    ``seed`` (its zeta ``zeta_list[seed]``, None: the firmware's), its result with ``terminal`` (the
    ``terminal_residual`` through the ``rejection`` table; none without a table) added."""
    from ground.adcs import body_pointing as bps

    def add_terminal(res, hist):
        res["terminal"] = terminal_residual(res, hist, rejection)
    zeta = None if zeta_list is None else zeta_list[seed]
    return bps.sweep_one(seed, run_dir, ts_list, params, noise_seed, zeta=zeta,
                         finish=None if rejection is None else add_terminal, **kw)


def best_index(values, keep=None):
    """The index of the least value that is not None (and ``keep[i]``, when given); None when there is none."""
    ok = [(v, i) for i, v in enumerate(values) if v is not None and (keep is None or keep[i])]
    return min(ok)[1] if ok else None


def best_pair(s, i, what):
    """``ts_best_<what>_s`` (and with a zeta grid ``zeta_best_<what>``) of point ``i`` (None: none)."""
    out = {"ts_best_%s_s" % what: None if i is None else s["ts_s"][i]}
    if s.get("zeta") is not None:
        out["zeta_best_%s" % what] = None if i is None else s["zeta"][i]
    return out


def add_summary(s, results, table, requirements):
    """The sweep's summary ``s`` (``bps_cli.sweep_summary``: J per point, ``ts_best_s`` its minimum) with the
    terminal objective: ``residual_sigma_arcsec`` [X, Y] and ``residual_3sigma_arcsec`` per point (None where J
    is None), each run's body ``pointing_3sigma_arcsec`` and ``stability_3sigma_arcsec_s``, ``ts_best_body_s``
    (J's minimum), ``ts_best_terminal_s`` and ``ts_best_s`` (the residual's minimum),
    ``ts_best_terminal_in_budget_s`` (the residual's minimum over the points whose body 3σ figures meet
    ``requirements``, the spacecraft file's budgets: the fine loop needs the body within them to hold the beam),
    the rejection's source; with a zeta grid each best's ``zeta_best_<body|terminal|terminal_in_budget>``
    (``zeta_best_s`` the terminal's) and ``by_zeta`` (``zeta_table``). Returns ``s``."""
    term = [None if j is None or not (r or {}).get("terminal") else r["terminal"] for j, r in zip(s["J"], results)]
    r3 = [None if v is None else v["residual_3sigma_arcsec"] for v in term]
    p3 = [None if v is None else r["pointing_3sigma_arcsec"] for v, r in zip(term, results)]
    w3 = [None if v is None else r["stability_3sigma_arcsec_s"] for v, r in zip(term, results)]
    pb, wb = requirements["body_pointing_3sigma_arcsec"], requirements["body_stability_3sigma_arcsec_s"]
    within = [v is not None and p <= pb and w <= wb for v, p, w in zip(r3, p3, w3)]
    s.update(objective="terminal", rejection={"source": table["source"], "what": table["what"]},
             residual_sigma_arcsec=[None if v is None else v["residual_sigma_arcsec"] for v in term],
             residual_3sigma_arcsec=r3, residual_unit="arcsec", pointing_3sigma_arcsec=p3,
             stability_3sigma_arcsec_s=w3, budgets={"pointing_3sigma_arcsec": pb, "stability_3sigma_arcsec_s": wb})
    s.update(best_pair(s, best_index(s["J"]), "body"), **best_pair(s, best_index(r3), "terminal"))
    s.update(best_pair(s, best_index(r3, within), "terminal_in_budget"), ts_best_s=s["ts_best_terminal_s"])
    if s.get("zeta") is not None:
        s.update(zeta_best_s=s["zeta_best_terminal"], by_zeta=zeta_table(s, within))
    return s


def zeta_table(s, within):
    """Per zeta of the grid: its least residual 3σ over t_s and that t_s, and the same among the points within the
    body budgets (``within``), {"zeta", "ts_best_terminal_s", "residual_3sigma_arcsec", "ts_best_in_budget_s",
    "residual_3sigma_in_budget_arcsec"}."""
    out = []
    r3 = s["residual_3sigma_arcsec"]
    for z in s["zeta_values"]:
        mine = [v if zi == z else None for v, zi in zip(r3, s["zeta"])]
        i, k = best_index(mine), best_index(mine, within)
        out.append({"zeta": z, "ts_best_terminal_s": None if i is None else s["ts_s"][i],
                    "residual_3sigma_arcsec": None if i is None else r3[i],
                    "ts_best_in_budget_s": None if k is None else s["ts_s"][k],
                    "residual_3sigma_in_budget_arcsec": None if k is None else r3[k]})
    return out


def _at(s, what):
    """'<t_s> s' of a best (with its zeta on a grid)."""
    t, z = s["ts_best_%s_s" % what], s.get("zeta_best_%s" % what)
    return "%s s" % t if s.get("zeta") is None or t is None else "%s s, ζ = %g" % (t, z)


def report_lines(s):
    """report.md's table of both objectives per point and their optima (per zeta too, on a grid)."""
    b = s["budgets"]
    zs = s.get("zeta")
    out = ["## Both objectives (Sec. 8.3: the attitude loop tuned with the fine loop)", "",
           "Residual after the fine loop: the body error through %s." % s["rejection"]["what"], "",
           "| t_s (s) |%s J (rad²) | residual 1σ X, Y (arcsec) | residual 3σ (arcsec) | body 3σ pointing (arcsec), "
           "stability (arcsec/s) |" % ("" if zs is None else " ζ |"), "|---|---|---|---|---|" + ("" if zs is None
                                                                                               else "---|")]
    for n, (t, j, sg, r3, p, w) in enumerate(zip(s["ts_s"], s["J"], s["residual_sigma_arcsec"],
                                                 s["residual_3sigma_arcsec"], s["pointing_3sigma_arcsec"],
                                                 s["stability_3sigma_arcsec_s"])):
        out.append("| %g |%s %s | %s | %s | %s |" % (
            t, "" if zs is None else " %g |" % zs[n], "—" if j is None else "%.4e" % j,
            "—" if sg is None else "%.4f, %.4f" % tuple(sg),
            "—" if r3 is None else "%.4f" % r3, "—" if p is None else "%.1f, %.1f%s" % (
                p, w, "" if p <= b["pointing_3sigma_arcsec"] and w <= b["stability_3sigma_arcsec_s"] else
                " (over the budget)")))
    out += ["", "optimum: body objective (J) t_s = %s; terminal objective (residual 3σ) t_s = %s, %s among the "
            "points whose body 3σ meets the budgets (%g arcsec, %g arcsec/s); thesis 33 s%s." % (
                _at(s, "body"), _at(s, "terminal"), _at(s, "terminal_in_budget"),
                b["pointing_3sigma_arcsec"], b["stability_3sigma_arcsec_s"], "" if zs is None else ", ζ = 1"), ""]
    if zs is not None:
        out += ["| ζ | best t_s (s) | residual 3σ (arcsec) | best t_s within the budgets (s) | its residual 3σ "
                "(arcsec) |", "|---|---|---|---|---|"]
        out += ["| %g | %s | %s | %s | %s |" % (r["zeta"], _num(r["ts_best_terminal_s"], "%g"),
                                               _num(r["residual_3sigma_arcsec"], "%.4f"),
                                               _num(r["ts_best_in_budget_s"], "%g"),
                                               _num(r["residual_3sigma_in_budget_arcsec"], "%.4f"))
                for r in s["by_zeta"]]
        out.append("")
    return out


def _num(v, fmt):
    return "—" if v is None else fmt % v
