"""``fps system``: the whole terminal in one run, the ADCS loop and the fine-pointing loop coupled live.

- The ADCS loop (``--adcs``) runs ahead in its own process (``multiprocessing``, spawn) and sends one message
  per 1 s cycle: ``firmware``, the ADCS flight software on CAN against the emulated spacecraft
  (``emulator.adcs_session.AdcsSession``), or ``ground``, the body pointing simulator of Sec. 6.4
  (``ground.adcs.body_pointing.simulate``: truth, 41-state APKF, STKF with the EAFLS and the controller, run whole and
  sent in 1 s slices; its results are those of ``fps adcs bps``). Of each cycle's ten 0.1 s truth samples the
  body pointing error (dtheta1, dtheta2 about the laser line of sight, Eq. 6.12-6.16) and the stability
  (Eq. 6.18-6.21) are taken by ``ground.adcs.body_pointing.pointing_errors``; the flight software's estimates ("est")
  are compared with the truth at the cycle's start.
- The fine-pointing loop runs as ``fps hil`` does (``ground.hil``: the bench in lockstep with the controller
  firmware over serial, ``micropython`` or ``cpython``, at 637.8 Hz; H calibration, Q2 calibration, Q2
  recorder), but its disturbance player is live: from the start of the collection window (after the ADCS's
  30 s hold and 4 t_s of settling, t = 0 of the play) the 10 Hz dtheta are resampled to the 8.192 ms distfile
  step by 3rd-order Lagrange interpolation (Sec. 7.3.1, ``ground.resample``: the same samples ``fps distfile
  generate --source bps`` would write) and appended to an in-memory distfile that ``firmware.player.Player``
  plays (Keys's 6-point cubic interpolation, Eq. 7.7-7.8 to AD660 codes at 10.6 kHz). A sample beyond the P-FSM's
  +-3 deg / 13.33 is refused (the run fails, as ``ground.distfile_cli.check_playable`` refuses a distfile).
- Coupling and timing: before each 1 s chunk of the fine loop the main process takes ADCS messages until the
  disturbance is known to the chunk's end (plus the interpolation stencil); the ADCS process is ahead, so the
  two loops overlap on two cores. The body pointing reaches the P-FSM with no other delay.

- One verdict for the terminal (``verdict``): the fine loop (every Q2 sample within 11.98″) and the body loop
  (3σ pointing <= 150″, stability <= 35″/s); exit 0 only when the run completed and both are met, 3 when it
  completed and a budget was missed.
- Failures end the run within a bound: the ADCS process sends a heartbeat every ``HEARTBEAT_S`` and is declared
  stopped after ``SILENT_S`` without a message; ``AdcsFeed.close`` asks it to stop, then SIGTERMs, then SIGKILLs
  it (``STOP_S``), reading its queue meanwhile so that its writer never blocks the exit.

Run folder (atomic writes): ``config.json``, ``calibration.json``, ``q2_calibration.json``, ``telemetry.csv``,
``samples.npz`` (as ``fps hil``), ``body.npz`` (10 Hz dtheta, domega and estimate errors), ``summary.json``
(``complete`` false until the end; ``verdict``; a stopped run's ``error`` and ``stopped_in``, the phase it was
in), ``report.md`` and ``system_pointing.png`` (both pointing errors on one time axis); a failure, Ctrl-C or
SIGTERM leaves the folder valid with ``complete: false``.
"""

import contextlib
import io
import json
import math
import multiprocessing
import os
import queue
import signal
import struct
import sys
import threading
import time

import numpy as np

from ground import hil, report
from ground.adcs.campaign import MAX_DURATION_S     # the ADCS's run is held in memory, as fps adcs bps's
from ground.adcs.options import add_fault_options, add_satb_gnss_option, faults_from_args
from ground.fileio import cache_folder, run_folder, write_atomic, write_json
from protocol.units import RAD_PER_ARCSEC

ADCS_KINDS = ("firmware", "ground")
FIGURE = "system_pointing.png"
RUNTIMES = ("micropython", "cpython", "qemu")
LEAD_S = 2.0              # ADCS seconds simulated beyond the play: the last chunk's interpolation stencil
STENCIL_S = 0.25          # the 10 Hz samples needed beyond a distfile sample (two steps of 0.1 s, and a margin)
WAIT_S = 600.0            # longest wait for the ADCS's progress (a message other than its heartbeat)
HEARTBEAT_S = 1.0         # the ADCS process says it is alive this often, whatever it is doing
SILENT_S = 10.0           # no message at all for this long (heartbeat included): the ADCS stopped answering
START_S = 60.0            # the ADCS process's first message (its heartbeat) is due within this of its start
STOP_S = (2.0, 3.0, 2.0)  # close(): the ADCS process's time to end when asked, after SIGTERM, after SIGKILL
GOAL_RTF = 5.0            # issue 13: the 600 s run >= 5x real time on 2 cores
def firmware_available():
    """True when the ADCS-on-CAN session (``emulator.adcs_session``) is part of this build."""
    import importlib.util
    return importlib.util.find_spec("emulator.adcs_session") is not None


