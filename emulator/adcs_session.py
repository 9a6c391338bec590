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

``link_faults`` (``protocol.faults.LinkFaults``): bit flips in the slcan ASCII stream and frame lines dropped,
both directions, at this end of the pty, from the first burst on (``silence`` in the session's virtual
seconds).

A device reply the firmware misses by its tick is counted by the firmware (ADCS_STATUS counters); a wheel
that got no RW_CMD in a cycle is counted here (``missed_rw_cmd``), and one whose RW_CMD had a non-finite torque
or an enable other than 0/1 (ignored: the wheel keeps its last command) too (``refused_rw_cmd``).
Faults (``faults`` dict):
``wheel_silent`` [i, t0]: from t0 wheel i's node is dead (no RW_TLM, commands ignored, the rotor coasts);
``startracker_blind`` [t0, t1]: the star tracker answers "no solution" (valid 0); ``gnss_outage`` [t0, t1]:
no GNSS fix of SatA (SatB's relay too); ``beacon_lost`` t0: the beacon answers "not in view" (valid 0).

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
from emulator.launcher import ADCS_IMAGE, ADCS_MACHINE, FirmwareProcess, command, qemu_command, start_board
from protocol.units import RAD_PER_ARCSEC
from emulator.spacecraft import scenario
from emulator.spacecraft.devices import Magnetometer, Magnetorquers, SpacecraftDevices
from emulator.spacecraft.dynamics import dcm
from emulator.spacecraft.wheels import N_WHEELS
from firmware.adcs.apkf_lean import MOMENTUM
from firmware.adcs.lockstep import burst_bit
from protocol import core, table

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MAIN = os.path.join(ROOT, "firmware", "adcs", "main_can.py")
RUNTIMES = ("inproc", "micropython", "cpython", "qemu")
# the qemu runtime's board, as a run's summary.json states it
BOARD = {"board": "QEMU mps2-an500 (ARM's MPS2 FPGA board, AN500 image) standing for a CubeSat ADCS computer",
         "core": "ARM Cortex-M7 with FPv5-D16 (double-precision FPU); MicroPython floats single precision",
         "clock_hz": 216e6, "cpi_range": [1.0, 2.0]}
WORLDS = ("thesis", "flight")
FAULTS = ("wheel_silent", "startracker_blind", "gnss_outage", "beacon_lost")
SPAN_MARGIN_S = 8.0                  # the orbit truth's span beyond the run (``scenario.truth_span``)
MAX_LATE_CYCLES = 3                  # late cycles in a row that end the session: the firmware is hung
ISOTP_TIMEOUT_MS = 20.0              # N_Bs on the lockstep pty, both ends (ISO's 1000 ms is for a real bus)
TRY_MIN_S, TRY_MAX_S = 0.02, 1.0     # the first try's wait for the cycle's replies: 3 x the recent reply time
RETRY_S = 0.03                       # a further try's first wait: an answer from the cache takes ~10 ms
TRY_BACKOFF = 1.5                    # each further try of a cycle waits this much longer (up to TRY_MAX_S)
MODE_NAME = dict((v, k) for k, v in table.ADCS_MODES)
STALE_BITS = table.ADCS_STALE

P = core.PACKET_ID
N = core.NODE
RW_NODES = tuple(N["RW%d" % i] for i in range(N_WHEELS))


def check_faults(faults, duration_s):
    """Validate the faults dict (see the module docstring); returns a normalised copy."""
    if faults is None:
        return {}
    if not isinstance(faults, dict):
        raise ValueError("faults must be a dict with keys among %s" % ", ".join(FAULTS))
    out = {}
    for k, v in faults.items():
        if k not in FAULTS:
            raise ValueError("unknown fault %r (known: %s)" % (k, ", ".join(FAULTS)))
        try:
            if isinstance(v, bool) or (isinstance(v, (list, tuple)) and any(isinstance(e, bool) for e in v)):
                raise TypeError("true/false is not a number")          # JSON true would read as 1
            if k == "beacon_lost":
                out[k] = t0 = float(v)
                ok = np.isfinite(t0) and t0 >= 0
            elif isinstance(v, (str, bytes)):   # "12" would read as [1, 2]
                ok = False
            elif k == "wheel_silent":
                i, t0 = int(v[0]), float(v[1])
                out[k] = [i, t0]
                ok = 0 <= i < N_WHEELS and np.isfinite(t0) and t0 >= 0 and float(v[0]) == i and len(v) == 2
            else:
                t0, t1 = float(v[0]), float(v[1])
                out[k] = [t0, t1]
                ok = len(v) == 2 and np.isfinite(t0) and np.isfinite(t1) and 0 <= t0 < t1
        except (TypeError, ValueError, IndexError):
            ok = False
        if not ok:
            raise ValueError("fault %s = %r: expected %s" % (k, v, {
                "wheel_silent": "[wheel 0-3, t0_s >= 0]", "beacon_lost": "t0_s >= 0"}.get(k, "[t0_s, t1_s], 0 <= t0 < t1")))
        if t0 >= duration_s:                     # t0: the fault's start, set by its branch above
            raise ValueError("fault %s starts at %g s, not before the run's end (%g s): it would never happen"
                             % (k, t0, duration_s))
    return out


def _check_args(runtime, duration_s, ts, truth, apkf_momentum, world, probe, link_faults):
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
    if runtime == "inproc" and link_faults is not None:
        raise ValueError("link faults need a link: runtime inproc has none (use cpython, micropython or qemu)")


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
    probe(tick, t, u) after each cycle of the app, ``self.app``, with the truth still at the cycle's time)."""

    def __init__(self, *, runtime="micropython", satb_gnss=False, seed=0, duration_s=600.0, ts=33.0,
                 params=None, faults=None, log=None, truth="two-body", cache_dir=None, hold_s=scenario.HOLD_S,
                 reply_timeout_s=30.0, heap_out=None, record=False, apkf_momentum="filtered", link_faults=None,
                 spacecraft=None, magnetic_devices=False, world="thesis", flight=None, probe=None):
        _check_args(runtime, duration_s, ts, truth, apkf_momentum, world, probe, link_faults)
        self.probe = probe
        self.apkf_momentum = apkf_momentum
        self.runtime, self.satb, self.seed = runtime, bool(satb_gnss), int(seed)
        self.duration_s, self.ts, self.hold_s = float(duration_s), float(ts), float(hold_s)
        self.faults = check_faults(faults, duration_s)
        self.log = log
        self.reply_timeout_s = float(reply_timeout_s)
        self.link_faults = link_faults
        self.faults_port = None
        self.heap_out = heap_out
        self.recorded = [] if record else None     # per tick: [tick, t_ms, [[pid, src, payload hex], ...]]
        self.K = int(np.ceil(self.duration_s))
        self.spacecraft = d = spacecraft or scenario.thesis_3u()
        self.world_name, self.flight = world, dict(flight or {})
        fly = world == "flight"
        if fly and d["magnetorquers"] is None:
            raise ValueError("magnetorquers = null: the flight world unloads the wheels with magnetorquers")
        self.world = w = scenario.pointing_world(self.K, self.seed, self.satb, truth, cache_dir, SPAN_MARGIN_S,
                                                 n_tags=self.K + 1, spacecraft=d, flight=fly)
        magnetic_devices = magnetic_devices or fly
        self.xg, self.wheels, self.sc, self.st = w.xg, w.wheels, w.sc, w.st
        self.gnss_a, self.beacon, self.relay, self.tb, self.xb_tb = w.gnss_a, w.beacon, w.relay, w.tb, w.xb_tb
        self.jb = 0
        self.params = scenario.truth_params(self.sc, d) if params is None else _load_params(params, d)
        self.devices = None                      # the magnetic devices (SpacecraftDevices), when served
        if magnetic_devices:
            r_mag = np.random.default_rng(np.random.SeedSequence(self.seed).spawn(8)[7])
            mag, mtq = Magnetometer.from_spacecraft(d, r_mag), Magnetorquers.from_spacecraft(d)
            if mag is not None or mtq is not None:
                self.devices = SpacecraftDevices(self.sc, self.st, magnetometer=mag, magnetorquers=mtq)
        self._mtq_cmd = None                     # MTQ_CMD payload received this cycle
        # the flight world's firmware sends one each cycle: wait for it as for the RW_CMDs (a lost one is asked for
        # again with the tick), so that a lossy link's run stays the clean run's
        self._expect_mtq = world == "flight" and self.devices is not None and self.devices.mtq is not None
        self._mtq_reply = []                     # its answer (MTQ_TLM or NACK), sent in the next burst
        self.n_mtq_cmd = self.refused_mtq_cmd = 0
        self.stkf_x0 = w.stkf_x0.tolist()
        self.k = 0
        self.proc = None
        self.link = None
        self.app = None                          # runtime inproc: the firmware's App in this process
        self._tmp = None
        self._cmd = [None] * N_WHEELS            # RW_CMD payload received this cycle
        self._commanded = [True] * N_WHEELS      # a reply (RW_TLM) is due in the next burst
        self.n_late = 0
        self._late_run = 0                       # consecutive late cycles
        self.missed_rw_cmd = [0] * N_WHEELS
        self.refused_rw_cmd = [0] * N_WHEELS     # RW_CMD with a non-finite torque or an enable other than 0/1
        self.fault_log = []
        self.retries = {"tick_resent": 0, "missing_answered": 0, "packets_resent": 0, "burst_resent": 0,
                        "cycles_retried": 0}
        self._burst_pkts = []                    # (bit, pid, src, payload) of the open cycle's burst
        self._tick_payload = None
        self._reply_s = 0.05                     # recent wall time from ADCS_TICK to the cycle's last reply
        self.last_status = None
        self._cycle_us = [0, 0, 0]               # the firmware's own cycle times (ADCS_STATUS): n, sum, largest
        self._mode = None
        self.mode_changes = []                   # {"t_s", "from", "to", "reason"} per ADCS_STATUS mode change
        self._st_ok_t = 0.0                      # the star tracker's last valid output (truth side)
        self._st_blind_before = 0.0              # and the blind stretch that output ended (s)
        self.st_valid_log = []                   # per cycle: the star tracker's output valid
        self.wheel_rpm_log = []                  # per cycle: the largest |wheel speed| at its end (rpm)
        self._active = set()
        self.wall_s = 0.0
        self.closed = False

    # --- process and link -----------------------------------------------------------------------------
    def _say(self, msg):
        if self.log is not None:
            self.log(msg)

    def config(self):
        """The firmware's configuration (written to its config.json): parameter file, gains, STKF start, and
        the spacecraft file's nominal figures, not the emulated (true) vehicle's, as ground/adcs/body_pointing.py's flight
        software: the wheels' axes, torque limit, friction model and read-out noise, the star tracker's, GNSS's
        and beacon's noise, the APKF's initial 1 sigma, the STKF's P0 and the laser axis."""
        d = self.spacecraft
        w, u, g = d["wheels"], d["uncertainty"], d["gnss"]
        return {"params": self.params, "ts": self.ts, "hold_s": self.hold_s, "satb_gnss": self.satb,
                "stkf_x0": self.stkf_x0, "stkf_P0": list(self.world.stkf_P0_diag), "lag_s": scenario.LAG_S,
                "torque_max": w["torque_limit_nm"],
                "friction": [w["friction_coulomb_nm"], w["friction_viscous_nms_rad"],
                             w["friction_smooth_rpm"] * 2 * np.pi / 60],
                "beacon_sigma_arcsec": self.beacon.sigma / RAD_PER_ARCSEC,
                "gnss_sigma": [g["sigma_position_m"], g["sigma_velocity_m_s"]],
                "wheel_axes": self.wheels.c0.tolist(), "tach_noise_rpm": w["tach_noise_rpm"], "wheels": w,
                "star_tracker_sigma_arcsec": list(d["star_tracker"]["sigma_arcsec"]),
                "apkf_p0": [u["attitude_sigma_deg"], u["rate_sigma_deg_s"], u["disturbance_torque_sigma_nm"]],
                "laser_axis": scenario.laser_axis(d).tolist(),
                "apkf_momentum": self.apkf_momentum, "gmst0_rad": self.world.field.gmst0,
                "isotp_timeout_ms": ISOTP_TIMEOUT_MS, "world": self.world_name, "flight": self.flight,
                "magnetorquers": d["magnetorquers"]}

    def start(self):
        """Spawn the firmware, open the slcan bus, wait for its HELLO, send the first burst."""
        if self.runtime == "inproc":             # the app on this host: the same bytes, no process or wire
            from firmware.adcs.app import App
            from firmware.adcs.lockstep import InProcess
            self.link = InProcess(App(json.loads(json.dumps(self.config()))), N["ADCS"], self.probe)
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
                                      isotp_timeout_s=ISOTP_TIMEOUT_MS / 1000.0)
        if self.runtime == "qemu":               # the ADCS PIL board: its UART is QEMU's pty
            if not os.path.exists(ADCS_IMAGE):
                raise OSError("runtime qemu needs the ADCS PIL image %s (make pil)" % os.path.relpath(ADCS_IMAGE))
            self.proc, self.link = start_board(qemu_command(ADCS_IMAGE, serial="pty", icount=True,
                                                            machine=ADCS_MACHINE),
                                               "import firmware.adcs.pil_main", connect,
                                               first_line=json.dumps(self.config(), separators=(",", ":")),
                                               name="ADCS board")
            path = "QEMU's pty"
        else:
            m, s = os.openpty()
            tty.setraw(s)
            os.set_blocking(m, False)
            path = os.ttyname(s)
            extra = [self.heap_out] if self.heap_out else []
            argv, env = command(self.runtime, MAIN, [m, cfg] + extra, micropython_opts=("-X", "heapsize=64M"))
            try:
                self.proc = FirmwareProcess(argv, env=env, pass_fds=(m,), name="ADCS firmware")
            finally:
                os.close(m)
            try:
                self.link = connect(path)
            finally:
                os.close(s)
        deadline = time.monotonic() + 30.0
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None or self.link.closed:
                err = self._stderr()
                self.close()
                raise OSError("ADCS firmware (%s) did not start: %s" % (self.runtime, err or "no HELLO in 30 s"))
            if any(p[0] == P["HELLO"] for p in self.link.recv(min(left, 0.5))):
                break
        self._say("ADCS firmware up (%s, pid %d), CAN over slcan on %s" % (self.runtime, self.proc.pid, path))
        return self._begin()

    def _begin(self):
        """Faults on the link, the wall clock, the first burst."""
        if self.link_faults is not None:
            from protocol.faults import inject
            self.faults_port = inject(self.link, self.link_faults, clock=lambda: float(self.k))
        self._t_wall = time.perf_counter()
        self._burst()
        return self

    def _has_mtq(self):
        return self.devices is not None and self.devices.mtq is not None

    def _exited(self):
        return self.link.closed or (self.proc is not None and self.proc.poll() is not None)

    def _stderr(self):
        return self.proc.stderr_tail(2000).strip() if self.proc is not None else ""

    def _send(self, pid, src, payload):
        bit = burst_bit(pid, src, payload)      # the firmware's own naming of the burst's packets
        self._burst_pkts.append((bit, pid, src, payload))
        if self.recorded is not None:
            self._rec.append([pid, src, payload.hex()])

    # --- faults ---------------------------------------------------------------------------------------
    def _fault(self, name, t):
        f = self.faults.get(name)
        if f is None:
            on = False
        elif name == "beacon_lost":
            on = t >= f
        elif name == "wheel_silent":
            on = t >= f[1]
        else:
            on = f[0] <= t < f[1]
        if on != (name in self._active):
            (self._active.add if on else self._active.discard)(name)
            what = "%s %s" % (name, "begins" if on else "ends")
            if name == "wheel_silent":
                what += " (wheel %d)" % f[0]
            self.fault_log.append({"t_s": t, "event": what})
            self._say("t = %.0f s: fault %s" % (t, what))
        return on

    # --- the cycle -----------------------------------------------------------------------------------
    def _burst(self):
        """ADCS_TICK(k) naming the burst, then the device replies and sensor outputs at t_k."""
        k, sc = self.k, self.sc
        t = float(k)
        t_ms = int(round(t * 1000))
        self._rec = []
        self._burst_pkts = []
        dead = self.faults["wheel_silent"][0] if self._fault("wheel_silent", t) else -1
        if dead >= 0:
            self.wheels.command(dead, 0.0, False)          # the node is dead: its driver stops, the rotor coasts
        for pid, src, _, payload in self._mtq_reply:       # unnamed packets first (see the module docstring)
            self._send(pid, src, payload)
        self._mtq_reply = []
        if self.devices is not None and self.devices.mag is not None:
            pid, src, _, payload = self.devices.magnetometer(N["ADCS"], t_ms)
            self._send(pid, src, payload)
        speed = self.wheels.read_speed_rpm(sc.omega_rw_rel)
        for i in range(N_WHEELS):
            if i != dead and self._commanded[i]:
                self._send(P["RW_TLM"], RW_NODES[i], core.encode_payload(
                    P["RW_TLM"], speed=float(speed[i]), torque=float(sc.tau_motor[i])))
            self._commanded[i] = False
        qm, ok = self.st.measure(sc.q, sc.omega)
        if self._fault("startracker_blind", t):
            ok = False
        if ok and self.k > 0:
            self._st_blind_before, self._st_ok_t = self.k - self._st_ok_t, float(self.k)
        self.st_valid_log.append(bool(ok))
        if not ok:
            qm = np.array([0.0, 0.0, 0.0, 1.0])
        self._send(P["STARTRACKER"], N["STARTRACKER"], core.encode_payload(
            P["STARTRACKER"], t_ms=t_ms, q0=float(qm[0]), q1=float(qm[1]), q2=float(qm[2]), q3=float(qm[3]),
            valid=int(ok)))
        x = self.xg[k * scenario.WORLD_RATE_HZ].ravel()
        outage = self._fault("gnss_outage", t)
        zg = self.gnss_a.measure(x[0:6])                      # drawn always: streams stay aligned
        if not outage:
            self._send(P["GNSS"], N["GNSS"], _gnss_payload(t_ms, 0, zg))
        if self.relay is not None:
            while self.jb < self.tb.size and self.tb[self.jb] <= t:
                self.relay.sample(self.tb[self.jb], self.xb_tb[self.jb])
                self.jb += 1
            for tm, z in self.relay.due(t):
                if not outage:
                    self._send(P["GNSS"], N["GNSS"], _gnss_payload(int(round(tm * 1000)), 1, z))
        y = self.beacon.measure_dcm(x[0:3], x[6:9], dcm(sc.q))
        lost = self._fault("beacon_lost", t)
        y = y / np.linalg.norm(y)
        self._send(P["BEACON"], N["BEACON"], core.encode_payload(
            P["BEACON"], t_ms=t_ms, ux=float(y[0]), uy=float(y[1]), uz=float(y[2]), valid=0 if lost else 1))
        mask, n_b = 0, 0
        for bit, _, _, _ in self._burst_pkts:
            mask |= bit
            n_b += bit == B_GNSS_B
        self._tick_payload = core.encode_payload(P["ADCS_TICK"], tick=k, t_ms=t_ms, burst=mask, n_gnss_b=n_b)
        self._tick_sent = time.monotonic()
        self._send_burst(None)
        if self.recorded is not None:
            self.recorded.append([k, t_ms, self._rec])

    def _send_burst(self, bits):
        """ADCS_TICK(k) then the burst's packets (``bits`` None), or only the packets of ``bits`` (an answer to
        ADCS_MISSING: the firmware has the cycle open)."""
        if bits is None:
            self.link.send_raw(P["ADCS_TICK"], N["SPACECRAFT"], N["ADCS"], self._tick_payload)
        for bit, pid, src, payload in self._burst_pkts:
            if bits is None or bit & bits:
                self.link.send_raw(pid, src, N["ADCS"], payload)

    def _await(self):
        """RW_CMDs and ADCS_STATUS of tick k (None if late), trying again as the module docstring says."""
        k = self.k
        t0 = self._tick_sent
        deadline = t0 + self.reply_timeout_s
        self._cmd = [None] * N_WHEELS
        self._mtq_cmd = None
        status = None
        heard = False                            # anything of cycle k came back (a reply or ADCS_MISSING)
        try_s = min(TRY_MAX_S, max(TRY_MIN_S, 3.0 * self._reply_s))
        try_end = t0 + try_s
        resent = 0                               # ADCS_TICK(k) sent again so far
        while True:
            now = time.monotonic()
            if status is not None and all(c is not None for c in self._cmd) and (
                    self._mtq_cmd is not None or not self._expect_mtq):
                if not resent:                   # the try's wait follows the clean cycles' reply time
                    self._reply_s = 0.8 * self._reply_s + 0.2 * (now - t0)
                return status
            if now >= deadline:
                return status
            if now >= try_end:                   # a try without the cycle's replies: the tick again
                resent += 1
                self.retries["tick_resent"] += 1
                self.retries["cycles_retried"] += resent == 1
                if heard:
                    self.link.send_raw(P["ADCS_TICK"], N["SPACECRAFT"], N["ADCS"], self._tick_payload)
                else:                            # the tick or the whole burst may be lost: all of it again
                    self.retries["burst_resent"] += 1
                    self._send_burst(None)
                try_s = RETRY_S if resent == 1 else min(TRY_MAX_S, TRY_BACKOFF * try_s)
                try_end = time.monotonic() + try_s
                continue
            for pid, src, dst, seq, payload in self.link.recv(min(deadline, try_end) - now):
                if pid == P["RW_CMD"] and dst in RW_NODES:
                    if payload[-1] == k & 0xFF:          # not a late copy of the previous cycle's
                        self._cmd[RW_NODES.index(dst)] = payload
                        heard = True
                elif pid == P["MTQ_CMD"] and dst == N["MTQ"] and self._has_mtq():
                    if len(payload) == core.PACKET[pid].size and payload[-1] == k & 0xFF:   # not a late copy
                        self._mtq_cmd = payload
                        heard = True
                elif pid == P["ADCS_STATUS"]:
                    d = core.payload_dict(pid, payload)
                    if d["tick"] == k:
                        status, heard = d, True
                elif pid == P["ADCS_MISSING"]:
                    d = core.payload_dict(pid, payload)
                    if d["tick"] == k and status is None:
                        heard = True
                        self.retries["missing_answered"] += 1
                        n = sum(1 for b, _, _, _ in self._burst_pkts if b & d["missing"])
                        self.retries["packets_resent"] += n
                        self._send_burst(d["missing"])
            if self._exited():
                raise OSError("ADCS firmware exited at t = %d s (code %s): %s"
                              % (k, self.proc.poll() if self.proc else None, self._stderr() or "no message"))

    def cycle(self):
        """One 1 s flight-software cycle = 10 dynamics steps of 0.1 s (see the module docstring)."""
        if self.link is None:
            raise OSError("session not started (call start())")
        if self.k >= self.K:
            raise ValueError("the session's %d s are done" % self.K)
        status = self._await()
        t = float(self.k)
        dead = self.faults["wheel_silent"][0] if "wheel_silent" in self._active else -1
        if status is None:
            self.n_late += 1
            self._late_run += 1
            if self._late_run >= MAX_LATE_CYCLES:     # alive but hung: its pty would fill and block the bursts
                raise OSError("ADCS firmware gave no ADCS_STATUS for %d cycles in a row (%g s each) at t = %d s: "
                              "hung? %s" % (self._late_run, self.reply_timeout_s, self.k, self._stderr()))
            self._say("t = %.0f s: no ADCS_STATUS within %.0f s (late cycle; wheels hold)" % (t, self.reply_timeout_s))
            status = {}
        else:
            self._late_run = 0
        applied = np.full(N_WHEELS, np.nan)
        for i in range(N_WHEELS):
            pl = self._cmd[i]
            if i == dead:
                continue
            if pl is None:
                self.missed_rw_cmd[i] += 1
                continue
            d = core.payload_dict(P["RW_CMD"], pl)
            if np.isfinite(d["torque"]) and d["enable"] <= 1:
                self.wheels.command(i, d["torque"], bool(d["enable"]))
                applied[i] = d["torque"] if d["enable"] else 0.0
            else:                                  # the wheel keeps its last command; counted, not silent
                self.refused_rw_cmd[i] += 1
            self._commanded[i] = True
        if self._mtq_cmd is not None and self._has_mtq():
            self._mtq_reply = self.devices.handle(P["MTQ_CMD"], N["ADCS"], N["MTQ"], self._mtq_cmd)
            ok = self._mtq_reply[0][0] == P["MTQ_TLM"]
            self.n_mtq_cmd += ok
            self.refused_mtq_cmd += not ok
        out = {k: np.zeros((10, n)) for k, n in (("q", 4), ("w", 3), ("w_rel", 4), ("ra", 3), ("va", 3), ("rb", 3),
                                                 ("vb", 3))}
        out["t"] = np.zeros(10)
        for j in range(10):
            self.sc.step()
            g = self.xg[(self.k * 10 + j + 1) * (scenario.WORLD_RATE_HZ // 10)]
            out["t"][j] = self.sc.t
            out["q"][j], out["w"][j], out["w_rel"][j] = self.sc.q, self.sc.omega, self.sc.omega_rw_rel
            out["ra"][j], out["va"][j], out["rb"][j], out["vb"][j] = g[0, 0:3], g[0, 3:6], g[1, 0:3], g[1, 3:6]
        if not np.all(np.isfinite(self.sc.x)):
            raise FloatingPointError("truth diverged at t = %.1f s" % self.sc.t)
        self.wheel_rpm_log.append(float(np.abs(self.sc.omega_rw_rel).max() * 60 / (2 * np.pi)))
        est = self._on_status(status, t) if status else {}
        out["status"], out["est"], out["rw_cmd"] = status, est, applied
        self.k += 1
        if self.k < self.K:
            self._burst()
        self.wall_s = time.perf_counter() - self._t_wall
        return out

    def _on_status(self, status, t):
        """Take cycle k's ADCS_STATUS (named mode and stale sensors, the firmware's cycle time, a mode change
        logged with its reason); returns the flight software's estimates it carries."""
        status["adcs_mode_name"] = MODE_NAME.get(status["adcs_mode"], "?")
        status["stale_names"] = [n for n, b in STALE_BITS if status["stale"] >> b & 1]
        self.last_status = status
        if status["tick"] > 0:               # the first cycle starts the filters
            c = self._cycle_us
            c[0] += 1
            c[1] += status["cycle_us"]
            c[2] = max(c[2], status["cycle_us"])
        if status["adcs_mode_name"] != self._mode:
            if self._mode is not None:
                self.mode_changes.append({"t_s": t, "from": self._mode, "to": status["adcs_mode_name"],
                                          "reason": self._why(self._mode, status)})
            self.fault_log.append({"t_s": t, "event": "ADCS mode %s" % status["adcs_mode_name"]})
            self._say("t = %.0f s: ADCS mode %s -> %s%s" % (t, self._mode, status["adcs_mode_name"],
                                                              (" (stale: %s)" % ", ".join(status["stale_names"]))
                                                              if status["stale_names"] else ""))
            self._mode = status["adcs_mode_name"]
        return {"q": np.array([status[n] for n in ("q0", "q1", "q2", "q3")]),
                "w": np.array([status[n] for n in ("wx", "wy", "wz")]),
                "ra": np.array([status[n] for n in ("rax", "ray", "raz")]),
                "rb": np.array([status[n] for n in ("rbx", "rby", "rbz")]),
                "att_sigma_rad": status["att_sigma"], "t": t}

    def blind_share(self, t_from):
        """The share of cycles from ``t_from`` (s) on whose star-tracker output was not valid (None if none)."""
        v = self.st_valid_log[int(np.ceil(t_from)):]
        return None if not v else 1.0 - sum(v) / len(v)

    def wheel_rpm_max(self, t_from=0.0):
        """The largest |wheel speed| (rpm) at the ends of the cycles from ``t_from`` (s) on (None if none)."""
        v = self.wheel_rpm_log[int(np.ceil(t_from)):]
        return max(v) if v else None

    def _why(self, before, status):
        """The reason of a mode change, from the transition and what this side knows (the firmware reports the
        mode; ADCS_STATUS has no room for a reason)."""
        to = status["adcs_mode_name"]
        if to == "DEGRADED":
            return "a wheel failed or a sensor stale (stale: %s; wheels failed bits %d)" % (
                ", ".join(status["stale_names"]) or "none", status["wheels_failed"])
        if before == "DEGRADED":
            return "the wheels and sensors are back"
        if to == "HOLD":
            return "the APKF started" if before in (None, "INIT") else "rate damping (no command at this geometry)"
        if to == "SLEW":
            return ("the hold is over: the slew to the partner's line of sight" if before == "HOLD" else
                    "the estimate is off the command beyond the re-slew limit" if before == "POINT" else
                    "the star tracker is back after %d s blind, the estimate off the command: a new slew"
                    % self._st_blind_before if before == "ACQUIRE" else "slew")
        if to == "ACQUIRE":
            return "the slew's reference reached the command; waiting for the star tracker"
        if to == "POINT":
            return ("the star tracker is back after %d s blind, the estimate on the command"
                    % self._st_blind_before if before == "ACQUIRE" else "pointing")
        return to

    def board(self):
        """A qemu run's board and its instructions per 1 Hz cycle (None for the other runtimes): under ``-icount
        shift=0`` one instruction is one virtual ns, so the firmware's own cycle time (ADCS_STATUS.cycle_us, its
        timer: the filters, the control law and the commands; the packets' decoding outside it) in us is
        thousands of instructions."""
        if self.runtime != "qemu":
            return None
        n, total, worst = self._cycle_us
        return {"target": dict(BOARD), "instructions_per_cycle": {
            "what": "the firmware's own cycle (ADCS_STATUS.cycle_us: filters, control law, commands) under -icount "
                    "shift=0, one instruction a virtual ns; the first cycle (the filters' start) left out",
            "n": n, "mean": 1000.0 * total / n if n else None, "max": 1000.0 * worst if n else None}}

    def summary(self):
        st = self.last_status or {}
        return {"runtime": self.runtime, "satb_gnss": self.satb, "seed": self.seed, "ts_s": self.ts,
                "spacecraft": self.spacecraft["name"],
                "cycles": self.k, "virtual_s": float(self.k), "wall_s": self.wall_s,
                "speed_x_realtime": (self.k / self.wall_s) if self.wall_s > 0 else None,
                "late_cycles": self.n_late, "missed_rw_cmd": list(self.missed_rw_cmd),
                "refused_rw_cmd": list(self.refused_rw_cmd),
                "magnetic_devices": None if self.devices is None else {
                    "magnetometer": self.devices.mag is not None, "magnetorquers": self._has_mtq(),
                    "mtq_cmd": self.n_mtq_cmd, "refused_mtq_cmd": self.refused_mtq_cmd},
                "firmware_missed": {"rw": [st.get("miss_rw%d" % i) for i in range(N_WHEELS)],
                                    "startracker": st.get("miss_st"), "gnss": st.get("miss_gnss"),
                                    "beacon": st.get("miss_beacon"), "st_invalid": st.get("n_st_invalid"),
                                    "beacon_invalid": st.get("n_beacon_invalid"), "gnss_b_fused": st.get("n_gnss_b"),
                                    "stkf_refused": st.get("n_refused"),
                                    "rx_drops": st.get("n_rx_drop")},
                "wheels_failed": st.get("wheels_failed"), "last_mode": st.get("adcs_mode_name"),
                "link": self.link.counters() if self.link is not None else {},
                "link_faults": self.link_faults.as_dict() if self.link_faults is not None else None,
                "retries": dict(self.retries),
                "faults": self.faults, "fault_log": list(self.fault_log), "world": self.world_name,
                "mode_changes": list(self.mode_changes), "max_wheel_speed_rpm": self.wheel_rpm_max(),
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




B_GNSS_B = 1 << dict(table.ADCS_STALE)["GNSS_B"]


def _gnss_payload(t_ms, sat, z):
    """GNSS payload of a fix z = (x, y, z m, vx, vy, vz m/s): raw = round(value / the field's scale in the table)."""
    scale = core.field_scales("GNSS")
    raw = dict((n, int(round(z[i] * (1.0 / scale[n])))) for i, n in enumerate(("x", "y", "z", "vx", "vy", "vz")))
    return core.encode_payload(P["GNSS"], raw, t_ms=t_ms & 0xFFFFFFFF, sat=sat)


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
