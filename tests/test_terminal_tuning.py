"""``fps adcs sweep --objective terminal`` (``ground.adcs.terminal_tuning``): the body objective as it is, the
residual through a known sensitivity, the options' bad values (two-body truth, short runs)."""

import json
import math

import numpy as np
import pytest

from emulator.spacecraft import scenario
from ground import cli
from ground.adcs import body_pointing as bps, terminal_tuning as tt

BODY_KEYS = {"ts_s", "J", "ts_best_s", "complete", "satb_gnss", "ts_thesis_s", "J_unit", "failures", "wall_s",
             "duration_s", "spacecraft"}


@pytest.fixture(scope="module")
def params_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("tt") / "params.json"
    bps.write_params(str(p), scenario.truth_params(scenario.pointing_world(10, 0).sc))
    return str(p)


def _sweep(params_file, tmp_path, name, extra=()):
    out = tmp_path / name
    rc = cli.main(["adcs", "sweep", "--ts", "15:25:10", "--duration", "5", "--workers", "1", "--params", params_file,
                   "--truth", "two-body", "--quiet", "--cache-dir", str(tmp_path / "c"), "-o", str(out)] + list(extra))
    return rc, out, json.loads((out / "summary.json").read_text())


def test_body_objective_is_the_default_and_unchanged_and_terminal_flies_the_same_runs(params_file, tmp_path):
    rc0, out0, s0 = _sweep(params_file, tmp_path, "default")
    rc1, out1, s1 = _sweep(params_file, tmp_path, "body", ["--objective", "body"])
    rc2, out2, s2 = _sweep(params_file, tmp_path, "terminal", ["--objective", "terminal"])
    assert rc0 == rc1 == rc2 == 0
    assert set(s0) == BODY_KEYS and s0.pop("wall_s") and s1.pop("wall_s") and s0 == s1
    assert (out0 / "report.md").read_text() == (out1 / "report.md").read_text()
    assert not (out0 / tt.FIGURE).exists() and (out2 / tt.FIGURE).exists()
    assert s2["J"] == s0["J"] and s2["ts_best_body_s"] == s0["ts_best_s"]          # the same runs, bit for bit
    r3 = s2["residual_3sigma_arcsec"]
    assert all(v > 0 for v in r3) and s2["ts_best_terminal_s"] == s2["ts_best_s"] == s2["ts_s"][int(np.argmin(r3))]
    for sg, v in zip(s2["residual_sigma_arcsec"], r3):
        assert v == pytest.approx(3 * math.hypot(*sg))
    assert s2["rejection"]["source"] == "model" and "residual 3σ" in (out2 / "report.md").read_text()


def _table(f, s):
    return {"source": "test", "what": "test", "freq_hz": list(f), "s_abs": [list(s), list(s)]}


def test_a_tone_through_a_known_sensitivity_leaves_amplitude_times_gain_over_root_two():
    k = 0.02                                            # |S| = k f, the integral loop's slope (per Hz)
    tab = _table([0.01, 10.0], [k * 0.01, k * 10.0])
    n, dt, amp = 3000, 0.1, 40.0
    for m in (3, 250, 2900):                           # on the mirrored series' bins: exact
        f0 = m / (2 * n * dt)
        x = amp * np.cos(2 * np.pi * f0 * (np.arange(n) + 0.5) * dt)
        got = tt.residual_sigma(x, dt, lambda f: tt.s_abs(tab, 0, f))
        assert got == pytest.approx(amp * k * f0 / math.sqrt(2), rel=1e-9)
    f0 = 0.3217                                        # off the bins: within 1 %
    x = amp * np.sin(2 * np.pi * f0 * np.arange(n) * dt + 0.4) + 7.0
    assert tt.residual_sigma(x, dt, lambda f: tt.s_abs(tab, 0, f)) == pytest.approx(amp * k * f0 / math.sqrt(2),
                                                                                      rel=0.01)
    x = np.random.default_rng(1).normal(size=n)        # a flat |S| = c scales the 1 sigma by c
    assert tt.residual_sigma(x, dt, lambda f: np.full(np.shape(f), 0.5)) == pytest.approx(0.5 * x.std(), rel=1e-9)


