"""The PD's damping ratio zeta through the flight config (``pd_zeta``, Eq. 6.6): absent = the firmware's 1 bit for
bit, D proportional to zeta, bad values refused; ``fps adcs sweep --zeta`` over the (t_s, zeta) grid (two-body
truth, short runs)."""

import json
import math

import pytest

from emulator.adcs_session import AdcsSession
from emulator.spacecraft import scenario
from firmware.adcs import app as A, control
from ground import cli
from ground.adcs import body_pointing as bps, terminal_tuning as tt


def _cfg(zeta=None):
    return AdcsSession(runtime="cpython", duration_s=30.0, ts=40.0, zeta=zeta).config()


def test_zeta_absent_is_the_firmwares_one_bit_for_bit_and_d_follows_eq_6_6():
    assert "pd_zeta" not in _cfg() and _cfg(0.7)["pd_zeta"] == 0.7
    a0, a1, a7 = (A.App(_cfg(z)).act for z in (None, 1.0, 0.7))
    assert list(a0.K) == list(a1.K) == list(a7.K) and list(a0.D) == list(a1.D)
    wn = control.natural_frequency(40.0)
    J = list(a0.J)
    assert list(a7.D) == pytest.approx([2 * 0.7 * wn * j for j in J], rel=1e-6)   # D = 2 zeta wn J (float32)
    assert list(a7.D) != list(a0.D) and max(abs(v) for v in J) > 0


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "x"])
def test_the_firmware_refuses_a_bad_zeta(bad):
    with pytest.raises(ValueError, match="zeta"):
        A.App(dict(_cfg(), pd_zeta=bad))
    with pytest.raises(ValueError, match="zeta"):
        AdcsSession(runtime="cpython", duration_s=30.0, zeta=bad)


@pytest.mark.parametrize("argv", [["sweep", "--zeta", "0,1"], ["sweep", "--zeta", "nan"], ["sweep", "--zeta", "1,1"],
                                  ["sweep", "--zeta", "1,"], ["bps", "--zeta", "-0.5"], ["bps", "--zeta", "inf"]])
def test_a_bad_zeta_exits_2_naming_the_option(argv, tmp_path, capsys):
    rc = cli.main(["adcs"] + argv + ["--duration", "5", "--truth", "two-body", "-o", str(tmp_path / "o")])
    assert rc == 2 and "--zeta" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_grid_points_and_their_limit():
    assert tt.grid([10.0, 20.0], None, 4) == ([10.0, 20.0], None)
    assert tt.grid([10.0, 20.0], [0.7, 1.0], 4) == ([10.0, 20.0, 10.0, 20.0], [0.7, 0.7, 1.0, 1.0])
    with pytest.raises(ValueError, match="--zeta"):
        tt.grid([10.0, 20.0], [0.7, 1.0, 1.4], 5)


def test_the_sweeps_grid_in_the_summary_and_zeta_one_is_the_default_run(tmp_path):
    p = tmp_path / "params.json"
    bps.write_params(str(p), scenario.truth_params(scenario.pointing_world(10, 0).sc))

    def sweep(name, extra):
        out = tmp_path / name
        rc = cli.main(["adcs", "sweep", "--ts", "15", "--duration", "5", "--workers", "1", "--params", str(p),
                       "--truth", "two-body", "--quiet", "--cache-dir", str(tmp_path / "c"), "-o", str(out)] + extra)
        return rc, out, json.loads((out / "summary.json").read_text())

    rc0, _, s0 = sweep("default", ["--objective", "terminal"])
    rc1, out, s1 = sweep("grid", ["--objective", "terminal", "--zeta", "1,0.6"])
    assert rc0 == rc1 == 0 and "zeta" not in s0 and "by_zeta" not in s0
    assert s1["ts_s"] == [15.0, 15.0] and s1["zeta"] == [1.0, 0.6] and s1["zeta_values"] == [1.0, 0.6]
    assert s1["J"][0] == s0["J"][0] and s1["residual_3sigma_arcsec"][0] == s0["residual_3sigma_arcsec"][0]
    assert s1["J"][1] != s1["J"][0]
    r3 = s1["residual_3sigma_arcsec"]
    i = min(range(2), key=lambda k: r3[k])
    assert (s1["ts_best_terminal_s"], s1["zeta_best_terminal"]) == (15.0, s1["zeta"][i]) == (15.0, s1["zeta_best_s"])
    assert [r["zeta"] for r in s1["by_zeta"]] == [1.0, 0.6]
    assert [r["residual_3sigma_arcsec"] for r in s1["by_zeta"]] == r3
    res = [json.loads((out / ("run_%04d" % k) / "result.json").read_text()) for k in range(2)]
    assert [r["pd_zeta"] for r in res] == [1.0, 0.6] and all(math.isfinite(r["J_rad2"]) for r in res)
    text = (out / "report.md").read_text()
    assert "| 15 | 0.6 |" in text and "ζ = 1" in text and (out / tt.FIGURE).exists()
