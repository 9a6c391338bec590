"""Host (CPython) transports carrying packets: pyserial, pseudo-terminals, python-can, in-process.

``open_link(spec, node)`` returns a ``Link``; specs:

- ``inproc``: an in-process pair; the returned Link's ``.peer`` is the other end (see ``inproc_pair``).
- ``loop://`` or ``serial:PATH`` or any pyserial URL/path (``/dev/ttyUSB0``, ``serial:/dev/pts/3``).
- ``pty``: create a pseudo-terminal pair; the Link holds the master, ``.peer_path`` is the slave for
  another process (``serial:PATH`` or ``protocol.stream.StreamLink``). The slave is in raw mode before any
  byte is written; this side keeps it open until the peer's first byte arrives, after which EIO on the
  master means the peer left (``closed``).
- ``can:virtual:CHANNEL`` (or ``can:INTERFACE:CHANNEL``): python-can.
- ``slcan:PATH``: python-can's slcan adapter on a serial device or pty slave (``sleep_after_open=0``).
- ``slcan-pty``: be the slcan *device*: create a pty, speak Lawicel ASCII on the master (``LawicelBus``),
  ``.peer_path`` for the process that opens ``slcan:PATH``.

Serial links frame with ``protocol.host`` (COBS + CRC-16). CAN links send a payload of up to 8 bytes as one
frame and longer ones with ISO-TP (PyPI ``can-isotp``), ids per ``protocol.can``; a receive thread answers
ISO-TP flow control at once, and ``accept=(nodes...)`` makes a CAN link also deliver packets addressed to the
nodes it serves (see ``CanLink``).
"""

import collections
import errno
import logging
import os
import select
import threading
import time
import tty

from protocol import can as canmap
from protocol import core, host

# can-isotp logs each error it hands our error handler (counted: isotp_errors) as a WARNING too; with no logging
# configured, Python's last-resort handler printed those on the user's stderr
logging.getLogger("isotp").addHandler(logging.NullHandler())


class Link:
    """Common part: addressing, sequence numbers, ``send``; subclasses move frames."""

    def __init__(self, node):
        self.node = core.node_id(node)
        self.closed = False
        self.closed_why = None    # what closed it, when more than the peer leaving (a serial link)
        self.tx_frames = 0
        self._seq = 0

    def send(self, name_or_id, dst, payload=b"", **fields):
        """Send a packet from this node: ``payload`` bytes, or field values (defaults for the rest).

        Returns the sequence number used. Unknown names, bad lengths and out-of-range values raise ValueError.
        """
        pkt = core.packet_def(name_or_id)
        if payload:
            if fields:
                raise ValueError("%s: give payload bytes or fields, not both" % pkt.name)
            if len(payload) != pkt.size:
                raise ValueError("%s payload is %d bytes, expected %d" % (pkt.name, len(payload), pkt.size))
        else:
            payload = core.encode_payload(pkt.id, fields)
        seq = self._seq
        self.send_raw(pkt.id, self.node, core.node_id(dst), payload)
        return seq

    def send_raw(self, pid, src, dst, payload):
        raise NotImplementedError

    def recv(self, timeout=None):
        """Packets ``[(pid, src, dst, seq, payload)]``, waiting up to ``timeout`` s (None = forever) for at
        least one; [] on timeout or once the peer has left (then ``closed`` is True)."""
        raise NotImplementedError

    def counters(self):
        raise NotImplementedError

    def close(self):
        self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# --- byte streams ----------------------------------------------------------------------------------------
class PeerGone(Exception):
    """The other end of a byte stream closed."""


SPIN_S = 300e-6   # longest busy-poll before a blocking read on a pty or serial port
STALL_S = 5.0     # a pty peer that reads nothing for this long while our writes wait is gone (hung)


