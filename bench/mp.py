"""Run a script under the MicroPython unix port, optionally under ``valgrind --tool=callgrind`` for its x86-64
instruction count (deterministic, unlike its time on a shared machine), for the benchmarks."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")


def run(script, args=(), callgrind=False, heap=None, timeout=900, path=None):
    """stdout of ``micropython [-X heapsize=HEAP] script args`` (MICROPYPATH: the repo, or ``path``, and the
    frozen modules), or with ``callgrind`` the instructions it executed (int). RuntimeError with its stderr's
    tail if it fails."""
    env = dict(os.environ, MICROPYPATH=(path or ROOT) + ":.frozen")
    cmd = [MICROPYTHON] + (["-X", "heapsize=%s" % heap] if heap else []) + [script] + [str(a) for a in args]
    if callgrind:
        cmd = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null"] + cmd
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError("micropython %s failed: %s" % (os.path.basename(script), p.stderr[-500:]))
    if not callgrind:
        return p.stdout
    for line in p.stderr.splitlines():
        if "I   refs:" in line or "I refs:" in line:
            return int(line.split(":")[1].strip().replace(",", ""))
    raise RuntimeError("no instruction count in callgrind output")
