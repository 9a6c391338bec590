"""The beacon camera's misalignment: the spacecraft file's angles, the truth's camera, and the STKF that
estimates them (``stkf.beacon_m``, ``stkf_sim.simulate(beacon_misalignment=...)``)."""

import copy

import numpy as np
import pytest

from emulator.navsensors import Beacon
from emulator.spacecraft import dispersion
from emulator.spacecraft.dynamics import dcm
from ground.adcs import stkf, stkf_sim
from ground.cli import main
from protocol import spacecraft as sf

X = np.concatenate([[6.8e6, 1.0e5, -2.0e5, 10.0, 7600.0, 50.0], [5.0e6, 4.0e6, 1.5e6, -4000.0, 5000.0, 3000.0]])
A = dcm(np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9]))


def _file(sigma_deg=0.1, error_deg=(0.1, -0.05, 0.08), figure_deg=None):
    raw = sf.read(sf.preset_path("thesis-3u"))
    raw["uncertainty"]["beacon_misalignment_sigma_deg"] = sigma_deg
    raw["truth"]["beacon_misalignment_error_deg"] = list(error_deg)
    if figure_deg is not None:
        raw["beacon"]["misalignment_deg"] = list(figure_deg)
    return raw


# --- zero misalignment: the thesis's STKF unchanged ------------------------------------------------------------
def test_zero_misalignment_leaves_the_thesis_stkf_bit_for_bit():
    """thesis-3u (figure, 1 sigma and truth all zero), "ignore": the thesis STKF's figures of a short run."""
    pins = {1: (25.979021788931533, 22.108676329377722, 15.207196642644703, 551.187144842662),
            2: (17.565052223252657, 13.14734191546495, 7.897195589728653, 942.4411779913139)}
    for case, pin in pins.items():
        r, h = stkf_sim.simulate(case, 120.0, seed=5, truth="two-body")
        assert (r["final_sigma_pointing_arcsec"], r["final_error_pointing_arcsec"], float(h["err"][-1, 6]),
                float(h["nees"].sum())) == pin
        assert r["beacon_misalignment"] == "ignore" and r["misalignment_truth_arcsec"] == [0.0, 0.0, 0.0]


def test_at_zero_the_augmented_model_is_the_thesis_model():
    x = np.concatenate([X, np.zeros(3)])
    P_att = np.diag([1e-9, 2e-9, 3e-9])
    h, H = stkf.beacon_m(x, A)
    assert np.array_equal(h, stkf.h_beacon(X, A)) and np.allclose(H[:, :12], stkf.H_beacon(X, A), rtol=0,
                                                                   atol=1e-21)
    assert np.array_equal(H[:, stkf.IM], stkf.skew(h))           # C v ~ v + v x delta
    assert np.array_equal(stkf.R_beacon_m(x, A, 3e-4, P_att), stkf.R_beacon(h, 3e-4, P_att))
    assert np.array_equal(stkf.misalignment_dcm(np.zeros(3)), np.eye(3))
    b0, b1 = Beacon(np.random.default_rng(3)), Beacon(np.random.default_rng(3), misalignment_deg=[0.0, 0.0, 0.0])
    assert b1.C is None and np.array_equal(b0.measure_dcm(X[0:3], X[6:9], A), b1.measure_dcm(X[0:3], X[6:9], A))


# --- the model ------------------------------------------------------------------------------------------------
def test_the_camera_rotation_is_the_small_rotation_of_the_truth():
    delta = np.radians([0.3, -1.2, 2.0])
    assert np.allclose(stkf.misalignment_dcm(delta), stkf_sim.small_rotation(delta), rtol=0, atol=1e-15)
    y = Beacon(np.random.default_rng(0), sigma_arcsec=0.0, misalignment_deg=np.degrees(delta)).measure_dcm(
        X[0:3], X[6:9], A)
    assert np.allclose(y, stkf.beacon_m(np.concatenate([X, delta]), A)[0], rtol=0, atol=1e-15)


