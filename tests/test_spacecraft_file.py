"""One spacecraft file (protocol.spacecraft, fps spacecraft): every preset passes the checker and names its sources,
thesis-3u's figures equal the code's thesis constants (so a drift on either side fails here), each class of bad input
is refused naming the key, the value and the range, the CLI exits 0 or 2 without a traceback, the checker gives the
same results under MicroPython, and docs/SPACECRAFT.md is fresh."""

import copy
import inspect
import json
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from ground import cli, spacecraft_cli
from protocol import spacecraft as sc

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")
MP_SCRIPT = os.path.join(ROOT, "tests", "mp", "spacecraft_check.py")
PRESETS = ("generic-12u", "generic-6u", "thesis-3u")


def raw(name="thesis-3u"):
    with open(sc.preset_path(name)) as f:
        return json.load(f)


def defaults(f):
    return dict((k, p.default) for k, p in inspect.signature(f).parameters.items()
                if p.default is not inspect.Parameter.empty)


# --- presets ------------------------------------------------------------------------------------------------
def test_every_preset_passes_the_checker_and_names_its_sources():
    assert tuple(sc.presets()) == PRESETS
    leaves = [e["path"] for e in sc.SCHEMA if e["kind"] not in ("block", "sources")
              and e["path"] not in ("format", "name", "description")]
    for name in PRESETS:
        d = sc.load(name)
        assert d["name"] == name and d["format"] == sc.FORMAT
        assert sc.check(d) == d and sc.check(raw(name)) == d           # idempotent; the raw file gives the same
        for path in leaves:                                           # every figure present has a source
            parts = path.split(".")
            if spacecraft_cli._get(d, path) is spacecraft_cli._ABSENT:
                assert any(d.get(p) is None for p in parts[:1]), (name, path)   # in a null block
                continue
            assert any(".".join(parts[:i]) in d["sources"] for i in range(1, len(parts) + 1)), (name, path)
        for text in d["sources"].values():                            # files named in sources are this repo's
            for f in re.findall(r"[\w/]+\.py\b", text):
                base = os.path.basename(f)
                assert any(base in files for _, _, files in os.walk(ROOT)), (name, f)
    for name in ("generic-6u", "generic-12u"):
        d = sc.load(name)
        assert "not a specific vehicle" in d["description"] and d["truth"] is None
        assert all(re.match(r"(Representative|Assumed|Stated|Not measured|None)", t) for t in d["sources"].values())
    assert all("thesis" in t.lower() for t in sc.load("thesis-3u")["sources"].values())


def test_the_generic_vehicles_are_plausible():
    j3, j6, j12 = (sc.principal_moments(sc.load(n)["inertia_kgm2"]) for n in ("thesis-3u", "generic-6u",
                                                                            "generic-12u"))
    assert 3 < j6[2] / j3[2] < 10 and 5 < j12[2] / j3[2] < 20
    big = [int(np.argmax(sc.load(n)["inertia_kgm2"][:3])) for n in ("thesis-3u", "generic-6u", "generic-12u")]
    assert len(set(big)) == 3                                          # the largest moment about y, z, x
    for n, mass in (("generic-6u", (10, 14)), ("generic-12u", (20, 24))):
        d = sc.load(n)
        assert mass[0] <= d["mass_kg"] <= mass[1]
        products = np.abs(d["inertia_kgm2"][3:])
        assert products.max() < 1e-2 and products.min() >= 1e-3
        w = d["wheels"]
        h = w["rotor_inertia_kgm2"][0] * w["speed_limit_rpm"] * 2 * math.pi / 60
        assert 0.02 < h < 0.2 and w["torque_limit_nm"] >= 2e-3      # a larger-class wheel than the 3U's 3 mN m s
        o = d["orbit"]
        from emulator.spacecraft.environment import CircularOrbit     # the state is the circular orbit's
        c = o["circular"]
        orb = CircularOrbit(c["altitude_km"] * 1e3, c["inclination_deg"], c["raan_deg"], c["arg_lat_deg"])
        assert np.allclose(orb.position(0.0), o["state"]["position_m"], rtol=0, atol=1e-3)
        assert np.allclose(orb.velocity(0.0), o["state"]["velocity_m_s"], rtol=0, atol=1e-4)


