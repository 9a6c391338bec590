"""The spacecraft's side of the ADCS's CAN bus: each cycle's burst (ADCS_TICK naming the device replies and sensor
outputs at t_k) and the ADCS's commands applied to the wheels and magnetorquers, with the device faults on their
schedule. ``emulator.adcs_session.AdcsSession`` carries it over the link (its module docstring: the lockstep, the
faults, the magnetic devices). The magnetic devices' faults (the flight world's): ``magnetometer_silent`` t0, from t0
no MAGNETOMETER packet; ``magnetorquer_dead`` [i, t0], from t0 rod i's driver is dead: the rod gives no dipole and
MTQ_TLM names it in ``silent`` (``devices.SpacecraftDevices.rods_dead``)."""

import numbers

import numpy as np

from emulator.occultation import occulted
from emulator.spacecraft import scenario
from emulator.spacecraft.dynamics import dcm
from emulator.spacecraft.wheels import N_WHEELS
from firmware.adcs.health import MAG_SILENT, N_RODS as _FW_RODS
from firmware.adcs.lockstep import burst_bit
from protocol import core, table
from protocol.spacecraft import num_text, value_text

FAULTS = ("wheel_silent", "startracker_blind", "gnss_outage", "beacon_lost", "magnetometer_silent",
          "magnetorquer_dead")
P = core.PACKET_ID
N = core.NODE
RW_NODES = tuple(N["RW%d" % i] for i in range(N_WHEELS))
B_GNSS_B = 1 << dict(table.ADCS_STALE)["GNSS_B"]


class Faults(dict):
    """A faults dict that knows where each entry was given (``sources``: key -> e.g. "--faults faults.json" or
    "--beacon-lost"), so that ``check_faults`` names it in its messages."""

    def __init__(self, entries, sources):
        dict.__init__(self, entries)
        self.sources = dict(sources)


_WINDOW = "[t0 s, t1 s], 0 <= t0 < t1"
_EXPECTED = {"wheel_silent": "[wheel 0-3, t0 s >= 0]", "startracker_blind": _WINDOW, "gnss_outage": _WINDOW,
             "beacon_lost": "t0 s >= 0", "magnetometer_silent": "t0 s >= 0",
             "magnetorquer_dead": "[rod 0-2, t0 s >= 0]"}
N_RODS = _FW_RODS                               # MTQ_TLM's bits name three rods
_UNIT = {"wheel_silent": ("wheel", N_WHEELS), "magnetorquer_dead": ("rod", N_RODS)}     # [unit, t0] faults
_START = ("beacon_lost", "magnetometer_silent")                                          # t0 faults


def _real(v):
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def _seconds(k, v, x):
    """``x``, an element of fault ``k``'s value ``v`` (or ``v`` itself), as finite seconds >= 0 (a float);
    ValueError naming the key, the value and the element otherwise."""
    what = '"%s": %s' % (k, value_text(v))
    if x is not v:
        what += ": " + value_text(x)
    if not _real(x):
        raise ValueError("%s is not a number (seconds)" % what)
    try:
        t = float(x)
    except OverflowError:                       # an integer beyond any float
        t = float("inf")
    if not (np.isfinite(t) and t >= 0):
        raise ValueError("%s is out of range (expected %s, finite)" % (what, _EXPECTED[k]))
    return t


def _fault(k, v):
    """(fault ``k``'s value ``v`` normalised, its start t0 in s); ValueError naming the key and the value."""
    if k in _START:
        t0 = _seconds(k, v, v)
        return t0, t0
    if not isinstance(v, (list, tuple, np.ndarray)) or len(v) != 2:        # "12" would read as [1, 2]
        raise ValueError('"%s": %s: expected %s' % (k, value_text(v), _EXPECTED[k]))
    if k in _UNIT:
        i, (unit, n) = v[0], _UNIT[k]
        if not _real(i):
            raise ValueError('"%s": %s: %s is not a number (the %s, 0-%d)'
                             % (k, value_text(v), value_text(i), unit, n - 1))
        if i not in range(n):
            raise ValueError('"%s": %s: the %s must be 0 to %d (expected %s)'
                             % (k, value_text(v), unit, n - 1, _EXPECTED[k]))
        t0 = _seconds(k, v, v[1])
        return [int(i), t0], t0
    t0, t1 = _seconds(k, v, v[0]), _seconds(k, v, v[1])
    if not t0 < t1:
        raise ValueError('"%s": %s: expected %s' % (k, value_text(v), _EXPECTED[k]))
    return [t0, t1], t0


