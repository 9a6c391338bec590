"""Benchmark of the HIL over a bad link (issue 8): MicroPython controller over a serial pty, faults injected at the
transport (``--link-faults``). Figures: wall time and counters of a 120 s run with and without faults and whether
its samples and control telemetry are bit-identical; heavy faults (complete and identical, or a clear stop within
60 s wall); a 2 s silence and a permanent one; calibration under faults; real-time overruns of a board (MicroPython
``firmware.main`` on a relayed pty) at 637.8 Hz and 2 kHz.
"""

import contextlib
import io
import json
import os
import shutil
import subprocess
import tempfile
import time

import numpy as np

from emulator.bench import Bench
from emulator.truth import true_h_field
from ground import distfile_cli, sources
from ground.cli import main as _fps
from ground.fileio import write_atomic, write_json
from ground.runtime import ROOT, micropython_binary

DURATION_S = 120.0
LIGHT = "bytes=0.01,frames=0.05,seed=1"
HEAVY = "bytes=0.05,frames=0.20,seed=1"
CONTROL_COLS = 14


def fps(argv):
    """``fps`` in-process with its printout swallowed (the tables below say what matters)."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return _fps(argv)


def _hil(tmp, name, dist, cal, duration, *extra):
    out = os.path.join(tmp, name)
    t0 = time.perf_counter()
    rc = fps(["hil", "--distfile", dist, "--calibration", cal, "--duration", "%g" % duration, "--runtime",
              "micropython", "--no-plots", "--quiet", "-o", out] + list(extra))
    wall = time.perf_counter() - t0
    with open(os.path.join(out, "summary.json")) as f:
        return rc, wall, out, json.load(f)


def _identical(a, b):
    za, zb = np.load(os.path.join(a, "samples.npz")), np.load(os.path.join(b, "samples.npz"))
    same = all(np.array_equal(za[k], zb[k]) for k in za.files)
    ta = [",".join(line.split(",")[:CONTROL_COLS]) for line in open(os.path.join(a, "telemetry.csv"))]
    tb = [",".join(line.split(",")[:CONTROL_COLS]) for line in open(os.path.join(b, "telemetry.csv"))]
    return same and ta == tb


def _row(label, rc, wall, s, ident="—"):
    b = s["link"]["bench"]
    c = s["link"]["controller"] or {}
    return "| %s | %d | %s | %.1f | %s | %s | %s | %s | %s | %s |" % (
        label, rc, s["complete"], wall, b.get("controller_resent", 0), b.get("command_retries", 0),
        b.get("overruns", 0), c.get("resent_ticks_answered", "—"), c.get("rx_frames_dropped", "—"), ident)


def main(duration_s=DURATION_S):
    tmp = tempfile.mkdtemp(prefix="bench_faults_")
    try:
        _main(tmp, duration_s)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _main(tmp, duration_s):
    dist = os.path.join(tmp, "stat.dist")
    write_atomic(dist, distfile_cli.generate(sources.GaussMarkov2(), duration_s + 5, 1, "stat"))
    cal = os.path.join(tmp, "cal.json")
    write_json(cal, true_h_field(Bench(noise=False), None, 0.01))

    print("### fps hil, MicroPython over a serial pty, %g s virtual, faults on the link\n" % duration_s)
    print("| run | exit | complete | wall (s) | TICKs resent | command retries | overruns | controller: "
          "resends answered | controller: frames dropped | bit-identical to clean |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    failed = []
    rc, wall, clean, s = _hil(tmp, "clean", dist, cal, duration_s)
    print(_row("clean", rc, wall, s), flush=True)
    if rc != 0:
        failed.append("the clean run (exit %d): %s" % (rc, s["error"]))
    rc, wall, out, s = _hil(tmp, "light", dist, cal, duration_s, "--link-faults", LIGHT)
    print(_row("`%s` (goal: completes, identical)" % LIGHT, rc, wall, s, _identical(clean, out)), flush=True)
    rc, wall, out, s = _hil(tmp, "heavy", dist, cal, duration_s, "--link-faults", HEAVY)
    ident = _identical(clean, out) if s["complete"] else "stopped: %s" % (s["error"] or "")[:90]
    print(_row("`%s` (goal: identical, or a clear stop within 60 s)" % HEAVY, rc, wall, s, ident), flush=True)
    rc, wall, out, s = _hil(tmp, "silence", dist, cal, min(duration_s, 10.0), "--link-faults", "silence=3:2")
    print(_row("10 s with `silence=3:2` (goal: ridden through)", rc, wall, s, "held %d ticks" % s["overruns"]),
          flush=True)
    rc, wall, out, s = _hil(tmp, "dead", dist, cal, min(duration_s, 10.0), "--link-faults", "silence=3:inf")
    n = len(np.load(os.path.join(out, "samples.npz"))["t_s"])
    print(_row("10 s with `silence=3:inf` (goal: ends within the bound, valid folder)", rc, wall, s,
               "%d samples kept" % n), flush=True)

    print("\n### fps calibrate under faults (MicroPython, 5x5 grid)\n")
    print("| run | wall (s) | exit | same H table as clean |")
    print("|---|---|---|---|")
    hs = []
    for name, extra in (("clean", []), ("`%s`" % LIGHT, ["--link-faults", LIGHT])):
        out = os.path.join(tmp, "cal_%d.json" % len(hs))
        t0 = time.perf_counter()
        rc = fps(["calibrate", "--runtime", "micropython", "--grid", "5", "--no-plots", "--no-truth", "-o", out]
                 + extra)
        wall = time.perf_counter() - t0
        hs.append(json.load(open(out))["points"] if rc == 0 else None)
        print("| %s | %.1f | %d | %s |" % (name, wall, rc, "—" if len(hs) == 1 else
                                          (hs[0] is not None and hs[0] == hs[1])), flush=True)

    print("\n### A board in real time (MicroPython firmware.main on a relayed pty), 10 s\n")
    print("| loop rate | board timing | overruns | ticks | share | requirement met |")
    print("|---|---|---|---|---|---|")
    for rate in (637.8, 2000.0):
        ov, n, met, zl, rc, err = _board_realtime(tmp, dist, cal, rate)
        if rc not in (0, 3):        # the run did not complete: its counts are not the figure
            failed.append("the board at %g Hz (exit %d): %s" % (rate, rc, err))
            met = "failed (exit %d): %s" % (rc, (err or "")[:90])
        print("| %g Hz | %s | %d | %d | %.2f %% | %s |" % (rate, "zero-latency" if zl else "arduino-zero", ov, n,
                                                           100.0 * ov / max(n, 1), met), flush=True)
    if failed:      # the tables are printed; make bench must still say the benchmark failed
        raise RuntimeError("; ".join(failed))


def _board_realtime(tmp, dist, cal, rate, duration=10.0):
    from tests.ptyrelay import relay_pair
    with relay_pair() as (board_path, host_path):
        env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen")
        proc = subprocess.Popen([micropython_binary(), "-m", "firmware.main", "controller", "--link",
                                 "serial:" + board_path, "--rate", repr(rate)], cwd=ROOT, env=env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            out = os.path.join(tmp, "rt_%g" % rate)
            extra = []
            if rate * (3 * 426e-6 + 290e-6) > 1.001:    # the Arduino Zero's reads do not fit in the tick
                cfg = os.path.join(tmp, "zero_latency.json")
                write_json(cfg, {"board": {"timing": "zero-latency"}})
                extra = ["--config", cfg]
            rc = fps(["hil", "--distfile", dist, "--calibration", cal, "--duration", "%g" % duration,
                      "--runtime", "board", "--port", host_path, "--realtime", "--rate-hz", repr(rate), "--no-plots",
                      "--quiet", "-o", out] + extra)
            with open(os.path.join(out, "summary.json")) as f:
                s = json.load(f)
            return (s["overruns"], int(round(s["duration_s"] * rate)), s["requirement_met"], bool(extra), rc,
                    s["error"])
        finally:
            proc.terminate()
            proc.wait(5)


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
