"""The host records each sustained FSM saturation: ``hil.saturation_summary`` on CTRL_STATUS telemetry
(synthetic, from the controller itself) and an ``fps hil`` run whose disturbance passes the mirror's range
(summary.json ``saturation``, the mode changes, report.md, the verdict line, telemetry.csv)."""

import json

import numpy as np
import pytest

from emulator.bench import Bench
from emulator.truth import true_h_field
from firmware.controller import SAT_TICKS, TRACK, Controller
from ground import report
from ground.cli import main as fps
from ground.fileio import write_json
from ground.hil import saturation_summary, verdict_lines
from ground.rig import decode_status
from protocol import distfile, htable
from tests.mp import firmware_plant as fp
from tests.test_firmware_saturation import fs

RATE = 637.8


def _telemetry(script, decim=64):
    """Run a controller through ``script`` ((sample, n), ...) at bench ticks 0, 1, ...; CTRL_STATUS on the
    ticks k % decim == 0, decoded as the rig decodes it. Returns (statuses, per-tick sat_run)."""
    c = Controller(table=htable.grid_from_calibration(fp.calibration()), limit_code=fs.LIMIT_CODE)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    out, runs = [], []
    k = 0
    for smp, n in script:
        for _ in range(n):
            c.step(*smp)
            runs.append(c.sat_run)
            if k % decim == 0:
                out.append(decode_status(c.status_payload(k)))
            k += 1
    return out, runs


def _runs(runs):
    """(start, length) of each run of ticks on the clamp, from the per-tick sat_run."""
    out = []
    for k, r in enumerate(runs):
        if r == 1:
            out.append([k, 1])
        elif r:
            out[-1][1] = r
    return [tuple(x) for x in out]


def test_an_episode_from_controller_telemetry_exact_start_length_and_command():
    status, runs = _telemetry(fs.SCRIPT)
    (start, length), short = _runs(runs)           # one sustained run (a beam dropout inside), one short
    assert length >= SAT_TICKS > short[1]
    s = saturation_summary(status, RATE, tick0=0)
    assert s["ticks"] == status[-1]["n_sat"] > 0 and s["seconds"] == round(s["ticks"] / RATE, 4)
    assert s["threshold_ticks"] == SAT_TICKS and s["episodes_unseen"] == 0
    [e] = s["episodes"]
    assert (e["start_tick"], e["ticks"], e["ended"]) == (start, length, True)
    assert e["start_s"] == round(start / RATE, 4) and e["seconds"] == round(length / RATE, 4)
    assert e["max_command_code"] == [fs.LIMIT_CODE, fs.LIMIT_CODE]   # on the clamp, signed (AD5664R codes)
    json.dumps(s)                                                   # plain JSON types

    # still on the clamp at the last CTRL_STATUS: not ended, the length seen so far
    status2, runs2 = _telemetry(fs.SCRIPT[:4])
    [e] = saturation_summary(status2, RATE, tick0=0)["episodes"]
    assert e["ended"] is False and e["start_tick"] == start and e["ticks"] == status2[-1]["sat_run"]
    # counted from the status before the play; an episode over before tick0 is not the play's
    s3 = saturation_summary(status[4:], RATE, tick0=status[4]["tick"] - 10, before=status[3])
    assert s3["ticks"] == status[-1]["n_sat"] - status[3]["n_sat"] and s3["episodes"][0]["start_s"] < 0
    assert saturation_summary(status, RATE, tick0=start + length)["episodes"] == []
    assert saturation_summary([], RATE, tick0=0)["episodes"] == []


def test_an_episode_between_two_statuses_is_counted_unseen():
    status, _ = _telemetry(fs.SCRIPT, decim=1)
    sparse = [status[0], status[-1]]            # decim far above the threshold: the episode fell between
    s = saturation_summary(sparse, RATE, tick0=0)
    assert s["episodes"] == [] and s["episodes_unseen"] == 1 and s["ticks"] == status[-1]["n_sat"]
    assert "1 more began and ended between two CTRL_STATUS" in report.saturation_md(s)
    assert verdict_lines({"saturation": s}) == [
        "FSM SATURATED: 1 sustained episode (>= 64 ticks on the clamp), 1 of them between two CTRL_STATUS; "
        "%d ticks (%.2f s) on the clamp in all" % (s["ticks"], s["seconds"])]


def test_report_and_verdict_lines():
    status, _ = _telemetry(fs.SCRIPT)
    sat = saturation_summary(status, RATE, tick0=0)
    md = report.saturation_md(sat)
    e = sat["episodes"][0]
    assert md.startswith("## FSM saturation") and "| %.2f | %d |" % (e["start_s"], e["ticks"]) in md
    lines = verdict_lines({"saturation": sat, "mode_changes": [
        {"t_s": 0.2, "tick": 128, "from": "TRACK", "to": "SATURATED", "why": "x"},
        {"t_s": 0.5, "tick": 320, "from": "SATURATED", "to": "TRACK", "why": "y"},
        {"t_s": 0.6, "tick": 384, "from": "TRACK", "to": "SATURATED", "why": "x"},
        {"t_s": 0.7, "tick": 448, "from": "SATURATED", "to": "ACQUIRE", "why": "BEAM_LOST"}]})
    assert lines[0].startswith("FSM SATURATED: 1 sustained episode (>= 64 ticks on the clamp), longest %d ticks"
                               % e["ticks"])
    assert lines[1:] == ["controller went from SATURATED to ACQUIRE at t = 0.70 s (BEAM_LOST)",
                         "beam lost: ACQUIRE 1 time, 0.00 s in all, longest 0.00 s from t = 0.70 s; TRACK again 0 "
                         "times, still in ACQUIRE at the end"]
    short = dict(sat, episodes=[])
    assert verdict_lines({"saturation": short}) == [
        "FSM command on its clamp for %d ticks (%.2f s) in all, never 64 in a row" % (sat["ticks"], sat["seconds"])]
    assert verdict_lines({"saturation": dict(short, ticks=0)}) == []
    assert "no CTRL_STATUS" in report.saturation_md(None)


