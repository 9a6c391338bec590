"""The lean STKF's J2 model (firmware/adcs/stkf_kernels.py, ``gravity="j2"``): the two-body default unchanged bit
for bit, the J2 acceleration against its closed form and against the potential's gradient, phi against a
numerical Jacobian of f, a propagation against brahe's J2 model, the same results under micropython, and the
configuration's refusals."""

import json
from array import array

import numpy as np
import pytest

from firmware.adcs import estimation
from firmware.adcs import stkf_kernels as K
from firmware.adcs import stkf_lean
from protocol.units import J2_EARTH, MU_EARTH, R_EARTH_EQ
from tests.adcs_lean_common import run_mp

# LEO states [r (m), v (m/s)]: 51.65 deg, near-polar, over the north pole and on the equator
STATES = (np.array([4.1e6, -3.2e6, 4.2e6, 4.9e3, 5.3e3, 0.3e3]),
          np.array([1.0e6, 0.5e6, 6.8e6, -3.5e3, 6.6e3, 0.0]),
          np.array([0.0, 0.0, 6.9e6, 7.6e3, 0.0, 0.0]),
          np.array([6.9e6, 0.0, 0.0, 0.0, 7.6e3, 0.0]))


def _f(x6, dt, j2):
    b = array("d", list(x6))
    K.f(b, 0, dt, j2)
    return np.array(b)


def _phi(x6, dt, j2):
    b = array("d", bytes(8 * 36))
    K.phi(b, array("d", list(x6)), 0, dt, j2)
    return np.array(b).reshape(6, 6)


def _accel(r, j2):
    """f's acceleration at r: one RK4 step of h = 1 ms from rest, dv / h (its error ~|G| h^2, 1e-12 relative)."""
    h = 1e-3
    return _f(np.concatenate([r, np.zeros(3)]), h, j2)[3:6] / h


def _closed_form(r):
    x, y, z = r
    rn = np.linalg.norm(r)
    k = -1.5 * J2_EARTH * MU_EARTH * R_EARTH_EQ ** 2 / rn ** 5
    w = 5.0 * z * z / rn ** 2
    return k * np.array([x * (1 - w), y * (1 - w), z * (3 - w)])


def _potential(r):
    """U (m^2/s^2, a = -grad U) of the two-body and J2 terms: -mu/|r| (1 - J2 (R/|r|)^2 P2(z/|r|))."""
    rn = np.linalg.norm(r)
    s = r[2] / rn
    return -MU_EARTH / rn * (1.0 - J2_EARTH * (R_EARTH_EQ / rn) ** 2 * 0.5 * (3 * s * s - 1))


def test_two_body_default_is_the_ground_models_bit_for_bit():
    """f and phi without j2 (and with j2 = 0.0) are the two-body model: f equals the ground STKF's RK4
    (ground/adcs/stkf.py) bit for bit; the configuration without the keys gives the thesis's model and qa."""
    from ground.adcs import stkf
    for x in STATES:
        for dt in (1.0, 0.37, 3.5, -2.0):
            b = array("d", list(x))
            K.f(b, 0, dt)
            assert np.array_equal(np.array(b), stkf.f(x, dt))
            assert np.array_equal(np.array(b), _f(x, dt, 0.0))
        P0 = array("d", bytes(8 * 36))
        K.phi(P0, array("d", list(x)), 0, 1.0)
        assert np.array_equal(np.array(P0).reshape(6, 6), _phi(x, 1.0, K.GRAVITY["two-body"]))
    assert estimation.stkf_model({}) == {"gravity": "two-body", "qa": K.QA_THESIS}
    f = stkf_lean.LeanStkf(list(STATES[0]) * 2, [1.0] * 12, 0.0)
    assert f.j2 == 0.0 and f.qa == K.QA_THESIS


def test_j2_acceleration_against_its_closed_form_and_the_potential():
    """f's acceleration with j2 minus without it is the closed-form J2 term (~1e-2 m/s^2 in LEO), and the whole
    is minus the numerical gradient of the two-body + J2 potential."""
    for x in STATES:
        r = x[0:3]
        a2, a0 = _accel(r, K.J2_TERM), _accel(r, 0.0)
        aj = _closed_form(r)
        assert 5e-3 < np.linalg.norm(aj) < 3e-2
        assert np.allclose(a2 - a0, aj, rtol=1e-6, atol=1e-11)
        h = 10.0
        grad = np.array([(_potential(r + h * e) - _potential(r - h * e)) / (2 * h) for e in np.eye(3)])
        assert np.allclose(a2, -grad, rtol=0, atol=5e-8)
        assert np.abs(a0 + grad).max() > 1e-3          # the two-body model is not the potential's


def test_phi_against_a_numerical_jacobian_of_f_over_1_s():
    """phi with j2 is f's Jacobian over 1 s to the order it is built (Eq. 3.30 at the step's start): in the
    blocks of G its error is several times smaller than the two-body phi's against the same J2 f (the J2
    gradient, ~4e-3 of G); the I dt block is within the central differences' rounding."""
    for x in STATES:
        J = np.zeros((6, 6))
        for j, d in enumerate((1.0, 1.0, 1.0, 0.1, 0.1, 0.1)):
            e = np.zeros(6)
            e[j] = d
            J[:, j] = (_f(x + e, 1.0, K.J2_TERM) - _f(x - e, 1.0, K.J2_TERM)) / (2 * d)
        for rows, cols in ((slice(0, 3), slice(0, 3)), (slice(3, 6), slice(0, 3)), (slice(3, 6), slice(3, 6))):
            err_j2 = np.abs(_phi(x, 1.0, K.J2_TERM) - J)[rows, cols].max()
            err_2b = np.abs(_phi(x, 1.0, 0.0) - J)[rows, cols].max()
            assert err_j2 < 2.5e-9 and err_2b > 2.0 * err_j2
        assert np.abs(_phi(x, 1.0, K.J2_TERM) - J)[0:3, 3:6].max() < 6e-9     # the differences' rounding: 7e6 m
        Pj = _phi(x, 1.0, K.J2_TERM)
        assert np.allclose(Pj[3:6, 0:3], Pj[3:6, 0:3].T, rtol=0, atol=1e-18)    # G is a Hessian: symmetric