# --- the live disturbance: 10 Hz body pointing error -> distfile samples -> the P-FSM player ------------------
class LiveDistfile:
    """A float32 distfile (``protocol.distfile`` kind 1) growing in memory, read by ``firmware.player.Player``
    exactly as a file: ``raw``, ``count``, ``sample_offset(i)``, ``period_us``, ``kind``, ``scale``."""

    kind = 1
    scale = 1.0

    def __init__(self, period_us):
        self.period_us = int(period_us)
        self.raw = bytearray()
        self.count = 0

    def append(self, x, y):
        xy = np.empty(2 * len(x), dtype="<f4")
        xy[0::2], xy[1::2] = x, y
        self.raw += xy.tobytes()
        self.count += len(x)

    def sample_offset(self, i):
        if i < 0 or i >= self.count:
            raise IndexError("live distfile sample %d out of range [0, %d)" % (i, self.count))
        return 8 * i

    def sample(self, i):
        return struct.unpack_from("<ff", self.raw, self.sample_offset(i))


class LiveDisturbance:
    """The body pointing error (t in s of the ADCS, dtheta in arcsec, 10 Hz) from ``t0`` on, resampled to the
    distfile step as it arrives (3rd-order Lagrange, Sec. 7.3.1; a sample is made once its 4-point stencil is
    known, so it equals ``ground.resample.to_dist_step`` of the whole history) and appended to ``reader``.
    ``covered_s`` is the play time known so far. A sample beyond the P-FSM's range raises ValueError."""

    def __init__(self, t0, period_us=None):
        from ground.resample import DIST_PERIOD_US
        self.t0 = float(t0)
        self.reader = LiveDistfile(period_us or DIST_PERIOD_US)
        self.dt = self.reader.period_us * 1e-6
        self.t = np.zeros(0)
        self.xy = np.zeros((0, 2))
        self.x, self.y = [], []       # what was made, arcsec (for the summary)

    def add(self, t, dtheta_arcsec):
        keep = np.asarray(t) >= self.t0 - 1e-9
        if not keep.any():
            return
        self.t = np.concatenate([self.t, np.asarray(t, float)[keep]])
        self.xy = np.vstack([self.xy, np.asarray(dtheta_arcsec, float)[keep]])
        self._make()

    @property
    def covered_s(self):
        return (self.reader.count - 1) * self.dt if self.reader.count else -1.0

    def _make(self):
        from ground.distfile_cli import check_playable
        from ground.resample import lagrange3
        n = len(self.t)
        if n < 4:
            return
        j0 = self.reader.count
        j1 = j0
        while self.t0 + j1 * self.dt < self.t[n - 2] - 1e-9:     # stencil t[i-1] .. t[i+2] all known
            j1 += 1
        if j1 == j0:
            return
        t_out = self.t0 + np.arange(j0, j1) * self.dt
        i = int(np.searchsorted(self.t, t_out[0], side="right")) - 1
        w = max(0, i - 1)
        xy = lagrange3(self.t[w:], self.xy[w:], t_out)
        try:
            check_playable(xy[:, 0], xy[:, 1], self.reader.period_us)
        except ValueError:
            x = np.concatenate([self.x, xy[:, 0]])      # the message names the sample from the play's start
            y = np.concatenate([self.y, xy[:, 1]])
            try:
                check_playable(x, y, self.reader.period_us)
            except ValueError as exc:
                raise ValueError("the live body pointing error cannot be played: %s" % exc) from None
        self.x.extend(xy[:, 0].tolist())
        self.y.extend(xy[:, 1].tolist())
        self.reader.append(xy[:, 0], xy[:, 1])


# --- the ADCS process ----------------------------------------------------------------------------------------
def settle_s(ts):
    """Where the collection window starts: the 30 s hold and 4 t_s of settling (``bps.simulate``)."""
    from ground.adcs import body_pointing as bps
    return bps.HOLD_S + 4.0 * ts


def estimation_accuracy(t, err, t_from, t_to):
    """The filters' accuracy over [t_from, t_to] from rows of ``bps.estimate_errors``: attitude and rate 1 sigma
    per axis and 3 sigma (of the norm, as the pointing budget), rA and rB position RMS (m)."""
    from ground.adcs import body_pointing as bps
    t = np.asarray(t, float)
    err = np.asarray(err, float).reshape(-1, len(bps.EST_COLS))
    sel = (t >= t_from - 1e-9) & (t <= t_to + 1e-9) & np.all(np.isfinite(err), axis=1)
    if sel.sum() < 2:
        return None
    e = err[sel]
    sa, sw = e[:, 0:3].std(axis=0), e[:, 3:6].std(axis=0)
    return {"attitude_sigma_arcsec": sa.tolist(), "attitude_3sigma_arcsec": float(3 * np.linalg.norm(sa)),
            "rate_sigma_arcsec_s": sw.tolist(), "rate_3sigma_arcsec_s": float(3 * np.linalg.norm(sw)),
            "ra_rms_m": float(np.sqrt(np.mean(e[:, 6] ** 2))), "rb_rms_m": float(np.sqrt(np.mean(e[:, 7] ** 2))),
            "samples": int(sel.sum())}


class _Stopped(Exception):
    """The parent asked the ADCS process to stop."""


def _vehicle(spec):
    """The spec's checked spacecraft file (thesis-3u when it has none)."""
    from emulator.spacecraft import scenario
    return spec.get("spacecraft") or scenario.thesis_3u()