# --- thesis-3u against the code -------------------------------------------------------------------------------
def test_thesis_3u_inertia_dipole_and_wheels_are_the_code_constants():
    """Nominal figures (what the filters and controllers start from) and true ones (Sec. 4.8)."""
    from emulator.spacecraft import environment as env, scenario
    from emulator.spacecraft.dynamics import DJ_THESIS, J0_THESIS
    from emulator.spacecraft.wheels import (DELTA1_DEG_THESIS, DELTA2_DEG_THESIS, DJ_RW_THESIS, J_RW_NOMINAL, RPM,
                                            WheelParams)
    from firmware.adcs import apkf_lean
    from ground.adcs import apkf, body_pointing as bps

    d = sc.load("thesis-3u")
    w, t = d["wheels"], d["truth"]
    assert tuple(d["inertia_kgm2"]) == J0_THESIS and tuple(t["inertia_error_kgm2"]) == DJ_THESIS
    assert d["residual_dipole_am2"] == [0.0] * 3 and tuple(t["residual_dipole_error_am2"]) == env.M_DIPOLE_THESIS
    assert defaults(scenario.PD.__init__)["j0"] == J0_THESIS
    ini = defaults(apkf.initial_state)
    assert tuple(ini["j5"]) == tuple(d["inertia_kgm2"][1:]) and w["rotor_inertia_kgm2"] == [ini["jrw"]] * 4
    assert w["count"] == 4 and w["rotor_inertia_kgm2"] == [J_RW_NOMINAL] * 4
    assert tuple(t["rotor_inertia_error_kgm2"]) == DJ_RW_THESIS
    assert w["delta1_deg"] == w["delta2_deg"] == [0.0] * 4
    assert tuple(t["delta1_error_deg"]) == DELTA1_DEG_THESIS and tuple(t["delta2_error_deg"]) == DELTA2_DEG_THESIS
    wp = WheelParams()
    assert (w["torque_limit_nm"], w["speed_limit_rpm"], w["friction_coulomb_nm"], w["friction_viscous_nms_rad"],
            w["friction_smooth_rpm"], w["tach_noise_rpm"], w["imbalance_static_kgm"], w["imbalance_dynamic_kgm2"],
            w["arm_m"]) == (wp.torque_max, wp.speed_max_rpm, wp.friction_coulomb, wp.friction_viscous,
                            wp.friction_smooth_rpm, wp.noise_rpm, wp.imbalance_static, wp.imbalance_dynamic, wp.arm)
    assert apkf_lean.FRICTION == (w["friction_coulomb_nm"], w["friction_viscous_nms_rad"],
                                  w["friction_smooth_rpm"] * RPM)
    assert apkf_lean.TORQUE_MAX == w["torque_limit_nm"] and bps.TACH_NOISE_RPM == w["tach_noise_rpm"]
    assert defaults(apkf.Model.__init__)["tach_rpm"] == defaults(apkf_lean.Model.__init__)["tach_rpm"] == 10.0


def test_thesis_3u_true_figures_are_what_the_simulations_fly():
    """Bit for bit: the truth's J, dipole, rotors and axes (Eq. 4.149)."""
    from emulator.spacecraft.dynamics import Spacecraft
    from emulator.spacecraft.wheels import WheelParams, Wheels, pyramid_c0

    d = sc.load("thesis-3u")
    wp = WheelParams()
    tf = sc.true_figures(d)
    assert tf["rotor_inertia_kgm2"] == wp.j_rw.tolist() and tf["delta1_deg"] == wp.delta1_deg.tolist()
    assert tf["delta2_deg"] == wp.delta2_deg.tolist()
    sim = Spacecraft()
    assert np.array_equal(np.array(sc.inertia_matrix(d, True)), sim.j) and tf["residual_dipole_am2"] == \
        sim.dipole.tolist()
    assert np.array_equal(np.array(sc.wheel_axes(d)).T, pyramid_c0())
    assert np.array_equal(np.array(sc.wheel_axes(d, True)).T, Wheels().c)


