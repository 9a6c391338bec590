"""Spacecraft dynamics: momentum conservation (Eq. 4.16), wheel spin-up, kinematics (Eq. 4.10), environment."""

import numpy as np
import pytest

from emulator.spacecraft import environment as env
from emulator.spacecraft.dynamics import DJ_THESIS, J0_THESIS, Spacecraft, dcm, inertia_matrix, quat_mul
from emulator.spacecraft.wheels import RPM, WheelParams, Wheels, pyramid_c0

NULL = np.array([1.0, -1.0, 1.0, -1.0])     # null space of the pyramid: C0 NULL = 0


def _free(wheels=None, **kw):
    """A spacecraft with no environment torques."""
    return Spacecraft(wheels=wheels or Wheels(WheelParams.ideal()), orbit=None, **kw)


def _quat_from_dcm(a):
    """Inverse of Eq. 4.7 (for building test attitudes)."""
    q4 = 0.5 * np.sqrt(1 + np.trace(a))
    return np.array([(a[1, 2] - a[2, 1]) / (4 * q4), (a[2, 0] - a[0, 2]) / (4 * q4),
                     (a[0, 1] - a[1, 0]) / (4 * q4), q4])


def test_null_vector_is_null():
    assert np.allclose(pyramid_c0() @ NULL, 0.0)


@pytest.mark.parametrize("friction", [False, True])
def test_inertial_momentum_conserved_600s(friction):
    p = WheelParams(jitter=False) if friction else WheelParams(friction_coulomb=0.0, friction_viscous=0.0)
    w = Wheels(p)   # thesis wheels, misaligned: C NULL != 0, so the commands below also torque the body
    sc = Spacecraft(wheels=w, orbit=None, dt=0.1, omega=np.radians([1.0, 0.0, 0.0]),
                    omega_rw=np.array([1000.0, -1500.0, 800.0, 2000.0]) * RPM)
    h0 = sc.momentum_inertial()
    for k in range(6):       # change the commands every 100 s: momentum moves between body and wheels
        w.command_all(1e-5 * NULL * (-1) ** k + np.array([2e-7, -1e-7, 0.0, 1e-7]) * k)
        sc.run(100.0)
    assert sc.t == pytest.approx(600.0)
    assert np.abs(sc.omega_rw - np.array([1000.0, -1500.0, 800.0, 2000.0]) * RPM).max() > 100 * RPM
    assert np.linalg.norm(sc.momentum_inertial() - h0) <= 1e-9 * np.linalg.norm(h0)


def test_wheel_speed_follows_torque_until_the_limit():
    p = WheelParams.ideal()
    w = Wheels(p)
    sc = _free(w, dt=0.1)
    u = np.array([5e-5, -2e-5, 0.0, 1e-5])
    w.command_all(u)
    sc.run(30.0)
    assert np.allclose(sc.omega_rw, u / w.j * 30.0, rtol=1e-12, atol=1e-12)
    assert w.counters()["speed_clip"] == [0, 0, 0, 0]
    t_lim = w.speed_max * w.j[0] / u[0]                      # 62.8 s for wheel 0
    sc.run(100.0)
    assert sc.omega_rw_rel[0] == pytest.approx(w.speed_max, rel=1e-4)     # the limit is on the relative speed
    assert sc.omega_rw[1] == pytest.approx(u[1] / w.j[1] * 130.0, rel=1e-12)
    n_clip = w.counters()["speed_clip"][0]
    assert abs(n_clip - (130.0 - t_lim) / 0.1) <= 2
    assert np.allclose(sc.tau_motor[1:], u[1:])


def test_torque_limit_clips_and_is_counted():
    w = Wheels(WheelParams.ideal(torque_max=1e-4))
    sc = _free(w, dt=0.1)
    w.command_all([3e-4, -3e-4, 5e-5, 0.0])
    sc.run(10.0)
    assert np.allclose(sc.omega_rw, np.array([1e-4, -1e-4, 5e-5, 0.0]) / w.j * 10.0, rtol=1e-12)
    assert w.counters()["torque_clip"] == [100, 100, 0, 0]


