"""Reaction wheel assembly: geometry against the thesis (Eq. 4.147-4.149), limits, friction, read-out, jitter."""

import numpy as np
import pytest

from emulator.spacecraft.wheels import (RPM, WheelParams, Wheels, misaligned_c, misalignment_axes,
                                        pyramid_c0)

C_EQ_4_149 = np.array([[-0.76820, -0.72728, 0.36636, 0.70252],
                       [-0.39087, 0.39403, 0.68484, -0.59026],
                       [0.50703, 0.56195, 0.62988, 0.39755]])


def test_pyramid_is_symmetric_unit_axes():
    c0 = pyramid_c0()
    assert np.allclose(np.linalg.norm(c0, axis=0), 1.0)
    assert np.allclose(c0 @ c0.T, 4.0 / 3.0 * np.eye(3))     # symmetric pyramid: isotropic torque envelope


def test_misalignment_axes_orthonormal():
    c0 = pyramid_c0()
    c1, c2 = misalignment_axes(c0)
    for a, b in ((c0, c1), (c0, c2), (c1, c2)):
        assert np.allclose(np.sum(a * b, axis=0), 0.0, atol=1e-15)
    assert np.allclose(np.linalg.norm(c1, axis=0), 1.0) and np.allclose(np.linalg.norm(c2, axis=0), 1.0)


def test_true_c_matches_eq_4_149():
    assert np.abs(Wheels().c - C_EQ_4_149).max() < 1e-4       # printed to 5 digits
    assert np.allclose(misaligned_c(pyramid_c0(), np.zeros(4), np.zeros(4)), pyramid_c0())


@pytest.mark.parametrize("kw, key", [
    (dict(j_rw=(3e-6, 3e-6, -1e-6, 3e-6)), "j_rw"),
    (dict(j_rw=(3e-6, 3e-6, 3e-6)), "j_rw"),
    (dict(delta1_deg=(0, 0, float("nan"), 0)), "delta1_deg"),
    (dict(torque_max=0.0), "torque_max"),
    (dict(noise_rpm=-1.0), "noise_rpm"),
    (dict(noise_rpm=-1), "noise_rpm"),
    (dict(arm="4 cm"), "arm"),
    (dict(speed_max_rpm=float("inf")), "speed_max_rpm"),
])
def test_bad_params_name_the_field(kw, key):
    with pytest.raises(ValueError, match=key):
        WheelParams(**kw)


def test_bad_command_refused():
    w = Wheels()
    with pytest.raises(ValueError, match="index"):
        w.command(4, 0.0)
    with pytest.raises(ValueError, match="finite"):
        w.command(0, float("nan"))


def test_torque_and_speed_limits_clip_and_count():
    p = WheelParams.ideal()
    w = Wheels(p)
    w.command_all([2 * p.torque_max, -0.5 * p.torque_max, p.torque_max, -3 * p.torque_max])
    speed = np.array([0.0, 0.0, 0.999, 0.0]) * p.speed_max_rpm * RPM
    dt = 0.1
    tq = w.apply_limits(speed, dt)
    room = w.j[2] * (w.speed_max - speed[2]) / dt
    assert tq[0] == p.torque_max and tq[3] == -p.torque_max and tq[1] == -0.5 * p.torque_max
    assert tq[2] == pytest.approx(room)
    assert w.counters() == {"torque_clip": [1, 0, 0, 1], "speed_clip": [0, 0, 1, 0]}
    # braking a wheel above its limit is allowed; coasting (enable 0) applies nothing
    w.command(2, -p.torque_max)
    w.command(0, p.torque_max, enable=False)
    tq = w.apply_limits(np.array([0.0, 0.0, 1.01, 0.0]) * w.speed_max, dt)
    assert tq[2] == -p.torque_max and tq[0] == 0.0


def test_friction_opposes_spin_and_is_odd():
    w = Wheels(WheelParams(friction_coulomb=2e-6, friction_viscous=2e-10))
    s = np.array([-5000.0, -10.0, 10.0, 5000.0]) * RPM
    f = w.friction(s)
    assert np.all(np.sign(f) == np.sign(s))           # torque resisting the spin (subtracted from the motor)
    assert np.allclose(w.friction(-s), -f)
    assert f[3] == pytest.approx(2e-6 + 2e-10 * 5000 * RPM, rel=1e-9)


def test_readout_noise_sigma_and_determinism():
    truth = np.array([100.0, -200.0, 3000.0, 0.0]) * RPM
    a = Wheels(rng=np.random.default_rng(7))
    b = Wheels(rng=np.random.default_rng(7))
    c = Wheels(rng=np.random.default_rng(8))
    ra = np.array([a.read_speed_rpm(truth) for _ in range(4000)])
    rb = np.array([b.read_speed_rpm(truth) for _ in range(4000)])
    rc = np.array([c.read_speed_rpm(truth) for _ in range(10)])
    assert np.array_equal(ra, rb)
    assert not np.array_equal(ra[:10], rc)
    err = ra - truth / RPM
    assert np.all(np.abs(err.std(axis=0) / 10.0 - 1) < 0.06)
    assert np.all(np.abs(err.mean(axis=0)) < 4 * 10.0 / np.sqrt(4000))


def test_jitter_amplitude_direction_and_zero_mean():
    p = WheelParams(imbalance_static=5e-8, imbalance_dynamic=5e-10, arm=0.04)
    w = Wheels(p)
    speed = np.array([0.0, 0.0, 6000.0, 0.0]) * RPM          # only wheel 2 spins
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    forces, torques = [], []
    for a in angles:
        f, t = w.jitter(speed, np.full(4, a))
        forces.append(f)
        torques.append(t)
    forces, torques = np.array(forces), np.array(torques)
    w2 = speed[2] ** 2
    assert np.allclose(np.linalg.norm(forces, axis=1), 5e-8 * w2)          # |F| = U_s W^2 at every angle
    assert np.allclose(forces @ w.c[:, 2], 0.0, atol=1e-15)               # radial to the spin axis
    assert np.abs(forces.mean(axis=0)).max() < 1e-12 * 5e-8 * w2 * 1e3    # averages out over a turn
    # torque = r x F + U_d W^2 u; its largest value is sqrt(|r x u|^2 ...) bounded by (arm U_s + U_d) W^2
    assert np.linalg.norm(torques, axis=1).max() <= (0.04 * 5e-8 + 5e-10) * w2 * (1 + 1e-12)
    assert np.linalg.norm(torques, axis=1).min() > 0
