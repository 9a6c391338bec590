"""The ADCS flight application (MicroPython): the 1 Hz cycle that ties the lean APKF, the lean STKF/AFLS and
the pointing controller together, and its CAN service loop. The same app flies on a board, in its own
process on CAN (``serve``), and in process under the ground's analysis (``InProcess``, the same packets' bytes).

One cycle (the sequence of Sec. 6.4.2 at the flight side's scale):

1. sensors: the wheels' RW_TLM (tachometer read-outs at the cycle's time), the star tracker, SatA's GNSS, the
   beacon and SatB's relayed GNSS (time-tagged 2-3 s back) received since the last cycle;
2. lean APKF (attitude, rate, disturbance torque; parameters from the calibration's parameter file), started
   from the first two valid star-tracker outputs; its orbit and field inputs from the STKF's rA and a tilted
   dipole field model (the emulator's own model, IGRF-2020 degree 1, turned from ``gmst0_rad``, the GMST at
   the epoch the ground loads in the configuration);
3. lean STKF/AFLS: predict, SatA's GNSS, the beacon (Eq. 5.13-5.17) with the APKF's attitude covariance
   4 P_qq in its noise (Eq. 5.15-5.16, Sec. 5.3.3), SatB's GNSS at its time tag (EAFLS);
4. during the hold (``hold_s``, while the APKF converges) rate damping: -D w plus the gyroscopic and
   modelled external torques fed forward, as the thesis world's hold (with idle wheels the thesis's residual dipole takes
   the body past the star tracker's 0.1 deg/s within ~6-9 s, measured, and the filter goes blind);
   after it the command at SatB (Eq. 6.3-6.4) and
   its rate (central difference over +-0.5 s of the orbit propagator), quaternion PD (Eq. 6.5-6.7) with the
   gyroscopic term and the modelled external torque fed forward, saturation, minimum-norm wheel torques
   (Eq. 6.11) plus friction compensation. The first acquisition: once the estimate says the slew to SatB is
   done (within ``acquire_deg``, 1 deg, of the command), rate damping again (q_c = q, w_c = 0, mode HOLD) for
   as long as the star tracker gives no valid fix; the first valid fix there ends it for good. Where the
   command does not exist (line of sight opposite the laser axis: Eq. 6.3's rotation is not unique) rate
   damping too, for that cycle (mode HOLD). The
   slew leaves a rate error of ~0.05 deg/s from the calibrated parameters (and ~5 arcsec/s per s more while
   blind, from the modelled torques' errors), which beside SatB's ~0.06 deg/s keeps the true rate at the
   tracker's 0.1 deg/s limit: with the filtered momentum input, a 600 s CAN session on the calibration file
   of seed 1 (hpop truth) lost the tracker for good without this, and 14 of 14 sessions (the files of seeds
   0-5 with hpop truth, bench_adcs_can; 0-7 with two-body truth) regain it within ~50 s of the slew with it;
5. RW_CMD to each wheel, then ADCS_STATUS (mode, stale sensors, missed replies, estimates).

The STKF is firmware/adcs/stkf_lean.py's ``LeanStkf`` through its public calls only (predict, update_gnss,
update_beacon, get). Its lag (4 s, ``lag_s``) is kept only with SatB's GNSS: without it no measurement arrives
late, so SatB's smoother holds two nodes of 6 states (lag 0, capacity 3, the minimum), which keeps its joint
covariance at 12 x 12 instead of 30 x 30. The capacity follows from the lag (``stkf_cap``: the lag's nodes at
1 Hz plus two). A measurement the filter refuses is counted (ADCS_STATUS.n_refused) and the cycle goes on.

Degraded operation: a sensor that misses its cycle is counted and the filters propagate without it; a wheel
whose RW_TLM is missed 3 cycles in a row is declared failed, its column leaves the torque allocation (the other
three span the body axes) and its read-out is held for the APKF; with two or more failed the wheels left do not
span the body axes: no torque is allocated, the working wheels get their friction compensation only (they keep
their speed, so the body feels no torque from them); the mode is DEGRADED while a wheel has
failed or the star tracker, SatA's GNSS or the beacon (or SatB's GNSS when used) has been silent, invalid or
refused for ``stale_s`` seconds. The ticks' times drive both filters: a tick later than one step after the last
propagates the APKF over each second of the gap (and the STKF, in predictions of at most 600 s); a tick at the
last one's time does not step the APKF; a tick earlier than it neither, and its SatA GNSS fix and beacon are
refused (n_refused: the STKF is at the later time).
"""

import math
import struct

try:
    from time import ticks_diff                   # MicroPython: ticks wrap (2^30 us on a 32-bit board)
except ImportError:                               # CPython
    def ticks_diff(a, b):
        return a - b

from firmware.adcs import apkf_lean, control, flight, linalg, stkf_lean
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators
from protocol import can as canmap
from protocol import core
from protocol.consts import (MODE_ACQUIRE, MODE_DEGRADED, MODE_HOLD, MODE_INIT, MODE_POINT, MODE_SLEW,
                             STALE_BEACON, STALE_GNSS_A, STALE_GNSS_B, STALE_RW0, STALE_STARTRACKER)
from protocol.units import MU_EARTH, RAD_PER_ARCSEC