def test_principal_axis_spin_matches_closed_form_quaternion():
    j = (0.01, 0.02, 0.03, 0.0, 0.0, 0.0)
    rate = np.radians(2.0)
    sc = _free(inertia=j, dt=0.1, omega=(0.0, 0.0, rate))
    sc.run(600.0)
    phi = rate * 600.0
    expect = np.array([0.0, 0.0, np.sin(phi / 2), np.cos(phi / 2)])
    assert min(np.abs(sc.q - expect).max(), np.abs(sc.q + expect).max()) < 1e-9
    # A(q) is inertial -> body: the body x axis seen from inertial space has turned by +phi about z
    assert np.allclose(dcm(sc.q).T @ [1, 0, 0], [np.cos(phi), np.sin(phi), 0], atol=1e-9)


def test_quaternion_stays_unit_in_a_tumble():
    sc = Spacecraft(dt=0.1, omega=np.radians([3.0, -2.0, 4.0]), omega_rw=np.array([3000, -2000, 1000, 0]) * RPM)
    sc.wheels.command_all([1e-4, 2e-4, -3e-4, 1e-4])
    norms = []
    for _ in range(60):
        sc.run(10.0)
        norms.append(np.linalg.norm(sc.q))
    assert np.abs(np.array(norms) - 1.0).max() < 1e-14
    assert 0 < sc.q_drift_max < 1e-9          # RK4 itself keeps |q| = 1 closely; renormalising only trims it


def test_external_disturbance_adds_inertial_momentum():
    tau_i = np.array([1e-6, -2e-6, 5e-7])

    def dist(t, q, w):          # a torque fixed in inertial space, given to the body in body axes
        return dcm(q) @ tau_i

    sc = _free(dt=0.1, omega=np.radians([0.5, 0.2, -0.3]), omega_rw=np.array([500, 0, -500, 100]) * RPM,
               disturbance=dist)
    h0 = sc.momentum_inertial()
    sc.run(300.0)
    expect = h0 + tau_i * 300.0
    assert np.linalg.norm(sc.momentum_inertial() - expect) <= 1e-9 * np.linalg.norm(expect)


def test_gravity_gradient_zero_on_principal_axes_and_restoring():
    j = inertia_matrix(np.add(J0_THESIS, DJ_THESIS))
    vals, vecs = np.linalg.eigh(j)
    r = 6771e3
    scale = 3 * env.MU_EARTH / r ** 3 * (vals[-1] - vals[0])
    for k in range(3):
        tau = env.gravity_gradient_torque(j, r * vecs[:, k])
        assert np.linalg.norm(tau) < 1e-12 * scale
    # minimum axis tilted by eps toward the middle axis: the torque turns the body back (about min x mid)
    eps = np.radians(1.0)
    rb = r * (np.cos(eps) * vecs[:, 0] + np.sin(eps) * vecs[:, 1])
    tau = env.gravity_gradient_torque(j, rb)
    axis = np.cross(vecs[:, 0], vecs[:, 1])
    assert tau @ axis == pytest.approx(scale / 3 * 3 * np.cos(eps) * np.sin(eps) * (vals[1] - vals[0])
                                       / (vals[-1] - vals[0]), rel=1e-9)


def test_gravity_gradient_matches_point_masses():
    rng = np.random.default_rng(3)
    rho = rng.normal(0, 0.1, (12, 3))
    m = rng.uniform(0.1, 1.0, 12)
    rho -= (m[:, None] * rho).sum(0) / m.sum()          # centre of mass at the origin
    j = sum(mk * (rk @ rk * np.eye(3) - np.outer(rk, rk)) for mk, rk in zip(m, rho))
    rb = 6771e3 * np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    exact = np.zeros(3)
    for mk, rk in zip(m, rho):
        p = rb + rk
        exact += np.cross(rk, -env.MU_EARTH * mk * p / np.linalg.norm(p) ** 3)
    got = env.gravity_gradient_torque(j, rb)
    assert np.linalg.norm(got - exact) < 1e-5 * np.linalg.norm(exact)


