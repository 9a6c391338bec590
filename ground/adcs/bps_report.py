"""The body pointing simulator's reports and figures: report.md of a thesis-world run (the thesis's figures beside
ours, the error budget, the estimators' consistency) and of a flight-world run (its checks, passes, modes, wheels
and magnetorquers), and their plots (``fps adcs bps`` and ``fps adcs sweep`` write them)."""

import os

import numpy as np

from ground.adcs import body_pointing as bps, control
from ground.adcs.flight_world import stkf_text
from ground.verdict import table as verdict_table
from protocol.spacecraft import THESIS_REQUIREMENTS

FIGURES_FLIGHT = ("flight_pointing.png", "flight_wheels.png")


def _collected(s):
    """What the run collected: its duration, or for an interrupted run how much of it."""
    if s["complete"] or s.get("simulated_s") is None:
        return "%g s collected" % s["duration_s"]
    got = max(0.0, s["simulated_s"] - s["settle_s"])
    return "%g s of %g s collected (interrupted at t = %g s)" % (got, s["duration_s"], s["simulated_s"])


def report_md(s, args_text):
    th = bps.THESIS[s["satb_gnss"]]
    rows = [("δθ1 (arcsec)", th["theta"][0], s["pointing_mean_arcsec"], s["pointing_sigma_arcsec"], 0),
            ("δθ2 (arcsec)", th["theta"][1], s["pointing_mean_arcsec"], s["pointing_sigma_arcsec"], 1),
            ("δω1 (arcsec/s)", th["omega"][0], s["stability_mean_arcsec_s"], s["stability_sigma_arcsec_s"], 0),
            ("δω2 (arcsec/s)", th["omega"][1], s["stability_mean_arcsec_s"], s["stability_sigma_arcsec_s"], 1)]
    out = ["# Body pointing simulation (Sec. 6.4.4)", "", "`%s`" % args_text, "",
           "Spacecraft %s; t_s = %g s, %s SatB's GNSS, %s at 10 Hz after %g s (30 s hold + 4 t_s), truth %s, "
           "seed %d. complete: %s" % (_name(s.get("spacecraft")), s["ts_s"],
                                      "with" if s["satb_gnss"] else "without", _collected(s), s["settle_s"],
                                      s["truth"], s["seed"], s["complete"]), ""] + occultation_md(s) + [
           "| figure | thesis (mean, 1σ) | ours (mean, 1σ) | 1σ ratio |", "|---|---|---|---|"]
    for label, t, m, sd, i in rows:
        if m is None:
            out.append("| %s | (%.3f, %.3f) | — | — |" % (label, t[0], t[1]))
        else:
            out.append("| %s | (%.3f, %.3f) | (%.3f, %.3f) | %.2f |" % (label, t[0], t[1], m[i], sd[i],
                                                                       sd[i] / t[1]))
    p3, w3 = s.get("pointing_3sigma_arcsec"), s.get("stability_3sigma_arcsec_s")
    th3 = bps.thesis_3sigma(s["satb_gnss"])
    req = s.get("requirements") or THESIS_REQUIREMENTS
    budgets = (req["body_pointing_3sigma_arcsec"], req["body_stability_3sigma_arcsec_s"])
    out += [""] + verdict_table([("3σ %s, two axes in total" % what, None if v is None else round(v, 1), b,
                                  None if v is None else v <= b, th)
                                 for what, v, b, th in (("pointing (arcsec)", p3, budgets[0], th3[0]),
                                                        ("stability (arcsec/s)", w3, budgets[1], th3[1]))],
                                extra="thesis") + [
            "J = %s rad² (Eq. 6.22); largest pointing error %s arcsec; largest wheel speed %.0f rpm (the "
            "emulated wheels' datasheet: %s rpm; this run's limit %.0f rpm, reached %s times); "
            "wall %.1f s." % ("—" if s.get("J_rad2") is None else "%.3e" % s["J_rad2"],
                              "—" if s.get("pointing_max_arcsec") is None else "%.1f" % s["pointing_max_arcsec"],
                              s["max_wheel_speed_rpm"], "{:,.0f}".format(s.get("wheel_datasheet_rpm", control.WHEEL_DATASHEET.speed_max_rpm)),
                              s.get("wheel_speed_limit_rpm", float("nan")),
                              sum((s.get("wheel_speed_clips") or {}).get("speed_clip", [])), s["wall_s"]), "",
            "The thesis's wheels have no speed limit (Eq. 4.56), nor does this run in effect: the residual dipole's "
            "secular torque builds up in the wheels, which a flight design must unload (magnetorquers); the thesis "
            "does not model that (scenario.POINTING_WHEEL_RPM; bench_bps runs the same with 20,000 and 10,000 rpm "
            "limits).", "",
            ] + budget_md(s.get("budget")) + consistency_md(s.get("consistency")) + [
            "Known differences from the thesis: the APKF misses the thesis's attitude 1σ by ~2x (docs/ADCS.md, "
            "\"Attitude determination\"); "
            "the controller adds the command rate, w x H, the APKF's external-torque estimate, the wheels' "
            "datasheet friction and the absolute torque scale to Eq. 6.5 (firmware/adcs/allocation.py); a 30 s "
            "hold with rate damping on the estimate precedes the slew, and after the slew the rate is damped until "
            "the star tracker's first fix (firmware/adcs/modes.py); Eq. 6.7 as printed, wn = 8/t_s.", ""]
    return "\n".join(out)