R_EARTH = 6371.2e3
OMEGA_EARTH = 7.2921159e-5
IGRF2020_DIPOLE_NT = (-29404.8, -1450.9, 4652.5)
RPM = 2.0 * math.pi / 60.0
NW = 4
FAIL_AFTER = 3
NEVER = 65535
NOT_HEARD = (False,) * NW
UNIT_TOL = 1e-3        # | |v|^2 - 1 | of a unit vector or quaternion off the bus (float32 rounding: ~1e-7)
_INF = float("inf")
# The flight world's options (configuration key "flight"; units in the names) and their defaults. The eigenaxis
# slew is short rather than slow: the star tracker is blind above its 0.1 deg/s, and the lean APKF's rate error
# grows ~5 arcsec/s per blind second (a 90 deg slew at 0.5 deg/s left ~0.1 deg/s, which kept the tracker blind;
# at 2 deg/s, < 0.03 deg/s); 2 deg/s is ~1/2 of what the 3U's wheels hold at 80 % of their speed, 0.2 deg/s^2 ~16 %
# of their torque.
FLIGHT = {
    "slew_rate_deg_s": 2.0,
    "slew_acc_deg_s2": 0.2,
    "reslew_deg": 1.0,             # POINT -> SLEW when the estimate is this far off the command
    "unload_gain_1_s": 2e-3,       # the cross-product law's gain: the wheels' momentum across b decays in ~500 s
    "innovation_gate": 44.84,      # chi-square, 3 dof, 1 - 1e-9: a star-tracker fix beyond it resets the attitude
    "beacon_gate_arcsec": 300.0,   # the STKF takes the beacon only while the attitude 1 sigma is within this
    "wheel_bias_share": 0.2,       # the wheels' null-space speed bias, a share of their speed limit
    "wheel_bias_gain_1_s": 0.01,   # and its gain: ~100 s to reach it
}

P_RW_CMD = core.PACKET_ID["RW_CMD"]
P_RW_TLM = core.PACKET_ID["RW_TLM"]
P_ST = core.PACKET_ID["STARTRACKER"]
P_GNSS = core.PACKET_ID["GNSS"]
P_BEACON = core.PACKET_ID["BEACON"]
P_TICK = core.PACKET_ID["ADCS_TICK"]
P_MISSING = core.PACKET_ID["ADCS_MISSING"]
P_STATUS = core.PACKET_ID["ADCS_STATUS"]
P_MAG = core.PACKET_ID["MAGNETOMETER"]
P_MTQ_CMD = core.PACKET_ID["MTQ_CMD"]
MTQ = core.NODE["MTQ"]
DEG = math.pi / 180.0
RW0 = core.NODE["RW0"]
_FMT = dict((p, core.PACKET[p].fmt) for p in (P_RW_TLM, P_ST, P_GNSS, P_BEACON, P_TICK, P_STATUS, P_RW_CMD,
                                               P_MISSING, P_MAG, P_MTQ_CMD))
MAG_T = core.field_scales(P_MAG)["bx"] * 1e-9      # tesla per MAGNETOMETER count
_SCALE = core.field_scales(P_GNSS)
GNSS_M, GNSS_MS = _SCALE["x"], _SCALE["vx"]       # GNSS position (m) and velocity (m/s) per count, from the table


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


def _steps(t, t0):
    """Whole 1 s steps from t0 to t (the ticks' times are whole seconds)."""
    return int(math.floor(t - t0 + 0.5))


def stkf_cap(lag_s, rate_hz=1.0):
    """The lean STKF's node capacity for a lag at the 1 Hz predict rate: the nodes within the lag plus two
    (the anchor and the new node; stkf_lean.LeanStkf's docstring: 6 at 1 Hz with the 4 s lag), at least 3."""
    n = int(math.ceil(lag_s * rate_hz - 1e-9)) + 2
    return n if n > 3 else 3


