"""STKF (Eq. 5.6-5.17, 5.54-5.60), EAFLS on the orbit problem, orbit truth, sensors and ``fps adcs stkf``."""

import json
import os

import numpy as np
import pytest

from emulator import orbits
from emulator.interp import lagrange
from emulator.navsensors import Gnss
from ground.adcs import afls, stkf, stkf_sim
from protocol.units import RAD_PER_ARCSEC


def test_kepler_truth_conserves_energy_and_matches_rk4():
    t, x = orbits.truth_samples("two-body", 600.0)
    xa = x[:, 0, :]
    e = 0.5 * (xa[:, 3:] ** 2).sum(1) - orbits.MU / np.linalg.norm(xa[:, :3], axis=1)
    assert np.ptp(e) < 1e-6 * abs(e[0])
    xs = np.concatenate([orbits.X0_A, orbits.X0_B])
    for _ in range(100):
        xs = stkf.f(xs, 1.0)
    np.testing.assert_allclose(xs[:3], x[100, 0, :3], atol=1e-3)


@pytest.mark.parametrize("kind", ["two-body", "hpop"])
def test_lagrange10_interpolation_error_below_1mm(kind):
    """Sec. 6.4.1: 10th-order Lagrange on the 1 s samples, checked against the truth at half seconds."""
    t, x = orbits.truth_samples(kind, 600.0, x0s=(one_x0(),))
    tq = np.arange(0.5, 600.0, 7.0)
    if kind == "two-body":
        ref = orbits.kepler(one_x0(), tq)
    else:
        _, xh = orbits.truth_samples(kind, 600.0, x0s=(one_x0(),), step_s=0.5)
        ref = xh[np.round(tq / 0.5).astype(int), 0, :]
    got = lagrange(t, x[:, 0, :], tq, order=10)
    err = np.linalg.norm(got[:, :3] - ref[:, :3], axis=1)
    assert err.max() < 1e-3, err.max()
    # 3rd order is visibly worse on the same data: the test can fail
    assert np.linalg.norm(lagrange(t, x[:, 0, :], tq, order=3)[:, :3] - ref[:, :3], axis=1).max() > 10 * err.max()


def one_x0():
    return orbits.X0_A


def test_hpop_truth_is_cached_atomically(tmp_path):
    t1, x1 = orbits.truth_samples("hpop", 60.0, cache_dir=str(tmp_path))
    files = os.listdir(tmp_path / "truth_cache")
    assert len(files) == 1 and files[0].endswith(".npz")
    real = orbits.hpop
    orbits.hpop = None                                  # the second call must read the cache, not propagate
    try:
        t2, x2 = orbits.truth_samples("hpop", 60.0, cache_dir=str(tmp_path))
    finally:
        orbits.hpop = real
    np.testing.assert_array_equal(x1, x2)
    _, xk = orbits.truth_samples("two-body", 60.0)
    d = np.linalg.norm(x1[-1, 0, :3] - xk[-1, 0, :3])
    assert 1.0 < d < 5e3  # perturbations act (J2 alone: hundreds of m in a minute), but no blow-up


def test_short_hpop_truth_matches_the_start_of_a_longer_one():
    """brahe refused samples over spans under ~40 s ("outside propagator time range"), so ``fps adcs stkf
    --duration 10`` failed; a short truth now propagates over at least orbits.HPOP_MIN_SPAN_S."""
    _, x_long = orbits.truth_samples("hpop", 60.0)
    for d in (1.0, 20.0):
        t, x = orbits.truth_samples("hpop", d)
        assert x.shape == (len(t), 2, 6) and t[-1] == d + 10
        assert np.abs(x[:, :, :3] - x_long[:len(t), :, :3]).max() < 1e-3     # m


def test_orbit_under_the_surface_refused():
    bad = orbits.X0_A.copy()
    bad[:3] *= 0.9
    with pytest.raises(ValueError, match="under the Earth"):
        orbits.truth_samples("two-body", 10.0, x0s=(bad, orbits.X0_B))
    with pytest.raises(ValueError, match="NaN"):
        orbits.check_state([np.nan] * 6)
    with pytest.raises(ValueError, match="truth"):
        orbits.truth_samples("sgp4", 10.0)


