"""fps adcs campaign: the flight world over vehicles drawn from one file; its shares with their intervals, the
worst vehicles with their seeds, and a folder that resumes without flying a finished vehicle again."""

import json
import os

import pytest

from ground import cli
from ground.adcs import population

SHORT = ["adcs", "campaign", "--spacecraft", "generic-6u", "--orbits", "0.05", "--workers", "1", "--quiet",
         "--no-plots"]


def test_the_wilson_interval():
    lo, hi = population.wilson(95, 100)
    assert 0.885 < lo < 0.890 and 0.977 < hi < 0.980
    lo, hi = population.wilson(2, 2)
    assert hi == pytest.approx(1.0) and 0.3 < lo < 0.4


def test_a_campaign_resumes_and_refuses_another_campaigns_folder(tmp_path, capsys):
    out = tmp_path / "c"
    rc = cli.main(SHORT + ["--runs", "2", "-o", str(out)])
    s = json.loads((out / "summary.json").read_text())
    # 0.05 orbits hold no pointing pass: every vehicle misses that check, named, and the run exits 3
    assert rc == 3 and s["complete"] and s["runs_done"] == 2 and s["all_checks"]["met"] == 0
    assert s["checks"]["passes"]["met"] == 0 and s["checks"]["passes"]["ci95"][1] < 0.85
    assert all("0 pointing pass(es) after the first orbit" in w["missed"] for w in s["worst"])
    r0 = json.loads((out / "run_0000" / "result.json").read_text())
    r1 = json.loads((out / "run_0001" / "result.json").read_text())
    assert r0["vehicle"]["kind"] == "drawn" and r0["vehicle"]["truth"] != r1["vehicle"]["truth"]
    assert "--vehicle drawn --seed N" in (out / "report.md").read_text()
    # an interrupted campaign: one vehicle's result missing; the same command flies only that one
    os.remove(out / "run_0001" / "result.json")
    t0 = os.stat(out / "run_0000" / "result.json").st_mtime_ns
    capsys.readouterr()
    assert cli.main(SHORT + ["--runs", "2", "-o", str(out)]) == 3
    assert "resuming: 1 of 2 vehicles already flown" in capsys.readouterr().err
    assert os.stat(out / "run_0000" / "result.json").st_mtime_ns == t0
    assert json.loads((out / "run_0001" / "result.json").read_text())["vehicle"] == r1["vehicle"]
    assert json.loads((out / "summary.json").read_text())["runs_done"] == 2
    # other options into the same folder: refused, nothing touched
    assert cli.main(SHORT + ["--runs", "3", "-o", str(out)]) == 2
    assert "holds another campaign (it differs in seeds)" in capsys.readouterr().err
    assert os.stat(out / "run_0000" / "result.json").st_mtime_ns == t0


def test_a_vehicle_whose_run_failed_counts_as_a_miss():
    """A run that failed (its APKF diverged on that vehicle) is in the shares as a vehicle that met no check,
    with its cause, not left out of them."""
    from ground.adcs import population
    ok = {"seed": 0, "ok": True, "checks": {"pointing": {"ok": True, "what": "3σ pointing <= 150"}},
          "figures": {"pointing_3sigma_arcsec": 15.0}, "vehicle": {}, "line_of_sight": True}
    bad = {"seed": 1, "error": "FloatingPointError: APKF diverged at t = 554 s: P is not positive definite"}
    s = population.aggregate([ok, bad], {})
    assert s["all_checks"]["met"] == 1 and s["all_checks"]["of"] == 2 and s["all_checks"]["share"] == 0.5
    assert s["checks"]["pointing"]["of"] == 2 and s["runs_failed"] == 1
    assert s["failures"] == [{"seed": 1, "error": bad["error"]}]


