"""Benchmark of the ground tools: real-time factor of a 600 s ``fps hil`` per runtime x link, and the wall
time of ``fps calibrate`` (121 points) in-process and over the MicroPython serial link.

Goals: >= 100x in-process under CPython; >= 12x for MicroPython over a serial pty, with no
decay between the first and the last minute of the run.
"""

import os
import shutil
import tempfile
import time

from bench import verdict
from ground import calibrate, distfile_cli, runtime, sources
from ground.fileio import write_atomic, write_json
from ground.hil import run_hil

COMBOS = (("inproc", "inproc", 100.0), ("cpython", "serial", None), ("micropython", "serial", 12.0),
          ("cpython", "can", None))      # the goal: real-time factor at least
DURATION_S = 600.0


def _goal(x):
    return "—" if x is None else "≥ %gx" % x


def _calibrate(rt, link, path):
    t0 = time.perf_counter()
    with runtime.open_rig(rt, link) as rig:
        cal, failed, _ = calibrate.run_calibration(rig, calibrate.sec74_grid(11), 0.01, log=lambda m: None)
    wall = time.perf_counter() - t0
    if path and not failed:
        write_json(path, cal)
    return wall, len(cal["points"]), len(failed)


def main(duration_s=DURATION_S):
    tmp = tempfile.mkdtemp(prefix="bench_hil_")
    try:
        _main(tmp, duration_s)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _main(tmp, duration_s):
    failed = []
    dist = os.path.join(tmp, "stat.dist")
    write_atomic(dist, distfile_cli.generate(sources.GaussMarkov2(), duration_s, 1, "stat"))
    cal_path = os.path.join(tmp, "cal.json")

    print("### fps calibrate (121 points, Sec. 7.4)\n")
    print("| runtime | link | goal | wall (s, incl. start-up) | points ok | failed |")
    print("|---|---|---|---|---|---|")
    for rt, link, goal, path in (("inproc", "inproc", "≤ 10 s", cal_path), ("micropython", "serial", "—", None)):
        try:
            wall, ok, bad = _calibrate(rt, link, path)
            if bad:
                failed.append("fps calibrate %s/%s (%d points failed)" % (rt, link, bad))
            print("| %s | %s | %s | %.2f | %d | %d |" % (rt, link, goal, wall, ok, bad), flush=True)
        except (OSError, ValueError) as exc:
            failed.append("fps calibrate %s/%s" % (rt, link))
            print("| %s | %s | %s | failed: %s | | |" % (rt, link, goal, exc), flush=True)

    print("\n### fps hil, %g s virtual (Sec. 7.5)\n" % duration_s)
    print("| runtime | link | goal | real-time factor | first minute | last minute | wall (s) | overruns |")
    print("|---|---|---|---|---|---|---|---|")
    for rt, link, goal in COMBOS:
        out = os.path.join(tmp, "hil_%s_%s" % (rt, link))
        try:
            s = run_hil(dist, cal_path, duration_s, rt, link, out, quiet=True, plots=False)
            print("| %s | %s | %s | %.1fx%s | %.1fx | %.1fx | %.1f | %d |"
                  % (rt, link, _goal(goal), s["real_time_factor"],
                     verdict(s["real_time_factor"], goal, at_most=False), s["real_time_factor_first_minute"],
                     s["real_time_factor_last_minute"], s["play_wall_s"], s["overruns"]), flush=True)
        except (OSError, ValueError, RuntimeError) as exc:
            failed.append("fps hil %s/%s" % (rt, link))
            print("| %s | %s | %s | failed: %s | | | | |" % (rt, link, _goal(goal), str(exc)[:120]), flush=True)
    if failed:      # the tables are printed; make bench must still say the benchmark failed
        raise RuntimeError("runs failed: %s" % ", ".join(failed))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