def test_phi_matches_finite_difference_of_propagation():
    x = np.concatenate([orbits.X0_A, orbits.X0_B])
    ph = stkf.Phi(x, 1.0)
    J = np.zeros((12, 12))
    for i in range(12):
        h = 10.0 if i % 6 < 3 else 0.1
        e = np.zeros(12)
        e[i] = h
        J[:, i] = (stkf.f(x + e, 1.0) - stkf.f(x - e, 1.0)) / (2 * h)
    np.testing.assert_allclose(ph, J, atol=1e-8)


def test_beacon_jacobian_matches_finite_difference():
    x = np.concatenate([orbits.X0_A, orbits.X0_B])
    A = stkf_sim.small_rotation(np.array([0.3, -0.2, 0.5]))
    H = stkf.H_beacon(x, A)
    J = np.zeros((3, 12))
    for i in range(12):
        e = np.zeros(12)
        e[i] = 1.0
        J[:, i] = (stkf.h_beacon(x + e, A) - stkf.h_beacon(x - e, A)) / 2.0
    np.testing.assert_allclose(H, J, atol=1e-12)


def test_gnss_and_beacon_stacked_measurement():
    """The stacked update of SatA's GNSS and the beacon (stkf_sim and bps): h, H of each part stacked, R block
    diagonal (independent noises); the attitude term of the beacon's R (Eq. 5.15-5.16) lies across the line
    of sight only: y^T R_b y = sigma_b^2, across it the attitude covariance adds."""
    x = np.concatenate([orbits.X0_A, orbits.X0_B])
    A = stkf_sim.small_rotation(np.array([0.3, -0.2, 0.5]))
    h, H = stkf.gnss_beacon(x, A)
    np.testing.assert_allclose(h, np.concatenate([x[0:6], stkf.h_beacon(x, A)]), rtol=1e-12)
    np.testing.assert_array_equal(H[0:6], np.hstack([np.eye(6), np.zeros((6, 6))]))
    np.testing.assert_allclose(H[6:9], stkf.H_beacon(x, A), rtol=1e-12, atol=1e-20)
    R_g = Gnss(np.random.default_rng(0)).R
    sb, P_att = 60 * RAD_PER_ARCSEC, np.diag((np.array([9.81, 8.01, 19.70]) * RAD_PER_ARCSEC) ** 2)
    y = stkf.h_beacon(x, A)
    R = stkf.R_gnss_beacon(R_g, y, sb, P_att)
    assert R.shape == (9, 9) and np.all(R[0:6, 6:9] == 0) and np.all(R[6:9, 0:6] == 0)
    np.testing.assert_array_equal(R[0:6, 0:6], R_g)
    np.testing.assert_array_equal(R[6:9, 6:9], stkf.R_beacon(y, sb, P_att))
    assert y @ R[6:9, 6:9] @ y == pytest.approx(sb ** 2, rel=1e-9)
    e = np.cross(y, [0.0, 0.0, 1.0])
    e /= np.linalg.norm(e)
    assert e @ R[6:9, 6:9] @ e > 1.01 * sb ** 2