def _ground_run(spec, params, on_cycle=None, stop=None):
    """``bps.simulate`` for the spec; returns (result, history, estimate errors (K+1, 8)). ``on_cycle(msg)``
    gets each second as the simulation makes it (the body pointing error of its ten steps, Eq. 6.12-6.21, on the
    truth ``simulate`` hands over, and the estimate errors at its start)."""
    from ground.adcs import body_pointing as bps
    d = _vehicle(spec)
    lb = bps.laser_axis(d)

    def second(k, hist, fsw, x):
        if stop is not None and stop.is_set():
            raise _Stopped
        sl = slice(10 * k + 1, 10 * k + 11)
        dth, dom = bps.pointing_errors(hist["q"][sl], hist["w"][sl], x[:, 0, 0:3], x[:, 0, 3:6], x[:, 1, 0:3],
                                       x[:, 1, 3:6], lb)
        on_cycle({"t": hist["t"][sl].copy(), "dtheta": dth / RAD_PER_ARCSEC, "domega": dom / RAD_PER_ARCSEC, "t_est": float(k),
                  "est_err": fsw["est_err"][k].copy()})

    fly = spec.get("world") == "flight"
    res, hist = bps.simulate(ts=spec["ts"], satb_gnss=spec["satb_gnss"],
                             duration_s=spec["adcs_duration_s"] + (_t_settle(spec) if fly else 0.0),
                             seed=spec["seed"], params=params, truth=spec["truth"], cache_dir=spec["cache_dir"],
                             on_second=second if on_cycle is not None else None, spacecraft=d,
                             world=spec.get("world", "thesis"))
    return res, hist, hist["fsw_est_err"]


def _reference(res, hist, err, spec):
    """The ground filters' figures of a ``bps.simulate`` run over the window the play covers (``duration_s``
    from the end of the settling), as ``fps system`` takes its own."""
    from ground.adcs import body_pointing as bps
    t0 = _t_settle(spec)
    t1 = t0 + spec["duration_s"]
    sel = (hist["t"] >= t0 - 1e-9) & (hist["t"] <= t1 + 1e-9)
    out = bps.statistics(hist["dtheta_arcsec"][sel] * RAD_PER_ARCSEC, hist["domega_arcsec_s"][sel] * RAD_PER_ARCSEC)
    out["complete"] = bool(res["complete"])
    out["estimation"] = estimation_accuracy(np.arange(len(err)), err, t0, t1)
    out["source"] = "ground.adcs.body_pointing.simulate (41-state APKF, STKF + EAFLS), seed %d" % spec["seed"]
    return out


def _t_settle(spec):
    """Where the play starts in the ADCS's time (``run_system``'s t_settle)."""
    return spec.get("t_settle", settle_s(spec["ts"]))


def _send_ground(spec, params, q, stop):
    q.put(("info", {"settle_s": _t_settle(spec)}))
    try:
        res, hist, err = _ground_run(spec, params, lambda m: q.put(("cycle", m)), stop)
    except _Stopped:
        return
    q.put(("reference", _reference(res, hist, err, spec)))


def _send_firmware(spec, params, q, stop):
    """The session's cycles (``duration_s`` = its number of 1 s cycles: the settling, the play and the lead);
    the orbit truth and its cache as the ground reference's, where the session takes them."""
    from emulator.adcs_session import AdcsSession
    from ground.adcs import body_pointing as bps
    n = int(np.ceil(_t_settle(spec) + spec["adcs_duration_s"]))
    q.put(("info", {"settle_s": _t_settle(spec)}))
    link_faults = None
    if spec.get("link_faults"):
        from protocol.faults import LinkFaults
        link_faults = LinkFaults.parse(spec["link_faults"])
    d = _vehicle(spec)
    lb = bps.laser_axis(d)
    s = AdcsSession(runtime=spec["runtime"], satb_gnss=spec["satb_gnss"], seed=spec["seed"], duration_s=float(n),
                    ts=spec["ts"], params=params, log=lambda m: q.put(("log", m)), truth=spec["truth"],
                    cache_dir=spec["cache_dir"], faults=spec.get("faults"), link_faults=link_faults, spacecraft=d,
                    world=spec.get("world", "thesis"))
    try:
        s.start()
        prev = None          # the truth at the end of the previous cycle: the instant of this cycle's estimate
        for _ in range(n):
            if stop.is_set():
                return
            c = s.cycle()
            dth, dom = bps.pointing_errors(c["q"], c["w"], c["ra"], c["va"], c["rb"], c["vb"], lb)
            e = c.get("est") or {}
            err = np.full(len(bps.EST_COLS), np.nan)
            if prev is not None and all(k in e for k in ("q", "w", "ra", "rb")):
                err = bps.estimate_errors(e["q"], e["w"], e["ra"], e["rb"], *prev)
            prev = (c["q"][-1], c["w"][-1], c["ra"][-1], c["rb"][-1])
            t = np.round(np.asarray(c["t"], float) * 10.0) / 10.0      # the 0.1 s steps, without summing drift
            q.put(("cycle", {"t": t, "dtheta": dth / RAD_PER_ARCSEC, "domega": dom / RAD_PER_ARCSEC,
                             "t_est": float(e.get("t", t[0] - 0.1)), "est_err": err,
                             "status": _jsonable(c.get("status"))}))
        q.put(("adcs_summary", _jsonable(dict(s.summary(), **(s.board() or {})))))
    finally:
        s.close()
    res, hist, err = _ground_run(spec, params)          # the ground filters on the same scenario
    q.put(("reference", _reference(res, hist, err, spec)))