class App:
    """The ADCS application's state. ``on_packet(pid, src, payload)`` stores a sensor reading;
    ``cycle(tick, t)`` runs one 1 Hz cycle and returns the wheel torques (``u``, N m) it commands."""

    def __init__(self, cfg):
        self.params = cfg["params"]
        self.scale = float(self.params.get("torque_scale", 1.0))
        self.ts = float(cfg.get("ts", 33.0))
        self.hold_s = float(cfg.get("hold_s", 30.0))
        self.gmst0 = float(cfg["gmst0_rad"])       # the field model's Earth angle at t = 0 (GMST at the epoch)
        self.stale_s = float(cfg.get("stale_s", 10.0))
        self.satb = bool(cfg.get("satb_gnss", False))
        self.torque_max = float(cfg.get("torque_max", apkf_lean.TORQUE_MAX))
        self.fric = cfg.get("friction", apkf_lean.FRICTION)        # coulomb, viscous, smoothing rad/s
        self.sigma_b = float(cfg.get("beacon_sigma_arcsec", 60.0)) * RAD_PER_ARCSEC
        # the vehicle (a spacecraft file's figures; the defaults are the thesis's 3U): the lean APKF's nominal
        # wheel axes, star-tracker and read-out noise and initial 1 sigma, the wheels its parameter file is checked
        # against, and the laser axis of the command
        self.sigma_st = [float(v) for v in cfg.get("star_tracker_sigma_arcsec", (20.0, 20.0, 60.0))]
        self.mkw = {"c0": cfg.get("wheel_axes"), "sigma_st_arcsec": self.sigma_st,
                    "tach_rpm": float(cfg.get("tach_noise_rpm", 10.0)),
                    "p0": cfg.get("apkf_p0", (10.0, 10.0, 1e-6)), "wheels": cfg.get("wheels")}
        self.laser = tuple(float(v) for v in cfg.get("laser_axis", control.LASER_AXIS))
        sg = cfg.get("gnss_sigma", (30.0, 1.0))
        self.Rg = stkf_lean.zeros_d(36)
        for i in range(6):
            self.Rg[i * 7] = (sg[0] if i < 3 else sg[1]) ** 2
        lag = float(cfg.get("lag_s", stkf_lean.LAG_S)) if self.satb else 0.0
        self.stkf = stkf_lean.LeanStkf(cfg["stkf_x0"], cfg["stkf_P0"], 0.0, lag, cap=stkf_cap(lag))
        self.xs = stkf_lean.zeros_d(12)     # the STKF's estimate [rA, vA, rB, vB] and its 1 sigma (get())
        self.sig = stkf_lean.zeros_d(12)
        self.stkf.get(self.xs, self.sig)
        self.apkf = None
        self.t_apkf = 0.0                   # the APKF's time (s)
        self.model = apkf_lean.Model(self.params, **self.mkw)   # J, C Jrw for the controller before the APKF starts
        zeros = linalg.zeros
        m = self.model
        self.J = zeros(9)
        for i in range(9):
            self.J[i] = m.J[i] / self.scale
        self.C = zeros(12)                  # normalised axes (3 x 4) and their Jrw
        self.Cu = zeros(12)                 # the axes in use (failed wheels' columns zero)
        jrw = zeros(4)
        for i in range(12):
            self.C[i] = m.C[i]
        for i in range(4):
            jrw[i] = m.jrw[i] / self.scale
        self.cjrw = [self.C[i] * jrw[i % 4] for i in range(12)]   # C Jrw (3 x 4), for H = J w + C Jrw w_rw
        self.m_ff = (m.m[0] / self.scale, m.m[1] / self.scale, m.m[2] / self.scale)   # dipole, N m / T
        self.cof_failed = -1                # the failed set self.Cu and self.cof were made for
        self.cof = None
        self.K = zeros(9)
        self.D = zeros(9)
        control.gains(self.K, self.D, self.J, self.ts)
        self.acquired = False               # a valid star-tracker fix after the slew to SatB (see _control)
        self.acquiring = False              # rate damping until then
        self.no_command = False             # rate damping: no pointing command at this geometry
        self.cos_acq = math.cos(math.radians(float(cfg.get("acquire_deg", 1.0))) / 2.0)
        self.cw = control.Work(zeros)
        self.qc = zeros(4)
        self.qm_, self.qp_ = zeros(4), zeros(4)
        self.wc = zeros(3)
        self.tau = zeros(3)
        self.tff = zeros(3)
        self.H = zeros(3)
        self.u = zeros(4)
        # the lean APKF's momentum input (apkf_lean.Model): the read-outs filtered on the torques this app
        # commanded (flown), or, for comparison, the raw read-out difference or the torques alone (see the
        # docs/ADCS.md's "Lean flight ADCS under MicroPython")
        self.momentum = cfg.get("apkf_momentum", "filtered")
        if self.momentum not in apkf_lean.MOMENTUM:
            raise ValueError("apkf_momentum must be one of %s, got %r" % (", ".join(apkf_lean.MOMENTUM),
                                                                          self.momentum))
        self.A = zeros(9)
        self.b = zeros(3)
        self.rmid = zeros(3)
        self.xo = stkf_lean.zeros_d(12)
        self.Patt = zeros(9)
        # sensor inputs of the cycle
        self.wp = zeros(4)
        self.rw_got = [False] * NW
        self.rw_miss_run = [0] * NW
        self.failed = 0
        self.qst = zeros(4)
        self.qst_prev = zeros(4)
        self.st_got = self.st_valid = self.st_prev_ok = False
        self.t_st_prev = 0.0
        self.zg = stkf_lean.zeros_d(6)
        self.gnss_got = False
        self.gnss_t = -1.0
        self.yb = zeros(3)
        self.bc_got = self.bc_valid = False
        self.zb = [stkf_lean.zeros_d(6) for _ in range(4)]
        self.tb = [0.0] * 4
        self.nb = 0
        # counters and ages
        self.miss_rw = [0] * NW
        self.miss_st = self.miss_gnss = self.miss_beacon = 0
        self.n_st_invalid = self.n_beacon_invalid = self.n_gnss_b = self.n_gnss_b_drop = 0
        self.n_refused = 0                  # STKF measurements (or predictions) refused with ValueError
        self.beacon_used = False            # the STKF took this cycle's beacon
        self.last_ok = {"st": 0.0, "gnss": 0.0, "beacon": 0.0, "gnss_b": 0.0}
        self.stale = 0
        self.mode = MODE_INIT
        self.t = 0.0
        self._flight_init(cfg)

    def _flight_init(self, cfg):
        """The flight world's state (``world`` "flight" in the configuration; ``flight`` its options, the
        defaults ``FLIGHT``'s; ``magnetorquers`` the spacecraft file's block)."""
        self.fly = cfg.get("world", "thesis") == "flight"
        self.fmode = MODE_INIT
        self.m_cmd = linalg.zeros(3)
        self.mtq_sat = 0
        self.n_resets = 0                   # attitude resets by the innovation gate; the last one's NIS
        self.reset_nis = 0.0
        self.mag = linalg.zeros(3)
        self.mag_got = False
        self.mag_miss = 0.0                 # the magnetometer's largest difference from the model field (T)
        self.t_st_ok = 0.0
        if not self.fly:
            return
        fo = cfg.get("flight") or {}
        for k in fo:
            if k not in FLIGHT:
                raise ValueError("unknown flight option %r (the options: %s)" % (k, ", ".join(sorted(FLIGHT))))
        opts = dict(FLIGHT)
        opts.update(fo)
        fo = opts
        mt = cfg.get("magnetorquers")
        if not mt:
            raise ValueError("the flight world needs the spacecraft's magnetorquers (configuration key "
                             "magnetorquers)")
        ax = mt["axes"]
        for i in range(3):
            for j in range(3):
                if abs(ax[i][j] / math.sqrt(sum(v * v for v in ax[i])) - (1.0 if i == j else 0.0)) > 1e-9:
                    raise ValueError("the lean ADCS drives three rods along body x, y, z; magnetorquers.axes = %r"
                                     % (ax,))
        self.mtq_limit = float(mt["dipole_limit_am2"])
        self.slew = flight.Slew(float(fo["slew_rate_deg_s"]) * DEG, float(fo["slew_acc_deg_s2"]) * DEG)
        self.reslew = float(fo["reslew_deg"]) * DEG
        self.k_unload = float(fo["unload_gain_1_s"])
        self.gate = float(fo["innovation_gate"])
        self.gate_b = float(fo["beacon_gate_arcsec"]) * RAD_PER_ARCSEC
        w = cfg.get("wheels") or {}
        lim = float(w.get("speed_limit_rpm", 10000.0)) * RPM
        self.bias = float(fo["wheel_bias_share"]) * lim
        self.bias_gain = float(fo["wheel_bias_gain_1_s"])
        self.jrw_nom = [float(v) for v in w.get("rotor_inertia_kgm2", (3e-6,) * NW)]
        self.nvec = flight.null_vector(self.C)
        self.m_file = list(self.model.m)          # the parameter file's dipole (filter units)
        self.z3 = linalg.zeros(3)
        self.qr, self.wr = linalg.zeros(4), linalg.zeros(3)

    # --- inputs -----------------------------------------------------------------------------------
    def on_packet(self, pid, src, payload):
        """Store one sensor packet for the next cycle. Payloads outside the table's ranges are not used: a
        non-finite wheel speed is no reply; a star-tracker fix is valid only with valid == 1 and a finite unit
        quaternion, a beacon only with valid == 1 and a vector that is not off unit length (else each is
        counted invalid; a NaN in the beacon goes to the STKF, which refuses it: n_refused); a GNSS fix of a
        satellite other than 0 or 1 is refused (n_refused). Of SatB's fixes (``satb_gnss``) the newest 4 of a
        cycle are kept, an older one beyond them is refused (n_refused)."""
        if pid == P_RW_TLM:
            i = src - RW0
            if 0 <= i < NW:
                speed, _ = struct.unpack(_FMT[P_RW_TLM], payload)
                if -_INF < speed < _INF:
                    self.wp[i] = speed * RPM
                    self.rw_got[i] = True
        elif pid == P_ST:
            t_ms, q0, q1, q2, q3, valid = struct.unpack(_FMT[P_ST], payload)
            self.st_got = True
            n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3      # NaN or inf fail the comparison
            self.st_valid = valid == 1 and abs(n2 - 1.0) < UNIT_TOL
            q = self.qst
            q[0], q[1], q[2], q[3] = q0, q1, q2, q3
        elif pid == P_GNSS:
            v = struct.unpack(_FMT[P_GNSS], payload)
            if v[1] > 1:
                self.n_refused += 1
                return
            if v[1] == 0:
                z = self.zg
                self.gnss_got = True
            elif not self.satb:              # SatB's GNSS not used
                return
            else:                            # SatB's: the newest len(zb) of the cycle are kept (in order)
                if self.nb == len(self.zb):       # full: the oldest is dropped (refused), its buffer reused
                    self.zb.append(self.zb.pop(0))
                    self.tb.append(self.tb.pop(0))
                    self.nb -= 1
                    self.n_gnss_b_drop += 1
                    self.n_refused += 1
                z = self.zb[self.nb]
                self.tb[self.nb] = v[0] / 1000.0
                self.nb += 1
            for i in range(3):
                z[i] = v[2 + i] * GNSS_M
                z[3 + i] = v[5 + i] * GNSS_MS
        elif pid == P_MAG:
            t_ms, bx, by, bz, valid = struct.unpack(_FMT[P_MAG], payload)
            self.mag_got = valid == 1
            self.mag[0], self.mag[1], self.mag[2] = bx * MAG_T, by * MAG_T, bz * MAG_T
        elif pid == P_BEACON:
            t_ms, ux, uy, uz, valid = struct.unpack(_FMT[P_BEACON], payload)
            self.bc_got = True
            self.bc_valid = valid == 1 and not abs(ux * ux + uy * uy + uz * uz - 1.0) >= UNIT_TOL   # NaN: STKF
            self.yb[0], self.yb[1], self.yb[2] = ux, uy, uz

    # --- the cycle -------------------------------------------------------------------------------
    @micropython.native
    def _wheels_in(self):
        for i in range(NW):
            if self.rw_got[i]:
                self.rw_miss_run[i] = 0
                if self.failed & (1 << i):
                    self.failed &= ~(1 << i)        # it answers again: back into the allocation
            else:                                   # every wheel answers each tick (commands())
                self.miss_rw[i] += 1
                self.rw_miss_run[i] += 1
                if self.rw_miss_run[i] >= FAIL_AFTER:
                    self.failed |= 1 << i
        if self.failed != self.cof_failed:           # the axes in use and their (C C^T)^-1 cofactors
            for r in range(3):
                for i in range(4):
                    self.Cu[r * 4 + i] = 0.0 if self.failed & (1 << i) else self.C[r * 4 + i]
            try:
                self.cof = control.cct_cofactors(self.Cu)
            except ValueError:              # the axes left do not span: _control allocates nothing
                self.cof = None
            self.cof_failed = self.failed

    @micropython.native
    def _env(self, t, X=None):
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

    def _apkf(self, t):
        """Start the APKF from two valid star-tracker fixes one step (1 s) apart, or run it to t: one step per
        second since its last (a gap in the ticks: the steps before the last without measurements, the wheels
        on their last command, rA propagated for their field and orbit inputs; the momentum input's read-out
        change falls in the last step). A tick whose time did not advance by a step (repeated or earlier)
        leaves it as it is. A fix the APKF refuses (S not positive definite) is stale in the status."""
        st_ok = self.st_got and self.st_valid
        if self.apkf is None:
            if st_ok and self.st_prev_ok and _steps(t, self.t_st_prev) == 1:
                q, p = self.qst, self.qst_prev       # w0 = rotvec(q (x) p^-1) / 1 s
                pc = (-p[0], -p[1], -p[2], p[3])
                dq = linalg.zeros(4)
                control.quat_mul(dq, q, pc)
                s = 2.0 if dq[3] >= 0 else -2.0
                self.apkf = apkf_lean.LeanApkf(self.params, q, (s * dq[0], s * dq[1], s * dq[2]), self.wp,
                                           momentum=self.momentum, friction=self.fric, torque_max=self.torque_max,
                                           **self.mkw)
                self.t_apkf = t
            self.st_prev_ok = st_ok
            if st_ok:
                self.t_st_prev = t
                for i in range(4):
                    self.qst_prev[i] = self.qst[i]
            return
        n = _steps(t, self.t_apkf)
        if n < 1:
            return
        if n > 1:
            xo = self.xo
            xo[0:6] = self.xs[0:6]
            for j in range(n - 1):
                self.apkf.step(self.apkf.wm, None, self._env(self.t_apkf + j + 1, xo), self.u, NOT_HEARD)
                stkf_lean.f(xo, 0, 1.0)
            env = self._env(t, xo)
        else:
            env = self._env(t)
        k = self.apkf.skipped
        if self.fly:
            self._step_flight(env, st_ok)
        else:
            self.apkf.step(self.wp, self.qst if st_ok else None, env, self.u, self.rw_got)
        if self.apkf.skipped != k:
            self.st_valid = False            # refused (S not positive definite): stale, as an invalid fix
        self.t_apkf += n

    def _step_flight(self, env, st_ok):
        """The flight world's APKF step: the magnetorquers' dipole of the step a known input (added to the
        parameter file's residual in the model), the prediction, then the star tracker's fix unless its
        normalised innovation passes ``gate``: then the attitude is reset to it (``flight.reset_attitude``)."""
        a = self.apkf
        m = a.model.m
        for i in range(3):
            m[i] = self.m_file[i] + self.scale * self.m_cmd[i]
        a.step(self.wp, None, env, self.u, self.rw_got)
        if not st_ok:
            return
        apkf_lean.error_vec(self.z3, self.qst, a.x)
        nis = flight.nis3(self.z3, a.P, a.model.R)
        if nis > self.gate:
            flight.reset_attitude(a.x, a.P, self.qst, a.model.R)
            self.n_resets += 1
            self.reset_nis = nis
        elif not apkf_lean.update(a.x, a.P, self.qst, a.model, a.work):
            a.skipped += 1

    @micropython.native
    def _attitude(self):
        """(q, P_att 3 x 3): the APKF's, or the star tracker's before it starts."""
        if self.apkf is not None:
            P = self.apkf.P
            for i in range(3):
                for j in range(3):
                    self.Patt[i * 3 + j] = 4.0 * P[i * 9 + j]
            return self.apkf.x
        for i in range(9):
            self.Patt[i] = 0.0
        for i in range(3):
            self.Patt[i * 4] = (self.sigma_st[i] * RAD_PER_ARCSEC) ** 2
        return self.qst

    def _stkf(self, t, q):
        """Predict to t, then SatA's GNSS, the beacon and SatB's delayed GNSS. A measurement the filter
        refuses (ValueError: NaN, out of order, older than the lag, S not positive definite; the filter is left
        as it was) is counted in ``n_refused`` and the cycle goes on, its sensor stale as for a missed reading
        (SatA's GNSS, the beacon); so is a refused prediction. Before the APKF starts the beacon needs the
        star tracker's valid fix of this cycle."""
        f = self.stkf
        if t > f.now + 1e-9:
            try:
                while t - f.now > stkf_lean.MAX_STEP_S:       # a gap in the ticks: propagate in steps
                    f.predict(f.now + stkf_lean.MAX_STEP_S)
                f.predict(t)
            except ValueError:
                self.n_refused += 1
        if self.gnss_got:
            try:
                f.update_gnss(self.zg, self.Rg, 0, t=t)
            except ValueError:
                self.n_refused += 1
                self.gnss_got = False            # not usable (miss_gnss was counted: it came)
        gated = self.fly and not math.sqrt(self.Patt[0] + self.Patt[4] + self.Patt[8]) <= self.gate_b
        self.beacon_used = False
        if self.bc_got and self.bc_valid and not gated and (self.apkf is not None or (self.st_got and self.st_valid)):
            try:
                f.update_beacon(self.yb, q, self.Patt, self.sigma_b, t=t)
                self.beacon_used = True
            except ValueError:
                self.n_refused += 1
                self.bc_valid = False
        if self.satb:
            for j in range(self.nb):
                try:
                    f.update_gnss(self.zb[j], self.Rg, 1, t=self.tb[j])
                    self.n_gnss_b += 1
                    self.last_ok["gnss_b"] = t
                except ValueError:                   # older than the lag, out of order, repeated, NaN
                    self.n_refused += 1
        self.nb = 0
        f.get(self.xs, self.sig)

    @micropython.native
    def _command_rate(self):
        """q_c (Eq. 6.3-6.4) at the STKF state and w_c by a central difference over +-0.5 s."""
        X, xo = self.xs, self.xo
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
    def _control(self, t):
        u = self.u
        for i in range(4):
            u[i] = 0.0
        if self.apkf is None:
            return u
        if self.fly:
            return self._control_flight(t)
        x = self.apkf.x
        q = x
        hold = t < self.hold_s
        self.acquiring = self.no_command = False
        if not hold:
            try:
                self._command_rate()
            except (ValueError, ZeroDivisionError):    # no command at this geometry (line of sight opposite
                hold = self.no_command = True          # the laser axis, rA = rB): rate damping, mode HOLD
        if not hold:
            if not self.acquired:           # the first acquisition (module docstring, step 4)
                qc = self.qc
                if abs(q[0] * qc[0] + q[1] * qc[1] + q[2] * qc[2] + q[3] * qc[3]) > self.cos_acq:
                    if self.st_got and self.st_valid:
                        self.acquired = True
                    else:
                        hold = self.acquiring = True
        if hold:                              # rate damping: q_c = q, w_c = 0
            for i in range(4):
                self.qc[i] = q[i]
            for i in range(3):
                self.wc[i] = 0.0
        return self._torque(t, x, self.m_ff)

    @micropython.native
    def _torque(self, t, x, m_ff):
        """u (4, N m): the PD on (self.qc, self.wc) with the gyroscopic term and the modelled external torque
        (dipole ``m_ff``, physical) fed forward, saturated, allocated, plus friction compensation."""
        u = self.u
        q, w = x, (x[4], x[5], x[6])
        J, sc, H, cj = self.J, self.scale, self.H, self.cjrw
        w0, w1, w2 = w
        wp0, wp1, wp2, wp3 = self.wp
        for i in range(3):
            s = J[i * 3] * w0 + J[i * 3 + 1] * w1 + J[i * 3 + 2] * w2
            s += cj[i * 4] * wp0
            s += cj[i * 4 + 1] * wp1
            s += cj[i * 4 + 2] * wp2
            s += cj[i * 4 + 3] * wp3
            H[i] = s
        # feed-forward: gravity gradient (J), m x b, tau_d (the APKF's model, Eq. 4.68-4.75)
        control.dcm(self.A, q)
        A, X = self.A, self.xs
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
        control.pd_torque(self.tau, q, w, self.qc, self.wc, self.K, self.D, H, tff)
        if self.cof is not None:             # else the wheels left do not span: no torque to allocate
            control.saturate(self.tau, self.Cu, self.torque_max, self.cof)
            control.wheel_torques(u, self.tau, self.Cu, self.cof)
        c, v, sm = self.fric
        for i in range(4):
            if self.failed & (1 << i):
                u[i] = 0.0
            else:
                wi = self.wp[i]
                u[i] = u[i] + v * wi + c * math.tanh(wi / sm)
        return u

    def _control_flight(self, t):
        """The flight world's control: HOLD (rate
        damping) until ``hold_s``, then SLEW (``flight.Slew`` from the estimate to the command), ACQUIRE (rate
        damping on the estimate until the star tracker answers: the blind slew leaves a rate error of a few
        hundredths of a deg/s, and the command's own turn on top of it could keep the tracker blind), POINT (the command; SLEW again beyond ``reslew``); where the
        command does not exist, rate damping (HOLD). The magnetorquers' dipole: the cross-product law on the
        wheels' momentum with the estimated residual dipole cancelled, the field the model's through the estimate
        (the APKF's own; the magnetometer's packets ride unnamed in the burst, so a lost one could not be asked for
        again and would make a lossy link's run differ from the clean one: its readings are only compared with the
        model, ``mag_miss``); the wheels held off zero in the null space."""
        x = self.apkf.x
        qc, wc = self.qc, self.wc
        hold = t < self.hold_s
        self.no_command = False
        st_ok = self.st_got and self.st_valid
        if not hold:
            try:
                self._command_rate()
            except (ValueError, ZeroDivisionError):
                hold = self.no_command = True
        if not hold and self.fmode == MODE_ACQUIRE and not st_ok:
            hold = True                       # rate damping until the star tracker answers
        if hold:
            for i in range(4):
                qc[i] = x[i]
            for i in range(3):
                wc[i] = 0.0
            if self.fmode not in (MODE_HOLD, MODE_ACQUIRE) and not self.no_command:
                self.fmode = MODE_HOLD
        else:
            err = flight.angle(x, qc)
            if self.fmode == MODE_POINT and err > self.reslew:
                self.fmode = MODE_SLEW
                self.slew.active = False
            elif self.fmode == MODE_ACQUIRE and st_ok:
                self.fmode = MODE_POINT if err <= self.reslew else MODE_SLEW
                self.slew.active = False
            if self.fmode in (MODE_INIT, MODE_HOLD) or (self.fmode == MODE_SLEW and not self.slew.active):
                self.slew.start(x, qc)
                self.fmode = MODE_SLEW
            if self.fmode == MODE_SLEW:
                self.slew.reference(self.qr, self.wr, qc, wc)
                for i in range(4):
                    qc[i] = self.qr[i]
                for i in range(3):
                    wc[i] = self.wr[i]
                if not self.slew.active:
                    self.fmode = MODE_ACQUIRE
        # the magnetorquers: h = C Jrw W (body), b the model field through the estimate (as the APKF's)
        cj, wp = self.cjrw, self.wp
        h = [cj[i * 4] * wp[0] + cj[i * 4 + 1] * wp[1] + cj[i * 4 + 2] * wp[2] + cj[i * 4 + 3] * wp[3]
             for i in range(3)]
        control.dcm(self.A, x)
        field_dipole(self.b, self.xs, t, self.gmst0)
        A = self.A
        b = [A[i * 3] * self.b[0] + A[i * 3 + 1] * self.b[1] + A[i * 3 + 2] * self.b[2] for i in range(3)]
        if self.mag_got:                      # the magnetometer against the model: its largest miss (T)
            d = math.sqrt(sum((self.mag[i] - b[i]) ** 2 for i in range(3)))
            if d > self.mag_miss:
                self.mag_miss = d
        mf = self.m_ff
        self.mtq_sat = flight.unloading(self.m_cmd, b, h, self.k_unload, self.mtq_limit, mf)
        m = self.m_cmd
        u = self._torque(t, x, (mf[0] + m[0], mf[1] + m[1], mf[2] + m[2]))
        if self.cof is not None and not self.failed:
            flight.null_bias(u, self.nvec, wp, self.jrw_nom, self.bias, self.bias_gain)
        return u

    def _only_st(self, t):
        """True when the star tracker is the only sensor silent for ``stale_s`` (in a slew it is blind by design)."""
        keys = ("gnss", "beacon", "gnss_b") if self.satb else ("gnss", "beacon")
        for k in keys:
            if t - self.last_ok[k] >= self.stale_s:
                return False
        return True

    def mtq_payload(self, tick):
        """MTQ_CMD of cycle ``tick``: this cycle's dipole (flight world)."""
        m = self.m_cmd
        return struct.pack(_FMT[P_MTQ_CMD], m[0], m[1], m[2], 1, tick & 0xFF)

    @micropython.native
    def cycle(self, tick, t):
        """One 1 Hz cycle at time t (s) on the readings received since the last one; returns u (4, N m)."""
        self.t = t
        self._wheels_in()
        st_ok = self.st_got and self.st_valid
        if not self.st_got:
            self.miss_st += 1
        elif not self.st_valid:
            self.n_st_invalid += 1
        if not self.gnss_got:
            self.miss_gnss += 1
        if not self.bc_got:
            self.miss_beacon += 1
        elif not self.bc_valid:
            self.n_beacon_invalid += 1
        self._apkf(t)
        st_ok = self.st_got and self.st_valid
        q = self._attitude()
        self._stkf(t, q)
        if st_ok:
            self.last_ok["st"] = t
        if self.gnss_got:
            self.last_ok["gnss"] = t
            self.gnss_t = t
        if self.bc_got and self.bc_valid:
            self.last_ok["beacon"] = t
        u = self._control(t)
        # stale bits and mode
        stale = 0
        if not st_ok:
            stale |= 1 << STALE_STARTRACKER
        if not self.gnss_got:
            stale |= 1 << STALE_GNSS_A
        if self.satb and t - self.last_ok["gnss_b"] >= self.stale_s:
            stale |= 1 << STALE_GNSS_B
        if not (self.bc_got and self.bc_valid):
            stale |= 1 << STALE_BEACON
        for i in range(NW):
            if not self.rw_got[i]:
                stale |= 1 << (STALE_RW0 + i)
        self.stale = stale
        long_gap = False
        keys = ("st", "gnss", "beacon", "gnss_b") if self.satb else ("st", "gnss", "beacon")
        for k in keys:
            if t - self.last_ok[k] >= self.stale_s:
                long_gap = True
        if st_ok:
            self.t_st_ok = t
        if self.apkf is None:
            self.mode = MODE_INIT
        elif self.failed or (long_gap and not (self.fly and self.fmode in (MODE_SLEW, MODE_ACQUIRE) and self._only_st(t))):
            self.mode = MODE_DEGRADED
        elif self.fly:
            self.mode = MODE_HOLD if self.no_command else self.fmode
        elif t < self.hold_s or self.acquiring or self.no_command:
            self.mode = MODE_HOLD
        else:
            self.mode = MODE_POINT
        self.clear_inputs()
        return u

    def clear_inputs(self):
        """Forget the readings received for the next cycle (done after each cycle, and when the spacecraft
        gives up a cycle whose burst was incomplete)."""
        for i in range(NW):
            self.rw_got[i] = False
        self.st_got = self.gnss_got = self.bc_got = self.mag_got = False
        self.nb = 0

    def status_payload(self, tick, cycle_us=0, n_rx_drop=0):
        x = self.apkf.x if self.apkf is not None else self.qst
        w = (x[4], x[5], x[6]) if self.apkf is not None else (0.0, 0.0, 0.0)
        X = self.xs
        sig = 0.0
        if self.apkf is not None:
            P = self.apkf.P
            sig = math.sqrt(max(0.0, 4.0 * (P[0] + P[10] + P[20])))
        age = NEVER if self.gnss_t < 0 else min(NEVER - 1, max(0, int(self.t - self.gnss_t)))
        m = self.miss_rw
        return struct.pack(_FMT[P_STATUS], tick & 0xFFFFFFFF, self.mode, self.stale, self.failed,
                           m[0] & 0xFFFF, m[1] & 0xFFFF, m[2] & 0xFFFF, m[3] & 0xFFFF,
                           self.miss_st & 0xFFFF, self.miss_gnss & 0xFFFF, self.miss_beacon & 0xFFFF,
                           self.n_st_invalid & 0xFFFF, self.n_beacon_invalid & 0xFFFF, self.n_gnss_b & 0xFFFF,
                           self.n_refused & 0xFFFF,
                           n_rx_drop & 0xFFFF, age, x[0], x[1], x[2], x[3], w[0], w[1], w[2],
                           X[0], X[1], X[2], X[6], X[7], X[8], sig, cycle_us & 0xFFFFFFFF)

    def commands(self, u, tick=0):
        """[(dst, RW_CMD payload)] of cycle ``tick``: a torque to each wheel in use, coast (enable 0) to a failed
        one. Every wheel is expected to answer by the next tick (a failed one too: it may come back)."""
        out = []
        for i in range(NW):
            en = 0 if self.failed & (1 << i) else 1
            out.append((RW0 + i, struct.pack(_FMT[P_RW_CMD], u[i] if en else 0.0, en, tick & 0xFF)))
        return out