@pytest.mark.parametrize("delta_deg", [(0.0, 0.0, 0.0), (0.1, -0.05, 0.08), (2.0, -3.0, 1.5)])
def test_H_against_a_numerical_derivative(delta_deg):
    """H of ``beacon_m`` (and the stacked ``gnss_beacon_m``) against central differences of h over all 15 states:
    10 m in the positions (H ~ 1/rho ~ 3e-7 per m), 10 m/s in the velocities, 1e-5 rad in the angles."""
    x = np.concatenate([X, np.radians(delta_deg)])
    step = np.array([10.0] * 12 + [1e-5] * 3)
    for fn in (stkf.beacon_m, stkf.gnss_beacon_m):
        H = fn(x, A)[1]
        Hn = np.column_stack([(fn(x + e, A)[0] - fn(x - e, A)[0]) / (2 * s) for e, s in zip(np.diag(step), step)])
        assert np.allclose(H, Hn, rtol=1e-6, atol=1e-15)
    assert np.abs(stkf.beacon_m(x, A)[1][:, stkf.IM]).max() > 0.5        # the angles are seen


def test_the_augmented_model_holds_the_angles_constant():
    x = np.concatenate([X, [1e-3, -2e-3, 5e-4]])
    assert np.array_equal(stkf.f_m(x, 1.0)[stkf.IM], x[stkf.IM])
    assert np.array_equal(stkf.f_m(x, 1.0)[:12], stkf.f(X, 1.0)) and np.array_equal(stkf.f_m(X[6:12], 1.0),
                                                                                     stkf.f(X[6:12], 1.0))
    ph, q = stkf.Phi_m(x, 1.0), stkf.Q_m(1.0)
    assert np.array_equal(ph[stkf.IM, stkf.IM], np.eye(3)) and not ph[stkf.IM, :12].any()
    assert np.array_equal(ph[:12, :12], stkf.Phi(X, 1.0)) and not q[stkf.IM].any() and q[:12, :12].any()


# --- the estimate ---------------------------------------------------------------------------------------------
def test_a_short_run_estimates_the_misalignment():
    """Case 2 (SatB's GNSS pins the line of sight), 300 s: the estimate moves from the figure (0) to within 3 sigma
    of the truth and its 1 sigma shrinks from the file's 0.1 deg; "ignore" keeps the figure's error."""
    d = sf.check(_file())
    truth = np.array([0.1, -0.05, 0.08]) * 3600.0
    r, h = stkf_sim.simulate(2, 300.0, seed=1, truth="two-body", spacecraft=d, beacon_misalignment="estimate")
    assert np.allclose(r["misalignment_truth_arcsec"], truth)
    assert h["msig"][0].max() <= 360.0 and np.abs(h["merr"][0]).max() > 100.0     # after the first update
    e, s = np.abs(h["merr"][-1]), h["msig"][-1]
    assert np.all(e <= 3 * s) and np.all(s < 60.0) and np.all(e < 0.2 * np.abs(truth))
    assert r["misalignment_within_3sigma"] is True
    r0, h0 = stkf_sim.simulate(2, 300.0, seed=1, truth="two-body", spacecraft=d)
    assert np.allclose(h0["merr"][-1], -truth) and "misalignment_within_3sigma" not in r0


def test_ignore_holds_the_files_figure():
    """A file whose figure equals the truth: "ignore" takes the camera at the figure, so the beacon carries no
    bias; the pointing then matches a perfectly aligned camera's to the noise."""
    fig = (0.3, -0.2, 0.25)
    d = sf.check(_file(0.1, (0.0, 0.0, 0.0), fig))
    assert np.allclose(stkf_sim.misalignment_setup(d, "ignore")["C"], stkf.misalignment_dcm(np.radians(fig)))
    r, h = stkf_sim.simulate(1, 300.0, seed=2, truth="two-body", spacecraft=d)
    r0, h0 = stkf_sim.simulate(1, 300.0, seed=2, truth="two-body")
    assert abs(r["final_error_pointing_arcsec"] - r0["final_error_pointing_arcsec"]) < 1.0
    assert np.array_equal(h["merr"][-1], np.zeros(3))


