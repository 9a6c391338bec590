"""The ADCS app's sensor intake (MicroPython): the readings of one cycle, decoded off the bus into preallocated
buffers, and the checks that decide which of them are usable. A reading outside the packet table's ranges is not
used; what is refused is counted in the app's ``Health``."""

import struct

from firmware.adcs.apkf_lean_model import NW, RPM   # the wheels the lean ADCS flies; rad/s per rpm
from firmware.adcs.linalg import micropython, zeros     # micropython: the module, or CPython's no-op stand-in
from firmware.adcs.stkf_lean import zeros_d
from protocol import core
from protocol.consts import (FMT_BEACON, FMT_GNSS, FMT_MAGNETOMETER, FMT_MTQ_TLM, FMT_RW_TLM, FMT_STARTRACKER,
                             NODE_RW0, P_BEACON, P_GNSS, P_MAGNETOMETER, P_MTQ_TLM, P_RW_TLM, P_STARTRACKER)

UNIT_TOL = 1e-3        # | |v|^2 - 1 | of a unit vector or quaternion off the bus (float32 rounding: ~1e-7)
_INF = float("inf")

MAG_T = core.field_scales(P_MAGNETOMETER)["bx"] * 1e-9      # tesla per MAGNETOMETER count
_SCALE = core.field_scales(P_GNSS)
GNSS_M, GNSS_MS = _SCALE["x"], _SCALE["vx"]       # GNSS position (m) and velocity (m/s) per count, from the table
SATB_FIXES = 4                                    # SatB's fixes of one cycle kept (the newest)


class Intake:
    """One cycle's readings: the wheels' speeds ``wp`` (rad/s) and which answered (``rw_got``), the star tracker's
    quaternion ``qst`` (``st_got``, ``st_valid``), SatA's GNSS ``zg`` (m, m/s; ``gnss_got``), the beacon's unit
    vector ``yb`` (``bc_got``, ``bc_valid``), SatB's relayed fixes ``zb[:nb]`` at their times ``tb`` (s), the
    magnetometer's field ``mag`` (T, ``mag_got``), the rods whose driver did not answer the last MTQ_CMD
    (``mtq_silent`` bits, in its MTQ_TLM: ``mtq_got``). The estimators clear a flag when they refuse its reading."""

    def __init__(self, satb, health):
        self.satb = satb                    # SatB's GNSS is used
        self.health = health
        self.wp = zeros(NW)
        self.rw_got = [False] * NW
        self.qst = zeros(4)
        self.st_got = self.st_valid = False
        self.zg = zeros_d(6)
        self.gnss_got = False
        self.yb = zeros(3)
        self.bc_got = self.bc_valid = False
        self.zb = [zeros_d(6) for _ in range(SATB_FIXES)]
        self.tb = [0.0] * SATB_FIXES
        self.nb = 0
        self.mag = zeros(3)
        self.mag_got = False
        self.mtq_got = False
        self.mtq_silent = 0

    @micropython.native
    def st_ok(self):
        """A valid star-tracker fix this cycle."""
        return self.st_got and self.st_valid

    def on_packet(self, pid, src, payload):
        """Store one sensor packet for the next cycle. A non-finite wheel speed is no reply; a star-tracker fix is
        valid only with valid == 1 and a finite unit quaternion, a beacon only with valid == 1 and a vector that is
        not off unit length (else each is counted invalid; a NaN in the beacon goes to the STKF, which refuses it:
        n_refused); a GNSS fix of a satellite other than 0 or 1 is refused (n_refused). Of SatB's fixes
        (``satb``) the newest 4 of a cycle are kept, an older one beyond them is refused (n_refused)."""
        if pid == P_RW_TLM:
            i = src - NODE_RW0
            if 0 <= i < NW:
                speed, _ = struct.unpack(FMT_RW_TLM, payload)
                if -_INF < speed < _INF:
                    self.wp[i] = speed * RPM
                    self.rw_got[i] = True
        elif pid == P_STARTRACKER:
            t_ms, q0, q1, q2, q3, valid = struct.unpack(FMT_STARTRACKER, payload)
            self.st_got = True
            n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3      # NaN or inf fail the comparison
            self.st_valid = valid == 1 and abs(n2 - 1.0) < UNIT_TOL
            q = self.qst
            q[0], q[1], q[2], q[3] = q0, q1, q2, q3
        elif pid == P_GNSS:
            self._gnss(struct.unpack(FMT_GNSS, payload))
        elif pid == P_MAGNETOMETER:
            t_ms, bx, by, bz, valid = struct.unpack(FMT_MAGNETOMETER, payload)
            self.mag_got = valid == 1
            self.mag[0], self.mag[1], self.mag[2] = bx * MAG_T, by * MAG_T, bz * MAG_T
        elif pid == P_MTQ_TLM:
            self.mtq_silent = struct.unpack(FMT_MTQ_TLM, payload)[4]
            self.mtq_got = True
        elif pid == P_BEACON:
            t_ms, ux, uy, uz, valid = struct.unpack(FMT_BEACON, payload)
            self.bc_got = True
            self.bc_valid = valid == 1 and not abs(ux * ux + uy * uy + uz * uz - 1.0) >= UNIT_TOL   # NaN: STKF
            self.yb[0], self.yb[1], self.yb[2] = ux, uy, uz

    def _gnss(self, v):
        hl = self.health
        if v[1] > 1:
            hl.n_refused += 1
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
                hl.n_gnss_b_drop += 1
                hl.n_refused += 1
            z = self.zb[self.nb]
            self.tb[self.nb] = v[0] / 1000.0
            self.nb += 1
        for i in range(3):
            z[i] = v[2 + i] * GNSS_M
            z[3 + i] = v[5 + i] * GNSS_MS

    @micropython.native
    def clear(self):
        """Forget the readings (after each cycle, and when the spacecraft gives up a cycle whose burst was
        incomplete)."""
        for i in range(NW):
            self.rw_got[i] = False
        self.st_got = self.gnss_got = self.bc_got = self.mag_got = self.mtq_got = False
        self.nb = 0
