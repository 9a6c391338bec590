"""The emulated spacecraft serving its devices on CAN to the ADCS flight software in a separate process.

Contract: ``AdcsSession``: start, cycle, summary, close (docs/ADCS.md, "ADCS on CAN").

The wire: a pseudo-terminal. The firmware (``firmware/adcs/main_can.py``, under ``micropython`` or CPython)
holds the master and plays the serial-CAN adapter's side of Lawicel (``firmware/hal/slcan.py``); this side
opens python-can's ``slcan`` interface on the slave (``protocol.link.open_link("slcan:PATH")``), with
can-isotp for the payloads over 8 bytes. Runtime ``qemu``: the firmware is the ADCS PIL board's (``make pil``:
QEMU's mps2-an500, a Cortex-M7 with its FPU; ``firmware/adcs/pil_main.py``), its UART QEMU's pty, where this side
opens the same slcan interface; its configuration goes over the UART first; ``board()`` gives its instructions per
cycle. Devices: RW0..RW3 (RW_CMD -> RW_TLM), STARTRACKER, GNSS (SatA, and
SatB's fixes relayed 2-3 s late when ``satb_gnss``), BEACON; the emulator is node SPACECRAFT. With
``magnetic_devices`` (the flight world's; off for the thesis's, which has none) also the spacecraft file's
magnetometer (MAGNETOMETER) and magnetorquers (MTQ: MTQ_CMD -> MTQ_TLM), where its blocks are not null.

Runtime ``inproc``: the same app (``firmware.adcs.app.App``) in this process behind
``firmware.adcs.lockstep.InProcess``, which takes the same packets' bytes and gives the same replies without a process
or a wire: the analysis host of the one flight stack (``fps adcs bps --world flight`` flies it), bit for bit the
cpython runtime's history.

Lockstep (one ``cycle()`` = one flight-software second = 10 RK4 steps of 0.1 s), exactly once per cycle over
a link that loses packets (``firmware.adcs.lockstep.Lockstep`` is the other side):

1. ADCS_TICK(k, t_k, burst, n_gnss_b) opens cycle k, naming the burst that follows it (sent at the end of the
   previous cycle, or by ``start``): the RW_TLM of each wheel that was commanded (its reply, with the speed at
   t_k: the reply's deadline is the next tick) or at k = 0 the first read-out; STARTRACKER, GNSS A, due GNSS B,
   BEACON (ISO-TP). A device that is silent (a fault) is not in the burst, so the firmware sees it missed;
2. the firmware runs its cycle once the burst named is in, and sends RW_CMD x4 and ADCS_STATUS(k);
3. this side waits for ADCS_STATUS(k) and the four RW_CMD (and in the flight world the MTQ_CMD). A try without them (the first waits 3 x the clean
   cycles' reply time, the next ``RETRY_S``, then x 1.5 per try up to 1 s) sends ADCS_TICK(k) again: the firmware answers from its cache when k has run, or
   with ADCS_MISSING(k, bits) while the burst is incomplete, and those packets are sent again (the burst whole
   when nothing came back at all). Every retry is counted (``summary()["retries"]``). After
   ``reply_timeout_s`` of wall time the cycle is late: the wheels keep their last command as a driver would;
   ``MAX_LATE_CYCLES`` late cycles in a row end the session with OSError, the firmware being hung. Then the
   commands are applied and the dynamics stepped 10 x 0.1 s;
4. k + 1: the next burst.

The magnetic devices (``magnetic_devices``): each burst carries a MAGNETOMETER packet (the true field at t_k in
the body frame: the truth's field model at its position, turned by its attitude; ``Magnetometer``'s bias and
noise, its random stream the eighth child of ``SeedSequence(seed)``, so the world's seven are as without it) and,
after a cycle whose MTQ_CMD was applied, the MTQ_TLM (or NACK) answering it. ADCS_STALE has no bit left for
them: they are not named in ADCS_TICK.burst (the firmware does not wait for them, ADCS_MISSING cannot ask for
them again) and are sent before the named packets, so they arrive while the cycle is open. An MTQ_CMD of cycle
k (its ``cycle`` byte k mod 256, sent before ADCS_STATUS(k)) is applied with the wheel commands: the truth's
dipole becomes its residual dipole plus the rods' applied dipole (``devices.Magnetorquers``: least-squares share
per rod, clipped at the file's limit) and the field torque m x b follows; without one the rods keep their last
command, as a driver would. The lean flight firmware sends none.

The first contact: this side sends HELLO to the firmware every ``HELLO_RETRY_S`` (doubling up to
``HELLO_RETRY_MAX_S``) until the firmware's HELLO comes (it says one when the channel opens, and answers each
HELLO with its own), so a lost HELLO either way costs a retry; after ``HELLO_WAIT_S`` the session ends with
OSError naming the link and its counters (or the firmware's own end, when its process exited).

``link_faults`` (``protocol.faults.LinkFaults``): bit flips in the slcan ASCII stream and frame lines dropped,
both directions, at this end of the pty, from the HELLO on (``silence`` in the session's virtual seconds, from the
first burst on).

A device reply the firmware misses by its tick is counted by the firmware (ADCS_STATUS counters); a wheel
that got no RW_CMD in a cycle is counted here (``missed_rw_cmd``), and one whose RW_CMD had a non-finite torque
or an enable other than 0/1 (ignored: the wheel keeps its last command) too (``refused_rw_cmd``).
Faults (``faults`` dict):
``wheel_silent`` [i, t0]: from t0 wheel i's node is dead (no RW_TLM, commands ignored, the rotor coasts);
``startracker_blind`` [t0, t1]: the star tracker answers "no solution" (valid 0); ``gnss_outage`` [t0, t1]:
no GNSS fix of SatA (SatB's relay too); ``beacon_lost`` t0: the beacon answers "not in view" (valid 0).
The beacon also answers "not in view" whenever the Earth, with 100 km of atmosphere, is between the two
satellites (``emulator.occultation``; counted in ``beacon_occulted_cycles``).

Truth: the world ground/adcs/body_pointing.py runs, built by the same ``emulator.spacecraft.scenario.pointing_world``
(orbits of ``emulator.orbits``, two-body by default, brahe ``hpop`` on request, on a 20 Hz grid by 10th-order
Lagrange; the spacecraft of ``emulator.spacecraft`` (RK4 at 0.1 s) from q = [0, 0, 0, 1] at rest; the star
tracker, GNSS, beacon and relay of ``emulator.navsensors``; the STKF's start), for the vehicle of a spacecraft
file (``spacecraft``, default thesis-3u: the true vehicle, orbits, epoch and sensors); the parameter file of a
perfect calibration of that vehicle (``emulator.spacecraft.scenario.truth_params``) unless one is given, checked
against it. The firmware's configuration carries the file's nominal figures (``AdcsSession.config``).
"""

