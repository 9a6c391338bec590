"""fps adcs apkf|mekf --spacecraft: the truth, the filters' model, priors and initial P come from a spacecraft file
(protocol.spacecraft); thesis-3u gives the thesis's runs bit for bit; the summary records the file; bad input
exits 2 naming it."""

import json
import os

import numpy as np
import pytest

from emulator.spacecraft import scenario
from ground import cli
from ground.adcs import apkf, runs
from protocol import spacecraft as sf

SHORT = {"duration_s": 60.0}


def _same(a, b):
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_thesis_3u_is_the_default_bit_for_bit():
    d = sf.load("thesis-3u")
    a = scenario.simulate(1, 3, duration=60, gyro=True)
    b = scenario.simulate(1, 3, duration=60, gyro=True, spacecraft=d)
    for k, v in a.items():
        if isinstance(v, np.ndarray):
            assert np.array_equal(v, b[k]), k
    for k, v in a["truth"].items():
        assert np.array_equal(v, b["truth"][k]), k
    assert _same(runs.run_mekf(3, params=SHORT), runs.run_mekf(3, params=SHORT, spacecraft=d))
    assert _same(runs.run_apkf(3, params=SHORT, form="thesis"),
                 runs.run_apkf(3, params=SHORT, spacecraft=d, form="thesis"))
    m, m0 = runs.apkf_model(d), apkf.Model()
    assert np.array_equal(apkf.initial_covariance(m), apkf.initial_covariance(m0))
    # the consistent form adds the file's Jxx spread (thesis-3u: 5e-3 kg m^2), which the thesis holds exact
    x0 = apkf.initial_state([0, 0, 0, 1.0], np.zeros(3), np.zeros(4))
    p = np.zeros(apkf.N)
    p[9:14], p[25:29] = x0[10:15], x0[26:30]
    assert np.allclose(apkf.initial_covariance(m, x0) - apkf.initial_covariance(m0),
                       m.scale_var * np.outer(p, p), rtol=0, atol=1e-18)
    assert 0.1 < m.scale_var < 0.2           # (5e-3 / 12e-3)^2 = 0.17 to first order
    assert m.jxx == m0.jxx and np.array_equal(m.R_st, m0.R_st) and m.R_rw == m0.R_rw
    assert np.array_equal(m.c0, m0.c0) and np.array_equal(m.c1, m0.c1) and np.array_equal(m.c2, m0.c2)


def test_generic_6u_truth_and_priors_are_the_6u():
    d = sf.load("generic-6u")
    o = scenario.simulate(1, 0, duration=10, spacecraft=d)
    s = o["spacecraft"]
    assert np.array_equal(s.j, np.array(sf.inertia_matrix(d, True)))      # no truth block: the figures
    assert np.array_equal(s.wheels.c, np.array(sf.wheel_axes(d, True)).T)
    assert s.wheels.j.tolist() == d["wheels"]["rotor_inertia_kgm2"] and s.wheels.p.noise_rpm == 2.0
    assert s.dipole.tolist() == d["residual_dipole_am2"]
    assert abs(o["truth"]["scale"] - 1.0) < 1e-3                         # s = Jxx_ref / Jxx(with rotors) ~ 1
    m = runs.apkf_model(d)
    u = d["uncertainty"]
    assert m.jxx == d["inertia_kgm2"][0] and np.allclose(np.sqrt(np.diag(m.R_st)) * 2 / apkf.quat.RAD_PER_ARCSEC,
                                                         d["star_tracker"]["sigma_arcsec"])
    assert np.allclose(m.c0, np.array(sf.wheel_axes(d)).T)
    p0 = np.diag(apkf.initial_covariance(m))
    assert np.allclose(np.sqrt(p0[apkf.IJ]), u["inertia_sigma_kgm2"][1:])
    assert np.allclose(np.sqrt(p0[apkf.IJR]), u["rotor_inertia_sigma_kgm2"])
    assert np.allclose(np.sqrt(p0[apkf.IW]), np.radians(u["rate_sigma_deg_s"]))
    k0, f = runs._start_apkf(scenario.simulate(1, 0, duration=20, spacecraft=d), 1, spacecraft=d)
    assert f.x[10:15].tolist() == d["inertia_kgm2"][1:] and f.x[26:30].tolist() == d["wheels"]["rotor_inertia_kgm2"]
    assert f.model.jxx == d["inertia_kgm2"][0]
    pd = scenario.PD(**scenario.truth_setup(d)["pd"])
    assert np.array_equal(pd.j, np.array(sf.inertia_matrix(d)))


