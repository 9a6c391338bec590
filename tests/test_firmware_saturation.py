"""Saturation is an event: the controller counts the ticks its integral law hits the clamp, enters SATURATED
after SAT_TICKS of them in a row, returns to TRACK when the command comes off the clamp, and reports it all in
CTRL_STATUS (n_sat, sat_run, sat_last, n_sat_episodes); in CPython and under MicroPython (bytecode and viper,
heap locked)."""

import os
import sys

import pytest

from firmware.controller import ACQUIRE, HOLD, SAT_TICKS, SATURATED, TRACK, Controller
from protocol import core, htable
from tests.mp import firmware_plant as fp
from tests.test_firmware_mp import ROOT, run_mp

sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
try:
    import firmware_saturation as fs
finally:
    sys.path.pop(0)

P = core.PACKET_ID
FAR, BACK, DARK = fs.FAR, fs.BACK, fs.DARK


@pytest.fixture(scope="module")
def grid():
    return htable.grid_from_calibration(fp.calibration())


def tracking(grid, **kw):
    c = Controller(table=grid, limit_code=fs.LIMIT_CODE, **kw)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    return c


def _settings(c, mode):
    return c.handle(P["CTRL_SETTINGS"], 1, 5, core.encode_payload("CTRL_SETTINGS", mode=mode))[0]


def _status(c):
    return core.payload_dict(P["CTRL_STATUS"], c.status_payload())


def test_threshold_is_64_ticks_the_default_status_decimation():
    assert SAT_TICKS == 64 == Controller().decim
    assert core.MODE["SATURATED"] == SATURATED == 5


def test_sustained_saturation_enters_saturated_counts_and_returns_to_track(grid):
    c = tracking(grid)
    run = n_sat = 0
    entered = None
    for k in range(150):                      # a far-off spot: the law walks onto the clamp and stays there
        c.step(*FAR)
        if c.flags & 2:
            run += 1
            n_sat += 1
        assert (c.sat_run, c.n_sat) == (run, n_sat)
        if entered is None and c.mode == SATURATED:
            entered = k
        assert c.mode == (SATURATED if run >= SAT_TICKS else TRACK)
    assert 0 < n_sat < 150 and entered is not None and c.n_sat_episodes == 1 and c.sat_last == 0
    assert abs(c.vx_q8) == abs(c.vy_q8) == fs.LIMIT_CODE << 8          # on the clamp, no windup past it
    st = _status(c)
    assert (st["mode"], st["flags"] & 2, st["n_sat"], st["sat_run"], st["sat_last"], st["n_sat_episodes"]) == (
        SATURATED, 2, n_sat, run, 0, 1)
    assert st["why"] == 0                     # why keeps its meaning (SAFE's reason): SATURATED is its own
    for _ in range(20):                       # the beam drops on the clamp: hold; the run goes on, uncounted
        c.step(*DARK)
    assert (c.mode, c.sat_run, c.n_sat) == (SATURATED, run + 20, n_sat)
    assert _settings(c, TRACK)[0] == P["ACK"] and c.mode == SATURATED    # TRACK asked: SATURATED is TRACK
    assert c.handle(P["CTRL_SETTINGS"], 1, 6, bytes([5]) + core.encode_payload("CTRL_SETTINGS")[1:])[0][2][2] \
        == core.ERROR["BAD_VALUE"]           # the ground cannot command SATURATED
    c.step(*FAR)
    x_clamp = c.vx_q8
    c.step(*BACK)                             # the error reverses: off the clamp, back to TRACK at once
    assert abs(c.vx_q8) < abs(x_clamp) and not c.flags & 2
    assert (c.mode, c.sat_run, c.sat_last, c.n_sat, c.n_sat_episodes) == (TRACK, 0, run + 21, n_sat + 1, 1)
    st = _status(c)
    assert (st["mode"], st["sat_run"], st["sat_last"]) == (TRACK, 0, run + 21)


def test_short_runs_count_but_are_no_episode_and_other_modes_end_a_run(grid):
    c = tracking(grid)
    for _ in range(200):
        c.step(*FAR)
    c.step(*BACK)
    ep, last = c.n_sat_episodes, c.sat_last
    n0 = c.n_sat
    for _ in range(SAT_TICKS - 1):            # back onto the clamp for less than the threshold
        c.step(*FAR)
        if c.sat_run:
            assert c.mode == TRACK
    c.step(*BACK)
    assert c.n_sat > n0 and (c.mode, c.sat_run, c.n_sat_episodes, c.sat_last) == (TRACK, 0, ep, last)
    for _ in range(100):
        c.step(*FAR)
    assert c.mode == SATURATED and c.n_sat_episodes == ep + 1
    run = c.sat_run
    assert _settings(c, HOLD)[0] == P["ACK"] and c.mode == HOLD
    c.step(*FAR)                              # HOLD: no law, the run ends there
    assert (c.mode, c.sat_run, c.sat_last) == (HOLD, 0, run)


