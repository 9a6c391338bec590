"""``run_system``: both loops in one run, the run folder and its summary."""

import contextlib
import io
import math
import os
import sys
import time

import numpy as np

from ground import hil, report
from ground.adcs.campaign import MAX_DURATION_S     # the ADCS's run is held in memory, as fps adcs bps's
from ground.adcs.options import check_stkf_accel
from ground.fileio import run_folder, write_atomic, write_json
from ground.system.adcs import AdcsFailed, AdcsFeed, estimation_accuracy, settle_s
from ground.system.constants import ADCS_KINDS, FIGURE, GOAL_RTF, LEAD_S, RUNTIMES, STENCIL_S, firmware_available
from ground.system.live import LiveDisturbance
from ground.system.reporting import _plot, report_md, thesis_body, verdict
from protocol import spacecraft as sf
from protocol.units import RAD_PER_ARCSEC


# --- the run -------------------------------------------------------------------------------------------------
def check_inputs(duration_s, runtime_name, adcs, ts, truth, seed=0):
    from ground.adcs import body_pointing as bps
    from ground.adcs.bps_source import TRUTHS
    from ground import runtime
    runtime.check_seed(seed)
    if not (isinstance(duration_s, (int, float)) and math.isfinite(duration_s)
            and hil.MIN_PLAY_S <= duration_s <= MAX_DURATION_S):
        raise ValueError("--duration must be in [%g, %g] s, got %r" % (hil.MIN_PLAY_S, MAX_DURATION_S, duration_s))
    if runtime_name not in RUNTIMES:
        raise ValueError("--runtime %r: the fine-pointing controller runs under one of %s"
                         % (runtime_name, ", ".join(RUNTIMES)))
    if adcs not in ADCS_KINDS:
        raise ValueError("--adcs %r: one of %s" % (adcs, ", ".join(ADCS_KINDS)))
    if adcs == "firmware" and not firmware_available():
        raise ValueError("--adcs firmware: the ADCS-on-CAN session (emulator/adcs_session.py) is not in this "
                         "build; use --adcs ground (the body pointing simulator of Sec. 6.4)")
    if truth not in TRUTHS:
        raise ValueError("--truth must be one of %s, got %r" % ("/".join(TRUTHS), truth))
    if runtime_name == "qemu":           # both boards' images, before the ADCS process starts (make pil)
        from ground.runtime import check_pil
        check_pil("controller")
        if adcs == "firmware":
            check_pil("adcs")
    return bps.check_ts(ts)


def calibrate_inproc(seed, config, path):
    """The Sec. 7.4 H calibration (121 points) in this process, written to ``path``; OSError if points fail."""
    from ground import calibrate, runtime
    with runtime.open_rig("inproc", "inproc", config=config, seed=seed) as rig:
        cal, failed, _ = calibrate.run_calibration(rig, calibrate.sec74_grid(11), 0.01, log=lambda m: None)
    if failed:
        raise OSError("H calibration: %d grid points failed (first: %s)" % (len(failed), failed[0][1]))
    calibrate.check_calibration(cal)
    cal["runtime"], cal["link"] = "inproc", "inproc"
    write_json(path, cal)
    return cal