class _FdPort:
    """A file descriptor (pty master, posix serial port): select + os.read; writes wait while the peer reads,
    and a pty master we own is non-blocking so that a peer which stops reading (alive but hung, its pty buffer
    full) ends the link after ``STALL_S`` instead of blocking the writer for ever."""

    def __init__(self, fd, hold_fd=None, owns=True):
        self.fd = fd
        self._hold = hold_fd   # our copy of a pty slave, closed once the peer has spoken
        self._owns = owns
        if owns:
            os.set_blocking(fd, False)

    def read(self, timeout):
        r = None
        if timeout:
            # Busy-poll up to SPIN_S first: a lockstep peer answers within ~100 us, and a blocked wake-up
            # across cores costs tens of us on a VM (10x -> 15x real time for the MicroPython HIL).
            end = time.perf_counter() + min(SPIN_S, timeout)
            while not r and time.perf_counter() < end:
                r, _, _ = select.select((self.fd,), (), (), 0)
        if not r:
            r, _, _ = select.select((self.fd,), (), (), timeout)
        if not r:
            return b""
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise PeerGone() from None
            raise
        if not data:
            raise PeerGone()
        if self._hold is not None:
            os.close(self._hold)
            self._hold = None
        return data

    def write(self, data):
        mv = memoryview(data)
        end = None
        try:
            while mv:
                try:
                    n = os.write(self.fd, mv)
                except BlockingIOError:
                    n = 0
                if n:
                    mv = mv[n:]
                    end = None
                    continue
                now = time.monotonic()
                if end is None:
                    end = now + STALL_S
                elif now >= end:
                    raise PeerGone("the peer read nothing for %g s" % STALL_S)
                select.select((), (self.fd,), (), end - now)
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise PeerGone() from None
            raise

    def close(self):
        if self._hold is not None:
            os.close(self._hold)
            self._hold = None
        if self._owns:
            os.close(self.fd)


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


class SerialLink(Link):
    """Packets framed with COBS + CRC-16 (``protocol.host``) over a byte stream."""

    def __init__(self, port, node):
        Link.__init__(self, node)
        self._port = port
        self._dec = host.Decoder()
        self.peer_path = None
        self.peer = None

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


