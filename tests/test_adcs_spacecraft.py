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
    for fn in (runs.run_apkf, runs.run_mekf):
        assert _same(fn(3, params=SHORT), fn(3, params=SHORT, spacecraft=d)), fn.__name__
    m, m0 = runs.apkf_model(d), apkf.Model()
    assert np.array_equal(apkf.initial_covariance(m), apkf.initial_covariance(m0))
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
    assert m.jxx == d["inertia_kgm2"][0] and np.allclose(np.sqrt(np.diag(m.R_st)) * 2 / apkf.quat.ARCSEC,
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
