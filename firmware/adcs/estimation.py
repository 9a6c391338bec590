"""The ADCS app's estimation (MicroPython): the lean APKF (attitude, rate, disturbance torque) and the lean
STKF/AFLS (both satellites' orbits) run on a cycle's readings, in the order of Sec. 6.4.2.

The APKF starts from the first two valid star-tracker fixes one step apart; its orbit and field inputs are the
STKF's rA and a tilted dipole field model (the emulator's own model, IGRF-2020 degree 1, turned from ``gmst0_rad``,
the GMST at the epoch the ground loads in the configuration). The STKF is ``stkf_lean.LeanStkf`` through its public
calls only: predict, SatA's GNSS, the beacon (Eq. 5.13-5.17) with the APKF's attitude covariance 4 P_qq in its
noise (Eq. 5.15-5.16, Sec. 5.3.3), SatB's GNSS at its time tag (EAFLS). Its lag (4 s, ``lag_s``) is kept only with
SatB's GNSS: without it no measurement arrives late, so SatB's smoother holds two nodes of 6 states (lag 0,
capacity 3, the minimum), which keeps its joint covariance at 12 x 12 instead of 30 x 30. A measurement the filter
refuses is counted (``Health.n_refused``) and the cycle goes on.

The ticks' times drive both filters: a tick later than one step after the last propagates the APKF over each second
of the gap (and the STKF, in predictions of at most 600 s); a tick at the last one's time does not step the APKF;
a tick earlier than it neither, and its SatA GNSS fix and beacon are refused (the STKF is at the later time).

In the flight world the magnetorquers' dipole is a known input of the APKF's model, and a star-tracker fix whose
normalised innovation passes the gate resets the attitude to it (``flight.reset_attitude``); the beacon is taken
only while the attitude's 1 sigma is within ``beacon_gate_arcsec``.
"""

import math

from firmware.adcs import apkf_lean, control, flight, linalg, stkf_lean
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators
from protocol.units import MU_EARTH, RAD_PER_ARCSEC

R_EARTH = 6371.2e3
OMEGA_EARTH = 7.2921159e-5
IGRF2020_DIPOLE_NT = (-29404.8, -1450.9, 4652.5)
NOT_HEARD = (False,) * 4


@micropython.native
def field_dipole(b, r, t, gmst0):
    """b (3) = the tilted-dipole field (T, inertial) at r (m) and time t (s): (R/|r|)^3 (3 (m.r^) r^ - m), the
    dipole turned by the Earth angle gmst0 + w_E t (gmst0, rad: GMST at t = 0)."""
    th = gmst0 + OMEGA_EARTH * t
    c, s = math.cos(th), math.sin(th)
    g10, g11, h11 = IGRF2020_DIPOLE_NT
    mx, my, mz = 1e-9 * (c * g11 - s * h11), 1e-9 * (s * g11 + c * h11), 1e-9 * g10
    rn = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    rx, ry, rz = r[0] / rn, r[1] / rn, r[2] / rn
    k = (R_EARTH / rn) ** 3
    d = 3.0 * (mx * rx + my * ry + mz * rz)
    b[0], b[1], b[2] = k * (d * rx - mx), k * (d * ry - my), k * (d * rz - mz)


def steps(t, t0):
    """Whole 1 s steps from t0 to t (the ticks' times are whole seconds)."""
    return int(math.floor(t - t0 + 0.5))


def stkf_cap(lag_s, rate_hz=1.0):
    """The lean STKF's node capacity for a lag at the 1 Hz predict rate: the nodes within the lag plus two
    (the anchor and the new node; stkf_lean.LeanStkf's docstring: 6 at 1 Hz with the 4 s lag), at least 3."""
    n = int(math.ceil(lag_s * rate_hz - 1e-9)) + 2
    return n if n > 3 else 3