def run_system(duration_s, out_dir, runtime_name="micropython", adcs="firmware", satb_gnss=False, seed=0, ts=33.0,
               truth="hpop", calibration_path=None, params_path=None, bps_cache=None, config=None, q2_dvp=0.05,
               quiet=False, plots=True, faults=None, link_faults=None, spacecraft=None, world="thesis",
               vehicle="file", stkf_accel=None):
    """The whole run; returns the summary (also in ``out_dir/summary.json``). Bad input raises ValueError before
    anything is written; afterwards the folder always ends valid, and a failure raises ``hil.RunFailed``, an
    interruption ``hil.Interrupted``. ``faults``: the ADCS session's (``emulator.adcs_session``: wheel_silent,
    startracker_blind, gnss_outage, beacon_lost; times in the ADCS's seconds, the play starting after its
    settling), with either ADCS (the same app); their log in the summary's ``adcs_summary`` and the report.
    ``link_faults``: a ``protocol.faults.LinkFaults`` on the ADCS's CAN link (its slcan stream; firmware ADCS
    only), the retries it costs in ``adcs_summary``'s ``retries``. ``spacecraft``: a preset's name or a spacecraft
    file (None: thesis-3u), the vehicle of the ADCS (``fps adcs bps`` or ``fps adcs can`` with ``--spacecraft``);
    ``vehicle``: the simulated vehicle, its truth block or drawn from ``seed`` (``emulator.spacecraft.dispersion``).
    ``world``: "thesis" (Sec. 6.4's) or "flight" (``fps adcs bps --world flight``'s: datasheet wheels,
    magnetorquers, the rate-limited slew; the lean firmware flies its modes, ``firmware/adcs/flight.py``); in the
    flight world the play starts at ``bps.flight_settle_s`` (the planned slew, re-acquisition and 4 t_s).
    ``stkf_accel``: ``--stkf-accel``, the flight STKF's form over the hpop truth in the flight world, either ADCS
    (both fly the flight app; None: white, the default; ``options.check_stkf_accel``)."""
    from ground import runtime
    from ground.calibrate import load_calibration

    t_wall0 = time.perf_counter()
    ts = check_inputs(duration_s, runtime_name, adcs, ts, truth, seed)
    stkf_accel = check_stkf_accel(stkf_accel, world, truth, runtime=runtime_name if adcs == "firmware" else None)
    hil.check_q2_dv(q2_dvp)
    runtime.check_board(config)
    cal = load_calibration(calibration_path) if calibration_path else None
    duration_s = float(duration_s)
    d, record, params, t_settle, faults = _vehicle(adcs, world, faults, link_faults, spacecraft, params_path, ts,
                                                   duration_s, seed, vehicle)
    run_folder(out_dir, hil.FIGURES + (FIGURE,))           # the fine loop's figures are hil's
    rec = hil.Recorder(out_dir)
    summary = hil.new_summary(duration_s)
    summary.update({"adcs": adcs, "runtime": runtime_name, "goal_real_time_factor": GOAL_RTF,
                    "satb_gnss": bool(satb_gnss), "ts_s": ts, "seed": seed, "phase": "start", "stopped_in": None,
                    "spacecraft": record, "world": world, "requirements": sf.requirements(d),
                    **({"stkf_accel": stkf_accel} if (world, truth) == ("flight", "hpop") else {})})
    write_json(rec.path("summary.json"), summary)
    spec = _spec(adcs, runtime_name, satb_gnss, seed, ts, truth, duration_s, params, bps_cache, faults, d,
                 link_faults, world, t_settle, stkf_accel)
    live = LiveDisturbance(t_settle)
    say = (lambda m: None) if quiet else (lambda m: print("fps system: " + m, file=sys.stderr))
    feed = AdcsFeed(spec, live.add)
    feed.info["adcs"] = adcs
    run, q2cal = hil.RunOutcome(runtime_name, "serial"), None
    try:
        with run.guard():
            try:
                summary["phase"] = "start"           # where the run is (and, in stopped_in, where it stopped)
                feed.start()
                config_json = dict(spec_config(spec), satb_gnss=satb_gnss, world=world, spacecraft=record,
                                   params=params_path and os.path.abspath(params_path),
                                   calibration=calibration_path and os.path.abspath(calibration_path),
                                   distfile_period_us=live.reader.period_us)
                write_json(rec.path("config.json"), config_json)
                cal = _h_calibration(cal, summary, say, seed, config, rec)
                summary["phase"] = "controller_start"
                with runtime.open_rig(runtime_name, "serial", config=config, seed=seed) as rig:
                    run.rig = rig
                    feed.on_wait = rig.keepalive      # the ADCS's pace is not the fine loop's link silence
                    write_json(rec.path("config.json"), dict(hil.run_config(rig, duration_s, seed, {}), **config_json))
                    q2cal = _play(rig, rec, cal, q2_dvp, feed, live, summary, t_settle, duration_s, quiet, say)
                feed.on_wait = feed.on_samples = None     # the play is over: later samples recorded, not played
                summary["phase"] = "reference"
                with contextlib.suppress(OSError):    # the ground filters' column (firmware: after the session)
                    feed.take(want=lambda: feed.reference is not None, timeout_s=300.0)
            except AdcsFailed as exc:                 # the ADCS's own failure: not the fine loop link's
                run.failure, run.adcs_failed = str(exc), True
            except BaseException:
                feed.close()                          # bounded, whatever the ADCS process is doing
                raise
            if feed.close():
                raise KeyboardInterrupt               # Ctrl-C or SIGTERM while the ADCS process was being stopped
        _finish(run, rec, summary, q2cal, plots, feed, live, t_settle, t_wall0, faults)
    except BaseException as exc:     # past the guard (a bug, the disk, Ctrl-C while finishing): the folder says so
        feed.close()
        _stopped_folder(rec, summary, exc)
        raise
    run.raise_if_stopped(out_dir, summary)
    return summary


