"""The ADCS app's service loops (MicroPython): the lockstep with the emulated spacecraft, exactly once per cycle
over a lossy link (``Lockstep``); the app on a CAN port (``serve``, a board or a process of its own); the app in
process behind the calls a CAN link takes (``InProcess``, the ground's analysis). All three give the app the same
packets' bytes and send the same replies (``telemetry.cycle_replies``)."""

import struct

from firmware.adcs.apkf_lean_model import NW     # the wheels the lean ADCS flies
from firmware.adcs.telemetry import cycle_replies
from protocol import can as canmap
from protocol import core
from protocol.compat import ticks_diff          # MicroPython: ticks wrap (2^30 us on a 32-bit board)
from protocol.consts import (FMT_ADCS_MISSING, FMT_ADCS_TICK, NODE_BROADCAST, NODE_RW0, P_ADCS_MISSING, P_ADCS_TICK,
                             P_BEACON, P_GNSS, P_HELLO, P_RW_TLM, P_STARTRACKER, STALE_BEACON, STALE_GNSS_A,
                             STALE_GNSS_B, STALE_RW0, STALE_STARTRACKER)



def _drops(port):
    """Frames and payloads the CAN port dropped (``protocol.can.rx_drops``)."""
    return canmap.rx_drops(port.counters())


def _damaged(port):
    """Of those, the ones that arrived damaged (``protocol.can.rx_damaged``: never a timeout or a cut-off
    transfer, which a slow host causes)."""
    return canmap.rx_damaged(port.counters())


_B_GNSS_A = 1 << STALE_GNSS_A
_B_GNSS_B = 1 << STALE_GNSS_B


def burst_bit(pid, src, payload):
    """The ADCS_STALE bit naming a burst packet (ADCS_TICK.burst), 0 for a packet that is not one."""
    if pid == P_RW_TLM:
        i = src - NODE_RW0
        return 1 << (STALE_RW0 + i) if 0 <= i < NW else 0
    if pid == P_STARTRACKER:
        return 1 << STALE_STARTRACKER
    if pid == P_GNSS:
        sat = payload[4]                     # after t_ms (I)
        return _B_GNSS_A if sat == 0 else (_B_GNSS_B if sat == 1 else 0)
    if pid == P_BEACON:
        return 1 << STALE_BEACON
    return 0


class Lockstep:
    """The lockstep with the emulated spacecraft, exactly once per cycle over a lossy link.

    ``ADCS_TICK(k, burst, n_gnss_b)`` opens cycle k and names the sensor packets that follow it; the packets are
    given to the app while a cycle is open (a copy arriving while none is, a late resend of an earlier burst, is
    dropped: ``n_late``; a second copy of one already in is dropped too: ``n_dup``), and the cycle runs once,
    when every packet named is in. A resent ``ADCS_TICK(k)``: answered from the cache when k has run (RW_CMD x4
    and ADCS_STATUS again, no second cycle), with ``ADCS_MISSING(k, bits)`` while its burst is incomplete. A
    tick older than the last run is dropped. ``step(tick, t)`` runs the cycle and returns the replies
    [(pid, dst, payload)]; ``host`` is the node whose ADCS_TICK opened the cycle (the replies go to it).
    """

    def __init__(self, app, step):
        self.app = app
        self.step = step
        self.last = -1
        self.replies = ()
        self.open_k = -1
        self.t_ms = 0
        self.want = self.have = self.nb_want = 0
        self.tb = []                         # SatB fix times (ms) taken in the open cycle
        self.n_late = self.n_dup = self.n_missing = self.n_cached = 0
        self.host = 0

    def _ready(self):
        return self.want & ~_B_GNSS_B & ~self.have == 0 and len(self.tb) >= self.nb_want

    def _run(self):
        k = self.open_k
        self.open_k = -1
        self.replies = self.step(k, self.t_ms / 1000.0)
        self.last = k
        return self.replies

    def on_tick(self, tick, t_ms, burst, n_gnss_b, src=0):
        """Replies [(pid, dst, payload)] to an ADCS_TICK from node ``src``."""
        self.host = src
        if tick == self.last:
            self.n_cached += 1
            return self.replies
        if tick < self.last:
            return ()
        if tick != self.open_k:
            if self.open_k >= 0:             # a cycle given up by the spacecraft: its partial inputs go
                self.app.clear_inputs()
            self.open_k, self.t_ms, self.want, self.nb_want, self.have = tick, t_ms, burst, n_gnss_b, 0
            self.tb = []
        elif not self._ready():
            self.n_missing += 1
            miss = self.want & ~self.have & ~_B_GNSS_B
            if len(self.tb) < self.nb_want:
                miss |= _B_GNSS_B
            return ((P_ADCS_MISSING, src, struct.pack(FMT_ADCS_MISSING, tick & 0xFFFFFFFF, miss)),)
        return self._run() if self._ready() else ()

    def on_packet(self, pid, src, payload):
        """Replies to a sensor packet: the cycle's, when it completes the open burst."""
        if self.open_k < 0:
            self.n_late += 1
            return ()
        bit = burst_bit(pid, src, payload)
        if bit == _B_GNSS_B:
            t_ms = struct.unpack_from("<I", payload, 0)[0]
            if t_ms in self.tb:
                self.n_dup += 1
                return ()
            self.tb.append(t_ms)
        elif bit & self.have:
            self.n_dup += 1
            return ()
        self.have |= bit
        self.app.on_packet(pid, src, payload)
        return self._run() if self._ready() else ()