def check_faults(faults, duration_s):
    """Validate the faults dict (``AdcsSession``'s module docstring); returns a normalised copy (a plain dict).
    ValueError naming the key and its value as JSON writes them (``"beacon_lost": "3" is not a number
    (seconds)``): a string, true/false or null where a number is due, a number out of range (an integer
    beyond any float included), an unknown key, a fault that starts at or after ``duration_s``. With a
    ``Faults`` dict the message begins with where the entry was given."""
    if faults is None:
        return {}
    if not isinstance(faults, dict):
        raise ValueError("faults must be an object with keys among %s, got %s"
                         % (", ".join(FAULTS), value_text(faults, 40)))
    sources = getattr(faults, "sources", {})
    out = {}
    for k, v in faults.items():
        where = "%s: " % sources[k] if k in sources else ""
        if k not in FAULTS:
            raise ValueError("%sunknown fault %s (known: %s)" % (where, value_text(k, 40), ", ".join(FAULTS)))
        try:
            out[k], t0 = _fault(k, v)
        except ValueError as exc:
            raise ValueError(where + str(exc)) from None
        if t0 >= duration_s:
            raise ValueError('%s"%s" starts at %s s, not before the run\'s end (%g s): it would never happen'
                             % (where, k, num_text(t0), duration_s))
    return out


def magnetic_events(before, now, t):
    """The health events [{"t_s", "event", "reason"}] of ADCS_STATUS.magnetic_failed going from ``before`` to
    ``now`` (bits 0-2 rods out of the unloading, bit 3 the magnetometer silent: ``firmware.adcs.health``) at t."""
    out = []
    for i in range(N_RODS):
        b = 1 << i
        if (before ^ now) & b:
            out.append({"t_s": t, "event": "rod %d %s the unloading" % (i, "out of" if now & b else "back in"),
                        "reason": "its driver silent in 3 MTQ_TLM in a row: the other rods' least-squares torque"
                        if now & b else "its driver answers again"})
    if (before ^ now) & MAG_SILENT:
        out.append({"t_s": t, "event": "magnetometer %s" % ("silent" if now & MAG_SILENT else "back"),
                    "reason": "no valid reading 3 cycles in a row: the unloading goes on with the onboard field "
                              "model (the STKF's position, the APKF's attitude), its only field; the model check "
                              "pauses" if now & MAG_SILENT else "a valid reading again"})
    return out


def gnss_payload(t_ms, sat, z):
    """GNSS payload of a fix z = (x, y, z m, vx, vy, vz m/s): raw = round(value / the field's scale in the table)."""
    scale = core.field_scales("GNSS")
    raw = dict((n, int(round(z[i] * (1.0 / scale[n])))) for i, n in enumerate(("x", "y", "z", "vx", "vy", "vz")))
    return core.encode_payload(P["GNSS"], raw, t_ms=t_ms & 0xFFFFFFFF, sat=sat)


class FaultSchedule:
    """The device faults (``check_faults``'s dict) by time: ``on(name, t)`` says whether one is on at t (s), and
    logs each begin and end (``log``: {"t_s", "event"}; ``say(msg)`` told too)."""

    def __init__(self, faults, say):
        self.faults = faults
        self.active = set()
        self.log = []
        self.say = say

    def on(self, name, t):
        f = self.faults.get(name)
        if f is None:
            on = False
        elif name in _START:
            on = t >= f
        elif name in _UNIT:
            on = t >= f[1]
        else:
            on = f[0] <= t < f[1]
        if on != (name in self.active):
            (self.active.add if on else self.active.discard)(name)
            what = "%s %s" % (name, "begins" if on else "ends")
            if name in _UNIT:
                what += " (%s %d)" % (_UNIT[name][0], f[0])
            self.log.append({"t_s": t, "event": what})
            self.say("t = %.0f s: fault %s" % (t, what))
        return on

    def dead_wheel(self):
        """The wheel whose node is dead (-1: none)."""
        return self.faults["wheel_silent"][0] if "wheel_silent" in self.active else -1