def _drops(port):
    """Frames and payloads the CAN port dropped (``protocol.can.rx_drops``)."""
    return canmap.rx_drops(port.counters())


_B_GNSS_A = 1 << STALE_GNSS_A
_B_GNSS_B = 1 << STALE_GNSS_B


def burst_bit(pid, src, payload):
    """The ADCS_STALE bit naming a burst packet (ADCS_TICK.burst), 0 for a packet that is not one."""
    if pid == P_RW_TLM:
        i = src - RW0
        return 1 << (STALE_RW0 + i) if 0 <= i < NW else 0
    if pid == P_ST:
        return 1 << STALE_STARTRACKER
    if pid == P_GNSS:
        sat = payload[4]                     # after t_ms (I)
        return _B_GNSS_A if sat == 0 else (_B_GNSS_B if sat == 1 else 0)
    if pid == P_BEACON:
        return 1 << STALE_BEACON
    return 0


class Lockstep:
    """The lockstep with the emulated spacecraft, exactly once per cycle over a lossy link.

    ``ADCS_TICK(k, burst, n_gnss_b)`` opens cycle k and names the sensor packets that follow it; the packets are
    given to the app while a cycle is open (a copy arriving while none is, a late resend of an earlier burst, is
    dropped: ``n_late``; a second copy of one already in is dropped too: ``n_dup``), and the cycle runs once,
    when every packet named is in. A resent ``ADCS_TICK(k)``: answered from the cache when k has run (RW_CMD x4
    and ADCS_STATUS again, no second cycle), with ``ADCS_MISSING(k, bits)`` while its burst is incomplete. A
    tick older than the last run is dropped. ``step(tick, t)`` runs the cycle and returns the replies
    [(pid, dst, payload)]; ``host`` is the node whose ADCS_TICK opened the cycle (the replies go to it).
    """

    def __init__(self, app, step):
        self.app = app
        self.step = step
        self.last = -1
        self.replies = ()
        self.open_k = -1
        self.t_ms = 0
        self.want = self.have = self.nb_want = 0
        self.tb = []                         # SatB fix times (ms) taken in the open cycle
        self.n_late = self.n_dup = self.n_missing = self.n_cached = 0
        self.host = 0

    def _ready(self):
        return self.want & ~_B_GNSS_B & ~self.have == 0 and len(self.tb) >= self.nb_want

    def _run(self):
        k = self.open_k
        self.open_k = -1
        self.replies = self.step(k, self.t_ms / 1000.0)
        self.last = k
        return self.replies

    def on_tick(self, tick, t_ms, burst, n_gnss_b, src=0):
        """Replies [(pid, dst, payload)] to an ADCS_TICK from node ``src``."""
        self.host = src
        if tick == self.last:
            self.n_cached += 1
            return self.replies
        if tick < self.last:
            return ()
        if tick != self.open_k:
            if self.open_k >= 0:             # a cycle given up by the spacecraft: its partial inputs go
                self.app.clear_inputs()
            self.open_k, self.t_ms, self.want, self.nb_want, self.have = tick, t_ms, burst, n_gnss_b, 0
            self.tb = []
        elif not self._ready():
            self.n_missing += 1
            miss = self.want & ~self.have & ~_B_GNSS_B
            if len(self.tb) < self.nb_want:
                miss |= _B_GNSS_B
            return ((P_MISSING, src, struct.pack(_FMT[P_MISSING], tick & 0xFFFFFFFF, miss)),)
        return self._run() if self._ready() else ()

    def on_packet(self, pid, src, payload):
        """Replies to a sensor packet: the cycle's, when it completes the open burst."""
        if self.open_k < 0:
            self.n_late += 1
            return ()
        bit = burst_bit(pid, src, payload)
        if bit == _B_GNSS_B:
            t_ms = struct.unpack_from("<I", payload, 0)[0]
            if t_ms in self.tb:
                self.n_dup += 1
                return ()
            self.tb.append(t_ms)
        elif bit & self.have:
            self.n_dup += 1
            return ()
        self.have |= bit
        self.app.on_packet(pid, src, payload)
        return self._run() if self._ready() else ()