def test_thesis_3u_sensor_figures_are_the_code_constants():
    """Star tracker, gyro, GNSS, beacon and relay against the devices' and the filters' defaults."""
    from emulator.navsensors import Beacon, Gnss, Relay
    from emulator.spacecraft import scenario
    from emulator.spacecraft.devices import StarTracker
    from firmware.adcs import apkf_lean
    from ground.adcs import apkf, mekf

    d = sc.load("thesis-3u")
    st = d["star_tracker"]
    sd = defaults(StarTracker.__init__)
    assert tuple(st["sigma_arcsec"]) == sd["sigma_arcsec"] and st["rate_limit_deg_s"] == sd["rate_max_dps"]
    assert defaults(scenario.simulate)["st_rate_max_dps"] == st["rate_limit_deg_s"]
    assert tuple(st["sigma_arcsec"]) == defaults(apkf.Model.__init__)["sigma_st_arcsec"] == \
        defaults(apkf_lean.Model.__init__)["sigma_st_arcsec"]
    assert st["rate_hz"] == 1.0 == 1.0 / defaults(apkf.Model.__init__)["dt"]
    g = d["gyro"]
    gd, md = defaults(scenario.MemsGyro.__init__), defaults(mekf.MEKF.__init__)
    assert (g["arw_deg_rt_h"], g["bias_deg_h"], g["bias_instability_deg_h"]) == (
        gd["arw_deg_rt_h"], gd["bias_deg_h"], gd["instability_deg_h"])
    assert md["sigma_v"] == np.radians(g["arw_deg_rt_h"]) / 60.0
    assert md["sigma_u"] == np.radians(g["bias_instability_deg_h"]) / 3600.0 / 60.0
    assert md["P0_bias"] == np.radians(g["bias_deg_h"]) / 3600.0
    assert np.array_equal(md["sigma_st_rad"], np.array(st["sigma_arcsec"]) * mekf.quat.RAD_PER_ARCSEC)
    gn, bd, rd = defaults(Gnss.__init__), defaults(Beacon.__init__), defaults(Relay.__init__)
    assert (d["gnss"]["sigma_position_m"], d["gnss"]["sigma_velocity_m_s"]) == (gn["sigma_r_m"], gn["sigma_v_m_s"])
    assert d["beacon"]["sigma_arcsec"] == bd["sigma_arcsec"] and tuple(d["partner"]["relay_delay_s"]) == rd["delay_s"]


def test_thesis_3u_orbit_partner_and_body_are_the_code_constants():
    from emulator import orbits
    from emulator.spacecraft import environment as env
    from ground.adcs import control

    d = sc.load("thesis-3u")
    c, od = d["orbit"]["circular"], defaults(env.CircularOrbit.__init__)
    assert (c["altitude_km"] * 1000.0, c["inclination_deg"], c["raan_deg"], c["arg_lat_deg"]) == (
        od["altitude"], od["inclination_deg"], od["raan_deg"], od["arg_lat_deg"])
    s = d["orbit"]["state"]
    assert sc.epoch_tuple(d) == orbits.EPOCH_UTC
    assert s["position_m"] + s["velocity_m_s"] == orbits.X0_A.tolist()
    assert d["partner"]["position_m"] + d["partner"]["velocity_m_s"] == orbits.X0_B.tolist()
    cs = orbits.CUBESAT_3U
    assert (d["mass_kg"], d["surface"]["drag_area_m2"], d["surface"]["cd"], d["surface"]["srp_area_m2"],
            d["surface"]["cr"]) == (cs["mass_kg"], cs["drag_area_m2"], cs["cd"], cs["srp_area_m2"], cs["cr"])
    assert d["laser_axis"] == control.LASER_AXIS.tolist()
    assert d["magnetorquers"]["dipole_limit_am2"] == 0.3 and d["magnetometer"]["noise_nt"] == 50.0


