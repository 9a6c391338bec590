"""``fps hil``: the emulated hardware-in-the-loop run of Sec. 7.5.

Starts the emulated bench, the disturbance player (in-process beside the bench: the SimArduino; the firmware
player's codes computed with numpy, ``emulator.serve.DistfilePlayer``)
and the controller firmware (in-process, or a CPython/MicroPython subprocess over a serial pty or CAN slcan),
uploads the H calibration (HTABLE_*), calibrates Q2 against the P-FSM, then plays the distfile with the
controller in TRACK mode and records Q2 at 630 Hz through the ADS1256 model beside the emulator's truth.

Q2 calibration (Sec. 7.5, "by the same method as Sec. 7.4, but with the P-FSM and Q2"): with the FSM held
at its null, the P-FSM is perturbed by +-dVp along X, Y and both (8 points); least squares gives G2 with
R2 = G2 dVp (+ offset column for the fit only). A P-FSM voltage is an error angle by Eq. 7.8
(0.012343 V/arcsec), so a Q2 ratio R2 reads as the error theta = G2^-1 R2 / 0.012343 arcsec. R2 is taken
absolute (zero at Q2's own centre), so Q1/Q2 misalignment shows as a mean error, as in the thesis.

Run folder (every file written atomically): ``config.json``, ``calibration.json`` (as uploaded),
``q2_calibration.json``, ``telemetry.csv`` (CTRL_STATUS), ``samples.npz`` (Q2 counts, Q2 and truth error
angles at the Q2 instants: 630 Hz, so the loop's ripple near 637.8 Hz folds to lines at 4-60 Hz there, as the
thesis's recorder folded it), ``summary.json`` (``complete`` false until the run ends; ``saturation``: the fine
loop's time on its FSM clamp and each sustained episode, ``saturation_summary``), ``report.md`` and the
plots ``fig7-18_scatter.png``, ``fig7-19_time.png``. Ctrl-C or SIGTERM stops the run and leaves the folder
valid with what was recorded and ``complete: false``.
"""

import contextlib
import io
import json
import os
import sys
import time

import numpy as np

from emulator.hcal import STEPS, fit_h
from emulator.runtime import sigterm_as_interrupt
from ground import report, verdict
from ground.calibrate import load_calibration
from ground.link_report import link_counters
from ground.distfile_cli import V_PER_ARCSEC, check_playable, load as load_distfile
from ground.fileio import output_folder, run_folder, write_atomic, write_json
from ground.hil_report import (_nonzero, _per_10s, _rate, jitter_harmonics, mode_changes,  # noqa: F401
                               report_md, saturation_summary, verdict_lines, wire_deadline)
from ground.rig import AD660_CODES_PER_VOLT
from ground.runtime import tick_timeout
from protocol import htable

CHUNK_S = 1.0     # virtual seconds per lockstep call (progress and interruption granularity)


class Interrupted(Exception):
    pass


MIN_PLAY_S = 0.01          # the shortest play: six Q2 samples at 630 Hz (shorter ones recorded none)
Q2_DV_MIN_CODES = 4       # the Q2 calibration's P-FSM step spans at least this many AD660 codes


def check_q2_dv(dvp):
    """``--q2-dv`` (V) in [Q2_DV_MIN_CODES AD660 codes, 2 V]: a smaller step rounds to too few DAC codes (at
    1e-4 V, none: G2 singular); ValueError naming it otherwise."""
    lo = Q2_DV_MIN_CODES / AD660_CODES_PER_VOLT
    if isinstance(dvp, bool) or not isinstance(dvp, (int, float)) or not lo <= dvp <= 2.0:
        raise ValueError("--q2-dv must be in [%.2g, 2] V (at least %d codes of the P-FSM's AD660 DAC, %.3g mV "
                         "each), got %r" % (lo, Q2_DV_MIN_CODES, 1e3 / AD660_CODES_PER_VOLT, dvp))
    return float(dvp)


