"""The bench as the ground tools see it: a lockstep emulator, the controller firmware, and packets between.

``Rig`` owns an ``emulator.bench.Bench`` and its ``Lockstep`` clock. The controller firmware runs
in-process (``InprocController``: the same ``on_tick``/``handle`` a link would reach) or in another process
behind a protocol link (``ground.runtime``: CPython or MicroPython, serial pty or CAN slcan), seen through
``RemoteController``. Either way the ground only sends packets to the CONTROLLER node and reads the replies and
CTRL_STATUS telemetry from ``inbox``; calibration and HIL code therefore takes the same path on every runtime.
"""

import time
from collections import deque

import numpy as np

from emulator.bench import Bench
from emulator.lockstep import HoldPlayer, Lockstep
from protocol import core, table

GROUND = core.NODE["GROUND"]
CONTROLLER = core.NODE["CONTROLLER"]
PLAYER = core.NODE["PLAYER"]
PFSM_V_PER_ARCSEC = 0.012343     # Eq. 7.8
P_STATUS = core.PACKET_ID["CTRL_STATUS"]
P_ACK = core.PACKET_ID["ACK"]
P_NACK = core.PACKET_ID["NACK"]
ERROR_NAME = {e[1]: e[0] for e in table.ERRORS}
CODES_PER_VOLT = 13107.2     # AD5664R tilt code per FSM tilt volt (firmware.ad5664r)
AD660_CODES_PER_VOLT = 65536 / 20.0


class InprocController:
    """The firmware controller object driven directly: ``on_tick`` for the clock, ``send_ground`` for packets.

    Telemetry: every ``decim`` ticks a CTRL_STATUS payload (``status_payload``) goes to ``inbox`` as a
    packet tuple (pid, src, dst, seq, payload), as firmware.main would send it on a link.
    """

    def __init__(self, controller):
        self.ctrl = controller
        self.inbox = deque()
        self._seq = 0
        self._on_tick = controller.on_tick      # bound once: this runs every tick
        self._status_due = controller.status_due_at

    def on_tick(self, tick, t_us, vx, vy, vs):
        words = self._on_tick(tick, t_us, vx, vy, vs)
        if self._status_due(tick):
            self._push(P_STATUS, self.ctrl.status_payload(tick))
        return words

    def poll(self, timeout_s):
        """Replies are immediate in-process: nothing to wait for."""

    def _push(self, pid, payload):
        self.inbox.append((pid, CONTROLLER, GROUND, self._seq & 0xFF, payload))
        self._seq += 1

    def send_ground(self, pid, payload, seq, dst=CONTROLLER):
        if dst != CONTROLLER:
            raise ValueError("in-process endpoint reaches the CONTROLLER only, not node 0x%02x" % dst)
        for rpid, _dst, rpayload in self.ctrl.handle(pid, GROUND, seq, payload):
            self._push(rpid, rpayload)
        return seq & 0xFF

    def counters(self):
        return {}


def decode_status(payload):
    """CTRL_STATUS as a dict in physical units: ratios, volts, applied tilt codes."""
    d = core.payload_dict(P_STATUS, payload)
    x_code = (d["code_xp"] - d["code_xn"]) / 2.0
    y_code = (d["code_yp"] - d["code_yn"]) / 2.0
    return {"tick": d["tick"], "mode": d["mode"], "beam": bool(d["flags"] & 1), "sat": bool(d["flags"] & 2),
            "rx": d["rx"] / 32768.0, "ry": d["ry"] / 32768.0, "vs": d["vs"],
            "v_cmd": (d["vx"] * 1e-6, d["vy"] * 1e-6),
            "v_applied": (x_code / CODES_PER_VOLT, y_code / CODES_PER_VOLT),
            "n_lost": d["n_lost"], "n_sat": d["n_sat"], "n_unknown": d["n_unknown"],
            "why": d["why"], "n_dup": d["n_dup"], "n_gap": d["n_gap"], "n_rx_drop": d["n_rx_drop"],
            "sat_run": d["sat_run"], "sat_last": d["sat_last"], "n_sat_episodes": d["n_sat_episodes"]}


class CommandError(ValueError):
    """The controller refused a command (NACK)."""


class NoAnswer(OSError):
    """A command went unanswered through every retry: the link is down."""


