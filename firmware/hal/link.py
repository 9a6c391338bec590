"""Link HAL: the controller's Q1 input and SPI output carried over the protocol (HIL against the emulator).

``serve_controller`` answers each TICK (the Q1 sample) with one FSM_SPI (the tick number and the AD5664R
words), plus CTRL_STATUS every ``decim`` ticks, both addressed to the TICK's sender (the HIL host, whose
ground side reads the status), and handles every other packet between ticks.
The per-tick path unpacks and packs with preallocated buffers; framing is the link's. The links: a desktop's
(``firmware.hal.ports.open_link``) or a board's (``firmware.hal.stdio``); they time out in ms here (``recv_ms``).
"""

import struct

from firmware.controller import FW_VERSION, heap_lock, heap_unlock, hello_payload
from protocol import consts

try:
    from micropython import const
except ImportError:                       # CPython
    def const(x):
        return x

P_TICK = consts.P_TICK
P_FSM_SPI = consts.P_FSM_SPI
P_STATUS = consts.P_CTRL_STATUS
P_HELLO = consts.P_HELLO
BROADCAST = consts.NODE_BROADCAST
_TICK_FMT = consts.FMT_TICK
_SPI_FMT = consts.FMT_FSM_SPI
_SPI_SIZE = consts.SIZES[P_FSM_SPI]
# a board link's kinds of TICK exchange (``firmware.hal.stdio``'s ``_K_*``) that only this loop knows
_K_STATUS = const(2)
_K_RESEND = const(3)


def serve_controller(ctl, link, rate_hz=637.8, poll_ms=100):
    """Run the controller on a link until the peer leaves (OSError if the link failed instead: the process then
    exits 1 with the reason on stderr, firmware.main).

    Exactly-once ticks: the first copy of TICK k steps the controller; a resent TICK k (its answer was lost)
    is answered again with the FSM_SPI words, and the CTRL_STATUS if one was due, computed for k, without a
    second step (``n_dup``). A TICK older than the last is stale: dropped unanswered and counted in
    ``n_rx_drop``. A second stale TICK in a row, not older than the first, means the last tick number was
    damage the CRC-16 let through (else every later TICK would be stale and the run would end as a dead
    link): it is stepped and the ticks go on from it. Ticks the bench ran without us
    (a gap in the tick numbers) count as link silence toward SAFE (``n_gap``) once the next TICK confirms the
    jump (so a damaged tick number neither counts nor sends the controller to SAFE), as does a wait of
    ``poll_ms`` without any packet. A HELLO from the bench starts a new session (tick numbers may start again).
    CTRL_STATUS is due on ticks k with k % decim == 0 (``status_due_at``), so the bench knows which ticks
    carry one; it goes out after the FSM_SPI (the loop's output first), to the TICK's sender. A link with
    ``answer_ticks`` answers the common ticks itself (``_fast_ticks``), those with a CTRL_STATUS due included. A TICK whose Q1 counts lie beyond the 12-bit ADC (the packet table's
    0..4095: only damage the CRC-16 missed makes one) is dropped unanswered and counted with the frames dropped
    (``n_rx_drop``); the step's integers stay within +-2^30 (on a 32-bit board a larger count overflows: a heap
    allocation under ``heap_lock``, or a wrapped ratio in viper).
    """
    me = link.node
    out = bytearray(_SPI_SIZE)
    status = None
    status_tick = -1
    last = -1
    bad_ticks = 0                             # TICKs dropped: counts beyond 0..4095, or older than the last
    stale = -1                                # the last TICK older than ``last`` in a row (-1: none)
    gap = 0                                   # ticks skipped by the jump to ``last``, until a TICK confirms it
    w = ctl.words
    rx_drops = getattr(link, "rx_drops", None)
    fast = getattr(link, "answer_ticks", None)   # a board's machine-code path for the common tick
    kind = getattr(link, "exchange_kind", None)  # a board's meter: a resend's or a status tick's exchange
    link.send_raw(P_HELLO, me, BROADCAST, hello_payload(me, FW_VERSION))
    silent_ticks = int(poll_ms * rate_hz / 1000) or 1
    while not link.closed:
        if fast is not None and stale < 0 and not gap and -1 <= last < 0x3FFFFFFF:   # -1: a session's tick 0
            last, status, status_tick = _fast_ticks(fast, ctl, last, out, link, rx_drops, bad_ticks, status,
                                                    status_tick)
        pkts = link.recv_ms(poll_ms)
        if not pkts:
            ctl.link_silent(silent_ticks)
            continue
        for pid, src, dst, seq, payload in pkts:
            if dst != me and dst != BROADCAST:
                continue
            if pid != P_TICK:
                if _handle(ctl, link, me, pid, src, seq, payload):     # a HELLO: a new session
                    last = stale = status_tick = -1
                    gap = 0
                continue
            tick, t_us, vx, vy, vs = struct.unpack(_TICK_FMT, payload)
            if (vx | vy | vs) >> 12:          # beyond the 12-bit ADC (damage the CRC let through): drop it,
                bad_ticks += 1                # the bench resends; stepped, it would break the +-2^30 bound
                continue
            if tick == last:                  # a resend: the same answer, no second step
                _answer_again(ctl, link, me, src, status if status_tick == tick else None, out, kind)
                continue
            if tick < last:                   # stale, or our last came from a tick number the CRC let
                if stale < 0 or tick < stale:   # through damaged: two in a row going forward are the
                    stale = tick              # bench's clock, and we take it up again
                    bad_ticks += 1
                    continue
                last = tick - 1
                gap = 0                       # the jump to it was that damage, not ticks run without us
            stale = -1
            if gap:                           # the jump before the last tick, confirmed by this one
                ctl.n_gap += gap
                ctl.link_silent(gap)
            gap = tick - last - 1 if last >= 0 and tick > last + 1 else 0
            last = tick
            ctl.heard(True)
            heap_lock()                       # the step allocates nothing; locked, its frame stays off the heap
            try:
                n = ctl.step(vx, vy, vs)
            finally:                          # never leave the heap locked behind an exception
                heap_unlock()
            struct.pack_into(_SPI_FMT, out, 0, tick, n, w[0], w[1], w[2], w[3])
            status, status_tick = _answer(ctl, link, me, src, tick, rx_drops, bad_ticks, out, status, status_tick,
                                          kind)
    _closed(link)


