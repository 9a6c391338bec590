"""The flight world (``fps adcs bps --world flight``): the flight app's laws one by one (firmware/adcs/flight.py),
the ground APKF's magnetorquer input and innovation gate, the drag and solar pressure torques, a short run's mode
sequence and limits, the CLI's checks and refusals, and (FPS_SLOW=1) the 3-orbit goals on the shipped
spacecraft."""

import json

import numpy as np
import pytest

from emulator.spacecraft.environment import SurfaceTorques, magnetic_torque
from firmware.adcs import flight
from ground.adcs import apkf, body_pointing as bps, modes, quat
from ground.adcs.modes import MODE_CODE
from ground.cli import main as fps
from protocol import spacecraft as sf

DEG = np.pi / 180


def _axis_quat(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([a * np.sin(angle / 2), [np.cos(angle / 2)]])


def _angle(q, p):
    return 2 * np.arcsin(min(1.0, np.linalg.norm(quat.error_vec(q, p))))


def _slew(qs, qc, rate, acc):
    s = flight.Slew(rate, acc)
    s.start(list(qs), list(qc))
    return s


def test_eigenaxis_slew_keeps_its_limits_and_arrives():
    qc = _axis_quat([1, 2, -1], 2.5)                     # 143 deg from the start
    s = _slew([0, 0, 0, 1.0], qc, 0.5 * DEG, 0.05 * DEG)
    q_ref, w_ref = [0.0] * 4, [0.0] * 3
    rates, steps = [], 0
    while s.active:
        s.reference(q_ref, w_ref, list(qc), [0.0, 0.0, 0.0])
        rates.append(np.linalg.norm(w_ref))
        steps += 1
        assert steps < 2000
    rates = np.array(rates)
    assert rates.max() <= 0.5 * DEG * (1 + 1e-9)
    assert np.abs(np.diff(rates)).max() <= 0.05 * DEG * (1 + 1e-6) + 1e-12 or rates[-1] < 0.05 * DEG
    assert abs(rates.sum() - 2.5) < 1e-9                 # the reference covered the angle, nothing more
    s.reference(q_ref, w_ref, list(qc), [0.0, 0.0, 0.0])
    assert _angle(np.array(q_ref), qc) < 1e-12
    # against a command that turns: the reference ends on it and its rate then is the command's
    w_c = np.array([0.0, 0.06, 0.0]) * DEG
    qc0 = _axis_quat([0, 0, 1], 1.0)
    s = _slew([0, 0, 0, 1.0], qc0, 0.5 * DEG, 0.05 * DEG)
    q = qc0
    for _ in range(400):
        s.reference(q_ref, w_ref, list(q), list(w_c))
        q = quat.propagate(q, w_c, 1.0)
    assert not s.active and _angle(np.array(q_ref), quat.propagate(q, -w_c, 1.0)) < 1e-9
    assert np.allclose(w_ref, w_c, atol=1e-9)


def test_the_times_in_each_mode_add_up():
    changes = [{"t_s": 1.0, "from": "INIT", "to": "HOLD"}, {"t_s": 30.0, "from": "HOLD", "to": "SLEW"},
               {"t_s": 100.0, "from": "SLEW", "to": "POINT"}]
    t = modes.time_in(changes, 250)
    assert t == {"INIT": 1, "HOLD": 29, "SLEW": 70, "ACQUIRE": 0, "POINT": 150, "DEGRADED": 0}


def _unloading(b, h, gain, limit, m_res=(0.0, 0.0, 0.0)):
    m = [0.0] * 3
    sat = flight.unloading(m, list(b), list(h), gain, limit, list(m_res))
    return np.array(m), [bool(sat >> i & 1) for i in range(3)]


def test_unloading_law_removes_momentum_across_the_field_and_clips_per_rod():
    rng = np.random.default_rng(1)
    for _ in range(20):
        b, h = rng.normal(size=3) * 3e-5, rng.normal(size=3) * 1e-3
        m, sat = _unloading(b, h, 1e-3, 10.0)
        assert not any(sat)
        h_perp = h - b * (b @ h) / (b @ b)
        assert np.allclose(magnetic_torque(m, b), -1e-3 * h_perp, rtol=1e-9, atol=1e-18)
    m, sat = _unloading([3e-5, 0, 0], [0, 0, 1.0], 1.0, 0.2)
    assert sat == [False, True, False] and np.allclose(m, [0, 0.2, 0])      # h x b, clipped
    # the estimated residual is cancelled: with no momentum the command is -m_residual
    m, _ = _unloading([1e-5, 2e-5, 0], np.zeros(3), 1e-3, 1.0, m_res=[0.1, -0.05, 0.2])
    assert np.allclose(m, [-0.1, 0.05, -0.2])
    m, sat = _unloading([0.0, 0.0, 0.0], [1e-3, 0, 0], 1e-3, 1.0)
    assert np.all(m == 0) and not any(sat)                                  # no field: no command


def test_null_bias_moves_the_wheels_without_torquing_the_body():
    d = sf.load("thesis-3u")
    C = np.array(sf.wheel_axes(d)).T
    n = np.array(flight.null_vector(C.ravel().tolist()))
    assert np.allclose(C @ n, 0, atol=1e-12) and abs(np.linalg.norm(n) - 1) < 1e-12 and n[np.argmax(np.abs(n))] > 0
    u = [0.0] * 4
    flight.null_bias(u, n, [0.0] * 4, [3e-6] * 4, 2000 * bps.RPM, 0.01)
    assert np.allclose(C @ u, 0, atol=1e-15) and np.abs(u).max() > 0
    w_at = n * (2000 * bps.RPM / np.mean(np.abs(n)))
    u = [0.0] * 4
    flight.null_bias(u, n, w_at.tolist(), [3e-6] * 4, 2000 * bps.RPM, 0.01)
    assert np.allclose(u, 0, atol=1e-15)


def test_surface_torques_are_the_offset_cross_the_force():
    d = sf.load("thesis-3u")
    s = d["orbit"]["state"]
    x0 = np.array(s["position_m"] + s["velocity_m_s"])
    t = np.arange(0, 3.0)
    x = np.array([x0, x0, x0])
    st = SurfaceTorques(t, x, sf.epoch_tuple(d), d["surface"], [0.02, 0.0, 0.0])
    assert 1e-13 < st.rho[0] < 1e-10                     # 400 km: Harris-Priester's range
    q = _axis_quat([0.3, -1, 0.2], 0.7)
    tau = st(1.0, q)
    f_b = quat.dcm(q) @ st.force_i[1]
    assert np.allclose(tau, np.cross([0.02, 0, 0], f_b), rtol=1e-12, atol=0)
    assert 1e-9 < np.linalg.norm(tau) < 1e-6
    vr = x0[3:6] - np.cross([0, 0, 7.2921159e-5], x0[0:3])
    assert np.dot(st.force_i[1], vr) < 0                # drag (~6 uN) outweighs solar pressure (~0.2 uN) here


def test_apkf_takes_the_magnetorquer_dipole_as_a_known_input():
    model = apkf.Model()
    x = apkf.initial_state(_axis_quat([1, 0, 0], 0.3), np.array([1e-3, -2e-3, 5e-4]), np.full(4, 100.0))
    m_ctrl = np.array([0.1, -0.2, 0.05])
    model.m_ctrl = m_ctrl
    with_input = apkf.propagate(x, model, 0.0)
    model.m_ctrl = None
    y = x.copy()
    y[15:18] += m_ctrl
    without = apkf.propagate(y, model, 0.0)
    assert np.allclose(with_input[0:7], without[0:7], rtol=0, atol=1e-15)
    model.m_ctrl = m_ctrl
    F1 = apkf.jacobian(x, model, 0.0)
    model.m_ctrl = None
    assert np.allclose(F1, apkf.jacobian(y, model, 0.0))
    assert not np.allclose(F1, apkf.jacobian(x, model, 0.0))


def test_apkf_gate_resets_on_a_lost_attitude_and_not_on_noise():
    model = apkf.Model()
    q0 = _axis_quat([0, 1, 0], 0.2)
    f = apkf.APKF(apkf.initial_state(q0, np.zeros(3), np.zeros(4)), model=model)
    f.P[0:3, 0:3] = np.eye(3) * (20 * quat.RAD_PER_ARCSEC) ** 2
    f.gate = 44.84
    f.step(0.0, np.zeros(4), quat.from_small(np.array([5, -5, 10]) * quat.RAD_PER_ARCSEC / 2, q0))
    assert f.resets == []
    far = quat.quat_mul(_axis_quat([1, 0, 0], 2 * DEG), f.x[0:4])
    f.step(1.0, np.zeros(4), far)
    assert len(f.resets) == 1 and f.resets[0][1] > 44.84 and abs(f.resets[0][2] - 7200) < 50
    assert _angle(f.x[0:4], far) < 1e-12 and np.allclose(f.P[0:3, 3:], 0)


@pytest.fixture(scope="module")
def params():
    return bps.calibrate(seed=0)


def test_a_short_flight_run_slews_acquires_and_points_within_the_wheels(params):
    res, hist = bps.simulate(params=params, duration_s=700, world="flight", truth="two-body", seed=3)
    to = [c["to"] for c in res["mode_changes"]]
    assert to[:4] == ["HOLD", "SLEW", "ACQUIRE", "POINT"] or to[:5] == ["HOLD", "SLEW", "ACQUIRE", "SLEW", "ACQUIRE"]
    assert res["world"] == "flight" and res["wheel_speed_limit_rpm"] == 10000
    assert sum(res["wheel_speed_clips"]["speed_clip"]) == 0
    assert res["max_wheel_speed_rpm_run"] < 8000
    rate = np.linalg.norm(hist["w"], axis=1) / DEG
    assert rate.max() < 2.0 * 1.1 + 0.1                  # the slew's limit plus the command's own turn
    assert res["passes"] == [] and res["time_in_mode_s"]["POINT"] > 300
    point = hist["fsw_mode"][:, 0] == MODE_CODE["POINT"]
    k = np.nonzero(point)[0]
    assert np.nanmean(np.abs(hist["dtheta_arcsec"][10 * k[k > k[0] + 150]])) < 100


def test_the_thesis_world_is_untouched_by_the_flight_options(params):
    a, _ = bps.simulate(params=params, duration_s=100, truth="two-body")
    b, _ = bps.simulate(params=params, duration_s=100, truth="two-body", flight={"slew_rate_deg_s": 3.0})
    assert a["world"] == "thesis" and a["pointing_3sigma_arcsec"] == b["pointing_3sigma_arcsec"]
    # the app's thesis modes: the hold, then POINT; DEGRADED while the star tracker is blind for long in the slew
    # the PD flies to the command (above 0.1 deg/s), POINT again once it answers
    changes = a["mode_changes"]
    assert [c["to"] for c in changes][:2] == ["HOLD", "POINT"] and changes[-1]["to"] == "POINT"
    assert all("STARTRACKER" in c["reason"] for c in changes if c["to"] == "DEGRADED")
    with pytest.raises(ValueError, match="unknown flight option"):
        bps.simulate(params=params, duration_s=10, flight={"slew_rate": 1})
    with pytest.raises(ValueError, match="world must be one of"):
        bps.simulate(params=params, duration_s=10, world="orbit")


def test_cli_flight_world_checks_and_refusals(tmp_path, capsys):
    out = tmp_path / "run"
    rc = fps(["adcs", "bps", "--world", "flight", "--session", "400", "--truth", "two-body", "--quiet",
              "--no-plots", "--cache-dir", str(tmp_path / "cache"), "-o", str(out)])
    assert rc == 3                                      # no pass collected: the run cannot report success
    s = json.load(open(out / "summary.json"))
    assert s["budgets_met"] is False and s["checks"]["passes"]["ok"] is False and s["world"] == "flight"
    assert "REQUIREMENT MISSED" in capsys.readouterr().err
    assert "| t (s) | mode change | reason |" in (out / "report.md").read_text()
    bad = tmp_path / "nomtq.json"
    d = json.load(open(sf.preset_path("generic-6u")))
    d["magnetorquers"] = None
    bad.write_text(json.dumps(d))
    for args, what in ((["--orbits", "0"], "--orbits"), (["--spacecraft", str(bad)], "magnetorquers = null")):
        rc = fps(["adcs", "bps", "--world", "flight", "--quiet", "-o", str(tmp_path / "x")] + args)
        assert rc == 2 and what in capsys.readouterr().err
    for cmd in (["adcs", "campaign", "--runs", "1"], ["system", "--world", "flight"]):   # refused before any run
        rc = fps(cmd + ["--spacecraft", str(bad), "-o", str(tmp_path / cmd[1])])
        err = capsys.readouterr().err
        assert rc == 2 and "magnetorquers = null" in err and "--spacecraft %s" % bad in err
        assert not (tmp_path / cmd[1]).exists()
    try:
        rc = fps(["adcs", "bps", "--world", "moon", "-o", str(tmp_path / "y")])
    except SystemExit as exc:
        rc = exc.code
    assert rc == 2 and "invalid choice" in capsys.readouterr().err


@pytest.mark.slow(reason="3 orbits per spacecraft, ~1 min each: FPS_SLOW=1")
@pytest.mark.parametrize("name", ["thesis-3u", "generic-6u", "generic-12u"])
def test_three_orbits_in_the_flight_world_meet_the_goals(name):
    d = sf.load(name)
    if d["partner"] is None:
        d = bps.with_partner(d)
    p = bps.calibrate(seed=0, spacecraft=d)
    s = d["orbit"]["state"]
    T = bps.orbit_period(np.array(s["position_m"] + s["velocity_m_s"]))
    res, _ = bps.simulate(params=p, duration_s=3 * T, world="flight", truth="hpop", spacecraft=d)
    assert len(res["passes"]) == 2
    for q in res["passes"]:
        assert q["pointing_3sigma_arcsec"] < 150 and q["stability_3sigma_arcsec_s"] < 35
    assert res["max_wheel_speed_rpm"] <= 0.8 * res["wheel_speed_limit_rpm"]
    assert res["star_tracker_blind_share"] < 0.1 and res["complete"]
