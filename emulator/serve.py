"""Devices on a link: ``fps emulator serve --link serial|can [--devices bench|wheels]``.

Creates the device end of a link (a pseudo-terminal pair for serial, an slcan device on a pty for CAN),
prints the path the controller firmware should open, says HELLO until the controller speaks (its HELLO: a
HELLO lost either way costs a retry), and runs the
lockstep clock: each tick a TICK packet
carries the Q1 sample, the controller answers with FSM_SPI (``emulator.lockstep.RemoteController``). The
P-FSM holds fixed volts or plays a distfile (the firmware player's 6-point kernel, Eq. 7.7-7.8).
At the end a summary (counters, true sky error statistics, packets received from the controller) is printed
and optionally written as JSON, ``"complete": true``; when Ctrl-C, SIGTERM or a failed link ends the run early,
the JSON still holds what ran, with ``"complete": false`` and the ``error``.

``--devices wheels`` serves the spacecraft instead (``serve_wheels``): RW0..RW3 and the star tracker of
``emulator.spacecraft``, paced by the wall clock.
"""

import collections
import signal
import sys
import time
from array import array

import numpy as np

from emulator.bench import Bench
from emulator.config import load_config
from emulator.fileio import write_json
from emulator.lockstep import HoldPlayer, Lockstep, RemoteController
from emulator.runtime import sigterm_as_interrupt
from protocol import core, distfile


