"""CAN HAL over Lawicel (slcan) ASCII: the firmware plays the serial-CAN adapter, the host opens python-can's
``slcan`` interface on the other end of the pty. Runs under the MicroPython unix port and CPython.

On a board a ``machine.CAN`` backend (``CAN.send(data, id, extframe=True)`` / ``CAN.recv``) would replace
``SlcanAdapter``: ``CanPort`` only needs ``send_frame(cid, data)`` and ``poll(timeout_ms)`` returning received
frames, so the packet layer (29-bit ids of ``protocol.can``, ISO-TP of ``protocol.isotp`` for payloads over
8 bytes, flow control answered at once) stays the same.

Adapter side of Lawicel, as a CANable/USBtin answers (``\\r`` = OK, ``\\a`` = error):
``O``/``L`` open (normal/listen), ``C`` close, ``S0``-``S8`` bit rate, ``s`` BTR, ``V`` version ``V1013``,
``N`` serial ``NFPS0``, ``F`` status ``F00``, ``Z`` timestamps; ``Tiiiiiiiildd..`` / ``tiiildd..`` a frame to
transmit (answered ``Z``/``z``, or ``\\a`` when closed or malformed). Received frames go out as ``T`` lines.

The fd (a pty master, non-blocking) is read with ``select.poll`` and ``readinto`` into a preallocated buffer;
lines are parsed in place (hex digits decoded arithmetically, ``_hexval``), T lines are written from one
preallocated buffer.
"""

import select

from protocol import can as canmap
from protocol import core, isotp
from protocol.stream import poll_events, ticks_diff, ticks_ms

_HEX = b"0123456789ABCDEF"
_OK = b"\r"
_ERR = b"\a"


def _hexval(c):
    if 48 <= c <= 57:
        return c - 48
    c |= 0x20
    if 97 <= c <= 102:
        return c - 87
    return -1


def _hexnum(b, i, n):
    """int of the n hex digits at b[i:], -1 if any is not hex."""
    v = 0
    for k in range(i, i + n):
        d = _hexval(b[k])
        if d < 0:
            return -1
        v = (v << 4) | d
    return v


