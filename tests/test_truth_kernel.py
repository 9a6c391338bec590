"""The truth's C kernel (emulator.spacecraft._truth) against the Python form of the RK4 step: the same spacecraft
stepped by both agrees to rounding (1e-12 of each block of the state) over thousands of steps, with the
environment in C (circular orbit, orbit grid, tilted dipole, surface torques, jitter) and called back in Python
(another orbit, field or disturbance)."""

import copy
import pickle

import numpy as np
import pytest

from emulator.spacecraft import environment as env, kernel, scenario
from emulator.spacecraft.dynamics import Spacecraft
from emulator.spacecraft.wheels import RPM, WheelParams, Wheels

built = pytest.mark.skipif(not kernel.available(), reason="the truth's C kernel is not built (pip install -e .)")
BLOCKS = (slice(0, 4), slice(4, 7), slice(7, 11), slice(11, 15))
RTOL = 1e-12


class PyOrbit:
    """A circular orbit the kernel does not know: called back."""

    def __init__(self):
        self.o = env.CircularOrbit(altitude=500e3, inclination_deg=97.0)

    def position(self, t):
        return self.o.position(t)


class PyField:
    """A field the kernel does not know: called back."""

    def __init__(self):
        self.f = env.TiltedDipoleField(gmst0_rad=0.3)

    def field_floats(self, r_i, t):
        return tuple(1.5 * b for b in self.f.field_floats(r_i, t))


def drag(t, q, w):
    """A Python disturbance torque (N m) that depends on the attitude, the rate and the time."""
    return 1e-7 * np.array([np.sin(1e-3 * t) + q[0], w[1] - q[3], 0.5 * np.cos(q[2])])


def _make(form, jitter=False, speed_max_rpm=10000.0, **kw):
    p = WheelParams(jitter=jitter, speed_max_rpm=speed_max_rpm)
    return Spacecraft(wheels=Wheels(p, rng=np.random.default_rng(0)), omega=np.radians([1.0, -0.5, 0.3]),
                      omega_rw=np.array([1000.0, -1500.0, 800.0, 2000.0]) * RPM, kernel=form == "kernel", **kw)


def _fly(sc, n, seed=1):
    """n steps under commands that change every 10 steps; returns the states, torques and counters."""
    rng = np.random.default_rng(seed)
    xs, tq = [], []
    for k in range(n):
        if k % 10 == 0:
            sc.wheels.command_all(rng.uniform(-1.2e-3, 1.2e-3, 4), enable=rng.uniform() > 0.05)
        if k == n // 2 and sc.dipole is not None:
            sc.dipole = -2.0 * sc.dipole                     # the magnetorquers' way: the dipole changes in flight
        sc.step()
        xs.append(sc.x.copy())
        tq.append(sc.tau_motor.copy())
    return np.array(xs), np.array(tq), sc.wheels.counters(), sc.q_drift_max


def _agree(a, b, n=2000):
    xa, ta, ca, da = _fly(a, n)
    xb, tb, cb, db = _fly(b, n)
    assert a.truth_form == "python" and b.truth_form == "kernel"
    for s in BLOCKS:
        scale = np.abs(xa[:, s]).max()
        assert np.abs(xa[:, s] - xb[:, s]).max() <= RTOL * scale, s
    assert np.abs(ta - tb).max() <= RTOL * np.abs(ta).max()
    assert ca == cb
    assert db == pytest.approx(da, rel=1e-6, abs=1e-15)
    ea, eb = a.external_torque(a.t, xa[-1]), b.external_torque(a.t, xa[-1])     # the recorder's call
    assert np.abs(ea - eb).max() <= RTOL * np.abs(ea).max()
    return xa


CASES = {
    "circular orbit, dipole field": {},
    "orbit None": dict(orbit=None),
    "no gravity gradient, no dipole": dict(gravity_gradient=False, dipole=None),
    "Python disturbance": dict(disturbance=drag),
    "Python orbit and field, Python disturbance": dict(orbit=PyOrbit(), field=PyField(), disturbance=drag),
    "orbit None, Python disturbance": dict(orbit=None, disturbance=drag),
    "wheels at their speed limit": dict(speed_max_rpm=2100.0),
}


@built
@pytest.mark.parametrize("case", sorted(CASES))
def test_kernel_agrees_with_python_form(case):
    xa = _agree(_make("python", **CASES[case]), _make("kernel", **CASES[case]))
    assert np.ptp(xa[:, 4:7]) > 1e-4                  # the run went somewhere


@built
@pytest.mark.parametrize("disturbance", [None, drag])
def test_kernel_agrees_with_jitter(disturbance):
    """Jitter at 10 000 rpm needs a short step (Spacecraft's check); both forms at dt = 0.5 ms."""
    a, b = (_make(f, jitter=True, dt=5e-4, disturbance=disturbance) for f in ("python", "kernel"))
    _agree(a, b, n=1500)


@built
def test_kernel_agrees_in_the_flight_world():
    """The flight world's truth: the orbit grid, the tilted dipole at the epoch, the surface torques; the kernel is
    rebuilt when the disturbance changes in flight."""
    a, b = (scenario.pointing_world(120, 0, flight=True).sc for _ in range(2))
    assert isinstance(a.disturbance, env.SurfaceTorques)
    a.truth_form = "python"
    xa, _, _, _ = _fly(a, 600)
    xb, _, _, _ = _fly(b, 600)
    a.disturbance = b.disturbance = drag
    ya, _, _, _ = _fly(a, 400)
    yb, _, _, _ = _fly(b, 400)
    for s in BLOCKS:
        for p, q in ((xa, xb), (ya, yb)):
            assert np.abs(p[:, s] - q[:, s]).max() <= RTOL * np.abs(p[:, s]).max()


def test_forms_chosen(monkeypatch):
    assert Spacecraft(kernel=False).truth_form == "python"
    assert Spacecraft().truth_form == ("kernel" if kernel.available() else "python")
    monkeypatch.setenv("FPS_TRUTH", "python")
    assert Spacecraft().truth_form == "python"
    with pytest.raises(ValueError, match="not built"):
        Spacecraft(kernel=True)


@built
def test_kernel_refuses_bad_state():
    sc = _make("kernel")
    sc.x = sc.x.astype(np.float32)
    with pytest.raises(ValueError, match="x must be 15"):
        sc.step()


@built
def test_a_copy_steps_on():
    """A copied or pickled spacecraft leaves the kernel behind and builds its own: it steps as the original."""
    sc = _make("kernel", disturbance=drag)
    _fly(sc, 20)
    for dup in (copy.deepcopy, lambda s: pickle.loads(pickle.dumps(s))):
        twin = dup(sc)
        sc.step()
        twin.step()
        assert twin.truth_form == "kernel" and np.array_equal(twin.x, sc.x)
