"""Pure framing core derived from the packet table: CRC-16, CRC-32, COBS, header, payload codecs.

Runs unchanged under CPython and MicroPython (the firmware uses it). The host path in
``protocol.host`` swaps in crcmod and the ``cobs`` package; tests prove both give identical bytes.
Under MicroPython ``crc16``, ``cobs_encode``, ``cobs_decode``, ``Encoder`` and ``Decoder`` run the viper
code of ``protocol.fast`` (``FAST`` is True); ``crc16_pure``, ``cobs_encode_pure`` and ``cobs_decode_pure``
stay the reference (CPython uses them), and tests/mp/protocol_fast.py proves the same bytes.

Serial frame on the wire::

    COBS(body + CRC16) + 0x00
    body   = header + payload
    header = version u8 | packet id u8 | source node u8 | destination node u8 | sequence u8
    CRC16  = CRC-16/CCITT-FALSE over body (poly 0x1021, init 0xFFFF, no reflection), big-endian
"""

import struct
import sys

from protocol import table

HEADER_FMT = "<BBBBB"
HEADER_SIZE = 5
CRC_SIZE = 2
MAX_PAYLOAD = 255
MAX_BODY = HEADER_SIZE + MAX_PAYLOAD
MAX_FRAME = MAX_BODY + CRC_SIZE + (MAX_BODY + CRC_SIZE) // 254 + 2

FLOAT32_MAX = 3.4028234663852886e38     # largest finite float32 ('f' fields)
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


class PacketDef:
    """A packet declaration with its derived struct format (all fields little-endian)."""

    def __init__(self, decl):
        self.id, self.name, self.src, self.dst, self.doc, self.fields = decl
        self.fmt = "<" + "".join(f[1] for f in self.fields)
        self.size = struct.calcsize(self.fmt)
        self.names = tuple(f[0] for f in self.fields)
        self.defaults = tuple(f[6] for f in self.fields)


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


def _check(pkt, field, v):
    fmt = field[1]
    name = pkt.name + "." + field[0]
    if fmt[-1] == "s":
        if not isinstance(v, (bytes, bytearray)):
            raise ValueError("%s: expected bytes, got %r" % (name, v))
        if len(v) > int(fmt[:-1]):
            raise ValueError("%s: %d bytes > %s" % (name, len(v), fmt[:-1]))
        return bytes(v)
    lo, hi = field_range(field)
    if fmt in _INT_RANGE:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError("%s: expected an integer, got %r" % (name, v))
    else:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v:
            raise ValueError("%s: expected a number, got %r" % (name, v))
        # refuse what struct would reject or silently carry: non-finite values, and beyond float32 for 'f'
        flo, fhi = (-FLOAT32_MAX, FLOAT32_MAX) if fmt == "f" else (-FLOAT64_MAX, FLOAT64_MAX)
        if v < flo or v > fhi:
            raise ValueError("%s = %r out of range [%r, %r]" % (name, v, flo if lo is None else lo,
                                                                fhi if hi is None else hi))
        v = float(v)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueError("%s = %r out of range [%r, %r]" % (name, v, lo, hi))
    return v


def encode_payload(name_or_id, values=None, **kw):
    """Payload bytes for a packet; ``values`` (dict) or keywords give raw field values.

    Fields left out take their default. Unknown names and out-of-range values raise ValueError; so do
    non-finite floats and floats beyond float32 (an 'f' field) or a field's declared range.
    """
    pkt = packet_def(name_or_id)
    if values:
        kw.update(values)
    for k in kw:
        if k not in pkt.names:
            raise ValueError("%s has no field %r (fields: %s)" % (pkt.name, k, ", ".join(pkt.names)))
    args = []
    for f in pkt.fields:
        args.append(_check(pkt, f, kw.get(f[0], f[6])))
    return struct.pack(pkt.fmt, *args)


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


# --- CRC-16/CCITT-FALSE and CRC-32 (IEEE), table driven --------------------------------------------
def _make_crc16_table():
    t = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x1021) if c & 0x8000 else (c << 1)
        t.append(c & 0xFFFF)
    return tuple(t)


def _make_crc32_table():
    t = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        t.append(c)
    return tuple(t)


_CRC16 = _make_crc16_table()
_CRC32 = _make_crc32_table()


def crc16_pure(data, crc=0xFFFF):
    """CRC-16/CCITT-FALSE (crcmod ``crc-ccitt-false``)."""
    t = _CRC16
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ t[(crc >> 8) ^ b]
    return crc


