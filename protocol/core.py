"""The packet table's lookups and payload codecs (names, ids, ``PacketDef``s, field checks), CRC-32, and the
serial framing of ``protocol.frame`` under the same names (``core.Decoder``, ``core.crc16``, ...).

Runs under CPython and MicroPython (the unix-port firmware and the ADCS use it); a board short of RAM imports
``protocol.frame`` and ``protocol.consts`` instead (the controller on the 32 KB Cortex-M0 does).
"""

import struct

from protocol import table
from protocol.consts import FLOAT32_MAX
from protocol.frame import (CRC_SIZE, DROP_REASONS, FAST, HEADER_FMT, HEADER_SIZE, MAX_BODY, MAX_FRAME,  # noqa: F401
                            MAX_PAYLOAD, Decoder, Encoder, cobs_decode, cobs_decode_pure, cobs_encode,
                            cobs_encode_pure, crc16, crc16_pure, encode_body, encode_frame)
# largest finite double ('d' fields), from its bytes: as a literal it freezes to an "inf" constant that a port with
# single-precision floats cannot compile; there it is inf at run time (any finite value is in range)
FLOAT64_MAX = struct.unpack("<d", b"\xff\xff\xff\xff\xff\xff\xef\x7f")[0]

_INT_RANGE = {
    "B": (0, 0xFF), "b": (-0x80, 0x7F), "H": (0, 0xFFFF), "h": (-0x8000, 0x7FFF),
    "I": (0, 0xFFFFFFFF), "i": (-0x80000000, 0x7FFFFFFF),
}

# --- lookups derived from the table ----------------------------------------------------------------
NODE = {}
NODE_NAME = {}
for _n in table.NODES:
    NODE[_n[0]] = _n[1]
    NODE_NAME[_n[1]] = _n[0]
MODE = {}
MODE_NAME = {}
for _m in table.MODES:
    MODE[_m[0]] = _m[1]
    MODE_NAME[_m[1]] = _m[0]
SAFE_REASON = {}
for _m in table.SAFE_REASONS:
    SAFE_REASON[_m[1]] = _m[0]
ERROR = {}
for _e in table.ERRORS:
    ERROR[_e[0]] = _e[1]


def node_id(name_or_num):
    """Node address from a node name (``"CONTROLLER"``) or a number 0..255; ValueError otherwise."""
    if isinstance(name_or_num, str):
        n = NODE.get(name_or_num.upper())
        if n is None:
            raise ValueError("unknown node %r (nodes: %s)" % (name_or_num, ", ".join(NODE)))
        return n
    if isinstance(name_or_num, bool) or not isinstance(name_or_num, int) or not 0 <= name_or_num <= 255:
        raise ValueError("node address %r out of range [0, 255]" % (name_or_num,))
    return name_or_num


def field_range(field):
    """(lo, hi) raw range of a field: its declared bounds, else its format's."""
    fmt = field[1]
    lo, hi = field[4], field[5]
    r = _INT_RANGE.get(fmt)
    if r is not None:
        if lo is None:
            lo = r[0]
        if hi is None:
            hi = r[1]
    return lo, hi


class PacketDef:
    """A packet declaration with its derived struct format (all fields little-endian)."""

    def __init__(self, decl):
        self.id, self.name, self.src, self.dst, self.doc, self.fields = decl
        self.fmt = "<" + "".join(f[1] for f in self.fields)
        self.size = struct.calcsize(self.fmt)
        self.names = tuple(f[0] for f in self.fields)
        self.defaults = tuple(f[6] for f in self.fields)
        self.ranges = tuple(field_range(f) for f in self.fields)


PACKET = {}       # id -> PacketDef
PACKET_ID = {}    # name -> id
for _p in table.PACKETS:
    _d = PacketDef(_p)
    if _d.id in PACKET or _d.name in PACKET_ID:
        raise ValueError("duplicate packet %s" % _d.name)
    if _d.size > MAX_PAYLOAD:
        raise ValueError("packet %s payload %d > %d" % (_d.name, _d.size, MAX_PAYLOAD))
    PACKET[_d.id] = _d
    PACKET_ID[_d.name] = _d.id


