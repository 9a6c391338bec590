"""Rigid spacecraft with four reaction wheels: quaternion kinematics and Euler's equation, RK4.

Conventions (Yoon 2017, Sec. 4.2-4.3): q = [q1, q2, q3, q4] with the scalar last, the attitude from the inertial
to the body frame, A(q) = (q4^2 - |e|^2) I + 2 e e^T - 2 q4 [e x] (Eq. 4.7), and

    q_dot = 1/2 Omega(w) q,  Omega(w) = [[-[w x], w], [-w^T, 0]]                    (Eq. 4.10)
    J w_dot = -w x (J w + C Jrw W) - C Jrw W_dot + tau_ext                          (Eq. 4.16, 4.56, 4.67)
    Jrw W_dot = tau_motor - tau_friction(W_rel),  angle_dot = W_rel                (Eq. 4.55-4.56)

J is the spacecraft inertia without the rotors' axial inertia; W the rotors' absolute spin rates about their axes
(inertial rate projected on c_i), so the rotor momentum C Jrw W is exact and nothing is left out. What a
tachometer reads, what friction and the motor's speed limit act on, and what turns the jitter phase is the speed
relative to the body, W_rel = W - C^T w (``omega_rw_rel``); the ``omega_rw`` given to the constructor is that
relative speed. In the thesis's form (Eq. 4.12-4.16, 4.55) the same momentum is (J + C Jrw C^T) w + C Jrw W_rel:
its J includes the rotors' transverse share J_a. The motor and friction torques are
internal: H = J w + C Jrw W obeys dH/dt|body = -w x H + tau_ext, so the inertial A^T H is conserved without external
torque. tau_ext = gravity gradient + residual dipole (Eq. 4.68-4.75) + a pluggable callable + wheel jitter.
The motor torque is held over each fixed RK4 step (zero-order hold, as a 1 Hz-10 Hz flight computer drives it).

Two forms of the step: ``derivative``/``_step_python`` here on Python floats (the reference), and the C kernel
``emulator.spacecraft._truth`` (built by ``pip install -e .``), the same operations in the same order
(``emulator.spacecraft.kernel``). ``Spacecraft.truth_form`` says which one steps.
"""

import math

import numpy as np

from emulator.spacecraft import environment as env, kernel as _kernel
from emulator.spacecraft.wheels import N_WHEELS, RPM as _RPM, Wheels

# [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz], kg m^2 (Sec. 4.8): nominal and true error; products are matrix entries.
J0_THESIS = (12e-3, 47e-3, 45e-3, 1e-3, 2e-3, 3e-3)
DJ_THESIS = (-1.2e-3, 3.29e-3, 3.6e-3, 0.1e-3, -0.12e-3, 0.21e-3)
_DEFAULT = object()     # "use the thesis's orbit / field" (None turns them off)


def inertia_matrix(j6):
    """3 x 3 symmetric inertia from [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz]; ValueError unless it is a rigid body's:
    positive definite, and no principal moment larger than the sum of the other two (triangle inequality)."""
    a = np.array(j6, dtype=float).reshape(-1)
    if a.shape != (6,) or not np.all(np.isfinite(a)):
        raise ValueError("inertia must be 6 finite numbers [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz], got %r" % (j6,))
    j = np.array([[a[0], a[3], a[4]], [a[3], a[1], a[5]], [a[4], a[5], a[2]]])
    lam = np.linalg.eigvalsh(j)
    if lam[0] <= 0:
        raise ValueError("inertia %r is not positive definite" % (j6,))
    if lam[2] > (lam[0] + lam[1]) * (1.0 + 1e-9):
        raise ValueError("inertia %r is no rigid body's: its largest principal moment %.6g exceeds the sum of the "
                         "other two, %.6g" % (j6, lam[2], lam[0] + lam[1]))
    return j


