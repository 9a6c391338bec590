"""Device side of the spacecraft on the protocol: reaction wheels RW0..RW3, the star tracker, and (when the
spacecraft file has them) the magnetorquers and the magnetometer.

``SpacecraftDevices.handle(pid, src, dst, payload)`` takes one received packet and returns the replies as
``[(pid, src, dst, payload), ...]``; a link (or a test) carries them. RW_CMD to RW<i> sets wheel i's torque and
enable and is answered by RW_TLM (noisy speed read-out, Eq. 4.57, and the torque the driver applies after its
limits). ``startracker(dst)`` makes a STARTRACKER packet (pid, src, dst, payload) from the true attitude now
(Eq. 4.63-4.66). MTQ_CMD to MTQ sets the rods' dipole (``Magnetorquers``: least-squares share per rod, clipped
at the rod's limit; the spacecraft's dipole becomes its residual dipole plus the rods', so the field torque
m x b follows) and is answered by MTQ_TLM (a rod whose driver is dead, ``rods_dead``: no dipole, named in its
``silent`` bits); ``magnetometer(dst)`` makes a MAGNETOMETER packet from the true field
in the body frame (``Magnetometer``: constant bias plus white noise). Neither is in the thesis: they are the
spacecraft file's ``magnetorquers`` and ``magnetometer`` blocks (``from_spacecraft``, None for a null block).
"""

import numpy as np

from protocol import core
from emulator.spacecraft.dynamics import dcm, quat_mul
from emulator.spacecraft.wheels import N_WHEELS
from protocol.units import RAD_PER_ARCSEC

RW_CMD = core.PACKET_ID["RW_CMD"]
RW_TLM = core.PACKET_ID["RW_TLM"]
STARTRACKER = core.PACKET_ID["STARTRACKER"]
NACK = core.PACKET_ID["NACK"]
MTQ_CMD = core.PACKET_ID["MTQ_CMD"]
MTQ_TLM = core.PACKET_ID["MTQ_TLM"]
MAGNETOMETER = core.PACKET_ID["MAGNETOMETER"]
RW_NODES = tuple(core.NODE["RW%d" % i] for i in range(N_WHEELS))
MTQ_NODE = core.NODE["MTQ"]
MAG_NODE = core.NODE["MAGNETOMETER"]
_MAG_FIELD = core.packet_def(MAGNETOMETER).fields[1]          # bx: bz and by share its scale and range
MAG_COUNT_NT = _MAG_FIELD[3]                                   # nT per count on the wire
MAG_FULL_SCALE_T = _MAG_FIELD[5] * MAG_COUNT_NT * 1e-9         # the packet's range, the sensor's full scale


class StarTracker:
    """Star tracker with the sensor frame on the body axes (Eq. 4.63-4.66).

    q_meas = q_n (x) q, q_n = normalise([v/2, 1]), v ~ N(0, diag(sigma^2)); no output (valid = 0) when the body
    rate is at or above ``rate_max_dps`` (Sec. 4.8: 20, 20, 60 arcsec 1 sigma; 0.1 deg/s).
    """

    def __init__(self, rng, sigma_arcsec=(20.0, 20.0, 60.0), rate_max_dps=0.1):
        self.rng = rng
        self.sigma = np.array(sigma_arcsec, dtype=float) * RAD_PER_ARCSEC
        if self.sigma.shape != (3,) or not np.all(np.isfinite(self.sigma)) or np.any(self.sigma < 0):
            raise ValueError("sigma_arcsec must be 3 finite numbers >= 0, got %r" % (sigma_arcsec,))
        if not (np.isfinite(rate_max_dps) and rate_max_dps >= 0):
            raise ValueError("rate_max_dps must be a finite number >= 0 deg/s, got %r" % (rate_max_dps,))
        self.rate_max = np.radians(rate_max_dps)

    def measure(self, q, omega):
        """(q_meas with q4 >= 0, valid). The noise is drawn even when invalid, so streams stay aligned."""
        v = self.sigma * self.rng.standard_normal(3)
        qn = np.array([0.5 * v[0], 0.5 * v[1], 0.5 * v[2], 1.0])
        qm = quat_mul(qn / np.linalg.norm(qn), q)
        if qm[3] < 0:
            qm = -qm
        return qm, bool(np.linalg.norm(omega) < self.rate_max)