def _jsonable(v):
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


class StopFlag:
    """The parent's "stop" to the ADCS process: one shared byte, no lock and no waiters, so that setting it never
    blocks on a process that died (``multiprocessing.Event.set`` waits for its sleepers, a dead one for ever).
    ``is_set()`` as ``threading.Event``'s."""

    def __init__(self, ctx):
        self._v = ctx.RawValue("b", 0)

    def set(self):
        self._v.value = 1

    def is_set(self):
        return bool(self._v.value)


def _heartbeat(q, stop):
    """A daemon thread putting ("alive", None) every ``HEARTBEAT_S`` until ``stop``: the parent tells a busy
    ADCS from one that stopped answering (``SILENT_S``)."""
    def beat():
        while not stop.is_set():
            with contextlib.suppress(Exception):
                q.put(("alive", None))
            time.sleep(HEARTBEAT_S)
    threading.Thread(target=beat, name="fps-system-heartbeat", daemon=True).start()


def adcs_worker(spec, q, stop):
    """The ADCS process: messages ("info" | "cycle" | "adcs_summary" | "reference" | "error" | "end" | "alive",
    dict). Stopped by the parent (``stop`` or SIGTERM), it leaves without waiting to flush its queue."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # the parent takes Ctrl-C and stops this process
    busy = [True]

    def on_term(signum, frame):                       # terminate(): unwind, so the session closes its firmware
        signal.signal(signal.SIGTERM, signal.SIG_DFL)    # a second one ends the process at once
        q.cancel_join_thread()                        # the parent has given up: exit without flushing the queue
        if busy[0]:
            raise _Stopped
        os._exit(0)                                   # done (flushing at exit): nothing to unwind
    signal.signal(signal.SIGTERM, on_term)
    try:
        _heartbeat(q, stop)
        try:
            from ground.adcs import body_pointing as bps, bps_cli
            d = _vehicle(spec)
            params = spec["params"] or bps_cli.calibration(spec["seed"], spec["bps_cache"], False, d)
            bps.check_params(params, spacecraft=d)
            (_send_ground if spec["adcs"] == "ground" else _send_firmware)(spec, params, q, stop)
        except _Stopped:
            pass
        except BaseException as exc:       # noqa: BLE001 (reported to the parent, which fails the run)
            q.put(("error", "%s: %s" % (type(exc).__name__, exc)))
        if stop.is_set():
            q.cancel_join_thread()          # the parent stopped reading: do not wait on a full pipe at exit
        else:
            q.put(("end", {}))
    except _Stopped:
        pass
    finally:
        busy[0] = False


class AdcsFeed:
    """The parent's side of the ADCS process: ``take(until_t)`` collects messages until the ADCS has reached
    ``until_t`` (s of ADCS time); the 10 Hz samples go to ``on_samples(t, dtheta)`` (None: recorded only).
    ``close()`` ends the process within ``sum(STOP_S)`` s whatever its state."""

    def __init__(self, spec, on_samples):
        ctx = multiprocessing.get_context("spawn")
        self.q = ctx.Queue()
        self.stop = StopFlag(ctx)
        # not a daemon: the session may start processes of its own; close() always ends it
        self.proc = ctx.Process(target=adcs_worker, args=(spec, self.q, self.stop), name="fps-system-adcs")
        self.on_samples = on_samples
        self.t, self.dth, self.dom = [], [], []
        self.t_est, self.est_err = [], []
        self.info, self.reference, self.adcs_summary, self.last_status = {}, None, None, None
        self.t_last = -1.0
        self.ended = False
        self.closed = False
        self.log = []               # the session's one-line messages (mode changes, late cycles, faults)
        self.wait_s = 0.0           # the fine loop's wall time spent waiting for the ADCS
        self.t_started = None       # perf_counter at start()
        self.t_heard = None         # perf_counter of the last message read (heartbeat included)

    def start(self):
        """Start the ADCS process with SIGINT blocked (Ctrl-C is the parent's: it stops the process)."""
        self.t_started = time.perf_counter()
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            self.proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)

    def _handle(self, kind, d, play=True):
        """One message. ``play`` false (after the play, or a failed run): samples are recorded but not played,
        and an ADCS error goes to the log instead of raising."""
        if kind == "cycle":
            self.t.append(d["t"])
            self.dth.append(d["dtheta"])
            self.dom.append(d["domega"])
            self.t_est.append(d["t_est"])
            self.est_err.append(d["est_err"])
            if d.get("status") is not None:
                self.last_status = d["status"]
            self.t_last = float(d["t"][-1])
            if play and self.on_samples is not None:
                self.on_samples(d["t"], d["dtheta"])
        elif kind == "info":
            self.info.update(d)
        elif kind == "reference":
            self.reference = d
        elif kind == "adcs_summary":
            self.adcs_summary = d
        elif kind == "error":
            if not play:
                self.log.append("ADCS error: %s" % d)
                return
            raise OSError("the ADCS (%s) failed: %s" % (self.info.get("adcs", "process"), d))
        elif kind == "log":
            self.log.append(d)
        elif kind == "end":
            self.ended = True

    def _get(self, timeout):
        try:
            m = self.q.get(timeout=timeout)
        except queue.Empty:
            return None
        except (OSError, EOFError, ValueError):    # the pipe broke (a killed process) or the queue is closed
            return None
        self.t_heard = time.perf_counter()
        return m

    def take(self, until_t=None, want=None, timeout_s=WAIT_S):
        """Messages until the ADCS time reaches ``until_t`` (or ``want()`` is true); OSError if it cannot: the
        process ended or exited, sent nothing for ``SILENT_S`` (``START_S`` for its first message), or made no
        progress (a message other than its heartbeat) for ``timeout_s``."""
        t_wait0 = time.perf_counter()
        t_progress = t_wait0
        try:
            while not (until_t is not None and self.t_last >= until_t - 1e-9 or want is not None and want()):
                if self.ended:
                    raise OSError("the ADCS ended at t = %.1f s, before t = %s s" % (
                        self.t_last, "%.1f" % until_t if until_t is not None else "?"))
                m = self._get(0.5)
                now = time.perf_counter()
                if m is None:
                    if not self.proc.is_alive() and self.q.empty():
                        raise OSError("the ADCS process exited (status %s) at t = %.1f s"
                                      % (self.proc.exitcode, self.t_last))
                    if self.t_heard is None and now - (self.t_started or t_wait0) > START_S:
                        raise OSError("the ADCS process sent nothing within %g s of its start" % START_S)
                    if self.t_heard is not None and now - self.t_heard > SILENT_S:
                        raise OSError("the ADCS process stopped answering: nothing from it for %g s (at t = %.1f s)"
                                      % (SILENT_S, self.t_last))
                    if now - t_progress > timeout_s:
                        raise OSError("no progress of the ADCS for %g s (at t = %.1f s)" % (timeout_s, self.t_last))
                    continue
                if m[0] != "alive":
                    t_progress = now
                    self._handle(*m)
        finally:
            self.wait_s += time.perf_counter() - t_wait0

    def drain(self, wait_s=1.0):
        """What has arrived (for at most ``wait_s`` of reading), recorded, never played and never raising."""
        deadline = time.perf_counter() + wait_s
        while time.perf_counter() < deadline:
            try:
                m = self.q.get_nowait()
            except (queue.Empty, OSError, EOFError, ValueError):
                return
            if m[0] != "alive":
                with contextlib.suppress(Exception):
                    self._handle(*m, play=False)

    def arrays(self):
        from ground.adcs import body_pointing as bps
        cat = (lambda v, shape: np.concatenate(v) if v else np.zeros(shape))
        return (cat(self.t, (0,)), cat(self.dth, (0, 2)), cat(self.dom, (0, 2)), np.array(self.t_est),
                np.array(self.est_err).reshape(-1, len(bps.EST_COLS)))

    def close(self):
        """Stop the ADCS process and return whether a Ctrl-C or SIGTERM came meanwhile (held until the process is
        gone). Asked first (``stop``), then SIGTERM (with SIGCONT, for a stopped process), then SIGKILL, each
        given its share of ``STOP_S``; its queue is read meanwhile, so its writer never blocks on a full pipe.
        Idempotent; never raises."""
        if self.closed:
            return False
        self.closed = True
        with _signals_held() as held:
            self.stop.set()
            try:
                if self.proc.pid is not None:
                    for step, wait_s in zip(("ask", "terminate", "kill"), STOP_S):
                        if step == "terminate":
                            with contextlib.suppress(Exception):
                                self.proc.terminate()
                                os.kill(self.proc.pid, signal.SIGCONT)
                        elif step == "kill":
                            with contextlib.suppress(Exception):
                                self.proc.kill()
                        self._drain_until_gone(wait_s)
                        if not self.proc.is_alive():
                            break
                    with contextlib.suppress(Exception):
                        self.proc.join(0.1)
            finally:
                with contextlib.suppress(Exception):
                    self.q.cancel_join_thread()
                    self.q.close()
        return bool(held)

    def _drain_until_gone(self, wait_s):
        deadline = time.perf_counter() + wait_s
        while self.proc.is_alive() and time.perf_counter() < deadline:
            m = self._get(0.05)
            if m is not None and m[0] != "alive":
                with contextlib.suppress(Exception):
                    self._handle(*m, play=False)
        if not self.proc.is_alive():
            self.drain()