def cycle_replies(app, cmds, tick, host, cycle_us=0, n_rx_drop=0):
    """A cycle's replies [(pid, dst, payload)]: the RW_CMDs ``cmds`` (``App.commands``), in the flight world the
    magnetorquers' MTQ_CMD, then the ADCS_STATUS to ``host`` that closes the cycle."""
    out = [(P_RW_CMD, dst_w, pl) for dst_w, pl in cmds]
    if app.fly:
        out.append((P_MTQ_CMD, MTQ, app.mtq_payload(tick)))
    out.append((P_STATUS, host, app.status_payload(tick, cycle_us, n_rx_drop)))
    return out


class InProcess:
    """The app on this host, behind the calls a CAN link takes (``send_raw``, ``recv``, ``counters``, ``close``):
    the spacecraft's packets go to ``Lockstep`` as the bytes a bus would carry, and the replies come back the
    same way, so a session flies the very code and bytes ``serve`` flies, without a process or a wire."""

    def __init__(self, app, node, probe=None):
        self.app = app
        self.node = node
        self.probe = probe                   # probe(tick, t, u): called after each cycle, before its replies
        self.closed = False
        self.inbox = []
        self.ls = Lockstep(app, self._step)
        app.lockstep = self.ls

    def _step(self, tick, t):
        u = self.app.cycle(tick, t)
        if self.probe is not None:
            self.probe(tick, t, u)
        return cycle_replies(self.app, self.app.commands(u, tick), tick, self.ls.host)

    def send_raw(self, pid, src, dst, payload):
        if dst != self.node:
            return
        if pid == P_TICK:
            tick, t_ms, burst, n_gnss_b = struct.unpack(_FMT[P_TICK], payload)
            out = self.ls.on_tick(tick, t_ms, burst, n_gnss_b, src)
        else:
            out = self.ls.on_packet(pid, src, payload)
        for rpid, rdst, rpl in out:
            self.inbox.append((rpid, self.node, rdst, 0, rpl))

    def recv(self, timeout=0.0):
        out, self.inbox = self.inbox, []
        return out

    def counters(self):
        return {}

    def close(self):
        self.closed = True