class SlcanAdapter:
    """The adapter side of Lawicel on a file descriptor (int) or a path; frames in and out.

    ``poll(timeout_ms)`` reads what has arrived, answers commands, and returns the list of frames the host
    asked to transmit, ``[(can_id, extended, data)]``; ``send_frame(cid, data)`` hands a received CAN frame to
    the host (a ``T`` line). Frames arriving while the channel is closed are refused with BEL, as an adapter
    does. Counters: ``n_rx``, ``n_tx``, ``n_bad`` (malformed lines), ``n_closed`` (frames while closed).
    """

    def __init__(self, dev, bufsize=1024):
        self._f = open(dev, "r+b", buffering=0)
        self._poll = select.poll()
        self._poll.register(self._f, select.POLLIN)
        self._ipoll = getattr(self._poll, "ipoll", None)
        self._buf = bytearray(bufsize)
        self._line = bytearray(64)
        self._n = 0
        self._tline = bytearray(1 + 8 + 1 + 16 + 1)
        self.is_open = False
        self.bitrate = None
        self.closed = False
        self.n_rx = self.n_tx = self.n_bad = self.n_closed = 0

    def _write(self, data):
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
        except OSError:
            self.closed = True

    def send_frame(self, cid, data):
        """One received CAN frame (29-bit id) to the host: ``T`` + 8 hex id + dlc + data + CR."""
        b = self._tline
        b[0] = 84  # 'T'
        for k in range(8):
            b[1 + k] = _HEX[(cid >> (28 - 4 * k)) & 0xF]
        n = len(data)
        b[9] = 48 + n
        i = 10
        for k in range(n):
            v = data[k]
            b[i] = _HEX[v >> 4]
            b[i + 1] = _HEX[v & 0xF]
            i += 2
        b[i] = 13
        self._write(memoryview(b)[:i + 1])
        self.n_tx += 1

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
                except OSError:   # EIO: the host closed the pty
                    n = 0
            if n is None:
                if ev & (select.POLLHUP | select.POLLERR):
                    self.closed = True
                return out
            if n == 0:
                self.closed = True
                return out
            self._bytes(n, out)
            if out:
                return out
            wait = 0
        return out

    def _bytes(self, n, out):
        buf, line = self._buf, self._line
        for k in range(n):
            c = buf[k]
            if c == 13 or c == 10:
                if self._n < 0:           # the end of an overlong line: answered as a malformed command
                    self._n = 0
                    self._write(_ERR)
                elif self._n:
                    self._command(self._n, out)
                    self._n = 0
                elif c == 13:
                    self._write(_OK)     # an empty command: the adapter answers OK (python-can flushes so)
            elif self._n < 0:
                pass                      # the rest of an overlong line
            elif self._n < len(line):
                line[self._n] = c
                self._n += 1
            else:
                self._n = -1              # overlong line: drop it, up to its end
                self.n_bad += 1

    def _command(self, n, out):
        b = self._line
        c = b[0]
        if c == 84 or c == 116:          # T / t
            ext = c == 84
            w = 8 if ext else 3
            if n < w + 2:
                self.n_bad += 1
                self._write(_ERR)
                return
            cid = _hexnum(b, 1, w)
            dlc = _hexval(b[1 + w])
            if cid < 0 or dlc < 0 or dlc > 8 or n < 2 + w + 2 * dlc:
                self.n_bad += 1
                self._write(_ERR)
                return
            if not self.is_open:
                self.n_closed += 1
                self._write(_ERR)
                return
            data = bytearray(dlc)
            for k in range(dlc):
                hi = _hexval(b[2 + w + 2 * k])
                lo = _hexval(b[3 + w + 2 * k])
                if hi < 0 or lo < 0:
                    self.n_bad += 1
                    self._write(_ERR)
                    return
                data[k] = (hi << 4) | lo
            out.append((cid, ext, data))
            self.n_rx += 1
            self._write(b"Z\r" if ext else b"z\r")
        elif c == 79 or c == 76:         # O / L
            self.is_open = True
            self._write(_OK)
        elif c == 67:                     # C
            self.is_open = False
            self._write(_OK)
        elif c == 83:                     # S0..S8
            d = _hexval(b[1]) if n > 1 else -1
            if 0 <= d <= 8 and not self.is_open:
                self.bitrate = d
                self._write(_OK)
            else:
                self._write(_ERR)
        elif c == 86:                     # V
            self._write(b"V1013\r")
        elif c == 78:                     # N
            self._write(b"NFPS0\r")
        elif c == 70:                     # F
            self._write(b"F00\r")
        else:                             # s (BTR), Z (timestamps), Y, ...: accepted
            self._write(_OK)

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

    ``send_raw(pid, src, dst, payload)``: one frame, or ISO-TP (FF, then the CFs as the receiver's flow
    control arrives; up to ``isotp_timeout_ms`` waiting, frames received meanwhile are kept).
    ``recv_ms(timeout_ms)``: packets ``[(pid, src, dst, None, payload)]`` for this node, BROADCAST or an
    ``accept`` node. Drops by reason in ``counters()``.
    """

    def __init__(self, adapter, node, accept=(), isotp_timeout_ms=1000):
        self.ad = adapter
        self.node = core.node_id(node)
        self.accept = [self.node, 0xFF] + [core.node_id(a) for a in accept]
        self.timeout_ms = isotp_timeout_ms
        self._dec = canmap.CanDecoder(self._new_channel)   # its ISO-TP channels answer with flow control
        self._q = []
        self.other_dst = 0
        self.isotp_timeouts = 0
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
        if len(payload) <= canmap.SINGLE_MAX:
            self.ad.send_frame(canmap.can_id(pid, src, dst), payload)
        else:
            ch = self._dec.channel(canmap.can_id(pid, dst, src, True))   # flow control comes back on this id
            ch.send(payload)
            t0 = ticks_ms()
            while ch.sending and not self.ad.closed:
                left = self.timeout_ms - ticks_diff(ticks_ms(), t0)
                if left <= 0:
                    ch.abort()
                    self.isotp_timeouts += 1
                    return False
                self._frames(self.ad.poll(left))
        self.tx_packets += 1
        return True

    def recv_ms(self, timeout_ms):
        """Packets received, waiting up to ``timeout_ms`` (None = forever) for at least one."""
        if self._q:
            out, self._q = self._q, []
            return out
        t0 = ticks_ms()
        wait = -1 if timeout_ms is None else timeout_ms
        while not self.ad.closed:
            self._frames(self.ad.poll(wait))
            if self._q:
                out, self._q = self._q, []
                return out
            if timeout_ms is not None:
                wait = timeout_ms - ticks_diff(ticks_ms(), t0)
                if wait <= 0:
                    return []
        return []

    def counters(self):
        d = self._dec.counters()
        d["other_dst"] = self.other_dst
        d["isotp_timeouts"] = self.isotp_timeouts
        d["tx_packets"] = self.tx_packets
        d["slcan_bad"] = self.ad.n_bad
        d["slcan_closed"] = self.ad.n_closed
        return d

    def close(self):
        self.ad.close()
