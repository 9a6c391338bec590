"""The ADCS flight application (MicroPython): the 1 Hz cycle that ties its components together. The same app flies
on a board, in its own process on CAN and in process under the ground's analysis (``lockstep``: ``serve`` and
``InProcess``, the same packets' bytes).

The components, one file each:

- ``intake.Intake``: the cycle's readings off the bus, and which are usable;
- ``health.Health``: missed, invalid and refused readings, failed wheels and magnetic devices, stale sensors;
- ``estimation.Estimation``: the lean APKF and the lean STKF/AFLS;
- ``modes.Modes``: the mode machine and the command at SatB (where a mode transition is decided);
- ``allocation.Allocation``: the PD, saturation and wheel allocation, friction compensation, the magnetorquers'
  unloading (where a wheel command is allocated);
- ``telemetry``: RW_CMD, MTQ_CMD and ADCS_STATUS.

One cycle (the sequence of Sec. 6.4.2 at the flight side's scale):

1. sensors: the wheels' RW_TLM (tachometer read-outs at the cycle's time), the star tracker, SatA's GNSS, the
   beacon and SatB's relayed GNSS (time-tagged 2-3 s back) received since the last cycle; a wheel silent for
   3 cycles leaves the allocation, a rod whose driver is silent in 3 MTQ_TLM the unloading (the magnetometer
   silent for 3 cycles is reported: the unloading runs on the field model);
2. the lean APKF (attitude, rate, disturbance torque; parameters from the calibration's parameter file);
3. the lean STKF/AFLS: predict, SatA's GNSS, the beacon, SatB's GNSS at its time tag;
4. the mode and the command (``modes``), the wheel torques (``allocation``);
5. RW_CMD to each wheel, then ADCS_STATUS (mode, stale sensors, missed replies, estimates).

The configuration's ``world`` picks the thesis world (the thesis's Ch. 6 pointing) or the flight world (slew,
acquisition, magnetorquer unloading, the innovation gate: ``flight``, options under its key ``flight``).
"""

from firmware.adcs import flight, telemetry
from firmware.adcs.allocation import Allocation
from firmware.adcs.estimation import Estimation
from firmware.adcs.health import RODS, Health
from firmware.adcs.intake import Intake
from firmware.adcs.linalg import micropython     # the module, or CPython's no-op stand-in for its decorators
from firmware.adcs.modes import Modes


class App:
    """The ADCS application. ``on_packet(pid, src, payload)`` stores a sensor reading; ``cycle(tick, t)`` runs one
    1 Hz cycle and returns the wheel torques (``u``, N m) it commands. Its components: ``rd`` (readings),
    ``health``, ``est`` (filters), ``modes``, ``act`` (control and allocation). ``estimation``: the class (or
    factory) of the filters, called as estimation(cfg, rd, health, flight options); None: the lean filters that
    fly (``estimation.Estimation``); the ground's analysis may pass its own (same calls)."""

    def __init__(self, cfg, estimation=None):
        fo = flight.options(cfg)
        self.fly = fo is not None
        satb = bool(cfg.get("satb_gnss", False))
        self.health = Health(satb, float(cfg.get("stale_s", 10.0)))
        self.rd = Intake(satb, self.health)
        self.est = (estimation or Estimation)(cfg, self.rd, self.health, fo)
        self.modes = Modes(cfg, fo)
        self.act = Allocation(cfg, self.est.model, fo)
        self.t = 0.0
        self.mode = self.modes.mode

    def on_packet(self, pid, src, payload):
        """Store one sensor packet for the next cycle (``intake.Intake.on_packet``)."""
        self.rd.on_packet(pid, src, payload)

    @micropython.native
    def cycle(self, tick, t):
        """One 1 Hz cycle at time t (s) on the readings received since the last one; returns u (4, N m)."""
        rd, hl, est = self.rd, self.health, self.est
        self.t = t
        hl.wheels(rd.rw_got)
        hl.magnetics(rd)
        self.act.use_wheels(hl.failed)
        hl.count(rd)
        est.run_apkf(t, self.act.u, self.act.m_cmd)
        est.fill_unheard()
        st_ok = rd.st_ok()
        est.run_stkf(t, est.attitude())
        hl.heard(rd, t)
        u = self.control(t, st_ok)
        hl.stale_bits(rd, t)
        self.mode = self.modes.decide(t, est.apkf is not None, hl)
        rd.clear()
        return u

    @micropython.native
    def control(self, t, st_ok):
        """The cycle's command and wheel torques (none before the APKF starts)."""
        est, act, md = self.est, self.act, self.modes
        act.idle()
        if est.apkf is None:
            return act.u
        x, X = est.apkf.x, est.xs
        if self.fly:
            md.flight(t, x, st_ok, X)
            return act.flight(t, x, md.qc, md.wc, self.rd, self.health.failed, X, self.health.magnetic & RODS)
        md.thesis(t, x, st_ok, X)
        return act.torque(t, x, act.m_ff, md.qc, md.wc, self.rd.wp, self.health.failed, X)

    def clear_inputs(self):
        """Forget the readings received (the spacecraft gave up a cycle whose burst was incomplete)."""
        self.rd.clear()

    def status_payload(self, tick, cycle_us=0, n_rx_drop=0, n_rx_damaged=0):
        """ADCS_STATUS of cycle ``tick`` (``telemetry.status_payload``)."""
        return telemetry.status_payload(self, tick, cycle_us, n_rx_drop, n_rx_damaged)

    def commands(self, u, tick=0):
        """[(dst, RW_CMD payload)] of cycle ``tick`` (``telemetry.commands``)."""
        return telemetry.commands(u, self.health.failed, tick)