def test_dipole_field_magnitudes():
    f = env.TiltedDipoleField()
    b0 = np.linalg.norm(f.m_ecef)
    m_hat = f.m_ecef / b0
    r = 6771e3
    eq = np.cross(m_hat, [1.0, 0.0, 0.0])
    eq /= np.linalg.norm(eq)
    scale = (env.R_EARTH / r) ** 3
    assert np.linalg.norm(f.field(r * eq, 0.0)) == pytest.approx(b0 * scale, rel=1e-12)
    assert f.field(r * eq, 0.0) @ m_hat == pytest.approx(-b0 * scale, rel=1e-12)     # northward (m is south)
    assert np.linalg.norm(f.field(r * m_hat, 0.0)) == pytest.approx(2 * b0 * scale, rel=1e-12)
    assert 29e-6 < b0 < 31e-6
    # the dipole turns with the Earth once a sidereal day
    day = 2 * np.pi / env.OMEGA_EARTH
    assert np.allclose(f.field(r * eq, day), f.field(r * eq, 0.0), atol=1e-15)
    assert not np.allclose(f.field(r * eq, day / 4), f.field(r * eq, 0.0), atol=1e-7)
    # the derivative's float form is the same field, from an array or a list
    r_i = r * (eq + 0.3 * m_hat)
    assert f.field_floats(r_i, 77.0) == f.field_floats(r_i.tolist(), 77.0) == tuple(f.field(r_i, 77.0).tolist())


def test_external_torque_is_gravity_gradient_plus_dipole():
    sc = Spacecraft(q=(0.1, -0.2, 0.3, 0.9))
    t = 123.0
    a = dcm(sc.q)
    r_i = sc.orbit.position(t)
    expect = (env.gravity_gradient_torque(sc.j, a @ r_i)
              + np.cross(env.M_DIPOLE_THESIS, a @ sc.field.field(r_i, t)))
    assert np.allclose(sc.external_torque(t, sc.x), expect, rtol=1e-14, atol=0)
    assert np.linalg.norm(expect) > 1e-7


def test_dipole_is_one_value_the_torque_follows():
    """``Spacecraft.dipole`` read and set goes to the value the derivative uses (Eq. 4.71)."""
    sc = Spacecraft(q=(0.1, -0.2, 0.3, 0.9), gravity_gradient=False)
    t, x = 123.0, sc.x.copy()
    tau = sc.external_torque(t, x)
    assert np.array_equal(sc.dipole, env.M_DIPOLE_THESIS) and np.linalg.norm(tau) > 1e-7
    sc.dipole = -2.0 * sc.dipole
    assert np.allclose(sc.external_torque(t, x), -2.0 * tau, rtol=1e-14, atol=0)
    sc.dipole = None
    assert sc.dipole is None and not sc.external_torque(t, x).any()


def test_circular_orbit_radius_and_speed():
    o = env.CircularOrbit(altitude=400e3, inclination_deg=51.65)
    for t in (0.0, 1000.0, 3000.0):
        assert np.linalg.norm(o.position(t)) == pytest.approx(env.R_EARTH + 400e3, rel=1e-12)
        assert o.position(t) @ o.velocity(t) == pytest.approx(0.0, abs=1e-3)
    period = 2 * np.pi / o.n
    assert np.allclose(o.position(period), o.position(0.0), atol=1e-6)
    assert np.degrees(np.arcsin(o.position(period / 4)[2] / o.a)) == pytest.approx(51.65, abs=1e-9)


def test_quat_mul_composes_dcms():
    rng = np.random.default_rng(1)
    q, p = rng.normal(size=4), rng.normal(size=4)
    q, p = q / np.linalg.norm(q), p / np.linalg.norm(p)
    assert np.allclose(dcm(quat_mul(q, p)), dcm(q) @ dcm(p))
    assert np.allclose(_quat_from_dcm(dcm(q)) * np.sign(q[3]), q)


@pytest.mark.parametrize("kw, key", [
    (dict(dt=0.0), "dt"),
    (dict(inertia=(1, 1, 1, 2, 0, 0)), "positive definite"),
    (dict(inertia=(1, 1, 1)), "inertia"),
    (dict(q=(0, 0, 0, 0)), "q"),
    (dict(omega=(0, 0)), "omega"),
    (dict(omega_rw=(0, 0, float("nan"), 0)), "omega_rw"),
    (dict(wheels=Wheels(WheelParams(jitter=True)), dt=0.01), "jitter"),
])
def test_bad_input_refused(kw, key):
    with pytest.raises(ValueError, match=key):
        Spacecraft(**kw)