def test_thesis_3u_uncertainties_are_the_filters_priors():
    """The APKF's P0 (Sec. 4.8), the MEKF's, the STKF's (Sec. 5.5.1)."""
    from emulator.spacecraft import scenario
    from ground.adcs import apkf, mekf

    u = sc.load("thesis-3u")["uncertainty"]
    p0 = np.diag(apkf.initial_covariance(apkf.Model()))
    deg = apkf.DEG
    assert np.array_equal(p0[apkf.IQ], [(u["attitude_sigma_deg"] * deg / 2) ** 2] * 3)
    assert np.array_equal(p0[apkf.IW], [(u["rate_sigma_deg_s"] * deg) ** 2] * 3)
    assert np.array_equal(p0[apkf.ITD], [u["disturbance_torque_sigma_nm"] ** 2] * 3)
    assert np.array_equal(p0[apkf.IJ], np.array(u["inertia_sigma_kgm2"][1:]) ** 2)      # Jyy .. Jyz; Jxx fixed
    assert np.array_equal(p0[apkf.IM], [u["residual_dipole_sigma_am2"] ** 2] * 3)
    assert np.array_equal(p0[apkf.ID1], [(u["misalignment_sigma_deg"] * deg) ** 2] * 4)
    assert np.array_equal(p0[apkf.ID2], p0[apkf.ID1])
    assert np.array_equal(p0[apkf.IJR], [u["rotor_inertia_sigma_kgm2"] ** 2] * 4)
    assert defaults(mekf.MEKF.__init__)["P0_att_rad"] == np.radians(u["attitude_sigma_deg"])
    assert scenario.STKF_P0_DIAG == ([u["orbit_position_sigma_m"] ** 2] * 3 + [u["orbit_velocity_sigma_m_s"] ** 2]
                                     * 3) * 2


def test_helpers():
    d = sc.load("generic-12u")
    J = np.array(sc.inertia_matrix(d))
    assert np.array_equal(J, J.T) and J[0, 1] == d["inertia_kgm2"][3] and J[1, 2] == d["inertia_kgm2"][5]
    assert np.allclose(sc.principal_moments(d["inertia_kgm2"]), np.linalg.eigvalsh(J), rtol=1e-14, atol=0)
    assert sc.inertia_matrix(d, True) == sc.inertia_matrix(d)                 # no truth block: the figures
    a = np.array(sc.wheel_axes(d))
    assert a.shape == (4, 3) and np.allclose(np.linalg.norm(a, axis=1), 1.0) and np.allclose(a[3], 1 / math.sqrt(3))
    e = copy.deepcopy(d)
    e["wheels"]["delta1_deg"] = [0.0, 0.0, 0.0, 2.0]
    b = np.array(sc.wheel_axes(e))
    tilt = math.degrees(math.acos(float(a[3] @ b[3])))
    assert abs(tilt - math.degrees(math.atan(math.radians(2.0)))) < 1e-9          # atan of the angle, as stated
    par = copy.deepcopy(d)                    # parallel neighbours: e1 from the least aligned body axis
    par["wheels"]["nominal_axes"] = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1]]
    e1, e2 = sc.misalignment_axes(sc.wheel_axes(par))
    assert np.allclose(e1[2], [0, 1, 0]) and np.allclose(np.cross(e1[2], e2[2]), [0, 0, 1])


# --- bad input ------------------------------------------------------------------------------------------------
def _set(d, path, value):
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if isinstance(d, list) else d[k]
    if value is KeyError:
        del d[keys[-1]]
    elif isinstance(d, list):
        d[int(keys[-1])] = value
    else:
        d[keys[-1]] = value