import json
import os
import shutil
import tempfile
import time
import tty

import numpy as np

from emulator import orbits
from emulator.adcs_bus import N, P, FaultSchedule, SpacecraftBus, check_faults
from emulator.adcs_replies import ReplyWait, StatusWatch
from emulator.launcher import (ADCS_IMAGE, ADCS_MACHINE, PIL_ISOTP_TIMEOUT_MS, FirmwareProcess, command,
                               qemu_command, start_board)
from emulator.runtime import last_lines
from protocol import core
from protocol.units import RAD_PER_ARCSEC
from emulator.spacecraft import scenario
from emulator.spacecraft.devices import Magnetometer, Magnetorquers, SpacecraftDevices
from emulator.spacecraft.wheels import N_WHEELS
from firmware.adcs.apkf_lean import MOMENTUM
from firmware.adcs.control import check_zeta

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MAIN = os.path.join(ROOT, "firmware", "adcs", "main_can.py")
RUNTIMES = ("inproc", "micropython", "cpython", "qemu")
# the qemu runtime's board, as a run's summary.json states it
BOARD = {"board": "QEMU mps2-an500 (ARM's MPS2 FPGA board, AN500 image) standing for a CubeSat ADCS computer",
         "core": "ARM Cortex-M7 with FPv5-D16 (double-precision FPU); MicroPython floats single precision",
         "clock_hz": 216e6, "cpi_range": [1.0, 2.0]}
