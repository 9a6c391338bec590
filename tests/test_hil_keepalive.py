"""The ground's own waits never read as a silent link: the controller under MicroPython on a serial pty counts the
wall time between TICKs as link silence (``firmware.hal.link.serve_controller``) and enters SAFE past its limit;
``Rig.keepalive`` while the ground waits keeps it in TRACK, so the run is the same however long the wait."""

import time

import pytest

from emulator.bench import Bench
from emulator.runtime import micropython_binary
from emulator.truth import true_h_field
from ground import runtime
from ground.hil import _check_tracking, mode_changes
from protocol import core, htable

SAFE_TICKS = 1900         # about 3 s of the controller's silence count (63 ticks per empty 100 ms poll): a loaded
                          # machine's own gaps between TICKs stay below it

pytestmark = pytest.mark.skipif(micropython_binary() is None, reason="needs the MicroPython unix port")


def _wait_run(keepalive, wait_s=6.0):
    """TRACK, 0.2 s of ticks, a wait of ``wait_s`` wall seconds with or without keep-alives, 0.2 s of ticks:
    the Q2 samples after the wait and the modes the controller reported."""
    cal = true_h_field(Bench(noise=False), None, 0.01)
    with runtime.open_rig("micropython", "serial", seed=4) as rig:
        rig.keepalive_s = 0.2
        rig.upload_htable(htable.pack_calibration(cal))
        rig.settings("TRACK", decim=16, safe_ticks=SAFE_TICKS)
        rig.run(128)
        t_end = time.perf_counter() + wait_s
        while time.perf_counter() < t_end:
            if keepalive:
                rig.keepalive()
            time.sleep(0.05)
        out = rig.run(128)
        rig.take_status()
        return out["q2"], rig


def test_a_wait_past_the_silence_limit_with_keepalives_gives_the_run_without_a_wait():
    q2_wait, rig = _wait_run(True)
    assert mode_changes(rig, 0) == []
    assert rig.last_status["mode"] == core.MODE["TRACK"]
    _check_tracking(rig)
    q2_none, _ = _wait_run(True, wait_s=0.0)
    assert (q2_wait == q2_none).all()


def test_without_keepalives_the_same_wait_ends_in_safe_and_is_reported_with_its_reason():
    _, rig = _wait_run(False)
    st = rig.last_status
    assert st["mode"] == core.MODE["SAFE"] and core.SAFE_REASON[st["why"]] == "LINK_SILENT"
    with pytest.raises(OSError, match=r"in SAFE \(LINK_SILENT\) at the play's start"):
        _check_tracking(rig)
    changes = mode_changes(rig, rig.lockstep.tick)       # before the play: t < 0, the reason named
    assert [(c["from"], c["to"], c["why"]) for c in changes] == [("TRACK", "SAFE", "LINK_SILENT")]
    assert changes[0]["t_s"] < 0
