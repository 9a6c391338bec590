"""The ADCS side of ``fps system``: the ADCS (the flight firmware on CAN, or the ground loop) in a process of its own, its messages (``AdcsFeed``), its heartbeat and its stop."""

import contextlib
import multiprocessing
import os
import queue
import signal
import sys
import tempfile
import threading
import time

import numpy as np

from emulator.runtime import die_with_parent, exit_status, last_lines
from ground.system.constants import HEARTBEAT_S, SILENT_S, START_S, STOP_S, WAIT_S
from protocol.units import RAD_PER_ARCSEC


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


class AdcsFailed(OSError):
    """The ADCS side of ``fps system`` failed (its process, its session, its firmware): the message names the
    part, not the fine loop's link."""


class _ChildFd:
    """A file descriptor handed to the spawned ADCS process: pickled while the process starts, the descriptor is
    passed to it (``multiprocessing.reduction.DupFd``); ``fd`` is its number there."""

    def __init__(self, fd):
        self.fd = fd

    def __reduce__(self):
        from multiprocessing import reduction
        return _child_fd, (reduction.DupFd(self.fd),)


def _child_fd(dup):
    return _ChildFd(dup.detach())


def _vehicle(spec):
    """The spec's checked spacecraft file (thesis-3u when it has none)."""
    from emulator.spacecraft import scenario
    return spec.get("spacecraft") or scenario.thesis_3u()


def _ground_run(spec, params, on_cycle=None, stop=None):
    """``bps.simulate`` for the spec; returns (result, history, estimate errors (K+1, 8)). ``on_cycle(msg)``
    gets each second as the simulation makes it (the body pointing error of its ten steps, Eq. 6.12-6.21, on the
    truth ``simulate`` hands over, and the estimate errors at its start)."""
    from emulator.spacecraft import scenario
    from ground.adcs import body_pointing as bps
    d = _vehicle(spec)
    lb = scenario.laser_axis(d)

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
                             world=spec.get("world", "thesis"), faults=spec.get("faults"),
                             stkf_accel=spec.get("stkf_accel", "white"))
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
    out["source"] = ("ground.adcs.flight_world.simulate (the flight app in process: lean APKF, lean STKF + AFLS)"
                     if spec.get("world") == "flight" else
                     "ground.adcs.body_pointing.simulate (41-state APKF, STKF + EAFLS)") + ", seed %d" % spec["seed"]
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
    if res.get("devices"):
        q.put(("adcs_summary", _jsonable(res["devices"])))
    q.put(("reference", _reference(res, hist, err, spec)))


def _send_firmware(spec, params, q, stop):
    """The session's cycles (``duration_s`` = its number of 1 s cycles: the settling, the play and the lead);
    the orbit truth and its cache as the ground reference's, where the session takes them."""
    from emulator.adcs_session import AdcsSession
    from ground.adcs import body_pointing as bps
    from emulator.spacecraft import scenario
    n = int(np.ceil(_t_settle(spec) + spec["adcs_duration_s"]))
    q.put(("info", {"settle_s": _t_settle(spec)}))
    link_faults = None
    if spec.get("link_faults"):
        from protocol.faults import LinkFaults
        link_faults = LinkFaults.parse(spec["link_faults"])
    d = _vehicle(spec)
    lb = scenario.laser_axis(d)
    s = AdcsSession(runtime=spec["runtime"], satb_gnss=spec["satb_gnss"], seed=spec["seed"], duration_s=float(n),
                    ts=spec["ts"], params=params, log=lambda m: q.put(("log", m)), truth=spec["truth"],
                    cache_dir=spec["cache_dir"], faults=spec.get("faults"), link_faults=link_faults, spacecraft=d,
                    world=spec.get("world", "thesis"), stkf_accel=spec.get("stkf_accel", "white"))
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


def _die_of(signum):
    """End this process by ``signum``'s default action (its parent reads "killed by SIGTERM", not a status)."""
    signal.signal(signum, signal.SIG_DFL)
    with contextlib.suppress(Exception):
        sys.stderr.flush()
    os.kill(os.getpid(), signum)
    os._exit(128 + signum)                            # not reached: the default action ends the process


