"""The pure protocol modules (core, can, isotp, stream) give identical results under MicroPython, and the
viper fast paths MicroPython selects (protocol.fast) give the pure reference's bytes, from source and .mpy."""

import json
import os
import subprocess
import sys

from protocol import core

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")
SCRIPT = os.path.join(ROOT, "tests", "mp", "protocol_pure.py")
FAST = os.path.join(ROOT, "tests", "mp", "protocol_fast.py")
GOLDEN = os.path.join(ROOT, "tests", "data", "golden_frames.txt")


def run(exe, script=SCRIPT, args=(), path=ROOT):
    env = dict(os.environ, MICROPYPATH=path + ":.frozen", PYTHONPATH=ROOT)
    r = subprocess.run([exe, script] + list(args), capture_output=True, text=True, timeout=60, env=env, cwd="/")
    assert r.returncode == 0, r.stderr
    return r.stdout.splitlines()


def test_pure_modules_identical_under_micropython_and_cpython():
    mp = run(MICROPYTHON)
    cp = run(sys.executable)
    assert mp == cp
    assert len(mp) > 60
    assert all(line.split()[-1] == "True" for line in mp if line.split()[0] in ("cobs_rt", "can_rt"))
    assert mp[-1].startswith("isotp 300 ") and mp[-1].endswith(" 0")


def check_fast(res, n):
    assert res["fast"] is True                       # MicroPython did select the viper path
    assert res["bad"] == dict.fromkeys(res["bad"], 0), res["bad"]
    assert len(res["bad"]) == 10
    assert res["cases"] == n
    golden = [ln for ln in open(GOLDEN) if ln.strip() and not ln.startswith("#")]
    assert res["golden"] == len(golden) == len(core.PACKET)
    assert res["stream_packets"] > 0 and res["drops"] > 0   # the stream had good and damaged frames


def test_viper_fast_paths_give_the_pure_bytes_under_micropython():
    check_fast(json.loads(run(MICROPYTHON, FAST, (GOLDEN, "3000"))[-1]), 3000)


def test_viper_fast_paths_load_from_mpy(tmp_path):
    from tools import mpy_build
    mpy_build.build(str(tmp_path))                   # default -march=host: the .mpy holds x64 viper code
    assert os.path.exists(os.path.join(str(tmp_path), "protocol", "fast.mpy"))
    check_fast(json.loads(run(MICROPYTHON, FAST, (GOLDEN, "300"), path=str(tmp_path))[-1]), 300)


def test_cpython_uses_the_pure_reference():
    assert core.FAST is False
    assert core.crc16 is core.crc16_pure and core.cobs_encode is core.cobs_encode_pure
    assert core.cobs_decode is core.cobs_decode_pure
