"""The ADCS app's health (MicroPython): what each sensor missed, sent invalid or had refused, the wheels' and the
magnetic devices' failure detection and the sensors' staleness, as ADCS_STATUS reports them.

A wheel whose RW_TLM is missed ``FAIL_AFTER`` (3) cycles in a row is declared failed (its bit in ``failed``); it
is back as soon as it answers. The same for the magnetic devices (``magnetic``, ADCS_STATUS.magnetic_failed): a
rod whose driver MTQ_TLM names silent 3 times in a row leaves the unloading (bits ``RODS``) until it answers (a
lost MTQ_TLM counts neither way: it rides unnamed in the burst, so a lossy link would otherwise fail the rods); the
magnetometer, once heard, without a valid reading 3 cycles in a row is silent (bit ``MAG_SILENT``) until one
comes (one that never answered is not flagged: the spacecraft may have none). A sensor is stale in a cycle it
gave nothing usable (the ``STALE_*`` bits of the packet table); it has been silent for long when its last usable
reading is ``stale_s`` seconds old or more.
"""

from firmware.adcs.apkf_lean_model import NW     # the wheels the lean ADCS flies
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators
from protocol.consts import STALE_BEACON, STALE_GNSS_A, STALE_GNSS_B, STALE_RW0, STALE_STARTRACKER

FAIL_AFTER = 3
N_RODS = 3
RODS = 0x7             # ADCS_STATUS.magnetic_failed: bits 0-2 the rods out of the unloading
MAG_SILENT = 0x8       # bit 3: the magnetometer silent


class Health:
    """Counters (16-bit on the wire), the failed-wheel mask and the stale bits of the last cycle."""

    def __init__(self, satb, stale_s):
        self.satb = satb
        self.stale_s = stale_s
        self.miss_rw = [0] * NW
        self.rw_miss_run = [0] * NW         # cycles in a row each wheel missed
        self.failed = 0
        self.magnetic = 0                   # ADCS_STATUS.magnetic_failed: rods out, the magnetometer silent
        self.rod_miss_run = [0] * N_RODS    # MTQ_TLM in a row naming each rod silent
        self.mag_miss_run = 0               # cycles in a row without a valid magnetometer reading
        self.mag_heard = False
        self.miss_st = self.miss_gnss = self.miss_beacon = 0
        self.n_st_invalid = self.n_beacon_invalid = self.n_gnss_b = self.n_gnss_b_drop = 0
        self.n_refused = 0                  # measurements (or predictions) the filters refused, fixes dropped
        self.n_resets = 0                   # attitude resets by the innovation gate; the last one's NIS and angle
        self.reset_nis = self.reset_arcsec = 0.0
        self.last_ok = {"st": 0.0, "gnss": 0.0, "beacon": 0.0, "gnss_b": 0.0}
        self.gnss_t = -1.0                  # the time of SatA's last usable fix (-1: never)
        self.stale = 0

    @micropython.native
    def wheels(self, rw_got):
        """The failed mask after a cycle's read-outs (every wheel answers each tick: ``telemetry.commands``)."""
        for i in range(NW):
            if rw_got[i]:
                self.rw_miss_run[i] = 0
                if self.failed & (1 << i):
                    self.failed &= ~(1 << i)        # it answers again: back into the allocation
            else:
                self.miss_rw[i] += 1
                self.rw_miss_run[i] += 1
                if self.rw_miss_run[i] >= FAIL_AFTER:
                    self.failed |= 1 << i

    @micropython.native
    def magnetics(self, rd):
        """``magnetic`` after a cycle's readings (``intake.Intake`` ``rd``; the module docstring)."""
        if rd.mtq_got:
            for i in range(N_RODS):
                if rd.mtq_silent & (1 << i):
                    self.rod_miss_run[i] += 1
                    if self.rod_miss_run[i] >= FAIL_AFTER:
                        self.magnetic |= 1 << i
                else:
                    self.rod_miss_run[i] = 0
                    self.magnetic &= ~(1 << i)          # it answers again: back into the unloading
        if rd.mag_got:
            self.mag_heard = True
            self.mag_miss_run = 0
            self.magnetic &= ~MAG_SILENT
        elif self.mag_heard:
            self.mag_miss_run += 1
            if self.mag_miss_run >= FAIL_AFTER:
                self.magnetic |= MAG_SILENT

    @micropython.native
    def count(self, rd):
        """The cycle's missed and invalid readings (``intake.Intake`` ``rd``)."""
        if not rd.st_got:
            self.miss_st += 1
        elif not rd.st_valid:
            self.n_st_invalid += 1
        if not rd.gnss_got:
            self.miss_gnss += 1
        if not rd.bc_got:
            self.miss_beacon += 1
        elif not rd.bc_valid:
            self.n_beacon_invalid += 1

    @micropython.native
    def heard(self, rd, t):
        """The times of the readings the filters took at cycle time t (s)."""
        if rd.st_ok():
            self.last_ok["st"] = t
        if rd.gnss_got:
            self.last_ok["gnss"] = t
            self.gnss_t = t
        if rd.bc_got and rd.bc_valid:
            self.last_ok["beacon"] = t

    @micropython.native
    def stale_bits(self, rd, t):
        """The cycle's ``STALE_*`` bits (SatB's GNSS: stale when silent for ``stale_s``)."""
        stale = 0
        if not rd.st_ok():
            stale |= 1 << STALE_STARTRACKER
        if not rd.gnss_got:
            stale |= 1 << STALE_GNSS_A
        if self.satb and t - self.last_ok["gnss_b"] >= self.stale_s:
            stale |= 1 << STALE_GNSS_B
        if not (rd.bc_got and rd.bc_valid):
            stale |= 1 << STALE_BEACON
        for i in range(NW):
            if not rd.rw_got[i]:
                stale |= 1 << (STALE_RW0 + i)
        self.stale = stale
        return stale

    @micropython.native
    def silent(self, t, keys):
        """True when any of the sensors ``keys`` (of ``last_ok``) has been silent for ``stale_s`` at t."""
        for k in keys:
            if t - self.last_ok[k] >= self.stale_s:
                return True
        return False

    def long_gap(self, t):
        """A sensor silent for ``stale_s``: the star tracker, SatA's GNSS, the beacon (SatB's GNSS when used)."""
        return self.silent(t, ("st", "gnss", "beacon", "gnss_b") if self.satb else ("st", "gnss", "beacon"))

    def only_st(self, t):
        """True when the star tracker is the only sensor silent for ``stale_s`` (in a slew it is blind by
        design)."""
        return not self.silent(t, ("gnss", "beacon", "gnss_b") if self.satb else ("gnss", "beacon"))
