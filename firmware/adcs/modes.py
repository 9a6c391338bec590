"""The ADCS app's guidance and modes (MicroPython): where each cycle's mode is decided and the command the PD
tracks, q_c and w_c, is set. Modes are the packet table's integers (``protocol.consts.MODE_*``).

The command is the attitude at SatB (Eq. 6.3-6.4) at the STKF's state and its rate, a central difference over
+-0.5 s of the orbit propagator. Where it does not exist (the line of sight opposite the laser axis: Eq. 6.3's
rotation is not unique) the cycle rate-damps (q_c = q, w_c = 0, mode HOLD).

Thesis world: HOLD (rate damping while the APKF converges, ``hold_s``; with idle wheels the thesis's residual
dipole takes the body past the star tracker's 0.1 deg/s within ~6-9 s, measured, and the filter goes blind), then
POINT at the command. The first acquisition: once the estimate says the slew to SatB is done (within
``acquire_deg``, 1 deg, of the command), rate damping again (mode HOLD) for as long as the star tracker gives no
valid fix; the first valid fix there ends it for good. The slew leaves a rate error of ~0.05 deg/s from the
calibrated parameters (and ~5 arcsec/s per s more while blind, from the modelled torques' errors), which beside
SatB's ~0.06 deg/s keeps the true rate at the tracker's 0.1 deg/s limit: with the filtered momentum input, a 600 s
CAN session on the calibration file of seed 1 (hpop truth) lost the tracker for good without this, and 14 of 14
sessions (the files of seeds 0-5 with hpop truth, bench_adcs_can; 0-7 with two-body truth) regain it within ~50 s
of the slew with it.

Flight world: HOLD until ``hold_s``, then SLEW (``flight.Slew`` from the estimate to the command), ACQUIRE (rate
damping on the estimate until the star tracker answers: the blind slew leaves a rate error of a few hundredths of a
deg/s, and the command's own turn on top of it could keep the tracker blind), POINT (the command; SLEW again
beyond ``reslew_deg``).

Either world: DEGRADED while a wheel has failed or the star tracker, SatA's GNSS or the beacon (or SatB's GNSS when
used) has been silent for ``stale_s`` (``health.Health``); in the flight world's SLEW and ACQUIRE the star tracker
alone being silent is not degraded (it is blind by design there). INIT until the APKF starts.
"""

import math

from firmware.adcs import control, flight, linalg, stkf_lean
from firmware.adcs.linalg import micropython
from protocol.consts import MODE_ACQUIRE, MODE_DEGRADED, MODE_HOLD, MODE_INIT, MODE_POINT, MODE_SLEW

DEG = math.pi / 180.0