def test_propagation_against_brahes_j2_model():
    """600 s of f with j2 (RK4, 1 s steps) against a DOP853 integration of brahe's two-body + J2 acceleration
    (its EGM2008 J2 and R: the J2 term ~7e-7 apart from ours, ~1 mm in 600 s): within 5 cm, where the two-body
    model is ~1 km off."""
    brahe = pytest.importorskip("brahe")
    from scipy.integrate import solve_ivp
    for x in STATES[0:2]:
        sol = solve_ivp(lambda t, s: np.concatenate([s[3:6], brahe.accel_earth_zonal_gravity(s[0:3], 2)]),
                        (0.0, 600.0), x, method="DOP853", rtol=1e-12, atol=1e-9)
        ref = sol.y[:, -1]
        assert np.linalg.norm(_f(x, 600.0, K.J2_TERM)[0:3] - ref[0:3]) < 0.05
        assert np.linalg.norm(_f(x, 600.0, 0.0)[0:3] - ref[0:3]) > 100.0


def test_j2_kernels_under_micropython_as_under_cpython(tmp_path):
    """The J2 kernels under the unix port give CPython's results (float64 on both)."""
    job = {"x": [list(x) for x in STATES], "dt": [1.0, -2.5]}
    p = tmp_path / "job.json"
    p.write_text(json.dumps(job))
    res = run_mp("stkf_j2.py", p)
    k = 0
    for x in STATES:
        for dt in job["dt"]:
            assert np.allclose(res["f"][k], _f(x, dt, K.J2_TERM), rtol=1e-14, atol=0)
            assert np.allclose(res["phi"][k], _phi(x, dt, K.J2_TERM).ravel(), rtol=1e-13, atol=1e-20)
            k += 1


def test_j2_filter_runs_and_differs_from_two_body():
    """A LeanStkf with gravity="j2" predicts with the J2 term: SatA's state after 100 s differs from the
    two-body filter's by the J2 term's ~50 m, and the generated node's kernels take it (no refusal)."""
    x0 = list(STATES[0]) + list(STATES[1])
    fs = [stkf_lean.LeanStkf(x0, [100.0] * 12, 0.0, gravity=g, qa=5e-6) for g in ("two-body", "j2")]
    for f in fs:
        for k in range(1, 101):
            f.predict(float(k))
    d = np.linalg.norm(np.array(fs[1].xa[0:3]) - np.array(fs[0].xa[0:3]))
    ref = np.linalg.norm(_f(STATES[0], 100.0, K.J2_TERM)[0:3] - _f(STATES[0], 100.0, 0.0)[0:3])
    assert 10.0 < d == pytest.approx(ref, rel=1e-9)


@pytest.mark.parametrize("cfg, msg", [({"stkf_gravity": "J2"}, "stkf_gravity must be one of j2, two-body"),
                                      ({"stkf_gravity": None}, "stkf_gravity must be one of"),
                                      ({"stkf_qa": 0.0}, "stkf_qa must be a number > 0"),
                                      ({"stkf_qa": "0.01"}, "stkf_qa must be a number > 0"),
                                      ({"stkf_qa": float("inf")}, "stkf_qa must be a number > 0"),
                                      ({"stkf_qa": True}, "stkf_qa must be a number > 0")])
def test_bad_configuration_is_refused_with_its_key(cfg, msg):
    with pytest.raises(ValueError, match=msg):
        estimation.stkf_model(cfg)


def test_lean_stkf_refuses_a_bad_model():
    x0 = list(STATES[0]) * 2
    with pytest.raises(ValueError, match="gravity model must be one of j2, two-body"):
        stkf_lean.LeanStkf(x0, [1.0] * 12, 0.0, gravity="j3")
    with pytest.raises(ValueError, match="process noise qa must be > 0"):
        stkf_lean.LeanStkf(x0, [1.0] * 12, 0.0, qa=-1.0)


def test_flight_world_configures_j2_under_hpop_and_the_others_do_not(tmp_path):
    """The session's configuration: the flight world's STKF flies J2 with its derived qa under the hpop truth;
    the thesis world, and the flight world over a two-body truth (an Earth without J2), have neither key (the
    thesis's two-body model and qa)."""
    from emulator.adcs_session import AdcsSession
    from emulator.spacecraft.scenario import FLIGHT_STKF
    cfg = {(w, t): AdcsSession(runtime="inproc", duration_s=2.0, world=w, truth=t, cache_dir=str(tmp_path)).config()
           for w, t in (("thesis", "hpop"), ("flight", "hpop"), ("flight", "two-body"))}
    j2 = cfg["flight", "hpop"]
    assert {k: j2[k] for k in FLIGHT_STKF} == {"stkf_gravity": "j2", "stkf_qa": FLIGHT_STKF["stkf_qa"]}
    assert estimation.stkf_model(j2) == {"gravity": "j2", "qa": FLIGHT_STKF["stkf_qa"]}
    for key in (("thesis", "hpop"), ("flight", "two-body")):
        assert "stkf_gravity" not in cfg[key] and "stkf_qa" not in cfg[key]
