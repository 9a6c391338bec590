"""``fps adcs can``: the ADCS flight software (its own micropython or CPython process, or the ADCS PIL board under
QEMU) steering the emulated spacecraft over CAN (Lawicel over a pty, python-can's slcan on the emulator side), with
optional faults (one option each, or ``--faults FILE``).

Run folder (``-o DIR``, atomic writes): ``summary.json`` (written at the start with ``complete`` false; the
session's counters, the link's retries and faults, the fault log, the ADCS's last status and the body
pointing figures after the hold and 4 t_s, arcsec and arcsec/s), ``history.npz`` (10 Hz truth t, q, w and the
pointing error dtheta/domega in arcsec; 1 Hz status fields, the flight software's estimates ``est_q``,
``est_w``, ``est_ra``, ``est_rb`` and the wheel commands applied ``rw_cmd_nm``), ``report.md`` (the verdict table,
the run, the mode changes and the faults), ``pointing.png`` (the pointing error with the ADCS mode). ``--link-faults`` damages the slcan stream (bit flips, frame lines dropped, both
directions): the lockstep's retries keep every cycle exactly once, and the retries are counted in the summary.
A run that fails (the firmware exits or hangs, no HELLO, the link closes) leaves ``summary.json`` with ``complete``
false, the ``error`` and the link's counters (exit 1).
Ctrl-C or SIGTERM leaves a valid folder with ``complete`` false and every cycle flown so far (exit 130); the
firmware's process (or QEMU) dies with this one however it ends. ``budgets_met``: the pointing figures against the
3σ budgets (150 arcsec, 35 arcsec/s); a run that misses them exits 3, one too short to have them (null) exits 0.
"""

import os
import sys

import numpy as np

from emulator.adcs_session import RUNTIMES
from emulator.runtime import interrupts_between
from emulator.spacecraft import scenario
from ground.adcs import body_pointing as bps, campaign
from ground.adcs.bps_cli import CACHE_DEFAULT
from ground.adcs.flight_world import stkf_text
from ground.adcs.options import (add_fault_options, add_satb_gnss_option, add_session_option, add_spacecraft_option,
                                add_stkf_accel_option, check_session, check_stkf_accel, faults_from_args, fly,
                                load_spacecraft, refuse_option)
from ground import verdict
from ground.fileio import cache_folder, output_folder, run_folder, write_atomic, write_json
from protocol import spacecraft as sf
from protocol.units import RAD_PER_ARCSEC

FIGURE = "pointing.png"
STATUS_KEYS = ("tick", "adcs_mode", "stale", "wheels_failed", "miss_st", "miss_gnss", "miss_beacon", "n_gnss_b",
               "n_refused", "att_sigma", "cycle_us")


