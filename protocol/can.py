"""CAN mapping of the packet table: 29-bit ids, single frames, ISO-TP for longer payloads, DBC file.

Pure Python (CPython and MicroPython). 29-bit extended identifier::

    bits 28..26  priority, 0 = most urgent (derived from the packet id, see ``priority``)
    bit  25      ISO-TP: 1 = the frame is part of an ISO 15765-2 transfer carrying the payload
    bits 24..17  packet id
    bit  16      reserved, 0 (frames with it set are dropped)
    bits 15..8   source node
    bits  7..0   destination node

Every packet carries an end-to-end check after its payload: 2 bytes, little-endian, CRC-16/CCITT-FALSE
(the serial frame's CRC) over ``pid, src, dst`` and the payload (``check``). The CAN bus's own CRC-15 covers a
frame on the wire only: an slcan adapter's ASCII stream, a USB-serial harness or a gateway may damage a frame
before or after it, and a flipped hex digit is still a valid Lawicel line. The check catches that, and a frame
delivered to the wrong packet id or node (the id is in the CRC), as CSP's CRC32 and AUTOSAR E2E do.

A packet whose payload and check fit 8 bytes is one frame with the ISO-TP bit clear: data = payload (exactly
as the serial payload, little-endian fields) + check, so the generated DBC describes it. A longer one is sent
with ISO-TP on the id with the ISO-TP bit set; the receiver's flow control frames go back on the same id with
source and destination swapped. CAN carries no sequence number (arbitration keeps order): decoded packets have
``seq`` None; a lost packet is the sender's to resend (``protocol.link.CanLink``, ``firmware.hal.slcan``).
"""

from protocol import core, isotp, lawicel, table

SINGLE_MAX = 8         # data bytes of a classic CAN frame
CHECK_BYTES = 2        # the end-to-end check after each payload
ISOTP_BIT = 1 << 25
RESERVED_BIT = 1 << 16
EFF_MASK = 0x1FFFFFFF
PID_MASK = 0xFF << 17

# (first id, last id, priority): lockstep first, bulk uploads last.
PRIORITIES = (
    (0x10, 0x1F, 1),  # lockstep tick / FSM command / P-FSM / Q2
    (0x01, 0x0F, 2),  # hello, ack, nack
    (0x40, 0x4F, 3),  # wheels and attitude sensors
    (0x20, 0x3F, 4),  # controller and player settings, status, upload begin/end
)
CHUNK_PRIORITY = 6     # *_CHUNK upload packets
DEFAULT_PRIORITY = 5

DROP_REASONS = ("not_extended", "reserved_bit", "unknown_id", "bad_length", "bad_crc") + isotp.ERRORS
SLCAN_DROPS = tuple("slcan_" + r for r in lawicel.DROPS)   # malformed Lawicel lines, on whichever side reads
RX_DROPS = tuple(set(DROP_REASONS)) + SLCAN_DROPS   # bad_length is a frame's and an ISO-TP transfer's: one counter
LINK_DROPS = tuple(set(core.DROP_REASONS + RX_DROPS))   # a serial link's decoder or a CAN link's, each once

# What arrived damaged, apart from what was lost to slowness. Damaged: a frame failing the end-to-end check or the
# table, an ISO-TP frame breaking the protocol's rules by its content (a wrong sequence number or length, a flow
# control frame saying overflow: no node here refuses a transfer, and flow control carries no check), a malformed
# Lawicel line. Not damage: a transfer timed out or interrupted on receive (``unexpected_cf``; can-isotp's
# ``ISOTP_RX_LATE``: a slow sender), a frame refused by a closed slcan channel (``slcan_closed``), and what a
# port counts of its own sends (``tx_*``: ISO-TP's N_Bs, resends, failures).
RX_DAMAGE = tuple(r for r in set(DROP_REASONS) if r != "unexpected_cf") + tuple(
    "slcan_" + r for r in lawicel.DROPS if r != "closed")
# can-isotp's receive errors (``protocol.canlink.CanLink`` counts each as ``isotp_`` + its class name; its send
# errors as ``tx_isotp_`` + the name, ``ISOTP_TX``)
ISOTP_DAMAGE = tuple("isotp_" + n for n in (
    "WrongSequenceNumberError", "InvalidCanDataError", "ChangingInvalidRXDLError", "FrameTooLongError",
    "MissingEscapeSequenceError", "UnsupportedWaitFrameError", "OverflowError"))
ISOTP_RX_LATE = tuple("isotp_" + n for n in (
    "ConsecutiveFrameTimeoutError", "UnexpectedConsecutiveFrameError", "ReceptionInterruptedWithFirstFrameError",
    "ReceptionInterruptedWithSingleFrameError"))
ISOTP_TX = ("TimeoutError", "FlowControlTimeoutError", "UnexpectedFlowControlError", "MaximumWaitFrameReachedError",
            "BadGeneratorError")
LINK_DAMAGE = tuple(set(core.DROP_REASONS + RX_DAMAGE)) + ISOTP_DAMAGE   # a serial decoder's or a CAN link's


