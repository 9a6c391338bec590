"""Host (CPython) transports carrying packets: pyserial, pseudo-terminals, python-can, in-process.

``open_link(spec, node)`` returns a ``Link``; specs:

- ``inproc``: an in-process pair; the returned Link's ``.peer`` is the other end (see ``inproc_pair``).
- ``loop://`` or ``serial:PATH`` or any pyserial URL/path (``/dev/ttyUSB0``, ``serial:/dev/pts/3``).
- ``pty``: create a pseudo-terminal pair; the Link holds the master, ``.peer_path`` is the slave for
  another process (``serial:PATH`` or ``protocol.stream.StreamLink``). The slave is in raw mode before any
  byte is written; this side keeps it open until the peer's first byte arrives, after which EIO on the
  master means the peer left (``closed``).
- ``can:virtual:CHANNEL`` (or ``can:INTERFACE:CHANNEL``): python-can.
- ``slcan:PATH``: python-can's slcan adapter on a serial device or pty slave, read in blocks and dropping
  malformed lines (``protocol.slcanbus.SlcanBus``).
- ``slcan-pty``: be the slcan *device*: create a pty, speak Lawicel ASCII on the master
  (``protocol.slcanbus.LawicelBus``), ``.peer_path`` for the process that opens ``slcan:PATH``.

Serial links frame with ``protocol.host`` (COBS + CRC-16). CAN links send a packet (payload and its end-to-end
check) of up to 8 bytes as one frame and longer ones with ISO-TP (PyPI ``can-isotp``), ids per
``protocol.can``; a receive thread answers ISO-TP flow control at once, and ``accept=(nodes...)`` makes a CAN
link also deliver packets addressed to the nodes it serves (see ``CanLink``).
"""

import collections
import logging
import os
import threading
import time
import tty

from protocol import can as canmap
from protocol import core, host
from protocol.fdport import PeerGone, _FdPort

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


# --- byte streams (protocol.fdport: a file descriptor's) -------------------------------------------------


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