def stkf_model(cfg):
    """The STKF's dynamics from the configuration: ``stkf_gravity`` ("two-body", Eq. 5.7, the default; "j2": with
    the J2 term) and ``stkf_accel``: "white" (the default: white acceleration noise ``stkf_qa``, m^2/s^3, Eq. 5.8;
    default the thesis's 0.01; ``LeanStkf``'s keywords) or "markov" (the acceleration as a first-order
    Gauss-Markov state per axis of 1 sigma ``stkf_sigma_a``, m/s^2, and correlation time ``stkf_tau``, s;
    ``stkf_dmc.DmcStkf``'s keywords). ValueError naming the key for a bad value."""
    gravity, accel = cfg.get("stkf_gravity", "two-body"), cfg.get("stkf_accel", "white")
    if not (isinstance(gravity, str) and gravity in stkf_lean.GRAVITY):
        raise ValueError("stkf_gravity must be one of %s, got %r" % (", ".join(sorted(stkf_lean.GRAVITY)), gravity))
    if accel not in ("white", "markov"):
        raise ValueError("stkf_accel must be white or markov, got %r" % (accel,))
    keys = ("stkf_qa",) if accel == "white" else ("stkf_sigma_a", "stkf_tau")
    out = {"gravity": gravity}
    for key in keys:
        v = cfg.get(key, stkf_lean.QA_THESIS if key == "stkf_qa" else None)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and v - v == 0 and v > 0):
            raise ValueError("%s must be a number > 0 (%s), got %r" % (key, UNITS[key], v))
        out[key[5:]] = float(v)
    return out


UNITS = {"stkf_qa": "m^2/s^3", "stkf_sigma_a": "m/s^2", "stkf_tau": "s"}


def stkf_filter(kw):
    """The STKF class for ``stkf_model``'s keywords: ``stkf_dmc.DmcStkf`` (imported only then) for markov's."""
    if "tau" not in kw:
        return stkf_lean.LeanStkf
    from firmware.adcs import stkf_dmc
    return stkf_dmc.DmcStkf


def vehicle(cfg):
    """The lean APKF's vehicle from the configuration (a spacecraft file's figures; the defaults are the thesis's
    3U): its nominal wheel axes, star-tracker and read-out noise, initial 1 sigma and the wheels its parameter file
    is checked against (``apkf_lean.Model``'s keywords)."""
    return {"c0": cfg.get("wheel_axes"),
            "sigma_st_arcsec": [float(v) for v in cfg.get("star_tracker_sigma_arcsec", (20.0, 20.0, 60.0))],
            "tach_rpm": float(cfg.get("tach_noise_rpm", 10.0)),
            "p0": cfg.get("apkf_p0", (10.0, 10.0, 1e-6)), "wheels": cfg.get("wheels")}