def test_mode_changes_name_acquire_its_reason_and_the_return():
    """CTRL_STATUS's (mode, why) at each exit from TRACK into ACQUIRE and each return: summary.json's
    mode_changes and the verdict's lines name them."""
    from types import SimpleNamespace
    from ground.hil_report import mode_changes
    from protocol import core
    m = core.MODE
    rig = SimpleNamespace(rate_hz=RATE, mode_log=[
        (-64, m["HOLD"], 0), (-10, m["TRACK"], 0), (640, m["ACQUIRE"], 1), (1280, m["TRACK"], 1),
        (1920, m["ACQUIRE"], 1), (2560, m["SAFE"], 2)])
    ch = mode_changes(rig, tick0=0)
    assert [(c["from"], c["to"], c["why"]) for c in ch] == [
        ("TRACK", "ACQUIRE", "BEAM_LOST"), ("ACQUIRE", "TRACK", "beam back on Q1 for 64 ticks in a row"),
        ("TRACK", "ACQUIRE", "BEAM_LOST"), ("ACQUIRE", "SAFE", "LINK_SILENT")]
    assert verdict_lines({"mode_changes": ch, "duration_s": 5.0}) == [
        "controller left TRACK for ACQUIRE at t = 1.00 s (BEAM_LOST)",
        "controller went from ACQUIRE to TRACK at t = 2.01 s (beam back on Q1 for 64 ticks in a row)",
        "controller left TRACK for ACQUIRE at t = 3.01 s (BEAM_LOST)",
        "controller went from ACQUIRE to SAFE at t = 4.01 s (LINK_SILENT)",
        "beam lost: ACQUIRE 2 times, 2.01 s in all, longest 1.00 s from t = 1.00 s; TRACK again 1 time"]
    many = [dict(ch[k % 2], t_s=k) for k in range(30)]
    lines = verdict_lines({"mode_changes": many, "duration_s": 40.0})
    assert len(lines) == 14 and lines[12] == "and 18 more mode changes (summary.json's mode_changes)"
    assert lines[13].startswith("beam lost: ACQUIRE 15 times, 15.00 s in all") and lines[13].endswith(
        "TRACK again 15 times")


@pytest.fixture(scope="module")
def beyond_range(tmp_path_factory):
    """(distfile, calibration): the body error held at 760 arcsec on X for 1 s (the FSM's range ends near
    700), the emulator's true H field."""
    d = tmp_path_factory.mktemp("sat")
    cal = str(d / "cal.json")
    write_json(cal, true_h_field(Bench(noise=False), None, 0.01))
    period = distfile.DEFAULT_PERIOD_US
    t = np.arange(int(4.0 / (period * 1e-6))) * period * 1e-6
    x = np.interp(t, [0, 0.5, 1.0, 2.0, 2.5, 4.0], [0, 0, 760, 760, 0, 0])
    path = d / "beyond.dist"
    path.write_bytes(distfile.pack(x, np.zeros_like(x), period))
    return str(path), cal


@pytest.mark.parametrize("runtime", ["inproc", "micropython"])
def test_fps_hil_records_the_episode_in_summary_report_and_telemetry(tmp_path, capsys, beyond_range, runtime):
    dist, cal = beyond_range
    out = tmp_path / "run"
    rc = fps(["hil", "--distfile", dist, "--calibration", cal, "--duration", "3.5", "--runtime", runtime,
              "--no-plots", "--quiet", "-o", str(out)])
    assert rc == 3                                      # the requirement is missed while on the clamp
    s = json.loads((out / "summary.json").read_text())
    sat = s["saturation"]
    [e] = sat["episodes"]
    assert 0.5 < e["start_s"] < 1.0 and e["ended"] and 1.5 * RATE > e["ticks"] > 1.0 * RATE   # 1 s at 760″, ramps
    assert e["max_command_code"][0] == -32767           # X on the mirror's clamp (TILT_LIMIT_CODE)
    assert sat["ticks"] == e["ticks"] and sat["episodes_unseen"] == 0
    changes = [(m["from"], m["to"]) for m in s["mode_changes"]]
    assert changes == [("TRACK", "SATURATED"), ("SATURATED", "TRACK")]
    assert s["mode_changes"][0]["why"] == "FSM command on its clamp for 64 ticks in a row"
    assert 0 < s["mode_changes"][0]["t_s"] - e["start_s"] <= (SAT_TICKS + 64) / RATE
    md = (out / "report.md").read_text()
    assert "## FSM saturation" in md and "- FSM SATURATED: 1 sustained episode" in md
    assert "FSM SATURATED: 1 sustained episode" in capsys.readouterr().out
    rows = (out / "telemetry.csv").read_text().splitlines()
    head = rows[0].split(",")
    assert head[-3:] == ["sat_run", "sat_last", "n_sat_episodes"]
    assert max(int(r.split(",")[head.index("sat_run")]) for r in rows[1:]) >= SAT_TICKS
