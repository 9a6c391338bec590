"""Serial transports: a pyserial port (a device, ``loop://``, a URL), a pseudo-terminal this side creates
(``open_pty``: the master here, the slave's path for another process), and an in-process pair (``inproc_pair``);
frames COBS + CRC-16 (``protocol.host``)."""

import collections
import os
import threading
import time
import tty

from protocol import host
from protocol.fdport import PeerGone, _FdPort
from protocol.linkbase import Link


class _SerialPort:
    """A pyserial port without a file descriptor (``loop://``, sockets, ...)."""

    def __init__(self, ser):
        self.ser = ser
        self._timeout = -1

    def read(self, timeout):
        import serial
        if timeout != self._timeout:
            self.ser.timeout = timeout
            self._timeout = timeout
        try:
            data = self.ser.read(max(1, self.ser.in_waiting))
        except serial.SerialException:
            raise PeerGone() from None
        return data

    def write(self, data):
        self.ser.write(data)

    def close(self):
        self.ser.close()


class _PyserialFd(_FdPort):
    """A posix pyserial port: select + os.read on its fd (raw mode set by pyserial at open)."""

    def __init__(self, ser):
        _FdPort.__init__(self, ser.fileno(), owns=False)
        self.ser = ser

    def write(self, data):
        import serial
        try:
            self.ser.write(data)
        except serial.SerialException:
            raise PeerGone() from None

    def close(self):
        self.ser.close()


class _MemPipe:
    """One direction-pair end of an in-process byte pipe (thread safe, never blocks a writer)."""

    def __init__(self, cond, rx, tx, state):
        self._cond = cond
        self._rx = rx
        self._tx = tx
        self._state = state  # shared dict: open ends

    def read(self, timeout):
        with self._cond:
            if not self._rx:
                if self._state["open"] < 2:
                    raise PeerGone()
                self._cond.wait(timeout)
            if not self._rx:
                if self._state["open"] < 2:
                    raise PeerGone()
                return b""
            data = b"".join(self._rx)
            self._rx.clear()
            return data

    def write(self, data):
        with self._cond:
            if self._state["open"] < 2:
                raise PeerGone()
            self._tx.append(bytes(data))
            self._cond.notify_all()

    def close(self):
        with self._cond:
            self._state["open"] -= 1
            self._cond.notify_all()


RX_TAIL = 1024


class SerialLink(Link):
    """Packets framed with COBS + CRC-16 (``protocol.host``) over a byte stream. ``rx_tail`` keeps the last
    ``RX_TAIL`` bytes received: what a board printed instead of frames (a traceback) can be told."""

    def __init__(self, port, node):
        Link.__init__(self, node)
        self._port = port
        self._dec = host.Decoder()
        self.peer_path = None
        self.peer = None
        self.rx_tail = bytearray()     # the last RX_TAIL bytes received, frames or not (a board's console text)

    def send_raw(self, pid, src, dst, payload):
        """Send one frame; returns its sequence number."""
        seq = self._seq
        self._seq = (seq + 1) & 0xFF
        self.write(host.encode_frame(pid, src, dst, seq, payload))
        self.tx_frames += 1
        return seq

    def write(self, data):
        """Raw bytes onto the stream (tests use it to inject damage); sets ``closed`` if the peer left."""
        if self.closed:
            return
        try:
            self._port.write(data)
        except PeerGone as exc:
            self.closed = True
            self.closed_why = str(exc) or None

    def recv(self, timeout=None):
        deadline = None if timeout is None else time.monotonic() + timeout
        wait = timeout
        while not self.closed:
            try:
                data = self._port.read(wait)
            except PeerGone:
                self.closed = True
                return []
            if data:
                self.rx_tail += data
                if len(self.rx_tail) > RX_TAIL:
                    del self.rx_tail[:-RX_TAIL]
                out = self._dec.feed(data)
                if out:
                    return out
            if deadline is not None:
                wait = deadline - time.monotonic()
                if wait <= 0:
                    return []
        return []

    def counters(self):
        d = self._dec.counters()
        d["tx_frames"] = self.tx_frames
        return d

    def close(self):
        if self._port is not None:
            self._port.close()
            self._port = None
        self.closed = True


def inproc_pair(node_a, node_b):
    """Two connected in-process serial Links (frames really go through COBS/CRC)."""
    cond = threading.Condition()
    ab = collections.deque()
    ba = collections.deque()
    state = {"open": 2}
    a = SerialLink(_MemPipe(cond, ba, ab, state), node_a)
    b = SerialLink(_MemPipe(cond, ab, ba, state), node_b)
    a.peer = b
    b.peer = a
    return a, b


def open_pty(node):
    """A SerialLink on a new pty master; ``.peer_path`` is the slave (already raw) for the peer."""
    master, slave = os.openpty()
    tty.setraw(slave)
    link = SerialLink(_FdPort(master, hold_fd=slave), node)
    link.peer_path = os.ttyname(slave)
    return link


def open_serial(url, node, baudrate=115200):
    """A SerialLink on a pyserial port (path or URL such as ``loop://``)."""
    import serial
    ser = serial.serial_for_url(url, baudrate=baudrate, timeout=0)
    try:
        fd = ser.fileno()
    except (AttributeError, serial.SerialException, OSError):
        fd = None
    return SerialLink(_PyserialFd(ser) if isinstance(fd, int) else _SerialPort(ser), node)
