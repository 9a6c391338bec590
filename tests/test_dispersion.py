"""The simulated vehicle: a truth block stays fixed, a file without one flies a vehicle drawn from its seed within
its uncertainty (never its own figures), the draws replay by seed and keep the file's spread, and every command
records the vehicle it flew."""

import json

import numpy as np
import pytest

from emulator.spacecraft import dispersion
from ground import cli
from ground.adcs import runs
from protocol import spacecraft as sf


def test_a_truth_block_stays_and_nominal_flies_the_figures():
    d = sf.load("thesis-3u")
    f, rec = dispersion.flown(d, 7)
    assert f == d and rec["kind"] == "truth block" and rec["truth"] == d["truth"]
    f, rec = dispersion.flown(d, 7, "nominal")
    assert f["truth"] is None and rec["kind"] == "nominal"
    f, rec = dispersion.flown(d, 7, "drawn")
    assert rec["kind"] == "drawn" and rec["seed"] == 7 and f["truth"] != d["truth"]
    assert d["truth"] == sf.load("thesis-3u")["truth"]          # the file itself is left as it was


@pytest.mark.parametrize("name", ["generic-6u", "generic-12u"])
def test_a_file_without_a_truth_block_flies_a_drawn_vehicle(name):
    d = sf.load(name)
    assert d["truth"] is None
    a, ra = dispersion.flown(d, 3)
    b, _ = dispersion.flown(d, 3)
    c, _ = dispersion.flown(d, 4)
    assert ra["kind"] == "drawn" and a["truth"] is not None
    assert a == b and a["truth"] != c["truth"]                 # --seed N replays vehicle N
    assert any(abs(e) > 0 for e in a["truth"]["inertia_error_kgm2"])


def test_drawn_vehicles_are_plausible_and_spread_as_the_file_says():
    d = sf.load("generic-12u")
    u = d["uncertainty"]
    t = [dispersion.draw_truth(d, s) for s in range(300)]
    raw = json.load(open(sf.preset_path("generic-12u")))
    for s in (0, 1, 2):
        sf.check(dict(raw, truth=t[s]))                        # the checker takes a drawn truth block
    dj = np.array([x["inertia_error_kgm2"] for x in t])
    assert np.allclose(dj.std(axis=0), u["inertia_sigma_kgm2"], rtol=0.15)
    assert np.allclose(dj.mean(axis=0), 0.0, atol=3 * np.array(u["inertia_sigma_kgm2"]) / np.sqrt(300))
    da = np.array([x["delta1_error_deg"] + x["delta2_error_deg"] for x in t])
    assert abs(da.std() - u["misalignment_sigma_deg"]) < 0.1 * u["misalignment_sigma_deg"]
    dm = np.array([x["residual_dipole_error_am2"] for x in t])
    assert abs(dm.std() - u["residual_dipole_sigma_am2"]) < 0.15 * u["residual_dipole_sigma_am2"]
    for x in t:
        j = np.array(d["inertia_kgm2"]) + np.array(x["inertia_error_kgm2"])
        lam = sf.principal_moments(list(j))
        assert lam[0] > 0 and lam[2] <= lam[0] + lam[1]
        assert all(a + b > 0 for a, b in zip(d["wheels"]["rotor_inertia_kgm2"], x["rotor_inertia_error_kgm2"]))


def test_a_too_wide_uncertainty_is_a_clear_error():
    raw = json.load(open(sf.preset_path("generic-6u")))
    raw["uncertainty"]["inertia_sigma_kgm2"] = [10.0, 10.0, 10.0, 10.0, 10.0, 10.0]
    d = sf.check(raw)
    with pytest.raises(ValueError, match="inertia_sigma_kgm2 is too wide"):
        dispersion.draw_truth(d, 0)


def test_the_scale_spread_is_taken_from_the_draws():
    d = sf.load("generic-12u")
    rho2 = (d["uncertainty"]["inertia_sigma_kgm2"][0] / d["inertia_kgm2"][0]) ** 2
    v = dispersion.scale_second_moment(d)
    assert rho2 < v < 1.3 * rho2           # s = 1 / (1 + e): a little more than first order at 10 %


def test_each_run_of_a_campaign_flies_its_own_vehicle():
    d = sf.load("generic-12u")
    a = runs.run_apkf(0, None, params={"duration_s": 20.0}, spacecraft=d, keep_series=False)
    b = runs.run_apkf(1, None, params={"duration_s": 20.0}, spacecraft=d, keep_series=False)
    assert a["vehicle"]["kind"] == b["vehicle"]["kind"] == "drawn"
    assert a["vehicle"]["truth"] != b["vehicle"]["truth"]
    assert a["vehicle"]["truth"] == dispersion.draw_truth(d, 0)
    n = runs.run_apkf(0, None, params={"duration_s": 20.0}, spacecraft=d, keep_series=False, vehicle="nominal")
    assert n["vehicle"]["kind"] == "nominal" and n["vehicle"]["truth"] is None


def test_the_cli_records_the_vehicle_and_refuses_a_bad_choice(tmp_path, capsys):
    out = tmp_path / "c"
    assert cli.main(["adcs", "mekf", "--spacecraft", "generic-12u", "--runs", "1", "--workers", "1", "--quiet",
                     "--no-plots", "--params", str(_short(tmp_path)),
                     "-o", str(out)]) in (0, 1)
    s = json.loads((out / "summary.json").read_text())
    assert s["vehicle"] == "file" and s["per_run"][0]["vehicle"]["kind"] == "drawn"
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        cli.main(["adcs", "mekf", "--vehicle", "average", "-o", str(tmp_path / "d")])
    assert e.value.code == 2
    assert "--vehicle" in capsys.readouterr().err


def _short(tmp_path):
    p = tmp_path / "short.json"
    p.write_text(json.dumps({"duration_s": 20}))
    return p