def test_pointing_covariance_matches_sampled_errors():
    """Eq. 5.59 against the sample covariance of Eq. 5.58 errors drawn from P and P_att."""
    rng = np.random.default_rng(3)
    x = np.concatenate([orbits.X0_A, orbits.X0_B])
    M = rng.normal(size=(12, 12))
    P = M @ M.T * 400.0 + np.diag([50.0 ** 2] * 12)
    P_att = np.diag((np.array([9.81, 8.01, 19.7]) * RAD_PER_ARCSEC) ** 2)
    A = np.eye(3)
    Pz = stkf.pointing_covariance(x, P, A, P_att)
    L = np.linalg.cholesky(P)
    errs = []
    for _ in range(4000):
        xt = x - L @ rng.normal(size=12)
        At = stkf_sim.small_rotation(np.sqrt(np.diag(P_att)) * rng.normal(size=3)) @ A
        errs.append(stkf.pointing_error(x, A, xt, At))
    S = np.cov(np.array(errs).T)
    np.testing.assert_allclose(np.sqrt(np.diag(S)), np.sqrt(np.diag(Pz)), rtol=0.06)
    T = stkf.T_b2z(stkf.pointing(x, A))
    np.testing.assert_allclose(T @ T.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(T @ stkf.pointing(x, A), [0, 0, 1], atol=1e-12)


def _orbit_problem(seed=4, K=25):
    """Measurements of a short Case 2 run: SatA GNSS each second, SatB GNSS at t+0.37 s delivered 2-3 s late."""
    rng = np.random.default_rng(seed)
    _, xs = orbits.truth_samples("two-body", K + 1.0)
    t_s = np.arange(xs.shape[0], dtype=float)
    g = Gnss(rng)
    ga = {k: g.measure(xs[k, 0]) for k in range(1, K + 1)}
    tb = np.arange(0, K - 3) + 0.37
    xb = lagrange(t_s, xs[:, 1, :], tb, order=10)
    gb = [(tb[j], int(np.ceil(tb[j] + rng.uniform(2, 3))), g.measure(xb[j])) for j in range(tb.size)]
    x0 = xs[0].ravel() + rng.normal(size=12) * np.repeat([100.0, 0.5, 100.0, 0.5], 3)
    P0 = np.diag(np.repeat([100.0 ** 2, 0.5 ** 2, 100.0 ** 2, 0.5 ** 2], 3))
    return x0, P0, ga, gb, g.R, K


def test_eafls_matches_in_order_ekf_on_the_orbit_problem():
    """EAFLS (Eq. 5.43-5.52) vs an EKF re-run with every measurement in time order.

    Stated tolerance: 1 mm and 1e-6 m/s on the state, 1e-6 relative on the covariance diagonal (the two
    differ only by where the dynamics are linearised; both are 1e-9-exact on a linear system)."""
    x0, P0, ga, gb, R, K = _orbit_problem()
    Ha, Hb = stkf.H_gnss("A"), stkf.H_gnss("B")
    flt = afls.Afls(x0, P0, 0.0, 4.0, stkf.f, stkf.Phi, stkf.Q)
    for k in range(1, K + 1):
        flt.predict(float(k))
        flt.update(ga[k], R, lambda x: x[:6], lambda x: Ha)
        for tm, kd, z in gb:
            if kd == k:
                flt.update(z, R, lambda x: x[6:], lambda x: Hb, t=tm)
    meas = sorted([(float(k), "A", z) for k, z in ga.items()] + [(tm, "B", z) for tm, kd, z in gb if kd <= K])
    x, P, t = x0.copy(), P0.copy(), 0.0
    for tm, s, z in meas:
        if tm > t:
            x, P = stkf.predict(x, P, tm - t)
            t = tm
        H = Ha if s == "A" else Hb
        x, P = stkf.update(x, P, z, R, H, H @ x)
    assert t == K
    np.testing.assert_allclose(flt.x[[0, 1, 2, 6, 7, 8]], x[[0, 1, 2, 6, 7, 8]], atol=1e-3)
    np.testing.assert_allclose(flt.x[[3, 4, 5, 9, 10, 11]], x[[3, 4, 5, 9, 10, 11]], atol=1e-6)
    np.testing.assert_allclose(np.diag(flt.Pk), np.diag(P), rtol=1e-6)
    assert flt.generated == len([g for g in gb if g[1] <= K])
    # without SatB's GNSS the SatB estimate is far worse: the delayed data did act
    assert np.sqrt(P[6, 6]) < 0.5 * np.sqrt(P0[6, 6])


def test_case2_short_run_is_consistent_and_case1_keeps_pointing():
    r2, h2 = stkf_sim.simulate(2, 200.0, seed=5)
    r1, h1 = stkf_sim.simulate(1, 200.0, seed=5)
    assert r2["oosm_nodes_generated"] > 150
    assert r2["final_sigma_rb_m"] < 30 < r1["final_sigma_rb_m"]
    # errors inside 4 sigma after convergence, every state
    z = np.abs(h2["err"][50:] / h2["sig"][50:])
    assert np.mean(z < 3) > 0.95 and z.max() < 5
    # pointing known far better than SatB's position alone would give (Sec. 5.5.3)
    rho = 2.3e6
    assert r1["final_sigma_pointing_arcsec"] < 0.2 * r1["final_sigma_rb_m"] / rho / RAD_PER_ARCSEC


def test_bad_measurements_refused_by_the_filter():
    x0, P0, ga, gb, R, K = _orbit_problem(K=8)
    Ha = stkf.H_gnss("A")
    flt = afls.Afls(x0, P0, 0.0, 4.0, stkf.f, stkf.Phi, stkf.Q)
    for k in range(1, 8):
        flt.predict(float(k))
    with pytest.raises(ValueError, match="longer than the smoother's lag"):
        flt.update(ga[1], R, lambda x: x[:6], lambda x: Ha, t=1.5)
    with pytest.raises(ValueError, match="future"):
        flt.update(ga[1], R, lambda x: x[:6], lambda x: Ha, t=7.2)
    bad = ga[5].copy()
    bad[2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        flt.update(bad, R, lambda x: x[:6], lambda x: Ha, t=5.0)
    with pytest.raises(ValueError, match="longer than the smoother's lag"):
        stkf_sim.simulate(2, 10.0, lag_s=2.0)
    for text in ("gps:1:2", "beacon:5:1", "relay:x:3"):
        with pytest.raises(ValueError, match="outage"):
            stkf_sim.parse_outage(text)


def test_outages_propagate_on_and_are_reported():
    r, h = stkf_sim.simulate(2, 300.0, seed=2, outages=["gnss_a:100:160", "relay:80:240", "beacon:150:170"])
    sensors = {(o["sensor"], o["to_s"] is None) for o in r["outages"]}
    assert ("gnss_a", False) in sensors and ("relay", False) in sensors and ("beacon", False) in sensors
    assert any("no relay" in line for line in r["log"]) and any("gnss_a back" in line for line in r["log"])
    assert h["sig"][159, 0] > 2 * h["sig"][99, 0]           # SatA's sigma grew while propagating
    assert np.all(np.isfinite(h["err"])) and h["sig"][-1, 6] < 30    # and came back after


def test_cli_summary_keys_report_and_plots(tmp_path, capsys):
    from ground.cli import main
    out = tmp_path / "run"
    rc = main(["adcs", "stkf", "--case", "2", "--duration", "60", "--runs", "2", "--workers", "1",
               "--truth", "two-body", "--quiet", "-o", str(out)])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    for k in ("final_sigma_ra_m", "final_sigma_va_m_s", "final_sigma_rb_m", "final_sigma_vb_m_s",
              "final_sigma_pointing_arcsec", "runs", "complete"):
        assert k in s
    assert s["complete"] is True and s["runs"] == 2
    rep = (out / "report.md").read_text()
    assert "| rB (m) | 9.21 |" in rep
    assert (out / "fig5-6_states.png").exists() and (out / "fig5-7_pointing.png").exists()
    assert (out / "run_0001" / "run.log").exists()


def test_cli_bad_input_and_interrupt(tmp_path, capsys, monkeypatch):
    from ground.cli import main
    from ground.adcs import campaign
    assert main(["adcs", "stkf", "--case", "2", "--lag", "2", "-o", str(tmp_path / "a")]) == 2
    assert "lag" in capsys.readouterr().err
    assert main(["adcs", "stkf", "--case", "1", "--runs", "0", "-o", str(tmp_path / "b")]) == 2
    assert main(["adcs", "stkf", "--case", "1", "--outage", "sun:1:2", "-o", str(tmp_path / "c")]) == 2
    assert main(["adcs", "stkf", "--case", "1", "--outage", "relay:1:2", "-o", str(tmp_path / "c")]) == 2
    assert "no relay" in capsys.readouterr().err
    assert main(["adcs", "stkf", "--case", "1", "--duration", "100", "--outage", "beacon:100:200", "-o",
                 str(tmp_path / "d")]) == 2
    assert "starts at or after the run's end (--duration 100 s)" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(campaign, "run_campaign", interrupted)
    out = tmp_path / "d"
    rc = main(["adcs", "stkf", "--case", "1", "--truth", "two-body", "--duration", "20", "--quiet", "-o", str(out)])
    assert rc == 130
    assert json.loads((out / "summary.json").read_text())["complete"] is False


def test_apkf_attitude_feeds_the_beacon_noise():
    """With the APKF in the same simulation the body rotates (Sec. 4.8 scenario) and P_att is the APKF's."""
    A_true, A_hat, P_att = stkf_sim.apkf_attitude(0, 40)
    assert np.abs(A_true[40] - A_true[0]).max() > 1e-3            # the scenario's attitude moves
    ang = [np.arccos(np.clip((np.trace(A_hat[k] @ A_true[k].T) - 1) / 2, -1, 1)) for k in (10, 40)]
    assert max(ang) < 10 * np.sqrt(np.trace(P_att[40]))         # estimate near truth, in its own sigma
    r, h = stkf_sim.simulate(1, 40.0, seed=0, attitude="apkf")
    assert r["attitude"] == "apkf" and np.all(np.isfinite(h["psig"]))
    with pytest.raises(ValueError, match="attitude"):
        stkf_sim.simulate(1, 10.0, attitude="gyro")
