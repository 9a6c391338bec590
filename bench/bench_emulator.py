"""Bench emulator speed: real-time factor of a 600 s lockstep run (default arduino-zero board timing, and zero
latency) and the cost of a tick by part.

The run: 637.8 Hz control ticks, P-FSM at 10.6 kHz (a 2 Hz sine from a numpy player), Q2 at 630 Hz, and a
trivial in-process controller that holds the mirror at the centre null (the benchmark).
Parts, as the lockstep's loop runs them (``Bench.run_ticks``): the tick advance (mirror dynamics, the Q2
sample, the P-FSM input sums), the Q1 sample with the controller call, the SPI decode of new words (alone);
link (a TICK / FSM_SPI round trip in-process through the framing, and over a pty to another process).
"""

import os
import subprocess
import sys
import time

import numpy as np

from bench import verdict
from emulator.bench import Bench
from emulator.lockstep import Lockstep, RemoteController, SinePlayer
from emulator.mirrors import INIT_WORDS, fsm_words

RATE = 637.8
GOAL_RTF = 150.0

_PEER = r"""
import sys
from protocol import core
from protocol.stream import StreamLink
link = StreamLink(sys.argv[1], "CONTROLLER")
words = [int(w) for w in sys.argv[2].split(",")]
tick_id = core.PACKET_ID["TICK"]
link.send("HELLO", "BENCH", node=link.node)
while not link.closed:
    for pid, src, dst, seq, payload in link.recv(500):
        if pid == tick_id:
            tick = core.decode_payload(pid, payload)[0]
            link.send("FSM_SPI", src, tick=tick, n=4, w0=words[0], w1=words[1], w2=words[2], w3=words[3])
"""


class HoldMirror:
    """Trivial controller: the init sequence, then the same four words every tick."""

    def __init__(self, cfg):
        self.words = list(fsm_words(0.0375, -0.0026, cfg))

    def on_tick(self, tick, t_us, vx, vy, vs):
        return list(INIT_WORDS) if tick == 0 else self.words


def full_run(duration_s=600.0, timing=None, fused=True):
    """The 600 s run; adds ``cpu_s`` (process time: the one-core cost, unaffected by other loads). ``timing``:
    the board timing (None: the config's default, ``arduino-zero``; or ``zero-latency``); ``fused=False``: the
    tick one part per call (``emulator.bench_composed``)."""
    from emulator.config import default_config
    cfg = default_config()
    if timing is not None:
        cfg["board"]["timing"] = timing
    b = Bench(cfg, seed=1, fused=fused)
    c0 = time.process_time()
    res = Lockstep(b, HoldMirror(b.config), SinePlayer()).run(duration_s)
    res["cpu_s"] = time.process_time() - c0
    return res


def parts(blocks=80):
    """CPU microseconds per tick, as the lockstep runs them (``Bench.run_ticks`` over blocks of 256 ticks):
    the tick advance alone (P-FSM input sums, mirrors, Q2 at 630 Hz), the Q1 sample with a trivial controller
    call added, and the SPI decode of a new set of words (``spi_words`` called alone)."""
    b = Bench(seed=2)
    c = HoldMirror(b.config)
    b.spi_words(INIT_WORDS)
    words = [fsm_words(0.0375 + 1e-4 * (i % 7), -0.0026, b.config) for i in range(8)]
    counts = np.full(256, 17)
    codes = np.full(17 * 256, 0x8000, np.uint16)
    clock = time.process_time
    n = 256 * blocks
    t0 = clock()
    for i in range(n):
        b.spi_words(words[i & 7])
    t_spi = (clock() - t0) / n
    b.spi_words(c.words)
    rows = []
    t0 = clock()
    for _ in range(blocks):
        b.load_pfsm(codes, codes, counts)
        b.run_ticks(256, rows)
    t_adv = (clock() - t0) / n
    t0 = clock()
    for _ in range(blocks):
        b.load_pfsm(codes, codes, counts)
        b.run_ticks(256, rows, c.on_tick)
    t_q1 = (clock() - t0) / n - t_adv
    return {"advance": t_adv * 1e6, "sensing": t_q1 * 1e6, "spi": t_spi * 1e6}