# --- CAN -------------------------------------------------------------------------------------------------
class CanLink(Link):
    """Packets over a python-can bus: one frame up to 8 bytes, else ISO-TP with can-isotp.

    Delivers packets addressed to this node, to BROADCAST, or to one of the ``accept`` nodes (names or
    addresses: the nodes this link serves, e.g. GROUND on the HIL host's BENCH link, whose replies and ISO-TP
    flow control come back addressed to GROUND); others are counted as ``other_dst``.
    ``seq`` is None on CAN (see ``protocol.can``).

    A receive thread reads the bus all the time, reassembles ISO-TP transfers and answers their flow control
    at once, as a CAN driver would: a peer's multi-frame send must not wait for this side to call ``recv``
    (it gives up after ``ISOTP_TIMEOUT`` and the packet is lost). ``recv`` takes the packets it queued.
    """

    ISOTP_TIMEOUT = 1.0
    POLL_S = 0.05     # the receive thread's bus wait: how soon it sees close()

    def __init__(self, bus, node, accept=()):
        Link.__init__(self, node)
        self.bus = bus
        self.accept = frozenset([self.node, 0xFF] + [core.node_id(n) for n in accept])
        self._dec = canmap.CanDecoder()
        self._stacks = {}   # rx id -> (TransportLayerLogic, deque of rx frames)
        self._rxq = collections.deque()
        self._cond = threading.Condition()   # guards everything above and every bus.send
        self.other_dst = 0
        self.isotp_errors = collections.Counter()
        self.peer_path = None
        self._stop = False
        self._thread = threading.Thread(target=self._receive, name="canlink-rx", daemon=True)
        self._thread.start()

    def _stack(self, rxid):
        entry = self._stacks.get(rxid)
        if entry is None:
            import isotp
            q = collections.deque()
            txid = canmap.reply_id(rxid)

            def txfn(m):
                self._tx(m.arbitration_id, m.data)

            def count(err):
                self.isotp_errors[type(err).__name__] += 1

            addr = isotp.Address(isotp.AddressingMode.Normal_29bits, txid=txid, rxid=rxid)
            ms = int(self.ISOTP_TIMEOUT * 1000)
            st = isotp.TransportLayerLogic(
                lambda *_: q.popleft() if q else None, txfn, addr, error_handler=count,
                params={"stmin": 0, "blocksize": 0, "rx_flowcontrol_timeout": ms + 500,   # ours fires first
                        "rx_consecutive_frame_timeout": ms, "max_frame_size": 4095})
            entry = self._stacks[rxid] = (st, q)
        return entry

    def _tx(self, cid, data):
        import can
        try:
            self.bus.send(can.Message(arbitration_id=cid, data=bytes(data), is_extended_id=True))
        except can.CanOperationError:
            self.closed = True

    def send_raw(self, pid, src, dst, payload):
        """Send one packet; a long one blocks until its ISO-TP transfer is done (TimeoutError after
        ``ISOTP_TIMEOUT`` s without flow control, ConnectionRefusedError if the receiver's flow control says
        overflow). Returns None: CAN frames carry no sequence number."""
        self._seq = (self._seq + 1) & 0xFF
        with self._cond:
            if len(payload) <= canmap.SINGLE_MAX:
                self._tx(canmap.can_id(pid, src, dst), payload)
            else:
                st, _ = self._stack(canmap.can_id(pid, dst, src, True))
                refused = self.isotp_errors["OverflowError"]
                st.send(bytes(payload))
                st.process()
                deadline = time.monotonic() + self.ISOTP_TIMEOUT
                while st.transmitting() and not self.closed:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        st.stop_sending()
                        raise TimeoutError("ISO-TP send of packet 0x%02x to node 0x%02x: no flow control"
                                           % (pid, dst))
                    self._cond.wait(min(left, 0.01))   # the receive thread takes the flow control
                    st.process()
                if self.isotp_errors["OverflowError"] != refused:      # can-isotp stopped: nothing was delivered
                    raise ConnectionRefusedError("ISO-TP send of packet 0x%02x to node 0x%02x: the receiver's flow "
                                                 "control says overflow (%d bytes)" % (pid, dst, len(payload)))
        self.tx_frames += 1

    def _receive(self):
        """The receive thread: frames to packets (and ISO-TP flow control) until close() or the bus fails."""
        import can
        while not self._stop:
            try:
                msg = self.bus.recv(self.POLL_S)
                gone = getattr(self.bus, "peer_gone", False)
            except (can.CanError, OSError):   # the slcan adapter or host went away
                msg, gone = None, True
            if msg is None and not gone:
                continue
            with self._cond:
                if msg is not None:
                    p = self._frame(msg)
                    if p is not None:
                        self._rxq.append(p)
                if gone:
                    self.closed = True
                self._cond.notify_all()
            if gone:
                return

    def _frame(self, msg):
        if msg.is_error_frame or msg.is_remote_frame:
            return None
        cid = msg.arbitration_id
        dst = cid & 0xFF
        if msg.is_extended_id and dst not in self.accept:
            self.other_dst += 1
            return None
        if msg.is_extended_id and cid & canmap.ISOTP_BIT and not cid & canmap.RESERVED_BIT:
            if (cid >> 17) & 0xFF not in core.PACKET or (cid >> 8) & 0xFF not in core.NODE_NAME:
                self._dec.drops["unknown_id"] += 1      # no ISO-TP stack for it: garbage ids would pile them up
                return None
            st, q = self._stack(cid)
            q.append(isotp_msg(msg))
            st.process()
            payload = st.recv()
            if payload is None:
                return None
            return self._dec.packet((cid >> 17) & 0xFF, (cid >> 8) & 0xFF, dst, bytes(payload))
        return self._dec.feed(cid, msg.data, msg.is_extended_id)

    def recv(self, timeout=None):
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._rxq:
                if self.closed:
                    return []
                if deadline is None:
                    self._cond.wait()
                else:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return []
                    self._cond.wait(left)
            out = list(self._rxq)
            self._rxq.clear()
            return out

    def counters(self):
        with self._cond:
            d = self._dec.counters()
            d["other_dst"] = self.other_dst
            d["tx_frames"] = self.tx_frames
            d.update(("isotp_" + k, v) for k, v in self.isotp_errors.items())
        return d

    def close(self):
        import can
        self._stop = True
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join()
        if self.bus is not None:
            try:
                self.bus.shutdown()
            except can.CanOperationError:  # an slcan adapter already gone
                pass
            self.bus = None
        with self._cond:
            self.closed = True
            self._cond.notify_all()