def test_beam_loss_on_the_clamp_enters_acquire_and_the_beam_back_returns_to_the_law(grid):
    c = tracking(grid, acq_ticks=30, centre_ticks=100)
    for _ in range(100):
        c.step(*FAR)
    assert c.mode == SATURATED
    for _ in range(30):
        c.step(*DARK)
    assert (c.mode, c.why) == (ACQUIRE, 1)    # BEAM_LOST, as from TRACK
    run, clamped = c.sat_run, list(c.words)
    c.step(*DARK)                             # no law in ACQUIRE: the run ends; the command held on the clamp
    assert (c.mode, c.sat_run, c.sat_last, c.words) == (ACQUIRE, 0, run, clamped)
    for _ in range(68):                       # 99 lost in a row
        c.step(*DARK)
    assert c.words == clamped
    c.step(*DARK)                             # centre_ticks lost: the ramp takes the command off the clamp
    assert abs(c.vx_q8) < fs.LIMIT_CODE << 8 and c.mode == ACQUIRE and c.flags & 2 == 0
    ep = c.n_sat_episodes
    for _ in range(30):                       # the spot back but far off: TRACK, and the law onto the clamp again
        c.step(*FAR)
    assert c.mode == TRACK
    for _ in range(SAT_TICKS + 40):
        c.step(*FAR)
    assert c.mode == SATURATED and c.n_sat_episodes == ep + 1


def test_acquire_under_micropython_bytecode_and_viper_with_the_heap_locked():
    """The beam lost on the clamp, ACQUIRE's hold and ramp, a dropout in the beam's return and TRACK again,
    under micropython: the bytecode and viper controllers agree on every word and state slot with the heap locked
    and give CPython's modes, counters and CTRL_STATUS."""
    res = run_mp("firmware_saturation.py", "acquire")
    ref = fs.run(acquire=True)
    assert res["alloc_bytes"] == 0 and res["mismatch"] == 0
    assert res["crc"] == res["crc_viper"] == ref["crc"]
    assert res["modes"] == ref["modes"] and res["status"] == ref["status"] and res["counters"] == ref["counters"]
    modes = res["modes"]
    lost_at = 40 + 150                                    # the first DARK tick
    assert modes[lost_at - 1] == SATURATED and modes[lost_at + 62] == SATURATED
    assert set(modes[lost_at + 63:lost_at + 400 + 30 + 1 + 63]) == {ACQUIRE}   # the loss, the lit ticks debounced
    assert modes[lost_at + 400 + 30 + 1 + 63] == TRACK and modes[-1] == TRACK
    hold, ramped, end = res["status"]
    assert (hold["mode"], hold["why"], hold["sat_run"]) == (ACQUIRE, 1, 0) and hold["sat_last"] >= SAT_TICKS
    assert abs(hold["code_xp"] - 0x8000) == abs(hold["code_yp"] - 0x8000) == fs.LIMIT_CODE    # held on the clamp
    assert ramped["mode"] == ACQUIRE and ramped["vx"] == ramped["vy"] == 0 and ramped["flags"] & 1   # centred, lit
    assert end["mode"] == TRACK and end["n_lost"] == 401


def test_sat_ticks_acq_ticks_and_centre_ticks_are_checked():
    for name in ("sat_ticks", "acq_ticks", "centre_ticks"):
        for bad in (0, 65536, True):
            with pytest.raises(ValueError, match=name):
                Controller(**{name: bad})
        assert getattr(Controller(**{name: 10}), name) == 10


def test_saturation_under_micropython_bytecode_and_viper_with_the_heap_locked():
    """The same samples under micropython: the bytecode and viper controllers agree on every word and state
    slot, step with the heap locked (nothing allocated), and give CPython's modes, counters and CTRL_STATUS."""
    res = run_mp("firmware_saturation.py")
    ref = fs.run()
    assert res["alloc_bytes"] == 0 and res["mismatch"] == 0
    assert res["crc"] == res["crc_viper"] == ref["crc"]
    assert res["modes"] == ref["modes"] and res["status"] == ref["status"] and res["counters"] == ref["counters"]
    modes = res["modes"]
    assert SATURATED in modes and modes[-1] == TRACK
    first = modes.index(SATURATED)
    assert set(modes[first:first + modes.count(SATURATED)]) == {SATURATED}     # one episode, one block
    sat, back, end = res["status"]
    assert sat["mode"] == SATURATED and sat["sat_run"] >= SAT_TICKS and sat["n_sat_episodes"] == 1
    assert back["mode"] == TRACK and back["sat_run"] == 0 and back["sat_last"] > sat["sat_run"]
    assert end["n_sat"] > back["n_sat"] and end["n_sat_episodes"] == 1     # the second run was short
