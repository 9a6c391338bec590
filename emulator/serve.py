"""The bench as a device on a link: ``fps emulator serve --link serial|can``.

Creates the device end of a link (a pseudo-terminal pair for serial, an slcan device on a pty for CAN),
prints the path the controller firmware should open, waits for its first packet (HELLO), and runs the
lockstep clock: each tick a TICK packet
carries the Q1 sample, the controller answers with FSM_SPI (``emulator.lockstep.RemoteController``). The
P-FSM holds fixed volts or plays a distfile (linear interpolation between its samples, Eq. 7.7-7.8).
At the end a summary (counters, true sky error statistics, packets received from the controller) is printed
and optionally written as JSON.
"""

import collections
import sys
from array import array

import numpy as np

from emulator.bench import Bench
from emulator.config import load_config, write_json_atomic
from emulator.lockstep import HoldPlayer, Lockstep, RemoteController
from protocol import core


class DistfilePlayer:
    """Plays a distfile's error angles into AD660 codes (into ``array("H")`` buffers) at ``pfsm_hz``: linear interpolation between samples,
    V = 0.012343 V/arcsec x theta_e (Eq. 7.8) through ``bench.pfsm_v_for_error``; holds the last sample at
    the end (``fill`` then returns fewer codes than asked)."""

    def __init__(self, dist, bench, pfsm_hz=10600.0):
        xs, ys = zip(*(dist.sample(i) for i in range(dist.count)))
        self.t = np.arange(dist.count) * (dist.period_us * 1e-6)
        self.vx = np.array([bench.pfsm_v_for_error(v) for v in xs])
        self.vy = np.array([bench.pfsm_v_for_error(v) for v in ys])
        self.pfsm_hz = pfsm_hz
        self.range_v = bench.pfsm.range_v
        self.i = 0
        self.n_total = int(self.t[-1] * pfsm_hz) + 1

    def _codes(self, v):
        return np.clip(np.round(v / self.range_v * 32768.0) + 0x8000, 0, 0xFFFF).astype(np.uint16)

    def fill(self, xbuf, ybuf, n):
        n = max(0, min(n, self.n_total - self.i))
        t = (self.i + np.arange(n)) / self.pfsm_hz
        xbuf[:n] = array("H", self._codes(np.interp(t, self.t, self.vx)).tobytes())
        ybuf[:n] = array("H", self._codes(np.interp(t, self.t, self.vy)).tobytes())
        self.i += n
        return n


def serve(args):
    """Run the bench on a link for ``args.duration`` virtual seconds (see emulator/cli.py for the options)."""
    from protocol.link import open_link
    bench = Bench(load_config(args.config), seed=args.seed)
    if args.distfile:
        from protocol import distfile
        with open(args.distfile, "rb") as f:
            player = DistfilePlayer(distfile.parse(f.read()), bench)
    else:
        player = HoldPlayer(*(bench.pfsm.v_to_code(v) for v in args.pfsm_v))
    link = open_link("pty" if args.link == "serial" else "slcan-pty", "BENCH")
    print(link.peer_path, flush=True)
    print("bench: waiting for the controller on %s (%s link)" % (link.peer_path, args.link),
          file=sys.stderr, flush=True)
    ctrl = RemoteController(link, timeout_s=args.deadline)
    lock = Lockstep(bench, ctrl, player, rate_hz=args.rate, deadline_s=args.deadline, realtime=args.realtime)
    try:
        if not ctrl.wait_peer(args.wait):
            raise OSError("no controller spoke on %s within %g s" % (link.peer_path, args.wait))
        res = lock.run(args.duration)
    finally:
        link.close()
    truth = res["truth_arcsec"]
    seen = collections.Counter(core.PACKET[p[0]].name if p[0] in core.PACKET else str(p[0]) for p in ctrl.inbox)
    summary = summarize(truth, lock.counters())
    summary.update({"link": args.link, "seed": args.seed, "duration_s": args.duration, "rate_hz": args.rate,
                    "packets_from_controller": dict(seen), "bench_config": bench.config})
    print("bench: %d ticks, %d overruns; true error mean (%.3f, %.3f) arcsec, 1 sigma (%.3f, %.3f), max |e| %.3f"
          % (summary["counters"]["ticks"], summary["counters"]["overruns"], *summary["mean_arcsec"],
             *summary["std_arcsec"], summary["max_abs_arcsec"]), file=sys.stderr)
    if args.output:
        write_json_atomic(args.output, summary)
    return 0


def summarize(truth_arcsec, counters):
    """Statistics of the true sky error at the Q2 instants, with the run's counters."""
    t = np.asarray(truth_arcsec, dtype=float).reshape(-1, 2)
    if len(t) == 0:
        return {"counters": counters, "samples": 0, "mean_arcsec": [0.0, 0.0], "std_arcsec": [0.0, 0.0],
                "max_abs_arcsec": 0.0, "last_arcsec": [0.0, 0.0]}
    return {"counters": counters, "samples": len(t), "mean_arcsec": t.mean(axis=0).tolist(),
            "std_arcsec": t.std(axis=0).tolist(), "max_abs_arcsec": float(np.hypot(t[:, 0], t[:, 1]).max()),
            "last_arcsec": t[-1].tolist()}
