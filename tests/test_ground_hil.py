"""``fps hil`` (Sec. 7.5): short runs through every runtime x link, the run folder, interruption, statistics."""

import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from ground import report
from ground.cli import main as fps

SUMMARY_KEYS = {"complete", "duration_s", "real_time_factor", "overruns", "q2", "truth"}
STAT_KEYS = {"mean_arcsec", "std_arcsec", "max_radial_arcsec", "within_4_arcsec", "within_requirement",
             "pointing_loss_db"}


def _check_run(folder, duration):
    s = json.loads((folder / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(s)
    assert s["complete"] is True and s["duration_s"] == pytest.approx(duration, abs=0.01)
    assert s["overruns"] == 0
    for side in ("q2", "truth"):
        assert STAT_KEYS <= set(s[side])
        assert s[side]["within_requirement"] == 1.0
        assert s[side]["max_radial_arcsec"] < report.REQUIREMENT_ARCSEC
    z = np.load(folder / "samples.npz")
    n = len(z["t_s"])
    assert abs(n - 630 * duration) <= 2                     # Q2 at 630 Hz
    assert z["q2_err_arcsec"].shape == z["truth_err_arcsec"].shape == (n, 2)
    # Q2, calibrated against the P-FSM, sees the same motion as the truth (up to Q1/Q2 misalignment bias)
    dq = z["q2_err_arcsec"] - z["q2_err_arcsec"].mean(0)
    dt = z["truth_err_arcsec"] - z["truth_err_arcsec"].mean(0)
    assert np.abs(dq - dt).max() < 0.5
    for name in ("config.json", "calibration.json", "q2_calibration.json", "telemetry.csv", "report.md",
                 "fig7-18_scatter.png", "fig7-19_time.png"):
        assert (folder / name).stat().st_size > 0, name
    assert len((folder / "telemetry.csv").read_text().splitlines()) > 1
    return s


def test_hil_inproc_run_folder_and_table(tmp_path, capsys, inputs):
    dist, cal = inputs
    out = tmp_path / "run"
    assert fps(["hil", "--distfile", dist, "--calibration", cal, "--duration", "8", "-o", str(out)]) == 0
    s = _check_run(out, 8)
    text = capsys.readouterr().out
    assert "thesis (Sec. 7.5)" in text and "0.5513" in text and str(out) in text
    # the run's motion is real: the distfile moves the beam by tens of arcsec, the loop holds it to < 1"
    z = np.load(out / "samples.npz")
    assert s["truth"]["std_arcsec"][0] < 1.0 and np.ptp(z["q2_counts"][:, 0]) > 0


@pytest.mark.parametrize("runtime,link", [
    ("cpython", "serial"),
    ("micropython", "serial"),
    ("cpython", "can"),
])
def test_hil_subprocess_runtimes(tmp_path, inputs, runtime, link):
    dist, cal = inputs
    out = tmp_path / "run"
    assert fps(["hil", "--distfile", dist, "--calibration", cal, "--duration", "3", "--runtime", runtime,
                "--link", link, "--no-plots", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] and s["overruns"] == 0 and s["q2"]["within_requirement"] == 1.0


def test_hil_refuses_bad_combinations_and_inputs(tmp_path, capsys, inputs):
    dist, cal = inputs
    base = ["hil", "--distfile", dist, "--calibration", cal, "-o", str(tmp_path / "r")]
    assert fps(base + ["--runtime", "micropython", "--link", "can"]) == 2
    assert "serial only" in capsys.readouterr().err
    assert fps(base + ["--duration", "100"]) == 2
    assert "longer than the distfile" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text('{"grid_v": [0, 1], "points": []}')
    assert fps(["hil", "--distfile", dist, "--calibration", str(bad), "-o", str(tmp_path / "r2")]) == 2
    assert "calibration" in capsys.readouterr().err


def test_hil_sigterm_leaves_valid_partial_folder(tmp_path, inputs):
    dist, cal = inputs
    out = tmp_path / "run"
    # the controller in a subprocess paces the run near real time (in-process, 30 s may take under 0.3 s)
    proc = subprocess.Popen([sys.executable, "-m", "ground.cli", "hil", "--distfile", dist, "--calibration", cal,
                             "--duration", "30", "--runtime", "cpython", "--link", "serial", "--no-plots",
                             "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while not (out / "config.json").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err.decode()
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is False and s["duration_s"] < 30
    z = np.load(out / "samples.npz")
    assert len(z["t_s"]) == s["q2_samples"]
    assert abs(len(z["t_s"]) - 630 * s["duration_s"]) <= 2      # every sample played is kept, to the last tick
    assert b"partial run" in err
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]


def test_error_stats_and_pointing_loss():
    assert report.THETA0_ARCSEC == pytest.approx(23.96 / math.sqrt(2 * math.log(2)))
    # 3 dB at the half width at half maximum (Ch. 2)
    assert report.pointing_loss_db(23.96 / 2) == pytest.approx(10 * math.log10(2))
    x = np.array([0.0, 3.0, 0.0, 12.5])
    y = np.array([0.0, 0.0, -3.9, 0.0])
    s = report.error_stats(x, y)
    assert s["max_radial_arcsec"] == 12.5
    assert s["within_4_arcsec"] == 0.75 and s["within_requirement"] == 0.75
    assert s["pointing_loss_db"] == pytest.approx(np.mean(report.pointing_loss_db(np.hypot(x, y))))
    assert report.error_stats([], [])["mean_arcsec"] is None