def test_a_residual_dipole_beyond_the_rods_is_named_as_the_wheels_miss_cause():
    """The cause a vehicle shows: its residual dipole (the file's plus the drawn error) needs more of a rod than
    its limit, and the wheels' check missed; named only then, with the shares against the limit."""
    from protocol import spacecraft as sf
    d = sf.load("thesis-3u")
    lim = d["magnetorquers"]["dipole_limit_am2"]
    d = dict(d, truth=dict(d.get("truth") or {}, residual_dipole_error_am2=[0.0, 1.5 * lim, 0.0]))
    r = population.dipole_beyond_rods(d)
    assert r["beyond"] and abs(r["shares_am2"][1] - (d["residual_dipole_am2"][1] + 1.5 * lim)) < 1e-12
    missed = {"checks": {"wheels": {"ok": False, "what": "wheels"}}, "mtq_duty": 1.0}
    causes = population.miss_causes(missed, d)
    assert len(causes) == 1 and "beyond the rods' ±%g A m^2" % lim in causes[0]
    assert population.miss_causes({"checks": {"wheels": {"ok": True, "what": "wheels"}}}, d) == []
    small = dict(d, truth=dict(d["truth"], residual_dipole_error_am2=[0.0, 0.0, 0.0]),
                 residual_dipole_am2=[0.0, 0.5 * lim, 0.0])
    assert not population.dipole_beyond_rods(small)["beyond"] and population.miss_causes(missed, small) == []
    worst = population.aggregate([dict(missed, seed=3, ok=False, figures={}, vehicle={}, causes=causes)], {})
    assert causes[0] in worst["worst"][0]["missed"]


def test_a_vehicle_held_in_acquire_is_named_with_its_largest_wheel_tilt():
    """A vehicle that missed with its wheels within their limit and spent most of the run in ACQUIRE: the time
    there, the star tracker's blindness and its largest wheel tilt (each wheel's two angles together, the file's
    figures plus its drawn errors) name the cause; not for a vehicle that met every check, nor for one that
    pointed most of the run, nor after a dipole cause."""
    from protocol import spacecraft as sf
    d = sf.load("thesis-3u")
    d = dict(d, truth=dict(d["truth"], delta1_error_deg=[0.0, 24.0 - d["wheels"]["delta1_deg"][1], 0.0, 0.0],
                           delta2_error_deg=[0.0, 7.0 - d["wheels"]["delta2_deg"][1], 0.0, 0.0],
                           residual_dipole_error_am2=[0.0, 0.0, 0.0]))
    held = {"ok": False, "checks": {"wheels": {"ok": True, "what": "wheels"}},
            "time_in_mode_s": {"HOLD": 30.0, "SLEW": 60.0, "POINT": 910.0, "ACQUIRE": 9000.0},
            "star_tracker_blind_share": 0.88}
    causes = population.miss_causes(held, d)
    assert len(causes) == 1 and causes[0].startswith("held in ACQUIRE 90 % of the run (POINT 910 s), the star "
                                                     "tracker blind 88 % of the time, the wheels within their limit")
    assert "largest wheel tilt %.1f deg" % max(25.0, *(abs(a) for a in d["wheels"]["delta1_deg"])) in causes[0]
    assert population.miss_causes(dict(held, ok=True), d) == []
    pointed = dict(held, time_in_mode_s={"POINT": 9000.0, "ACQUIRE": 1000.0})
    assert population.miss_causes(pointed, d) == []


def test_each_figures_mean_over_the_vehicles_is_in_the_summary_and_the_report():
    """The mean row: for a filter's NEES share, the population's share of all its seconds in the band."""
    rs = [{"seed": i, "ok": True, "checks": {"pointing": {"ok": True, "what": "p"}}, "vehicle": {},
           "figures": {"stkf_nees_in_band_share": v, "pointing_3sigma_arcsec": 10.0}} for i, v in enumerate((0.8, 0.9, 1.0))]
    s = population.aggregate(rs, {"spacecraft": {"name": "x", "sha256": "0", "source": "x"}, "runs": 3,
                                  "vehicle_text": "drawn", "orbits": 3, "seeds": [0, 1, 2], "vehicle": "drawn",
                                  "truth": "two-body", "ts_s": 33.0, "satb_gnss": False})
    assert abs(s["figures"]["stkf_nees_in_band_share"]["mean"] - 0.9) < 1e-12
    s["complete"] = True
    text = population.report_md(s)
    assert "| min | median | mean |" in text and "| 0.8 | 0.9 | 0.9 |" in text