def test_jitter_shakes_the_body_at_the_wheel_rate():
    p = WheelParams.ideal(imbalance_static=4.8e-8, imbalance_dynamic=5e-10, jitter=True)
    w = Wheels(p)
    speed = 3000 * RPM                                      # 50 Hz
    dt = 2e-4
    sc = Spacecraft(wheels=w, orbit=None, dt=dt, omega_rw=(speed, 0.0, 0.0, 0.0))
    rates = []
    for _ in range(200):                                    # 0.04 s = two turns
        sc.step()
        rates.append(sc.omega.copy())
    rates = np.array(rates)
    # independent estimate: w(t) = J^-1 * integral of the imbalance torque at angle W t (gyroscopic terms ~0.5 %)
    t = np.linspace(0.0, 0.04, 20001)
    tau = np.array([w.jitter(np.array([speed, 0, 0, 0]), np.array([speed * tk, 0, 0, 0]))[1] for tk in t])
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (tau[1:] + tau[:-1]) * (t[1] - t[0]), axis=0)])
    expect = (np.linalg.inv(sc.j) @ integral[100::100].T).T
    assert np.ptp(expect) > 1e-6                             # a visible swing (rad/s)
    assert np.abs(rates - expect).max() < 0.005 * np.ptp(expect)
    assert np.allclose(sc.angle_rw[0], speed * 0.04, rtol=1e-7)       # phase turns with W - c.w (w ~ 1e-6 rad/s)


def test_wheel_speed_relative_to_body_everywhere():
    """W is absolute; the read-out, friction, speed limit, jitter phase and initial speeds use W - c_i.w."""
    p = WheelParams.ideal(friction_viscous=1e-6, speed_max_rpm=2000.0)
    w = Wheels(p)
    omega = np.radians([2.0, -1.0, 0.5])
    rel0 = np.array([1000.0, -500.0, 0.0, 200.0]) * RPM
    sc = Spacecraft(wheels=w, orbit=None, dt=0.1, omega=omega, omega_rw=rel0)
    cw = w.c.T @ omega
    assert np.allclose(sc.omega_rw, rel0 + cw, rtol=0, atol=1e-15)         # initial speeds are relative
    assert np.allclose(sc.omega_rw_rel, rel0, rtol=0, atol=1e-15)
    assert np.all(np.abs(cw) > 1e-3)                                        # the two differ here
    d = sc.derivative(0.0, sc.x, np.zeros(4))
    assert np.allclose(d[7:11] * w.j, -p.friction_viscous * rel0, rtol=1e-12)   # friction on W - c.w
    assert np.allclose(d[11:15], rel0, rtol=1e-12)                          # jitter phase turns with W - c.w
    assert np.allclose(w.read_speed_rpm(sc.omega_rw_rel), rel0 / RPM)
    # momentum stays exact: H = J w + C Jrw W is conserved without external torque
    h0 = sc.momentum_inertial()
    w.command_all([1e-5, -1e-5, 2e-5, 0.0])
    sc.run(20.0)
    assert np.allclose(sc.momentum_inertial(), h0, rtol=0, atol=1e-12 + 1e-9 * np.linalg.norm(h0))


