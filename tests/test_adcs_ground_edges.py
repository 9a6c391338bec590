"""ADCS ground edge cases: the datasheet wheels in bps, a diverged MEKF named, friction defaults, Phi truncation."""

import numpy as np
import pytest

from emulator.spacecraft.wheels import WheelParams, Wheels
from ground.adcs import control, mekf, runs


def test_a_diverged_mekf_run_is_named_as_the_mekf(monkeypatch):
    """run_mekf's divergence check used the APKF's message: a diverged MEKF was reported as "APKF diverged"."""
    real = mekf.MEKF.step

    def step(self, w_meas, q_meas=None):
        x, P = real(self, w_meas, q_meas)
        self.P[4, 4] = np.nan
        return x, self.P

    monkeypatch.setattr(mekf.MEKF, "step", step)
    with pytest.raises(FloatingPointError, match=r"^MEKF diverged at t = \d+ s: P is not finite"):
        runs.run_mekf(0, None, params={"duration_s": 10})


def test_friction_compensation_defaults_are_the_wheel_datasheet():
    """control.friction_compensation says it is the datasheet model; its default Coulomb smoothing was 10 rpm
    where the wheels' model (WheelParams) smooths over 1 rpm, so near zero speed the defaults compensated
    a tenth of the friction."""
    W = np.array([-3.0, -0.2, 0.05, 0.5]) * 2 * np.pi / 60          # rad/s, near zero speed
    w = Wheels(WheelParams())
    assert np.allclose(control.friction_compensation(W), w.friction(W), rtol=1e-12, atol=0)


def test_phi_series_truncation_at_the_scenarios_wheel_speeds():
    """apkf's docstring said A dt was ~0.03 (truncation < 1e-8); with the Sec. 4.8 wheels near 12 000 rpm the
    [H x] term makes |A dt| ~0.5 (measured over the 930 s run: up to 0.55). What the docstring now states: the
    4th-order series stays within 1e-6 of expm there."""
    from scipy.linalg import expm

    from ground.adcs import apkf
    model = apkf.Model()
    x = apkf.initial_state(np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9]),
                           np.radians([1.5, -1.0, 1.2]), np.array([12000.0, -11000.0, 9000.0, -10000.0]) * np.pi / 30)
    A = apkf.jacobian(x, model, 100.0)[0:6, 0:6]
    assert 0.3 < np.linalg.norm(A, 2) < 1.0
    E = apkf._series(A, 1.0, 4)[0]
    assert np.abs(E - expm(A)).max() < 1e-6


def test_bps_flight_software_uses_the_wheel_datasheet_not_the_truth(monkeypatch):
    """The flight software bps.simulate flies (the app, in a session) takes the torque limit and the friction
    model for its compensation from the spacecraft file (the datasheet), not from the emulated wheels' own
    parameters (the truth): a wheel whose friction differs from its datasheet is not compensated exactly."""
    from emulator.spacecraft import scenario
    from emulator.spacecraft.dynamics import Spacecraft
    from firmware.adcs import allocation
    from ground.adcs import body_pointing as bps

    real_world = scenario.pointing_world

    def world(*a, **kw):                                 # the truth's wheels: 5x the datasheet friction
        w = real_world(*a, **kw)
        w.wheels.p.friction_coulomb *= 5.0
        w.wheels.p.friction_viscous *= 5.0
        return w

    seen = []
    real_init = allocation.Allocation.__init__

    def init(self, *a, **kw):
        real_init(self, *a, **kw)
        seen.append((tuple(self.fric), self.torque_max))

    monkeypatch.setattr(scenario, "pointing_world", world)
    monkeypatch.setattr(allocation.Allocation, "__init__", init)
    sc = Spacecraft(wheels=Wheels(WheelParams(**scenario.SCENARIO_WHEELS)))
    res, _ = bps.simulate(ts=1.0, duration_s=1.0, seed=0, params=scenario.truth_params(sc), hold_s=2.0)
    d = WheelParams()
    assert res["complete"] and len(seen) == 1
    assert seen[0] == ((d.friction_coulomb, d.friction_viscous, d.friction_smooth_rpm * 2 * np.pi / 60),
                       scenario.thesis_3u()["wheels"]["torque_limit_nm"])
