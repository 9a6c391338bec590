"""Device side of the spacecraft on the protocol: reaction wheels RW0..RW3 and the star tracker.

``SpacecraftDevices.handle(pid, src, dst, payload)`` takes one received packet and returns the replies as
``[(pid, src, dst, payload), ...]``; a link (or a test) carries them. RW_CMD to RW<i> sets wheel i's torque and
enable and is answered by RW_TLM (noisy speed read-out, Eq. 4.57, and the torque the driver applies after its
limits). ``startracker(dst)`` makes a STARTRACKER packet (pid, src, dst, payload) from the true attitude now
(Eq. 4.63-4.66).
"""

import numpy as np

from protocol import core
from emulator.spacecraft.dynamics import quat_mul
from emulator.spacecraft.wheels import N_WHEELS

ARCSEC = np.pi / (180.0 * 3600.0)
RW_CMD = core.PACKET_ID["RW_CMD"]
RW_TLM = core.PACKET_ID["RW_TLM"]
STARTRACKER = core.PACKET_ID["STARTRACKER"]
NACK = core.PACKET_ID["NACK"]
RW_NODES = tuple(core.NODE["RW%d" % i] for i in range(N_WHEELS))


class StarTracker:
    """Star tracker with the sensor frame on the body axes (Eq. 4.63-4.66).

    q_meas = q_n (x) q, q_n = normalise([v/2, 1]), v ~ N(0, diag(sigma^2)); no output (valid = 0) when the body
    rate is at or above ``rate_max_dps`` (Sec. 4.8: 20, 20, 60 arcsec 1 sigma; 0.1 deg/s).
    """

    def __init__(self, rng, sigma_arcsec=(20.0, 20.0, 60.0), rate_max_dps=0.1):
        self.rng = rng
        self.sigma = np.array(sigma_arcsec, dtype=float) * ARCSEC
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


class SpacecraftDevices:
    """RW0..RW3 and STARTRACKER served from one ``Spacecraft``; counters of what was refused."""

    def __init__(self, spacecraft, startracker=None):
        self.sc = spacecraft
        self.st = startracker if startracker is not None else StarTracker(spacecraft.wheels.rng)
        self.n_nack = 0
        self.n_cmd = 0

    def _nack(self, pid, me, src, seq, code):
        self.n_nack += 1
        return [(NACK, me, src, core.encode_payload(NACK, ref_id=pid, ref_seq=(seq or 0) & 0xFF,
                                                       code=core.ERROR[code]))]

    def handle(self, pid, src, dst, payload, seq=0):
        """Replies to one packet; [] if it is not addressed to a wheel. ``seq`` (None on CAN) goes into NACKs."""
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
