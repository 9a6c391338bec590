"""The firmware against the emulated bench in lockstep: 10 s runs whose AD5664R word streams must be identical
with the controller in-process (CPython), as a CPython subprocess over a pty, as a MicroPython subprocess over
a pty, and as a CPython subprocess over CAN (slcan on a pty). Same seed, distfile and calibration each time."""

import math
import os
import subprocess
import sys

import pytest

from emulator import bench as bench_mod
from emulator import lockstep, truth
from firmware.controller import TRACK, Controller
from firmware.player import Player
from protocol import core, distfile, htable
from protocol import link as hostlink
from tests.test_firmware_mp import MICROPYTHON, ROOT

SECONDS = 10.0
SEED = 11


class Recorder:
    """Wraps a controller (in-process or RemoteController) and keeps every word it answers."""

    def __init__(self, inner):
        self.inner = inner
        self.words = []
        self.missed = 0

    def on_tick(self, tick, t_us, vx, vy, vs):
        w = self.inner.on_tick(tick, t_us, vx, vy, vs)
        if not w:
            self.missed += 1
        else:
            self.words.extend(w)
        return w

    def counters(self):
        return self.inner.counters() if hasattr(self.inner, "counters") else {}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("lockstep")
    grid = htable.grid_from_calibration(truth.true_h_field())
    blob = d / "htable.bin"
    blob.write_bytes(htable.pack(grid))
    n = int(SECONDS / 0.008192) + 2
    xs = [120.0 * math.sin(2 * math.pi * 0.2 * k * 0.008192) + 30.0 * math.sin(2 * math.pi * 3.1 * k * 0.008192)
          for k in range(n)]
    ys = [-90.0 * math.cos(2 * math.pi * 0.15 * k * 0.008192) for k in range(n)]
    dist = distfile.pack(xs, ys, source="test", seed=SEED)
    return {"blob": str(blob), "dist": dist}


def _run(setup, controller, seconds=SECONDS):
    player = Player(distfile.parse(setup["dist"]))
    player.oneshot()
    rec = Recorder(controller)
    ls = lockstep.Lockstep(bench_mod.Bench(seed=SEED), rec, player)
    res = ls.run(duration_s=seconds)
    return rec, res


def _in_process(setup):
    c = Controller(table=setup["blob"])
    c.mode = TRACK
    rec, res = _run(setup, c)
    return rec, res


def _remote(setup, argv, link, scheme="serial", seconds=SECONDS):
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    proc = subprocess.Popen(argv + ["-m", "firmware.main", "controller", "--link", scheme + ":" + link.peer_path,
                             "--table", setup["blob"], "--track"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        hello = []
        for _ in range(100):
            hello += [p for p in link.recv(timeout=0.2) if p[0] == core.PACKET_ID["HELLO"]]
            if hello or proc.poll() is not None:
                break
        assert hello, "the firmware never said HELLO: %s" % proc.stderr.read().decode()[-2000:]
        rc = lockstep.RemoteController(link, timeout_s=5.0)
        rec, res = _run(setup, rc, seconds)
        statuses = [p for p in rc.inbox if p[0] == core.PACKET_ID["CTRL_STATUS"]]
        return rec, res, statuses
    finally:
        link.close()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def reference(setup):
    rec, res = _in_process(setup)
    assert rec.missed == 0 and len(rec.words) == 4 * res["ticks"]
    err = res["truth_arcsec"]
    n = len(err)
    assert max(abs(v) for row in err[n // 10:] for v in row) < 11.98     # tracking within the requirement
    return rec.words


def test_in_process_tracks(reference):
    assert len(reference) == 4 * int(round(SECONDS * 637.8))


def _check_remote(reference, rec, statuses):
    assert rec.missed == 0
    assert len(rec.words) == len(reference)
    assert len(reference) > 1000
    first_diff = next((k for k in range(len(reference)) if rec.words[k] != reference[k]), None)
    assert first_diff is None, "streams differ from word %d" % first_diff
    assert len(statuses) >= len(reference) // 4 // 64 - 1      # telemetry at the default decimation


def test_cpython_subprocess_over_pty_bit_identical(setup, reference):
    link = hostlink.open_link("pty", "BENCH")
    rec, res, statuses = _remote(setup, [sys.executable], link)
    _check_remote(reference, rec, statuses)


def test_micropython_subprocess_over_pty_bit_identical(setup, reference):
    if not os.path.exists(MICROPYTHON):
        pytest.skip("micropython binary not installed")
    link = hostlink.open_link("pty", "BENCH")
    rec, res, statuses = _remote(setup, [MICROPYTHON], link)
    _check_remote(reference, rec, statuses)


def test_cpython_subprocess_over_slcan_bit_identical(setup, reference):
    """CAN: python-can's slcan adapter on a pty, ISO-TP for the multi-frame packets (about 18 s of wall time)."""
    link = hostlink.open_link("slcan-pty", "BENCH")
    rec, res, statuses = _remote(setup, [sys.executable], link, scheme="slcan")
    _check_remote(reference, rec, statuses)