def isotp_msg(msg):
    import isotp
    return isotp.CanMessage(arbitration_id=msg.arbitration_id, data=msg.data, dlc=msg.dlc,
                            extended_id=msg.is_extended_id)


_HEX = b"0123456789ABCDEFabcdef"
LAWICEL_LINE_MAX = 26    # the longest Lawicel line before its CR: 'T', 8 id digits, the DLC, 16 data digits


def _lawicel_bus_class():
    import can

    class LawicelBus(can.BusABC):
        """The device side of an slcan adapter on a pty master: Lawicel ASCII in and out.

        Frames the slcan host sends (``T`` lines) are received here; frames sent here reach the host as
        ``T`` lines. Commands ``O``, ``C``, ``L``, ``S0``..``S9``, ``V``, ``N`` are answered like an adapter.
        """

        def __init__(self, channel="slcan-pty", **kw):
            self._master, slave = os.openpty()
            tty.setraw(slave)
            self.peer_path = os.ttyname(slave)
            self._port = _FdPort(self._master, hold_fd=slave)
            self._buf = bytearray()
            self._skip = False               # in an overlong line: dropped up to its CR
            self._rx = collections.deque()
            self.is_open = False
            self.peer_gone = False
            self._wlock = threading.Lock()   # replies from the receive thread, frames from any thread
            can.BusABC.__init__(self, channel, **kw)

        def _write(self, data):
            with self._wlock:
                try:
                    self._port.write(data)
                except PeerGone:
                    self.peer_gone = True

        def _line(self, line):
            if not line:
                return
            c = line[:1]
            if c in (b"T", b"t", b"R", b"r"):
                ext = c in (b"T", b"R")
                remote = c in (b"R", b"r")
                n = 8 if ext else 3
                # exactly: n hex id digits (29 or 11 bits), one DLC digit 0-8, 2 x DLC hex data digits
                dlc = line[1 + n:2 + n]
                dlc = int(dlc) if dlc.isdigit() and dlc <= b"8" else -1
                body = line[1:1 + n] + line[2 + n:]
                if (dlc < 0 or len(line) != 2 + n + (0 if remote else 2 * dlc) or body.strip(_HEX)
                        or int(line[1:1 + n], 16) > (0x1FFFFFFF if ext else 0x7FF)):
                    self._write(b"\a")
                    return
                cid = int(line[1:1 + n], 16)
                data = b"" if remote else bytes.fromhex(line[2 + n:].decode())
                if self.is_open:
                    self._rx.append(can.Message(arbitration_id=cid, is_extended_id=ext, data=data, dlc=dlc,
                                                is_remote_frame=remote, timestamp=time.time()))
                    self._write(b"Z\r" if ext else b"z\r")
                else:
                    self._write(b"\a")
            elif c in (b"O", b"L"):
                self.is_open = True
                self._write(b"\r")
            elif c == b"C":
                self.is_open = False
                self._write(b"\r")
            elif c == b"V":
                self._write(b"V1013\r")
            elif c == b"N":
                self._write(b"NFPS0\r")
            else:  # S0-S9, s, F, Z, ...: accepted
                self._write(b"\r")

        def _recv_internal(self, timeout):
            deadline = None if timeout is None else time.monotonic() + timeout
            while not self._rx:
                wait = None if deadline is None else max(0.0, deadline - time.monotonic())
                try:
                    data = self._port.read(wait)
                except PeerGone:
                    self.peer_gone = True
                    raise can.CanOperationError("the slcan host closed the pty") from None
                self._buf.extend(data)
                while True:
                    i = self._buf.find(b"\r")
                    if i < 0:
                        break
                    line = bytes(self._buf[:i])
                    del self._buf[:i + 1]
                    if self._skip:            # the end of an overlong line, already answered
                        self._skip = False
                    else:
                        self._line(line)
                if len(self._buf) > LAWICEL_LINE_MAX:     # no CR in sight: garbage, not a line; answered once
                    del self._buf[:]
                    if not self._skip:
                        self._skip = True
                        self._write(b"\a")
                if deadline is not None and time.monotonic() >= deadline:
                    break
            if self._rx:
                return self._rx.popleft(), False
            return None, False

        def send(self, msg, timeout=None):
            if msg.is_extended_id:
                head = "%s%08X%d" % ("R" if msg.is_remote_frame else "T", msg.arbitration_id, msg.dlc)
            else:
                head = "%s%03X%d" % ("r" if msg.is_remote_frame else "t", msg.arbitration_id, msg.dlc)
            line = head + ("" if msg.is_remote_frame else bytes(msg.data).hex().upper()) + "\r"
            self._write(line.encode())

        def shutdown(self):
            can.BusABC.shutdown(self)
            self._port.close()

    return LawicelBus