def rx_drops(counters, reasons=RX_DROPS):
    """What a port dropped on receive, from its ``counters()``: each of ``reasons`` once (default the CAN
    decoder's and the Lawicel adapter's), and every ISO-TP receive error or timeout the port counts (``isotp_*``:
    can-isotp's). Frames for other nodes and what the port counts of its own sends (``tx_*``) are not drops."""
    n = 0
    for k, v in counters.items():
        if k in reasons or k.startswith("isotp_"):
            n += v
    return n


def rx_damaged(counters, reasons=LINK_DAMAGE):
    """What arrived damaged, from a port's ``counters()``: the drops of ``reasons`` (default ``LINK_DAMAGE``:
    a serial link's decoder, a CAN link's decoder, can-isotp's and the Lawicel lines'), never a timeout, an
    interrupted transfer or a send of its own (see ``RX_DAMAGE``)."""
    n = 0
    for k in reasons:
        v = counters.get(k)
        if v:
            n += v
    return n


def priority(pid):
    """CAN priority of a packet id (0 = most urgent)."""
    d = core.PACKET.get(pid)
    if d is not None and d.name.endswith("_CHUNK"):
        return CHUNK_PRIORITY
    for lo, hi, p in PRIORITIES:
        if lo <= pid <= hi:
            return p
    return DEFAULT_PRIORITY


def can_id(pid, src, dst, iso=False):
    """The 29-bit id of a packet from ``src`` to ``dst`` (``iso``: an ISO-TP frame)."""
    return ((priority(pid) << 26) | (ISOTP_BIT if iso else 0) | ((pid & 0xFF) << 17)
            | ((src & 0xFF) << 8) | (dst & 0xFF))


def split_id(cid):
    """(priority, iso, pid, src, dst) of a 29-bit id."""
    return (cid >> 26) & 7, (cid >> 25) & 1, (cid >> 17) & 0xFF, (cid >> 8) & 0xFF, cid & 0xFF


def reply_id(cid):
    """The same id with source and destination swapped (ISO-TP flow control goes back on it)."""
    return (cid & ~0xFFFF & EFF_MASK) | ((cid & 0xFF) << 8) | ((cid >> 8) & 0xFF)


def is_single(pid):
    """True when packet ``pid`` (payload and check) fits one frame."""
    return core.PACKET[pid].size + CHECK_BYTES <= SINGLE_MAX


def check(pid, src, dst, payload):
    """The end-to-end check of a packet: CRC-16/CCITT-FALSE over ``pid, src, dst`` then the payload."""
    return core.crc16(payload, core.crc16(bytes((pid & 0xFF, src & 0xFF, dst & 0xFF))))


def wire(pid, src, dst, payload):
    """The bytes a packet puts on CAN: the payload, then its check (little-endian)."""
    c = check(pid, src, dst, payload)
    return bytes(payload) + bytes((c & 0xFF, c >> 8))


def encode_frames(pid, src, dst, payload):
    """[(can_id, data)] for one packet: one frame, or ISO-TP FF+CFs (no flow control)."""
    data = wire(pid, src, dst, payload)
    if len(data) <= SINGLE_MAX:
        return [(can_id(pid, src, dst), data)]
    cid = can_id(pid, src, dst, True)
    return [(cid, f) for f in isotp.segment(data)]


def encode_packet(name_or_id, src, dst, values=None, **kw):
    pkt = core.packet_def(name_or_id)
    return encode_frames(pkt.id, src, dst, core.encode_payload(pkt.id, values, **kw))


class CanDecoder:
    """Frames in, packets out; never raises on frame contents. Drops counted in ``drops[reason]``.

    ``feed(can_id, data, extended=True)`` returns ``(pid, src, dst, None, payload)`` or None.
    ISO-TP transfers are reassembled per id (``channel``), by default passively (listen only), so a
    ``candump`` log decodes without flow control frames; ``make_channel(can_id)``, if given, makes the id's
    ``isotp.IsoTp`` instead (a node that answers with flow control, and sends its own transfers on it).
    """

    def __init__(self, make_channel=None):
        self.drops = {}
        for r in DROP_REASONS:
            self.drops[r] = 0
        self.frames = 0
        self._iso = {}
        self._make = make_channel

    def channel(self, cid):
        """The ISO-TP channel of id ``cid``, made on first use."""
        ch = self._iso.get(cid)
        if ch is None:
            ch = self._iso[cid] = isotp.IsoTp() if self._make is None else self._make(cid)
        return ch

    def feed(self, cid, data, extended=True):
        if not extended:
            self.drops["not_extended"] += 1
            return None
        if cid & RESERVED_BIT or cid > EFF_MASK:
            self.drops["reserved_bit"] += 1
            return None
        pid = (cid >> 17) & 0xFF
        if cid & ISOTP_BIT:
            ch = self.channel(cid)
            before = sum(ch.errors.values())
            payload = ch.feed(data)
            if sum(ch.errors.values()) != before:
                for r in isotp.ERRORS:
                    self.drops[r] += ch.errors[r]
                    ch.errors[r] = 0
            if payload is None:
                return None
        else:
            payload = bytes(data)
        return self.packet(pid, (cid >> 8) & 0xFF, cid & 0xFF, payload)

    def packet(self, pid, src, dst, data):
        """Check a frame's or a reassembled transfer's data (payload + check) against the table and the
        check; the packet tuple (payload without the check) or None (counted)."""
        pkt = core.PACKET.get(pid)
        if pkt is None:
            self.drops["unknown_id"] += 1
            return None
        n = pkt.size
        if len(data) != n + CHECK_BYTES:
            self.drops["bad_length"] += 1
            return None
        payload = bytes(data[:n])
        if check(pid, src, dst, payload) != data[n] | (data[n + 1] << 8):
            self.drops["bad_crc"] += 1
            return None
        self.frames += 1
        return (pid, src, dst, None, payload)

    def counters(self):
        d = {}
        for r in self.drops:
            d[r] = self.drops[r]
        d["frames"] = self.frames
        return d