def register(sub):
    p = sub.add_parser("can", help="the ADCS flight firmware on CAN against the emulated spacecraft",
                       description=__doc__.split("\n\n")[0])
    add_session_option(p, 600.0, "the 30 s hold and 4 t_s of settling (flight world: the planned slew and 4 t_s) "
                       "included, the pointing figures collected after them, 1 to %g (default 600)"
                       % campaign.MAX_DURATION_S)
    refuse_option(p, "--duration", "fps adcs can's length is --session S, the whole session from power-on in "
                  "seconds, the hold and the settling included (--duration, on fps system and fps adcs bps, is "
                  "the window collected after the settling)")
    p.add_argument("--runtime", default="micropython", choices=RUNTIMES,
                   help="the firmware's interpreter: micropython or cpython in a process of its own on CAN, "
                        "inproc (the same app and bytes in this process, no link), or qemu, the ADCS PIL board of "
                        "make pil (a Cortex-M7 with its FPU under QEMU; default micropython)")
    add_satb_gnss_option(p, False)
    p.add_argument("--ts", type=float, default=33.0, help="settling time t_s of the PD, s, in (0, %g] "
                   "(default 33)" % bps.MAX_TS_S)
    p.add_argument("--seed", type=int, default=0, help="scenario seed, >= 0 (default 0)")
    p.add_argument("--params", default=None, help="parameter file (fps adcs bps format, checked against "
                                                  "--spacecraft; default: a perfect calibration of the emulated "
                                                  "spacecraft)")
    add_spacecraft_option(p, "the emulated vehicle (inertia, dipole, wheels, star tracker), its orbits, epoch and "
                          "sensors, the default parameter file, and the firmware's configuration (wheel axes and "
                          "limits, sensor noise, initial 1 sigma, STKF P0, laser axis) from it")
    p.add_argument("--world", choices=bps.WORLDS, default="thesis",
                   help="thesis (default): Sec. 6.4's world; flight: the spacecraft file's wheel limits, drag and "
                        "solar pressure, its magnetorquers and magnetometer on the bus, and the firmware's flight "
                        "modes (rate-limited slew, re-acquisition, unloading); the pointing figures then start at "
                        "the planned slew's end plus 4 t_s (bps.flight_settle_s)")
    p.add_argument("--truth", choices=("two-body", "hpop"), default="two-body",
                   help="true orbits: two-body (default, fast) or hpop (brahe's high-fidelity orbits, computed "
                        "once into --cache-dir; in the flight world the STKF then flies its J2 model)")
    p.add_argument("--cache-dir", default=CACHE_DEFAULT, type=cache_folder,
                   help="the hpop truth's cache (--truth hpop; default %s)" % CACHE_DEFAULT)
    add_stkf_accel_option(p, "--world flight with --truth hpop")
    add_fault_options(p, "seconds from the session's start")
    p.add_argument("--link-faults", metavar="SPEC", default=None,
                   help="faults on the slcan stream, both directions: bytes=P (a bit flip per ASCII byte), "
                        "frames=P (a CAN frame's line dropped), seed=N, silence=START_S:LENGTH_S (seconds of the "
                        "run; LENGTH_S may be inf), first=N (the first N frame lines each way dropped, from the "
                        "firmware's HELLO on), e.g. bytes=0.001,frames=0.05,seed=1")
    p.add_argument("--quiet", action="store_true", help="no progress bar or messages")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("-o", "--output", required=True, type=output_folder, help="run folder")
    p.set_defaults(func=run)


def run(a):
    from emulator.spacecraft.scenario import HOLD_S
    check_session(a.session)
    a.stkf_accel = check_stkf_accel(a.stkf_accel, a.world, a.truth, runtime=a.runtime)    # "white" when not given
    bps.check_ts(a.ts)
    campaign.check_seed(a.seed)
    d, source = load_spacecraft(a.spacecraft, partner=True)
    d, record = fly(d, source, a.seed, a.vehicle)
    session, faults = _session(a, d)
    out = a.output
    run_folder(out, (FIGURE,))
    write_json(os.path.join(out, "summary.json"), {"complete": False, "faults": faults or {}, "spacecraft": record})
    try:
        rows, summary, interrupted = _fly(session, a)
    except OSError as exc:                   # the run failed: the folder says why, with the link's counters
        write_json(os.path.join(out, "summary.json"), dict(session.summary(), complete=False, interrupted=False,
                                                           error=str(exc), spacecraft=record))
        raise
    summary["complete"] = bool(summary["complete"] and not interrupted)
    summary["interrupted"] = interrupted
    summary["spacecraft"] = record
    summary["requirements"] = sf.requirements(d)
    summary["truth"] = a.truth
    if a.world == "flight":
        summary["stkf"] = session.stkf_form()      # the STKF's dynamics flown: its form and keywords
    hist = rows["hist"]
    h = {k: np.concatenate(v) if v else np.zeros((0, 3)) for k, v in hist.items()}
    settle = HOLD_S + 4 * a.ts if a.world == "thesis" else bps.flight_settle_s(d, a.ts)
    summary["settle_s"] = settle
    board = session.board()                  # --runtime qemu: the board and its instructions per cycle
    if board is not None:
        summary.update(board)
    if a.world == "flight":
        w = np.concatenate(hist["w"]) if hist["w"] else np.zeros((0, 3))
        summary["wheel_speed_limit_rpm"] = d["wheels"]["speed_limit_rpm"]
        summary["max_wheel_speed_rpm"] = session.wheel_rpm_max(settle)      # after the planned settling
        summary["star_tracker_blind_share"] = session.blind_share(settle)
        summary["max_body_rate_deg_s"] = float(np.degrees(np.linalg.norm(w, axis=1).max())) if len(w) else None
    _pointing(summary, h, settle, scenario.laser_axis(d))
    h.update(("status_" + k, np.asarray(v)) for k, v in rows["stat"].items())
    h.update(("est_" + k, np.asarray(v)) for k, v in rows["est"].items())
    h["rw_cmd_nm"] = np.asarray(rows["rw_cmd"])
    bps.save_history(os.path.join(out, "history.npz"), h)
    if not a.no_plots and "dtheta_arcsec" in h:
        from ground.adcs import bps_plots
        bps_plots.adcs_can_pointing(h, os.path.join(out, FIGURE), faults, summary)
    write_json(os.path.join(out, "summary.json"), summary)
    write_atomic(os.path.join(out, "report.md"), report_md(summary, a))
    _say(summary, a)
    verdict.close(out, verdict_lines(summary), err=("BUDGET", "INTERRUPTED"))
    if interrupted:
        return 130
    return 3 if summary["budgets_met"] is False else 0