@contextlib.contextmanager
def _signals_held():
    """SIGINT and SIGTERM are noted, not raised, inside (the main thread only); yields the list of those noted."""
    held = []
    old = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, lambda signum, frame: held.append(signum))
    except ValueError:          # not the main thread: signals are not delivered here anyway
        pass
    try:
        yield held
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


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
               quiet=False, plots=True, faults=None, link_faults=None, spacecraft=None, world="thesis"):
    """The whole run; returns the summary (also in ``out_dir/summary.json``). Bad input raises ValueError before
    anything is written; afterwards the folder always ends valid, and a failure raises ``hil.RunFailed``, an
    interruption ``hil.Interrupted``. ``faults``: the ADCS session's (``emulator.adcs_session``: wheel_silent,
    startracker_blind, gnss_outage, beacon_lost; times in the ADCS's seconds, the play starting after its
    settling), firmware ADCS only; its fault log is in the summary's ``adcs_summary`` and the report.
    ``link_faults``: a ``protocol.faults.LinkFaults`` on the ADCS's CAN link (its slcan stream; firmware ADCS
    only), the retries it costs in ``adcs_summary``'s ``retries``. ``spacecraft``: a preset's name or a spacecraft
    file (None: thesis-3u), the vehicle of the ADCS (``fps adcs bps`` or ``fps adcs can`` with ``--spacecraft``).
    ``world``: "thesis" (Sec. 6.4's) or "flight" (``fps adcs bps --world flight``'s: datasheet wheels,
    magnetorquers, the rate-limited slew; the lean firmware flies its modes, ``firmware/adcs/flight.py``); in the
    flight world the play starts at ``bps.flight_settle_s`` (the planned slew, re-acquisition and 4 t_s)."""
    from firmware.player import Player
    from ground import runtime
    from ground.adcs import body_pointing as bps, bps_cli, runs
    from ground.adcs.options import load_spacecraft
    from ground.calibrate import load_calibration

    t_wall0 = time.perf_counter()
    ts = check_inputs(duration_s, runtime_name, adcs, ts, truth, seed)
    if world not in bps.WORLDS:
        raise ValueError("--world must be one of %s, got %r" % (", ".join(bps.WORLDS), world))
    if faults and adcs != "firmware":
        raise ValueError("--faults needs --adcs firmware (the faults are the emulated spacecraft's devices')")
    if link_faults is not None and adcs != "firmware":
        raise ValueError("--link-faults needs --adcs firmware (they act on the ADCS's CAN link)")
    hil.check_q2_dv(q2_dvp)
    runtime.check_board(config)
    cal = load_calibration(calibration_path) if calibration_path else None
    d, source = load_spacecraft(spacecraft, partner=True)
    record = runs.spacecraft_record(d, source)
    params = bps.load_params(params_path, d)[-1] if params_path else None
    duration_s = float(duration_s)
    if world == "flight" and d["magnetorquers"] is None:
        raise ValueError("magnetorquers = null in the spacecraft file: the flight world unloads the wheels with "
                         "magnetorquers (or --world thesis)")
    t_settle = settle_s(ts) if world == "thesis" else bps.flight_settle_s(d, ts)
    if faults:
        from emulator.adcs_session import check_faults
        faults = check_faults(faults, t_settle + duration_s + LEAD_S)
    run_folder(out_dir, hil.FIGURES + (FIGURE,))           # the fine loop's figures are hil's
    rec = hil.Recorder(out_dir)
    summary = hil.new_summary(duration_s)
    summary.update({"adcs": adcs, "runtime": runtime_name, "goal_real_time_factor": GOAL_RTF,
                    "satb_gnss": bool(satb_gnss), "ts_s": ts, "seed": seed, "phase": "start", "stopped_in": None,
                    "spacecraft": record, "world": world})
    write_json(rec.path("summary.json"), summary)
    spec = {"adcs": adcs, "runtime": runtime_name, "satb_gnss": bool(satb_gnss), "seed": int(seed), "ts": ts,
            "truth": truth, "duration_s": duration_s, "adcs_duration_s": duration_s + LEAD_S, "params": params,
            "bps_cache": bps_cache or bps_cli.CACHE_DEFAULT,
            "cache_dir": os.path.abspath(bps_cache or bps_cli.CACHE_DEFAULT), "faults": faults or None,
            "link_faults": link_faults.describe() if link_faults is not None else None, "spacecraft": d,
            "world": world, "t_settle": t_settle}
    live = LiveDisturbance(t_settle)
    say = (lambda m: None) if quiet else (lambda m: print("fps system: " + m, file=sys.stderr))
    feed = AdcsFeed(spec, live.add)
    feed.info["adcs"] = adcs
    run = hil.RunOutcome(runtime_name, "serial")
    q2cal = None
    try:
        with run.guard():
            try:
                summary["phase"] = "start"           # where the run is (and, in stopped_in, where it stopped)
                feed.start()
                config_json = {
                    "adcs": adcs, "adcs_runtime": runtime_name if adcs == "firmware" else None,
                    "satb_gnss": satb_gnss, "ts_s": ts, "truth": truth, "settle_s": t_settle, "world": world,
                    "params": params_path and os.path.abspath(params_path),
                    "calibration": calibration_path and os.path.abspath(calibration_path), "seed": seed,
                    "duration_s": duration_s, "runtime": runtime_name, "link": "serial", "faults": faults or None,
                    "adcs_link_faults": spec["link_faults"], "spacecraft": record,
                    "distfile_period_us": live.reader.period_us, "live_player": True}
                write_json(rec.path("config.json"), config_json)
                if cal is None:
                    summary["phase"] = "h_calibration"
                    say("calibrating H in-process first (Sec. 7.4, 121 points; --calibration FILE skips this) ...")
                    cal = calibrate_inproc(seed, config, rec.path("calibration.json"))
                else:
                    write_json(rec.path("calibration.json"), cal)
                summary["phase"] = "controller_start"
                with runtime.open_rig(runtime_name, "serial", config=config, seed=seed) as rig:
                    run.rig = rig
                    write_json(rec.path("config.json"), dict(hil.run_config(rig, duration_s, seed, {}), **config_json))

                    def first_sample():
                        summary["phase"] = "adcs_settling"
                        if feed.t_last < t_settle + STENCIL_S + 0.2:
                            say("waiting for the ADCS to reach the end of its settling (t = %g s of its time) ..."
                                % t_settle)
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
                feed.on_samples = None                # the play is over: later samples are recorded, not played
                summary["phase"] = "reference"
                with contextlib.suppress(OSError):    # the ground filters' column (firmware: after the session)
                    feed.take(want=lambda: feed.reference is not None, timeout_s=300.0)
            except BaseException:
                feed.close()                          # bounded, whatever the ADCS process is doing
                raise
            if feed.close():
                raise KeyboardInterrupt               # Ctrl-C or SIGTERM while the ADCS process was being stopped
        stopped_in = summary["phase"] if run.failure or run.interrupted else None
        hil.board_figures(run, summary)            # --runtime qemu: the controller's board
        hil.finish_summary(rec, run, summary, q2cal, plots)
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
            _plot(rec, feed, q2cal, t_settle, faults)
        write_atomic(rec.path("report.md"), report_md(summary))
    except BaseException as exc:     # past the guard (a bug, the disk, Ctrl-C while finishing): the folder says so
        feed.close()
        _stopped_folder(rec, summary, exc)
        raise
    run.raise_if_stopped(out_dir, summary)
    return summary


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
    return {"settle_s": t_settle, "body_pointing": body, "estimation": est, "ground_reference": feed.reference,
            "disturbance": dist, "adcs_summary": feed.adcs_summary, "adcs_last_status": feed.last_status,
            "adcs_log": feed.log[-200:],
            "adcs_info": {k: v for k, v in feed.info.items() if k != "adcs"},
            "thesis_body": thesis_body()}


