"""The ADCS app's control and wheel allocation (MicroPython): where each cycle's wheel torques are computed.

Quaternion PD (Eq. 6.5-6.7) on the command with the gyroscopic term and the modelled external torque (gravity
gradient, the residual dipole in the model field, the APKF's disturbance torque: Eq. 4.68-4.75) fed forward,
saturation, minimum-norm wheel torques (Eq. 6.11) over the wheels in use, plus friction compensation. A failed wheel
(``health.Health.failed``) leaves the allocation, its column zero (the other three span the body axes); with two or
more failed the wheels left do not span the body axes: no torque is allocated and the working wheels get their
friction compensation only (they keep their speed, so the body feels no torque from them).

In the flight world the magnetorquers unload the wheels (``flight.unloading``: the cross-product law on the
wheels' momentum with the estimated residual dipole cancelled, the field the model's through the estimate, as the
APKF's; a rod out, ``health.Health.magnetic``, leaves the others' least-squares torque: ``flight.rods_left``) and
the wheels are held off zero speed in the null space (``flight.null_bias``). The magnetometer's packets
ride unnamed in the burst, so a lost one could not be asked for again and would make a lossy link's run differ from
the clean one: its readings are only compared with the model (``mag_miss``, T, the largest difference).
"""

import math

from firmware.adcs import apkf_lean, control, flight, linalg
from firmware.adcs.apkf_lean_model import NW, RPM
from firmware.adcs.estimation import field_dipole
from firmware.adcs.linalg import micropython
from protocol.units import MU_EARTH



def _check_rods(mt):
    """The magnetorquers' block of the spacecraft file, for the three rods along body x, y, z the app drives."""
    if not mt:
        raise ValueError("the flight world needs the spacecraft's magnetorquers (configuration key magnetorquers)")
    ax = mt["axes"]
    for i in range(3):
        for j in range(3):
            if abs(ax[i][j] / math.sqrt(sum(v * v for v in ax[i])) - (1.0 if i == j else 0.0)) > 1e-9:
                raise ValueError("the lean ADCS drives three rods along body x, y, z; magnetorquers.axes = %r"
                                 % (ax,))


