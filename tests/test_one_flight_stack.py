"""One flight stack: the ground's flight world flies the flight app (firmware/adcs/app.py) in process, and its
history is the one the same app gives in a process of its own over CAN, bit for bit."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from emulator.adcs_session import AdcsSession
from protocol.units import RAD_PER_ARCSEC

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _fps(*args):
    out = subprocess.run([sys.executable, "-m", "ground.cli"] + list(args), cwd=ROOT, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode in (0, 3), out.stderr
    return out


@pytest.fixture(scope="module")
def params(tmp_path_factory):
    p = tmp_path_factory.mktemp("params") / "params.json"
    p.write_text(json.dumps(AdcsSession(runtime="inproc", world="flight", duration_s=5).params))
    return str(p)


def test_bps_flight_world_and_adcs_can_give_the_same_attitude_history(tmp_path, params):
    n = "240"
    _fps("adcs", "bps", "--world", "flight", "--session", n, "--seed", "2", "--params", params, "--truth",
         "two-body", "--quiet", "--no-plots", "--cache-dir", str(tmp_path / "cache"), "-o", str(tmp_path / "bps"))
    _fps("adcs", "can", "--world", "flight", "--session", n, "--seed", "2", "--params", params, "--runtime",
         "cpython", "--quiet", "--no-plots", "-o", str(tmp_path / "can"))
    a, b = np.load(tmp_path / "bps" / "history.npz"), np.load(tmp_path / "can" / "history.npz")
    assert a["q"].shape == (10 * int(n) + 1, 4) and a["q"].shape[0] == b["q"].shape[0] + 1
    assert np.array_equal(a["q"][1:], b["q"]) and np.array_equal(a["w"][1:], b["w"])     # b starts at 0.1 s
    k = int(n)
    assert np.array_equal(a["fsw_q_hat"][1:k], b["est_q"][1:k])      # the app's estimate, as ADCS_STATUS gave it
    sa, sb = json.load(open(tmp_path / "bps" / "summary.json")), json.load(open(tmp_path / "can" / "summary.json"))
    assert sa["mode_changes"] == sb["mode_changes"] and sa["mode_changes"][-1]["to"] == "POINT"


@pytest.mark.parametrize("world", ["thesis", "flight"])
def test_the_inproc_host_flies_the_cpython_process_bit_for_bit(world):
    h = {}
    for runtime in ("inproc", "cpython"):
        s = AdcsSession(runtime=runtime, world=world, duration_s=120, seed=1)
        rows = []
        with s:
            for _ in range(120):
                c = s.cycle()
                rows.append(np.concatenate([c["q"].ravel(), c["w"].ravel(), c["rw_cmd"]]))
                st = c["status"]
        # all of the last status but the firmware's own timing and the frames its CAN port dropped (the wire's,
        # which inproc has not; the lockstep's retries keep the run the same whatever it drops)
        h[runtime] = (np.array(rows), {k: v for k, v in st.items() if k not in ("cycle_us", "n_rx_drop")},
                      s.summary()["mode_changes"])
    assert np.array_equal(h["inproc"][0], h["cpython"][0])
    assert h["inproc"][1] == h["cpython"][1] and h["inproc"][2] == h["cpython"][2]


def test_the_inproc_host_refuses_what_needs_a_link():
    from protocol.faults import LinkFaults
    with pytest.raises(ValueError, match="runtime inproc has none"):
        AdcsSession(runtime="inproc", duration_s=5, link_faults=LinkFaults.parse("bytes=0.001"))
    with pytest.raises(ValueError, match="inproc only"):
        AdcsSession(runtime="cpython", duration_s=5, probe=lambda *a: None)


def test_the_ground_estimators_fly_the_same_modes_command_and_allocation(params):
    """The estimator is a plug-in: the app's modes, command and allocation on the ground's 41-state APKF and full
    STKF (ground/adcs/estimators.py) slew, acquire and point as on the lean filters, from other estimates."""
    from ground.adcs import flight_world
    p = json.load(open(params))
    runs = {e: flight_world.simulate(params=p, duration_s=150, seed=1, estimator=e) for e in ("lean", "ground")}
    (rl, hl), (rg, hg) = runs["lean"], runs["ground"]
    assert rg["estimator"] == "ground" and "ground/adcs/estimators.py" in rg["flight_software"] and rg["complete"]
    assert [c["to"] for c in rg["mode_changes"]][:3] == [c["to"] for c in rl["mode_changes"]][:3] == \
        ["HOLD", "SLEW", "ACQUIRE"]
    assert not np.array_equal(hg["fsw_q_hat"][5:], hl["fsw_q_hat"][5:], equal_nan=True)   # other filters' estimates
    for h in (hl, hg):
        err = np.linalg.norm(h["fsw_est_err"][140:149, 0:3], axis=1)      # arcsec, once pointing
        sig = h["fsw_att_sigma"][140:149, 0] / RAD_PER_ARCSEC
        assert np.all(err < 120.0) and np.all(err < 5.0 * sig), (err, sig)


def test_another_estimation_needs_the_inproc_host_and_the_flight_world(tmp_path, capsys):
    from ground.adcs.estimators import estimation
    from ground.cli import main as fps
    from emulator.spacecraft import scenario
    with pytest.raises(ValueError, match="inproc only"):
        AdcsSession(runtime="cpython", duration_s=5, estimation=estimation(scenario.thesis_3u()))
    assert fps(["adcs", "bps", "--estimator", "ground", "--duration", "10", "-o", str(tmp_path / "x")]) == 2
    assert "--estimator is the flight world's" in capsys.readouterr().err


def test_consistency_tells_an_honest_1_sigma_from_an_overconfident_one():
    """app_host.consistency: errors drawn from the very covariance the record states are in band ~95 % of the
    seconds with RMS / 1 sigma ~1; the same errors against a covariance 9x too small (1 sigma 3x) are not."""
    from ground.adcs.app_host import consistency
    rng = np.random.default_rng(0)
    n = 4000
    A = rng.standard_normal((n, 3, 3)) * 0.3 + np.eye(3)
    C = np.einsum("kij,klj->kil", A, A) * 1e-10                           # rad^2, SPD, correlated
    e = np.einsum("kij,kj->ki", np.linalg.cholesky(C), rng.standard_normal((n, 3)))
    fsw = {"est_err": np.hstack([e / RAD_PER_ARCSEC, np.zeros((n, 5))]), "att_cov": C.reshape(n, 9),
           "stkf_err": np.hstack([e, e]) * 1e5, "stkf_cov": np.hstack([C.reshape(n, 9), C.reshape(n, 9) / 9]) * 1e10}
    c = consistency(fsw, 100)
    for key in ("apkf_attitude", "stkf_ra"):
        assert 0.93 < c[key]["nees_in_band_share"] < 0.97 and 2.8 < c[key]["nees_mean"] < 3.2
        assert all(0.9 < r < 1.1 for r in c[key]["rms_over_sigma"]) and c[key]["seconds"] == n - 100
    assert c["stkf_rb"]["nees_in_band_share"] < 0.5 and all(r > 2.5 for r in c["stkf_rb"]["rms_over_sigma"])


def test_both_worlds_report_their_estimators_consistency(params):
    """The thesis and the flight world each report the APKF's and the STKF's NEES and RMS / 1 sigma (the flight
    world's after its first orbit: none in a shorter run; its history has what they are computed from)."""
    from ground.adcs import app_host, flight_world, thesis_world
    p = json.load(open(params))
    rf, hf = flight_world.simulate(params=p, duration_s=200, seed=1)
    rt, _ = thesis_world.simulate(params=p, duration_s=60, seed=1)
    assert rf["consistency"]["from_s"] == np.ceil(rf["orbit_period_s"]) and rf["consistency"]["stkf_rb"] is None
    c2 = app_host.consistency({k[4:]: v for k, v in hf.items() if k.startswith("fsw_")}, 100)
    for c in (rt["consistency"], c2):
        for key in ("apkf_attitude", "stkf_ra", "stkf_rb"):
            assert c[key]["seconds"] > 0 and 0.0 <= c[key]["nees_in_band_share"] <= 1.0
        assert c["apkf_attitude"]["nees_in_band_share"] > 0.8