def calibrate_q2(rig, dvp=0.05, settle_ticks=16, avg_samples=48):
    """G2 (Q2 ratio per P-FSM volt) around P-FSM (0, 0) V, FSM held (HOLD mode); leaves the P-FSM at 0 V."""
    rig.settings("HOLD", decim=0)
    dvs, rs = [], []
    per_tick = rig.bench.q2_hz / rig.rate_hz
    n_avg = int(np.ceil(avg_samples / per_tick)) + 1
    for sx, sy in STEPS:
        rig.pfsm_v(sx * dvp, sy * dvp)
        rig.run(settle_ticks)
        q2 = rig.run(n_avg)["q2"]
        if len(q2) == 0 or np.any(q2[:, 4] <= 0):
            raise ValueError("Q2 calibration: no beam on Q2 at P-FSM (%g, %g) V" % (sx * dvp, sy * dvp))
        rs.append([np.mean(q2[:, 2] / q2[:, 4]), np.mean(q2[:, 3] / q2[:, 4])])
        dvs.append([(rig.hold.x_code - 0x8000) / AD660_CODES_PER_VOLT,
                    (rig.hold.y_code - 0x8000) / AD660_CODES_PER_VOLT])
    rig.pfsm_v(0.0, 0.0)
    dvs = np.array(dvs)
    g2, off, resid = fit_h(dvs - dvs.mean(axis=0), rs)
    return {"G2": g2.tolist(), "offset": off.tolist(), "residual": resid, "dvp": dvp,
            "arcsec_per_v": 1.0 / V_PER_ARCSEC, "method": "Sec. 7.5: Sec. 7.4 least squares with P-FSM and Q2"}


def q2_error_arcsec(q2, q2cal):
    """Error angles (x, y) arcsec from Q2 counts rows (sample, t_us, vx, vy, vs): G2^-1 R2 / 0.012343."""
    q2 = np.asarray(q2, dtype=float).reshape(-1, 5)
    vs = np.where(q2[:, 4] > 0, q2[:, 4], np.nan)
    r = np.column_stack([q2[:, 2] / vs, q2[:, 3] / vs])
    ginv = np.linalg.inv(np.array(q2cal["G2"]))
    v = r @ ginv.T
    return v * q2cal["arcsec_per_v"]


FIGURES = ("fig7-18_scatter.png", "fig7-19_time.png")


class Recorder:
    """Accumulates the run's samples and telemetry; writes the run folder."""

    def __init__(self, out_dir):
        self.dir = out_dir
        self.q2 = []
        self.truth = []
        self.status = []
        self.t_wall0 = time.perf_counter()
        self.play_wall = 0.0
        self.virtual_s = 0.0
        self.minute_rates = []    # (virtual s, wall s) per chunk, for the first/last minute rate
        self.tick0 = None         # the play's first tick (None: the play has not started)
        self.t0_us = 0
        self.status_before = None   # the last CTRL_STATUS before the play (saturation counts start there)
        self.unplayable = []        # (start, end) s of the play the bench could not play (beyond the P-FSM)

    def path(self, name):
        return os.path.join(self.dir, name)

    def add(self, out, status):
        if len(out["q2"]):
            self.q2.append(out["q2"])
            self.truth.append(out["truth_arcsec"])
        self.status.extend(status)

    def arrays(self):
        q2 = np.concatenate(self.q2) if self.q2 else np.zeros((0, 5), np.int64)
        tr = np.concatenate(self.truth) if self.truth else np.zeros((0, 2))
        return q2, tr

    def write_samples(self, q2, q2_err, truth, t0_us):
        buf = io.BytesIO()
        np.savez_compressed(buf, t_s=(q2[:, 1] - t0_us) * 1e-6, q2_sample=q2[:, 0], q2_counts=q2[:, 2:5],
                            q2_err_arcsec=q2_err, truth_err_arcsec=truth)
        write_atomic(self.path("samples.npz"), buf.getvalue())

    def write_telemetry(self):
        cols = ("tick", "mode", "beam", "sat", "rx", "ry", "vs", "n_lost", "n_sat", "n_unknown", "why",
                "n_gap")
        link = ("n_dup", "n_rx_drop")       # the link's own counters: they differ between runs by design
        sat = ("sat_run", "sat_last", "n_sat_episodes")     # after the link's: the older columns keep their place
        lines = [",".join(cols + ("v_cmd_x", "v_cmd_y") + link + sat)]
        for s in self.status:
            lines.append(",".join([str(int(s[c])) if c not in ("rx", "ry") else "%.6f" % s[c] for c in cols]
                                  + ["%.7f" % s["v_cmd"][0], "%.7f" % s["v_cmd"][1]]
                                  + [str(int(s[c])) for c in link + sat]))
        write_atomic(self.path("telemetry.csv"), "\n".join(lines) + "\n")