class Rig:
    """Bench + clock + controller endpoint. ``endpoint`` has ``on_tick``, ``inbox`` and ``send_ground``.

    ``pfsm_v(x, y)`` holds the P-FSM at the given volts (calibration); ``lockstep.player`` may be replaced
    by a distfile player for a HIL run.
    """

    def __init__(self, endpoint, config=None, seed=0, rate_hz=637.8, pfsm_hz=10600.0, block_ticks=256,
                 deadline_s=1.0):
        self.bench = Bench(config, seed=seed, rate_hz=rate_hz)
        self.endpoint = endpoint
        self.hold = HoldPlayer()
        self.lockstep = Lockstep(self.bench, endpoint, self.hold, rate_hz=rate_hz, pfsm_hz=pfsm_hz,
                                 block_ticks=block_ticks, deadline_s=deadline_s)
        self.rate_hz = rate_hz
        self.config = self.bench.config
        self._seq = 0
        self.status = []          # decoded CTRL_STATUS since the last take_status()
        self.replies = deque()    # other packets (ACK, NACK, ...) not yet consumed
        self.n_status_total = 0
        self.n_cmd_retries = 0
        self.n_stale_replies = 0
        self.last_status = None   # the latest CTRL_STATUS (decoded)
        self.mode_log = []        # (tick, mode, why) at each mode change seen in CTRL_STATUS

    def elapsed_s(self):
        """Virtual time run so far."""
        return self.lockstep.tick / self.rate_hz

    # --- P-FSM -------------------------------------------------------------------------------------
    def pfsm_v(self, vx, vy):
        """Hold the P-FSM at (vx, vy) volts through its AD660 codes (offset binary, 0x8000 = 0 V)."""
        for v in (vx, vy):
            if not -10.0 <= v <= 10.0:
                raise ValueError("P-FSM voltage %r outside the AD660 range +-10 V" % v)
        self.hold.x_code = min(0xFFFF, max(0, int(round(0x8000 + vx * AD660_CODES_PER_VOLT))))
        self.hold.y_code = min(0xFFFF, max(0, int(round(0x8000 + vy * AD660_CODES_PER_VOLT))))

    # --- clock -------------------------------------------------------------------------------------
    def run(self, n_ticks, progress=None):
        try:
            out = self.lockstep.run(n_ticks=n_ticks, progress=progress)
        finally:
            self._drain()
        return out

    def _drain(self):
        inbox = self.endpoint.inbox
        replies = self.replies
        while inbox:
            pkt = inbox.popleft()
            if pkt[0] == P_STATUS:
                try:
                    st = decode_status(pkt[4])
                except ValueError:
                    continue
                self.n_status_total += 1
                self.status.append(st)
                if self.last_status is None or st["mode"] != self.last_status["mode"]:
                    self.mode_log.append((st["tick"], st["mode"], st["why"]))
                self.last_status = st
            else:
                replies.append(pkt)

    def take_status(self):
        s, self.status = self.status, []
        return s

    keepalive_s = 1.0         # the longest the ground lets the controller's link go quiet while it waits (s)
    _t_alive = float("-inf")

    def keepalive(self):
        """Tell the controller the ground is still there while the ground waits on something else (the ADCS
        process, a file): an ACK of its telemetry, at most every ``keepalive_s`` s of wall time. Any packet but a
        TICK restarts the controller's link-silence count, and an ACK changes nothing else, so the host's own
        waits never read as a silent ground link (SAFE, LINK_SILENT), however slow the host."""
        now = time.perf_counter()
        if now - self._t_alive >= self.keepalive_s:
            self._t_alive = now
            self.endpoint.send_ground(P_ACK, bytes((P_STATUS, 0)), self._seq & 0xFF)
            self._seq += 1

    # --- commands ---------------------------------------------------------------------------------
    cmd_timeout_s = 0.05      # wait for ACK/NACK before resending a command
    cmd_tries = 40            # sends of one command before the link is declared down (NoAnswer)

    def command(self, name, dst=CONTROLLER, **fields):
        """Send a command (to the controller by default) and wait for its ACK, resending it every
        ``cmd_timeout_s`` until ACK or NACK. A reply counts when its ref_seq is one of this command's copies
        (the endpoint's ``send_ground`` returns the sequence number sent; None on CAN, which has none: then by
        packet id): a late second ACK of an earlier command is dropped (``n_stale_replies``), not taken for
        this one, whose frame may have been lost. The clock does not advance meanwhile, so a command takes effect
        before the same tick however many tries it took. Commands are idempotent (the firmware's contract), so
        a resend whose first copy was executed does no harm. A NACK raises CommandError naming the error code;
        ``cmd_tries`` unanswered sends raise NoAnswer."""
        pid = core.PACKET_ID[name]
        payload = core.encode_payload(pid, fields)
        clock = time.perf_counter
        seqs = set()              # the sequence numbers this command's copies went out with
        by_seq = True
        for attempt in range(self.cmd_tries):
            if attempt:
                self.n_cmd_retries += 1
            seq = self._seq & 0xFF
            self._seq += 1
            sent = self.endpoint.send_ground(pid, payload, seq, dst)
            if sent is None:      # a link without sequence numbers (CAN): replies match by packet id only
                by_seq = False
            else:
                seqs.add(sent & 0xFF)
            end = clock() + self.cmd_timeout_s
            while True:
                self._drain()
                while self.replies:
                    rpid, src, _dst, _rseq, rp = self.replies.popleft()
                    if (rpid == P_ACK or rpid == P_NACK) and by_seq and rp[0] == pid and rp[1] not in seqs:
                        self.n_stale_replies += 1     # the answer to an earlier copy of an earlier command
                        continue
                    if rpid == P_ACK and rp[0] == pid:
                        return
                    if rpid == P_NACK and rp[0] == pid:
                        code = rp[2]
                        raise CommandError("%s refused %s %s: %s" % (core.NODE_NAME.get(src, src), name,
                                                                     fields, ERROR_NAME.get(code, code)))
                left = end - clock()
                if left <= 0:
                    break
                self.endpoint.poll(left)
        raise NoAnswer("no answer to %s after %d tries over %.1f s" % (name, self.cmd_tries,
                                                                      self.cmd_tries * self.cmd_timeout_s))

    def settings(self, mode, decim=1, gain_q15=0, safe_ticks=65535):
        self.command("CTRL_SETTINGS", mode=core.MODE[mode], rx_cmd=0, ry_cmd=0, gain=gain_q15, decim=decim,
                     safe_ticks=safe_ticks)
        rc = getattr(self.endpoint, "rc", None)
        if rc is not None:        # the bench now knows which ticks carry CTRL_STATUS and asks again for a lost one
            rc.status_decim = decim

    def set_fsm(self, vx, vy):
        self.command("CTRL_SET_FSM", vx=int(round(vx * 1e6)), vy=int(round(vy * 1e6)))

    def upload(self, prefix, blob, dst=CONTROLLER):
        """<prefix>_BEGIN / CHUNK / END of ``blob`` (HTABLE to the controller, DIST to the player)."""
        crc = core.crc32(blob) & 0xFFFFFFFF
        self.command(prefix + "_BEGIN", total=len(blob), crc32=crc, dst=dst)
        n = table.CHUNK_BYTES
        for off in range(0, len(blob), n):
            part = blob[off:off + n]
            self.command(prefix + "_CHUNK", offset=off, length=len(part), data=part + bytes(n - len(part)),
                         dst=dst)
        self.command(prefix + "_END", total=len(blob), dst=dst)

    def upload_htable(self, blob):
        """The calibration blob (protocol.htable) to the controller."""
        self.upload("HTABLE", blob)