# --- candump -L log lines ----------------------------------------------------------------------------
def candump_line(cid, data, t=0.0, channel="can0"):
    """One ``candump -L`` line: ``(1700000000.000000) can0 08041001#0000`` (an ACK from CONTROLLER to GROUND)."""
    return "(%.6f) %s %08X#%s" % (t, channel, cid, "".join("%02X" % b for b in data))


def parse_candump(line):
    """(t, channel, can_id, extended, data) of a ``candump -L`` line; ValueError if malformed."""
    parts = line.split()
    if len(parts) != 3 or "#" not in parts[2]:
        raise ValueError("not a candump -L line: %r" % line)
    ident, _, hexdata = parts[2].partition("#")
    if hexdata.startswith("R"):
        raise ValueError("remote frame: %r" % line)
    if hexdata.startswith("#"):
        raise ValueError("CAN FD frame not supported: %r" % line)
    return (float(parts[0].strip("()")), parts[1], int(ident, 16), len(ident) == 8,
            bytes.fromhex(hexdata))


# --- DBC ---------------------------------------------------------------------------------------------
_BITS = {"B": 8, "b": 8, "H": 16, "h": 16, "I": 32, "i": 32, "f": 32}


def _num(x):
    r = repr(float(x))
    return r[:-2] if r.endswith(".0") else r


def dbc_text():
    """A DBC file describing every single-frame packet (Intel byte order, like the serial payload), its
    end-to-end check the last signal, ``e2e_check`` (see the module docstring).

    Message ids carry the packet id with the table's source/destination where it names one node (else
    0); look frames up with a frame-id mask of ``PID_MASK | ISOTP_BIT`` (cantools: ``frame_id_mask``,
    ``get_message_by_frame_id``) to match frames from any node.
    """
    lines = ['VERSION ""', "", "NS_ :", "", "BS_:", "", "BU_: " + " ".join(n[0] for n in table.NODES), ""]
    floats = []
    comments = []
    for pid in sorted(core.PACKET):
        pkt = core.PACKET[pid]
        if not is_single(pid):
            continue
        src = core.NODE.get(pkt.src, 0)
        dst = core.NODE.get(pkt.dst, 0)
        cid = can_id(pid, src, dst)
        sender = pkt.src if pkt.src in core.NODE else "Vector__XXX"
        receiver = pkt.dst if pkt.dst in core.NODE else "Vector__XXX"
        lines.append("BO_ %d %s: %d %s" % (cid | 0x80000000, pkt.name, pkt.size + CHECK_BYTES, sender))
        comments.append('CM_ BO_ %d "%s";' % (cid | 0x80000000, pkt.doc.replace('"', "'")))
        bit = 0
        for f in pkt.fields:
            name, fmt, unit, scale = f[0], f[1], f[2], f[3]
            n = _BITS[fmt]
            lo, hi = core.field_range(f)
            sign = "-" if fmt in "bhif" else "+"
            if fmt == "f":
                pmin = lo if lo is not None else 0
                pmax = hi if hi is not None else 0
                floats.append("SIG_VALTYPE_ %d %s : 1;" % (cid | 0x80000000, name))
            else:
                pmin, pmax = lo * scale, hi * scale
            lines.append(' SG_ %s : %d|%d@1%s (%s,0) [%s|%s] "%s" %s' % (
                name, bit, n, sign, _num(scale), _num(pmin), _num(pmax), unit, receiver))
            comments.append('CM_ SG_ %d %s "%s";' % (cid | 0x80000000, name, f[7].replace('"', "'")))
            bit += n
        lines.append(' SG_ e2e_check : %d|16@1+ (1,0) [0|65535] "" %s' % (bit, receiver))
        comments.append('CM_ SG_ %d e2e_check "CRC-16/CCITT-FALSE over pid, src, dst and the payload";'
                        % (cid | 0x80000000))
        lines.append("")
    return "\n".join(lines + comments + [""] + floats) + "\n"