def _progress_bar(total_s, quiet, desc="hil"):
    if quiet or not sys.stderr.isatty():
        return None
    from tqdm import tqdm
    return tqdm(total=round(total_s, 3), unit="s", desc=desc, file=sys.stderr,
                bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s virtual [{elapsed}<{remaining}, {rate_fmt}]")


def run_hil(distfile_path, calibration_path, duration_s, runtime_name, link_name, out_dir, config=None,
            seed=0, q2_dvp=0.05, quiet=False, plots=True, link_opts=None):
    """The whole run; returns the summary dict (also written to ``out_dir/summary.json``).

    Bad input raises ValueError before anything is written. Once the folder exists it always ends with a
    ``summary.json`` holding ``complete``, ``error``, ``requirement_met``, ``mode_changes`` and both sides'
    link counters; a failure then raises ``RunFailed``, an interruption ``Interrupted``."""
    from emulator.serve import DistfilePlayer
    from ground import runtime
    from protocol import distfile

    link_opts = dict(link_opts or {})
    runtime.check_options(runtime_name, link_name, **link_opts)
    cal = load_calibration(calibration_path)
    d, dx, dy = load_distfile(distfile_path)
    check_playable(dx, dy, d.period_us)
    if not duration_s >= MIN_PLAY_S:
        raise ValueError("--duration must be >= %g s (a few Q2 samples at 630 Hz), got %r" % (MIN_PLAY_S, duration_s))
    check_q2_dv(q2_dvp)
    runtime.check_seed(seed)
    runtime.check_board(config, link_opts.get("rate_hz", 637.8))
    play_s = d.duration_us() * 1e-6
    if duration_s > play_s + 1e-6:
        raise ValueError("--duration %g s is longer than the distfile (%g s)" % (duration_s, play_s))
    run_folder(out_dir, FIGURES)
    rec = Recorder(out_dir)
    faults = link_opts.get("link_faults")
    summary = new_summary(duration_s, faults)
    write_json(rec.path("summary.json"), summary)
    write_json(rec.path("calibration.json"), cal)
    q2cal = None
    run = RunOutcome(runtime_name, link_name)
    with run.guard():
        with runtime.open_rig(runtime_name, link_name, config=config, seed=seed, **link_opts) as rig:
            run.rig = rig
            if cal.get("bench_config") not in (None, rig.config):
                print("warning: %s was calibrated on another bench config than this run's" % calibration_path,
                      file=sys.stderr)
            write_json(rec.path("config.json"), dict({
                "distfile": os.path.abspath(distfile_path), "distfile_source": d.source, "distfile_seed": d.seed,
                "distfile_count": d.count, "distfile_period_us": d.period_us,
                "calibration": os.path.abspath(calibration_path)}, **run_config(rig, duration_s, seed, link_opts)))
            q2cal = prepare_play(rig, rec, cal, q2_dvp, (dx[0], dy[0]))
            with open(distfile_path, "rb") as f:      # firmware.player.Player's codes, whole blocks at a time
                player = DistfilePlayer(distfile.parse(f.read()), pfsm_hz=rig.lockstep.pfsm_hz)
            play(rig, rec, player, duration_s, summary, quiet)
    board_figures(run, summary)
    finish_summary(rec, run, summary, q2cal, plots)
    n_played = min(len(dx), int(round(rec.virtual_s * 1e6 / d.period_us)) + 1)
    summary["disturbance"] = report.error_stats(dx[:n_played], dy[:n_played])   # the body pointing error played
    summary["disturbance"]["source"] = d.source
    summary["jitter_harmonics"] = jitter_harmonics(distfile_path, rec, rec.t0_us, run.rig)
    write_json(rec.path("summary.json"), summary)
    write_atomic(rec.path("report.md"), report_md(summary))
    run.raise_if_stopped(out_dir, summary)
    return summary


def new_summary(duration_s, faults=None):
    """The summary a run folder starts with (``complete`` false until the run ends)."""
    return {"complete": False, "error": None, "requirement_met": False, "duration_s": 0.0,
            "requested_duration_s": duration_s, "real_time_factor": None, "overruns": 0, "q2": None,
            "truth": None, "mode_changes": [], "saturation": None,
            "link_faults": faults.as_dict() if faults else None,
            "link": {"bench": {}, "controller": None},
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def run_config(rig, duration_s, seed, link_opts):
    """The rig's part of ``config.json``."""
    faults = link_opts.get("link_faults")
    return {"duration_s": duration_s, "runtime": rig.runtime_name, "link": rig.link_name, "seed": seed,
            "rate_hz": rig.rate_hz, "pfsm_hz": rig.lockstep.pfsm_hz, "q2_hz": rig.bench.q2_hz,
            "bench_config": rig.bench.config, "realtime": rig.lockstep.realtime, "port": link_opts.get("port"),
            "link_faults": faults.describe() if faults else None,
            "tick_timeout_ms": tick_timeout(rig.link_name, link_opts.get("tick_timeout_ms"), rig.runtime_name),
            "tick_tries": link_opts.get("tick_tries"),
            "max_failed_ticks": link_opts.get("max_failed_ticks")}


class RunOutcome:
    """How a run ended: ``guard()`` turns Ctrl-C/SIGTERM into ``interrupted`` and an OSError/ValueError (the
    inputs were checked before: anything now is the run failing) into ``failure``; ``rig`` is the rig, once open."""

    def __init__(self, runtime_name, link_name):
        self.runtime_name, self.link_name = runtime_name, link_name
        self.rig = None
        self.interrupted = False
        self.failure = None

    @contextlib.contextmanager
    def guard(self):
        try:
            with sigterm_as_interrupt():
                yield self
        except KeyboardInterrupt:
            self.interrupted = True
        except (OSError, ValueError) as exc:
            from ground.runtime import exit_note
            self.rig = self.rig if self.rig is not None else getattr(exc, "rig", None)
            where = getattr(self.rig, "link_desc", None) or "%s over %s" % (self.runtime_name, self.link_name)
            msg = str(exc)
            if "process exited" not in msg:          # say so when the controller is gone, and what it said
                msg += exit_note(getattr(self.rig, "process", None), wait_s=0.5)
            self.failure = "%s: %s" % (where, msg)

    def raise_if_stopped(self, out_dir, summary):
        """After the folder is written: ``Interrupted`` or ``RunFailed`` (with the summary's error)."""
        if self.interrupted:
            raise Interrupted(out_dir)
        if self.failure:
            raise RunFailed("%s (partial run in %s, summary complete=false)" % (summary["error"], out_dir))


def prepare_play(rig, rec, cal, q2_dvp, first_arcsec):
    """Upload the H calibration, null at the centre, calibrate Q2 against the P-FSM (written to
    ``q2_calibration.json``), then walk the P-FSM in TRACK to the disturbance's first sample (Eq. 7.8).
    Returns the Q2 calibration. ``first_arcsec``: (x, y), or a callable giving it once Q2 is calibrated (a
    live disturbance, known later)."""
    rig.upload_htable(htable.pack_calibration(cal))
    rig.pfsm_v(0.0, 0.0)
    rig.settings("TRACK", decim=0)
    rig.run(int(0.2 * rig.rate_hz))
    q2cal = calibrate_q2(rig, q2_dvp)
    write_json(rec.path("q2_calibration.json"), q2cal)
    rig.settings("TRACK", decim=64)
    if callable(first_arcsec):
        first_arcsec = first_arcsec()
    # the AD660's +-10 V: a first sample at the P-FSM's edge (a live disturbance beyond its range is played there)
    v_first = tuple(max(-10.0, min(10.0, a * V_PER_ARCSEC)) for a in first_arcsec)
    n_walk = max(1, int(np.ceil(max(abs(v_first[0]), abs(v_first[1])) / 0.5)))
    for k in range(1, n_walk + 1):
        rig.pfsm_v(v_first[0] * k / n_walk, v_first[1] * k / n_walk)
        rig.run(24)
    rig.run(int(0.2 * rig.rate_hz))
    rig.take_status()
    rec.status_before = rig.last_status
    _check_tracking(rig)
    return q2cal


def _check_tracking(rig):
    """OSError unless the controller's last CTRL_STATUS before the play says TRACK (or SATURATED, TRACK on its
    clamp, or ACQUIRE, TRACK waiting for the beam, which it takes back on its own): a play that starts in SAFE or
    HOLD measures nothing the run is meant to show."""
    from protocol import core
    st = rig.last_status
    if st is None or st["mode"] in (core.MODE["TRACK"], core.MODE["SATURATED"], core.MODE["ACQUIRE"]):
        return
    mode = core.MODE_NAME.get(st["mode"], st["mode"])
    why = " (%s)" % core.SAFE_REASON.get(st["why"], st["why"]) if st["mode"] == core.MODE["SAFE"] else ""
    raise OSError("the controller was in %s%s at the play's start, not TRACK: the play was not run" % (mode, why))


def play(rig, rec, player, duration_s, summary, quiet, before_chunk=None, desc="hil"):
    """Play ``player`` (its first fill is the play's t = 0) for ``duration_s`` in chunks of ``CHUNK_S``,
    recording Q2, truth and telemetry into ``rec`` (``rec.tick0``, ``rec.t0_us`` mark the start). Before each
    chunk, ``before_chunk(t_end_s)`` may feed the player up to the chunk's end (a live disturbance). Every
    sample played before an interruption or failure is kept."""
    rig.lockstep.player = player
    overrun0 = rig.lockstep.n_overrun
    tick0 = rec.tick0 = rig.lockstep.tick
    rec.t0_us = int(round(tick0 * 1e6 / rig.rate_hz))
    if rig.faults is not None:       # silence windows count in virtual seconds of the play, per tick
        rc = rig.endpoint.rc
        rig.faults.clock = lambda: (rc.tick_now - tick0) / rig.rate_hz
    n_total = int(round(duration_s * rig.rate_hz))
    chunk = max(1, int(round(CHUNK_S * rig.rate_hz)))
    bar = _progress_bar(duration_s, quiet, desc)
    done = 0
    t_play0 = time.perf_counter()
    try:
        while done < n_total:
            n = min(chunk, n_total - done)
            if before_chunk is not None:
                before_chunk((done + n) / rig.rate_hz)
            tw = time.perf_counter()
            try:
                out = rig.run(n)
            except BaseException:
                if rig.lockstep.partial is not None:     # keep every sample played before the stop
                    rec.add(rig.lockstep.partial, rig.take_status())
                    rec.virtual_s = (rig.lockstep.tick - tick0) / rig.rate_hz
                raise
            rec.minute_rates.append((n / rig.rate_hz, time.perf_counter() - tw))
            rec.add(out, rig.take_status())
            done += n
            rec.virtual_s = done / rig.rate_hz
            proc = getattr(rig, "process", None)
            if proc is not None and proc.poll() is not None:
                from ground.runtime import stderr_tail
                raise OSError("controller process exited with status %s after %.1f s of the run: %s"
                              % (proc.returncode, rec.virtual_s, stderr_tail(proc)))
            if bar is not None:
                bar.update(n / rig.rate_hz)
    finally:
        rec.play_wall = time.perf_counter() - t_play0
        if bar is not None:
            bar.close()
        summary["overruns"] = rig.lockstep.n_overrun - overrun0


def board_figures(run, summary):
    """--runtime qemu: the board's own figures (``tools.pil_board.read_target``, read when the rig closed) into
    the summary as ``target`` and ``instructions_per_step``; nothing for the other runtimes."""
    target = getattr(getattr(run.rig, "process", None), "target", None)
    if target is not None:
        target = dict(target)
        summary["instructions_per_step"] = target.pop("instructions_per_step", None)
        summary["target"] = target


def finish_summary(rec, run, summary, q2cal, plots):
    """Fill ``summary`` from what ``rec`` holds and how ``run`` ended (samples, statistics, plots, link
    counters, mode changes, saturation, the error with both sides' counters)."""
    rig = run.rig
    summary["link"] = link_counters(rig)
    if rig is not None and rec.tick0 is None:
        summary["overruns"] = rig.lockstep.n_overrun
    q2, truth = rec.arrays()                      # once: the statistics, the files and the availability
    summary.update(_finish(rec, q2, truth, q2cal, rec.t0_us, complete=not (run.interrupted or run.failure),
                           plots=plots))
    lock = getattr(rig, "lockstep", None)         # no play: the changes up to where the run stopped
    tick0 = rec.tick0 if rec.tick0 is not None else lock.tick if lock is not None else None
    summary["mode_changes"] = mode_changes(rig, tick0) if tick0 is not None else []
    summary["saturation"] = (saturation_summary(rec.status, rig.rate_hz, rec.tick0, rec.status_before)
                             if rig is not None and rec.tick0 is not None else None)
    summary["availability"] = _availability(rec, rig, q2, truth)
    summary["interrupted"] = run.interrupted
    summary["error"] = run.failure
    if run.failure:
        c = summary["link"]
        summary["error"] = "%s [bench counters %s; controller counters %s]" % (
            run.failure, _nonzero(c["bench"]),
            "none received" if c["controller"] is None else _nonzero(c["controller"]))
    return summary


def _availability(rec, rig, q2, truth):
    """The play's link availability on the true error (``ground.availability``), with Q2's saturated samples;
    q2, truth: ``rec``'s samples."""
    from ground.availability import availability, q2_saturated
    if rec.tick0 is None or rig is None:
        return None
    rate = rig.rate_hz
    block = availability((q2[:, 1] - rec.t0_us) * 1e-6, truth, report.REQUIREMENT_ARCSEC, rec.status,
                         lambda t: rec.tick0 + int(round(t * rate)), rec.unplayable)
    block["q2_saturated_samples"] = q2_saturated(q2)
    return block


class RunFailed(OSError):
    """The run could not go on (link, controller process, a refused command); its folder holds what was done."""


def _finish(rec, q2, truth, q2cal, t0_us, complete, plots):
    from ground import plots as plt_mod
    q2_err = q2_error_arcsec(q2, q2cal) if q2cal is not None else np.full((len(q2), 2), np.nan)
    rec.write_samples(q2, q2_err, truth, t0_us)
    rec.write_telemetry()
    ok = np.all(np.isfinite(q2_err), axis=1)
    radial = np.hypot(q2_err[:, 0], q2_err[:, 1])
    met = bool(complete and len(q2) > 0 and ok.all() and np.all(radial <= report.REQUIREMENT_ARCSEC))
    res = {"complete": complete, "requirement_met": met, "duration_s": rec.virtual_s, "play_wall_s": rec.play_wall,
           "real_time_factor": rec.virtual_s / rec.play_wall if rec.play_wall > 0 else None,
           "real_time_factor_first_minute": _rate(rec.minute_rates, True),
           "real_time_factor_last_minute": _rate(rec.minute_rates, False),
           "real_time_factor_per_10s": _per_10s(rec.minute_rates),
           "q2_samples": int(len(q2)), "q2_beam_lost_samples": int((~ok).sum()),
           "q2": report.error_stats(q2_err[ok, 0], q2_err[ok, 1]),
           "truth": report.error_stats(truth[:, 0], truth[:, 1]),
           "thesis": report.THESIS, "q2_calibration": q2cal,
           "telemetry_status_packets": len(rec.status),
           "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    if plots and len(q2):
        t = (q2[:, 1] - t0_us) * 1e-6
        plt_mod.hil_scatter({"Q2": (q2_err[ok, 0], q2_err[ok, 1]), "truth": (truth[:, 0], truth[:, 1])},
                            rec.path(FIGURES[0]), report.REQUIREMENT_ARCSEC)
        plt_mod.hil_time_history({"Q2": (t[ok], q2_err[ok, 0], q2_err[ok, 1]),
                                  "truth": (t, truth[:, 0], truth[:, 1])}, rec.path(FIGURES[1]))
    return res


def _cmd(a):
    from ground import runtime
    cfg = None
    if a.config is not None:
        from emulator.config import load_config
        cfg = load_config(a.config)
    try:
        s = run_hil(a.distfile, a.calibration, a.duration, a.runtime, a.link, a.output, config=cfg,
                    seed=a.seed, q2_dvp=a.q2_dv, quiet=a.quiet, plots=not a.no_plots, link_opts=runtime.link_options(a))
    except Interrupted:
        with open(os.path.join(a.output, "summary.json")) as f:
            s = json.load(f)
        print("interrupted after %.1f s of virtual time: partial run in %s (summary complete=false)"
              % (s["duration_s"], a.output), file=sys.stderr)
        return 130
    except RunFailed as exc:
        with open(os.path.join(a.output, "summary.json")) as f:
            s = json.load(f)
        for line in verdict_lines(s)[1:]:
            print(line, file=sys.stderr)
        print("fps hil: error: %s" % exc, file=sys.stderr)
        return 1
    print(report.table(s))
    print()
    print("%s over %s: %.1f s virtual in %.1f s wall, real-time factor %.1fx (first minute %s, last %s), "
          "overruns %d" % (a.runtime, a.link, s["duration_s"], s["play_wall_s"], s["real_time_factor"],
                           _x(s["real_time_factor_first_minute"]), _x(s["real_time_factor_last_minute"]),
                           s["overruns"]))
    if s.get("jitter_harmonics") and isinstance(s["jitter_harmonics"], list):
        print()
        print("| wheel harmonic (Hz) | in the file X / Y (arcsec) | played | after the FSM loop (truth) | "
              "model after |")
        print("|---|---|---|---|---|")
        for h in s["jitter_harmonics"]:
            print("| %.2f | %.4f / %.4f | %.4f / %.4f | %.4f / %.4f | %.4f / %.4f |" % (
                h["wheel_hz"], *h["file_arcsec"], *h["played_arcsec"], *h["after_loop_arcsec"],
                *h["model_after_arcsec"]))
    verdict.close(a.output, verdict_lines(s))
    w = wire_deadline(s)
    return 0 if s["requirement_met"] and (w is None or w["met"]) else 3


def _x(v):
    return "—" if v is None else "%.1fx" % v


EXIT_STATUS = """exit status: 0 complete and every Q2 sample within 11.98 arcsec (with --runtime qemu, every tick's
answer out on the wire within its tick too); 3 complete but a requirement missed; 1 failed (link down or too noisy, controller exited, a command refused: the folder holds the partial
run with complete=false and the error); 2 bad input; 130 interrupted (partial folder, complete=false)."""


def add_run_arguments(p, seed_help="the emulator's seed, >= 0 (default 0)"):
    """The run flags ``fps hil`` and ``fps system`` share: bench config, seed, Q2 calibration, output."""
    p.add_argument("--config", help="bench config JSON (default: the thesis bench preset)")
    p.add_argument("--seed", type=int, default=0, help=seed_help)
    p.add_argument("--q2-dv", type=float, default=0.05, help="P-FSM perturbation for the Q2 calibration, V "
                   "(default 0.05; at least 4 codes of the P-FSM's DAC, 1.2 mV, up to 2 V)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("-o", "--output", required=True, type=output_folder, help="run folder")


def register(sub, name, help_):
    import argparse
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0], epilog=EXIT_STATUS,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--distfile", required=True, help="distfile to play (fps distfile generate)")
    p.add_argument("--calibration", required=True, help="H calibration JSON (fps calibrate)")
    p.add_argument("--duration", type=float, default=600.0, help="the seconds collected: the play, virtual s "
                   "(default 600)")
    from ground.runtime import add_link_arguments
    add_link_arguments(p)
    add_run_arguments(p)

    def func(a):
        from ground.runtime import default_link
        default_link(a)
        return _cmd(a)
    p.set_defaults(func=func)