def verdict(s):
    """One verdict for the terminal from a summary's figures. Fine loop: every Q2 sample within 11.98″ and none
    with the beam lost (``fps hil``'s requirement). Body loop: 3σ pointing and stability within
    ``bps.BUDGET_POINTING_3SIGMA`` and ``bps.BUDGET_STABILITY_3SIGMA`` (as ``fps adcs can`` judges them). A loop's
    ``met`` is None without figures; ``met`` is true only when the run completed and both loops are met.
    ``missed``: one line per figure that missed, naming the loop and by how much."""
    from ground.adcs import body_pointing as bps
    req = report.REQUIREMENT_ARCSEC
    n, lost = int(s.get("q2_samples") or 0), int(s.get("q2_beam_lost_samples") or 0)
    worst = (s.get("q2") or {}).get("max_radial_arcsec")
    fine = {"met": None if n == 0 else bool(lost == 0 and worst is not None and worst <= req),
            "worst_arcsec": worst, "budget_arcsec": req, "over_arcsec": _over(worst, req),
            "q2_samples": n, "beam_lost_samples": lost}
    b = s.get("body_pointing") or {}
    p, w = b.get("pointing_3sigma_arcsec"), b.get("stability_3sigma_arcsec_s")
    pb, wb = bps.BUDGET_POINTING_3SIGMA, bps.BUDGET_STABILITY_3SIGMA
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
    complete = bool(s.get("complete"))
    return {"complete": complete, "met": bool(complete and fine["met"] and body["met"]), "fine": fine,
            "body": body, "missed": missed}


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
    yes = (lambda m: "—" if m is None else ("yes" if m else "**NO**"))
    rows = [("fine (Q2)", "largest radial error (arcsec)", f["worst_arcsec"], f["budget_arcsec"], f["over_arcsec"],
             f["met"]),
            ("body (ADCS)", "3σ pointing (arcsec)", b["pointing_3sigma_arcsec"], b["pointing_budget_arcsec"],
             b["pointing_over_arcsec"], None if b["met"] is None else b["pointing_over_arcsec"] == 0),
            ("body (ADCS)", "3σ stability (arcsec/s)", b["stability_3sigma_arcsec_s"], b["stability_budget_arcsec_s"],
             b["stability_over_arcsec_s"], None if b["met"] is None else b["stability_over_arcsec_s"] == 0)]
    out = ["## Verdict", "", "| loop | figure | this run | budget | over by | met |", "|---|---|---|---|---|---|"]
    for loop, label, val, budget, over, met in rows:
        out.append("| %s | %s | %s | %g | %s | %s |" % (loop, label, _f(val), budget, _f(over), yes(met)))
    if f["beam_lost_samples"]:
        out.append("")
        out.append("The beam was lost on Q2 in %d of %d samples (the fine loop misses)."
                   % (f["beam_lost_samples"], f["q2_samples"]))
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


