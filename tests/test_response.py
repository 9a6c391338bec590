"""Board timing (emulator.timing) and the loop's frequency response (ground.response, ``fps response``)."""

import json

import numpy as np
import pytest

from emulator.bench import Bench
from emulator.config import default_config, validate
from emulator.lockstep import Lockstep, SinePlayer
from emulator.timing import board_timing
from ground import runtime
from ground.response import LoopModel, measure, truth_calibration
from protocol import htable


def _cfg(timing):
    cfg = default_config()
    cfg["board"]["timing"] = timing
    return cfg


def test_arduino_zero_timing_samples_in_read_order_and_lands_in_the_next_tick():
    tm = board_timing(default_config())
    assert tm.name == "arduino-zero"
    assert np.allclose(np.array(tm.sample_s) * 1e6, [351, 777, 1203])
    assert tm.land_s * 1e6 == pytest.approx(1568.0)
    d, f = tm.split(1 / 637.8)
    assert d == 1 and 0 <= f < 1e-6            # just inside the following tick
    with pytest.raises(ValueError, match="zero-latency"):
        tm.split(1 / 2000.0)                    # the reads do not fit a 500 us tick
    with pytest.raises(ValueError, match="board.timing"):
        validate({"board": {"timing": "fast"}})
    z = board_timing(_cfg("zero-latency"))
    assert z.zero and z.split(1 / 2000.0) == (0, 0.0)


def test_timed_lockstep_is_deterministic_and_a_missed_tick_still_lands_words_in_flight():
    from tests.test_emulator_lockstep import Integral
    runs = []
    for _ in range(2):
        b = Bench(seed=4)
        c = Integral(b.config, skip=range(50, 53))
        runs.append(Lockstep(b, c, SinePlayer(amp=2000, hz=20.0), record=True).run(n_ticks=300))
    assert np.array_equal(runs[0]["truth_arcsec"], runs[1]["truth_arcsec"])
    assert np.array_equal(runs[0]["q1"], runs[1]["q1"])
    assert runs[0]["counters"]["overruns"] == 3
    fsm = runs[0]["fsm_v"]
    assert not np.array_equal(fsm[50], fsm[49])    # tick 49's words land in tick 50 (one tick of latency)
    assert np.array_equal(fsm[51], fsm[50]) and np.array_equal(fsm[52], fsm[51])   # then the mirror holds


def test_timing_delays_the_loop_by_one_tick_against_zero_latency():
    """A step of the P-FSM: with the board's timing the first correction reaches the mirror a tick later."""
    from tests.test_emulator_lockstep import Integral
    first = {}
    for t in ("zero-latency", "arduino-zero"):
        b = Bench(_cfg(t), seed=1, noise=False)
        res = Lockstep(b, Integral(b.config), SinePlayer(amp=2000, hz=5.0), record=True).run(n_ticks=10)
        v = res["fsm_v"][:, 0]
        first[t] = int(np.argmax(np.abs(v) > 1e-9))
    assert first["arduino-zero"] == first["zero-latency"] + 1


@pytest.mark.parametrize("timing", ["arduino-zero", "zero-latency"])
def test_measured_sensitivity_matches_the_model_to_0_4_nyquist(timing):
    cfg = _cfg(timing)
    freqs = np.geomspace(1.0, 0.4 * 637.8 / 2, 8)
    with runtime.open_rig("inproc", "inproc", config=cfg, seed=2) as rig:
        rig.upload_htable(htable.pack_calibration(truth_calibration(cfg)))
        rig.pfsm_v(0.0, 0.0)
        rig.settings("TRACK", decim=0)
        rig.run(128)
        freqs, s = measure(rig, freqs, model=LoopModel(cfg))
    for ax in (0, 1):
        m = LoopModel(cfg, axis=ax).s_truth(freqs)
        err = np.abs(np.abs(s[:, ax]) / np.abs(m) - 1)
        assert np.all(err < 0.05), (ax, np.abs(s[:, ax]), np.abs(m))
        dphi = np.degrees(np.angle(s[:, ax] / m))
        assert np.all(np.abs(dphi) < 5.0), (ax, dphi)


def test_model_margins_and_bandwidth_at_the_default_gain():
    zl, az = LoopModel(_cfg("zero-latency")), LoopModel(default_config())
    for m in (zl, az):
        gm, pm = m.margins()
        assert gm > 6.0 and 30 < pm < 90          # the default g = 0.5 keeps a gain margin over 2
        assert 20 < m.bandwidth_hz() < 60
        assert m.stable(1.0) and not m.stable(10 ** ((gm + 0.5) / 20))
    # the 55 Hz figure: (z - 1)/(z - 1 + g) at the samples, 0.87 with zero latency
    assert abs(zl.s_samples(55.0)[0]) == pytest.approx(0.864, abs=0.01)
    assert abs(az.s_truth(55.0)[0]) > abs(zl.s_truth(55.0)[0])


def test_fps_response_cli_writes_the_summary_keys(tmp_path, capsys):
    from ground.cli import main
    rc = main(["response", "--points", "4", "--from", "2", "--to", "100", "--quiet", "--no-plots", "-o",
               str(tmp_path)])
    assert rc == 0
    s = json.load(open(tmp_path / "summary.json"))
    for k in ("freq_hz", "s_measured", "s_model", "phase_measured_deg", "phase_model_deg", "gain_margin_db",
              "phase_margin_deg", "bandwidth_hz"):
        assert k in s
    assert len(s["s_measured"]) == 4 and s["complete"]
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1].endswith(": summary.json, report.md")        # --no-plots: no figure
    assert main(["response", "--to", "400", "-o", str(tmp_path)]) == 2       # above the loop's Nyquist