BAD = [
    ("inertia_kgm2", [0.012, 0.047, 0.045, 0.03, 0.0, 0.0], r"^inertia_kgm2 = \[0\.012, .*: not positive definite"),
    ("inertia_kgm2", [0.012, 0.047, 0.1, 0.0, 0.0, 0.0], r"^inertia_kgm2 = .*largest principal moment 0\.1 exceeds "
     r"the sum of the other two, 0\.059 kg m\^2 \(triangle inequality"),
    ("truth.inertia_error_kgm2", [0.0, 0.0, 0.05, 0.0, 0.0, 0.0], r"^truth\.inertia_error_kgm2: the true inertia"
     r".*no rigid body's"),
    ("wheels.nominal_axes", [[1, 0, 0], [0, 1, 0], [1, 1, 0], [1, -1, 0]],
     r"^wheels\.nominal_axes = \[\[1, 0, 0\].*do not span three axes.*must be >= 0\.001"),
    ("wheels.nominal_axes", [[0, 0, 1]] * 4, r"^wheels\.nominal_axes = .*do not span three axes"),
    ("star_tracker.rate_limit_deg_s", 0, r"^star_tracker\.rate_limit_deg_s = 0: must be > 0 and <= 30 deg/s$"),
    ("star_tracker.rate_limit_deg_s", -0.1, r"^star_tracker\.rate_limit_deg_s = -0\.1: must be > 0"),
    ("wheels.speed_limit_rpm", -5, r"^wheels\.speed_limit_rpm = -5: must be > 0 and <= 100000 rpm$"),
    ("wheels.tach_noise_rpm", KeyError, r"^wheels\.tach_noise_rpm: missing \(.*> 0 and <= 1000 rpm\)"),
    ("inertia_kgm2", KeyError, r"^inertia_kgm2: missing"),
    ("gyro", KeyError, r"^gyro: missing"),
    ("wheels.tach_noise", 10.0, r"^wheels\.tach_noise: unknown key \(wheels takes: count, .*tach_noise_rpm"),
    ("colour", "red", r"^colour: unknown key"),
    ("inertia_kgm2.1", float("nan"), r"^inertia_kgm2\[1\] = nan: must be a finite number, from -10000 to 10000"),
    ("wheels.torque_limit_nm", float("inf"), r"^wheels\.torque_limit_nm = inf: must be a finite number, > 0 and "
     r"<= 10 N m$"),
    ("star_tracker.sigma_arcsec.2", -float("inf"), r"^star_tracker\.sigma_arcsec\[2\] = -inf: must be a finite"),
    ("uncertainty.misalignment_sigma_deg", float("nan"), r"^uncertainty\.misalignment_sigma_deg = nan"),
    ("wheels.count", "4", r'^wheels\.count = "4": must be a whole number from 3 to 8$'),
    ("wheels.count", 9, r"^wheels\.count = 9: must be a whole number from 3 to 8$"),
    ("mass_kg", True, r"^mass_kg = true: must be a number, > 0 and <= 2000 kg$"),
    ("mass_kg", "4", r'^mass_kg = "4": must be a number'),
    ("inertia_kgm2", [0.012, 0.047], r"^inertia_kgm2 = \[0\.012, 0\.047\]: must be a list of 6 numbers"),
    ("wheels", [1, 2], r"^wheels = \[1, 2\]: must be an object"),
    ("magnetorquers", {"axes": [[1, 0, 0], [0, 1, 0], [1, 1, 0]], "dipole_limit_am2": 0.2},
     r"^magnetorquers\.axes = .*do not span three axes"),
    ("orbit.state.epoch_utc", "19 Dec 2016", r'^orbit\.state\.epoch_utc = "19 Dec 2016": must be a UTC time'),
    ("partner.relay_delay_s", [3.0, 2.0], r"^partner\.relay_delay_s = \[3, 2\]: must be \[min, max\]"),
    ("format", "fps-bps-params/1", r'^format = "fps-bps-params/1": must be "fps-spacecraft/1"$'),
    ("mass_kg", 10 ** 400, r"^mass_kg = 100000\.\.\.000 \(401 digits\): must be a finite number, > 0 and <= 2000 kg$"),
    ("inertia_kgm2.0", -10 ** 400, r"^inertia_kgm2\[0\] = -100000\.\.\.000 \(401 digits\): must be a finite number"),
    ("wheels.count", 10 ** 400, r"^wheels\.count = 100000\.\.\.000 \(401 digits\): must be a whole number from 3"),
    ("wheels.count", float("inf"), r"^wheels\.count = inf: must be a whole number from 3 to 8$"),
    ("wheels.count", float("nan"), r"^wheels\.count = nan: must be a whole number from 3 to 8$"),
    ("name", [[[[[[[[[[["x"]]]]]]]]]]], r"^name = \[\[\[\[\[\[\[\[\[\.\.\.\]\]\]\]\]\]\]\]\]: must be a non-empty"),
]