def crc32(data, crc=0):
    """CRC-32/ISO-HDLC (zlib.crc32, binascii.crc32); chainable like zlib's."""
    t = _CRC32
    crc ^= 0xFFFFFFFF
    for b in data:
        crc = t[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


# --- COBS -----------------------------------------------------------------------------------------
def cobs_encode_pure(data):
    """Consistent Overhead Byte Stuffing; the result holds no 0x00 (delimiter not appended)."""
    n = len(data)
    out = bytearray(n + n // 254 + 1)
    code_i = 0
    o = 1
    code = 1
    for i in range(n):
        b = data[i]
        if b:
            out[o] = b
            o += 1
            code += 1
            if code == 0xFF and i + 1 < n:
                out[code_i] = code
                code_i = o
                o += 1
                code = 1
        else:
            out[code_i] = code
            code_i = o
            o += 1
            code = 1
    out[code_i] = code
    return bytes(out[:o])


def cobs_decode_pure(data):
    """Inverse of cobs_encode; None if the encoding is invalid (never raises on bytes)."""
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        end = i + code
        if code == 0 or end > n:
            return None
        blk = data[i + 1:end]
        if 0 in blk:
            return None
        out.extend(blk)
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


# --- fast paths: viper (protocol.fast) under MicroPython, the pure functions above elsewhere -------
_fast = None
if sys.implementation.name == "micropython":
    try:
        from protocol import fast as _fast
    except (ImportError, SyntaxError, ValueError):  # no native emitter, or a .mpy built for another arch
        _fast = None
FAST = _fast is not None

if FAST:
    _fast.set_table(_CRC16)

    def crc16(data, crc=0xFFFF):
        """CRC-16/CCITT-FALSE of a bytes-like object (viper)."""
        return _fast.crc16(data, len(data), crc)

    def cobs_encode(data):
        """COBS encode a bytes-like object (viper); same bytes as cobs_encode_pure."""
        n = len(data)
        out = bytearray(n + n // 254 + 1)
        return bytes(memoryview(out)[:_fast.cobs_encode(data, n, out)])

    def cobs_decode(data):
        """COBS decode a bytes-like object (viper); None if invalid, like cobs_decode_pure."""
        n = len(data)
        out = bytearray(n)
        k = _fast.cobs_decode(data, 0, n, out)
        return None if k < 0 else bytes(memoryview(out)[:k])
else:
    crc16 = crc16_pure
    cobs_encode = cobs_encode_pure
    cobs_decode = cobs_decode_pure


# --- frames ---------------------------------------------------------------------------------------
def encode_body(pid, src, dst, seq, payload):
    return struct.pack(HEADER_FMT, table.PROTOCOL_VERSION, pid, src, dst, seq & 0xFF) + payload


def encode_frame(pid, src, dst, seq, payload, crc_fn=crc16, cobs_fn=cobs_encode):
    """One serial frame: COBS(body + CRC16 big-endian) + 0x00."""
    body = encode_body(pid, src, dst, seq, payload)
    c = crc_fn(body)
    return cobs_fn(body + struct.pack(">H", c)) + b"\x00"


class Encoder:
    """Frames built in preallocated buffers, for the per-tick send path: ``frame(...)`` returns a memoryview
    of the frame (same bytes as ``encode_frame``), valid until the next call. Under MicroPython one viper
    call copies the payload, appends the CRC and COBS-encodes; only the returned view is allocated."""

    def __init__(self):
        self._body = bytearray(MAX_BODY + CRC_SIZE)
        self._out = bytearray(MAX_FRAME)
        self._mv = memoryview(self._out)

    def frame(self, pid, src, dst, seq, payload):
        if len(payload) > MAX_PAYLOAD:
            raise ValueError("payload is %d bytes > %d" % (len(payload), MAX_PAYLOAD))
        if FAST:
            b = self._body
            b[0] = table.PROTOCOL_VERSION
            b[1] = pid
            b[2] = src
            b[3] = dst
            b[4] = seq & 0xFF
            return self._mv[:_fast.frame(b, HEADER_SIZE, payload, self._out)]
        f = encode_frame(pid, src, dst, seq, payload)
        self._out[:len(f)] = f
        return self._mv[:len(f)]


def encode_packet(name_or_id, src, dst, seq=0, values=None, **kw):
    """Encode a whole frame from field values (raw units) in one call."""
    pkt = packet_def(name_or_id)
    return encode_frame(pkt.id, src, dst, seq, encode_payload(pkt.id, values, **kw))


# Drop reasons counted by the decoder.
DROP_REASONS = ("bad_cobs", "bad_crc", "too_short", "unknown_id", "bad_length", "bad_version", "oversize")


class Decoder:
    """Streaming frame decoder: feed arbitrary byte chunks, get packets; never raises on wire bytes.

    ``feed`` returns a list of ``(pid, src, dst, seq, payload)``. Damaged frames are dropped and counted
    in ``drops[reason]``; decoding resyncs at the next 0x00. Sequence gaps and duplicates are counted
    per source in ``gaps[src]`` (packets missing) and ``dups[src]``.
    """

    def __init__(self, crc_fn=crc16, cobs_fn=cobs_decode):
        self._crc = crc_fn
        self._cobs = cobs_fn
        # the viper path (MicroPython, default functions) decodes into a preallocated buffer
        self._fast = FAST and crc_fn is crc16 and cobs_fn is cobs_decode
        if self._fast:
            self._raw = bytearray(MAX_FRAME)
            self._rawmv = memoryview(self._raw)
        self._buf = bytearray()
        self._overflow = False
        self.drops = {}
        for r in DROP_REASONS:
            self.drops[r] = 0
        self.frames = 0
        self.gaps = {}
        self.dups = {}
        self._last_seq = {}

    def _drop(self, reason):
        self.drops[reason] += 1

    def feed(self, data, n=None):
        """Packets completed by ``data`` (only its first ``n`` bytes if given: a read buffer, not sliced)."""
        if self._fast:
            return self._feed_fast(data, len(data) if n is None else n)
        if n is not None:
            data = data[:n]
        out = []
        if not isinstance(data, bytes):
            data = bytes(data)
        start = 0
        n = len(data)
        while start < n:
            z = data.find(b"\x00", start)
            if z < 0:
                self._append(data[start:])
                break
            if self._buf or self._overflow:  # a frame split across feeds
                self._append(data[start:z])
                frame = bytes(self._buf)
                over = self._overflow
                self._buf = bytearray()
                self._overflow = False
            else:                             # the common case: the whole frame is in this chunk
                frame = data[start:z]
                over = len(frame) > MAX_FRAME
            start = z + 1
            if over:
                self._drop("oversize")
            elif frame:
                p = self._frame(frame)
                if p is not None:
                    out.append(p)
        return out

    def _feed_fast(self, data, n):
        """``feed`` without copying the chunk: find, COBS and CRC in viper, straight from ``data``."""
        out = []
        start = 0
        while start < n:
            z = _fast.find0(data, start, n)
            if z < 0:
                self._append(data[start:n])
                break
            if self._buf or self._overflow:  # a frame split across feeds
                self._append(data[start:z])
                src, i, end, over = self._buf, 0, len(self._buf), self._overflow
                self._buf = bytearray()
                self._overflow = False
            else:
                src, i, end, over = data, start, z, z - start > MAX_FRAME
            start = z + 1
            if over:
                self._drop("oversize")
            elif end > i:
                r = _fast.unframe(src, i, end, self._raw)
                if r < 0:
                    self._drop("bad_cobs")
                elif r & 0xFFFF < HEADER_SIZE + CRC_SIZE:
                    self._drop("too_short")
                elif r > 0xFFFF:
                    self._drop("bad_crc")
                else:
                    p = self._packet(self._raw, self._rawmv[HEADER_SIZE:r - CRC_SIZE])
                    if p is not None:
                        out.append(p)
        return out

    def _append(self, chunk):
        if self._overflow:
            return
        if len(self._buf) + len(chunk) > MAX_FRAME:
            self._overflow = True
            self._buf = bytearray()
        else:
            self._buf.extend(chunk)

    def _frame(self, frame):
        raw = self._cobs(frame)
        if raw is None:
            self._drop("bad_cobs")
            return None
        if len(raw) < HEADER_SIZE + CRC_SIZE:
            self._drop("too_short")
            return None
        if self._crc(raw[:-2]) != (raw[-2] << 8) | raw[-1]:
            self._drop("bad_crc")
            return None
        return self._packet(raw, raw[HEADER_SIZE:-CRC_SIZE])

    def _packet(self, raw, payload):
        """The packet whose header starts ``raw`` (CRC already checked), or None with the drop counted."""
        if raw[0] != table.PROTOCOL_VERSION:
            self._drop("bad_version")
            return None
        pid = raw[1]
        src = raw[2]
        dst = raw[3]
        seq = raw[4]
        pkt = PACKET.get(pid)
        if pkt is None:
            self._drop("unknown_id")
            return None
        if len(payload) != pkt.size:
            self._drop("bad_length")
            return None
        payload = bytes(payload)
        self.frames += 1
        last = self._last_seq.get(src)
        if last is not None:
            d = (seq - last) & 0xFF
            if d == 0:
                self.dups[src] = self.dups.get(src, 0) + 1
            elif d < 128:
                if d > 1:
                    self.gaps[src] = self.gaps.get(src, 0) + d - 1
        self._last_seq[src] = seq
        return (pid, src, dst, seq, payload)

    def counters(self):
        """Every counter in one dict (drops by reason, frames, gaps, dups)."""
        d = {}
        for r in self.drops:
            d[r] = self.drops[r]
        d["frames"] = self.frames
        d["seq_gaps"] = sum(self.gaps.values())
        d["seq_dups"] = sum(self.dups.values())
        return d
