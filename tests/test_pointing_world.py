"""The body-pointing scenario's world (``emulator.spacecraft.scenario.pointing_world``): ground/adcs/body_pointing.py's
``simulate`` and emulator/adcs_session.py's ``AdcsSession`` build it through the one builder and get the same
world for the same seed and length (the "same scenario" the benches and ``fps system`` compare on)."""

import copy

import numpy as np
import pytest

from emulator import adcs_session
from emulator.spacecraft import scenario
from ground.adcs import body_pointing as bps

TS, DURATION, SEED = 33.0, 1.0, 4
K = int(np.ceil(bps.HOLD_S + 4 * TS + DURATION))     # simulate's run length for TS, DURATION


def first_outputs(w):
    """The first outputs of a world's sensors and relay, drawn on a copy (the world is left as it was)."""
    w = copy.deepcopy(w)
    x = w.xg[0].ravel()
    q, ok = w.st.measure(w.sc.q, w.sc.omega)
    out = {"st": q, "st_ok": ok, "gnss_a": w.gnss_a.measure(x[0:6]), "beacon": w.beacon.measure_dcm(x[0:3], x[6:9], np.eye(3)),
           "tach": w.wheels.read_speed_rpm(w.sc.omega_rw_rel), "relay": None}
    if w.relay is not None:
        for tb, xb in zip(w.tb[:5], w.xb_tb[:5]):
            w.relay.sample(tb, xb)
        out["relay"] = [(tm, z) for tm, z in w.relay.due(10.0)]
    return out