class Magnetometer:
    """Three-axis magnetometer with its axes on the body axes: b_meas = b + bias + v, the bias drawn once per axis
    from N(0, bias_nt^2) at construction, v ~ N(0, noise_nt^2) per axis and sample. Readings beyond the
    MAGNETOMETER packet's full scale (+-100000 nT on an axis) are not valid. ``rate_hz`` is the file's output
    rate (the lockstep ADCS takes one sample per 1 s cycle)."""

    def __init__(self, rng, noise_nt, bias_nt, rate_hz=None):
        for name, v in (("noise_nt", noise_nt), ("bias_nt", bias_nt)):
            if isinstance(v, bool) or not (np.isfinite(v) and v >= 0):
                raise ValueError("%s must be a finite number >= 0 nT, got %r" % (name, v))
        self.rng = rng
        self.noise = float(noise_nt) * 1e-9
        self.bias = float(bias_nt) * 1e-9 * rng.standard_normal(3)       # tesla, constant
        self.rate_hz = rate_hz

    @classmethod
    def from_spacecraft(cls, d, rng):
        """The ``magnetometer`` block of a checked spacecraft file, or None when it is null."""
        m = d.get("magnetometer")
        if m is None:
            return None
        return cls(rng, m["noise_nt"], m["bias_nt"], m.get("rate_hz"))

    def measure(self, b_body_t):
        """(b_meas (3) T, valid) of the true field ``b_body_t`` (T, body frame). The noise is drawn even when
        the reading is not valid, so streams stay aligned."""
        b = np.asarray(b_body_t, dtype=float)
        bm = b + self.bias + self.noise * self.rng.standard_normal(3)
        return bm, bool(np.all(np.isfinite(bm)) and np.all(np.abs(bm) <= MAG_FULL_SCALE_T))


class Magnetorquers:
    """Three magnetorquer rods along ``axes`` (body frame, normalised here; spanning the body axes, as the
    spacecraft file requires), each limited to +-``dipole_limit_am2``. ``command(m)`` gives each rod its share
    of the body dipole m by least squares (s = argmin |A^T s - m|, A's rows the rod axes: exact for three
    spanning rods), clips each share at the limit and returns the body dipole the rods apply, A^T s, with
    which rods were clipped; ``applied`` holds it (zero before the first command)."""

    def __init__(self, axes, dipole_limit_am2):
        a = np.array(axes, dtype=float)
        if a.shape != (3, 3) or not np.all(np.isfinite(a)):             # MTQ_TLM.saturated names three rods
            raise ValueError("axes must be three rods' axes, 3-vectors of finite numbers, got %r" % (axes,))
        n = np.linalg.norm(a, axis=1)
        if np.any(n == 0):
            raise ValueError("a rod axis must not be zero, got %r" % (axes,))
        if isinstance(dipole_limit_am2, bool) or not (np.isfinite(dipole_limit_am2) and dipole_limit_am2 > 0):
            raise ValueError("dipole_limit_am2 must be a finite number > 0, got %r" % (dipole_limit_am2,))
        self.axes = a / n[:, None]
        self._lsq = np.linalg.pinv(self.axes.T)   # the least-squares shares of a body dipole
        self.limit = float(dipole_limit_am2)
        self.share = np.zeros(3)                  # each rod's dipole (A m^2, along its axis)
        self.applied = np.zeros(3)
        self.saturated = np.zeros(3, dtype=bool)
        self.dead = 0                             # bit i: rod i's driver is dead (no dipole, no answer)

    @classmethod
    def from_spacecraft(cls, d, rng=None):
        """The ``magnetorquers`` block of a checked spacecraft file, or None when it is null (``rng`` unused:
        the rods are noise free; the argument keeps the devices' constructors alike)."""
        m = d.get("magnetorquers")
        if m is None:
            return None
        return cls(m["axes"], m["dipole_limit_am2"])

    def command(self, m_body):
        """(applied body dipole (3) A m^2, saturated (bool per rod)) for the body dipole ``m_body``."""
        m = np.asarray(m_body, dtype=float)
        if m.shape != (3,) or not np.all(np.isfinite(m)):
            raise ValueError("m_body must be 3 finite numbers (A m^2), got %r" % (m_body,))
        s = self.shares(m)
        self.saturated = np.abs(s) > self.limit
        self.share = np.clip(s, -self.limit, self.limit)
        self.set_dead(self.dead)
        return self.applied.copy(), self.saturated.copy()

    def shares(self, m_body):
        """Each rod's least-squares share (A m^2, unclipped) of the body dipole ``m_body``."""
        return self._lsq @ np.asarray(m_body, dtype=float)

    def set_dead(self, mask):
        """Rods whose driver is dead (bit i: rod i) give no dipole from now on; ``applied`` is the others'."""
        self.dead = int(mask)
        live = np.array([0.0 if mask >> i & 1 else 1.0 for i in range(3)])
        self.applied = self.axes.T @ (self.share * live)

    def saturated_bits(self):
        """The MTQ_TLM.saturated bit field of the last command (bit i: rod i clipped)."""
        return sum(1 << i for i in range(len(self.saturated)) if self.saturated[i])