def test_sensitivity_table_interpolates_and_extends_as_f_below_it():
    tab = _table([1.0, 4.0, 100.0], [0.02, 0.08, 1.1])
    f = np.array([0.01, 0.5, 1.0, 2.0, 4.0, 500.0])
    assert tt.s_abs(tab, 1, f) == pytest.approx([2e-4, 0.01, 0.02, 0.04, 0.08, 1.1])
    model = tt.rejection_table("model")
    from emulator.config import default_config
    from ground.response import LoopModel
    for ax in (0, 1):
        m = LoopModel(default_config(), 637.8, 0.5, ax)
        for f in (2e-3, 0.05, 1.3, 4.9):
            assert tt.s_abs(model, ax, np.array([f]))[0] == pytest.approx(abs(m.s_truth(f)[0]), rel=1e-4)


def test_terminal_residual_of_a_history_takes_the_collection_window_per_axis():
    dt, n = 0.1, 2000
    t = np.arange(n) * dt
    tab = _table([0.01, 10.0], [0.01 * 0.01, 0.01 * 10.0])
    f1, f2 = 0.25, 1.0                                 # whole cycles over the window from 50 s
    x = np.column_stack([30 * np.sin(2 * np.pi * f1 * t), 10 * np.sin(2 * np.pi * f2 * t)])
    x[t < 50] = 1e4                                    # the settling, left out
    r = tt.terminal_residual({"settle_s": 50.0}, {"t": t, "dtheta_arcsec": x}, tab)
    want = [30 * 0.01 * f1 / math.sqrt(2), 10 * 0.01 * f2 / math.sqrt(2)]
    assert r["samples"] == 1500 and r["residual_sigma_arcsec"] == pytest.approx(want, rel=0.01)
    assert r["residual_3sigma_arcsec"] == pytest.approx(3 * math.hypot(*want), rel=0.01)
    assert tt.terminal_residual({"settle_s": 1e6}, {"t": t, "dtheta_arcsec": x}, tab) is None


def test_a_measured_rejection_from_fps_response(tmp_path):
    p = tmp_path / "response.json"
    p.write_text(json.dumps({"complete": True, "freq_hz": [1.0, 10.0], "s_measured": [0.03, 0.3],
                             "s_measured_y": [0.02, 0.2]}))
    tab = tt.check_args("terminal", str(p))
    assert tt.s_abs(tab, 0, np.array([0.1, 1.0]))[0] == pytest.approx(0.003)
    assert tt.s_abs(tab, 1, np.array([10.0]))[0] == pytest.approx(0.2)
    assert tt.check_args("body", None) is None


@pytest.mark.parametrize("extra, says", [
    (["--objective", "bogus"], "--objective"),
    (["--rejection", "model"], "--rejection"),                                      # the body objective's default
    (["--objective", "terminal", "--rejection", "/nonexistent/summary.json"], "--rejection"),
    (["--objective", "terminal", "--rejection", "INCOMPLETE"], "--rejection"),
    (["--objective", "terminal", "--rejection", "BAD"], "--rejection"),
])
def test_bad_objective_or_rejection_exits_2_before_any_run(extra, says, params_file, tmp_path, capsys):
    (tmp_path / "inc.json").write_text(json.dumps({"complete": False, "freq_hz": [1, 2], "s_measured": [1, 1],
                                                   "s_measured_y": [1, 1]}))
    (tmp_path / "bad.json").write_text(json.dumps({"complete": True, "freq_hz": [2, 1], "s_measured": [1, -1],
                                                   "s_measured_y": [1, 1]}))
    extra = [{"INCOMPLETE": str(tmp_path / "inc.json"), "BAD": str(tmp_path / "bad.json")}.get(e, e) for e in extra]
    out = tmp_path / "sweep"
    try:
        rc = cli.main(["adcs", "sweep", "--ts", "15", "--duration", "5", "--workers", "1", "--params", params_file,
                       "--truth", "two-body", "--quiet", "-o", str(out)] + extra)
    except SystemExit as exc:                          # argparse's own refusal
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2 and says in err and "Traceback" not in err and not (out / "run_0000").exists()