def assert_same_outputs(a, b):
    for key in ("st", "gnss_a", "beacon", "tach"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert a["st_ok"] == b["st_ok"]
    assert (a["relay"] is None) == (b["relay"] is None)
    if a["relay"] is not None:
        assert len(a["relay"]) == len(b["relay"]) == 5
        for (ta, za), (tb, zb) in zip(a["relay"], b["relay"]):
            assert ta == tb
            np.testing.assert_array_equal(za, zb)


@pytest.fixture
def built(monkeypatch):
    """Every world the builder makes, as built (a deep copy taken before its caller draws from it)."""
    worlds = []
    real = scenario.pointing_world

    def spy(*args, **kw):
        w = real(*args, **kw)
        worlds.append(copy.deepcopy(w))
        return w
    monkeypatch.setattr(scenario, "pointing_world", spy)
    return worlds


@pytest.mark.parametrize("satb", [False, True])
def test_bps_flies_the_sessions_world(built, satb, monkeypatch):
    """bps.simulate flies the flight app in a session (``AdcsSession(runtime="inproc")``): its world is the one a
    session of the same length builds, and its STKF starts from that world's start."""
    from ground.adcs import afls
    params = scenario.truth_params(scenario.pointing_world(K, 0).sc)
    built.clear()
    x0_used = []
    real_afls = afls.Afls

    def spy(x0, *args, **kw):
        x0_used.append(np.array(x0, copy=True))
        return real_afls(x0, *args, **kw)
    monkeypatch.setattr(afls, "Afls", spy)
    res, hist = bps.simulate(ts=TS, duration_s=DURATION, seed=SEED, params=params, truth="two-body",
                             satb_gnss=satb)
    assert res["simulated_s"] == K and len(built) == 1
    s = adcs_session.AdcsSession(runtime="cpython", duration_s=float(K), seed=SEED, ts=TS, params=params,
                                 satb_gnss=satb)                      # not started: the world only
    assert len(built) == 2
    g, e = built                                                      # bps's, a session's
    assert g.K == e.K == K and g.rate == e.rate == scenario.WORLD_RATE_HZ
    np.testing.assert_array_equal(g.xg, e.xg)
    np.testing.assert_array_equal(x0_used[0], g.stkf_x0)               # what bps's STKF started from
    assert s.config()["stkf_x0"] == g.stkf_x0.tolist() and s.config()["stkf_P0"] == scenario.STKF_P0_DIAG
    np.testing.assert_array_equal(hist["q"][0], g.sc.q)              # bps's truth starts where its world does
    assert_same_outputs(first_outputs(g), first_outputs(e))
    assert g.tb.size == e.tb.size == (K + 1 if satb else 0)
    if not satb:
        assert g.relay is None and e.relay is None and g.xb_tb is None


def test_the_world_depends_on_its_inputs():
    a, b = scenario.pointing_world(40, 1, True), scenario.pointing_world(40, 1, True)
    np.testing.assert_array_equal(a.stkf_x0, b.stkf_x0)
    assert_same_outputs(first_outputs(a), first_outputs(b))
    # SatB's GNSS draws from its own streams: the rest of the world is the same with it or without it
    c = scenario.pointing_world(40, 1, False)
    np.testing.assert_array_equal(c.stkf_x0, a.stkf_x0)
    oa, oc = first_outputs(a), first_outputs(c)
    for key in ("st", "gnss_a", "beacon", "tach"):
        np.testing.assert_array_equal(oa[key], oc[key])
    x = a.xg[0].ravel()
    for tb, xb in zip(a.tb[:5], a.xb_tb[:5]):                     # SatB's fixes taken, then SatA's: as without
        a.relay.sample(tb, xb)
    np.testing.assert_array_equal(a.gnss_a.measure(x[0:6]), c.gnss_a.measure(x[0:6]))
    # another seed, another world (same truth)
    d = scenario.pointing_world(40, 2, True)
    np.testing.assert_array_equal(d.xg, a.xg)
    assert not np.array_equal(d.stkf_x0, a.stkf_x0) and not np.array_equal(d.tb, a.tb)
    assert not np.array_equal(first_outputs(d)["gnss_a"], oa["gnss_a"])
    # the STKF starts off the truth by its P0: 4 km and 0.1 km/s 1 sigma (12 draws: well inside 6 sigma)
    dx = (a.stkf_x0 - a.xg[0].ravel()) / np.sqrt(scenario.STKF_P0_DIAG)
    assert np.all(np.abs(dx) < 6) and np.all(dx != 0)
    # the grid: 20 Hz over [0, K + 1] s, SatA's position on it as the spacecraft's orbit
    assert a.xg.shape == (41 * 20 + 1, 2, 6) and a.tg[-1] == 41.0
    assert a.sc.orbit is a.orbit and np.array_equal(a.orbit.position(12.35), a.xg[247, 0, 0:3])


def test_truth_span_keeps_each_callers_cache_key():
    assert bps.truth_span(992) == 1000.0 and bps.truth_span(993) == 2000.0         # bps flies a session
    assert scenario.truth_span(992, adcs_session.SPAN_MARGIN_S) == 1000.0
    assert scenario.truth_span(993, adcs_session.SPAN_MARGIN_S) == 2000.0


def gmst82_deg(y, mo, d, h, mi, s):
    """GMST (deg) by the IAU-1982 formula (Vallado, Eq. 3-47) with UT1 = UTC: an independent check of brahe."""
    a = (14 - mo) // 12
    yy, mm = y + 4800 - a, mo + 12 * a - 3
    jdn = d + (153 * mm + 2) // 5 + 365 * yy + yy // 4 - yy // 100 + yy // 400 - 32045
    jd = jdn - 0.5 + (h + mi / 60.0 + s / 3600.0) / 24.0
    t = (jd - 2451545.0) / 36525.0
    sec = 67310.54841 + (876600.0 * 3600 + 8640184.812866) * t + 0.093104 * t * t - 6.2e-6 * t ** 3
    return (sec / 240.0) % 360.0


def test_the_field_turns_from_the_epochs_gmst():
    """The body-pointing world's field starts at GMST of Eq. 5.53's epoch (139.40 deg), not at 0: the spacecraft,
    bps's APKF model and the firmware's configuration all use it."""
    from emulator import orbits
    from emulator.spacecraft.environment import OMEGA_EARTH
    g = orbits.epoch_gmst_rad()
    # UT1 - UTC was -0.5 s then: 0.002 deg of Earth rotation; the two GMST models agree far closer than 0.01 deg
    assert np.degrees(g) == pytest.approx(gmst82_deg(*orbits.EPOCH_UTC), abs=0.01)
    assert np.degrees(g) == pytest.approx(139.40, abs=0.01)
    w = scenario.pointing_world(40, 0)
    assert w.field.gmst0 == g and w.sc.field is w.field
    # at t the dipole has turned by gmst0 + w_E t: the field equals a zero-epoch field's at t + gmst0 / w_E
    r = w.orbit.position(3.0)
    zero = type(w.field)(gmst0_rad=0.0)
    np.testing.assert_allclose(w.field.field(r, 3.0), zero.field(r, 3.0 + g / OMEGA_EARTH), rtol=1e-9, atol=1e-15)
    assert np.degrees(np.arccos(w.field.field(r, 3.0) @ zero.field(r, 3.0)
                                / np.linalg.norm(w.field.field(r, 3.0)) / np.linalg.norm(zero.field(r, 3.0)))) > 1.0
    s = adcs_session.AdcsSession(runtime="cpython", duration_s=30.0)
    assert s.config()["gmst0_rad"] == g
    params = scenario.truth_params(w.sc)
    models = []
    real = bps.apkf.Model

    class Spy(real):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            models.append(self)
    import unittest.mock
    with unittest.mock.patch.object(bps.apkf, "Model", Spy):
        bps.simulate(ts=TS, duration_s=DURATION, seed=SEED, params=params, truth="two-body")
    assert models and models[0].field.gmst0 == g


def test_the_firmware_field_is_the_emulators():
    """firmware/adcs/estimation.py's field_dipole (the flight model) equals environment.TiltedDipoleField at the
    epoch's GMST, along an orbit and over hours (the Earth turns under it)."""
    from emulator import orbits
    from emulator.spacecraft.environment import TiltedDipoleField
    from firmware.adcs.estimation import field_dipole
    g = orbits.epoch_gmst_rad()
    f = TiltedDipoleField(gmst0_rad=g)
    b = [0.0, 0.0, 0.0]
    for t in (0.0, 1.5, 600.0, 7200.0, 43000.0):
        r = orbits.kepler(orbits.X0_A, np.array([t]))[0, 0:3]
        field_dipole(b, r.tolist(), t, g)
        np.testing.assert_allclose(b, f.field(r, t), rtol=1e-12, atol=1e-18)


def test_the_wheel_speed_limit_is_the_worlds_and_bps_reports_it():
    """The body-pointing world's wheels have no speed limit in effect (the thesis's Eq. 4.56), unless one is
    given; bps passes it on and reports the largest speed and the clips."""
    w = scenario.pointing_world(40, 0)
    assert w.wheels.speed_max == pytest.approx(scenario.POINTING_WHEEL_RPM * 2 * np.pi / 60)
    assert scenario.pointing_world(40, 0, wheel_speed_limit_rpm=900.0).wheels.speed_max == \
        pytest.approx(900.0 * 2 * np.pi / 60)
    params = scenario.truth_params(w.sc)
    free, hf = bps.simulate(ts=TS, duration_s=DURATION, seed=SEED, params=params, truth="two-body")
    capped, hc = bps.simulate(ts=TS, duration_s=DURATION, seed=SEED, params=params, truth="two-body",
                              wheel_speed_limit_rpm=300.0)
    assert free["wheel_speed_limit_rpm"] == scenario.POINTING_WHEEL_RPM and capped["wheel_speed_limit_rpm"] == 300.0
    assert free["max_wheel_speed_rpm"] > 300.0 and sum(free["wheel_speed_clips"]["speed_clip"]) == 0
    assert capped["max_wheel_speed_rpm"] <= 300.0 + 1e-6 and sum(capped["wheel_speed_clips"]["speed_clip"]) > 0