def field_body(sc):
    """The true field (T, body frame) at the spacecraft now: its field model at its orbit position, turned by
    its attitude, as its magnetic torque sees it; zero without an orbit or a field (no magnetic torque either)."""
    if sc.orbit is None or sc.field is None:
        return np.zeros(3)
    return dcm(sc.q) @ np.asarray(sc.field.field(sc.orbit.position(sc.t), sc.t), dtype=float)


def magnetometer_payload(t_ms, b_t, valid):
    """MAGNETOMETER payload: the field ``b_t`` (T) in counts of the table's scale (zeros when not valid)."""
    if valid:
        raw = [int(round(float(b) * 1e9 / MAG_COUNT_NT)) for b in b_t]
    else:
        raw = [0, 0, 0]
    return core.encode_payload(MAGNETOMETER, t_ms=int(t_ms) & 0xFFFFFFFF, bx=raw[0], by=raw[1], bz=raw[2],
                               valid=int(bool(valid)))


class SpacecraftDevices:
    """RW0..RW3 and STARTRACKER served from one ``Spacecraft``, and MTQ and MAGNETOMETER when given their
    devices (``Magnetorquers``, ``Magnetometer``); counters of what was refused. The spacecraft's dipole when
    this is built is its residual dipole (``residual_dipole``): after each MTQ_CMD its dipole is that plus the
    rods' (keep ``residual_dipole`` in step if you change the residual)."""

    def __init__(self, spacecraft, startracker=None, magnetometer=None, magnetorquers=None):
        self.sc = spacecraft
        self.st = startracker if startracker is not None else StarTracker(spacecraft.wheels.rng)
        self.mag = magnetometer
        self.mtq = magnetorquers
        d = spacecraft.dipole
        self.residual_dipole = np.zeros(3) if d is None else d
        self.n_nack = 0
        self.n_cmd = 0
        self.n_mtq_cmd = 0

    def _nack(self, pid, me, src, seq, code):
        self.n_nack += 1
        return [(NACK, me, src, core.encode_payload(NACK, ref_id=pid, ref_seq=(seq or 0) & 0xFF,
                                                       code=core.ERROR[code]))]

    def handle(self, pid, src, dst, payload, seq=0):
        """Replies to one packet; [] if it is not addressed to a wheel or to the magnetorquers (when there are
        some). ``seq`` (None on CAN) goes into NACKs."""
        if dst == MTQ_NODE and self.mtq is not None:
            return self._mtq(pid, src, dst, payload, seq)
        if dst not in RW_NODES:
            return []
        i = RW_NODES.index(dst)
        if pid != RW_CMD:
            return self._nack(pid, dst, src, seq, "UNKNOWN_PACKET")
        if len(payload) != core.PACKET[pid].size:
            return self._nack(pid, dst, src, seq, "BAD_VALUE")
        d = core.payload_dict(pid, payload)
        if not np.isfinite(d["torque"]) or d["enable"] > 1:
            return self._nack(pid, dst, src, seq, "BAD_VALUE")
        w = self.sc.wheels
        w.command(i, d["torque"], d["enable"])
        self.n_cmd += 1
        tq = w.limit(self.sc.omega_rw_rel, self.sc.dt)[0][i]
        speed_rpm = w.read_speed_rpm(self.sc.omega_rw_rel)[i]
        return [(RW_TLM, dst, src, core.encode_payload(RW_TLM, speed=float(speed_rpm), torque=float(tq)))]

    def startracker(self, dst=core.NODE["ADCS"]):
        """One STARTRACKER packet (pid, src, dst, payload) from the current true attitude and rate."""
        qm, valid = self.st.measure(self.sc.q, self.sc.omega)
        if not valid:
            qm = np.array([0.0, 0.0, 0.0, 1.0])
        t_ms = int(round(self.sc.t * 1000.0)) & 0xFFFFFFFF
        payload = core.encode_payload(STARTRACKER, t_ms=t_ms, q0=float(qm[0]), q1=float(qm[1]),
                                      q2=float(qm[2]), q3=float(qm[3]), valid=int(valid))
        return (STARTRACKER, core.NODE["STARTRACKER"], dst, payload)

    def _mtq(self, pid, src, dst, payload, seq):
        """MTQ_CMD: the rods take the command (enable 0: no dipole), the spacecraft's dipole becomes the residual
        plus the rods'; MTQ_TLM with the applied dipole, the clipped rods and those whose driver is dead
        (``silent``). NACK BAD_VALUE for a wrong length, a non-finite dipole or an enable other than 0/1 (the rods
        keep their last command)."""
        if pid != MTQ_CMD:
            return self._nack(pid, dst, src, seq, "UNKNOWN_PACKET")
        if len(payload) != core.PACKET[pid].size:
            return self._nack(pid, dst, src, seq, "BAD_VALUE")
        d = core.payload_dict(pid, payload)
        m = np.array([d["mx"], d["my"], d["mz"]])
        if not np.all(np.isfinite(m)) or d["enable"] > 1:
            return self._nack(pid, dst, src, seq, "BAD_VALUE")
        applied, _ = self.mtq.command(m if d["enable"] else np.zeros(3))
        self.sc.dipole = self.residual_dipole + applied
        self.n_mtq_cmd += 1
        return [(MTQ_TLM, dst, src, core.encode_payload(MTQ_TLM, mx=float(applied[0]), my=float(applied[1]),
                                                          mz=float(applied[2]), saturated=self.mtq.saturated_bits(),
                                                          silent=self.mtq.dead))]

    def rods_dead(self, mask):
        """The rods whose driver is dead (bit i: rod i; ``Magnetorquers.set_dead``), the spacecraft's dipole
        following at once; MTQ_TLM names them in ``silent``."""
        if self.mtq is not None and mask != self.mtq.dead:
            self.mtq.set_dead(mask)
            self.sc.dipole = self.residual_dipole + self.mtq.applied

    def magnetometer(self, dst=core.NODE["ADCS"], t_ms=None):
        """One MAGNETOMETER packet (pid, src, dst, payload) from the true field at the spacecraft now (``t_ms``
        default: its time); None when there is no magnetometer."""
        if self.mag is None:
            return None
        bm, valid = self.mag.measure(field_body(self.sc))
        if t_ms is None:
            t_ms = int(round(self.sc.t * 1000.0))
        return (MAGNETOMETER, MAG_NODE, dst, magnetometer_payload(t_ms, bm, valid))