def test_a_short_6u_apkf_run_converges_and_the_summary_names_the_file(tmp_path, capsys):
    out = str(tmp_path / "c")
    rc = cli.main(["adcs", "apkf", "--spacecraft", "generic-6u", "--runs", "1", "--workers", "1", "--quiet",
                   "--no-plots", "-o", out, "--params", _params(tmp_path, {"duration_s": 300.0})])
    assert rc == 0, capsys.readouterr().err
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    assert s["runs_diverged"] == 0 and s["runs"] == 1
    rec = s["spacecraft"]
    assert rec["source"] == "generic-6u" and rec["name"] == "generic-6u" and len(rec["sha256"]) == 12


def _params(tmp_path, d):
    p = str(tmp_path / "params.json")
    with open(p, "w") as f:
        json.dump(d, f)
    return p


@pytest.mark.parametrize("sub", ["apkf", "mekf"])
def test_bad_spacecraft_exits_2_naming_it(tmp_path, capsys, sub):
    out = str(tmp_path / "c")
    assert cli.main(["adcs", sub, "--spacecraft", "nope-7u", "-o", out, "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "nope-7u" in err and "generic-6u" in err and "Traceback" not in err
    bad = sf.load("generic-6u")
    bad["inertia_kgm2"][0] = -1.0
    path = str(tmp_path / "bad.json")
    with open(path, "w") as f:
        json.dump(bad, f)
    assert cli.main(["adcs", sub, "--spacecraft", path, "-o", out, "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and "inertia_kgm2" in err
    p = _params(tmp_path, {"inertia_kgm2": [0.012, 0.047, 0.045, 0.001, 0.002, 0.003]})
    assert cli.main(["adcs", sub, "--spacecraft", "generic-6u", "--params", p, "-o", out, "--workers", "1"]) == 2
    assert "--params sets inertia_kgm2" in capsys.readouterr().err


# --- fps adcs stkf | bps | sweep | can, fps system, fps distfile generate --source bps ---------------------------
VOLATILE = {"wall_s", "step_us_mean", "step_us_median", "speed_x_realtime", "status_cycle_us", "source"}


def _strip(v):
    """``v`` without its wall-clock figures (and the spacecraft record's ``source``, the name as given)."""
    if isinstance(v, dict):
        return {k: _strip(x) for k, x in v.items() if k not in VOLATILE}
    if isinstance(v, list):
        return [_strip(x) for x in v]
    return v


def _json(path):
    with open(path) as f:
        return _strip(json.load(f))


def _npz(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files if k not in VOLATILE}


def _same_npz(a, b):
    a, b = _npz(a), _npz(b)
    assert sorted(a) == sorted(b)
    for k in a:
        assert np.array_equal(a[k], b[k], equal_nan=True), k


@pytest.fixture(scope="module")
def thesis_copy(tmp_path_factory):
    """thesis-3u as a file of its own (given by path, not by name)."""
    p = tmp_path_factory.mktemp("sc") / "my-3u.json"
    p.write_text(json.dumps(sf.load("thesis-3u")))
    return str(p)


@pytest.fixture(scope="module")
def perfect_params(tmp_path_factory):
    p = tmp_path_factory.mktemp("pp") / "params.json"
    p.write_text(json.dumps(scenario.truth_params(scenario.pointing_world(2, 0).sc)))
    return str(p)


def _three(tmp_path, argv, thesis_copy):
    """Run ``fps argv -o DIR`` without --spacecraft, with thesis-3u and with thesis-3u's copy; the folders."""
    outs = []
    for extra in ([], ["--spacecraft", "thesis-3u"], ["--spacecraft", thesis_copy]):
        outs.append(tmp_path / ("run%d" % len(outs)))
        assert cli.main(argv + extra + ["-o", str(outs[-1])]) in (0, 3)
    return outs


def test_stkf_thesis_3u_is_the_default_bit_for_bit_and_the_6u_flies_its_figures(tmp_path, thesis_copy):
    argv = ["adcs", "stkf", "--case", "2", "--duration", "15", "--truth", "two-body", "--attitude", "apkf",
            "--workers", "1", "--quiet", "--no-plots"]
    outs = _three(tmp_path, argv, thesis_copy)
    ref = _json(outs[0] / "run_0000" / "result.json")
    for o in outs[1:]:
        assert _json(o / "run_0000" / "result.json") == ref
        _same_npz(outs[0] / "run_0000" / "history.npz", o / "run_0000" / "history.npz")
    assert _json(outs[1] / "summary.json") == _json(outs[0] / "summary.json")
    assert cli.main(argv + ["--spacecraft", "generic-6u", "-o", str(tmp_path / "six")]) == 0
    six = _json(tmp_path / "six" / "run_0000" / "result.json")
    assert six["spacecraft"] == "generic-6u" and ref["spacecraft"] == "thesis-3u"
    assert six["final_sigma_ra_m"] < 0.5 * ref["final_sigma_ra_m"]           # its GNSS: 10 m against 30 m
    assert _json(tmp_path / "six" / "summary.json")["spacecraft"]["name"] == "generic-6u"


def test_bps_and_sweep_thesis_3u_is_the_default_bit_for_bit(tmp_path, thesis_copy, perfect_params):
    d = sf.load("thesis-3u")
    from ground.adcs import body_pointing as bps
    assert _same(bps.calibrate(2, sets=1), bps.calibrate(2, sets=1, spacecraft=d))
    cache = str(tmp_path / "cache")
    argv = ["adcs", "bps", "--ts", "4", "--duration", "5", "--truth", "two-body", "--satb-gnss", "--params",
            perfect_params, "--cache-dir", cache, "--quiet", "--no-plots"]
    outs = _three(tmp_path, argv, thesis_copy)
    for o in outs[1:]:
        assert _json(o / "summary.json") == _json(outs[0] / "summary.json")
        _same_npz(outs[0] / "history.npz", o / "history.npz")
    argv = ["adcs", "sweep", "--ts", "4:8:4", "--duration", "3", "--truth", "two-body", "--params", perfect_params,
            "--cache-dir", cache, "--workers", "1", "--quiet", "--no-plots"]
    outs = _three(tmp_path / "sweep", argv, thesis_copy)
    for o in outs[1:]:
        assert _json(o / "summary.json") == _json(outs[0] / "summary.json")


def test_bps_on_the_6u_calibrates_and_points_the_6u(tmp_path, capsys, perfect_params):
    d = sf.load("generic-6u")
    out = tmp_path / "six"
    assert cli.main(["adcs", "bps", "--spacecraft", "generic-6u", "--duration", "20", "--truth", "two-body",
                     "--cache-dir", str(tmp_path / "cache"), "--quiet", "--no-plots", "-o", str(out)]) in (0, 3)
    s = _json(out / "summary.json")
    assert s["spacecraft"]["name"] == "generic-6u" and s["complete"] and s["tach_noise_rpm"] == 2.0
    p = json.loads((out / "params.json").read_text())
    assert np.allclose(p["x"]["jrw_kgm2"], d["wheels"]["rotor_inertia_kgm2"], rtol=0.2)     # the 6U's wheels
    assert abs(p["jxx_ref_kgm2"] - d["inertia_kgm2"][0]) < 1e-12                           # its Jxx reference
    assert s["pointing_3sigma_arcsec"] < 300                       # the +z laser axis tracks SatB
    # the thesis's parameter file does not describe the 6U's wheels
    assert cli.main(["adcs", "bps", "--spacecraft", "generic-6u", "--params", perfect_params, "--duration", "5",
                     "-o", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "x.jrw_kgm2[0] = " in err and "must be from 4.8e-06 to 0.00048 kg m^2" in err
    assert not (tmp_path / "x").exists()


def test_can_thesis_3u_is_the_default_bit_for_bit_and_the_firmware_gets_the_6u(tmp_path, thesis_copy):
    argv = ["adcs", "can", "--runtime", "cpython", "--session", "4", "--satb-gnss", "--quiet", "--no-plots"]
    outs = _three(tmp_path, argv, thesis_copy)
    for o in outs[1:]:
        _same_npz(outs[0] / "history.npz", o / "history.npz")
    from emulator.adcs_session import AdcsSession
    d = sf.load("generic-6u")
    s = AdcsSession(runtime="cpython", duration_s=2, spacecraft=d)
    c = s.config()
    assert np.allclose(c["wheel_axes"], np.array(sf.wheel_axes(d)).T) and c["laser_axis"] == [0.0, 0.0, 1.0]
    assert c["tach_noise_rpm"] == 2.0 and c["torque_max"] == 0.002 and c["gnss_sigma"] == [10.0, 0.1]
    assert c["star_tracker_sigma_arcsec"] == [6.0, 6.0, 40.0] and c["beacon_sigma_arcsec"] == pytest.approx(30.0)
    assert c["stkf_P0"] == [1e6] * 3 + [1.0] * 3 + [1e6] * 3 + [1.0] * 3
    assert np.allclose(c["params"]["x"]["jrw_kgm2"], d["wheels"]["rotor_inertia_kgm2"], rtol=1e-9)   # its truth
    assert np.isclose(c["params"]["jxx_ref_kgm2"], d["inertia_kgm2"][0] + 0.0, rtol=1e-9)
    assert s.sc.j[0, 1] == d["inertia_kgm2"][3] and s.wheels.p.noise_rpm == 2.0
    from firmware.adcs.app import App
    app = App(c)                                     # the flight app takes the 6U's configuration
    assert app.modes.laser == (0.0, 0.0, 1.0) and np.allclose(app.act.C, np.array(sf.wheel_axes(d)).T.ravel(), atol=1e-6)


def test_system_thesis_3u_is_the_default_bit_for_bit(perfect_params):
    from ground import system
    from ground.adcs import body_pointing as bps
    spec = {"ts": 4.0, "satb_gnss": True, "adcs_duration_s": 3.0, "seed": 1, "truth": "two-body",
            "cache_dir": None}
    params = json.loads(open(perfect_params).read())
    runs_ = [system._ground_run(dict(spec, spacecraft=d), params) for d in (None, sf.load("thesis-3u"))]
    for (ra, ha, ea), (rb, hb, eb) in zip(runs_, runs_[1:]):
        assert _strip(ra) == _strip(rb) and np.array_equal(ea, eb, equal_nan=True)
        for k in ha:
            assert np.array_equal(ha[k], hb[k], equal_nan=True), k
    assert bps.check_params(params, spacecraft=sf.load("thesis-3u"))[2] == params["jxx_ref_kgm2"]


def _five_wheels(tmp_path):
    d = sf.load("generic-6u")
    w = d["wheels"]
    w.update(count=5, nominal_axes=w["nominal_axes"] + [[0, 0, 1]], delta1_deg=[0.0] * 5, delta2_deg=[0.0] * 5,
             rotor_inertia_kgm2=w["rotor_inertia_kgm2"] + [4.8e-5])
    p = tmp_path / "five.json"
    p.write_text(json.dumps(sf.check(d)))
    return str(p)


@pytest.mark.parametrize("argv", [
    ["adcs", "stkf", "--case", "1", "--attitude", "apkf"], ["adcs", "bps"], ["adcs", "sweep"], ["adcs", "can"],
    ["system", "--adcs", "ground"], ["distfile", "generate", "--source", "bps", "--duration", "5"]])
def test_bad_spacecraft_exits_2_on_every_command(tmp_path, capsys, argv):
    bad = sf.load("generic-6u")
    bad["star_tracker"]["sigma_arcsec"][1] = float("nan")
    path = tmp_path / "nan.json"
    path.write_text(json.dumps(bad))
    cases = (("nope-7u", "neither a preset"), ("generic-12u", "partner = null"), (str(path), "sigma_arcsec[1] = nan"),
             (_five_wheels(tmp_path), "wheels.count = 5"))
    text = json.dumps(sf.load("generic-6u"))
    big = text.replace('"mass_kg": 12.0', '"mass_kg": 1' + "0" * 400)
    for name, bad, words in (("big", big, "mass_kg = 100000...000 (401 digits): must be a finite number, > 0 and "
                                          "<= 2000 kg"),
                             ("string", text.replace('"mass_kg": 12.0', '"mass_kg": "12"'), 'mass_kg = "12": must be '
                              "a number"),
                             ("deep", "[" * 100000 + "]" * 100000, "its arrays and objects nest too deeply to read")):
        (tmp_path / name).write_text(bad)
        cases += ((str(tmp_path / name), "--spacecraft %s: %s" % (tmp_path / name, words)),)
    for sc, words in cases:
        out = tmp_path / "out"
        assert cli.main(argv + ["--spacecraft", sc, "-o", str(out)]) == 2, sc
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err, err
        assert "--spacecraft %s: " % sc in err and words in err, err
        assert not out.exists()
