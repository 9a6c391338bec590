"""The pure protocol modules (core, can, isotp, stream) give identical results under MicroPython."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")
SCRIPT = os.path.join(ROOT, "tests", "mp", "protocol_pure.py")


def run(exe):
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    r = subprocess.run([exe, SCRIPT], capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 0, r.stderr
    return r.stdout.splitlines()


def test_pure_modules_identical_under_micropython_and_cpython():
    mp = run(MICROPYTHON)
    cp = run(sys.executable)
    assert mp == cp
    assert len(mp) > 60
    assert all(line.split()[-1] == "True" for line in mp if line.split()[0] in ("cobs_rt", "can_rt"))
    assert mp[-1].startswith("isotp 300 ") and mp[-1].endswith(" 0")
