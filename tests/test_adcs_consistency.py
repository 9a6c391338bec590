"""The APKF's consistent form: the iterated update over a blind stretch, and what it buys.

1. ``propagate_window``'s M is the Jacobian of the stretch (against finite differences of the propagation, to
   the linearisation's accuracy).
2. ``update_window`` with one pass is the EKF update (Eq. 4.139-4.142); with passes it moves the state.
3. Over Case 1 (3 seeds, 930 s) the consistent form's NEES after the first set sits at its dof and no parameter
   ends beyond 3 sigma; the thesis's form, same runs, is overconfident.
"""

import numpy as np
import pytest

from emulator.spacecraft import scenario
from ground.adcs import apkf, quat, runs


@pytest.fixture(scope="module")
def stretch():
    """A stretch of a Case 1 run: the state after the fix at 60 s and the 29 blind steps to the next fix."""
    o = scenario.simulate(case=1, seed=0, duration=130)
    k0, f = runs._start_apkf(o, 1, form="thesis")
    k = k0 + 1
    while True:
        f.step(o["t"][k - 1], o["tach"][k], o["st_q"][k] if o["st_valid"][k] else None)
        if o["st_valid"][k] and not o["st_valid"][k + 1]:
            break
        k += 1
    xa, Pa = f.x.copy(), f.P.copy()
    steps = []
    k += 1
    while not o["st_valid"][k]:
        steps.append((o["t"][k - 1], o["tach"][k]))
        k += 1
    steps.append((o["t"][k - 1], o["tach"][k]))
    return o, f.model, xa, Pa, steps, k


def test_the_stretch_jacobian_is_the_propagations(stretch):
    _, model, xa, _, steps, _ = stretch
    xb, M = apkf.propagate_window(xa, steps[:10], model)
    h = np.full(apkf.N, 1e-7)
    h[apkf.PARAMS] = np.abs(xa[7:30]) * 1e-6 + 1e-12
    for j in (0, 2, 4, 9, 12, 15, 19, 27, 31, 39):
        d = np.zeros(apkf.N)
        d[j] = h[j]
        xp = apkf.propagate_window(apkf.correct(xa, d), steps[:10], model)[0]
        xm = apkf.propagate_window(apkf.correct(xa, -d), steps[:10], model)[0]
        fd = (apkf.difference(xp, xb) - apkf.difference(xm, xb)) / (2 * h[j])
        # Phi is the linearisation at each step's start (Eq. 4.114-4.127), not RK4's exact Jacobian: they agree
        # to ~3e-4 of a column's scale over 10 s; a wrong carry or shift is off by O(1)
        assert np.allclose(M[:, j], fd, rtol=2e-2, atol=1e-2 * np.abs(M[:, j]).max()), j


def test_one_pass_is_the_ekf_update_and_passes_move_it(stretch):
    o, model, xa, Pa, steps, k = stretch
    x, P = xa, Pa
    for t, w in steps:
        x, P = apkf.predict(x, P, w, model, t, 1, 100.0)
    xb, M = apkf.propagate_window(xa, steps, model)
    assert np.array_equal(xb, x)                      # the same propagation as predict's
    R = model.R_st * 100.0
    x1, P1, n1 = apkf.update_window(xa, Pa, steps, x, P, M, o["st_q"][k], R, model, max_iter=1)
    xe, Pe = apkf.update(x, P, o["st_q"][k], R)
    assert n1 == 1
    assert np.allclose(x1, xe, rtol=1e-12, atol=1e-15) and np.allclose(P1, Pe, rtol=1e-9, atol=1e-20)
    xi, Pi, n = apkf.update_window(xa, Pa, steps, x, P, M, o["st_q"][k], R, model)
    assert 2 <= n < apkf.ITER_MAX
    assert np.max(np.abs(apkf.difference(xi, xe)) / np.sqrt(np.diag(Pi))) > 0.1


def _nees_after_first_set(form, seeds=range(3)):
    out, z_params = [], []
    for seed in seeds:
        r = runs.run_apkf(seed, None, case=1, form=form)
        assert r["ok"]
        out.append(r["series"]["nees"])
        z_params.append(r["final_normalised_error"][6:29])
        t0 = int(r["set_ends_s"][0])
    return float(np.mean(np.array(out)[:, t0:])), np.abs(np.array(z_params))


def test_the_consistent_form_is_consistent_where_the_thesiss_is_not():
    mean_c, zc = _nees_after_first_set("consistent")
    mean_t, zt = _nees_after_first_set("thesis")
    assert 4.5 < mean_c < 8.0, mean_c                  # 6 dof
    assert (zc <= 3.0).all()
    assert mean_t > 2 * mean_c and (zt > 3.0).any(), (mean_t, zt.max())