def _fast_ticks(fast, ctl, last, out, link, rx_drops, bad_ticks, status, status_tick):
    """The common ticks after tick ``last``, answered by the link itself (``fast``: its ``answer_ticks``, a
    board's: ``firmware.hal.stdio`` with ``firmware.hal.fast_tick``) in machine code, with the same calls and
    bytes as ``serve_controller`` (the heap locked there), until a frame is not one; CTRL_STATUS's n_rx_drop set
    first, as ``_send_status`` sets it. Returns the last tick answered, its FSM_SPI kept in ``out`` for a
    resend, and the last CTRL_STATUS sent with its tick (``status``, ``status_tick`` when none was)."""
    if rx_drops is not None:
        ctl.n_rx_drop = rx_drops() + bad_ticks
    tick, n = fast(ctl, last)
    if tick != last:
        w = ctl.words
        struct.pack_into(_SPI_FMT, out, 0, tick, n, w[0], w[1], w[2], w[3])
        if ctl.status_due_at(tick):
            return tick, link.status_sent(), tick
    return tick, status, status_tick


def _answer(ctl, link, me, dst, tick, rx_drops, bad_ticks, out, status, status_tick, kind):
    """Tick's FSM_SPI (``out``), then its CTRL_STATUS when one is due; returns the last CTRL_STATUS sent and its
    tick. ``kind``: the link's ``exchange_kind`` (None: the link has none)."""
    if not ctl.status_due_at(tick):
        link.send_raw(P_FSM_SPI, me, dst, out)
        return status, status_tick
    return _send_status(ctl, link, me, dst, tick, rx_drops, bad_ticks, out, kind), tick


def _answer_again(ctl, link, me, dst, status, out, kind):
    """A resent TICK answered again (counted in n_dup): its FSM_SPI, then the CTRL_STATUS it carried (None:
    none)."""
    ctl.n_dup += 1
    if kind is not None:
        kind(_K_RESEND)
    link.send_raw(P_FSM_SPI, me, dst, out)
    if status is not None:
        link.send_raw(P_STATUS, me, dst, status)


def _send_status(ctl, link, me, dst, tick, rx_drops, bad_ticks, out, kind):
    """Tick's FSM_SPI (``out``), then its CTRL_STATUS, with the frames the link dropped and the bad TICKs in
    n_rx_drop, both sent to dst (the HIL host that clocks us: on CAN, ISO-TP to an absent node would block);
    returns the status's payload."""
    if rx_drops is not None:
        ctl.n_rx_drop = rx_drops() + bad_ticks
    if kind is not None:
        kind(_K_STATUS)
    link.send_raw(P_FSM_SPI, me, dst, out)
    status = ctl.status_payload(tick)
    link.send_raw(P_STATUS, me, dst, status)
    return status


def _handle(ctl, link, me, pid, src, seq, payload):
    """A packet other than TICK, handled by the controller and its replies sent; True for a HELLO (the bench
    starts a new session)."""
    for rpid, rdst, rpayload in ctl.handle(pid, src, seq, payload):
        link.send_raw(rpid, me, rdst, rpayload)
    return pid == P_HELLO


def _closed(link):
    """Close the link; OSError naming the cause if it failed (more than the peer leaving)."""
    why = getattr(link, "closed_why", None)
    link.close()
    if why:
        raise OSError("the link failed: %s" % why)


def serve_player(player, link, poll_ms=100):
    """Serve the player's packets (PLAYER_CTRL, DIST upload) on a link until the peer leaves."""
    me = link.node
    while not link.closed:
        for pid, src, dst, seq, payload in link.recv_ms(poll_ms):
            if dst == me or dst == BROADCAST:
                for rpid, rdst, rpayload in player.handle(pid, src, seq, payload):
                    link.send_raw(rpid, me, rdst, rpayload)
    _closed(link)
