"""A planned slew's blind star tracker is named as planned (``StatusWatch``): the thesis world's DEGRADED in the slew
says "by plan", a blind tracker outside the slew or an injected ``startracker_blind`` stays a fault."""

from emulator.adcs_replies import PLANNED_BLIND, StatusWatch
from protocol import table

STALE = dict(table.ADCS_STALE)


def _status(mode, stale=(), wheels_failed=0):
    s = {"tick": 0, "adcs_mode": dict(table.ADCS_MODES)[mode], "cycle_us": 1000, "magnetic_failed": 0,
         "wheels_failed": wheels_failed, "att_sigma": 0.0, "stale": sum(1 << STALE[n] for n in stale)}
    s.update((n, 0.0) for n in ("q0", "q1", "q2", "q3", "wx", "wy", "wz", "rax", "ray", "raz", "rbx", "rby", "rbz"))
    return s


def _fly(blind_from, degraded_at, st_fault=None, stale=("STARTRACKER",)):
    """The mode changes and the lines said of a thesis-world run blind from ``blind_from`` s, DEGRADED at
    ``degraded_at`` s, back at ``degraded_at`` + 5 s (planned slew 30-162 s)."""
    said = []
    w = StatusWatch(said.append, [], slew=(30.0, 162.0), st_fault=st_fault)
    for t in range(0, degraded_at + 6):
        blind = blind_from <= t < degraded_at + 5
        mode = "DEGRADED" if degraded_at <= t < degraded_at + 5 else "POINT" if t >= 30 else "HOLD"
        w.take(_status(mode, stale if blind else ()), float(t), 0.0)
    return w.mode_changes, said


def test_the_slews_blind_tracker_is_planned_and_its_end_says_so():
    changes, said = _fly(31, 41)
    down = [c for c in changes if c["to"] == "DEGRADED"]
    assert [c["reason"] for c in down] == [PLANNED_BLIND] and "STARTRACKER" in PLANNED_BLIND
    assert changes[-1]["reason"] == "the star tracker is back after the planned slew"
    assert any("blind by plan" in s for s in said) and not any("(stale:" in s for s in said)


def test_a_blind_tracker_outside_the_plan_or_injected_or_with_another_sensor_is_a_fault():
    for kw in ({"blind_from": 200, "degraded_at": 210},                        # after the slew
               {"blind_from": 31, "degraded_at": 41, "st_fault": (35.0, 60.0)},  # injected over the stretch
               {"blind_from": 31, "degraded_at": 41, "stale": ("STARTRACKER", "BEACON")}):
        changes, said = _fly(**kw)
        down = [c for c in changes if c["to"] == "DEGRADED"]
        assert down and "blind by plan" not in down[0]["reason"] and "stale: STARTRACKER" in down[0]["reason"]
        assert any("(stale: STARTRACKER" in s for s in said)