def _spec(adcs, runtime_name, satb_gnss, seed, ts, truth, duration_s, params, bps_cache, faults, d, link_faults,
          world, t_settle, stkf_accel="white"):
    """The ADCS process's specification (``ground.system.adcs``): what it flies, where its cache is."""
    from ground.adcs import bps_cli
    cache = bps_cache or bps_cli.CACHE_DEFAULT
    return {"adcs": adcs, "runtime": runtime_name, "satb_gnss": bool(satb_gnss), "seed": int(seed), "ts": ts,
            "truth": truth, "duration_s": duration_s, "adcs_duration_s": duration_s + LEAD_S, "params": params,
            "bps_cache": cache, "cache_dir": os.path.abspath(cache), "faults": faults or None, "spacecraft": d,
            "link_faults": link_faults.describe() if link_faults is not None else None, "world": world,
            "t_settle": t_settle, "stkf_accel": stkf_accel}


def _h_calibration(cal, summary, say, seed, config, rec):
    """The H calibration the run flies: the one given (copied into the folder), or made in process first."""
    if cal is None:
        summary["phase"] = "h_calibration"
        say("calibrating H in-process first (Sec. 7.4, 121 points; --calibration FILE skips this) ...")
        return calibrate_inproc(seed, config, rec.path("calibration.json"))
    write_json(rec.path("calibration.json"), cal)
    return cal


def spec_config(spec):
    """The run's config.json entries its spec holds (``run_system``'s)."""
    return {"adcs": spec["adcs"], "adcs_runtime": spec["runtime"] if spec["adcs"] == "firmware" else None,
            "ts_s": spec["ts"], "truth": spec["truth"], "settle_s": spec["t_settle"], "seed": spec["seed"],
            "duration_s": spec["duration_s"], "runtime": spec["runtime"], "link": "serial",
            "faults": spec["faults"], "adcs_link_faults": spec["link_faults"], "live_player": True,
            **({"stkf_accel": spec["stkf_accel"]} if (spec["world"], spec["truth"]) == ("flight", "hpop") else {})}


def _finish(run, rec, summary, q2cal, plots, feed, live, t_settle, t_wall0, faults):
    """The run's folder completed, stopped or not: the summary with both loops' figures and the verdict, the
    plots and report.md."""
    stopped_in = summary["phase"] if run.failure or run.interrupted else None
    hil.board_figures(run, summary)            # --runtime qemu: the controller's board
    rec.unplayable = live.unplayable
    hil.finish_summary(rec, run, summary, q2cal, plots)
    if getattr(run, "adcs_failed", False):      # the ADCS's failure as it was said, without the fine loop's counters
        summary["error"] = run.failure
    summary["phase"] = "done" if stopped_in is None else ("interrupted" if run.interrupted else "failed")
    summary["stopped_in"] = stopped_in
    summary.update(_body_summary(feed, live, rec, t_settle))
    summary["wall_s"] = time.perf_counter() - t_wall0
    summary["real_time_factor_play"] = summary["real_time_factor"]
    summary["real_time_factor"] = rec.virtual_s / summary["wall_s"] if summary["wall_s"] > 0 else None
    summary["adcs_wait_s"] = feed.wait_s
    summary["verdict"] = verdict(summary)
    summary["requirement_met"] = summary["verdict"]["met"]
    write_json(rec.path("summary.json"), summary)
    if plots:
        _plot(rec, feed, q2cal, t_settle, faults, summary["requirements"])
    write_atomic(rec.path("report.md"), report_md(summary))


def _vehicle(adcs, world, faults, link_faults, spacecraft, params_path, ts, duration_s, seed=0, vehicle="file"):
    """``run_system``'s ADCS inputs checked: (the spacecraft file with the vehicle flown, its record, the parameter
    file or None, the ADCS's settling time, the faults checked against the run's span); ValueError naming the bad
    one."""
    from ground.adcs import body_pointing as bps
    from ground.adcs.options import fly, load_spacecraft
    if world not in bps.WORLDS:
        raise ValueError("--world must be one of %s, got %r" % (", ".join(bps.WORLDS), world))
    if link_faults is not None and adcs != "firmware":
        raise ValueError("--link-faults needs --adcs firmware (they act on the ADCS's CAN link)")
    d, source = load_spacecraft(spacecraft, partner=True, flight=world == "flight")
    d, record = fly(d, source, seed, vehicle)
    params = bps.load_params(params_path, d)[-1] if params_path else None
    t_settle = settle_s(ts) if world == "thesis" else bps.flight_settle_s(d, ts)
    if faults:
        from emulator.adcs_bus import check_faults
        faults = check_faults(faults, t_settle + duration_s + LEAD_S)
    return d, record, params, t_settle, faults