WORLDS = ("thesis", "flight")
SPAN_MARGIN_S = 8.0                  # the orbit truth's span beyond the run (``scenario.truth_span``)
MAX_LATE_CYCLES = 3                  # late cycles in a row that end the session: the firmware is hung
HELLO_WAIT_S = 30.0                  # wall seconds the firmware has to answer HELLO
HELLO_RETRY_S, HELLO_RETRY_MAX_S = 0.05, 0.5    # HELLO sent again after this, doubling up to the second
# why the qemu runtime flies the white STKF only
BOARD_STKF = ("the ADCS PIL image (make pil) freezes the white STKF's modules, not firmware/adcs/stkf_dmc.py; "
              "fly the markov STKF with runtime micropython, cpython or inproc")
ISOTP_TIMEOUT_MS = 20.0              # N_Bs on the lockstep pty, both ends (ISO's 1000 ms is for a real bus)


def _check_args(runtime, duration_s, ts, truth, apkf_momentum, world, probe, link_faults, estimation=None,
                stkf_accel="white"):
    """``AdcsSession``'s arguments that need no file: ValueError naming the one out of range."""
    if runtime not in RUNTIMES:
        raise ValueError("runtime %r not one of %s" % (runtime, ", ".join(RUNTIMES)))
    if not (np.isfinite(duration_s) and duration_s >= 1):
        raise ValueError("duration must be >= 1 s, got %r" % (duration_s,))
    if not (np.isfinite(ts) and ts > 0):
        raise ValueError("settling time ts must be > 0 s, got %r" % (ts,))
    if truth not in orbits.TRUTHS:
        raise ValueError("truth %r not one of %s" % (truth, ", ".join(orbits.TRUTHS)))
    if apkf_momentum not in MOMENTUM:
        raise ValueError("apkf_momentum must be one of %s, got %r" % (", ".join(MOMENTUM), apkf_momentum))
    if world not in WORLDS:
        raise ValueError("world must be one of %s, got %r" % (", ".join(WORLDS), world))
    if probe is not None and runtime != "inproc":
        raise ValueError("a probe reads the app's state: runtime inproc only")
    if estimation is not None and runtime != "inproc":
        raise ValueError("another estimation runs in this process: runtime inproc only")
    if runtime == "inproc" and link_faults is not None:
        raise ValueError("link faults need a link: runtime inproc has none (use cpython, micropython or qemu)")
    scenario.flight_stkf(stkf_accel)                # a known form
    if stkf_accel != "white" and runtime == "qemu":
        raise ValueError("stkf_accel %s: %s" % (stkf_accel, BOARD_STKF))
    if stkf_accel != "white" and (world, truth) != ("flight", "hpop"):
        raise ValueError("stkf_accel %s is the flight STKF's form over the hpop truth (world flight, truth hpop); "
                         "the %s world over the %s truth flies the thesis's two-body STKF" % (stkf_accel, world, truth))