def _finite(name, v, n):
    try:
        a = np.array(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        a = np.array([np.nan])
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ValueError("%s must be %d finite numbers, got %r" % (name, n, v))
    return a


def dcm(q):
    """A(q), inertial to body (Eq. 4.7)."""
    return np.array(_dcm_rows(q))


def _dcm_rows(q):
    """A(q) (Eq. 4.7) as three row tuples of Python floats."""
    e1, e2, e3, q4 = q
    return ((q4*q4 + e1*e1 - e2*e2 - e3*e3, 2*(e1*e2 + q4*e3), 2*(e1*e3 - q4*e2)),
            (2*(e1*e2 - q4*e3), q4*q4 - e1*e1 + e2*e2 - e3*e3, 2*(e2*e3 + q4*e1)),
            (2*(e1*e3 + q4*e2), 2*(e2*e3 - q4*e1), q4*q4 - e1*e1 - e2*e2 + e3*e3))


def dcms(q):
    """A(q) (Eq. 4.7) of each row of q (n, 4): (n, 3, 3), the same numbers as ``dcm`` row by row."""
    q = np.asarray(q, float)
    e1, e2, e3, q4 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    A = np.empty((len(q), 3, 3))
    A[:, 0, 0], A[:, 0, 1], A[:, 0, 2] = q4*q4 + e1*e1 - e2*e2 - e3*e3, 2*(e1*e2 + q4*e3), 2*(e1*e3 - q4*e2)
    A[:, 1, 0], A[:, 1, 1], A[:, 1, 2] = 2*(e1*e2 - q4*e3), q4*q4 - e1*e1 + e2*e2 - e3*e3, 2*(e2*e3 + q4*e1)
    A[:, 2, 0], A[:, 2, 1], A[:, 2, 2] = 2*(e1*e3 + q4*e2), 2*(e2*e3 - q4*e1), q4*q4 - e1*e1 - e2*e2 + e3*e3
    return A


def _rows_dot(a, v):
    """a v for a 3 x 3 given as rows and a 3-list."""
    return tuple(r[0] * v[0] + r[1] * v[1] + r[2] * v[2] for r in a)


def quat_mul(q, p):
    """q (x) p with A(q (x) p) = A(q) A(p) (Eq. 4.5, scalar last; q = [e, q4] of Eq. 4.2)."""
    qv, q4, pv, p4 = q[:3], q[3], p[:3], p[3]
    v = q4 * pv + p4 * qv - env.cross3(qv, pv)
    return np.array([v[0], v[1], v[2], q4 * p4 - qv @ pv])


class Spacecraft:
    """Attitude and wheel state, propagated by fixed-step RK4.

    State ``x`` = [q (4), w (3) rad/s, W (4) rad/s absolute, wheel angles relative to the body (4) rad].
    ``omega_rw`` (constructor) is the wheels' speed relative to the body, W_rel = W - C^T w.
    ``orbit=None`` turns off the gravity gradient and the magnetic torque; ``disturbance(t, q, w) -> (3,) N m``
    adds any other torque (body frame). ``orbit.position(t)`` returns an array (m, inertial); ``field`` needs
    ``field_floats(r_i, t)`` (``environment.TiltedDipoleField``).
    """

    def __init__(self, wheels=None, inertia=None, dt=0.1, q=(0.0, 0.0, 0.0, 1.0), omega=(0.0, 0.0, 0.0),
                 omega_rw=(0.0,) * N_WHEELS, orbit=_DEFAULT, field=_DEFAULT,
                 dipole=env.M_DIPOLE_THESIS, gravity_gradient=True, disturbance=None, t0=0.0, kernel=None):
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError("dt must be > 0 s, got %r" % (dt,))
        self.wheels = wheels if wheels is not None else Wheels()
        if inertia is None:
            inertia = np.add(J0_THESIS, DJ_THESIS)
        self.j = inertia_matrix(inertia)
        self.j_inv = np.linalg.inv(self.j)
        # the same as Python floats for ``derivative`` (the wheels' C and Jrw are fixed at their construction)
        self._j_rows, self._jinv_rows = self.j.tolist(), self.j_inv.tolist()
        self._c_rows, self._cj_rows = self.wheels.c.tolist(), self.wheels.cj.tolist()
        self._jrw = self.wheels.j.tolist()
        self.dt = float(dt)
        if self.wheels.p.jitter:
            dt_max = 0.1 * 2 * np.pi / self.wheels.speed_max
            if self.dt > dt_max:
                raise ValueError("jitter needs dt <= %.3g s (10 steps per turn at speed_max), got dt = %r"
                                 % (dt_max, dt))
        self.orbit = env.CircularOrbit() if orbit is _DEFAULT else orbit
        self.field = env.TiltedDipoleField() if field is _DEFAULT else field
        self.dipole = dipole
        self.gravity_gradient = gravity_gradient
        self.disturbance = disturbance
        qa = _finite("q", q, 4)
        if not qa.any():
            raise ValueError("q must not be all zero")
        w0 = _finite("omega", omega, 3)
        wr0 = _finite("omega_rw", omega_rw, N_WHEELS) + self.wheels.c.T @ w0      # absolute from relative
        self.x = np.concatenate([qa / np.linalg.norm(qa), w0, wr0, np.zeros(N_WHEELS)])
        self.t = float(t0)
        self.tau_motor = np.zeros(N_WHEELS)       # applied over the last step (after limits)
        self.steps = 0
        self.q_drift_max = 0.0
        self.truth_form = _kernel.form(kernel, type(self.wheels) is Wheels)
        self._kernel = self._kernel_key = None

    def __getstate__(self):
        """Copies and pickles leave the C kernel behind (it is built again at the next step)."""
        return dict(self.__dict__, _kernel=None, _kernel_key=None)

    # --- state views ---------------------------------------------------------------------------------
    @property
    def q(self):
        return self.x[0:4]

    @property
    def omega(self):
        return self.x[4:7]

    @property
    def omega_rw(self):
        return self.x[7:11]

    @property
    def omega_rw_rel(self):
        """Wheel speeds relative to the body, W - C^T w (what a tachometer reads), rad/s."""
        return self.x[7:11] - self.wheels.c.T @ self.x[4:7]

    @property
    def angle_rw(self):
        return self.x[11:15]

    @property
    def dipole(self):
        """Residual dipole m (A m^2, body frame) as a new array, or None; held as floats for ``derivative``."""
        return None if self._dipole is None else np.array(self._dipole)

    @dipole.setter
    def dipole(self, m):
        self._dipole = None if m is None else tuple(_finite("dipole (A m^2)", m, 3).tolist())

    def momentum_body(self, x=None):
        """H = J w + C Jrw W, body frame (Eq. 4.11-4.13, 4.55)."""
        x = self.x if x is None else x
        return self.j @ x[4:7] + self.wheels.cj @ x[7:11]

    def momentum_inertial(self):
        """A(q)^T H: constant without external torque."""
        return dcm(self.q).T @ self.momentum_body()

    # --- dynamics ------------------------------------------------------------------------------------
    def external_torque(self, t, x):
        """tau_ext (body frame, N m) at time t and state x: gravity gradient, residual dipole, the callable,
        jitter (its force moves the centre of mass, which this model does not follow)."""
        if self.truth_form == "kernel" and not self.wheels.p.jitter:
            return np.array(self._kernel_now().torque(t, np.ascontiguousarray(x, dtype=float), self._dipole))
        wrel = x[7:11] - self.wheels.c.T @ x[4:7] if self.wheels.p.jitter else None
        return np.array(self._tau_ext(t, x, x[0:4].tolist(), wrel))

    def _tau_ext(self, t, x, q, wrel):
        """``external_torque`` on Python floats (q a list; ``wrel`` the relative wheel speeds W - C^T w as an
        array, used only with jitter): 3-vectors cost numpy ~1 us an operation."""
        tx = ty = tz = 0.0
        if self.orbit is not None and (self.gravity_gradient or self._dipole is not None):
            a = _dcm_rows(q)
            r_i = self.orbit.position(t).tolist()
            if self.gravity_gradient:                                              # Eq. 4.69-4.75
                x0, x1, x2 = _rows_dot(a, r_i)
                rn = (x0 * x0 + x1 * x1 + x2 * x2) ** 0.5
                x0, x1, x2 = x0 / rn, x1 / rn, x2 / rn
                (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = self._j_rows
                y0 = j00 * x0 + j01 * x1 + j02 * x2
                y1 = j10 * x0 + j11 * x1 + j12 * x2
                y2 = j20 * x0 + j21 * x1 + j22 * x2
                k = 3.0 * env.MU_EARTH / rn ** 3
                tx += k * (x1 * y2 - x2 * y1)
                ty += k * (x2 * y0 - x0 * y2)
                tz += k * (x0 * y1 - x1 * y0)
            if self._dipole is not None and self.field is not None:                # Eq. 4.71, 4.73
                b0, b1, b2 = _rows_dot(a, self.field.field_floats(r_i, t))
                m0, m1, m2 = self._dipole
                tx += m1 * b2 - m2 * b1
                ty += m2 * b0 - m0 * b2
                tz += m0 * b1 - m1 * b0
        if self.disturbance is not None:
            d = np.asarray(self.disturbance(t, x[0:4], x[4:7]), dtype=float)
            tx, ty, tz = tx + float(d[0]), ty + float(d[1]), tz + float(d[2])
        if self.wheels.p.jitter:
            d = self.wheels.jitter(wrel, x[11:15])[1]
            tx, ty, tz = tx + float(d[0]), ty + float(d[1]), tz + float(d[2])
        return tx, ty, tz

    def derivative(self, t, x, tau_motor):
        """dx/dt (Eq. 4.10, 4.16, 4.55-4.56) on Python floats; ``tau_motor`` the 4 motor torques held."""
        q = x[0:4].tolist()
        w0, w1, w2 = x[4:7].tolist()
        W = x[7:11].tolist()
        c0, c1, c2 = self._c_rows
        p = self.wheels.p
        fv, fc, fs = p.friction_viscous, p.friction_coulomb, 1.0 / (p.friction_smooth_rpm * _RPM)
        wrel = [W[i] - (c0[i] * w0 + c1[i] * w1 + c2[i] * w2) for i in range(N_WHEELS)]   # relative speed
        net = [u - (fv * v + fc * math.tanh(v * fs)) for u, v in zip(tau_motor.tolist(), wrel)]  # Wheels.friction
        jrw = self._jrw
        (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = self._j_rows
        cj0, cj1, cj2 = self._cj_rows
        h0 = j00 * w0 + j01 * w1 + j02 * w2 + sum(a * b for a, b in zip(cj0, W))
        h1 = j10 * w0 + j11 * w1 + j12 * w2 + sum(a * b for a, b in zip(cj1, W))
        h2 = j20 * w0 + j21 * w1 + j22 * w2 + sum(a * b for a, b in zip(cj2, W))
        tx, ty, tz = self._tau_ext(t, x, q, np.array(wrel) if p.jitter else None)
        r0 = tx - (w1 * h2 - w2 * h1) - sum(a * b for a, b in zip(c0, net))     # Eq. 4.16
        r1 = ty - (w2 * h0 - w0 * h2) - sum(a * b for a, b in zip(c1, net))
        r2 = tz - (w0 * h1 - w1 * h0) - sum(a * b for a, b in zip(c2, net))
        (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = self._jinv_rows
        e0, e1, e2, q4 = q
        return np.array([                                                        # Eq. 4.10
            0.5 * (q4 * w0 - (w1 * e2 - w2 * e1)), 0.5 * (q4 * w1 - (w2 * e0 - w0 * e2)),
            0.5 * (q4 * w2 - (w0 * e1 - w1 * e0)), -0.5 * (w0 * e0 + w1 * e1 + w2 * e2),
            i00 * r0 + i01 * r1 + i02 * r2, i10 * r0 + i11 * r1 + i12 * r2, i20 * r0 + i21 * r1 + i22 * r2,
            net[0] / jrw[0], net[1] / jrw[1], net[2] / jrw[2], net[3] / jrw[3],
            wrel[0], wrel[1], wrel[2], wrel[3]])

    def step(self):
        """One RK4 step of dt with the wheels' limited motor torques held; the quaternion is renormalised. The C
        kernel's (``truth_form`` "kernel") or ``_step_python``; the two agree to rounding."""
        if self.truth_form == "python":
            return self._step_python()
        w = self.wheels
        x, tq = np.empty(15), np.empty(N_WHEELS)
        qn, clip = self._kernel_now().step(self.t, self.dt, self.x, x, tq, w.cmd, w.enable, self._dipole)
        if clip:
            w.n_torque_clip += [(clip >> i) & 1 for i in range(N_WHEELS)]
            w.n_speed_clip += [(clip >> (N_WHEELS + i)) & 1 for i in range(N_WHEELS)]
        self.q_drift_max = max(self.q_drift_max, abs(qn - 1.0))
        self.x, self.t, self.tau_motor = x, self.t + self.dt, tq
        self.steps += 1

    def _kernel_now(self):
        """The C kernel for the orbit, field, disturbance and gravity gradient as they are now."""
        key = (self.orbit, self.field, self.disturbance, self.gravity_gradient)
        if key != self._kernel_key:
            self._kernel, self._kernel_key = _kernel.build(self), key
        return self._kernel

    def _step_python(self):
        """``step`` on Python floats (the reference form)."""
        dt, t, x = self.dt, self.t, self.x
        tq = self.wheels.apply_limits(x[7:11] - self.wheels.c.T @ x[4:7], dt)
        k1 = self.derivative(t, x, tq)
        k2 = self.derivative(t + 0.5 * dt, x + 0.5 * dt * k1, tq)
        k3 = self.derivative(t + 0.5 * dt, x + 0.5 * dt * k2, tq)
        k4 = self.derivative(t + dt, x + dt * k3, tq)
        x = x + (dt / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
        qn = np.sqrt(x[0:4] @ x[0:4])
        self.q_drift_max = max(self.q_drift_max, abs(qn - 1.0))      # RK4's departure from |q| = 1
        x[0:4] /= qn
        self.x = x
        self.t = t + dt
        self.tau_motor = tq
        self.steps += 1

    def run(self, duration):
        """Advance by ``duration`` seconds (rounded to whole steps); returns the number of steps."""
        if not (np.isfinite(duration) and duration >= 0):
            raise ValueError("duration must be a finite number >= 0 s, got %r" % (duration,))
        n = int(round(duration / self.dt))
        for _ in range(n):
            self.step()
        return n
