"""The session's side of the lockstep's replies: ``ReplyWait`` sends a cycle's burst and waits for its RW_CMDs,
MTQ_CMD and ADCS_STATUS, trying again as ``emulator.adcs_session``'s docstring says; ``StatusWatch`` takes each
ADCS_STATUS (named mode and stale sensors, the firmware's cycle time, each mode change with its reason)."""

import time

import numpy as np

from emulator.adcs_bus import N, P, RW_NODES, magnetic_events
from emulator.spacecraft.wheels import N_WHEELS
from protocol import core, table

TRY_MIN_S, TRY_MAX_S = 0.02, 1.0     # the first try's wait for the cycle's replies: 3 x the recent reply time
RETRY_S = 0.03                       # a further try's first wait: an answer from the cache takes ~10 ms
TRY_BACKOFF = 1.5                    # each further try of a cycle waits this much longer (up to TRY_MAX_S)
MODE_NAME = dict((v, k) for k, v in table.ADCS_MODES)
STALE_BITS = table.ADCS_STALE
# a planned slew's blind star tracker, as the thesis world's DEGRADED names it (not a fault)
PLANNED_BLIND = "star tracker blind by plan: slew (STARTRACKER stale, not a fault)"


class ReplyWait:
    """The lockstep's waiting side of one cycle: the burst sent, then the cycle's RW_CMDs, MTQ_CMD (when
    ``expect_mtq``) and ADCS_STATUS awaited, trying again as the module docstring says; each retry counted in
    ``retries``, each late cycle in ``n_late``."""

    def __init__(self, bus, expect_mtq, reply_timeout_s):
        self.bus = bus
        self.expect_mtq = expect_mtq
        self.timeout_s = float(reply_timeout_s)
        self.cmd = [None] * N_WHEELS             # RW_CMD payload received this cycle
        self.mtq_cmd = None                      # MTQ_CMD payload received this cycle
        self.retries = {"tick_resent": 0, "missing_answered": 0, "packets_resent": 0, "burst_resent": 0,
                        "cycles_retried": 0, "hello_tries": 0}
        self.reply_s = 0.05                      # recent wall time from ADCS_TICK to the cycle's last reply
        self.tick_sent = 0.0
        self.n_late = 0
        self.late_run = 0                        # consecutive late cycles

    def send(self, link, bits=None):
        """ADCS_TICK(k) then the burst's packets (``bits`` None), or only the packets of ``bits`` (an answer to
        ADCS_MISSING: the firmware has the cycle open)."""
        if bits is None:
            link.send_raw(P["ADCS_TICK"], N["SPACECRAFT"], N["ADCS"], self.bus.tick_payload)
        for bit, pid, src, payload in self.bus.pkts:
            if bits is None or bit & bits:
                link.send_raw(pid, src, N["ADCS"], payload)

    def open(self, link):
        """Cycle k's ADCS_TICK and burst sent: its wait starts."""
        self.tick_sent = time.monotonic()
        self.send(link, None)

    def _done(self, status):
        return status is not None and all(c is not None for c in self.cmd) and (
            self.mtq_cmd is not None or not self.expect_mtq)

    def wait(self, k, link, exited):
        """RW_CMDs and ADCS_STATUS of tick k (None if late); ``exited()`` the firmware's end (an OSError)."""
        t0 = self.tick_sent
        deadline = t0 + self.timeout_s
        self.cmd = [None] * N_WHEELS
        self.mtq_cmd = None
        status = None
        heard = False                            # anything of cycle k came back (a reply or ADCS_MISSING)
        try_s = min(TRY_MAX_S, max(TRY_MIN_S, 3.0 * self.reply_s))
        try_end = t0 + try_s
        resent = 0                               # ADCS_TICK(k) sent again so far
        while True:
            now = time.monotonic()
            if self._done(status):
                if not resent:                   # the try's wait follows the clean cycles' reply time
                    self.reply_s = 0.8 * self.reply_s + 0.2 * (now - t0)
                return status
            if now >= deadline:
                return status
            if now >= try_end:                   # a try without the cycle's replies: the tick again
                resent += 1
                self.retries["tick_resent"] += 1
                self.retries["cycles_retried"] += resent == 1
                if heard:
                    link.send_raw(P["ADCS_TICK"], N["SPACECRAFT"], N["ADCS"], self.bus.tick_payload)
                else:                            # the tick or the whole burst may be lost: all of it again
                    self.retries["burst_resent"] += 1
                    self.send(link, None)
                try_s = RETRY_S if resent == 1 else min(TRY_MAX_S, TRY_BACKOFF * try_s)
                try_end = time.monotonic() + try_s
                continue
            for pkt in link.recv(min(deadline, try_end) - now):
                got, status = self._take(link, k, pkt, status)
                heard = heard or got
            exited(k)

    def _take(self, link, k, pkt, status):
        """(heard, status) after one packet of cycle k."""
        pid, src, dst, seq, payload = pkt
        if pid == P["RW_CMD"] and dst in RW_NODES:
            if payload[-1] == k & 0xFF:          # not a late copy of the previous cycle's
                self.cmd[RW_NODES.index(dst)] = payload
                return True, status
        elif pid == P["MTQ_CMD"] and dst == N["MTQ"] and self.bus.has_mtq():
            if len(payload) == core.PACKET[pid].size and payload[-1] == k & 0xFF:   # not a late copy
                self.mtq_cmd = payload
                return True, status
        elif pid == P["ADCS_STATUS"]:
            d = core.payload_dict(pid, payload)
            if d["tick"] == k:
                return True, d
        elif pid == P["ADCS_MISSING"]:
            d = core.payload_dict(pid, payload)
            if d["tick"] == k and status is None:
                self.retries["missing_answered"] += 1
                self.retries["packets_resent"] += sum(1 for b, _, _, _ in self.bus.pkts if b & d["missing"])
                self.send(link, d["missing"])
                return True, status
        return False, status