def verdict_rows(s):
    """The verdict's rows (what, ours, limit, met: True, False or None when the run has no figure): the body
    pointing and stability 3σ against the budgets the verdict reads (``s["requirements"]``)."""
    p, req = s.get("pointing") or {}, s["requirements"]
    return [(what, p.get(key), req[limit], None if p.get(key) is None else p[key] <= req[limit])
            for what, key, limit in (("body pointing 3σ (arcsec)", "pointing_3sigma_arcsec",
                                      "body_pointing_3sigma_arcsec"),
                                     ("body stability 3σ (arcsec/s)", "stability_3sigma_arcsec_s",
                                      "body_stability_3sigma_arcsec_s"))]


def verdict_lines(s):
    """The closing lines: the requirements met, missed (with each figure and its budget) or not reached."""
    if s.get("interrupted"):
        return ["INTERRUPTED after %d cycles: partial run, complete=false" % s["cycles"]]
    rows = verdict_rows(s)
    src = "the spacecraft file's" if s["requirements"]["source"] == "file" else "the thesis's"
    text = "; ".join("%s %.1f (budget %g)" % (w, v, lim) for w, v, lim, _ in rows if v is not None)
    if s["budgets_met"] is None:
        return ["no verdict: the run ended before the pointing window (%.0f s of settling), exit 0"
                % s["settle_s"]]
    if s["budgets_met"]:
        return ["requirements met (%s budgets): %s" % (src, text)]
    return ["BUDGET MISSED (%s budgets): %s%s" % (src, text, "" if s["complete"] else "; the run did not complete")]


def report_md(s, a):
    """report.md: the verdict table, the run, the mode changes and the faults."""
    sc = s.get("spacecraft") or {}
    out = ["# fps adcs can: the ADCS flight software over CAN", "",
           "Spacecraft %s (file %s, sha256 %s, vehicle %s); world %s; truth %s; runtime %s; t_s = %g s; seed %d; "
           "%s SatB's GNSS. complete: %s" % (sc.get("name"), sc.get("source"), sc.get("sha256"),
                                             (sc.get("vehicle") or {}).get("vehicle", "file"), a.world,
                                             s.get("truth", "two-body"),
                                             a.runtime, a.ts, a.seed, "with" if a.satb_gnss else "without",
                                             s["complete"]), ""]
    out += verdict.table([(w, None if v is None else round(v, 1), lim, met) for w, v, lim, met in verdict_rows(s)])
    out += ["The figures are taken after %.0f s (the hold and the settling); the budgets are %s." % (
        s["settle_s"], "the spacecraft file's" if s["requirements"]["source"] == "file" else "the thesis's (Sec. 6.4)"),
        "", "## The run", "",
        "- %s cycles of 1 s, last mode %s, %s late cycles; %s s wall (%s× real time)" % (
            _num(s.get("cycles"), "%d"), s.get("last_mode"), _num(s.get("late_cycles"), "%d"),
            _num(s.get("wall_s"), "%.1f"), _num(s.get("speed_x_realtime"), "%.2f")),
        "- missed by the firmware: %s" % _missed_text(s["firmware_missed"]),
        "- link retries: %d cycles retried, %d TICKs and %d packets resent. Retries are the lockstep's normal "
        "answer to frames that came late or damaged (a loaded machine makes more); each cycle still flies exactly "
        "once, so they change no figure." % (s["retries"]["cycles_retried"], s["retries"]["tick_resent"],
                                             s["retries"]["packets_resent"])]
    if s.get("stkf"):
        out.append("- %s" % stkf_text(s["stkf"]))
    if s.get("max_wheel_speed_rpm") is not None and s.get("wheel_speed_limit_rpm"):
        out.append("- largest wheel speed after the settling %.0f rpm (limit %g rpm)" % (
            s["max_wheel_speed_rpm"], s["wheel_speed_limit_rpm"]))
    out += ["", "## Mode changes", "", "| t (s) | from | to | reason |", "|---|---|---|---|"]
    out += ["| %.0f | %s | %s | %s |" % (c["t_s"], c["from"], c["to"], c.get("reason", ""))
            for c in s.get("mode_changes", [])] or ["| — | | | none |"]
    if s.get("faults"):
        out += ["", "## Faults", "", "Injected: %s." % ", ".join("%s %s" % kv for kv in s["faults"].items())]
    return "\n".join(out) + "\n"


