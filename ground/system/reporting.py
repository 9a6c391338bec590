"""What ``fps system`` reports: the verdict against both loops' budgets, report.md's tables beside the thesis's, the figure."""

import json

import numpy as np

from ground import hil, report
from ground.system.constants import FIGURE, GOAL_RTF
from ground.verdict import table as verdict_table


def verdict(s):
    """One verdict for the terminal from a summary's figures, against its ``requirements`` (the spacecraft
    file's block, or the thesis's: ``protocol.spacecraft.requirements``). Fine loop: every Q2 sample within
    ``fine_pointing_arcsec`` (the thesis's 11.98″) and none with the beam lost (``fps hil``'s requirement). Body
    loop: 3σ pointing and stability within ``body_pointing_3sigma_arcsec`` and ``body_stability_3sigma_arcsec_s``
    (as ``fps adcs can`` judges them). On the PIL board (``--runtime qemu``) the fine loop's controller must also
    send every FSM_SPI within its tick with the UART's bytes (``board``: ``hil_report.wire_deadline``; None on the
    other runtimes). A loop's ``met`` is None without figures; ``met`` is true only when the run completed and
    both loops (and the board) are met. ``missed``: one line per figure that missed, naming the loop and by how
    much."""
    from ground.hil_report import wire_deadline
    from protocol import spacecraft as sf
    r = s.get("requirements") or sf.requirements(None)
    req = r["fine_pointing_arcsec"]
    n, lost = int(s.get("q2_samples") or 0), int(s.get("q2_beam_lost_samples") or 0)
    worst = (s.get("q2") or {}).get("max_radial_arcsec")
    fine = {"met": None if n == 0 else bool(lost == 0 and worst is not None and worst <= req),
            "worst_arcsec": worst, "budget_arcsec": req, "over_arcsec": _over(worst, req),
            "q2_samples": n, "beam_lost_samples": lost}
    b = s.get("body_pointing") or {}
    p, w = b.get("pointing_3sigma_arcsec"), b.get("stability_3sigma_arcsec_s")
    pb, wb = r["body_pointing_3sigma_arcsec"], r["body_stability_3sigma_arcsec_s"]
    body = {"met": None if p is None or w is None else bool(p <= pb and w <= wb),
            "pointing_3sigma_arcsec": p, "pointing_budget_arcsec": pb, "pointing_over_arcsec": _over(p, pb),
            "stability_3sigma_arcsec_s": w, "stability_budget_arcsec_s": wb,
            "stability_over_arcsec_s": _over(w, wb), "samples": b.get("samples")}
    missed = []
    if fine["met"] is None:
        missed.append("fine: no Q2 sample recorded")
    elif not fine["met"]:
        if worst is not None and worst > req:
            missed.append("fine: largest Q2 error %.2f″ over the %.2f″ budget by %.2f″"
                          % (worst, req, worst - req))
        if lost:
            missed.append("fine: beam lost on Q2 in %d of %d samples" % (lost, n))
    if body["met"] is None:
        missed.append("body: no figures (fewer than 2 samples of the window played)")
    else:
        if p > pb:
            missed.append("body: 3σ pointing %.1f″ over the %g″ budget by %.1f″" % (p, pb, p - pb))
        if w > wb:
            missed.append("body: 3σ stability %.1f″/s over the %g″/s budget by %.1f″/s" % (w, wb, w - wb))
    board = wire_deadline(s)
    if board is not None and not board["met"]:
        missed.append("fine: the controller board's worst tick %d cycles on the wire at %d baud, over its %d by %d; "
                      "%d of %d ticks late" % (board["worst_cycles"], board["baud"], board["period_cycles"],
                                               max(0, board["worst_cycles"] - board["period_cycles"]),
                                               board["late_ticks"], board["ticks"]))
    complete = bool(s.get("complete"))
    met = complete and fine["met"] and body["met"] and (board is None or board["met"])
    return {"complete": complete, "met": bool(met), "fine": fine, "body": body, "board": board, "missed": missed}


def _over(v, budget):
    return None if v is None else max(0.0, float(v) - budget)


def exit_code(s):
    """``fps system``'s exit status for a finished summary: 0 the run completed and both loops met their budgets,
    3 it completed but a budget was missed, 1 it did not complete."""
    v = s.get("verdict") or verdict(s)
    return 0 if v["met"] else (3 if v["complete"] else 1)