def link_cost(ticks=3000):
    """Microseconds per tick added by a RemoteController: in-process framing, and a pty to a subprocess."""
    from protocol.link import inproc_pair, open_link
    import threading

    out = {}
    b = Bench(seed=3)
    c = HoldMirror(b.config)
    base = Lockstep(b, c).run(n_ticks=ticks)["wall_s"]
    # in-process pair, peer in a thread
    a, peer = inproc_pair("BENCH", "CONTROLLER")

    def answer():
        from protocol import core
        while not peer.closed:
            for pid, src, dst, seq, payload in peer.recv(timeout=0.2):
                if pid == core.PACKET_ID["TICK"]:
                    tick = core.decode_payload(pid, payload)[0]
                    peer.send("FSM_SPI", src, tick=tick, n=4, w0=c.words[0], w1=c.words[1], w2=c.words[2],
                              w3=c.words[3])

    th = threading.Thread(target=answer, daemon=True)
    th.start()
    b = Bench(seed=3)
    r = Lockstep(b, RemoteController(a, timeout_s=2.0)).run(n_ticks=ticks)
    a.close()
    out["inproc"] = ((r["wall_s"] - base) / ticks * 1e6, r["counters"]["overruns"])
    # pty, peer in another process
    link = open_link("pty", "BENCH")
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    proc = subprocess.Popen([sys.executable, "-c", _PEER, link.peer_path, ",".join(map(str, c.words))], env=env)
    try:
        b = Bench(seed=3)
        rc = RemoteController(link, timeout_s=2.0)
        rc.wait_peer(10.0)
        r = Lockstep(b, rc).run(n_ticks=ticks)
        out["pty"] = ((r["wall_s"] - base) / ticks * 1e6, r["counters"]["overruns"])
    finally:
        link.close()
        proc.kill()
        proc.wait()
    return out


def _fusing(runs):
    """What the fused loops pay: the same runs with the tick one part per call, the samples compared."""
    print()
    print("| tick written one part per call (Bench(fused=False)), the same run | arduino-zero timing | "
          "zero-latency timing |")
    print("|---|---|---|")
    rtf, same = [], []
    for t, res in runs.items():
        comp = full_run(timing=t, fused=False)
        rtf.append((600.0 / comp["cpu_s"], 600.0 / comp["cpu_s"] / (600.0 / res["cpu_s"]) - 1.0))
        same.append("yes" if all(np.array_equal(comp[k], res[k]) for k in ("q2", "truth_arcsec")) else "NO")
    print("| real-time factor, one core | %.0fx | %.0fx |" % (rtf[0][0], rtf[1][0]))
    print("| against the fused loops (the default) | %+.0f %% | %+.0f %% |" % (100 * rtf[0][1], 100 * rtf[1][1]))
    print("| Q2 samples and truth bit-identical to the fused loops | %s | %s |" % tuple(same))


def main():
    runs = {t: full_run(timing=t) for t in ("arduino-zero", "zero-latency")}
    res = runs["arduino-zero"]
    us_tick = res["cpu_s"] / res["ticks"] * 1e6
    print("| 600 s bench run (637.8 Hz ticks, 10.6 kHz P-FSM, Q2 630 Hz, hold controller) | goal | "
          "arduino-zero timing (default) | zero-latency timing |")
    print("|---|---|---|---|")
    print("| real-time factor, one core (CPU time) | >= %.0fx | %.0fx%s | %.0fx%s |"
          % (GOAL_RTF, 600.0 / res["cpu_s"], verdict(600.0 / res["cpu_s"], GOAL_RTF, at_most=False),
             600.0 / runs["zero-latency"]["cpu_s"], verdict(600.0 / runs["zero-latency"]["cpu_s"], GOAL_RTF,
                                                            at_most=False)))
    print("| real-time factor, wall clock (shared machine) | >= %.0fx | %.0fx | %.0fx |"
          % (GOAL_RTF, res["realtime_factor"], runs["zero-latency"]["realtime_factor"]))
    print("| wall time | <= %.1f s | %.2f s | %.2f s |" % (600.0 / GOAL_RTF, res["wall_s"],
                                                        runs["zero-latency"]["wall_s"]))
    print("| CPU cost per tick, total | <= %.1f us | %.2f us | %.2f us |"
          % (1e6 / RATE / GOAL_RTF, us_tick, runs["zero-latency"]["cpu_s"] / runs["zero-latency"]["ticks"] * 1e6))
    print("| ticks / Q2 samples / overruns | 382680 / 378000 / 0 | %d / %d / %d | %d / %d / %d |"
          % (res["ticks"], len(res["q2"]), res["counters"]["overruns"], runs["zero-latency"]["ticks"],
             len(runs["zero-latency"]["q2"]), runs["zero-latency"]["counters"]["overruns"]))
    _fusing(runs)
    p = parts()
    print()
    print("| CPU cost per tick by part (fused loop, blocks of 256 ticks) | ours (us) |")
    print("|---|---|")
    print("| tick advance (P-FSM input sums, mirrors, Q2 at 630 Hz) | %.2f |" % p["advance"])
    print("| Q1 sample and the controller call (same words: no decode) | %.2f |" % p["sensing"])
    print("| player and lockstep (rest of the total) | %.2f |"
          % max(0.0, us_tick - p["advance"] - p["sensing"]))
    print("| SPI decode of 4 new AD5664R words and MEMS input (alone; a tracking controller's cost) | %.2f |"
          % p["spi"])
    try:
        lc = link_cost()
    except ImportError:
        return
    print()
    print("| link cost per tick, wall (RemoteController round trip) | ours (us) | overruns |")
    print("|---|---|---|")
    print("| in-process pair (COBS + CRC framing, thread peer) | %.1f | %d |" % lc["inproc"])
    print("| pty to a CPython process (reference: 84 us median, 64-byte frame, 2 cores) | %.1f | %d |" % lc["pty"])


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