class Estimation:
    """Both filters of the app: ``apkf`` (None until it starts; ``t_apkf`` its time, s) and ``stkf``, with the
    STKF's estimate [rA, vA, rB, vB] and its 1 sigma in ``xs``, ``sig`` (m, m/s) after each cycle, and the
    attitude covariance the beacon takes in ``Patt`` (rad^2). ``rd`` is the app's ``intake.Intake``, ``health``
    its ``health.Health``; ``fo`` the flight world's options (None: the thesis world)."""

    def __init__(self, cfg, rd, health, fo=None):
        self.rd, self.health = rd, health
        self.params = cfg["params"]
        self.scale = float(self.params.get("torque_scale", 1.0))
        self.gmst0 = float(cfg["gmst0_rad"])       # the field model's Earth angle at t = 0 (GMST at the epoch)
        self.sigma_b = float(cfg.get("beacon_sigma_arcsec", 60.0)) * RAD_PER_ARCSEC
        self.mkw = vehicle(cfg)
        # the lean APKF's momentum input (apkf_lean.Model): the read-outs filtered on the torques this app
        # commanded (flown), or, for comparison, the raw read-out difference or the torques alone (see the
        # docs/ADCS.md's "Lean flight ADCS under MicroPython")
        momentum = cfg.get("apkf_momentum", "filtered")
        if momentum not in apkf_lean.MOMENTUM:
            raise ValueError("apkf_momentum must be one of %s, got %r" % (", ".join(apkf_lean.MOMENTUM), momentum))
        self.akw = dict(self.mkw)
        self.akw.update(momentum=momentum, friction=cfg.get("friction", apkf_lean.FRICTION),
                        torque_max=float(cfg.get("torque_max", apkf_lean.TORQUE_MAX)))
        self.model = apkf_lean.Model(self.params, **self.mkw)   # J, C Jrw for the controller before the APKF starts
        sg = cfg.get("gnss_sigma", (30.0, 1.0))
        self.Rg = stkf_lean.zeros_d(36)
        for i in range(6):
            self.Rg[i * 7] = (sg[0] if i < 3 else sg[1]) ** 2
        lag = float(cfg.get("lag_s", stkf_lean.LAG_S)) if rd.satb else 0.0
        kw = stkf_model(cfg)
        self.stkf = stkf_filter(kw)(cfg["stkf_x0"], cfg["stkf_P0"], 0.0, lag, cap=stkf_cap(lag), **kw)
        self.xs = stkf_lean.zeros_d(12)
        self.sig = stkf_lean.zeros_d(12)
        self.stkf.get(self.xs, self.sig)
        self.xo = stkf_lean.zeros_d(12)
        self.apkf = None
        self.t_apkf = 0.0
        self.qst_prev = linalg.zeros(4)     # the last valid fix before the APKF starts, at t_st_prev
        self.st_prev_ok = False
        self.t_st_prev = 0.0
        self.rmid, self.b, self.Patt = linalg.zeros(3), linalg.zeros(3), linalg.zeros(9)
        self.beacon_used = False            # the STKF took this cycle's beacon
        self.fly = fo is not None
        if self.fly:
            self.gate = float(fo["innovation_gate"])
            self.gate_b = float(fo["beacon_gate_arcsec"]) * RAD_PER_ARCSEC
            self.m_file = list(self.model.m)          # the parameter file's dipole (filter units)
            self.z3 = linalg.zeros(3)

    def start(self, q, w0, wp, t):
        """Start the APKF at time t (s) from attitude q, rate w0 (rad/s) and the wheels' speeds wp (rad/s)."""
        self.apkf = apkf_lean.LeanApkf(self.params, q, w0, wp, **self.akw)
        self.t_apkf = t

    @micropython.native
    def env(self, t, X=None):
        """(r unit, 3 mu/r^3, b_i) at mid-step t - 0.5 from rA, vA at t - 1: the STKF's (X None: self.xs,
        the previous cycle's) or X's."""
        if X is None:
            X = self.xs
        r = self.rmid
        for i in range(3):
            r[i] = X[i] + 0.5 * X[3 + i]
        rn = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        field_dipole(self.b, r, t - 0.5, self.gmst0)
        return ((r[0] / rn, r[1] / rn, r[2] / rn), 3.0 * MU_EARTH / (rn * rn * rn), self.b)

    def run_apkf(self, t, u, m_cmd=None):
        """Start the APKF from two valid star-tracker fixes one step (1 s) apart, or run it to t: one step per
        second since its last (a gap in the ticks: the steps before the last without measurements, the wheels on
        their last command ``u`` (N m), rA propagated for their field and orbit inputs; the momentum input's
        read-out change falls in the last step). A tick whose time did not advance by a step (repeated or
        earlier) leaves it as it is. A fix the APKF refuses (S not positive definite) is marked invalid, stale in
        the status. ``m_cmd``: the magnetorquers' dipole of the step (A m^2, flight world)."""
        rd = self.rd
        st_ok = rd.st_ok()
        if self.apkf is None:
            self._first_fixes(t, st_ok)
            return
        n = steps(t, self.t_apkf)
        if n < 1:
            return
        if n > 1:
            xo = self.xo
            xo[0:6] = self.xs[0:6]
            for j in range(n - 1):
                self.apkf.step(self.apkf.wm, None, self.env(self.t_apkf + j + 1, xo), u, NOT_HEARD)
                stkf_lean.f(xo, 0, 1.0)
            env = self.env(t, xo)
        else:
            env = self.env(t)
        k = self.apkf.skipped
        if self.fly:
            self._step_gated(env, st_ok, u, m_cmd)
        else:
            self.apkf.step(rd.wp, rd.qst if st_ok else None, env, u, rd.rw_got)
        if self.apkf.skipped != k:
            rd.st_valid = False              # refused (S not positive definite): stale, as an invalid fix
        self.t_apkf += n

    def _first_fixes(self, t, st_ok):
        """Before the APKF: it starts on a valid fix one step after the last, w0 = rotvec(q (x) p^-1) / 1 s."""
        rd = self.rd
        if st_ok and self.st_prev_ok and steps(t, self.t_st_prev) == 1:
            q, p = rd.qst, self.qst_prev
            pc = (-p[0], -p[1], -p[2], p[3])
            dq = linalg.zeros(4)
            control.quat_mul(dq, q, pc)
            s = 2.0 if dq[3] >= 0 else -2.0
            self.start(q, (s * dq[0], s * dq[1], s * dq[2]), rd.wp, t)
        self.st_prev_ok = st_ok
        if st_ok:
            self.t_st_prev = t
            for i in range(4):
                self.qst_prev[i] = rd.qst[i]

    def _step_gated(self, env, st_ok, u, m_cmd):
        """The flight world's APKF step: the magnetorquers' dipole of the step a known input (added to the
        parameter file's residual in the model), the prediction, then the star tracker's fix unless its
        normalised innovation passes ``gate``: then the attitude is reset to it (``flight.reset_attitude``)."""
        a, rd = self.apkf, self.rd
        m = a.model.m
        for i in range(3):
            m[i] = self.m_file[i] + self.scale * m_cmd[i]
        a.step(rd.wp, None, env, u, rd.rw_got)
        if not st_ok:
            return
        apkf_lean.error_vec(self.z3, rd.qst, a.x)
        nis = flight.nis3(self.z3, a.P, a.model.R)
        if nis > self.gate:
            flight.reset_attitude(a.x, a.P, rd.qst, a.model.R)
            hl, z = self.health, self.z3
            hl.n_resets += 1
            hl.reset_nis = nis
            hl.reset_arcsec = 2.0 * math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2]) / RAD_PER_ARCSEC
        elif not apkf_lean.update(a.x, a.P, rd.qst, a.model, a.work):
            a.skipped += 1

    def fill_unheard(self):
        """The speeds of the wheels not heard this cycle (``rd.wp``, rad/s): the wheel filter's prediction
        (``apkf_lean.wheel_speeds``: a silent rotor coasting down on its friction) instead of the last read-out,
        for the control's momentum and the unloading. Before the APKF starts, or without the wheel filter
        (momentum "tach" or "torque"), the last read-out stays."""
        a, rd = self.apkf, self.rd
        if a is None or not a.model.filtered:
            return
        for i in range(4):
            if not rd.rw_got[i]:
                rd.wp[i] = a.W[i]

    @micropython.native
    def attitude(self):
        """(q, P_att 3 x 3 in ``Patt``): the APKF's, or the star tracker's before it starts."""
        if self.apkf is not None:
            P = self.apkf.P
            for i in range(3):
                for j in range(3):
                    self.Patt[i * 3 + j] = 4.0 * P[i * 9 + j]
            return self.apkf.x
        sst = self.mkw["sigma_st_arcsec"]
        for i in range(9):
            self.Patt[i] = 0.0
        for i in range(3):
            self.Patt[i * 4] = (sst[i] * RAD_PER_ARCSEC) ** 2
        return self.rd.qst

    def run_stkf(self, t, q):
        """Predict to t, then SatA's GNSS, the beacon and SatB's delayed GNSS. A measurement the filter refuses
        (ValueError: NaN, out of order, older than the lag, S not positive definite; the filter is left as it was)
        is counted in ``n_refused`` and the cycle goes on, its sensor stale as for a missed reading (SatA's GNSS,
        the beacon); so is a refused prediction. Before the APKF starts the beacon needs the star tracker's valid
        fix of this cycle."""
        f, rd, hl = self.stkf, self.rd, self.health
        if t > f.now + 1e-9:
            try:
                while t - f.now > stkf_lean.MAX_STEP_S:       # a gap in the ticks: propagate in steps
                    f.predict(f.now + stkf_lean.MAX_STEP_S)
                f.predict(t)
            except ValueError:
                hl.n_refused += 1
        if rd.gnss_got:
            try:
                f.update_gnss(rd.zg, self.Rg, 0, t=t)
            except ValueError:
                hl.n_refused += 1
                rd.gnss_got = False            # not usable (miss_gnss was counted: it came)
        tr = self.Patt[0] + self.Patt[4] + self.Patt[8]
        gated = self.fly and not (tr >= 0.0 and math.sqrt(tr) <= self.gate_b)     # a broken P gates it too
        self.beacon_used = False
        if rd.bc_got and rd.bc_valid and not gated and (self.apkf is not None or rd.st_ok()):
            try:
                f.update_beacon(rd.yb, q, self.Patt, self.sigma_b, t=t)
                self.beacon_used = True
            except ValueError:
                hl.n_refused += 1
                rd.bc_valid = False
        if rd.satb:
            for j in range(rd.nb):
                try:
                    f.update_gnss(rd.zb[j], self.Rg, 1, t=rd.tb[j])
                    hl.n_gnss_b += 1
                    hl.last_ok["gnss_b"] = t
                except ValueError:                   # older than the lag, out of order, repeated, NaN
                    hl.n_refused += 1
        rd.nb = 0
        f.get(self.xs, self.sig)

    def position_cov(self, PA, PB):
        """PA[0:9], PB[0:9] = the STKF's 3 x 3 covariances of rA and rB now (m^2; ``LeanStkf.position_cov``)."""
        self.stkf.position_cov(PA, PB)

    def sigma_att(self):
        """The attitude's 1 sigma (rad, root of the trace of 4 P_qq), 0 before the APKF starts."""
        if self.apkf is None:
            return 0.0
        P = self.apkf.P
        return math.sqrt(max(0.0, 4.0 * (P[0] + P[10] + P[20])))
