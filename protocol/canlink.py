"""The CAN transport: python-can's buses (``virtual``, ``slcan`` through ``protocol.slcanbus.SlcanBus``, any
interface), a packet of up to 8 bytes as one frame and longer ones with ISO-TP (can-isotp), ids per
``protocol.can``; ``open_slcan_device`` is the Lawicel adapter's side on a pty (``protocol.slcanbus.LawicelBus``)."""

import collections
import logging
import threading
import time

from protocol import can as canmap
from protocol import core
from protocol.linkbase import Link

# can-isotp logs each error it hands our error handler (counted: isotp_errors) as a WARNING too; with no logging
# configured, Python's last-resort handler printed those on the user's stderr
logging.getLogger("isotp").addHandler(logging.NullHandler())


class CanLink(Link):
    """Packets over a python-can bus: one frame up to 8 bytes (payload + check), else ISO-TP with can-isotp.

    Delivers packets addressed to this node, to BROADCAST, or to one of the ``accept`` nodes (names or
    addresses: the nodes this link serves, e.g. GROUND on the HIL host's BENCH link, whose replies and ISO-TP
    flow control come back addressed to GROUND); others are counted as ``other_dst``.
    ``seq`` is None on CAN (see ``protocol.can``).

    A receive thread reads the bus all the time, reassembles ISO-TP transfers and answers their flow control
    at once, as a CAN driver would. Frames that fail the end-to-end check, the table or ISO-TP's rules are
    dropped and counted by reason; so are the adapter's malformed lines (``protocol.slcanbus``). can-isotp's
    errors are counted by cause: ``isotp_`` + its name on receive, ``tx_isotp_`` + its name for this link's own
    sends (``protocol.can.ISOTP_TX``: N_Bs timeouts, late flow control); ``protocol.can.rx_damaged`` tells the
    damaged from the late. Only the bus
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
        self._bus_counters = {}   # the bus's last counters, once close() has let it go
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
            for k, v in self.isotp_errors.items():
                d[("tx_isotp_" if k in canmap.ISOTP_TX else "isotp_") + k] = v
            c = getattr(self.bus, "counters", None)
            d.update(c() if c is not None else self._bus_counters)
        return d

    def close(self):
        """Stop the receive thread and shut the bus down; the bus's counters (an slcan port's lines dropped,
        refused, re-opened; injected faults) are read first and stay in ``counters()``."""
        import can
        self._stop = True
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join()
        if self.bus is not None:
            c = getattr(self.bus, "counters", None)
            if c is not None:
                with self._cond:
                    self._bus_counters = dict(c())
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
