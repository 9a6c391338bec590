"""``fps system``'s failure paths end within a bound with an honest folder, and its one verdict for the terminal.

Each failure test provokes one failure in a short ``--adcs ground`` run, measures from that moment to the end of
the command (at most ``BOUND_S``), and reads summary.json (complete false, the reason, where it stopped).
Ctrl-C runs ``fps system`` in its own interpreter, so that its exit (multiprocessing's exit handler waiting on
the ADCS process) is part of what is timed. A body error beyond the P-FSM's range is not a failure: the run
goes on."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from ground import report, system
from ground.adcs import body_pointing as bps
from ground.cli import main as fps

BOUND_S = 30.0


def _args(out, system_inputs, duration, *extra):
    params, cal, cache = system_inputs
    return ["system", "--adcs", "ground", "--duration", str(duration), "--truth", "two-body", "--params", params,
            "--calibration", cal, "--bps-cache", cache, "--quiet", "--no-plots", "-o", str(out)] + list(extra)


def _summary(out):
    s = json.loads((out / "summary.json").read_text())
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]
    return s


def _when_playing(out, then, timeout_s=120.0):
    """A thread calling ``then()`` once summary.json says the play has begun (and 0.5 s more)."""
    def watch():
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError, ValueError):
                if json.loads((out / "summary.json").read_text()).get("phase") == "play":
                    time.sleep(0.5)
                    then()
                    return
            time.sleep(0.02)
    th = threading.Thread(target=watch, daemon=True)
    th.start()
    return th


def test_a_body_error_beyond_the_pfsm_is_held_at_its_edge_counted_and_the_run_goes_on(tmp_path, system_inputs,
                                                                                       monkeypatch):
    """From 5 s to 8 s into the play the body pointing error is 5000 arcsec, beyond the P-FSM's 810: the bench
    plays the range's edge, counts the samples and their window, the availability names the outage's cause,
    and the run completes with the budget missed (exit 3), not a workbench failure."""
    from ground.availability import UNPLAYABLE
    add = system.LiveDisturbance.add

    def beyond(self, t, dtheta):
        t = np.asarray(t, float)
        d = np.array(dtheta, float)
        d[(t >= self.t0 + 5.0) & (t < self.t0 + 8.0)] = 5000.0
        return add(self, t, d)
    monkeypatch.setattr(system.LiveDisturbance, "add", beyond)
    out = tmp_path / "run"
    assert fps(_args(out, system_inputs, 12)) == 3
    s = _summary(out)
    assert s["complete"] is True and s["verdict"]["met"] is False
    held = s["disturbance"]["beyond_pfsm_range"]
    assert held["samples"] > 0 and len(held["windows_s"]) == 1
    (a, b), = held["windows_s"]
    assert 4.8 < a < 5.2 and 7.8 < b < 8.3
    causes = [o["cause"] for o in s["availability"]["outages"]]
    assert UNPLAYABLE in causes
    assert s["availability"]["availability"] < 0.8
    assert "not playable" in (out / "report.md").read_text()

def test_the_controller_exiting_mid_run_ends_the_command(tmp_path, system_inputs, monkeypatch, capsys):
    from ground import runtime
    rigs = []
    open_rig = runtime.open_rig

    @contextlib.contextmanager
    def keep(*a, **kw):
        with open_rig(*a, **kw) as rig:
            rigs.append(rig)
            yield rig
    monkeypatch.setattr(runtime, "open_rig", keep)
    out = tmp_path / "run"
    provoked = []

    def kill():
        rigs[0].process.kill()
        provoked.append(time.monotonic())
    _when_playing(out, kill)
    rc = fps(_args(out, system_inputs, 120))
    t_end = time.monotonic()
    err = capsys.readouterr().err
    assert provoked and rc == 1, err
    assert t_end - provoked[0] < BOUND_S
    assert "Traceback" not in err and "fps system: error:" in err
    s = _summary(out)
    assert s["complete"] is False and s["stopped_in"] == "play" and s["phase"] == "failed"
    assert s["error"] and "controller" in s["error"]
    assert s["verdict"]["met"] is False and s["duration_s"] < 120


def test_an_adcs_process_that_stops_answering_ends_the_command(tmp_path, system_inputs, monkeypatch, capsys):
    """SIGSTOP the ADCS process at its first 10 Hz cycle (its pipe then holds less than the settling): the run
    fails after ``SILENT_S`` of silence and the process is ended."""
    feeds, provoked = [], []
    handle = system.AdcsFeed._handle

    def stop_it(self, kind, d, play=True):
        if kind == "cycle" and not provoked:
            os.kill(self.proc.pid, signal.SIGSTOP)
            feeds.append(self)
            provoked.append(time.monotonic())
        return handle(self, kind, d, play)
    monkeypatch.setattr(system.AdcsFeed, "_handle", stop_it)
    out = tmp_path / "run"
    try:
        rc = fps(_args(out, system_inputs, 60))
        t_end = time.monotonic()
        err = capsys.readouterr().err
        assert provoked and rc == 1, err
        assert t_end - provoked[0] < BOUND_S
        assert feeds[0].proc.exitcode is not None                # the stopped process was ended
        assert "stopped answering" in err and "Traceback" not in err
        s = _summary(out)
        assert s["complete"] is False and s["phase"] == "failed" and s["stopped_in"] == "adcs_settling"
        assert "stopped answering" in s["error"] and s["verdict"]["met"] is False
    finally:
        for f in feeds:
            if f.proc.exitcode is None:
                with contextlib.suppress(OSError):
                    os.kill(f.proc.pid, signal.SIGCONT)
                f.proc.kill()


def test_ctrl_c_ends_the_command_with_130(tmp_path, system_inputs):
    """Ctrl-C as a terminal sends it: SIGINT to the whole process group (the controller's process too)."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "ground.cli"] + _args(out, system_inputs, 120), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))   # as a terminal's job
    provoked = []
    try:
        _when_playing(out, lambda: (os.killpg(proc.pid, signal.SIGINT), provoked.append(time.monotonic())))
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    t_end = time.monotonic()
    assert provoked and proc.returncode == 130, err.decode()
    assert t_end - provoked[0] < BOUND_S
    assert b"partial run" in err and b"Traceback" not in err
    s = _summary(out)
    assert s["complete"] is False and s["interrupted"] is True and s["stopped_in"] == "play"
    assert s["phase"] == "interrupted" and s["requirement_met"] is False and s["verdict"]["met"] is False
    assert 0 < s["duration_s"] < 120


# --- the verdict ------------------------------------------------------------------------------------------------
def _synthetic(fine_worst=3.0, lost=0, pointing=120.0, stability=20.0, complete=True):
    return {"complete": complete, "q2_samples": 1000, "q2_beam_lost_samples": lost,
            "q2": {"max_radial_arcsec": fine_worst},
            "body_pointing": {"pointing_3sigma_arcsec": pointing, "stability_3sigma_arcsec_s": stability,
                              "samples": 6001}}


def test_verdict_names_the_loop_that_missed_and_by_how_much():
    v = system.verdict(_synthetic())
    assert v["met"] is True and v["missed"] == [] and system.exit_code({"verdict": v}) == 0
    assert v["fine"] == {"met": True, "worst_arcsec": 3.0, "budget_arcsec": report.REQUIREMENT_ARCSEC,
                         "over_arcsec": 0.0, "q2_samples": 1000, "beam_lost_samples": 0}
    # the wheel silent from 300 s: body 3 sigma 182 arcsec against 150, fine loop holding
    v = system.verdict(_synthetic(pointing=182.0))
    assert v["met"] is False and v["fine"]["met"] is True and v["body"]["met"] is False
    assert v["body"]["pointing_over_arcsec"] == pytest.approx(32.0) and v["body"]["stability_over_arcsec_s"] == 0
    assert v["body"]["pointing_budget_arcsec"] == bps.BUDGET_POINTING_3SIGMA == 150.0
    assert v["missed"] == ["body: 3σ pointing 182.0″ over the 150″ budget by 32.0″"]
    assert system.exit_code({"verdict": v}) == 3
    v = system.verdict(_synthetic(stability=40.0))
    assert v["missed"] == ["body: 3σ stability 40.0″/s over the 35″/s budget by 5.0″/s"]
    assert v["body"]["stability_budget_arcsec_s"] == bps.BUDGET_STABILITY_3SIGMA == 35.0
    v = system.verdict(_synthetic(fine_worst=13.0))
    assert v["fine"]["met"] is False and v["body"]["met"] is True and system.exit_code({"verdict": v}) == 3
    assert v["missed"] == ["fine: largest Q2 error 13.00″ over the 11.98″ budget by 1.02″"]
    assert system.verdict(_synthetic(lost=3))["missed"] == ["fine: beam lost on Q2 in 3 of 1000 samples"]
    # both at once; and a run that did not complete is never met, whatever its figures
    assert len(system.verdict(_synthetic(fine_worst=20.0, pointing=200.0))["missed"]) == 2
    v = system.verdict(_synthetic(complete=False))
    assert v["met"] is False and v["fine"]["met"] and v["body"]["met"] and system.exit_code({"verdict": v}) == 1
    v = system.verdict({"complete": True, "q2_samples": 0, "q2": None, "body_pointing": None})
    assert v["met"] is False and v["fine"]["met"] is None and v["body"]["met"] is None
    md = system.verdict_md(dict(_synthetic(pointing=182.0), verdict=system.verdict(_synthetic(pointing=182.0))))
    assert "| body loop (ADCS): 3σ pointing (arcsec) | 182 | 150 | **NO** | 32 |" in md
    assert "**Terminal: BUDGET MISSED**: body: 3σ pointing 182.0″" in md


def test_a_late_tick_on_the_controller_boards_wire_misses_the_terminal():
    """--runtime qemu: the controller board's meter is part of the fine loop's verdict, in the exit status too."""
    board = {"baud": 2000000, "period_cycles": 75259, "worst_cycles": 70120, "late_ticks": 0, "ticks": 76500}
    s = dict(_synthetic(), target={"wire": {"board": board}})
    v = system.verdict(s)
    assert v["met"] is True and v["board"]["met"] is True and system.exit_code({"verdict": v}) == 0
    assert "| fine loop (controller board): the worst tick's FSM_SPI out, the UART at 2000000 baud" in \
        system.verdict_md(dict(s, verdict=v))
    s["target"]["wire"]["board"] = dict(board, worst_cycles=80000, late_ticks=2)
    v = system.verdict(s)
    assert v["met"] is False and v["fine"]["met"] is True and system.exit_code({"verdict": v}) == 3
    assert v["missed"] == ["fine: the controller board's worst tick 80000 cycles on the wire at 2000000 baud, over "
                           "its 75259 by 4741; 2 of 76500 ticks late"]
    assert system.verdict(_synthetic())["board"] is None          # the other runtimes: no board


def test_fps_system_exits_3_when_the_body_budget_is_missed_and_0_when_both_are_met(tmp_path, system_inputs, monkeypatch,
                                                                                 capsys):
    out = tmp_path / "met"
    rc = fps(_args(out, system_inputs, 2))
    s = _summary(out)
    assert rc == 0, capsys.readouterr().err
    assert s["complete"] is True and s["verdict"]["met"] is True and s["requirement_met"] is True
    assert s["verdict"]["fine"]["met"] and s["verdict"]["body"]["met"] and s["stopped_in"] is None
    assert "terminal: both loops within their budgets" in capsys.readouterr().out
    # the same run judged against a 1 arcsec pointing budget: complete, the fine loop met, the body not
    from protocol import spacecraft as sf
    monkeypatch.setitem(sf.THESIS_REQUIREMENTS, "body_pointing_3sigma_arcsec", 1.0)
    out = tmp_path / "missed"
    rc = fps(_args(out, system_inputs, 2))
    s = _summary(out)
    assert rc == 3
    assert s["complete"] is True and s["verdict"]["met"] is False and s["requirement_met"] is False
    assert s["verdict"]["fine"]["met"] is True and s["verdict"]["body"]["met"] is False
    over = s["verdict"]["body"]["pointing_over_arcsec"]
    assert over == pytest.approx(s["body_pointing"]["pointing_3sigma_arcsec"] - 1.0) and over > 0
    printed = capsys.readouterr().out
    assert "TERMINAL BUDGET MISSED: body: 3σ pointing" in printed and "fine loop: requirement met: all" in printed
    md = (out / "report.md").read_text()
    assert "**Terminal: BUDGET MISSED**: body: 3σ pointing" in md