def test_the_campaign_counts_parameters_within_3_sigma():
    good = {"seed": 0, "ok": True, "final_normalised_error": [0.0] * 41, "set_ends_s": [210.0],
            "final_error_attitude_arcsec": [1.0, 1.0, 1.0]}
    bad = dict(good, seed=1, final_normalised_error=[0.0] * 20 + [3.5] + [0.0] * 20)
    s = runs.aggregate([good, bad], "apkf", 1)
    assert s["params_within_3sigma_share"] == 0.5
    assert s["params_within_3sigma_by_parameter"][runs.PARAM_NAMES[20 - 6]] == 0.5
    assert s["params_within_3sigma_by_parameter"]["Jyy"] == 1.0


@pytest.mark.parametrize("name,fns,tilts", [
    ("generic-12u", ("apkf", "mekf"), 1.0), ("generic-6u", ("apkf", "mekf"), 1.0), ("thesis-3u", ("apkf",), 1.0),
    ("thesis-3u", ("apkf",), 0.3)])
def test_the_apkf_and_the_mekf_are_consistent_on_the_other_spacecraft(name, fns, tilts):
    """Each file's own priors against vehicles drawn from its uncertainty (case 1, 2 seeds, 930 s; ``tilts`` scales
    the file's wheel-tilt 1 sigma, the draws and the filter's P0 alike): the mean NEES after the first set near its 6
    dof, no parameter beyond 3 sigma at the end, no run diverged."""
    from protocol import spacecraft as sf
    d = sf.load(name)
    d["uncertainty"]["misalignment_sigma_deg"] *= tilts
    for fn in (getattr(runs, "run_" + f) for f in fns):
        rs = [fn(seed, None, case=1, spacecraft=d, vehicle="drawn") for seed in range(2)]
        assert all(r["vehicle"]["kind"] == "drawn" for r in rs)
        assert all(r["ok"] for r in rs)
        t0 = int(rs[0]["set_ends_s"][0])
        mean = float(np.mean([r["series"]["nees"][t0:] for r in rs]))
        assert 4.0 < mean < 8.5, (fn.__name__, mean)
        if fn is runs.run_apkf:
            assert (np.abs(np.array([r["final_normalised_error"][6:29] for r in rs])) <= 3.0).all()


def test_the_cli_records_the_form_and_the_thesis_form_differs(tmp_path, capsys):
    """``fps adcs apkf --filter`` (300 s, 1 seed): config.json and summary.json say the form; the two forms give
    different estimates; a bad form is refused by argparse (exit 2)."""
    from ground.cli import main
    from ground.fileio import read_json
    p = tmp_path / "p.json"
    p.write_text('{"duration_s": 300}')
    out = {}
    for form in ("consistent", "thesis"):
        o = tmp_path / form
        assert main(["adcs", "apkf", "--runs", "1", "--workers", "1", "--quiet", "--no-plots", "--params", str(p),
                     "--filter", form, "-o", str(o)]) == 0
        assert read_json(str(o / "config.json"), "config")["form"] == form
        out[form] = read_json(str(o / "summary.json"), "summary")
        assert out[form]["form"] == form and out[form]["per_run"][0]["filter_form"] == form
    assert out["consistent"]["final_error_attitude_arcsec"] != out["thesis"]["final_error_attitude_arcsec"]
    with pytest.raises(SystemExit) as e:
        main(["adcs", "apkf", "--filter", "ekf", "-o", str(tmp_path / "x")])
    assert e.value.code == 2


def test_the_stkf_campaign_reports_its_consistency():
    """Two 300 s Case 2 runs (two-body truth): the summary's NEES (12 dof) and RMS error / 1 sigma per vector are
    there and plausible (the STKF is cautious on the two-body truth: its acceleration noise is for HPOP's forces)."""
    from ground.adcs import stkf_sim
    res = [stkf_sim.simulate(2, 300.0, seed=s, truth="two-body")[0] for s in range(2)]
    s = stkf_sim.aggregate(res, 2, True)
    assert 3.0 < s["nees_mean"] < 14.0 and 0.0 <= s["nees_in_band_share"] <= 1.0
    for k in ("ra", "va", "rb", "vb"):
        assert 0.3 < s["rms_over_sigma_" + k] < 1.5, (k, s["rms_over_sigma_" + k])
    assert stkf_sim.consistency([])["nees_in_band_share"] is None


def test_the_campaign_gives_the_runs_nees_variance_against_chi_squares():
    """Two runs whose NEES after the first set is 0 and 12 (6 dof): per step a variance of 36 over the runs,
    three times chi-square's 2 x 6; the steps before the set's end are left out."""
    def run(seed, level):
        nees = [100.0] * 5 + [level] * 5
        return {"seed": seed, "ok": True, "set_ends_s": [5.0], "final_error_attitude_arcsec": [1.0, 1.0, 1.0],
                "series": {"nees": nees, "att_err": [[0.0, 0.0, 0.0]] * 10, "z_att_rate": [[0.0] * 6] * 10}}
    s = runs.aggregate([run(0, 0.0), run(1, 12.0)], "apkf", 1)
    assert s["nees"]["variance_ratio_after"] == pytest.approx(3.0)
    assert runs.aggregate([run(0, 6.0)], "apkf", 1)["nees"]["variance_ratio_after"] is None