def verdict_lines(s):
    """The closing lines: ``hil.verdict_lines`` for the fine loop, then the body loop's and the terminal's."""
    v = s.get("verdict") or verdict(s)
    lines = ["fine loop: " + line if line.lower().startswith("requirement ") else line
             for line in hil.verdict_lines(dict(s, requirement_met=bool(v["complete"] and v["fine"]["met"])))]
    b = v["body"]
    if not v["complete"]:
        return lines
    if b["met"] is None:
        lines.append("body loop: no figures (fewer than 2 samples of the window played)")
    else:
        lines.append("body loop %s: 3σ pointing %.1f″ (budget %g″), 3σ stability %.1f″/s (budget %g″/s)" % (
            "within its budgets" if b["met"] else "BUDGET MISSED", b["pointing_3sigma_arcsec"],
            b["pointing_budget_arcsec"], b["stability_3sigma_arcsec_s"], b["stability_budget_arcsec_s"]))
    lines.append("terminal: both loops within their budgets" if v["met"] else
                 "TERMINAL BUDGET MISSED: " + "; ".join(v["missed"]))
    return lines


def verdict_md(s):
    """The report's verdict: each loop's figure against its budget, and the terminal's."""
    v = s.get("verdict") or verdict(s)
    f, b = v["fine"], v["body"]
    rows = [("fine loop (Q2): largest radial error (arcsec)", f["worst_arcsec"], f["budget_arcsec"], f["met"],
             f["over_arcsec"]),
            ("body loop (ADCS): 3σ pointing (arcsec)", b["pointing_3sigma_arcsec"], b["pointing_budget_arcsec"],
             None if b["met"] is None else b["pointing_over_arcsec"] == 0, b["pointing_over_arcsec"]),
            ("body loop (ADCS): 3σ stability (arcsec/s)", b["stability_3sigma_arcsec_s"],
             b["stability_budget_arcsec_s"], None if b["met"] is None else b["stability_over_arcsec_s"] == 0,
             b["stability_over_arcsec_s"])]
    w = v.get("board")
    if w is not None:
        rows.append(("fine loop (controller board): the worst tick's FSM_SPI out, the UART at %d baud (cycles at "
                     "48 MHz)" % w["baud"], w["worst_cycles"], w["period_cycles"], w["met"],
                     max(0, w["worst_cycles"] - w["period_cycles"])))
    out = verdict_table(rows, extra="over by")[:-1]
    if f["beam_lost_samples"]:
        out.append("")
        out.append("The beam was lost on Q2 in %d of %d samples (the fine loop misses)."
                   % (f["beam_lost_samples"], f["q2_samples"]))
    av = s.get("availability") or {}
    if av.get("availability") is not None:
        from ground.hil_report import availability_line
        out.append("")
        out.append(availability_line(av, (s.get("truth") or {}).get("max_radial_arcsec")).capitalize() + ".")
        for o in av["outages"][:10]:
            out.append("- outage from t = %.2f s, %.3f s, peak %s″: %s%s" % (
                o["start_s"], o["length_s"], _f(o["peak_arcsec"], "%.1f"), o["cause"] or "cause unknown",
                "" if o["ended"] else " (not re-acquired by the end)"))
    out.append("")
    if not v["complete"]:
        why = ": %s" % s["error"] if s.get("error") else (", interrupted" if s.get("interrupted") else "")
        out.append("**Terminal: not judged: the run did not complete** (stopped in %s%s)."
                   % (s.get("stopped_in") or s.get("phase") or "?", why))
    elif v["met"]:
        out.append("**Terminal: both loops within their budgets.**")
    else:
        out.append("**Terminal: BUDGET MISSED**: %s." % "; ".join(v["missed"]))
    return "\n".join(out)


def thesis_body():
    """The Ch. 6 budget (3 sigma) and Sec. 6.4.4's measured figures (t_s = 33 s, 4000 s) as 3 sigma of the norm."""
    from ground.adcs import body_pointing as bps
    out = {"pointing_3sigma_arcsec": bps.BUDGET_POINTING_3SIGMA,
           "stability_3sigma_arcsec_s": bps.BUDGET_STABILITY_3SIGMA}
    for satb, key in ((False, "sec644_no_satb_gnss"), (True, "sec644_satb_gnss")):
        th = bps.THESIS[satb]
        p3, w3 = bps.thesis_3sigma(satb)
        out[key] = {"pointing_3sigma_arcsec": p3, "stability_3sigma_arcsec_s": w3,
                    "pointing_sigma_arcsec": [th["theta"][0][1], th["theta"][1][1]]}
    return out