def _name(spacecraft):
    """The spacecraft's name from a run's result (its name) or summary (``runs.spacecraft_record``)."""
    return spacecraft["name"] if isinstance(spacecraft, dict) else spacecraft or "thesis-3u"


def budget_md(b):
    """The error budget table (``bps.error_budget``), or nothing when the run was too short for one."""
    if not b:
        return []
    rows = [("total", "e(q): the pointing error at the 1 Hz instants"),
            ("estimation", "e(q) - e(q̂): the APKF's attitude error"),
            ("tracking", "e(q̂) - e(q_c): the controller's"),
            ("tracking_slow", "its %d s moving average: the bias a PD leaves" % bps.SLOW_S),
            ("command", "e(q_c): the STKF's and the command law's")]
    out = ["| error budget (arcsec) | δθ1 mean, 1σ | δθ2 mean, 1σ | what |", "|---|---|---|---|"]
    for k, what in rows:
        v, m = b[k + "_sigma_arcsec"], b.get(k + "_mean_arcsec")
        out.append("| %s | %s%.1f | %s%.1f | %s |" % (k, "" if m is None else "%.1f, " % m[0], v[0],
                                                       "" if m is None else "%.1f, " % m[1], v[1], what))
    return out + ["", "The parts are correlated (the controller acts on q̂), so their σ do not add in quadrature.", ""]


def plot_history(path, hist, settle_s, title, s=None):
    """Fig. 6-3/6-4 (``bps_plots.plot_history``)."""
    from ground.adcs import bps_plots
    bps_plots.plot_history(path, hist, settle_s, title, s)


def _f(v, fmt):
    return "—" if v is None else fmt % v