class SpacecraftBus:
    """The devices of the world ``world`` (``scenario.pointing_world``) on the bus: ``burst(k)`` the packets of
    cycle k, ``apply(cmds, mtq_cmd)`` the cycle's RW_CMD payloads (one per wheel, None: missed) and MTQ_CMD.
    ``devices``: the magnetic devices (``SpacecraftDevices``) or None; ``record``: keep every burst's packets
    (``recorded``: per tick [tick, t_ms, [[pid, src, payload hex], ...]])."""

    def __init__(self, world, devices, faults, say, record=False):
        self.w, self.sc, self.wheels, self.xg = world, world.sc, world.wheels, world.xg
        self.devices = devices
        self.faults = faults
        for k, what in (("magnetometer_silent", "a magnetometer"), ("magnetorquer_dead", "magnetorquers")):
            have = devices is not None and (devices.mag if k == "magnetometer_silent" else devices.mtq) is not None
            if k in faults.faults and not have:
                raise ValueError("fault \"%s\": no %s on this world's bus (the flight world's magnetic devices, "
                                 "from the spacecraft file)" % (k, what))
        self.jb = 0                              # SatB's next fix time (world.tb) to sample
        self.commanded = [True] * N_WHEELS       # a reply (RW_TLM) is due in the next burst
        self.missed_rw_cmd = [0] * N_WHEELS
        self.refused_rw_cmd = [0] * N_WHEELS     # RW_CMD with a non-finite torque or an enable other than 0/1
        self.n_mtq_cmd = self.refused_mtq_cmd = 0
        self.mtq_reply = []                      # the MTQ_CMD's answer (MTQ_TLM or NACK), sent in the next burst
        self.st_ok_t = 0.0                       # the star tracker's last valid output (truth side)
        self.st_blind_before = 0.0               # and the blind stretch that output ended (s)
        self.st_valid_log = []                   # per cycle: the star tracker's output valid
        self.beacon_occulted = 0                 # cycles the Earth hid the partner from the beacon camera
        g = self.xg[::scenario.WORLD_RATE_HZ]
        self.hidden = occulted(g[:, 0, 0:3], g[:, 1, 0:3])    # per whole second: the Earth between the two
        self.recorded = [] if record else None
        self._rec = []
        self.pkts = []                           # (bit, pid, src, payload) of the open cycle's burst
        self.tick_payload = None

    def has_mtq(self):
        return self.devices is not None and self.devices.mtq is not None

    def _send(self, pid, src, payload):
        bit = burst_bit(pid, src, payload)      # the firmware's own naming of the burst's packets
        self.pkts.append((bit, pid, src, payload))
        if self.recorded is not None:
            self._rec.append([pid, src, payload.hex()])

    def burst(self, k):
        """ADCS_TICK(k) naming the burst (``tick_payload``), then the device replies and sensor outputs at t_k
        (``pkts``)."""
        sc = self.sc
        t = float(k)
        t_ms = int(round(t * 1000))
        self._rec = []
        self.pkts = []
        dead = self.faults.faults["wheel_silent"][0] if self.faults.on("wheel_silent", t) else -1
        if dead >= 0:
            self.wheels.command(dead, 0.0, False)          # the node is dead: its driver stops, the rotor coasts
        for pid, src, _, payload in self.mtq_reply:        # unnamed packets first (AdcsSession's docstring)
            self._send(pid, src, payload)
        self.mtq_reply = []
        if self.has_mtq():
            self.devices.rods_dead(1 << self.faults.faults["magnetorquer_dead"][0]
                                   if self.faults.on("magnetorquer_dead", t) else 0)
        if self.devices is not None and self.devices.mag is not None and not self.faults.on("magnetometer_silent", t):
            pid, src, _, payload = self.devices.magnetometer(N["ADCS"], t_ms)
            self._send(pid, src, payload)
        speed = self.wheels.read_speed_rpm(sc.omega_rw_rel)
        for i in range(N_WHEELS):
            if i != dead and self.commanded[i]:
                self._send(P["RW_TLM"], RW_NODES[i], core.encode_payload(
                    P["RW_TLM"], speed=float(speed[i]), torque=float(sc.tau_motor[i])))
            self.commanded[i] = False
        self._star_tracker(k, t, t_ms)
        x = self.xg[k * scenario.WORLD_RATE_HZ].ravel()
        self._navigation(x, t, t_ms, bool(self.hidden[k]))
        mask, n_b = 0, 0
        for bit, _, _, _ in self.pkts:
            mask |= bit
            n_b += bit == B_GNSS_B
        self.tick_payload = core.encode_payload(P["ADCS_TICK"], tick=k, t_ms=t_ms, burst=mask, n_gnss_b=n_b)
        if self.recorded is not None:
            self.recorded.append([k, t_ms, self._rec])

    def _star_tracker(self, k, t, t_ms):
        sc = self.sc
        qm, ok = self.w.st.measure(sc.q, sc.omega)
        if self.faults.on("startracker_blind", t):
            ok = False
        if ok and k > 0:
            self.st_blind_before, self.st_ok_t = k - self.st_ok_t, float(k)
        self.st_valid_log.append(bool(ok))
        if not ok:
            qm = np.array([0.0, 0.0, 0.0, 1.0])
        self._send(P["STARTRACKER"], N["STARTRACKER"], core.encode_payload(
            P["STARTRACKER"], t_ms=t_ms, q0=float(qm[0]), q1=float(qm[1]), q2=float(qm[2]), q3=float(qm[3]),
            valid=int(ok)))

    def _navigation(self, x, t, t_ms, hidden):
        """SatA's GNSS, SatB's relayed fixes due at t, the beacon; x the orbits' truth at t, ``hidden`` whether the
        Earth (and its air) is between the two then (no beacon)."""
        w = self.w
        outage = self.faults.on("gnss_outage", t)
        zg = w.gnss_a.measure(x[0:6])                      # drawn always: streams stay aligned
        if not outage:
            self._send(P["GNSS"], N["GNSS"], gnss_payload(t_ms, 0, zg))
        if w.relay is not None:
            while self.jb < w.tb.size and w.tb[self.jb] <= t:
                w.relay.sample(w.tb[self.jb], w.xb_tb[self.jb])
                self.jb += 1
            for tm, z in w.relay.due(t):
                if not outage:
                    self._send(P["GNSS"], N["GNSS"], gnss_payload(int(round(tm * 1000)), 1, z))
        y = w.beacon.measure_dcm(x[0:3], x[6:9], dcm(self.sc.q))
        self.beacon_occulted += hidden
        lost = hidden or self.faults.on("beacon_lost", t)
        y = y / np.linalg.norm(y)
        self._send(P["BEACON"], N["BEACON"], core.encode_payload(
            P["BEACON"], t_ms=t_ms, ux=float(y[0]), uy=float(y[1]), uz=float(y[2]), valid=0 if lost else 1))

    def apply(self, cmds, mtq_cmd):
        """The cycle's RW_CMD payloads (per wheel, None: not received) and MTQ_CMD (None: none) applied; returns
        the torques applied (N m, NaN where none: a dead or silent wheel keeps its last command)."""
        dead = self.faults.dead_wheel()
        applied = np.full(N_WHEELS, np.nan)
        for i in range(N_WHEELS):
            pl = cmds[i]
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
            self.commanded[i] = True
        if mtq_cmd is not None and self.has_mtq():
            self.mtq_reply = self.devices.handle(P["MTQ_CMD"], N["ADCS"], N["MTQ"], mtq_cmd)
            ok = self.mtq_reply[0][0] == P["MTQ_TLM"]
            self.n_mtq_cmd += ok
            self.refused_mtq_cmd += not ok
        return applied