# --- CAN -------------------------------------------------------------------------------------------------
class CanLink(Link):
    """Packets over a python-can bus: one frame up to 8 bytes (payload + check), else ISO-TP with can-isotp.

    Delivers packets addressed to this node, to BROADCAST, or to one of the ``accept`` nodes (names or
    addresses: the nodes this link serves, e.g. GROUND on the HIL host's BENCH link, whose replies and ISO-TP
    flow control come back addressed to GROUND); others are counted as ``other_dst``.
    ``seq`` is None on CAN (see ``protocol.can``).

    A receive thread reads the bus all the time, reassembles ISO-TP transfers and answers their flow control
    at once, as a CAN driver would. Frames that fail the end-to-end check, the table or ISO-TP's rules are
    dropped and counted by reason; so are the adapter's malformed lines (``protocol.slcanbus``). Only the bus
    failing (a closed port, a vanished adapter or peer) closes the link; ``closed_why`` says what when it was
    more than the other end closing in order (a port error, a peer that stopped reading).

    Sending: an ISO-TP transfer whose flow control does not come within ``isotp_timeout_s`` (ISO 15765-2's
    N_Bs, default 1 s) is aborted and the whole packet sent again, ``isotp_tries`` sends in all; if none gets
    through the packet is lost (``send_raw`` returns False, counted ``tx_isotp_failed``) and the layer above
    resends it (a TICK, a command, an ADCS cycle). A receiver's partial transfer is discarded after N_Cr
    (``isotp_timeout_s``) or on the next first frame on its id.
    """

    ISOTP_TIMEOUT = 1.0
    POLL_S = 0.05     # the receive thread's bus wait: how soon it sees close()

    def __init__(self, bus, node, accept=(), isotp_timeout_s=None, isotp_tries=3):
        Link.__init__(self, node)
        self.bus = bus
        self.accept = frozenset([self.node, 0xFF] + [core.node_id(n) for n in accept])
        self.isotp_timeout_s = self.ISOTP_TIMEOUT if isotp_timeout_s is None else float(isotp_timeout_s)
        self.isotp_tries = int(isotp_tries)
        self._dec = canmap.CanDecoder()
        self._stacks = {}   # rx id -> (TransportLayerLogic, deque of rx frames)
        self._rxq = collections.deque()
        self._cond = threading.Condition()   # guards everything above and every bus.send
        self.other_dst = 0
        self.isotp_errors = collections.Counter()
        self.tx_isotp_resent = 0
        self.tx_isotp_failed = 0
        self.last_sent = None
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
            ms = max(1, int(self.isotp_timeout_s * 1000))
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
        except can.CanError as exc:
            self.closed = True
            self.closed_why = self.closed_why or str(exc)

    def send_raw(self, pid, src, dst, payload):
        """Send one packet; a long one blocks until its ISO-TP transfer is done or given up (see the class
        docstring; ``last_sent`` says which). A flow control saying overflow counts as a failed try
        (``isotp_OverflowError``): flow control frames carry no end-to-end check, so damage can make one.
        Returns None: CAN has no sequence number."""
        self.last_sent = self._send(pid, src, dst, payload)

    def _send(self, pid, src, dst, payload):
        self._seq = (self._seq + 1) & 0xFF
        data = canmap.wire(pid, src, dst, payload)
        with self._cond:
            if len(data) <= canmap.SINGLE_MAX:
                self._tx(canmap.can_id(pid, src, dst), data)
                self.tx_frames += 1
                return not self.closed
            st, _ = self._stack(canmap.can_id(pid, dst, src, True))
            for attempt in range(self.isotp_tries):
                if attempt:
                    self.tx_isotp_resent += 1
                refused = self.isotp_errors["OverflowError"]
                st.send(data)
                st.process()
                deadline = time.monotonic() + self.isotp_timeout_s
                while st.transmitting() and not self.closed:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        st.stop_sending()
                        self.isotp_errors["TimeoutError"] += 1
                        break
                    self._cond.wait(min(left, 0.01))   # the receive thread takes the flow control
                    st.process()
                else:
                    if self.closed:
                        return False
                    if self.isotp_errors["OverflowError"] == refused:
                        self.tx_frames += 1
                        return True
                    # can-isotp stopped on an overflow answer: nothing was delivered. Flow control frames carry
                    # no check, so a damaged one can say overflow too: tried again like a lost one.
            self.tx_isotp_failed += 1
            return False

    def _receive(self):
        """The receive thread: frames to packets (and ISO-TP flow control) until close() or the bus fails."""
        import can
        while not self._stop:
            why = None
            try:
                msg = self.bus.recv(self.POLL_S)
                gone = getattr(self.bus, "peer_gone", False)
            except (can.CanError, OSError) as exc:   # the port failed, or the adapter or its host went away
                msg, gone = None, True
                if getattr(self.bus, "peer_gone", False):   # our slcan buses: the other end closed (orderly)
                    why = getattr(self.bus, "fail_why", None)
                else:
                    why = str(exc) or type(exc).__name__
            if msg is None and not gone:
                continue
            with self._cond:
                if msg is not None:
                    p = self._frame(msg)
                    if p is not None:
                        self._rxq.append(p)
                if gone:
                    self.closed = True
                    self.closed_why = self.closed_why or why
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
            d["tx_isotp_resent"] = self.tx_isotp_resent
            d["tx_isotp_failed"] = self.tx_isotp_failed
            d.update(("isotp_" + k, v) for k, v in self.isotp_errors.items())
            c = getattr(self.bus, "counters", None)
            if c is not None:
                d.update(c())
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


def open_can(interface, channel, node, accept=(), isotp_timeout_s=None, isotp_tries=3, **kw):
    """A CanLink on python-can's ``interface`` (``slcan``: ``protocol.slcanbus.SlcanBus``)."""
    import can
    try:
        if interface == "slcan":
            from protocol.slcanbus import SlcanBus
            bus = SlcanBus(channel, **kw)
        else:
            bus = can.Bus(interface=interface, channel=channel, **kw)
    except can.CanInterfaceNotImplementedError as exc:      # a typo in the spec: bad input
        raise ValueError("CAN interface %r: %s" % (interface, exc)) from None
    except can.CanInitializationError as exc:               # no such port or adapter: the link failed
        raise OSError("CAN %s channel %r: %s" % (interface, channel, exc)) from None
    return CanLink(bus, node, accept, isotp_timeout_s=isotp_timeout_s, isotp_tries=isotp_tries)


def open_slcan_device(node, accept=(), isotp_timeout_s=None, isotp_tries=3):
    """Be the slcan adapter: a CanLink on a Lawicel-speaking pty master; ``.peer_path`` for ``slcan:``."""
    from protocol.slcanbus import LawicelBus
    bus = LawicelBus()
    link = CanLink(bus, node, accept, isotp_timeout_s=isotp_timeout_s, isotp_tries=isotp_tries)
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
        return open_slcan_device(node, accept, **kw)
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
