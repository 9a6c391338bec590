"""CAN HAL over Lawicel (slcan) ASCII: the firmware plays the serial-CAN adapter, the host opens python-can's
``slcan`` interface on the other end of the pty. Runs under the MicroPython unix port and CPython.

On a board a ``machine.CAN`` backend (``CAN.send(data, id, extframe=True)`` / ``CAN.recv``) would replace
``SlcanAdapter``: ``CanPort`` only needs ``send_frame(cid, data)`` and ``poll(timeout_ms)`` returning received
frames, so the packet layer (29-bit ids and the end-to-end check of ``protocol.can``, ISO-TP of
``protocol.isotp`` for longer packets, flow control answered at once) stays the same.

The adapter's commands are ``protocol.lawicel.Adapter``'s (the one Lawicel implementation, shared with the
host's test adapter); malformed lines are dropped and counted by reason there. The fd (a pty master,
non-blocking) is read with ``select.poll`` and ``readinto`` into a preallocated buffer; received frames go
out as ``T`` lines from one preallocated buffer.
"""

import sys

from protocol import can as canmap
from protocol import core, isotp, lawicel

try:
    import select
    from protocol.stream import poll_events, ticks_diff, ticks_ms
except ImportError:                  # a bare-metal board: no select, no time module; its adapter (UartSlcan) and
    select = poll_events = ticks_diff = ticks_ms = None      # its clock (CanPort's ``clock``) come with it


class _LawicelSide:
    """What both adapters share: the Lawicel interpreter ``lw`` and its state and counters."""

    @property
    def is_open(self):
        return self.lw.is_open

    @property
    def bitrate(self):
        return self.lw.bitrate

    @property
    def n_rx(self):
        return self.lw.n_rx

    @property
    def n_bad(self):
        """Malformed lines (every reason but ``closed``: a well-formed frame while the channel is closed)."""
        d = self.lw.drops
        return sum(d[r] for r in lawicel.DROPS if r != "closed")

    def send_frame(self, cid, data):
        """One received CAN frame (29-bit id) to the host: ``T`` + 8 hex id + dlc + data + CR."""
        n = lawicel.frame_line(self._tline, cid, data)
        self._write(memoryview(self._tline)[:n])
        self.n_tx += 1

    def counters(self):
        d = self.lw.counters()
        d["slcan_tx"] = self.n_tx
        return d


class UartSlcan(_LawicelSide):
    """The adapter side of Lawicel on a board's console UART (``sys.stdin.buffer`` / ``sys.stdout.buffer``: the ADCS
    PIL board, ``firmware.adcs.pil_main``). The board has no ``select``: ``ready()`` (its UART's receive flag) and
    ``clock`` (ticks_ms, ticks_diff) let ``poll`` wait for the next line up to its timeout; without them ``poll``
    blocks until the next line. ``closed`` once the input ends."""

    def __init__(self, reader=None, writer=None, ready=None, clock=None):
        self._r = reader if reader is not None else sys.stdin.buffer
        self._w = writer if writer is not None else sys.stdout.buffer
        self._ready = ready
        self._clock = clock
        self._buf = bytearray(1)
        self._tline = bytearray(lawicel.LINE_MAX)
        self.lw = lawicel.Adapter(self._write)
        self.closed = False
        self.fail_why = None
        self.n_tx = 0

    def _write(self, data):
        self._w.write(data)

    def poll(self, timeout_ms):
        """Frames the host sent in its next line (none for a command line), waiting up to ``timeout_ms`` (-1
        forever) for its first byte, then to its CR."""
        out = []
        b = self._buf
        if self._ready is not None and timeout_ms >= 0 and not self._ready():
            ms, diff = self._clock
            t0 = ms()
            while not self._ready():
                if diff(ms(), t0) >= timeout_ms:
                    return out
        while not self.closed:
            if not self._r.readinto(b):
                self.closed = True
            else:
                self.lw.feed(b, 1, out)
                if b[0] == 13:
                    break
        return out

    def close(self):
        self.closed = True


