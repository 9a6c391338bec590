"""The lean ADCS's flight world: firmware/adcs/flight.py's laws under MicroPython and CPython,
the firmware's modes over CAN against the emulated spacecraft (magnetorquers and magnetometer on the bus), and
``fps adcs can`` / ``fps system`` with ``--world flight``."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from firmware.adcs import flight
from ground.adcs import body_pointing as bps, quat
from tests.test_firmware_mp import run_mp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEG = np.pi / 180


def _cpython_laws():
    """tests/mp/firmware_flight.py's results under CPython (the same module, the same inputs)."""
    out = subprocess.run([sys.executable, os.path.join(ROOT, "tests", "mp", "firmware_flight.py")], cwd=ROOT,
                         capture_output=True, text=True, timeout=60, env=dict(os.environ, PYTHONPATH=ROOT))
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_flight_laws_agree_under_micropython_and_cpython():
    mp, cp = run_mp("firmware_flight.py"), _cpython_laws()
    assert mp["steps"] == cp["steps"] > 10
    assert np.allclose(np.array(mp["refs"]), np.array(cp["refs"]), rtol=0, atol=1e-9)
    b, h = np.array([2e-5, -1e-5, 3e-5]), np.array([1e-3, 2e-3, -5e-4])
    m = 2e-3 * np.cross(h, b) / (b @ b) - np.array([0.1, -0.15, 0.2])     # within the 0.3 A m^2 limit
    assert np.allclose(mp["m"], m, atol=1e-12) and np.allclose(cp["m"], m, atol=1e-15) and mp["sat"] == cp["sat"] == 0
    C = np.array(mp["null"])
    c0 = np.array([-0.577, -0.577, 0.577, 0.577, -0.577, 0.577, 0.577, -0.577, 0.577, 0.577, 0.577, 0.577])
    assert np.allclose(c0.reshape(3, 4) @ C, 0, atol=1e-12) and abs(np.linalg.norm(C) - 1) < 1e-12
    P = np.diag(1e-8 * np.arange(1, 10))
    z = np.array([1e-4, -2e-4, 5e-5])
    S = P[0:3, 0:3] + np.diag([1e-9, 1e-9, 9e-9])
    assert abs(mp["nis"] - z @ np.linalg.solve(S, z)) < 1e-9 * mp["nis"]
    # the reference's rate keeps the slew's limit (2 deg/s) plus the command's own turn
    w_ref = np.linalg.norm(np.array(mp["refs"])[:, 4:7], axis=1)
    assert w_ref.max() <= 2.0 * DEG + 0.001 + 1e-12 and w_ref.max() > 1.9 * DEG


def test_reset_attitude_clears_the_correlations():
    x = [0.1, 0.2, 0.3, 0.9] + [0.0] * 6
    P = [0.5] * 81
    flight.reset_attitude(x, P, [0.0, 0.0, 0.0, 1.0], [1.0, 0, 0, 0, 2.0, 0, 0, 0, 3.0])
    Pm = np.array(P).reshape(9, 9)
    assert x[0:4] == [0.0, 0.0, 0.0, 1.0] and np.allclose(Pm[0:3, 0:3], np.diag([1.0, 2.0, 3.0]))
    assert np.all(Pm[0:3, 3:] == 0) and np.all(Pm[3:, 0:3] == 0) and np.all(Pm[3:, 3:] == 0.5)


def test_the_firmware_flies_its_modes_over_can_with_the_magnetorquers():
    from emulator.adcs_session import AdcsSession
    runtime = "micropython" if os.path.exists(os.path.join(os.path.dirname(sys.executable), "micropython")) \
        else "cpython"
    s = AdcsSession(runtime=runtime, duration_s=300, world="flight")
    w, rpm = [], []
    with s:
        for _ in range(300):
            c = s.cycle()
            w.append(np.linalg.norm(c["w"], axis=1).max())
    summ = s.summary()
    to = [m["to"] for m in summ["mode_changes"]]
    assert to[:3] == ["HOLD", "SLEW", "ACQUIRE"] and to[-1] == "POINT", summ["mode_changes"]
    assert all(m["reason"] for m in summ["mode_changes"])
    assert summ["magnetic_devices"]["mtq_cmd"] == 300 and summ["magnetic_devices"]["refused_mtq_cmd"] == 0
    assert summ["world"] == "flight"
    assert np.degrees(max(w)) < 2.0 * 1.1 + 0.1                  # the slew's rate limit (+ the command's turn)
    assert s.wheel_rpm_max() < 0.8 * 10000
    t_point = [m["t_s"] for m in summ["mode_changes"] if m["to"] == "POINT"][-1]
    assert s.blind_share(t_point) == 0.0


def _fps(*args, timeout=900):
    return subprocess.run([sys.executable, "-m", "ground.cli"] + list(args), cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_fps_adcs_can_and_system_in_the_flight_world(tmp_path):
    p = _fps("adcs", "can", "--world", "flight", "--session", "360", "--quiet", "--no-plots",
             "-o", str(tmp_path / "can"))
    assert p.returncode == 0, p.stderr
    s = json.load(open(tmp_path / "can" / "summary.json"))
    assert s["world"] == "flight" and s["settle_s"] == bps.flight_settle_s(bps.scenario.thesis_3u())
    assert s["budgets_met"] is True and s["max_wheel_speed_rpm"] < 8000 and s["star_tracker_blind_share"] == 0
    p = _fps("system", "--duration", "20", "--truth", "two-body", "--quiet", "--no-plots", "-o", str(tmp_path / "sys"))
    assert p.returncode == 0, p.stderr
    s = json.load(open(tmp_path / "sys" / "summary.json"))
    assert s["world"] == "flight" and s["settle_s"] == bps.flight_settle_s(bps.scenario.thesis_3u())
    assert s["verdict"]["met"] is True
    modes_seen = [m["to"] for m in s["adcs_summary"]["mode_changes"]]
    assert "SLEW" in modes_seen and modes_seen[-1] == "POINT"


@pytest.mark.slow(reason="an 1800 s play, ~5 min: FPS_SLOW=1")
def test_fps_system_flight_1800_s_meets_its_goal(tmp_path):
    """The goal: the lean ADCS under MicroPython over CAN in the flight world, 1800 s: every Q2 sample within
    11.98 arcsec, the body loop within its budgets, the wheels within their limit, >= 5x real time."""
    p = _fps("system", "--duration", "1800", "--quiet", "--no-plots", "-o", str(tmp_path / "sys"), timeout=3000)
    assert p.returncode == 0, p.stderr
    s = json.load(open(tmp_path / "sys" / "summary.json"))
    assert s["verdict"]["met"] and s["real_time_factor"] >= 5.0
    a = s["adcs_summary"]
    assert a["world"] == "flight" and a["max_wheel_speed_rpm"] < a["wheel_datasheet_rpm"]