class DistfilePlayer:
    """The disturbance player's codes computed with numpy: the same integer arithmetic as
    ``firmware.player.Player`` played once (ONESHOT) at ``pfsm_hz`` (Keys's 6-point kernel over the distfile's
    Q2 codes, Eq. 7.7-7.8; see firmware/player.py), whole blocks at a time; tests/test_player_kernel.py checks
    the two give the same codes. Holds the last sample at the end (``fill`` then returns fewer codes than
    asked)."""

    def __init__(self, dist, pfsm_hz=10600.0):
        from firmware.player import Player
        rate = int(round(pfsm_hz))
        if abs(rate - pfsm_hz) > 1e-9:
            raise ValueError("the player runs at a whole number of Hz, got %r" % pfsm_hz)
        p = Player(rate_hz=rate)
        p.set_rate(rate, dist.period_us)
        self._inc, self._cell, self._s, self._div = p._inc, p._cell, p._shift, p._div
        n = dist.count
        q = self._q2(dist, n)
        w = q[np.clip(np.arange(n - 1)[:, None] + np.arange(-2, 4), 0, n - 1)]     # segments x 6 x 2
        a, b, q0, d, e, g = (w[:, j] for j in range(6))
        self.c3 = (a - 7 * b + 16 * q0 - 16 * d + 7 * e - g + 6) // 12
        self.d2 = (((-2 * a + 15 * b - 28 * q0 + 20 * d - 6 * e + g + 6) // 12) << 10) + 512
        self.d1 = (((a - 8 * b + 8 * d - e + 6) // 12) << 10) + 512
        self.d0 = ((q0 + 2) << 10) + 512
        self.hold = (q[-1] + 2) >> 2
        self.pfsm_hz = pfsm_hz
        self.i = 0
        self.n_play = -(-(n - 1) * self._cell // self._inc)        # outputs before the one-shot's end
        self.n_total = self.n_play + 1

    @staticmethod
    def _q2(dist, n):
        """The samples' Q2 codes (n x 2): ``ad660.arcsec_to_code_q2`` in numpy (the same double operations),
        and ``ad660.Q2Converter`` (the firmware's exact integers) for the values within 1e-6 of a rounding tie,
        where the two could differ."""
        from firmware import ad660
        raw = np.frombuffer(dist.raw, "<f4" if dist.kind == distfile.KIND_FLOAT32 else "<i4", 2 * n,
                            distfile.HEADER_SIZE).reshape(n, 2).astype(float)
        x = raw if dist.kind == distfile.KIND_FLOAT32 else raw * dist.scale
        c = (ad660.ZERO_CODE + x * (ad660.V_PER_ARCSEC * ad660.CODES_PER_VOLT)) * 4.0
        top = ad660.CODE_MAX * 4
        q = np.where(c <= 0.0, 0.0, np.where(c >= top, top, np.floor(c + 0.5))).astype(np.int64)
        tie = np.argwhere((np.abs(c - np.floor(c) - 0.5) < 1e-6) & (c > 0.0) & (c < top))
        if len(tie):
            cv = ad660.Q2Converter(dist.kind, dist.scale)
            for i, ax in tie.tolist():
                q[i, ax] = cv.code(dist.raw, dist.sample_offset(i) + 4 * ax)
        return q

    def codes(self, k):
        """Codes (len(k) x 2, int64) of outputs k (k < n_play)."""
        seg, ph = np.divmod(np.asarray(k, np.int64) * self._inc, self._cell)
        div = self._div
        f = ((((ph >> self._s) << 10) + (div >> 1)) // div)[:, None]
        h = (self.c3[seg] * f + self.d2[seg]) >> 10
        h = (h * f + self.d1[seg]) >> 10
        return np.clip((h * f + self.d0[seg]) >> 12, 0, 0xFFFF)

    def fill(self, xbuf, ybuf, n):
        n = max(0, min(n, self.n_total - self.i))
        k = self.i + np.arange(n)
        out = np.empty((n, 2), np.int64)
        play = k < self.n_play
        out[play] = self.codes(k[play])
        out[~play] = self.hold
        xbuf[:n] = array("H", out[:, 0].astype(np.uint16).tobytes())
        ybuf[:n] = array("H", out[:, 1].astype(np.uint16).tobytes())
        self.i += n
        return n


BENCH_DURATION_S = 10.0  # a bench serve run without --duration (virtual s)


def serve(args):
    """Run the bench on a link for ``args.duration`` virtual seconds (see emulator/cli.py for the options)."""
    from protocol.link import open_link
    duration = BENCH_DURATION_S if args.duration is None else args.duration
    bench = Bench(load_config(args.config), seed=args.seed)
    if args.distfile:
        with open(args.distfile, "rb") as f:
            player = DistfilePlayer(distfile.parse(f.read()))
    else:
        player = HoldPlayer(*(bench.pfsm.v_to_code(v) for v in args.pfsm_v))
    # the clock first: a rate the board or the P-FSM cannot run is refused before a path is printed
    lock = Lockstep(bench, None, player, rate_hz=args.rate, deadline_s=args.deadline, realtime=args.realtime)
    link = open_link("pty" if args.link == "serial" else "slcan-pty", "BENCH")
    print(link.peer_path, flush=True)
    print("bench: waiting for the controller on %s (%s link)" % (link.peer_path, args.link),
          file=sys.stderr, flush=True)
    ctrl = lock.controller = RemoteController(link, timeout_s=args.deadline, max_failed_ticks=args.max_failed_ticks)
    try:
        if not ctrl.wait_peer(args.wait):
            raise OSError("no controller spoke on %s within %g s" % (link.peer_path, args.wait))
        try:
            with sigterm_as_interrupt():
                res = lock.run(duration)
        except (KeyboardInterrupt, OSError) as exc:      # Ctrl-C or SIGTERM, the link failed: keep what ran
            if args.output and lock.partial is not None:
                summary = _bench_summary(args, bench, ctrl, lock, lock.partial, duration)
                summary.update({"complete": False, "error": "interrupted" if isinstance(exc, KeyboardInterrupt)
                                else str(exc)})
                write_json(args.output, summary, make_folder=False)
                print("bench: stopped after %d ticks; partial summary in %s" % (lock.tick, args.output),
                      file=sys.stderr)
            raise
    finally:
        link.close()
    summary = _bench_summary(args, bench, ctrl, lock, res, duration)
    summary["complete"] = True
    print("bench: %d ticks, %d overruns; true error mean (%.3f, %.3f) arcsec, 1 sigma (%.3f, %.3f), max |e| %.3f"
          % (summary["counters"]["ticks"], summary["counters"]["overruns"], *summary["mean_arcsec"],
             *summary["std_arcsec"], summary["max_abs_arcsec"]), file=sys.stderr)
    if args.output:
        write_json(args.output, summary, make_folder=False)
    return 0


def _bench_summary(args, bench, ctrl, lock, res, duration):
    seen = collections.Counter(core.PACKET[p[0]].name if p[0] in core.PACKET else str(p[0]) for p in ctrl.inbox)
    summary = summarize(res["truth_arcsec"], lock.counters())
    summary.update({"link": args.link, "seed": args.seed, "duration_s": duration, "rate_hz": args.rate,
                    "packets_from_controller": dict(seen), "hello_tries": ctrl.hello_tries,
                    "bench_config": bench.config})
    return summary


def summarize(truth_arcsec, counters):
    """Statistics of the true sky error at the Q2 instants, with the run's counters."""
    t = np.asarray(truth_arcsec, dtype=float).reshape(-1, 2)
    if len(t) == 0:
        return {"counters": counters, "samples": 0, "mean_arcsec": [0.0, 0.0], "std_arcsec": [0.0, 0.0],
                "max_abs_arcsec": 0.0, "last_arcsec": [0.0, 0.0]}
    return {"counters": counters, "samples": len(t), "mean_arcsec": t.mean(axis=0).tolist(),
            "std_arcsec": t.std(axis=0).tolist(), "max_abs_arcsec": float(np.hypot(t[:, 0], t[:, 1]).max()),
            "last_arcsec": t[-1].tolist()}


# --- the spacecraft: reaction wheels and star tracker -----------------------------------------------------
class _StopSignals:
    """SIGTERM and SIGINT set ``.name`` instead of killing the process, so the serve loop ends cleanly
    (the loop waits at most one physics step between checks); the old handlers come back on exit."""

    def __init__(self):
        self.name = None
        self._old = {}

    def _handler(self, signum, frame):
        self.name = signal.Signals(signum).name

    def __enter__(self):
        for s in (signal.SIGTERM, signal.SIGINT):
            self._old[s] = signal.signal(s, self._handler)
        return self

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)


def _name(pid):
    return core.PACKET[pid].name if pid in core.PACKET else "0x%02x" % pid


def serve_wheels(args):
    """Serve RW0..RW3 and the star tracker on a link, the physics paced by the wall clock.

    The clock starts when the flight computer speaks first (any packet, e.g. HELLO or an RW_CMD; until then
    nothing is sent, so nothing stale piles up in the pty). Then every ``args.dt`` of wall time the spacecraft
    takes one RK4 step (Eq. 4.10, 4.16) with the motor torques held; a step that starts more than one step
    late is counted in ``late_steps`` (the physics catches up, virtual time stays on the wall clock). RW_CMD
    to RW<i> is answered at once with RW_TLM or a NACK (``SpacecraftDevices.handle``); STARTRACKER goes to
    ADCS at virtual times 0, 1/hz, 2/hz, ... Ends after ``args.duration`` s (None: never), on SIGTERM or
    Ctrl-C, or when the peer leaves; then prints the counters (and writes them as JSON with ``-o``).
    """
    from emulator.spacecraft import Spacecraft, SpacecraftDevices, WheelParams, Wheels
    from emulator.spacecraft.devices import NACK, RW_NODES
    from emulator.spacecraft.wheels import RPM
    from protocol.link import open_link
    _check_wheel_args(args)
    sc = Spacecraft(wheels=Wheels(WheelParams(), rng=np.random.default_rng(args.seed)), dt=args.dt)
    dev = SpacecraftDevices(sc)
    # on CAN the link also takes what is addressed to the wheels and the star tracker's ISO-TP flow control
    link = open_link("pty" if args.link == "serial" else "slcan-pty", "SPACECRAFT",
                     accept=RW_NODES + (core.NODE["STARTRACKER"],))
    print(link.peer_path, flush=True)
    print("wheels: RW0..RW3 and STARTRACKER waiting for the flight computer on %s (%s link)"
          % (link.peer_path, args.link), file=sys.stderr, flush=True)
    rx, tx, nacks = collections.Counter(), collections.Counter(), collections.Counter()
    error_name = {code: name for name, code in core.ERROR.items()}

    def answer(packets):
        for pid, src, dst, seq, payload in packets:
            rx[_name(pid)] += 1
            for reply in dev.handle(pid, src, dst, payload, seq):
                if reply[0] == NACK:
                    nacks[error_name.get(core.payload_dict(NACK, reply[3])["code"], "?")] += 1
                link.send_raw(*reply)
                tx[_name(reply[0])] += 1

    clock = time.monotonic
    late = tx_timeouts = 0
    st_period, st_next = 1.0 / args.startracker_hz, 0.0
    with _StopSignals() as stop:
        try:
            first = _first_words(link, stop, args.wait)
            t0 = clock()
            answer(first)
            while True:
                if stop.name is not None or link.closed:
                    stopped_by = stop.name or "peer_left"
                    break
                if sc.t + 1e-9 >= st_next:
                    st_next += st_period
                    try:
                        link.send_raw(*dev.startracker())
                        tx["STARTRACKER"] += 1
                    except TimeoutError:          # CAN: the ISO-TP receiver gave no flow control
                        tx_timeouts += 1
                if args.duration is not None and sc.t + 1e-9 >= args.duration:
                    stopped_by = "duration"
                    break
                due = t0 + (sc.steps + 1) * sc.dt
                now = clock()
                if now >= due:
                    if now - due > sc.dt:
                        late += 1
                    sc.step()
                    continue
                answer(link.recv(timeout=due - now))
            wall = clock() - t0
        finally:
            link_counters = link.counters()
            link.close()
    summary = dict(devices="wheels", link=args.link, seed=args.seed, dt=sc.dt, stopped_by=stopped_by, virtual_s=sc.t,
                   wall_s=wall, steps=sc.steps, late_steps=late, tx_timeouts=tx_timeouts, packets_rx=dict(rx),
                   packets_tx=dict(tx), nacks=dict(nacks), link_counters=link_counters, clips=sc.wheels.counters(),
                   omega_rw_rpm=(sc.omega_rw / RPM).tolist())
    _say_wheels(summary)
    if args.output:
        write_json(args.output, summary, make_folder=False)
    return 0


def _check_wheel_args(args):
    """ValueError naming a bad ``--duration`` or ``--startracker-hz``."""
    if args.duration is not None and not args.duration > 0:
        raise ValueError("--duration must be > 0 s, got %r" % args.duration)
    if not (args.startracker_hz > 0 and np.isfinite(args.startracker_hz)):
        raise ValueError("--startracker-hz must be > 0, got %r" % args.startracker_hz)


def _first_words(link, stop, wait_s):
    """The first packets the flight computer sends (it speaks first), waited for up to ``wait_s`` s; OSError when
    none came (an empty list when stopped or the peer left meanwhile)."""
    clock = time.monotonic
    t_wait = clock() + wait_s
    first = []
    while not first and stop.name is None and not link.closed and clock() < t_wait:
        first = link.recv(timeout=min(0.1, max(0.0, t_wait - clock())))
    if not first and stop.name is None and not link.closed:
        raise OSError("no flight computer spoke on %s within %g s" % (link.peer_path, wait_s))
    return first


def _say_wheels(s):
    """The wheel node's last line on stderr: why it stopped, its steps, packets, NACKs, link drops and clips."""
    drops = {k: v for k, v in s["link_counters"].items() if v and k not in ("frames", "tx_frames")}
    print("wheels: stopped by %s after %.2f s (%d steps, %d late); packets in %s, out %s; NACKs %s; "
          "link drops %s; clips torque %s speed %s"
          % (s["stopped_by"], s["virtual_s"], s["steps"], s["late_steps"], s["packets_rx"], s["packets_tx"],
             s["nacks"], drops, s["clips"]["torque_clip"], s["clips"]["speed_clip"]), file=sys.stderr, flush=True)