class SlcanAdapter(_LawicelSide):
    """The adapter side of Lawicel on a file descriptor (int) or a path; frames in and out.

    ``poll(timeout_ms)`` reads what has arrived, answers commands, and returns the list of frames the host
    asked to transmit, ``[(can_id, extended, data)]``; ``send_frame(cid, data)`` hands a received CAN frame to
    the host (a ``T`` line). ``closed`` turns True only when the fd fails or the host closes the pty.
    Counters: ``n_rx``, ``n_tx``, ``n_bad`` (malformed lines), ``counters()`` by reason.
    """

    def __init__(self, dev, bufsize=1024):
        self._f = open(dev, "r+b", buffering=0)
        self._poll = select.poll()
        self._poll.register(self._f, select.POLLIN)
        self._ipoll = getattr(self._poll, "ipoll", None)
        self._buf = bytearray(bufsize)
        self._tline = bytearray(lawicel.LINE_MAX)
        self.lw = lawicel.Adapter(self._write)
        self.closed = False
        self.fail_why = None         # set when the fd failed other than by the host closing the pty
        self.n_tx = 0

    def _write(self, data):
        if self._f is None:
            return
        try:
            n = self._f.write(data)
            if n is None:
                n = 0
            mv = None
            while n < len(data):       # a full pty buffer: wait until writable
                if mv is None:
                    mv = memoryview(data)
                self._poll.modify(self._f, select.POLLOUT)
                self._poll.poll(100)
                self._poll.modify(self._f, select.POLLIN)
                n += self._f.write(mv[n:]) or 0
        except OSError as exc:
            self._failed(exc)

    def _failed(self, exc):
        self.closed = True
        code = exc.args[0] if exc.args else None
        if code not in (5, 32) and self.fail_why is None:     # EIO, EPIPE: the host closed its end (in order)
            self.fail_why = "slcan port: %s" % (exc,)

    def _events(self, wait):
        return poll_events(self._ipoll, self._poll, wait)

    def poll(self, timeout_ms):
        """Frames the host sent, waiting up to ``timeout_ms`` (-1 forever) for the first bytes."""
        out = []
        wait = timeout_ms
        while not self.closed:
            ev = self._events(wait)
            if not ev:
                return out
            n = None
            if ev & select.POLLIN:
                try:
                    n = self._f.readinto(self._buf)
                except OSError as exc:   # EIO: the host closed the pty
                    self._failed(exc)
                    n = 0
            if n is None:
                if ev & (select.POLLHUP | select.POLLERR):
                    self.closed = True
                return out
            if n == 0:
                self.closed = True
                return out
            self.lw.feed(self._buf, n, out)
            if out:
                return out
            wait = 0
        return out

    def close(self):
        if self._f is not None:
            try:
                self._poll.unregister(self._f)
            except (OSError, KeyError, ValueError):
                pass
            self._f.close()
            self._f = None
        self.closed = True