def _plot(rec, feed, q2cal, t_settle, faults=None, requirements=None):
    """system_pointing.png on the ADCS's clock (the fault options'): the body error over the window played and the
    fine error, both from the ADCS's start, against the ``requirements`` the verdict reads (default the
    thesis's)."""
    from ground import plots as plt_mod
    from protocol import spacecraft as sf
    t, dth, _dom, _te, _e = feed.arrays()
    q2, _truth = rec.arrays()
    body = fine = None
    if len(t):
        sel = (t >= t_settle - 1e-9) & (t <= t_settle + rec.virtual_s + 1e-9)     # the window played
        body = (t[sel], dth[sel, 0], dth[sel, 1])
    if len(q2) and q2cal is not None:
        e = hil.q2_error_arcsec(q2, q2cal)
        ok = np.all(np.isfinite(e), axis=1)
        fine = ((q2[ok, 1] - rec.t0_us) * 1e-6 + t_settle, e[ok, 0], e[ok, 1])
    if body is not None or fine is not None:
        r = requirements or sf.requirements(None)
        plt_mod.system_time_history(body, fine, rec.path(FIGURE), r["fine_pointing_arcsec"],
                                    r["body_pointing_3sigma_arcsec"], faults)


def _f(v, fmt="%.2f"):
    if v is None:
        return "—"
    if isinstance(v, (list, tuple)):
        return "(%s)" % ", ".join(fmt % x for x in v)
    return fmt % v


def side_by_side(s):
    """The report's table: this run beside the ground filters on the same scenario, and the thesis."""
    b = s.get("body_pointing") or {}
    e = s.get("estimation") or {}
    ref = s.get("ground_reference") or {}
    re = ref.get("estimation") or {}
    q2 = s.get("q2") or {}
    col = "this run (ADCS: %s)" % s.get("adcs")
    tb = s["thesis_body"]
    t6 = tb.get("sec644_satb_gnss" if s.get("satb_gnss") else "sec644_no_satb_gnss") or {}
    rows = [("body pointing 3σ (arcsec)", b.get("pointing_3sigma_arcsec"), ref.get("pointing_3sigma_arcsec"),
             "≤ %g (budget); %s (Sec. 6.4.4, 4000 s)" % (tb["pointing_3sigma_arcsec"],
                                                         _f(t6.get("pointing_3sigma_arcsec"), "%.1f"))),
            ("body pointing 1σ X, Y (arcsec)", b.get("pointing_sigma_arcsec"), ref.get("pointing_sigma_arcsec"),
             "%s (Sec. 6.4.4)" % _f(t6.get("pointing_sigma_arcsec"), "%.3f")),
            ("body stability 3σ (arcsec/s)", b.get("stability_3sigma_arcsec_s"), ref.get("stability_3sigma_arcsec_s"),
             "≤ %g (budget); %s (Sec. 6.4.4)" % (tb["stability_3sigma_arcsec_s"],
                                                 _f(t6.get("stability_3sigma_arcsec_s"), "%.1f"))),
            ("attitude estimate 3σ (arcsec)", e.get("attitude_3sigma_arcsec"), re.get("attitude_3sigma_arcsec"), "—"),
            ("rate estimate 3σ (arcsec/s)", e.get("rate_3sigma_arcsec_s"), re.get("rate_3sigma_arcsec_s"), "—"),
            ("SatA position RMS (m)", e.get("ra_rms_m"), re.get("ra_rms_m"), "—"),
            ("SatB position RMS (m)", e.get("rb_rms_m"), re.get("rb_rms_m"), "—"),
            ("fine pointing 1σ X, Y (arcsec, Q2)", q2.get("std_arcsec"), None, _f(report.THESIS["std_arcsec"], "%.4f")),
            ("fine pointing largest radial (arcsec)", q2.get("max_radial_arcsec"), None,
             "%.4f" % report.THESIS["max_radial_arcsec"]),
            ("fine share within 11.98″", q2.get("within_requirement"), None, "100 % (goal)"),
            ("mean pointing loss (dB)", q2.get("pointing_loss_db"), None, "%.4f (est.)" % report.THESIS["pointing_loss_db"])]
    out = ["| figure | %s | ground filters, same scenario | thesis |" % col, "|---|---|---|---|"]
    for label, mine, theirs, th in rows:
        fmt = "%.4f %%" if "share" in label else ("%.4f" if "fine" in label or "loss" in label else "%.2f")
        m = _f(None if mine is None else (100 * mine if "share" in label else mine), fmt)
        out.append("| %s | %s | %s | %s |" % (label, m, _f(theirs, fmt), th))
    return "\n".join(out)


def _hold_s():
    from ground.adcs import body_pointing as bps
    return bps.HOLD_S