class InProcess:
    """The app on this host, behind the calls a CAN link takes (``send_raw``, ``recv``, ``counters``, ``close``):
    the spacecraft's packets go to ``Lockstep`` as the bytes a bus would carry, and the replies come back the
    same way, so a session flies the very code and bytes ``serve`` flies, without a process or a wire."""

    def __init__(self, app, node, probe=None):
        self.app = app
        self.node = node
        self.probe = probe                   # probe(tick, t, u): called after each cycle, before its replies
        self.closed = False
        self.inbox = []
        self.ls = Lockstep(app, self._step)

    def _step(self, tick, t):
        u = self.app.cycle(tick, t)
        if self.probe is not None:
            self.probe(tick, t, u)
        return cycle_replies(self.app, self.app.commands(u, tick), tick, self.ls.host)

    def send_raw(self, pid, src, dst, payload):
        if dst != self.node:
            return
        if pid == P_HELLO:                   # answered as ``serve`` answers it
            out = ((P_HELLO, src, core.encode_payload(P_HELLO, node=self.node, fw_major=1, fw_minor=0)),)
        elif pid == P_ADCS_TICK:
            tick, t_ms, burst, n_gnss_b = struct.unpack(FMT_ADCS_TICK, payload)
            out = self.ls.on_tick(tick, t_ms, burst, n_gnss_b, src)
        else:
            out = self.ls.on_packet(pid, src, payload)
        for rpid, rdst, rpl in out:
            self.inbox.append((rpid, self.node, rdst, 0, rpl))

    def recv(self, timeout=0.0):
        out, self.inbox = self.inbox, []
        return out

    def counters(self):
        return {}

    def close(self):
        self.closed = True


def serve(app, port, ticks_us=None, poll_ms=1000, heap=None):
    """The ADCS on a CAN port until the host leaves: HELLO once the channel is open, and again to each HELLO
    received (the host repeats its own until it hears one: a lost HELLO costs a retry, not the session), then
    the lockstep (``Lockstep``): per cycle, RW_CMD x4 and ADCS_STATUS to the tick's sender. ``heap``:
    callable(tick, bytes) measuring the cycle's heap (gc.mem_alloc deltas, under MicroPython)."""
    me = port.node
    hello = core.encode_payload(P_HELLO, node=me, fw_major=1, fw_minor=0)
    ad = getattr(port, "ad", None)
    while ad is not None and not ad.is_open and not port.closed:
        port.recv_ms(100)             # the host opens the channel (O) before any frame can go out
    port.send_raw(P_HELLO, me, NODE_BROADCAST, hello)
    mem = None
    if heap is not None:
        import gc
        mem = gc
    def step(tick, t):
        t0 = ticks_us() if ticks_us else 0
        if mem is not None:
            mem.collect()
            mem.disable()
            m0 = mem.mem_alloc()
        u = app.cycle(tick, t)
        cmds = app.commands(u, tick)
        if mem is not None:
            heap(tick, mem.mem_alloc() - m0)
            mem.enable()
        dt = ticks_diff(ticks_us(), t0) if ticks_us else 0
        return cycle_replies(app, cmds, tick, ls.host, dt, _drops(port), _damaged(port))

    ls = Lockstep(app, step)
    while not port.closed:
        for pid, src, dst, seq, payload in port.recv_ms(poll_ms):
            if pid == P_HELLO:
                port.send_raw(P_HELLO, me, src, hello)
                continue
            if pid == P_ADCS_TICK:
                tick, t_ms, burst, n_gnss_b = struct.unpack(FMT_ADCS_TICK, payload)
                replies = ls.on_tick(tick, t_ms, burst, n_gnss_b, src)
            else:
                replies = ls.on_packet(pid, src, payload)
            for rpid, rdst, rpl in replies:
                port.send_raw(rpid, me, rdst, rpl)
    port.close()