def test_read_outs_and_speed_limit_use_the_relative_speed_on_a_turning_body():
    """With the body turning (so W and W - c_i.w differ by more than the tolerances), the wheel device's
    telemetry, the Sec. 4.8 scenario's tachometers (noise off) and the speed limit inside ``step`` all act on
    W - c_i.w."""
    from emulator.spacecraft import SpacecraftDevices, scenario
    from protocol import core
    omega = np.radians([5.0, -4.0, 3.0])
    rel0 = np.array([1000.0, -1500.0, 500.0, 1990.0]) * RPM
    sc = Spacecraft(wheels=Wheels(WheelParams.ideal(speed_max_rpm=2000.0)), orbit=None, dt=0.1, omega=omega,
                    omega_rw=rel0)
    cw = sc.wheels.c.T @ sc.omega
    assert np.all(np.abs(cw) > 0.01)                       # rad/s: ~0.1 rpm and more between W and W - c.w
    dev = SpacecraftDevices(sc)
    for i in range(4):
        (reply,) = dev.handle(core.PACKET_ID["RW_CMD"], core.NODE["ADCS"], core.NODE["RW%d" % i],
                              core.encode_payload("RW_CMD", torque=0.0, enable=1))
        speed = core.payload_dict(reply[0], reply[3])["speed"]
        assert speed == pytest.approx(sc.omega_rw_rel[i] / RPM, abs=1e-3)
        assert abs(speed - sc.omega_rw[i] / RPM) > 0.05
    # the speed limit: wheel 3 pushed toward +2000 rpm stops there, relative to the body
    sc.wheels.command_all([0.0, 0.0, 0.0, sc.wheels.p.torque_max])
    rel = []
    for _ in range(30):
        sc.step()
        rel.append(sc.omega_rw_rel[3])
    top = 2000.0 * RPM        # the motor stops at the limit; the body's nutation then moves c.w by a few 1e-3
    assert max(rel) <= top + 5e-3 and abs(rel[-1] - top) < 5e-3
    assert abs(sc.omega_rw[3] - top) > 0.1                 # rad/s: the absolute speed is not what stopped
    # the scenario's tachometers: without noise they read W - c.w exactly
    noiseless = WheelParams(**dict(scenario.SCENARIO_WHEELS, noise_rpm=0.0))
    o = scenario.simulate(case=1, seed=0, duration=20, wheel_params=noiseless)
    assert np.allclose(o["tach"], o["w_rel"], rtol=1e-12, atol=1e-12)
    w = Wheels(noiseless)
    assert np.abs(o["w"] @ w.c).max() > 1e-3               # rad/s: c.w is far above the tolerance above


def test_derivative_on_floats_equals_the_matrix_form():
    """``derivative`` works on Python floats; check it against Eq. 4.10, 4.16, 4.55-4.56 written with numpy,
    with the field, a disturbance callable and wheel jitter all on, at random states."""
    rng = np.random.default_rng(7)
    dist = lambda t, q, w: np.array([1e-6 * np.sin(t), 2e-6 * q[0], -3e-6 * w[2]])   # noqa: E731
    w = Wheels(WheelParams(jitter=True, speed_max_rpm=10000.0))
    sc = Spacecraft(wheels=w, dt=1e-4, disturbance=dist)
    for _ in range(5):
        q = rng.standard_normal(4)
        x = np.concatenate([q / np.linalg.norm(q), 1e-2 * rng.standard_normal(3), 300 * rng.standard_normal(4),
                            rng.uniform(0, 6, 4)])
        t, u = float(rng.uniform(0, 5000)), 1e-4 * rng.standard_normal(4)
        qq, om, W = x[0:4], x[4:7], x[7:11]
        wrel = W - w.c.T @ om
        net = u - w.friction(wrel)
        a = dcm(qq)
        r_i = sc.orbit.position(t)
        tau = (env.gravity_gradient_torque(sc.j, a @ r_i) + np.cross(sc.dipole, a @ sc.field.field(r_i, t))
               + dist(t, qq, om) + w.jitter(wrel, x[11:15])[1])
        h = sc.j @ om + w.cj @ W
        w_dot = np.linalg.solve(sc.j, tau - np.cross(om, h) - w.c @ net)
        e, q4 = qq[0:3], qq[3]
        q_dot = 0.5 * np.concatenate([q4 * om - np.cross(om, e), [-(om @ e)]])
        expect = np.concatenate([q_dot, w_dot, net / w.j, wrel])
        got = sc.derivative(t, x, u)
        assert np.allclose(got, expect, rtol=1e-12, atol=1e-14 * np.abs(expect).max())
        assert np.allclose(sc.external_torque(t, x), tau, rtol=1e-12, atol=0)


def test_inertia_must_be_a_rigid_bodys():
    """Positive definite is not enough: no principal moment may exceed the sum of the other two."""
    inertia_matrix(np.add(J0_THESIS, DJ_THESIS))
    with pytest.raises(ValueError, match="not positive definite"):
        inertia_matrix([0.012, 0.047, 0.045, 0.05, 0.0, 0.0])
    with pytest.raises(ValueError, match="no rigid body"):
        inertia_matrix([0.012, 0.012, 0.030, 0.0, 0.0, 0.0])
    inertia_matrix([0.012, 0.012, 0.024, 0.0, 0.0, 0.0])          # a flat plate: the limit, allowed