class Allocation:
    """The control law and allocation of one vehicle: ``model`` the lean APKF's (``apkf_lean.Model``: J, the wheel
    axes and their Jrw, the residual dipole), ``fo`` the flight world's options (None: the thesis world). ``u`` the
    wheel torques (N m) of the last cycle, ``m_cmd`` the magnetorquers' dipole (A m^2)."""

    def __init__(self, cfg, model, fo=None):
        zeros = linalg.zeros
        self.scale = sc = float(cfg["params"].get("torque_scale", 1.0))
        self.torque_max = float(cfg.get("torque_max", apkf_lean.TORQUE_MAX))
        self.fric = cfg.get("friction", apkf_lean.FRICTION)        # coulomb, viscous, smoothing rad/s
        self.gmst0 = float(cfg["gmst0_rad"])
        m = model
        self.J = zeros(9)
        for i in range(9):
            self.J[i] = m.J[i] / sc
        self.C = zeros(12)                  # normalised axes (3 x 4) and their Jrw
        self.Cu = zeros(12)                 # the axes in use (failed wheels' columns zero)
        jrw = zeros(4)
        for i in range(12):
            self.C[i] = m.C[i]
        for i in range(4):
            jrw[i] = m.jrw[i] / sc
        self.cjrw = [self.C[i] * jrw[i % 4] for i in range(12)]   # C Jrw (3 x 4), for H = J w + C Jrw w_rw
        self.m_ff = (m.m[0] / sc, m.m[1] / sc, m.m[2] / sc)        # dipole, N m / T
        self.cof_failed = -1                # the failed set self.Cu and self.cof were made for
        self.cof = None
        self.K, self.D = zeros(9), zeros(9)
        control.gains(self.K, self.D, self.J, float(cfg.get("ts", 33.0)), cfg.get("pd_zeta", control.ZETA))
        self.tau, self.tff, self.H, self.u = zeros(3), zeros(3), zeros(3), zeros(4)
        self.A, self.b = zeros(9), zeros(3)
        self.m_cmd = zeros(3)
        self.mtq_sat = 0                    # the rods clipped this cycle (bits)
        self.mag_miss = 0.0
        self.fly = fo is not None
        if self.fly:
            self._flight_init(cfg, fo)

    def _flight_init(self, cfg, fo):
        mt = cfg.get("magnetorquers")
        _check_rods(mt)
        self.mtq_limit = float(mt["dipole_limit_am2"])
        self.k_unload = float(fo["unload_gain_1_s"])
        w = cfg.get("wheels") or {}
        lim = float(w.get("speed_limit_rpm", 10000.0)) * RPM
        self.bias = float(fo["wheel_bias_share"]) * lim
        self.bias_gain = float(fo["wheel_bias_gain_1_s"])
        self.jrw_nom = [float(v) for v in w.get("rotor_inertia_kgm2", (3e-6,) * NW)]
        self.nvec = flight.null_vector(self.C)

    @micropython.native
    def use_wheels(self, failed):
        """The axes in use and their (C C^T)^-1 cofactors for the failed mask (bits), when it changed."""
        if failed == self.cof_failed:
            return
        for r in range(3):
            for i in range(4):
                self.Cu[r * 4 + i] = 0.0 if failed & (1 << i) else self.C[r * 4 + i]
        try:
            self.cof = control.cct_cofactors(self.Cu)
        except ValueError:                  # the axes left do not span: torque() allocates nothing
            self.cof = None
        self.cof_failed = failed

    @micropython.native
    def idle(self):
        """u = 0 (before the APKF starts; each cycle before the law adds to it)."""
        u = self.u
        for i in range(4):
            u[i] = 0.0
        return u

    @micropython.native
    def torque(self, t, x, m_ff, qc, wc, wp, failed, X):
        """u (4, N m): the PD on (qc, wc) at the APKF's state x with the gyroscopic term and the modelled external
        torque (dipole ``m_ff``, physical; the orbit rA of the STKF state X) fed forward, saturated, allocated,
        plus friction compensation; wp the wheels' speeds (rad/s)."""
        u = self.u
        q, w = x, (x[4], x[5], x[6])
        J, sc, H, cj = self.J, self.scale, self.H, self.cjrw
        w0, w1, w2 = w
        wp0, wp1, wp2, wp3 = wp
        for i in range(3):
            s = J[i * 3] * w0 + J[i * 3 + 1] * w1 + J[i * 3 + 2] * w2
            s += cj[i * 4] * wp0
            s += cj[i * 4 + 1] * wp1
            s += cj[i * 4 + 2] * wp2
            s += cj[i * 4 + 3] * wp3
            H[i] = s
        # feed-forward: gravity gradient (J), m x b, tau_d (the APKF's model, Eq. 4.68-4.75)
        control.dcm(self.A, q)
        A = self.A
        rn = math.sqrt(X[0] * X[0] + X[1] * X[1] + X[2] * X[2])
        rb = [(A[i * 3] * X[0] + A[i * 3 + 1] * X[1] + A[i * 3 + 2] * X[2]) / rn for i in range(3)]
        Jr = [J[i * 3] * rb[0] + J[i * 3 + 1] * rb[1] + J[i * 3 + 2] * rb[2] for i in range(3)]
        g = 3.0 * MU_EARTH / (rn * rn * rn)
        field_dipole(self.b, X, t, self.gmst0)
        bb = [A[i * 3] * self.b[0] + A[i * 3 + 1] * self.b[1] + A[i * 3 + 2] * self.b[2] for i in range(3)]
        m0, m1, m2 = m_ff
        tff = self.tff
        tff[0] = g * (rb[1] * Jr[2] - rb[2] * Jr[1]) + m1 * bb[2] - m2 * bb[1] + x[7] / sc
        tff[1] = g * (rb[2] * Jr[0] - rb[0] * Jr[2]) + m2 * bb[0] - m0 * bb[2] + x[8] / sc
        tff[2] = g * (rb[0] * Jr[1] - rb[1] * Jr[0]) + m0 * bb[1] - m1 * bb[0] + x[9] / sc
        if failed:
            self._coasting(tff, wp, failed)
        control.pd_torque(self.tau, q, w, qc, wc, self.K, self.D, H, tff)
        if self.cof is not None:             # else the wheels left do not span: no torque to allocate
            control.saturate(self.tau, self.Cu, self.torque_max, self.cof)
            control.wheel_torques(u, self.tau, self.Cu, self.cof)
        c, v, sm = self.fric
        for i in range(4):
            if failed & (1 << i):
                u[i] = 0.0
            else:
                wi = wp[i]
                u[i] = u[i] + v * wi + c * math.tanh(wi / sm)
        return u

    def _coasting(self, tff, wp, failed):
        """tff += C_k f(W_k) for each failed wheel k: its driver is off and its rotor coasts down on its friction
        f (the model's, as the friction compensation), whose reaction turns the body (H = J w + C Jrw W is
        conserved); wp the wheels' speeds (a failed wheel's: the wheel filter's estimate, rad/s)."""
        c, v, sm = self.fric
        C = self.C
        for i in range(4):
            if failed & (1 << i):
                f = v * wp[i] + c * math.tanh(wp[i] / sm)
                for r in range(3):
                    tff[r] += C[r * 4 + i] * f

    def flight(self, t, x, qc, wc, rd, failed, X, rods_out=0):
        """The flight world's u (4, N m): the magnetorquers' dipole (``m_cmd``) from the wheels' momentum
        h = C Jrw W and the model field b through the estimate (the rods ``rods_out``, bits, left out:
        ``flight.rods_left``), then ``torque`` with the dipole's torque fed forward and the wheels' null-space bias
        when all four work; ``rd`` the cycle's ``intake.Intake``."""
        cj, wp = self.cjrw, rd.wp
        h = [cj[i * 4] * wp[0] + cj[i * 4 + 1] * wp[1] + cj[i * 4 + 2] * wp[2] + cj[i * 4 + 3] * wp[3]
             for i in range(3)]
        control.dcm(self.A, x)
        field_dipole(self.b, X, t, self.gmst0)
        A = self.A
        b = [A[i * 3] * self.b[0] + A[i * 3 + 1] * self.b[1] + A[i * 3 + 2] * self.b[2] for i in range(3)]
        if rd.mag_got:                        # the magnetometer against the model: its largest miss (T)
            d = math.sqrt(sum((rd.mag[i] - b[i]) ** 2 for i in range(3)))
            if d > self.mag_miss:
                self.mag_miss = d
        mf = self.m_ff
        self.mtq_sat = flight.unloading(self.m_cmd, b, h, self.k_unload, self.mtq_limit, mf, rods_out)
        m = self.m_cmd
        u = self.torque(t, x, (mf[0] + m[0], mf[1] + m[1], mf[2] + m[2]), qc, wc, wp, failed, X)
        if self.cof is not None and not failed:
            flight.null_bias(u, self.nvec, wp, self.jrw_nom, self.bias, self.bias_gain)
        return u