def consistency_md(c, stkf=None):
    """report.md's table of the estimators' 1 sigma against their errors (``app_host.consistency``; with ``stkf``,
    the flight world's ``pointing.stkf_consistency``, the STKF's velocities, rB - rA and all 12 states too)."""
    if not c:
        return []
    if not any(c.get(k) for k in ("apkf_attitude", "stkf_ra", "stkf_rb")):
        return ["The estimators' consistency is taken from %.0f s on: this run has no second there." % c["from_s"], ""]
    out = ["Whether each estimator's 1σ holds, from %.0f s (NEES of 3 dof per second; a consistent filter has ~%.0f %% "
           "of its seconds within [%.2f, %.2f], a mean of 3 and RMS error / RMS 1σ of 1 per axis):" % (
               c["from_s"], 100 * c["p"], c["band"][0], c["band"][1]), "",
           "| estimate | seconds | NEES in band | mean NEES | RMS / 1σ per axis |", "|---|---|---|---|---|"]
    rows = [(what, c.get(key)) for key, what in (("apkf_attitude", "attitude (APKF)"),
                                                  ("stkf_ra", "SatA's position (STKF)"),
                                                  ("stkf_rb", "SatB's position (STKF)"))]
    if stkf:
        rows += [(what, stkf.get(key)) for key, what in (("va", "SatA's velocity (STKF)"),
                                                          ("vb", "SatB's velocity (STKF)"),
                                                          ("rba", "rB − rA, what pointing takes (STKF)"))]
    for what, v in rows:
        if v:
            out.append("| %s | %d | %.2f | %.2f | %s |" % (what, v["seconds"], v["nees_in_band_share"], v["nees_mean"],
                                                          ", ".join("%.2f" % r for r in v["rms_over_sigma"])))
    v = (stkf or {}).get("nees12_full_cov")
    if v:
        out += ["", "The STKF's 12 states [rA, vA, rB, vB] against its full 12 × 12 covariance (NEES of 12 dof): "
                "%.2f of %d seconds within [%.2f, %.2f], mean %.2f (12 when consistent)." % (
                    v["nees_in_band_share"], v["seconds"], v["band"][0], v["band"][1], v["nees_mean"])]
    return out + [""]


def occultation_md(s):
    """report.md's lines on the line of sight to the partner (``occultation.summary``): whether the Earth (plus
    the atmosphere's margin) blocks it, and that blocked samples are left out of the pointing figures."""
    o = s.get("occultation")
    if not o:
        return []
    if not o["line_of_sight"]:
        out = ["**Verdict: no line of sight.** The line of sight to the partner passes within %g km of the Earth's "
               "surface (sphere of %.3f km) %s, so this run's pointing figures are not reported and no budget "
               "is met." % (o["margin_km"], o["earth_radius_km"],
                            "throughout the pointing window" if o["window_share"] is not None else
                            "throughout the run")]
    elif o["share"] == 0:
        out = ["Line of sight: clear of the Earth and %g km of atmosphere throughout (lowest %.0f km above the "
               "surface)." % (o["margin_km"], o["min_clearance_km"])]
    else:
        out = ["Line of sight: occulted %.1f %% of the run (the Earth and %g km of atmosphere in the way; lowest %.0f "
               "km): those samples are left out of the pointing figures, the passes and the error budget (%d "
               "samples of the pointing window)." % (100 * o["share"], o["margin_km"], o["min_clearance_km"],
                                                     o.get("excluded_samples", 0))]
    iv = o["intervals"]
    if iv:
        out.append("Occulted: " + ", ".join("%.0f s for %.0f s" % (a, b) for a, b in iv[:10])
                   + (" and %d more (summary.json)" % (len(iv) - 10) if len(iv) > 10 else "") + ".")
    return out + [""]