def _plot(rec, feed, q2cal, t_settle, faults=None):
    """system_pointing.png on the ADCS's clock (the fault options'): the body error over the window played and the
    fine error, both from the ADCS's start."""
    from ground import plots as plt_mod
    from ground.adcs import body_pointing as bps
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
        plt_mod.system_time_history(body, fine, rec.path(FIGURE), report.REQUIREMENT_ARCSEC,
                                    bps.BUDGET_POINTING_3SIGMA, faults)


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
    lines.append("Estimates are compared with the truth at the instant of each 1 s cycle's estimate; the window "
                 "starts after the %g s hold and 4 t_s of settling (t = %.0f s)." % (_hold_s(), s.get("settle_s") or 0))
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


def _read_summary(out_dir):
    """The run folder's summary.json, or {} when it cannot be read (the error line says what happened)."""
    try:
        with open(os.path.join(out_dir, "summary.json")) as f:
            s = json.load(f)
        return s if isinstance(s, dict) else {}
    except (OSError, ValueError):
        return {}


def _link_faults_arg(text):
    """--link-faults SPEC as a ``LinkFaults`` (ValueError naming the option when it is malformed)."""
    if text is None:
        return None
    from protocol.faults import LinkFaults
    return LinkFaults.parse(text)


def _cmd(a):
    cfg = None
    if a.config is not None:
        from emulator.config import load_config
        cfg = load_config(a.config)
    try:
        s = run_system(a.duration, a.output, a.runtime, a.adcs, a.satb_gnss, a.seed, a.ts, a.truth, a.calibration,
                       a.params, a.bps_cache, cfg, a.q2_dv, a.quiet, not a.no_plots, faults_from_args(a),
                       _link_faults_arg(a.link_faults), a.spacecraft, a.world)
    except hil.Interrupted:
        s = _read_summary(a.output)
        print("interrupted after %.1f s of virtual time: partial run in %s (summary complete=false)"
              % (s.get("duration_s") or 0.0, a.output), file=sys.stderr)
        return 130
    except hil.RunFailed as exc:
        for line in verdict_lines(_read_summary(a.output))[1:]:
            print(line, file=sys.stderr)
        print("fps system: error: %s" % exc, file=sys.stderr)
        return 1
    print(side_by_side(s))
    print()
    print("ADCS %s, controller %s over serial: %.1f s virtual in %.1f s wall, real-time factor %s (play %s)"
          % (a.adcs, a.runtime, s["duration_s"], s["wall_s"], _x(s["real_time_factor"]),
             _x(s["real_time_factor_play"])))
    print("run folder %s: summary.json, report.md, samples.npz, body.npz, telemetry.csv%s"
          % (a.output, ", " + FIGURE if not a.no_plots else ""))
    rc = exit_code(s)
    for line in verdict_lines(s):
        print(line)
    return rc