def report_md(s):
    lines = ["# fps system: %.1f s of the collection window (ADCS %s, fine-pointing controller %s over serial)"
             % (s.get("duration_s") or 0.0, s.get("adcs"), s.get("runtime")), "", verdict_md(s), "",
             side_by_side(s), ""]
    if s.get("adcs") == "ground":
        lines.append("The ADCS of this run is the ground body pointing simulator itself, so both columns come "
                     "from the same run.")
    else:
        lines.append("Ground filters: `bps.simulate` with the same seed, duration, t_s, SatB GNSS and parameter "
                     "file; its sensor noise draws differ from the emulated spacecraft's, so the columns compare "
                     "the filters' accuracy, not the same noise.")
    settled = ("the %g s hold and 4 t_s of settling" % _hold_s() if s.get("world") == "thesis" else
               "the %g s hold, the planned first slew and its re-acquisition, and 4 t_s of settling" % _hold_s())
    lines.append("Estimates are compared with the truth at the instant of each 1 s cycle's estimate; the window "
                 "starts after %s (t = %.0f s)." % (settled, s.get("settle_s") or 0))
    if s.get("stkf_accel"):
        lines.append("The flight STKF's acceleration beyond its J2 model (hpop truth): %s (`--stkf-accel`)."
                     % s["stkf_accel"])
    lines += ["", "## Fine pointing (Q2 recorder, as fps hil)", "", report.table(s), "",
              report.saturation_md(s.get("saturation")), "",
              "real-time factor: %s over the whole command (%.1f s wall, goal ≥ %gx), %s during the play; "
              "the fine loop waited %.1f s for the ADCS" % (_x(s.get("real_time_factor")), s.get("wall_s") or 0.0,
                                                             GOAL_RTF, _x(s.get("real_time_factor_play")),
                                                             s.get("adcs_wait_s") or 0.0), ""]
    if s.get("adcs_summary") is not None or s.get("adcs_last_status") is not None:
        lines += adcs_session_md(s.get("adcs_summary"), s.get("adcs_last_status"))
    lines += ["- " + line for line in verdict_lines(s)]
    return "\n".join(lines) + "\n"


def _cell(v):
    """A value for a Markdown table cell: numbers and text as they are, lists and dicts as compact JSON."""
    if isinstance(v, (dict, list)):
        return "`%s`" % json.dumps(v, separators=(", ", ": "))
    return "%s" % (v,)


def wheel_names(mask):
    """The wheels a bit mask names (bit i: wheel i, ``RWi``), e.g. 2 -> "RW1"; "none" for 0."""
    if not isinstance(mask, int):
        return "—"
    names = ["RW%d" % i for i in range(8) if mask >> i & 1]
    return ", ".join(names) if names else "none"


def adcs_session_md(summary, status):
    """The report's ADCS section as Markdown tables: the mode changes, the fault log, the counters, the last
    status (bit masks decoded into wheel and sensor names)."""
    out = ["## ADCS session", ""]
    summary = dict(summary or {})
    changes, faults = summary.pop("mode_changes", None), summary.pop("fault_log", None)
    target, ipc = summary.pop("target", None), summary.pop("instructions_per_cycle", None)
    if target and ipc and ipc.get("n"):      # --runtime qemu: the ADCS's board
        f = target["clock_hz"]
        out += ["| ADCS board | instructions a cycle, mean | largest | share of 1 s at %.0f MHz (CPI %g-%g) |"
                % (f / 1e6, target["cpi_range"][0], target["cpi_range"][1]), "|---|---|---|---|",
                "| %s | %.2f M | %.2f M | %.1f-%.1f %% |" % (target["core"], ipc["mean"] / 1e6, ipc["max"] / 1e6,
                                                        100 * ipc["mean"] * target["cpi_range"][0] / f,
                                                        100 * ipc["mean"] * target["cpi_range"][1] / f), ""]
    if changes:
        out += ["| t (s) | mode change | reason |", "|---|---|---|"]
        out += ["| %.0f | %s -> %s | %s |" % (c["t_s"], c["from"], c["to"], c["reason"]) for c in changes] + [""]
    if faults:
        out += ["| t (s) | event |", "|---|---|"] + ["| %.0f | %s |" % (e["t_s"], e["event"]) for e in faults] + [""]
    if summary:
        out += ["| counter | value |", "|---|---|"] + ["| %s | %s |" % (k, _cell(v)) for k, v in summary.items()]
        out.append("")
    if status:
        st = dict(status)
        if "wheels_failed" in st:
            st["wheels_failed"] = "%s (bit mask %s)" % (wheel_names(st["wheels_failed"]), st["wheels_failed"])
        out += ["| last status | value |", "|---|---|"] + ["| %s | %s |" % (k, _cell(v)) for k, v in st.items()]
        out.append("")
    return out


def _x(v):
    return "—" if v is None else "%.1fx" % v