def adcs_worker(spec, q, stop, stderr=None):
    """The ADCS process: messages ("info" | "cycle" | "adcs_summary" | "reference" | "error" | "end" | "alive",
    dict). It dies with its parent (``die_with_parent``: the kernel kills it, and the firmware it started, however
    the parent ends); its stderr goes to ``stderr`` (a ``_ChildFd``: the parent quotes its last lines when it
    fails). A SIGTERM (the parent's ``close``, or anyone's) unwinds it, so the session closes its firmware, and
    it then dies of that SIGTERM; it leaves without waiting to flush its queue."""
    die_with_parent()
    if stderr is not None:
        os.dup2(stderr.fd, 2)
        os.close(stderr.fd)
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # the parent takes Ctrl-C and stops this process
    busy = [True]
    termed = []

    def on_term(signum, frame):                       # unwind, so the session closes its firmware
        signal.signal(signal.SIGTERM, signal.SIG_DFL)    # a second one ends the process at once
        termed.append(signum)
        q.cancel_join_thread()                        # exit without flushing the queue
        if busy[0]:
            raise _Stopped
        _die_of(signum)                               # done: nothing to unwind
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
            said = str(exc) if isinstance(exc, (OSError, ValueError)) and str(exc) else "%s: %s" % (
                type(exc).__name__, exc)
            q.put(("error", said))
        if stop.is_set() or termed:
            q.cancel_join_thread()          # the parent stopped reading: do not wait on a full pipe at exit
        else:
            q.put(("end", {}))
    except _Stopped:
        pass
    finally:
        busy[0] = False
    if termed:
        _die_of(termed[0])


class AdcsFeed:
    """The parent's side of the ADCS process: ``take(until_t)`` collects messages until the ADCS has reached
    ``until_t`` (s of ADCS time); the 10 Hz samples go to ``on_samples(t, dtheta)`` (None: recorded only).
    ``close()`` ends the process within ``sum(STOP_S)`` s whatever its state."""

    def __init__(self, spec, on_samples):
        ctx = multiprocessing.get_context("spawn")
        self.q = ctx.Queue()
        self.stop = StopFlag(ctx)
        self.errlog = tempfile.TemporaryFile()        # the process's stderr (``stderr_tail``)
        self.stderr_text = ""                         # what it wrote there, kept by close()
        # not a daemon: the session may start processes of its own; close() always ends it
        self.proc = ctx.Process(target=adcs_worker, args=(spec, self.q, self.stop, _ChildFd(self.errlog.fileno())),
                                name="fps-system-adcs")
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
        self.on_wait = None         # called as often as take() looks for a message (keeps other links alive)

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
            raise AdcsFailed("the ADCS (%s) failed: %s" % (self.info.get("adcs", "process"), d))
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

    def stderr_tail(self, n_chars=2000):
        """The last ``n_chars`` the ADCS process wrote to stderr (kept after ``close``)."""
        if self.errlog.closed:
            return self.stderr_text[-n_chars:]
        fd = self.errlog.fileno()
        size = os.fstat(fd).st_size
        return os.pread(fd, n_chars, max(0, size - n_chars)).decode(errors="replace")

    def death(self):
        """"the ADCS process was killed by SIGTERM at t = 41.0 s of its time: <its last stderr lines>" (or
        "exited with status N", "before its first cycle", "... and wrote nothing on stderr")."""
        tail = last_lines(self.stderr_tail())
        when = "before its first cycle" if self.t_last < 0 else "at t = %.1f s of its time" % self.t_last
        return "the ADCS process %s %s%s" % (exit_status(self.proc.exitcode), when,
                                             (": " + tail) if tail else " and wrote nothing on stderr")

    def take(self, until_t=None, want=None, timeout_s=WAIT_S):
        """Messages until the ADCS time reaches ``until_t`` (or ``want()`` is true); ``AdcsFailed`` if it cannot:
        the process ended or died, sent nothing for ``SILENT_S`` (``START_S`` for its first message), or made no
        progress (a message other than its heartbeat) for ``timeout_s``."""
        t_wait0 = time.perf_counter()
        t_progress = t_wait0
        try:
            while not (until_t is not None and self.t_last >= until_t - 1e-9 or want is not None and want()):
                if self.ended:
                    raise AdcsFailed("the ADCS ended at t = %.1f s, before t = %s s" % (
                        self.t_last, "%.1f" % until_t if until_t is not None else "?"))
                if self.on_wait is not None:
                    self.on_wait()
                m = self._get(0.5)
                now = time.perf_counter()
                if m is None:
                    if not self.proc.is_alive() and self.q.empty():
                        raise AdcsFailed(self.death())
                    if self.t_heard is None and now - (self.t_started or t_wait0) > START_S:
                        raise AdcsFailed("the ADCS process sent nothing within %g s of its start" % START_S)
                    if self.t_heard is not None and now - self.t_heard > SILENT_S:
                        raise AdcsFailed("the ADCS process stopped answering: nothing from it for %g s (at t = "
                                         "%.1f s)" % (SILENT_S, self.t_last))
                    if now - t_progress > timeout_s:
                        raise AdcsFailed("no progress of the ADCS for %g s (at t = %.1f s)"
                                         % (timeout_s, self.t_last))
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
                self._keep_stderr()
        return bool(held)

    def _keep_stderr(self):
        """What the process wrote to stderr into ``stderr_text`` (its last lines also into the log), the file
        closed."""
        if self.errlog.closed:
            return
        with contextlib.suppress(OSError):
            self.stderr_text = self.stderr_tail(1 << 20)
        self.errlog.close()
        tail = last_lines(self.stderr_text)
        if tail:
            self.log.append("ADCS process stderr: %s" % tail)

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
