"""The STKF's consistency in the flight world: its full covariance recorded each second, the NEES of its 12
states [rA, vA, rB, vB] against it, the share of seconds in the 95 % band, and RMS error / RMS 1 sigma per
satellite's position and velocity and for rB - rA (``summary.json`` ``stkf_consistency``, report.md)."""

import json

import numpy as np
import pytest
from scipy.stats import chi2

from emulator.adcs_session import AdcsSession
from ground.adcs import flight_world
from ground.adcs.bps_report import consistency_md
from ground.adcs.pointing import nees, stkf_consistency

PARTS = ("ra", "va", "rb", "vb", "rba")


@pytest.fixture(scope="module")
def run():
    """A flight-world run 340 s past its first orbit (5561 s on thesis-3u), where the figures start."""
    p = json.loads(json.dumps(AdcsSession(runtime="inproc", world="flight", duration_s=5).params))
    return flight_world.simulate(params=p, duration_s=5900, seed=1)


def test_the_summary_has_the_stkf_figures_finite(run):
    res, _ = run
    c = res["stkf_consistency"]
    assert c["from_s"] == np.ceil(res["orbit_period_s"]) and c["p"] == 0.95 and "full" in c["covariance"]
    n12 = c["nees12_full_cov"]
    assert n12["dof"] == 12 and n12["seconds"] > 300 and np.isfinite(n12["nees_mean"])
    assert 0.0 <= n12["nees_in_band_share"] <= 1.0
    assert n12["band"] == pytest.approx([chi2.ppf(0.025, 12), chi2.ppf(0.975, 12)])
    for name in PARTS:
        v = c[name]
        assert v["dof"] == 3 and v["seconds"] == n12["seconds"] and 0.0 <= v["nees_in_band_share"] <= 1.0
        for key in ("rms_error", "rms_sigma", "rms_over_sigma"):
            assert len(v[key]) == 3 and np.all(np.isfinite(v[key])) and min(v[key]) > 0
    # the positions as app_host.consistency gives them, from its own record
    for mine, theirs in (("ra", "stkf_ra"), ("rb", "stkf_rb")):
        assert c[mine]["nees_mean"] == pytest.approx(res["consistency"][theirs]["nees_mean"], rel=1e-9)


def test_the_history_records_the_stkf_and_the_nees_is_what_it_says(run):
    """Recomputed from the history alone: e^T P^-1 e by a Cholesky factor, the band share with scipy's chi2; the
    record itself against the recorder's own (positions' errors and covariances, the filter's 1 sigma)."""
    res, h = run
    e, P = h["fsw_stkf_x_err"], h["fsw_stkf_P"].reshape(-1, 12, 12)
    n = len(h["fsw_mode"])
    assert e.shape == (n, 12) and h["fsw_stkf_sig"].shape == (n, 12) and h["fsw_stkf_nees12_full_cov"].shape == (n, 1)
    k0 = int(res["stkf_consistency"]["from_s"])
    for k in (k0, k0 + 57, k0 + 200, n - 2):
        L = np.linalg.cholesky(P[k])
        y = np.linalg.solve(L, e[k])
        assert h["fsw_stkf_nees12_full_cov"][k, 0] == pytest.approx(y @ y, rel=1e-9)
    ok = np.isfinite(h["fsw_stkf_err"][:, 0])
    assert ok.sum() > n - 10
    assert np.array_equal(e[ok][:, [0, 1, 2, 6, 7, 8]], h["fsw_stkf_err"][ok])
    assert np.array_equal(P[ok][:, 0:3, 0:3].reshape(-1, 9), h["fsw_stkf_cov"][ok, 0:9])
    assert np.array_equal(P[ok][:, 6:9, 6:9].reshape(-1, 9), h["fsw_stkf_cov"][ok, 9:18])
    assert np.allclose(np.sqrt(np.einsum("kii->ki", P[1:-1])), h["fsw_stkf_sig"][1:-1], rtol=1e-12, atol=0)
    x = h["fsw_stkf_nees12_full_cov"][k0:-1, 0]
    lo, hi = chi2.ppf([0.025, 0.975], 12)
    c = res["stkf_consistency"]["nees12_full_cov"]
    assert c["nees_in_band_share"] == pytest.approx(np.mean((x >= lo) & (x <= hi)), abs=1e-12)
    assert c["nees_mean"] == pytest.approx(x.mean(), rel=1e-12)
    rel = e[k0:-1, 6:9] - e[k0:-1, 0:3]
    Prel = P[k0:-1, 0:3, 0:3] + P[k0:-1, 6:9, 6:9]          # the lean STKF's SatA and SatB are separate filters
    r = np.sqrt((rel ** 2).mean(axis=0)) / np.sqrt(np.einsum("kii->ki", Prel).mean(axis=0))
    assert res["stkf_consistency"]["rba"]["rms_over_sigma"] == pytest.approx(r, rel=1e-9)


def test_the_report_shows_the_stkf_beside_the_apkf(run):
    res, _ = run
    text = "\n".join(consistency_md(res["consistency"], res["stkf_consistency"]))
    for row in ("attitude (APKF)", "SatA's velocity (STKF)", "SatB's velocity (STKF)", "rB − rA", "NEES of 12 dof"):
        assert row in text


def test_the_nees_takes_the_full_covariance():
    """Errors drawn from a correlated covariance: against it ~95 % of the NEES of 12 dof fall in the band (mean 12);
    against its diagonal alone far fewer do (the mean is 12 either way), so dropping the cross terms would show."""
    rng = np.random.default_rng(1)
    n = 4000
    A = np.eye(12) + 0.9 * rng.standard_normal((12, 12))
    C = np.tile(A @ A.T, (n, 1, 1))
    e = rng.standard_normal((n, 12)) @ np.linalg.cholesky(C[0]).T
    c = stkf_consistency(e, C, 0)
    assert 0.93 < c["nees12_full_cov"]["nees_in_band_share"] < 0.97
    assert 11.5 < c["nees12_full_cov"]["nees_mean"] < 12.5
    for name in PARTS[:4]:
        assert 2.8 < c[name]["nees_mean"] < 3.2 and all(0.9 < r < 1.1 for r in c[name]["rms_over_sigma"])
    diag = np.einsum("kii->ki", C)[:, :, None] * np.eye(12)
    d = stkf_consistency(e, diag, 0)
    assert d["nees12_full_cov"]["nees_in_band_share"] < 0.9                 # the mean alone would not tell
    assert max(d["rba"]["rms_over_sigma"]) > 1.15 > max(c["rba"]["rms_over_sigma"])   # rB - rA's cross terms
    assert np.isnan(nees(np.full((1, 12), np.nan), C[:1])[0])
