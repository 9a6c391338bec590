"""The fine loop's link availability: outages on the true error, merged across short returns, each with its
cause from the controller's telemetry; the time in lock and Q2's saturated samples."""

import numpy as np

from ground.availability import availability, cause, outages, q2_saturated
from ground.hil_report import availability_line
from protocol import core

REQ = 11.98
RATE = 637.8


def _status(tick, mode, sat=False, beam=True, why=0):
    return {"tick": tick, "mode": core.MODE[mode], "sat": sat, "beam": beam, "why": why}


def test_outages_are_runs_beyond_the_requirement_merged_across_short_returns():
    t = np.arange(0, 10, 1 / 630)
    r = np.ones_like(t)
    r[(t > 2) & (t < 2.5)] = 30               # one outage ...
    r[(t > 2.52) & (t < 2.53)] = 30           # ... and a relapse 20 ms later: the same outage
    r[(t > 6) & (t < 6.2)] = 13               # a second, 3.5 s later
    runs = outages(t, r, REQ)
    assert len(runs) == 2
    assert t[runs[0][0]] > 2 and t[runs[0][1] - 1] < 2.53 and t[runs[1][0]] > 6


def test_availability_counts_the_play_in_lock_and_names_each_outages_cause():
    t = np.arange(0, 10, 1 / 630)
    truth = np.zeros((len(t), 2))
    truth[:, 0] = 1.0
    truth[(t > 2) & (t < 3), 0] = 40.0        # the FSM on its clamp
    truth[t > 9, 1] = -50.0                   # SAFE, not re-acquired
    status = [_status(0, "TRACK"), _status(int(2.0 * RATE), "SATURATED", sat=True),
              _status(int(3.0 * RATE), "TRACK"), _status(int(8.99 * RATE), "SAFE", why=2)]
    av = availability(t, truth, REQ, status, lambda s: int(round(s * RATE)))
    assert abs(av["availability"] - 0.8) < 0.005
    assert av["n_outages"] == 2
    first, last = av["outages"]
    assert "clamp" in first["cause"] and first["ended"] and abs(first["length_s"] - 1.0) < 0.01
    assert "SAFE" in last["cause"] and not last["ended"]
    assert av["reacquisition_s"] == [first["length_s"]]
    assert av["in_lock"]["max_radial_arcsec"] == 1.0
    line = availability_line(dict(av, q2_saturated_samples=7), 50.0)
    assert "80.0" in line and "2 outages" in line and "not re-acquired" in line and "7 samples" in line


def test_the_cause_follows_the_last_status_at_or_before_the_outage():
    st = [_status(0, "TRACK"), _status(100, "TRACK", beam=False), _status(200, "HOLD")]
    assert cause(st, 50).startswith("disturbance")
    assert cause(st, 150) == "beam off Q1"
    assert cause(st, 250) == "controller in HOLD"
    assert cause([], 10) == "no telemetry yet"
    st.append(_status(300, "ACQUIRE", beam=False, why=1))     # BEAM_LOST
    assert cause(st, 350) == "beam off Q1: controller in ACQUIRE (BEAM_LOST), TRACK again once the beam is back"


def test_q2_samples_on_the_adcs_rails_are_counted_and_empty_input_is_none():
    q2 = np.array([[0, 0, 5, 5, 100], [1, 1, 0x7FFFFF, 5, 100], [2, 2, 5, -0x800000, 100]])
    assert q2_saturated(q2) == 2
    assert q2_saturated(np.zeros((0, 5))) == 0
    assert availability([], np.zeros((0, 2)), REQ)["availability"] is None