class CanPort:
    """Packets over an adapter (``SlcanAdapter`` or a ``machine.CAN`` backend with the same two calls).

    ``send_raw(pid, src, dst, payload)``: one frame, or ISO-TP: the FF, then the CFs as the receiver's flow
    control arrives, frames received meanwhile kept. No flow control within ``isotp_timeout_ms`` (ISO 15765-2's
    N_Bs; its default 1000 ms) aborts the transfer and the whole packet is sent again, ``tries`` sends in all;
    returns False when every try failed (counted ``tx_isotp_failed``: the packet is lost, the peer's own resend
    recovers it) or the receiver's flow control said overflow. A lost CF is the receiver's to discard (its
    N_Cr, or the next FF on the id). ``recv_ms(timeout_ms)``: packets ``[(pid, src, dst, None, payload)]`` for
    this node, BROADCAST or an ``accept`` node; frames failing the end-to-end check or the table are dropped and
    counted by reason in ``counters()`` with the adapter's malformed lines; this side's own sends are counted
    apart (``tx_isotp_timeouts``, ``tx_isotp_resent``, ``tx_isotp_failed``), never as drops. ``clock``:
    (ticks_ms, ticks_diff) where there is no ``time`` module (a board's timer); None: MicroPython's or CPython's.
    """

    def __init__(self, adapter, node, accept=(), isotp_timeout_ms=1000, tries=3, clock=None):
        self.ad = adapter
        self._ticks_ms, self._ticks_diff = clock if clock is not None else (ticks_ms, ticks_diff)
        self.node = core.node_id(node)
        self.accept = [self.node, 0xFF] + [core.node_id(a) for a in accept]
        self.timeout_ms = int(isotp_timeout_ms)
        self.tries = tries
        self._dec = canmap.CanDecoder(self._new_channel)   # its ISO-TP channels answer with flow control
        self._q = []
        self.other_dst = 0
        self.isotp_timeouts = 0
        self.isotp_resent = 0
        self.isotp_failed = 0
        self.tx_packets = 0

    @property
    def closed(self):
        return self.ad.closed

    def _new_channel(self, rxid):
        txid = canmap.reply_id(rxid)
        ad = self.ad

        def tx(data):
            ad.send_frame(txid, data)

        return isotp.IsoTp(tx)

    def _frames(self, frames):
        for cid, ext, data in frames:
            if ext and (cid & 0xFF) not in self.accept:
                self.other_dst += 1
                continue
            p = self._dec.feed(cid, data, ext)
            if p is not None:
                self._q.append(p)

    def send_raw(self, pid, src, dst, payload):
        data = canmap.wire(pid, src, dst, payload)
        if len(data) <= canmap.SINGLE_MAX:
            self.ad.send_frame(canmap.can_id(pid, src, dst), data)
            self.tx_packets += 1
            return True
        ch = self._dec.channel(canmap.can_id(pid, dst, src, True))   # flow control comes back on this id
        drops = self._dec.drops
        for attempt in range(self.tries):
            if attempt:
                self.isotp_resent += 1
            refused = drops["overflow"] + ch.errors["overflow"]
            ch.send(data)
            t0 = self._ticks_ms()
            while ch.sending and not self.ad.closed:
                left = self.timeout_ms - self._ticks_diff(self._ticks_ms(), t0)
                if left <= 0:
                    ch.abort()
                    self.isotp_timeouts += 1
                    break
                self._frames(self.ad.poll(left))
            else:
                if self.ad.closed or drops["overflow"] + ch.errors["overflow"] != refused:
                    return False
                self.tx_packets += 1
                return True
        self.isotp_failed += 1
        return False

    def recv_ms(self, timeout_ms):
        """Packets received, waiting up to ``timeout_ms`` (None = forever) for at least one."""
        if self._q:
            out, self._q = self._q, []
            return out
        t0 = self._ticks_ms()
        wait = -1 if timeout_ms is None else timeout_ms
        while not self.ad.closed:
            self._frames(self.ad.poll(wait))
            if self._q:
                out, self._q = self._q, []
                return out
            if timeout_ms is not None:
                wait = timeout_ms - self._ticks_diff(self._ticks_ms(), t0)
                if wait <= 0:
                    return []
        return []

    def counters(self):
        d = self._dec.counters()
        d["other_dst"] = self.other_dst
        d["tx_isotp_timeouts"] = self.isotp_timeouts
        d["tx_isotp_resent"] = self.isotp_resent
        d["tx_isotp_failed"] = self.isotp_failed
        d["tx_packets"] = self.tx_packets
        c = getattr(self.ad, "counters", None)
        if c is not None:
            d.update(c())
        return d

    def close(self):
        self.ad.close()