def _play(rig, rec, cal, q2_dvp, feed, live, summary, t_settle, duration_s, quiet, say):
    """The fine loop's part on the open rig: wait for the ADCS's settling, the Q2 calibration and the walk to the
    first sample, then the play of the live disturbance; returns the Q2 calibration."""
    from firmware.player import Player

    def first_sample():
        summary["phase"] = "adcs_settling"
        if feed.t_last < t_settle + STENCIL_S + 0.2:
            say("waiting for the ADCS to reach the end of its settling (t = %g s of its time) ..." % t_settle)
        feed.take(t_settle + STENCIL_S + 0.2)
        summary["phase"] = "prepare_play"
        return live.reader.sample(0)
    summary["phase"] = "prepare_play"         # Q2 calibration, the walk to the first sample
    q2cal = hil.prepare_play(rig, rec, cal, q2_dvp, first_sample)
    player = Player()
    player.load(live.reader)
    player.oneshot()
    summary["phase"] = "play"             # for whoever watches the folder
    write_json(rec.path("summary.json"), summary)
    hil.play(rig, rec, player, duration_s, summary, quiet, desc="system",
             before_chunk=lambda t_end: feed.take(want=lambda: live.covered_s >= t_end + 0.01))
    return q2cal


def _stopped_folder(rec, summary, exc):
    """After an exception past the run's guard: summary.json says complete false and why (best effort: the
    exception itself is what the caller reports)."""
    interrupted = isinstance(exc, KeyboardInterrupt)
    summary.update({"complete": False, "requirement_met": False, "interrupted": interrupted,
                    "stopped_in": summary.get("stopped_in") or summary.get("phase"),
                    "phase": "interrupted" if interrupted else "failed"})
    if not interrupted:
        summary["error"] = summary.get("error") or "%s: %s" % (type(exc).__name__, exc)
    if isinstance(summary.get("verdict"), dict):
        summary["verdict"]["met"] = False
        summary["verdict"]["complete"] = False
    with contextlib.suppress(Exception):
        write_json(rec.path("summary.json"), summary)


def _body_summary(feed, live, rec, t_settle):
    """Body pointing (``bps.statistics``) over the window played, the estimates' accuracy, the reference."""
    from ground.adcs import body_pointing as bps
    t, dth, dom, t_est, err = feed.arrays()
    buf = io.BytesIO()
    np.savez_compressed(buf, t_s=t - t_settle, t_adcs_s=t, dtheta_arcsec=dth, domega_arcsec_s=dom,
                        t_est_s=t_est, est_err=err, est_cols=np.array(bps.EST_COLS))
    write_atomic(rec.path("body.npz"), buf.getvalue())
    sel = (t >= t_settle - 1e-9) & (t <= t_settle + rec.virtual_s + 1e-9)
    body = bps.statistics(dth[sel] * RAD_PER_ARCSEC, dom[sel] * RAD_PER_ARCSEC) if sel.sum() >= 2 else None
    est = estimation_accuracy(t_est, err, t_settle, t_settle + rec.virtual_s)
    n_played = min(len(live.x), int(round(rec.virtual_s / live.dt)) + 1)
    dist = report.error_stats(live.x[:n_played], live.y[:n_played])
    dist["source"] = "live ADCS (%s)" % feed.info.get("adcs")
    dist["beyond_pfsm_range"] = {"samples": live.n_unplayable, "seconds": live.n_unplayable * live.dt,
                                 "windows_s": [[round(a, 4), round(b, 4)] for a, b in live.unplayable[:50]]}
    return {"settle_s": t_settle, "body_pointing": body, "estimation": est, "ground_reference": feed.reference,
            "disturbance": dist, "adcs_summary": feed.adcs_summary, "adcs_last_status": feed.last_status,
            "adcs_log": feed.log[-200:],
            "adcs_info": {k: v for k, v in feed.info.items() if k != "adcs"},
            "thesis_body": thesis_body()}
