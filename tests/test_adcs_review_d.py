"""Review fixes (ADCS estimation and simulation): each test failed before its fix."""

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