def _num(v, fmt):
    """``v`` as ``fmt``, or "—" when the run has none (stopped before its first cycle)."""
    return "—" if v is None else fmt % v


def _missed_text(m):
    """The firmware's missed-input counters as words, the non-zero ones only (``none`` when all are zero or the
    firmware sent no status)."""
    parts = []
    for k, v in (m or {}).items():
        n = sum(x or 0 for x in v) if isinstance(v, list) else v
        if n:
            parts.append("%s %s" % (k.replace("_", " "), v if isinstance(v, list) else n))
    return ", ".join(parts) or "none"


def _session(a, d):
    """(the session, its faults) of the command's options on the spacecraft ``d``, the parameter file and the
    faults checked first."""
    from emulator.adcs_session import AdcsSession
    if a.params:
        bps.load_params(a.params, d)    # protocol.paramfile's checks against the spacecraft
    faults = faults_from_args(a)
    link_faults = None
    if a.link_faults:
        from protocol.faults import LinkFaults
        link_faults = LinkFaults.parse(a.link_faults)
    if a.runtime == "qemu":                 # QEMU and an ADCS image built from the tree's sources (make pil)
        from ground.runtime import check_pil
        check_pil("adcs")
    log = None if a.quiet else _log
    hpop = a.truth == "hpop"                # the two-body truth needs no cache
    session = AdcsSession(runtime=a.runtime, satb_gnss=a.satb_gnss, seed=a.seed, duration_s=a.session, ts=a.ts,
                          params=a.params, faults=faults, log=log, link_faults=link_faults, spacecraft=d,
                          world=a.world, truth=a.truth, cache_dir=os.path.abspath(a.cache_dir) if hpop else None,
                          stkf_accel=a.stkf_accel)
    return session, faults


def _log(message):
    """A session's line on stderr above the progress bar (tqdm.write), never over it."""
    from tqdm import tqdm
    tqdm.write(message, file=sys.stderr)


def _fly(session, a):
    """The session's cycles: (rows {hist, est, rw_cmd, stat}, its summary, interrupted by Ctrl-C or SIGTERM). The
    session is closed (its firmware stopped) however this ends, an interrupted start included; the rows of an
    interrupted run are those of the cycles recorded whole."""
    hist = {k: [] for k in ("t", "q", "w", "ra", "va", "rb", "vb")}
    est = {k: [] for k in ("q", "w", "ra", "rb")}
    rw_cmd = []
    stat = {k: [] for k in STATUS_KEYS}
    interrupted = False
    bar = None
    try:
        try:
            session.start()          # its waits for the boards' boot stay interruptible
            if not a.quiet:
                from tqdm import tqdm
                bar = tqdm(total=session.K, desc="ADCS on CAN (%s)" % a.runtime, unit="s", leave=False)
            for _ in range(session.K):
                with interrupts_between():       # a stop lands between cycles, never inside the bus's threads
                    c = session.cycle()
                for k in hist:
                    hist[k].append(c[k])
                for k in STATUS_KEYS:
                    stat[k].append(c["status"].get(k, -1))
                for k in est:
                    est[k].append(c["est"].get(k, np.full(4 if k == "q" else 3, np.nan)))
                rw_cmd.append(c["rw_cmd"])
                if bar is not None:
                    bar.update(1)
            summary = session.summary()
        finally:
            with interrupts_between():
                session.close()
    except KeyboardInterrupt:
        interrupted = True
        summary = session.summary()
        lists = list(hist.values()) + list(stat.values()) + list(est.values()) + [rw_cmd]
        n = min(len(v) for v in lists)           # a cycle the interruption cut while it was being recorded
        for v in lists:
            del v[n:]
        summary["cycles"], summary["virtual_s"] = n, float(n)        # the cycles the folder holds
    finally:
        if bar is not None:
            bar.close()
    return {"hist": hist, "est": est, "rw_cmd": rw_cmd, "stat": stat}, summary, interrupted