class Modes:
    """The mode machine of one world and the command (``qc``, ``wc``: rad, rad/s) it sets each cycle; ``fo`` the
    flight world's options (``flight.options``; None: the thesis world)."""

    def __init__(self, cfg, fo=None):
        zeros = linalg.zeros
        self.fly = fo is not None
        self.hold_s = float(cfg.get("hold_s", 30.0))
        self.laser = tuple(float(v) for v in cfg.get("laser_axis", control.LASER_AXIS))
        self.cos_acq = math.cos(math.radians(float(cfg.get("acquire_deg", 1.0))) / 2.0)
        self.acquired = False               # a valid star-tracker fix after the slew to SatB (thesis world)
        self.acquiring = False              # rate damping until then
        self.no_command = False             # rate damping: no pointing command at this geometry
        self.fmode = MODE_INIT              # the flight world's guidance mode
        self.mode = MODE_INIT               # the mode reported
        self.cw = control.Work(zeros)
        self.qc, self.wc = zeros(4), zeros(3)
        self.qm_, self.qp_ = zeros(4), zeros(4)
        self.xo = stkf_lean.zeros_d(12)
        if self.fly:
            self.slew = flight.Slew(float(fo["slew_rate_deg_s"]) * DEG, float(fo["slew_acc_deg_s2"]) * DEG)
            self.reslew = float(fo["reslew_deg"]) * DEG
            self.qr, self.wr = zeros(4), zeros(3)

    @micropython.native
    def command_rate(self, X):
        """q_c (Eq. 6.3-6.4) at the STKF state X [rA, vA, rB, vB] and w_c by a central difference over +-0.5 s."""
        xo = self.xo
        control.attitude_command(self.qc, X, (X[3], X[4], X[5]), (X[6], X[7], X[8]), self.cw, self.laser)
        for sgn, qq in ((-1.0, self.qm_), (1.0, self.qp_)):
            xo[0:12] = X[0:12]
            stkf_lean.f(xo, 0, 0.5 * sgn)
            stkf_lean.f(xo, 6, 0.5 * sgn)
            control.attitude_command(qq, xo, (xo[3], xo[4], xo[5]), (xo[6], xo[7], xo[8]), self.cw, self.laser)
        dq = self.cw.q1
        qm = self.qm_
        control.quat_mul(dq, self.qp_, (-qm[0], -qm[1], -qm[2], qm[3]))
        s = 2.0 if dq[3] >= 0 else -2.0
        for i in range(3):
            self.wc[i] = s * dq[i]        # rotvec / (2 h), 2 h = 1 s

    @micropython.native
    def _commanded(self, t, X):
        """True when the command is flown this cycle (after the hold, where it exists)."""
        self.no_command = False
        if t < self.hold_s:
            return False
        try:
            self.command_rate(X)
        except (ValueError, ZeroDivisionError):    # no command at this geometry (line of sight opposite
            self.no_command = True                 # the laser axis, rA = rB): rate damping, mode HOLD
            return False
        return True

    @micropython.native
    def _damp(self, q):
        """Rate damping: q_c = q, w_c = 0."""
        for i in range(4):
            self.qc[i] = q[i]
        for i in range(3):
            self.wc[i] = 0.0

    @micropython.native
    def thesis(self, t, q, st_ok, X):
        """The thesis world's command at the estimate q and the STKF state X (module docstring)."""
        self.acquiring = False
        hold = not self._commanded(t, X)
        if not hold and not self.acquired:     # the first acquisition
            qc = self.qc
            if abs(q[0] * qc[0] + q[1] * qc[1] + q[2] * qc[2] + q[3] * qc[3]) > self.cos_acq:
                if st_ok:
                    self.acquired = True
                else:
                    hold = self.acquiring = True
        if hold:
            self._damp(q)

    def flight(self, t, q, st_ok, X):
        """The flight world's mode machine and command at the estimate q and the STKF state X (module
        docstring)."""
        qc, wc = self.qc, self.wc
        hold = not self._commanded(t, X)
        if not hold and self.fmode == MODE_ACQUIRE and not st_ok:
            hold = True                       # rate damping until the star tracker answers
        if hold:
            self._damp(q)
            if self.fmode not in (MODE_HOLD, MODE_ACQUIRE) and not self.no_command:
                self.fmode = MODE_HOLD
            return
        err = flight.angle(q, qc)
        if self.fmode == MODE_POINT and err > self.reslew:
            self.fmode = MODE_SLEW
            self.slew.active = False
        elif self.fmode == MODE_ACQUIRE and st_ok:
            self.fmode = MODE_POINT if err <= self.reslew else MODE_SLEW
            self.slew.active = False
        if self.fmode in (MODE_INIT, MODE_HOLD) or (self.fmode == MODE_SLEW and not self.slew.active):
            self.slew.start(q, qc)
            self.fmode = MODE_SLEW
        if self.fmode == MODE_SLEW:
            self.slew.reference(self.qr, self.wr, qc, wc)
            for i in range(4):
                qc[i] = self.qr[i]
            for i in range(3):
                wc[i] = self.wr[i]
            if not self.slew.active:
                self.fmode = MODE_ACQUIRE

    @micropython.native
    def decide(self, t, started, health):
        """The mode reported for the cycle at t (s): ``started`` the APKF has started; ``health`` the app's
        ``health.Health`` after the cycle."""
        if not started:
            self.mode = MODE_INIT
        elif health.failed or (health.long_gap(t) and not (
                self.fly and self.fmode in (MODE_SLEW, MODE_ACQUIRE) and health.only_st(t))):
            self.mode = MODE_DEGRADED
        elif self.fly:
            self.mode = MODE_HOLD if self.no_command else self.fmode
        elif t < self.hold_s or self.acquiring or self.no_command:
            self.mode = MODE_HOLD
        else:
            self.mode = MODE_POINT
        return self.mode
