"""Bad input to the spacecraft emulator and its sensors gets a clear ValueError, never a silent NaN or no-op."""

import numpy as np
import pytest

from emulator.navsensors import Beacon
from emulator.spacecraft import StarTracker, WheelParams, Wheels
from emulator.spacecraft.dynamics import Spacecraft
from emulator.spacecraft.environment import CircularOrbit

NAN = float("nan")


@pytest.mark.parametrize("kw, key", [
    (dict(sigma_arcsec=(NAN, 20.0, 60.0)), "sigma_arcsec"),
    (dict(sigma_arcsec=(20.0, float("inf"), 60.0)), "sigma_arcsec"),
    (dict(rate_max_dps=NAN), "rate_max_dps"),
    (dict(rate_max_dps=-0.1), "rate_max_dps"),
])
def test_startracker_refuses_bad_noise_or_rate_limit(kw, key):
    with pytest.raises(ValueError, match=key):
        StarTracker(np.random.default_rng(0), **kw)


def test_startracker_with_good_figures_still_measures():
    st = StarTracker(np.random.default_rng(0), sigma_arcsec=(0.0, 0.0, 0.0), rate_max_dps=0.1)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    qm, valid = st.measure(q, np.zeros(3))
    assert valid and np.allclose(qm, q)


@pytest.mark.parametrize("duration", [-1.0, NAN, float("inf")])
def test_run_refuses_a_negative_or_non_finite_duration(duration):
    sc = Spacecraft(wheels=Wheels(WheelParams.ideal()), orbit=None)
    with pytest.raises(ValueError, match="duration"):
        sc.run(duration)
    assert sc.steps == 0 and sc.t == 0.0


def test_run_counts_the_steps_it_took():
    sc = Spacecraft(wheels=Wheels(WheelParams.ideal()), orbit=None, dt=0.5)
    assert sc.run(2.0) == 4 and sc.steps == 4 and sc.t == pytest.approx(2.0)
    assert sc.run(0.0) == 0


@pytest.mark.parametrize("m", [(NAN, 0.0, 0.0), (0.1, 0.2), "abc"])
def test_dipole_must_be_three_finite_numbers(m):
    with pytest.raises(ValueError, match="dipole"):
        Spacecraft(wheels=Wheels(WheelParams.ideal()), dipole=m)
    sc = Spacecraft(wheels=Wheels(WheelParams.ideal()))
    before = sc.dipole
    with pytest.raises(ValueError, match="dipole"):
        sc.dipole = m
    assert np.array_equal(sc.dipole, before)               # the old value is kept


@pytest.mark.parametrize("i", [1.5, -1, 4, "1"])
def test_wheel_command_refuses_a_bad_index(i):
    w = Wheels(WheelParams.ideal())
    with pytest.raises(ValueError, match="index"):
        w.command(i, 1e-4)
    assert not w.cmd.any()


def test_beacon_refuses_coincident_satellites():
    b = Beacon(np.random.default_rng(0))
    r = np.array([7e6, 0.0, 0.0])
    with pytest.raises(ValueError, match="coincide"):
        b.measure(r, r, (0.0, 0.0, 0.0, 1.0))


@pytest.mark.parametrize("kw", [dict(inclination_deg=NAN), dict(raan_deg=float("inf")), dict(arg_lat_deg=NAN)])
def test_circular_orbit_refuses_non_finite_angles(kw):
    with pytest.raises(ValueError, match="deg"):
        CircularOrbit(**kw)