def _pointing(summary, h, settle, lb):
    """The body pointing error (Eq. 6.12-6.21) into the history ``h`` and its statistics after ``settle`` (s)
    and the verdict on the budgets (``summary["requirements"]``) into ``summary``."""
    req = summary["requirements"]
    if len(h["t"]):
        dth, dom = bps.pointing_errors(h["q"], h["w"], h["ra"], h["va"], h["rb"], h["vb"], lb)
        h["dtheta_arcsec"], h["domega_arcsec_s"] = dth / RAD_PER_ARCSEC, dom / RAD_PER_ARCSEC
        sel = h["t"] >= settle
        if sel.sum() >= 2:
            summary["pointing"] = bps.statistics(dth[sel], dom[sel])
            summary["requirement"] = {"pointing_3sigma_arcsec": req["body_pointing_3sigma_arcsec"],
                                      "stability_3sigma_arcsec_s": req["body_stability_3sigma_arcsec_s"]}
    p = summary.get("pointing")
    summary["budgets_met"] = None if p is None else bool(
        summary["complete"] and p["pointing_3sigma_arcsec"] <= req["body_pointing_3sigma_arcsec"]
        and p["stability_3sigma_arcsec_s"] <= req["body_stability_3sigma_arcsec_s"])


def _say(summary, a):
    """The run's lines on stdout: the board's instructions a cycle (qemu), then the run."""
    ipc = summary.get("instructions_per_cycle")
    if ipc and ipc["n"]:
        t = summary["target"]
        print("the board (%s): %.2f M instructions a cycle on the mean, %.2f M the largest: %.1f-%.1f %% of 1 s at "
              "%.0f MHz%s" % (t["core"].split(" with")[0], ipc["mean"] / 1e6, ipc["max"] / 1e6,
                              100 * ipc["mean"] * t["cpi_range"][0] / t["clock_hz"],
                              100 * ipc["mean"] * t["cpi_range"][1] / t["clock_hz"], t["clock_hz"] / 1e6,
                              "; the filters' start apart: %.2f M" % (ipc["filters_start"] / 1e6)
                              if ipc.get("filters_start") else ""))
    r, p, req = summary["retries"], summary.get("pointing"), summary["requirements"]
    lk = summary.get("link") or {}
    print("ADCS on CAN, %s, %d s%s: last mode %s, late cycles %d, missed by the firmware: %s; link retries "
          "(normal when frames come late or damaged: each cycle still flies once): %d cycles, %d ticks and %d "
          "packets resent, ISO-TP transfers %d resent and %d failed (%d timeouts); %s" % (
        a.runtime, summary["cycles"], "" if summary["complete"] else " (interrupted)", summary["last_mode"],
        summary["late_cycles"], _missed_text(summary["firmware_missed"]), r["cycles_retried"], r["tick_resent"],
        r["packets_resent"], lk.get("tx_isotp_resent", 0), lk.get("tx_isotp_failed", 0),
        sum(v for k, v in lk.items() if "Timeout" in k),
        ("pointing 3σ %.1f″ (budget %.0f″), stability 3σ %.1f″/s (budget %.0f″/s)" % (
            p["pointing_3sigma_arcsec"], req["body_pointing_3sigma_arcsec"], p["stability_3sigma_arcsec_s"],
            req["body_stability_3sigma_arcsec_s"])) if p else "too short for pointing figures"))