def packet_def(name_or_id):
    """The PacketDef for a packet name or id; ValueError naming it if unknown."""
    if isinstance(name_or_id, str):
        pid = PACKET_ID.get(name_or_id)
        if pid is None:
            raise ValueError("unknown packet name %r" % name_or_id)
        return PACKET[pid]
    d = PACKET.get(name_or_id)
    if d is None:
        raise ValueError("unknown packet id %r" % name_or_id)
    return d


def field_scales(name_or_id):
    """{field name: scale} of a packet: the physical value of one raw count (the table's scale column)."""
    return dict((f[0], f[3]) for f in packet_def(name_or_id).fields)


def _name(pkt, field):
    return pkt.name + "." + field[0]


def _check(pkt, field, v, lo, hi):
    """The raw value ``v`` of ``field`` checked against its format and its (lo, hi) range (``field_range``)."""
    fmt = field[1]
    if fmt[-1] == "s":
        if not isinstance(v, (bytes, bytearray)):
            raise ValueError("%s: expected bytes, got %r" % (_name(pkt, field), v))
        if len(v) > int(fmt[:-1]):
            raise ValueError("%s: %d bytes > %s" % (_name(pkt, field), len(v), fmt[:-1]))
        return bytes(v)
    if fmt in _INT_RANGE:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError("%s: expected an integer, got %r" % (_name(pkt, field), v))
    else:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v:
            raise ValueError("%s: expected a number, got %r" % (_name(pkt, field), v))
        # refuse what struct would reject or silently carry: non-finite values, and beyond float32 for 'f'
        flo, fhi = (-FLOAT32_MAX, FLOAT32_MAX) if fmt == "f" else (-FLOAT64_MAX, FLOAT64_MAX)
        if v < flo or v > fhi:
            raise ValueError("%s = %r out of range [%r, %r]" % (_name(pkt, field), v, flo if lo is None else lo,
                                                                fhi if hi is None else hi))
        v = float(v)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueError("%s = %r out of range [%r, %r]" % (_name(pkt, field), v, lo, hi))
    return v


def encode_payload(name_or_id, values=None, **kw):
    """Payload bytes for a packet; ``values`` (dict) or keywords give raw field values.

    Fields left out take their default. Unknown names and out-of-range values raise ValueError; so do
    non-finite floats and floats beyond float32 (an 'f' field) or a field's declared range.
    """
    pkt = packet_def(name_or_id)
    if values:
        kw.update(values)
    names = pkt.names
    for k in kw:
        if k not in names:
            raise ValueError("%s has no field %r (fields: %s)" % (pkt.name, k, ", ".join(names)))
    return struct.pack(pkt.fmt, *[_check(pkt, f, kw.get(f[0], f[6]), r[0], r[1])
                                  for f, r in zip(pkt.fields, pkt.ranges)])


def decode_payload(pid, payload):
    """Field values (a tuple, table order) of a payload whose length is already checked."""
    return struct.unpack(PACKET[pid].fmt, payload)


def payload_dict(pid, payload):
    """Payload as {field: raw value} (bytes fields trimmed by a ``length`` field if present)."""
    pkt = PACKET[pid]
    vals = struct.unpack(pkt.fmt, payload)
    d = {}
    for i in range(len(pkt.names)):
        d[pkt.names[i]] = vals[i]
    if "data" in d and "length" in d:
        d["data"] = d["data"][:d["length"]]
    return d


# --- CRC-32 (IEEE), table driven (where binascii has none) ------------------------------------------
def _make_crc32_table():
    t = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        t.append(c)
    return tuple(t)


_CRC32 = _make_crc32_table()


def crc32(data, crc=0):
    """CRC-32/ISO-HDLC (zlib.crc32, binascii.crc32); chainable like zlib's."""
    t = _CRC32
    crc ^= 0xFFFFFFFF
    for b in data:
        crc = t[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def encode_packet(name_or_id, src, dst, seq=0, values=None, **kw):
    """Encode a whole frame from field values (raw units) in one call."""
    pkt = packet_def(name_or_id)
    return encode_frame(pkt.id, src, dst, seq, encode_payload(pkt.id, values, **kw))