def report_flight_md(s, args_text):
    """report.md of a flight-world run: the checks, each pass, the modes, the wheels and magnetorquers."""
    out = ["# Body pointing in the flight world", "", "`%s`" % args_text, "",
           "Spacecraft %s; t_s = %g s, %s SatB's GNSS, %.0f s (%.2f orbits of %.0f s), truth %s, seed %d. "
           "complete: %s" % (_name(s.get("spacecraft")), s["ts_s"], "with" if s["satb_gnss"] else "without",
                            s["simulated_s"], s["simulated_s"] / s["orbit_period_s"], s["orbit_period_s"],
                            s["truth"], s["seed"], s["complete"]), ""] + occultation_md(s) + [
           ] + verdict_table([(c["what"], c.get("ours"), c.get("budget"), c["ok"]) for c in s["checks"].values()])
    out += ["", "| pass (orbit) | from (s) | samples (10 Hz, POINT) | 3σ pointing (arcsec) | 3σ stability "
            "(arcsec/s) | largest wheel speed (rpm) |", "|---|---|---|---|---|---|"]
    for p in s["passes"]:
        if p.get("pointing_3sigma_arcsec") is None:
            out.append("| %d | — | %d | — | — | — |" % (p["orbit"], p["samples"]))
        else:
            out.append("| %d | %.0f | %d | %.1f | %.1f | %.0f |" % (
                p["orbit"], p["t_from_s"], p["samples"], p["pointing_3sigma_arcsec"],
                p["stability_3sigma_arcsec_s"], p["max_wheel_speed_rpm"]))
    tm = s["time_in_mode_s"]
    out += ["", "Time in each mode: " + ", ".join("%s %.0f s" % (k, v) for k, v in tm.items()) + ".",
            "Star tracker blind %s %% of the time after the first slew; the STKF took the beacon %.1f %% of the "
            "seconds (gated by the attitude 1σ); APKF attitude resets on a large innovation: %d." % (
                _f(None if s["star_tracker_blind_share"] is None else 100 * s["star_tracker_blind_share"], "%.2f"),
                100 * s["beacon_used_share"], len(s["apkf_attitude_resets"])),
            "Wheels: largest %s rpm after the first orbit (%.0f rpm over the run; limit %.0f rpm, speed clips %d); "
            "momentum at most %s N m s, %s at the end. Magnetorquers: duty %.2f (mean of the largest rod's |m| "
            "over its limit), saturated %.1f %% of the seconds." % (
                _f(s["max_wheel_speed_rpm"], "%.0f"), s["max_wheel_speed_rpm_run"], s["wheel_speed_limit_rpm"],
                sum((s.get("wheel_speed_clips") or {}).get("speed_clip", [])), _f(s["wheel_momentum_max_nms"], "%.2e"),
                _f(s["wheel_momentum_end_nms"], "%.2e"), s["mtq_duty"], 100 * s["mtq_saturated_share"]), ""]
    out += ["Estimation: %s." % stkf_text(s.get("stkf")), ""]
    out += consistency_md(s.get("consistency"), s.get("stkf_consistency"))
    out += ["| t (s) | mode change | reason |", "|---|---|---|"]
    for c in s["mode_changes"][:50]:
        out.append("| %.0f | %s -> %s | %s |" % (c["t_s"], c["from"], c["to"], c["reason"]))
    if len(s["mode_changes"]) > 50:
        out.append("| ... | %d more in summary.json | |" % (len(s["mode_changes"]) - 50))
    out += ["", "Not the thesis's world (that is `--world thesis`): datasheet wheel limits, drag and solar "
            "pressure torques, magnetorquer unloading, a rate-limited slew and the gates, flown by the flight app "
            "(firmware/adcs/app.py) in process%s." % (
                " on the ground's estimators (41-state APKF, full STKF: ground/adcs/estimators.py)"
                if s.get("estimator") == "ground" else ""), ""]
    return "\n".join(out)


def plot_flight(out, hist, s):
    """flight_pointing.png and flight_wheels.png (``bps_plots.plot_flight``)."""
    from ground.adcs import bps_plots
    bps_plots.plot_flight([os.path.join(out, f) for f in FIGURES_FLIGHT], hist, s)


def zeta_groups(s):
    """The points of a sweep summary per curve: [(zeta, indices)], one (None, all) without a zeta grid."""
    if s.get("zeta") is None:
        return [(None, list(range(len(s["ts_s"]))))]
    return [(z, [i for i, zi in enumerate(s["zeta"]) if zi == z]) for z in s["zeta_values"]]


def _curve(s, key, idx):
    """{t_s: value} of the points ``idx`` whose ``key`` is not None."""
    return dict((s["ts_s"][i], s[key][i]) for i in idx if s[key][i] is not None)