class AdcsSession:
    """See the module docstring and docs/ADCS.md's "ADCS on CAN". Extra keywords: ``truth`` ("two-body" or "hpop"),
    ``cache_dir`` (orbit truth cache), ``hold_s``, ``reply_timeout_s`` (wall seconds a cycle may take),
    ``heap_out`` (micropython: a JSON file of the heap bytes per cycle, written when the firmware exits),
    ``apkf_momentum`` (the lean APKF's momentum input: "filtered", the read-outs filtered on the commanded
    torques, flown; "tach", the read-out difference, and "torque", the commanded torques, for comparison),
    ``link_faults`` (a ``protocol.faults.LinkFaults`` on the slcan stream, see the module docstring),
    ``spacecraft`` (a checked spacecraft file, None: thesis-3u; see the module docstring),
    ``magnetic_devices`` (serve the file's magnetometer and magnetorquers on the bus, see the module docstring;
    off by default: thesis-3u's are assumptions for the flight world only), ``probe`` (runtime inproc: called as
    probe(tick, t, u) after each cycle of the app, ``self.app``, with the truth still at the cycle's time),
    ``estimation`` (runtime inproc: the app's filters other than the lean ones that fly, ``App``'s keyword; the
    ground's are ``ground.adcs.estimators.estimation``), ``wheel_speed_limit_rpm`` (the thesis world's true wheels'
    limit, ``scenario.pointing_world``'s; the flight world's is the file's), ``zeta`` (the PD's damping ratio,
    Eq. 6.6, the config's ``pd_zeta``; None: the firmware's ``ZETA``, and no key), ``stkf_accel`` (the flight
    STKF's form over the hpop truth, ``scenario.STKF_ACCELS``: "white", the default, or "markov"; the flight world
    with truth hpop only)."""

    def __init__(self, *, runtime="micropython", satb_gnss=False, seed=0, duration_s=600.0, ts=33.0,
                 params=None, faults=None, log=None, truth="two-body", cache_dir=None, hold_s=scenario.HOLD_S,
                 reply_timeout_s=30.0, heap_out=None, record=False, apkf_momentum="filtered", link_faults=None,
                 spacecraft=None, magnetic_devices=False, world="thesis", flight=None, probe=None,
                 estimation=None, wheel_speed_limit_rpm=scenario.POINTING_WHEEL_RPM, zeta=None, stkf_accel="white"):
        _check_args(runtime, duration_s, ts, truth, apkf_momentum, world, probe, link_faults, estimation, stkf_accel)
        self.stkf_accel = stkf_accel
        self.probe = probe
        self.estimation = estimation
        self.apkf_momentum = apkf_momentum
        self.runtime, self.satb, self.seed = runtime, bool(satb_gnss), int(seed)
        self.ts, self.hold_s = float(ts), float(hold_s)
        self.zeta = None if zeta is None else check_zeta(zeta)
        self.log = log
        self.link_faults = link_faults
        self.heap_out = heap_out
        self.K = int(np.ceil(float(duration_s)))
        self.spacecraft = d = spacecraft or scenario.thesis_3u()
        self.world_name, self.flight = world, dict(flight or {})
        fly = world == "flight"
        if fly and d["magnetorquers"] is None:
            raise ValueError("magnetorquers = null: the flight world unloads the wheels with magnetorquers")
        self.truth = truth
        self.world = w = scenario.pointing_world(self.K, self.seed, self.satb, truth, cache_dir, SPAN_MARGIN_S,
                                                 n_tags=self.K + 1, spacecraft=d, flight=fly,
                                                 wheel_speed_limit_rpm=wheel_speed_limit_rpm)
        self.params = scenario.truth_params(w.sc, d) if params is None else _load_params(params, d)
        devices = None                           # the magnetic devices (SpacecraftDevices), when served
        if magnetic_devices or fly:
            r_mag = np.random.default_rng(np.random.SeedSequence(self.seed).spawn(8)[7])
            mag, mtq = Magnetometer.from_spacecraft(d, r_mag), Magnetorquers.from_spacecraft(d)
            if mag is not None or mtq is not None:
                devices = SpacecraftDevices(w.sc, w.st, magnetometer=mag, magnetorquers=mtq)
        self.schedule = FaultSchedule(check_faults(faults, duration_s), self._say)
        self.bus = SpacecraftBus(w, devices, self.schedule, self._say, record)
        # the flight world's firmware sends an MTQ_CMD each cycle: waited for as the RW_CMDs (a lost one is asked
        # for again with the tick), so that a lossy link's run stays the clean run's
        self.wait = ReplyWait(self.bus, fly and devices is not None and devices.mtq is not None, reply_timeout_s)
        self.watch = StatusWatch(self._say, self.schedule.log, None if fly else (self.hold_s,
                                 self.hold_s + 4 * self.ts), self.schedule.faults.get("startracker_blind"))
        self.k = 0
        self.proc = None
        self.link = None
        self.app = None                          # runtime inproc: the firmware's App in this process
        self._tmp = None
        self.wheel_rpm_log = []                  # per cycle: the largest |wheel speed| at its end (rpm)
        self.wall_s = 0.0
        self._t_wall = None                      # set by the first burst: the fault clock runs from there
        self.closed = False

    # the world's and the bus's parts, as the callers know them
    sc = property(lambda self: self.world.sc)
    xg = property(lambda self: self.world.xg)
    wheels = property(lambda self: self.world.wheels)
    devices = property(lambda self: self.bus.devices)
    recorded = property(lambda self: self.bus.recorded)
    st_valid_log = property(lambda self: self.bus.st_valid_log)
    mode_changes = property(lambda self: self.watch.mode_changes)
    faults = property(lambda self: self.schedule.faults)          # the faults dict (check_faults)
    fault_log = property(lambda self: self.schedule.log)
    last_status = property(lambda self: self.watch.last)

    # --- process and link -----------------------------------------------------------------------------
    def _say(self, msg):
        if self.log is not None:
            self.log(msg)

    def config(self):
        """The firmware's configuration (written to its config.json): parameter file, gains, STKF start, and
        the spacecraft file's nominal figures, not the emulated (true) vehicle's, as ground/adcs/body_pointing.py's flight
        software: the wheels' axes, torque limit, friction model and read-out noise, the star tracker's, GNSS's
        and beacon's noise, the APKF's initial 1 sigma, the STKF's P0 and the laser axis; in the flight world the STKF's
        dynamics (``scenario.flight_stkf(stkf_accel)``: J2 and its process noise, white or Gauss-Markov) when the
        truth is hpop's, whose Earth has J2; a two-body truth has none, and the STKF keeps the thesis's two-body
        model and qa there."""
        d = self.spacecraft
        w, u, g = d["wheels"], d["uncertainty"], d["gnss"]
        return {"params": self.params, "ts": self.ts, "hold_s": self.hold_s, "satb_gnss": self.satb,
                "stkf_x0": self.world.stkf_x0.tolist(), "stkf_P0": list(self.world.stkf_P0_diag), "lag_s": scenario.LAG_S,
                "torque_max": w["torque_limit_nm"],
                "friction": [w["friction_coulomb_nm"], w["friction_viscous_nms_rad"],
                             w["friction_smooth_rpm"] * 2 * np.pi / 60],
                "beacon_sigma_arcsec": self.world.beacon.sigma / RAD_PER_ARCSEC,
                "gnss_sigma": [g["sigma_position_m"], g["sigma_velocity_m_s"]],
                "wheel_axes": self.world.wheels.c0.tolist(), "tach_noise_rpm": w["tach_noise_rpm"], "wheels": w,
                "star_tracker_sigma_arcsec": list(d["star_tracker"]["sigma_arcsec"]),
                "apkf_p0": [u["attitude_sigma_deg"], u["rate_sigma_deg_s"], u["disturbance_torque_sigma_nm"]],
                "laser_axis": scenario.laser_axis(d).tolist(),
                "apkf_momentum": self.apkf_momentum, "gmst0_rad": self.world.field.gmst0,
                "isotp_timeout_ms": ISOTP_TIMEOUT_MS, "world": self.world_name, "flight": self.flight,
                "magnetorquers": d["magnetorquers"],
                **(scenario.flight_stkf(self.stkf_accel) if (self.world_name, self.truth) == ("flight", "hpop")
                   else {}),
                **({} if self.zeta is None else {"pd_zeta": self.zeta})}

    def stkf_form(self):
        """The flight software's STKF dynamics, as a run records them: ``accel`` (``stkf_accel``) and the lean
        STKF's keywords from the configuration (``firmware.adcs.estimation.stkf_model``: gravity, and qa or
        sigma_a and tau)."""
        from firmware.adcs.estimation import stkf_model
        return dict(stkf_model(self.config()), accel=self.stkf_accel)

    def start(self):
        """Spawn the firmware, open the slcan bus, wait for its HELLO, send the first burst."""
        if self.runtime == "inproc":             # the app on this host: the same bytes, no process or wire
            from firmware.adcs.app import App
            from firmware.adcs.lockstep import InProcess
            app = App(json.loads(json.dumps(self.config())), estimation=self.estimation)
            self.link = InProcess(app, N["ADCS"], self.probe)
            self.app = self.link.app
            self._say("ADCS flight software in this process (inproc)")
            return self._begin()
        from protocol import link as hostlink
        self._tmp = tempfile.mkdtemp(prefix="fps-adcs-")
        cfg = os.path.join(self._tmp, "config.json")
        with open(cfg, "w") as fh:
            json.dump(self.config(), fh)
        accept = ("RW0", "RW1", "RW2", "RW3", "STARTRACKER", "GNSS", "BEACON")
        if self.devices is not None:             # MTQ_CMD, and the flow control of MTQ_TLM and MAGNETOMETER
            accept += (("MTQ",) if self.devices.mtq is not None else ()) + (
                ("MAGNETOMETER",) if self.devices.mag is not None else ())

        def connect(path):
            return hostlink.open_link("slcan:" + path, "SPACECRAFT", bitrate=1000000, accept=accept,
                                      isotp_timeout_s=(PIL_ISOTP_TIMEOUT_MS if self.runtime == "qemu"
                                                       else ISOTP_TIMEOUT_MS) / 1000.0)
        if self.runtime == "qemu":               # the ADCS PIL board: its UART is QEMU's pty
            if not os.path.exists(ADCS_IMAGE):
                raise OSError("runtime qemu needs the ADCS PIL image %s (make pil)" % os.path.relpath(ADCS_IMAGE))
            self.proc, self.link = start_board(qemu_command(ADCS_IMAGE, serial="pty", icount=True,
                                                            machine=ADCS_MACHINE),
                                               "import firmware.adcs.pil_main", connect,
                                               first_line=json.dumps(self.config(), separators=(",", ":")),
                                               name="qemu-system-arm (the ADCS PIL board)")
            path = "QEMU's pty"
        else:
            m, s = os.openpty()
            tty.setraw(s)
            os.set_blocking(m, False)
            path = os.ttyname(s)
            extra = [self.heap_out] if self.heap_out else []
            argv, env = command(self.runtime, MAIN, [m, cfg] + extra, micropython_opts=("-X", "heapsize=64M"))
            try:
                self.proc = FirmwareProcess(argv, env=env, pass_fds=(m,),
                                            name="the ADCS firmware (%s)" % self.runtime)
            finally:
                os.close(m)
            try:
                self.link = connect(path)
            finally:
                os.close(s)
        if self.link_faults is not None:
            from protocol.faults import inject
            inject(self.link, self.link_faults, clock=lambda: float(self.k) if self._t_wall is not None else None)
        try:
            self._hello("CAN (slcan on %s)" % path)
        except BaseException:
            self.close()
            raise
        self._say("ADCS firmware up (%s, pid %d), CAN over slcan on %s%s" % (
            self.runtime, self.proc.pid, path, "" if self.wait.retries["hello_tries"] == 1 else
            " (HELLO answered at try %d)" % self.wait.retries["hello_tries"]))
        return self._begin()

    def _hello(self, where):
        """HELLO to the firmware until its own comes (see the module docstring); OSError after ``HELLO_WAIT_S``,
        when its process exits or when the link closes. ``where``: the link, as the message names it."""
        hello = P["HELLO"]
        payload = core.encode_payload(hello, node=N["SPACECRAFT"])
        deadline = time.monotonic() + HELLO_WAIT_S
        gap = HELLO_RETRY_S
        while True:
            if self.proc.poll() is not None:
                raise OSError(self.proc.death(0.5, " before it said HELLO"))
            if self.proc.crashed():          # a board that stopped at boot: its traceback
                raise OSError(self.proc.crashed())
            if self.link.closed:
                raise OSError("the link to %s (%s) closed before it said HELLO%s%s" % (
                    self.proc.name, where, self.proc.exit_note(0.5), self._link_note()))
            now = time.monotonic()
            if now >= deadline:
                raise OSError("%s did not answer HELLO over %s within %g s (%d HELLOs sent)%s%s" % (
                    self.proc.name, where, HELLO_WAIT_S, self.wait.retries["hello_tries"],
                    (": " + last_lines(self._stderr())) if self._stderr() else "", self._link_note()))
            self.link.send_raw(hello, N["SPACECRAFT"], N["ADCS"], payload)
            self.wait.retries["hello_tries"] += 1
            end = min(deadline, now + gap)
            gap = min(2 * gap, HELLO_RETRY_MAX_S)
            while not self.link.closed:
                left = end - time.monotonic()
                if left <= 0:
                    break
                if any(p[0] == hello for p in self.link.recv(left)):
                    return

    def _link_note(self):
        """`` [link counters: name=value, ...]`` of the link's counters that are not zero ("" without any)."""
        try:
            c = self.link.counters() if self.link is not None else {}
        except Exception:   # noqa: BLE001 - a message's detail: a bus already gone reports nothing
            c = {}
        said = ", ".join("%s=%s" % (k, v) for k, v in sorted(c.items()) if v not in (0, None, "", []))
        return " [link counters: %s]" % said if said else ""

    def _begin(self):
        """The wall clock, the first burst (the fault clock's silences count from here)."""
        self._t_wall = time.perf_counter()
        self._burst()
        return self

    def _exited(self, k):
        """OSError when the firmware has left (its process or the link) in cycle k: the process named, how it
        ended and its last stderr lines."""
        if self.link.closed or (self.proc is not None and self.proc.poll() is not None):
            when = " at t = %d s" % k
            said = self.proc.death(1.0, when) if self.proc is not None else ""
            raise OSError(said or "the ADCS firmware's link closed%s%s%s" % (
                when, (" (%s is still running)" % self.proc.name) if self.proc is not None else "",
                self._link_note()))

    def _stderr(self):
        return self.proc.stderr_tail(2000).strip() if self.proc is not None else ""

    def _burst(self):
        """Cycle k's burst built (``SpacecraftBus.burst``) and sent with its ADCS_TICK."""
        self.bus.burst(self.k)
        self.wait.open(self.link)

    def cycle(self):
        """One 1 s flight-software cycle = 10 dynamics steps of 0.1 s (see the module docstring)."""
        if self.link is None:
            raise OSError("session not started (call start())")
        if self.k >= self.K:
            raise ValueError("the session's %d s are done" % self.K)
        status = self.wait.wait(self.k, self.link, self._exited)
        t = float(self.k)
        if status is None:
            self._late(t)
            status = {}
        else:
            self.wait.late_run = 0
        applied = self.bus.apply(self.wait.cmd, self.wait.mtq_cmd)
        sc, X, t10, w_rel = self.sc, np.empty((10, 15)), np.empty(10), np.empty((10, 4))
        for j in range(10):
            sc.step()
            X[j], t10[j], w_rel[j] = sc.x, sc.t, sc.omega_rw_rel
        sub = scenario.WORLD_RATE_HZ // 10
        g = self.xg[(self.k * 10 + 1) * sub:(self.k * 10 + 10) * sub + 1:sub]
        out = {"t": t10, "q": X[:, 0:4], "w": X[:, 4:7], "w_rel": w_rel,
               "ra": g[:, 0, 0:3], "va": g[:, 0, 3:6], "rb": g[:, 1, 0:3], "vb": g[:, 1, 3:6]}
        if not np.all(np.isfinite(sc.x)):
            raise FloatingPointError("truth diverged at t = %.1f s" % sc.t)
        self.wheel_rpm_log.append(float(np.abs(w_rel[9]).max() * 60 / (2 * np.pi)))
        est = self.watch.take(status, t, self.bus.st_blind_before) if status else {}
        out["status"], out["est"], out["rw_cmd"] = status, est, applied
        self.k += 1
        if self.k < self.K:
            self._burst()
        self.wall_s = time.perf_counter() - self._t_wall
        return out

    def _late(self, t):
        """A cycle without its ADCS_STATUS: the wheels hold; OSError after ``MAX_LATE_CYCLES`` in a row."""
        w = self.wait
        w.n_late += 1
        w.late_run += 1
        if w.late_run >= MAX_LATE_CYCLES:        # alive but hung: its pty would fill and block the bursts
            raise OSError("%s gave no ADCS_STATUS for %d cycles in a row (%g s each) at t = %d s: hung? %s%s" % (
                getattr(self.proc, "name", "the ADCS firmware"), w.late_run, w.timeout_s, self.k,
                last_lines(self._stderr()) or "(nothing on its stderr)", self._link_note()))
        self._say("t = %.0f s: no ADCS_STATUS within %.0f s (late cycle; wheels hold)" % (t, w.timeout_s))

    def blind_share(self, t_from):
        """The share of cycles from ``t_from`` (s) on whose star-tracker output was not valid (None if none)."""
        v = self.bus.st_valid_log[int(np.ceil(t_from)):]
        return None if not v else 1.0 - sum(v) / len(v)

    def wheel_rpm_max(self, t_from=0.0):
        """The largest |wheel speed| (rpm) at the ends of the cycles from ``t_from`` (s) on (None if none)."""
        v = self.wheel_rpm_log[int(np.ceil(t_from)):]
        return max(v) if v else None

    def board(self):
        """A qemu run's board and its instructions per 1 Hz cycle (None for the other runtimes): under ``-icount
        shift=0`` one instruction is one virtual ns, so the firmware's own cycle time (ADCS_STATUS.cycle_us, its
        timer: the filters, the control law and the commands; the packets' decoding outside it) in us is
        thousands of instructions."""
        if self.runtime != "qemu":
            return None
        n, total, worst = self.watch.cycle_us
        return {"target": dict(BOARD), "instructions_per_cycle": {
            "what": "the firmware's own cycle (ADCS_STATUS.cycle_us: filters, control law, commands) under -icount "
                    "shift=0, one instruction a virtual ns; the first cycle out of INIT (the filters' start) apart, "
                    "in filters_start",
            "n": n, "mean": 1000.0 * total / n if n else None, "max": 1000.0 * worst if n else None,
            "filters_start": None if self.watch.filters_start_us is None else 1000.0 * self.watch.filters_start_us}}

    def summary(self):
        st = self.watch.last or {}
        bus, dev = self.bus, self.bus.devices
        return {"runtime": self.runtime, "satb_gnss": self.satb, "seed": self.seed, "ts_s": self.ts,
                "spacecraft": self.spacecraft["name"],
                "cycles": self.k, "virtual_s": float(self.k), "wall_s": self.wall_s,
                "speed_x_realtime": (self.k / self.wall_s) if self.wall_s > 0 else None,
                "late_cycles": self.wait.n_late, "missed_rw_cmd": list(bus.missed_rw_cmd),
                "refused_rw_cmd": list(bus.refused_rw_cmd), "beacon_occulted_cycles": bus.beacon_occulted,
                "magnetic_devices": None if dev is None else {
                    "magnetometer": dev.mag is not None, "magnetorquers": bus.has_mtq(),
                    "mtq_cmd": bus.n_mtq_cmd, "refused_mtq_cmd": bus.refused_mtq_cmd},
                "firmware_missed": {"rw": [st.get("miss_rw%d" % i) for i in range(N_WHEELS)],
                                    "startracker": st.get("miss_st"), "gnss": st.get("miss_gnss"),
                                    "beacon": st.get("miss_beacon"), "st_invalid": st.get("n_st_invalid"),
                                    "beacon_invalid": st.get("n_beacon_invalid"), "gnss_b_fused": st.get("n_gnss_b"),
                                    "stkf_refused": st.get("n_refused"),
                                    "rx_drops": st.get("n_rx_drop"), "rx_damaged": st.get("n_rx_damaged")},
                "wheels_failed": st.get("wheels_failed"), "last_mode": st.get("adcs_mode_name"),
                "link": self.link.counters() if self.link is not None else {},
                "link_faults": self.link_faults.as_dict() if self.link_faults is not None else None,
                "retries": dict(self.wait.retries),
                "faults": self.faults, "fault_log": list(self.fault_log), "world": self.world_name,
                "mode_changes": list(self.watch.mode_changes), "max_wheel_speed_rpm": self.wheel_rpm_max(),
                "wheel_datasheet_rpm": self.spacecraft["wheels"]["speed_limit_rpm"],
                "complete": self.k >= self.K}

    def close(self):
        if self.closed:
            return
        self.closed = True
        if self.link is not None:
            try:
                self.link.close()
            except Exception:   # noqa: BLE001 - a bus already gone must not stop the cleanup
                pass
        if self.proc is not None:
            self.proc.stop()                 # the firmware leaves when the pty closes; else SIGTERM, SIGKILL
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()
        return False


def _load_params(params, spacecraft=None):
    """A parameter-file dict or path, checked (``protocol.paramfile``, the flight firmware's checker) against the
    checked spacecraft file ``spacecraft`` (None: the thesis's 3U); the dict as given."""
    from protocol import paramfile
    where = "parameter file"
    if isinstance(params, (str, os.PathLike)):
        from emulator.fileio import read_json
        where = str(params)
        params = read_json(params, "parameter file")
    try:
        paramfile.check(params, spacecraft)
    except ValueError as exc:
        raise ValueError("%s: %s" % (where, exc)) from None
    return params
