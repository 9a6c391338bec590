"""Serial stream link on a tty or pty slave, for CPython and MicroPython (the firmware's link HAL uses it).

The device is opened twice, ``'rb'`` and ``'wb'`` (under the MicroPython unix port a single ``'r+b'``
handle fails its writes), put in raw mode before any byte is written, and read with ``select.poll`` then
one ``readinto`` into a preallocated buffer. VMIN = VTIME = 0 makes that ``readinto`` return what is
waiting instead of blocking until the buffer is full (MicroPython loops on ``read`` until it gets 0).
The peer leaving shows as POLLHUP/POLLERR or EIO and sets ``closed``.
Under MicroPython a TICK's way through (``ipoll``, ``readinto``, the viper ``Decoder`` fed the buffer
unsliced, ``Encoder`` frames written from its own buffer) allocates a few hundred bytes: the packet list,
tuple and payload, and the frame's view.

Same methods as ``protocol.link.Link``, except that ``recv`` takes its timeout in milliseconds.
"""

import select
import termios

from protocol import core
from protocol.compat import ticks_diff, ticks_ms, ticks_us

# Linux termios values (MicroPython's termios module has no flag constants).
# IGNBRK BRKINT PARMRK ISTRIP INLCR IGNCR ICRNL IXON
_IFLAG_OFF = 0o1 | 0o2 | 0o10 | 0o40 | 0o100 | 0o200 | 0o400 | 0o2000
_OPOST = 0o1
_LFLAG_OFF = 0o10 | 0o100 | 0o2 | 0o1 | 0o100000  # ECHO ECHONL ICANON ISIG IEXTEN
_CSIZE_PARENB = 0o60 | 0o400
_CS8 = 0o60
_VMIN = 6
_VTIME = 5


def poll_events(ipoll, poll, wait):
    """The read handle's poll events after waiting up to ``wait`` ms (-1: forever), 0 if none: through
    MicroPython's allocation-free ``ipoll`` when the port has it, else ``poll``."""
    if ipoll is not None:
        for e in ipoll(wait):
            return e[1]
        return 0
    ev = poll.poll(wait)
    return ev[0][1] if ev else 0


def set_raw(fd):
    """cfmakeraw() with VMIN = VTIME = 0 (read returns what is waiting), applied with TCSANOW so that
    bytes already queued are kept (tty.setraw and MicroPython's termios.setraw flush them)."""
    a = termios.tcgetattr(fd)
    a[0] &= ~_IFLAG_OFF
    a[1] &= ~_OPOST
    a[2] = (a[2] & ~_CSIZE_PARENB) | _CS8
    a[3] &= ~_LFLAG_OFF
    a[6][_VMIN] = 0
    a[6][_VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, a)


class StreamLink:
    """Packets over a serial device or pty slave (pure framing core)."""

    def __init__(self, path, node, bufsize=512):
        self.node = core.node_id(node)
        self.path = path
        self._r = open(path, "rb", buffering=0)
        try:
            set_raw(self._r.fileno())
            self._w = open(path, "wb", buffering=0)
        except Exception:
            self._r.close()
            raise
        self._poll = select.poll()
        self._poll.register(self._r, select.POLLIN)
        self._ipoll = getattr(self._poll, "ipoll", None)   # MicroPython: polls without allocating
        self._buf = bytearray(bufsize)
        self._dec = core.Decoder()
        self._enc = core.Encoder()
        self._seq = 0
        self.tx_frames = 0
        self.closed = False

    def send(self, name_or_id, dst, payload=b"", **fields):
        """Send a packet from this node; ``payload`` bytes, or field values (defaults for the rest).

        Returns the sequence number used.
        """
        pkt = core.packet_def(name_or_id)
        if payload:
            if len(payload) != pkt.size:
                raise ValueError("%s payload is %d bytes, expected %d" % (pkt.name, len(payload), pkt.size))
        else:
            payload = core.encode_payload(pkt.id, fields)
        seq = self._seq
        self._seq = (seq + 1) & 0xFF
        self.send_raw(pkt.id, self.node, core.node_id(dst), payload, seq)
        return seq

    def send_raw(self, pid, src, dst, payload, seq=None):
        """Send one frame as given (no table checks beyond the header)."""
        if seq is None:
            seq = self._seq
            self._seq = (seq + 1) & 0xFF
        self.write(self._enc.frame(pid, src, dst, seq, payload))
        self.tx_frames += 1

    def write(self, data):
        """Write raw bytes (frames, or garbage in tests); sets ``closed`` if the peer left."""
        try:
            n = self._w.write(data) or 0
            if n < len(data):    # rare: a partial write; the rest through a view
                mv = memoryview(data)
                while n < len(mv):
                    n += self._w.write(mv[n:]) or 0
        except OSError:
            self.closed = True

    def recv(self, timeout_ms=None):
        """Packets ``[(pid, src, dst, seq, payload)]``, waiting up to ``timeout_ms`` (None = forever) for
        at least one; [] on timeout or once the peer has left (then ``closed`` is True)."""
        t0 = ticks_ms()
        wait = -1 if timeout_ms is None else timeout_ms
        while not self.closed:
            ev = self._events(wait)
            if ev:
                n = 0
                if ev & select.POLLIN:
                    try:
                        n = self._r.readinto(self._buf)
                    except OSError:  # EIO: the peer closed the pty
                        n = 0
                if not n:
                    self.closed = True  # readable with nothing to read, POLLHUP or POLLERR
                    return []
                out = self._dec.feed(self._buf, n)
                if out:
                    return out
            if timeout_ms is not None:
                wait = timeout_ms - ticks_diff(ticks_ms(), t0)
                if wait <= 0:
                    return []
        return []

    def _events(self, wait):
        return poll_events(self._ipoll, self._poll, wait)

    def counters(self):
        """Drops by reason, frames received, sequence gaps and duplicates, frames sent."""
        d = self._dec.counters()
        d["tx_frames"] = self.tx_frames
        return d

    def close(self):
        if self._r is not None:
            self._poll.unregister(self._r)
            self._r.close()
            self._w.close()
            self._r = None
        self.closed = True