class StatusWatch:
    """The ADCS_STATUS of each cycle: its mode and stale sensors named, the firmware's own cycle times
    (``cycle_us``: n, sum, largest; ``filters_start_us`` the first cycle out of INIT, which starts the filters,
    apart), each mode change with its reason (``mode_changes``: {"t_s", "from", "to",
    "reason"}; also an event in ``fault_log``), each magnetic device out or back (``health_events``:
    ``adcs_bus.magnetic_events``; also in ``fault_log``). ``slew`` (t0, t1), s: the planned slew, whose star
    tracker is blind by plan (the thesis world's firmware reports it DEGRADED: it has no slew mode);
    ``st_fault`` (t0, t1), s: an injected ``startracker_blind``, always a fault."""

    def __init__(self, say, fault_log, slew=None, st_fault=None):
        self.say = say
        self.fault_log = fault_log
        self.slew, self.st_fault = slew, st_fault
        self.st_blind_from = None            # the first cycle (s) of the star tracker's current blind stretch
        self.planned = False                 # the mode entered last was the planned slew's blind DEGRADED
        self.last = None
        self.cycle_us = [0, 0, 0]
        self.filters_start_us = None         # the cycle that starts the filters, apart from cycle_us
        self.mode = None
        self.mode_changes = []
        self.health_events = []
        self.magnetic = 0

    def take(self, status, t, st_blind_before):
        """Take cycle k's ADCS_STATUS at t (s); returns the flight software's estimates it carries."""
        status["adcs_mode_name"] = MODE_NAME.get(status["adcs_mode"], "?")
        status["stale_names"] = [n for n, b in STALE_BITS if status["stale"] >> b & 1]
        self.last = status
        blind = "STARTRACKER" in status["stale_names"]
        self.st_blind_from = (self.st_blind_from if self.st_blind_from is not None else t) if blind else None
        if self.filters_start_us is None and status["adcs_mode_name"] != "INIT":
            self.filters_start_us = status["cycle_us"]     # the first cycle out of INIT starts the filters
        else:
            c = self.cycle_us
            c[0] += 1
            c[1] += status["cycle_us"]
            c[2] = max(c[2], status["cycle_us"])
        for e in magnetic_events(self.magnetic, status["magnetic_failed"], t):
            self.health_events.append(e)
            self.fault_log.append(e)
            self.say("t = %.0f s: ADCS %s (%s)" % (t, e["event"], e["reason"]))
        self.magnetic = status["magnetic_failed"]
        name = status["adcs_mode_name"]
        if name != self.mode:
            planned = self.blind_by_plan(status, t)
            if self.mode is not None:
                self.mode_changes.append({"t_s": t, "from": self.mode, "to": name, "reason": PLANNED_BLIND
                                          if planned else "the star tracker is back after the planned slew"
                                          if self.planned else why(self.mode, status, st_blind_before)})
            self.planned = planned
            self.fault_log.append({"t_s": t, "event": "ADCS mode %s" % name})
            self.say("t = %.0f s: ADCS mode %s -> %s%s" % (t, self.mode, name, " (%s)" % PLANNED_BLIND if planned
                                                            else (" (stale: %s)" % ", ".join(status["stale_names"]))
                                                            if status["stale_names"] else ""))
            self.mode = name
        return {"q": np.array([status[n] for n in ("q0", "q1", "q2", "q3")]),
                "w": np.array([status[n] for n in ("wx", "wy", "wz")]),
                "ra": np.array([status[n] for n in ("rax", "ray", "raz")]),
                "rb": np.array([status[n] for n in ("rbx", "rby", "rbz")]),
                "att_sigma_rad": status["att_sigma"], "t": t}

    def blind_by_plan(self, status, t):
        """True when cycle t's DEGRADED is the planned slew's blind star tracker alone: no other sensor stale, no
        wheel failed, the blind stretch begun within ``slew`` and no injected ``startracker_blind`` over it."""
        if status["adcs_mode_name"] != "DEGRADED" or status["stale_names"] != ["STARTRACKER"] or \
                status["wheels_failed"] or self.slew is None or self.st_blind_from is None:
            return False
        f = self.st_fault
        return self.slew[0] <= self.st_blind_from <= self.slew[1] and (f is None or f[1] <= self.st_blind_from
                                                                        or f[0] > t)


def why(before, status, st_blind_before):
    """The reason of a mode change, from the transition and what this side knows (the firmware reports the mode;
    ADCS_STATUS has no room for a reason); ``st_blind_before`` the star tracker's last blind stretch (s)."""
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
                % st_blind_before if before == "ACQUIRE" else "slew")
    if to == "ACQUIRE":
        return "the slew's reference reached the command; waiting for the star tracker"
    if to == "POINT":
        return ("the star tracker is back after %d s blind, the estimate on the command"
                % st_blind_before if before == "ACQUIRE" else "pointing")
    return to