def open_can(interface, channel, node, accept=(), **kw):
    import can
    if interface == "slcan":
        kw.setdefault("sleep_after_open", 0)
    try:
        bus = can.Bus(interface=interface, channel=channel, **kw)
    except can.CanInterfaceNotImplementedError as exc:      # a typo in the spec: bad input
        raise ValueError("CAN interface %r: %s" % (interface, exc)) from None
    except can.CanInitializationError as exc:               # no such port or adapter: the link failed
        raise OSError("CAN %s channel %r: %s" % (interface, channel, exc)) from None
    return CanLink(bus, node, accept)


def open_slcan_device(node, accept=()):
    """Be the slcan adapter: a CanLink on a Lawicel-speaking pty master; ``.peer_path`` for ``slcan:``."""
    bus = _lawicel_bus_class()()
    link = CanLink(bus, node, accept)
    link.peer_path = bus.peer_path
    return link


def open_link(spec, node, **kw):
    """A Link for ``spec`` (see the module docstring); ``node`` is a node name or address.

    ``accept``: further destination nodes a CAN link delivers (see ``CanLink``); serial links deliver every
    packet whatever its destination, so it changes nothing there."""
    accept = kw.pop("accept", ())
    if spec == "inproc":
        a, _ = inproc_pair(node, kw.get("peer_node", "BROADCAST"))
        return a
    if spec == "pty":
        return open_pty(node)
    if spec == "slcan-pty":
        return open_slcan_device(node, accept)
    if spec.startswith("slcan:"):
        return open_can("slcan", spec[len("slcan:"):], node, accept, **kw)
    if spec.startswith("can:"):
        parts = spec.split(":", 2)
        if len(parts) != 3 or not parts[1] or not parts[2]:
            raise ValueError("CAN link spec %r: expected can:INTERFACE:CHANNEL" % spec)
        return open_can(parts[1], parts[2], node, accept, **kw)
    if spec.startswith("serial:"):
        return open_serial(spec[len("serial:"):], node, **kw)
    if "://" in spec or spec.startswith("/") or spec.upper().startswith("COM"):
        return open_serial(spec, node, **kw)
    raise ValueError("unknown link spec %r (inproc, pty, loop://, serial:PATH, can:virtual:CH, slcan:PATH, "
                     "slcan-pty)" % spec)