EXIT_STATUS = """exit status: 0 complete, and both loops within their budgets (fine: every Q2 sample within 11.98
arcsec; body: 3 sigma pointing <= 150 arcsec and stability <= 35 arcsec/s); 3 complete but a budget missed
(summary.json's verdict and report.md name the loop and by how much); 1 failed (the ADCS failed or stopped
answering, a body pointing error beyond the P-FSM's range, link down, controller exited: the folder holds the
partial run with complete=false, the error and stopped_in); 2 bad input; 130 interrupted (partial folder,
complete=false)."""


def register(sub, name, help_):
    import argparse
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0], epilog=EXIT_STATUS,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=600.0,
                   help="virtual seconds of the collection window played to the P-FSM, at most %g (default 600); "
                        "the ADCS runs 30 s + 4 t_s of settling before it and %g s beyond" % (MAX_DURATION_S, LEAD_S))
    p.add_argument("--adcs", choices=ADCS_KINDS, default="firmware" if firmware_available() else "ground",
                   help="firmware: the ADCS flight software on CAN against the emulated spacecraft; ground: the "
                        "body pointing simulator of Sec. 6.4 (default: firmware when this build has it)")
    p.add_argument("--runtime", default="micropython", choices=RUNTIMES,
                   help="where the fine-pointing controller (and the ADCS firmware) run: micropython and cpython "
                        "on this machine, qemu on the PIL boards of make pil (the controller on a Cortex-M0, the "
                        "ADCS on a Cortex-M7; default micropython)")
    add_satb_gnss_option(p, False)
    p.add_argument("--ts", type=float, default=33.0, help="ADCS settling time t_s in s (default 33, Sec. 6.4.4)")
    p.add_argument("--truth", choices=("hpop", "two-body"), default="hpop", help="true orbits (default hpop)")
    p.add_argument("--params", default=None, help="ADCS parameter file (fps adcs bps format; default: the cached "
                   "nine calibration sets of --seed)")
    p.add_argument("--bps-cache", default=None, type=cache_folder,
                   help="calibration and truth cache folder (default out/bps_cache)")
    p.add_argument("--calibration", default=None, help="H calibration JSON (fps calibrate; default: calibrate "
                   "in-process first, 121 points, written to the run folder)")
    add_fault_options(p, "seconds from the ADCS's start, the play beginning after its 30 s hold and 4 t_s; "
                         "firmware ADCS only")
    p.add_argument("--link-faults", default=None, metavar="SPEC",
                   help="faults on the ADCS's CAN link (firmware ADCS), both directions of its slcan stream: "
                        "bytes=P (a bit flip per ASCII byte), frames=P (a CAN frame's line dropped), seed=N, "
                        "silence=START_S:LENGTH_S (the ADCS's seconds; LENGTH_S may be inf); the lockstep's "
                        "retries keep each 1 Hz cycle exactly once, e.g. bytes=0.001,frames=0.05,seed=1")
    p.add_argument("--world", choices=("thesis", "flight"), default="flight",
                   help="flight (default): datasheet wheel limits, drag and solar pressure, magnetorquer "
                        "unloading, a rate-limited slew and re-acquisition (fps adcs bps --world flight), the play "
                        "starting once the planned slew and 4 t_s of settling are over (~410 s for thesis-3u); "
                        "thesis: Sec. 6.4's world, the play after 30 s + 4 t_s")
    from ground.adcs.options import add_spacecraft_option
    add_spacecraft_option(p, "the ADCS's vehicle, as fps adcs bps (--adcs ground) or fps adcs can (--adcs "
                          "firmware) take it; --params is checked against it")
    hil.add_run_arguments(p, "seed of the ADCS scenario and the bench emulator")
    p.set_defaults(func=_cmd)