@pytest.mark.parametrize("path, value, msg", BAD, ids=["%s=%r" % (b[0], b[1])[:40] for b in BAD])
def test_bad_input_names_the_key_the_value_and_the_range(path, value, msg):
    d = raw()
    _set(d, path, value)
    with pytest.raises(ValueError) as exc:
        sc.check(d)
    assert re.search(msg, str(exc.value)), str(exc.value)


def test_check_normalises_without_touching_its_input():
    d = raw()
    d["mass_kg"] = 4
    d.pop("truth")
    d.pop("sources")
    d["partner"] = None
    before = copy.deepcopy(d)
    out = sc.check(d)
    assert d == before
    assert isinstance(out["mass_kg"], float) and isinstance(out["wheels"]["count"], int)
    assert out["truth"] is None and out["partner"] is None and out["sources"] == {}
    assert all(isinstance(x, float) for a in out["wheels"]["nominal_axes"] for x in a)
    with pytest.raises(ValueError, match="must be a JSON object"):
        sc.check([])


def test_load_refuses_bad_files_naming_them(tmp_path):
    f = tmp_path / "dup.json"
    f.write_text('{"format": "a", "format": "b"}')
    with pytest.raises(ValueError, match="dup.json.*key \"format\" appears twice"):
        sc.load(str(f))
    f.write_text(json.dumps(raw()).replace('"rate_hz": 1.0}', '"rate_hz": NaN}', 1))
    with pytest.raises(ValueError, match=r"spacecraft file .*dup\.json: star_tracker\.rate_hz = nan"):
        sc.load(str(f))
    for bad, msg in (("nope", "neither a preset"), (str(tmp_path / "missing.json"), "cannot read it"),
                     (str(tmp_path), "cannot read it"), ("", "name a preset")):
        with pytest.raises(ValueError, match=msg):
            sc.load(bad)
    with pytest.raises(ValueError, match="no preset"):
        sc.preset_path("nope")


# --- the CLI --------------------------------------------------------------------------------------------------
def run(capsys, *argv):
    capsys.readouterr()
    try:
        rc = cli.main(["spacecraft"] + [str(a) for a in argv])
    except SystemExit as e:
        rc = e.code
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


def test_cli_list_show_check_template_schema(capsys, tmp_path):
    rc, out, _ = run(capsys, "list")
    assert rc == 0 and [line.split()[0] for line in out.splitlines()] == list(PRESETS)
    rc, out, _ = run(capsys, "show", "thesis-3u")
    assert rc == 0
    assert re.search(r"^wheels\.speed_limit_rpm +10000 +rpm$", out, re.M)
    assert re.search(r"^inertia_kgm2 +\[0\.012, 0\.047, 0\.045, 0\.001, 0\.002, 0\.003\] +kg m\^2$", out, re.M)
    assert re.search(r"^magnetorquers.dipole_limit_am2 +0.3 +A m\^2$", out, re.M) and "sources:" in out
    rc, out, _ = run(capsys, "show", "generic-6u", "--json")
    assert rc == 0 and json.loads(out) == sc.load("generic-6u")
    mine = tmp_path / "mine.json"
    rc, out, _ = run(capsys, "template", "generic-12u", "-o", mine)
    assert rc == 0 and "wrote" in out
    assert mine.read_bytes() == open(sc.preset_path("generic-12u"), "rb").read()
    rc, out, _ = run(capsys, "template", "thesis-3u", "-o", "-")
    assert rc == 0 and json.loads(out) == raw()
    rc, out, err = run(capsys, "check", mine)
    assert rc == 0 and out.startswith("ok: %s: generic-12u, 4 wheels" % mine) and err == ""
    rc, out, _ = run(capsys, "schema", "--json")
    keys = [r["key"] for r in json.loads(out)]
    assert rc == 0 and keys == [e["path"] for e in sc.SCHEMA]
    for argv in ([], ["--help"], ["check", "--help"], ["template", "--help"]):
        rc, out, err = run(capsys, *argv)
        assert rc in (0, 2) and "usage: fps spacecraft" in out + err
    rc, out, _ = run(capsys, "--help")
    assert "_kgm2 kg m^2" in out and "_rpm rev/min" in out


