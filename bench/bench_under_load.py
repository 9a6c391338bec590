"""Benchmark: the links keep lockstep on a loaded machine. Two busy loops run beside each run (load >= 6 on two
cores is the goal's condition; the load average is printed with each row): a clean 10 s CAN HIL (the CPython
controller over slcan) and a 60 s ``fps adcs can`` (the MicroPython flight software), five runs each, every run
complete and bit-identical to the first; then each with the first frame of its link dropped (``--link-faults
first=1``: a lost HELLO), which must complete too.
"""

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

from bench.bench_faults import _fps_timed, _hil, _identical
from emulator.bench import Bench
from emulator.truth import true_h_field
from ground import distfile_cli, sources
from ground.fileio import write_atomic, write_json

RUNS = 5
HIL_S, ADCS_S = 10.0, 60.0
BUSY = "while True: pass"


@contextlib.contextmanager
def busy_loops(n=2):
    """``n`` CPython processes spinning beside the runs (killed at the end however it ends)."""
    procs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(n)]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
            p.wait()


def _load():
    return os.getloadavg()[0]


def wait_for_load(target=6.0, limit_s=120.0):
    """Wait until the 1-minute load average reaches ``target`` (it lags the busy loops by about a minute), at
    most ``limit_s``; returns the load reached."""
    import time
    t_end = time.monotonic() + limit_s
    while _load() < target and time.monotonic() < t_end:
        time.sleep(2.0)
    return _load()


def main(runs=RUNS):
    tmp = tempfile.mkdtemp(prefix="bench_under_load_")
    try:
        with busy_loops():
            wait_for_load()
            _main(tmp, runs)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _same_history(a, b):
    za, zb = np.load(os.path.join(a, "history.npz")), np.load(os.path.join(b, "history.npz"))
    return za.files == zb.files and all(np.array_equal(za[k], zb[k], equal_nan=True) for k in za.files
                                        if k != "status_cycle_us")     # the cycle's own CPU time differs


def _main(tmp, runs):
    dist = os.path.join(tmp, "stat.dist")
    write_atomic(dist, distfile_cli.generate(sources.GaussMarkov2(), HIL_S + 5, 1, "stat"))
    cal = os.path.join(tmp, "cal.json")
    write_json(cal, true_h_field(Bench(noise=False), None, 0.01))
    print("### Under load: two busy loops beside each run; %d runs each, the first frame of each link dropped last\n"
          % runs)
    print("| run | load (1 min) | exit | complete | wall (s) | identical to the first (goal: 5 of 5 and the first=1 "
          "runs complete) |")
    print("|---|---|---|---|---|---|")
    ok = {"hil": 0, "adcs": 0}
    ref = None
    for k in range(runs + 1):
        extra = ["--link-faults", "first=1"] if k == runs else []
        rc, wall, out, s = _hil(tmp, "hil_%d" % k, dist, cal, HIL_S, "--link", "can", *extra, runtime="cpython")
        ref = ref or out
        same = _identical(ref, out) if s.get("complete") else "stopped: %s" % (s.get("error") or "")[:80]
        ok["hil"] += bool(k < runs and same is True)
        print("| CAN HIL %g s%s | %.1f | %d | %s | %.1f | %s |" % (HIL_S, ", first=1" if extra else " #%d" % (k + 1),
                                                                _load(), rc, s.get("complete"), wall, same),
              flush=True)
    ref = None
    for k in range(runs + 1):
        out = os.path.join(tmp, "adcs_%d" % k)
        rc, wall, s = _fps_timed(["adcs", "can", "--session", "%g" % ADCS_S, "--quiet", "--no-plots", "-o", out],
                                 "first=1" if k == runs else None)
        ref = ref or out
        same = _same_history(ref, out) if s.get("complete") else "stopped: %s" % (s.get("error") or "")[:80]
        ok["adcs"] += bool(k < runs and same is True)
        print("| fps adcs can %g s%s | %.1f | %d | %s | %.1f | %s |" % (
            ADCS_S, ", first=1" if k == runs else " #%d" % (k + 1), _load(), rc, s.get("complete"), wall, same),
            flush=True)
    print("\nidentical and complete: CAN HIL %d of %d, fps adcs can %d of %d (goal: %d of %d each)"
          % (ok["hil"], runs, ok["adcs"], runs, runs, runs))


if __name__ == "__main__":
    main()