def test_a_drawn_vehicle_draws_the_camera_within_its_sigma():
    raw = _file()
    raw["truth"] = None
    d = sf.check(raw)
    t = [dispersion.draw_truth(d, s)["beacon_misalignment_error_deg"] for s in range(200)]
    assert 0.08 < np.std(t) < 0.12 and len({tuple(v) for v in t}) == 200
    assert dispersion.draw_truth(d, 4) == dispersion.draw_truth(d, 4)
    d0 = copy.deepcopy(d)
    d0["uncertainty"]["beacon_misalignment_sigma_deg"] = 0.0
    a, b = dispersion.draw_truth(d, 4), dispersion.draw_truth(d0, 4)
    assert b["beacon_misalignment_error_deg"] == [0.0, 0.0, 0.0]
    assert {k: v for k, v in a.items() if "beacon" not in k} == {k: v for k, v in b.items() if "beacon" not in k}


# --- bad input --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("edit, message", [
    (lambda r: r["uncertainty"].update(beacon_misalignment_sigma_deg=-0.1),
     "uncertainty.beacon_misalignment_sigma_deg = -0.1: must be from 0 to 5 deg"),
    (lambda r: r["uncertainty"].update(beacon_misalignment_sigma_deg="0.1"),
     "uncertainty.beacon_misalignment_sigma_deg = \"0.1\": must be a number"),
    (lambda r: r["beacon"].update(misalignment_deg=[0.1, 0.0]), "beacon.misalignment_deg = [0.1, 0]: must be a list "
     "of 3 numbers, each from -5 to 5 deg"),
    (lambda r: r["beacon"].update(misalignment_deg=[0.1, float("nan"), 0.0]), "beacon.misalignment_deg[1] = nan: "
     "must be a finite number"),
    (lambda r: r["truth"].update(beacon_misalignment_error_deg=[0.0, 6.0, 0.0]),
     "truth.beacon_misalignment_error_deg[1] = 6: must be from -5 to 5 deg"),
    (lambda r: (r["beacon"].update(misalignment_deg=[0.0, 0.0, 4.0]),
                r["truth"].update(beacon_misalignment_error_deg=[0.0, 0.0, 2.0])),
     "truth.beacon_misalignment_error_deg[2] = 2: the true angle 6 must be from -5 to 5 deg"),
])
def test_bad_values_in_the_file_are_refused_by_name(edit, message):
    raw = _file()
    edit(raw)
    with pytest.raises(ValueError) as exc:
        sf.check(raw)
    assert str(exc.value).startswith(message)


def test_absent_or_null_angles_are_zero():
    raw = _file()
    del raw["beacon"]["misalignment_deg"], raw["uncertainty"]["beacon_misalignment_sigma_deg"]
    raw["truth"]["beacon_misalignment_error_deg"] = None
    d = sf.check(raw)
    assert sf.beacon_misalignment_deg(d) == [0.0, 0.0, 0.0] and sf.beacon_misalignment_sigma_deg(d) == 0.0
    assert sf.check(d) == d


def test_the_cli_refuses_an_estimate_without_an_uncertainty(tmp_path, capsys):
    """thesis-3u states no alignment uncertainty: --beacon-misalignment estimate exits 2 naming the key; a bad
    choice exits 2 too."""
    assert main(["adcs", "stkf", "--case", "1", "--beacon-misalignment", "estimate", "-o", str(tmp_path / "a")]) == 2
    assert "uncertainty.beacon_misalignment_sigma_deg" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["adcs", "stkf", "--case", "1", "--beacon-misalignment", "fit", "-o", str(tmp_path / "b")])
    assert exc.value.code == 2


def test_the_campaign_records_the_estimate(tmp_path):
    import json
    path = tmp_path / "sc.json"
    path.write_text(json.dumps(_file()))
    out = tmp_path / "run"
    assert main(["adcs", "stkf", "--case", "2", "--truth", "two-body", "--duration", "60", "--runs", "2",
                 "--workers", "1", "--quiet", "--no-plots", "--spacecraft", str(path), "--beacon-misalignment",
                 "estimate", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["beacon_misalignment"] == "estimate" and 0 <= s["misalignment_within_3sigma_share"] <= 1
    assert len(s["rms_final_error_misalignment_arcsec"]) == 3
    assert "misalignment" in (out / "report.md").read_text()
    r = json.loads((out / "run_0000" / "result.json").read_text())
    assert r["vehicle"]["kind"] == "truth block" and np.allclose(r["misalignment_truth_arcsec"],
                                                                 [360.0, -180.0, 288.0])