def test_cli_bad_input_exits_2_with_the_checker_message(capsys, tmp_path):
    bad = tmp_path / "bad.json"
    d = raw()
    d["wheels"]["speed_limit_rpm"] = -5
    bad.write_text(json.dumps(d))
    rc, out, err = run(capsys, "check", bad)
    assert rc == 2 and out == ""
    assert err.strip() == "fps spacecraft: error: spacecraft file %s: wheels.speed_limit_rpm = -5: must be > 0 " \
                          "and <= 100000 rpm" % bad
    files = {"garbage": b"\x00\xff{{", "text": b"hello {", "empty": b"", "list": b"[1, 2]",
             "nan": b'{"inertia_kgm2": [NaN]}'}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    (tmp_path / "folder").mkdir()
    cases = [(("check", tmp_path / "garbage"), "not a text file"), (("check", tmp_path / "text"), "not valid JSON"),
             (("check", tmp_path / "empty"), "not valid JSON"), (("check", tmp_path / "list"), "a JSON object"),
             (("check", tmp_path / "nan"), "format: missing"),
             (("check", tmp_path / "folder"), "cannot read it"), (("check", tmp_path / "missing.json"), "cannot read"),
             (("check", ""), "name a preset"), (("check", "nope"), "neither a preset"),
             (("show", tmp_path / "text"), "not valid JSON"), (("show", "nope"), "neither a preset"),
             (("template", "nope", "-o", tmp_path / "x.json"), "no preset"),
             (("template", "thesis-3u", "-o", tmp_path / "no" / "x.json"), "its folder does not exist"),
             (("template", "thesis-3u", "-o", tmp_path / "folder"), "is a folder"),
             (("template", "thesis-3u"), "required"), (("nope",), "invalid choice")]
    for argv, msg in cases:
        rc, out, err = run(capsys, *argv)
        assert rc == 2 and msg in err, (argv, rc, err)
        assert err.strip().splitlines()[-1].startswith("fps"), (argv, err)
    assert sorted(os.listdir(tmp_path)) == sorted(list(files) + ["bad.json", "folder"])


# --- MicroPython, the doc -------------------------------------------------------------------------------------
def _lines(exe):
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    r = subprocess.run([exe, MP_SCRIPT], capture_output=True, text=True, timeout=60, env=env, cwd="/")
    assert r.returncode == 0, r.stderr
    return r.stdout.splitlines()


_NUM = re.compile(r"-?\d+\.\d+(?:e[-+]?\d+)?|-?\d+e[-+]?\d+")


def test_the_checker_gives_the_same_results_under_micropython():
    """Line for line the same; a float may differ in its last bit where MicroPython's decimal parser is not
    correctly rounded (it reads "97.6" as 97.59999999999999 and "0.6124" as 0.6124000000000001), but thesis-3u's
    figures are read exactly."""
    mp, cp = _lines(MICROPYTHON), _lines(sys.executable)
    assert len(mp) == len(cp) > 50
    for a, b in zip(mp, cp):
        if a.startswith("thesis-3u") or not a.startswith(PRESETS):
            assert a == b
            continue
        na, nb = [float(x) for x in _NUM.findall(a)], [float(x) for x in _NUM.findall(b)]
        assert _NUM.sub("#", a) == _NUM.sub("#", b) and len(na) == len(nb)
        assert all(abs(x - y) <= 4e-16 * abs(y) for x, y in zip(na, nb)), (a, b)
    refused = [line for line in cp if line.startswith("refused ")]
    accepted = [line for line in cp if line.startswith("accepted ")]
    assert len(refused) == 41 and len(accepted) == 4 and "accepted integers True" in accepted


def test_spacecraft_md_is_fresh(capsys):
    rc, out, _ = run(capsys, "schema")
    assert rc == 0
    with open(os.path.join(ROOT, "docs", "SPACECRAFT.md")) as f:
        assert f.read() == out, "docs/SPACECRAFT.md is stale: run fps spacecraft schema > docs/SPACECRAFT.md"
    for key in (e["path"] for e in sc.SCHEMA):
        assert "`%s`" % key in out
    for must in ("| `wheels.speed_limit_rpm` ", "| > 0 and <= 100000 |", "-∫ x y dm", "## Presets", "`thesis-3u`"):
        assert must in out.replace("&nbsp;", "") or must in out