def serve(app, port, ticks_us=None, poll_ms=1000, heap=None):
    """The ADCS on a CAN port until the host leaves: HELLO once the channel is open, then the lockstep
    (``Lockstep``): per cycle, RW_CMD x4 and ADCS_STATUS to the tick's sender. ``heap``: callable(tick, bytes)
    measuring the cycle's heap (gc.mem_alloc deltas, under MicroPython)."""
    me = port.node
    hello = core.encode_payload(core.PACKET_ID["HELLO"], node=me, fw_major=1, fw_minor=0)
    ad = getattr(port, "ad", None)
    while ad is not None and not ad.is_open and not port.closed:
        port.recv_ms(100)             # the host opens the channel (O) before any frame can go out
    port.send_raw(core.PACKET_ID["HELLO"], me, 0xFF, hello)
    mem = None
    if heap is not None:
        import gc
        mem = gc
    def step(tick, t):
        t0 = ticks_us() if ticks_us else 0
        if mem is not None:
            mem.collect()
            mem.disable()
            m0 = mem.mem_alloc()
        u = app.cycle(tick, t)
        cmds = app.commands(u, tick)
        if mem is not None:
            heap(tick, mem.mem_alloc() - m0)
            mem.enable()
        dt = ticks_diff(ticks_us(), t0) if ticks_us else 0
        return cycle_replies(app, cmds, tick, ls.host, dt, _drops(port))

    ls = Lockstep(app, step)
    app.lockstep = ls
    while not port.closed:
        for pid, src, dst, seq, payload in port.recv_ms(poll_ms):
            if pid == P_TICK:
                tick, t_ms, burst, n_gnss_b = struct.unpack(_FMT[P_TICK], payload)
                replies = ls.on_tick(tick, t_ms, burst, n_gnss_b, src)
            else:
                replies = ls.on_packet(pid, src, payload)
            for rpid, rdst, rpl in replies:
                port.send_raw(rpid, me, rdst, rpl)
    port.close()