def plot_sweep(path, s):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ground.plots import save_png
    fig, ax = plt.subplots(figsize=(7, 4))
    for k, (z, idx) in enumerate(zeta_groups(s)):
        pts = _curve(s, "J", idx)
        if pts:
            ax.plot(list(pts), list(pts.values()), "o-", color="C%d" % (2 * k),
                    label=None if z is None else "J(t_s), ours, ζ = %g" % z)
    if s["ts_best_s"] is not None:
        ax.axvline(s["ts_best_s"], color="C1", ls="--", label="ours: %g s%s" % (
            s["ts_best_s"], "" if s.get("zeta") is None else ", ζ = %g" % s["zeta_best_s"]))
    ax.axvline(bps.TS_THESIS, color="k", ls=":", label="thesis: 33 s")
    ax.set_xlabel("t_s (s)")
    ax.set_ylabel("J (rad²)")
    ax.set_yscale("log")
    from matplotlib.ticker import LogFormatterSciNotation, LogLocator
    ax.yaxis.set_minor_locator(LogLocator(subs=(2, 3, 5)))          # J spans less than a decade: label 2, 3, 5
    ax.yaxis.set_minor_formatter(LogFormatterSciNotation(labelOnlyBase=False, minor_thresholds=(4, 1)))
    ax.grid(True, which="both", lw=0.3)
    if s.get("zeta") is None:
        ax.plot([], [], "C0o-", label="J(t_s), ours")
    ax.legend()
    ax.set_title("Objective J for the settling time (Fig. 6-2)")
    fig.tight_layout()
    save_png(fig, path, dpi=90)


def _index_of(s, what):
    """The point of the summary's best ``what`` (body, terminal, terminal_in_budget): its t_s and zeta; None."""
    t, z = s["ts_best_%s_s" % what], s.get("zeta_best_%s" % what)
    zs = s.get("zeta") or [None] * len(s["ts_s"])
    return next((i for i, (ti, zi) in enumerate(zip(s["ts_s"], zs)) if ti == t and zi == z), None)


def plot_objectives(path, s):
    """Fig. 6-2 with both objectives of a ``--objective terminal`` sweep: J of the body error (left axis, rad²)
    and the 3σ residual after the fine loop (right axis, arcsec), both on log scales (on a zeta grid one curve
    per zeta and objective, a colour per zeta), each one's minimum marked (the residual's also among the points
    within the body budgets), and the thesis's 33 s."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ground.plots import save_png
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax2 = ax.twinx()
    grid = s.get("zeta") is not None
    curves = ((ax, "J", "C0", "o--" if grid else "o-", "body objective J (rad²)", (("", "body", "*"),)),
              (ax2, "residual_3sigma_arcsec", "C3", "s-", "terminal objective: 3σ residual after the fine loop "
               "(arcsec)", (("", "terminal", "*"), (" within the body budgets", "terminal_in_budget", "P"))))
    for a_, key, color, style, label, bests in curves:
        for k, (z, idx) in enumerate(zeta_groups(s)):
            pts = _curve(s, key, idx)
            if pts:
                a_.plot(list(pts), list(pts.values()), style, color="C%d" % k if grid else color, ms=4,
                        label="%s, ζ = %g" % (label.split(" (")[0], z) if grid else label)
                a_.set_ylabel(label, color="k" if grid else color)
                a_.set_yscale("log")
        for what, best, marker in bests:
            i = _index_of(s, best)
            if i is not None:
                a_.plot([s["ts_s"][i]], [s[key][i]], marker, color=color, ms=15, mec="k", label="minimum%s: %g s%s"
                        % (what, s["ts_s"][i], ", ζ = %g" % s["zeta"][i] if grid else ""))
    ax.axvline(bps.TS_THESIS, color="k", ls=":", label="thesis: 33 s")
    ax.set_xlabel("t_s (s)")
    ax.grid(True, which="both", lw=0.3)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper center")
    ax.set_title("Settling time by the body error (Fig. 6-2) and by the residual after the fine loop", fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=90)