class LiveRig(Rig):
    """A real, free-running bench on a serial port (``--port``): the controller and the player MCUs answer
    on one link, time is the wall clock, ``run(n)`` waits n control periods collecting telemetry.

    The P-FSM is held by uploading a two-sample distfile of the wanted angle (Eq. 7.8) to the PLAYER
    and looping it: the same packets the thesis's SimArduino would take. No Q2 or truth here.
    """

    def __init__(self, port, rate_hz=637.8):
        from protocol.link import open_link
        self.link = open_link(port if "://" in port or port.startswith("serial:") else "serial:" + port,
                              "GROUND")
        self.endpoint = _LinkEndpoint(self.link)
        self.rate_hz = rate_hz
        self.config = {"port": port, "rate_hz": rate_hz}
        self._seq = 0
        self.status = []
        self.replies = deque()
        self.n_status_total = 0
        self.n_cmd_retries = 0
        self.n_stale_replies = 0
        self.last_status = None   # the latest CTRL_STATUS (decoded)
        self.mode_log = []        # (tick, mode, why) at each mode change seen in CTRL_STATUS
        self.pfsm_at = None
        self._t0 = None

    def elapsed_s(self):
        return 0.0 if self._t0 is None else time.perf_counter() - self._t0

    def run(self, n_ticks, progress=None):
        if self._t0 is None:
            self._t0 = time.perf_counter()
        end = time.perf_counter() + n_ticks / self.rate_hz
        while True:
            left = end - time.perf_counter()
            if left <= 0:
                break
            self.endpoint.inbox.extend(self.link.recv(timeout=left))
            if self.link.closed:
                raise OSError("bench link %s closed" % self.config["port"])
        self._drain()
        return {"q2": np.zeros((0, 5), np.int64), "truth_arcsec": np.zeros((0, 2))}

    def pfsm_v(self, vx, vy):
        from protocol import distfile
        for v in (vx, vy):
            if not -10.0 <= v <= 10.0:
                raise ValueError("P-FSM voltage %r outside the AD660 range +-10 V" % v)
        th = (vx / PFSM_V_PER_ARCSEC, vy / PFSM_V_PER_ARCSEC)
        self.upload("DIST", distfile.pack([th[0], th[0]], [th[1], th[1]], source="hold"), dst=PLAYER)
        self.command("PLAYER_CTRL", action=2, rate_hz=10600, dst=PLAYER)      # LOOP
        self.pfsm_at = (vx, vy)

    def close(self):
        self.link.close()


class _LinkEndpoint:
    def __init__(self, link):
        self.link = link
        self.inbox = deque()

    def send_ground(self, pid, payload, seq, dst=CONTROLLER):
        return self.link.send_raw(pid, GROUND, dst, payload)

    def poll(self, timeout_s):
        self.inbox.extend(self.link.recv(timeout=timeout_s))

    def counters(self):
        return self.link.counters()

