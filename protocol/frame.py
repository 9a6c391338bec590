"""Serial framing: CRC-16, COBS, the header, the streaming ``Decoder`` and the per-tick ``Encoder``.

Runs unchanged under CPython and MicroPython, and needs only ``protocol.consts`` (the packet table's numbers):
the firmware imports it without the table's lookups (``protocol.core``, which re-exports every name here for the
host). Under MicroPython ``crc16``, ``cobs_encode``, ``cobs_decode``, ``Encoder`` and ``Decoder`` run the viper
code of ``protocol.fast`` (``FAST`` is True); ``crc16_pure``, ``cobs_encode_pure`` and ``cobs_decode_pure`` stay
the reference (CPython uses them), and tests/mp/protocol_fast.py proves the same bytes. The host path in
``protocol.host`` swaps in crcmod and the ``cobs`` package; tests prove both give identical bytes.

Serial frame on the wire::

    COBS(body + CRC16) + 0x00
    body   = header + payload
    header = version u8 | packet id u8 | source node u8 | destination node u8 | sequence u8
    CRC16  = CRC-16/CCITT-FALSE over body (poly 0x1021, init 0xFFFF, no reflection), big-endian
"""

import struct
import sys

from protocol.consts import CRC16_TABLE, PROTOCOL_VERSION, SIZES

HEADER_FMT = "<BBBBB"
HEADER_SIZE = 5
CRC_SIZE = 2
MAX_PAYLOAD = 255
MAX_BODY = HEADER_SIZE + MAX_PAYLOAD


def frame_bytes(max_payload):
    """The longest frame (its 0x00 included) of a payload of up to ``max_payload`` bytes."""
    n = HEADER_SIZE + max_payload + CRC_SIZE
    return n + n // 254 + 2


MAX_FRAME = frame_bytes(MAX_PAYLOAD)


# --- CRC-16/CCITT-FALSE, table driven (the table in flash: ``consts.CRC16_TABLE``) -----------------
def crc16_pure(data, crc=0xFFFF):
    """CRC-16/CCITT-FALSE (crcmod ``crc-ccitt-false``)."""
    t = CRC16_TABLE
    for b in data:
        i = ((crc >> 8) ^ b) << 1
        crc = ((crc << 8) & 0xFFFF) ^ t[i] ^ (t[i + 1] << 8)
    return crc


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
    return struct.pack(HEADER_FMT, PROTOCOL_VERSION, pid, src, dst, seq & 0xFF) + payload


def encode_frame(pid, src, dst, seq, payload, crc_fn=crc16, cobs_fn=cobs_encode):
    """One serial frame: COBS(body + CRC16 big-endian) + 0x00."""
    body = encode_body(pid, src, dst, seq, payload)
    c = crc_fn(body)
    return cobs_fn(body + struct.pack(">H", c)) + b"\x00"


class Encoder:
    """Frames built in preallocated buffers, for the per-tick send path: ``frame(...)`` returns a memoryview
    of the frame (same bytes as ``encode_frame``), valid until the next call. Under MicroPython one viper
    call copies the payload, appends the CRC and COBS-encodes; only the returned view is allocated."""

    def __init__(self, max_payload=MAX_PAYLOAD):
        self.max_payload = max_payload
        self._body = bytearray(HEADER_SIZE + max_payload + CRC_SIZE)
        self._out = bytearray(frame_bytes(max_payload))
        self._mv = memoryview(self._out)

    def frame(self, pid, src, dst, seq, payload):
        if len(payload) > self.max_payload:
            raise ValueError("payload is %d bytes > %d" % (len(payload), self.max_payload))
        if FAST:
            b = self._body
            b[0] = PROTOCOL_VERSION
            b[1] = pid
            b[2] = src
            b[3] = dst
            b[4] = seq & 0xFF
            return self._mv[:_fast.frame(b, HEADER_SIZE, payload, self._out)]
        f = encode_frame(pid, src, dst, seq, payload)
        self._out[:len(f)] = f
        return self._mv[:len(f)]


# Drop reasons counted by the decoder.
DROP_REASONS = ("bad_cobs", "bad_crc", "too_short", "unknown_id", "bad_length", "bad_version", "oversize")


class Decoder:
    """Streaming frame decoder: feed arbitrary byte chunks, get packets; never raises on wire bytes.

    ``feed`` returns a list of ``(pid, src, dst, seq, payload)``. Damaged frames are dropped and counted
    in ``drops[reason]``; decoding resyncs at the next 0x00. Sequence gaps and duplicates are counted
    per source in ``gaps[src]`` (packets missing) and ``dups[src]``.
    """

    def __init__(self, crc_fn=crc16, cobs_fn=cobs_decode, raw=None, max_frame=MAX_FRAME):
        self._crc = crc_fn
        self._cobs = cobs_fn
        self.max_frame = max_frame        # longer frames are dropped as "oversize" (frame_bytes: a board's table)
        # the viper path (MicroPython, default functions) decodes into a preallocated buffer: ``raw`` (max_frame
        # bytes) if given, which may be the buffer fed (COBS decodes in place: it writes behind what it reads)
        self._fast = FAST and crc_fn is crc16 and cobs_fn is cobs_decode
        if self._fast:
            self._raw = bytearray(max_frame) if raw is None else raw
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
                over = len(frame) > self.max_frame
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
                src, i, end, over = data, start, z, z - start > self.max_frame
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
        if len(self._buf) + len(chunk) > self.max_frame:
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
        if raw[0] != PROTOCOL_VERSION:
            self._drop("bad_version")
            return None
        pid = raw[1]
        src = raw[2]
        dst = raw[3]
        seq = raw[4]
        size = SIZES[pid]
        if size == 0xFF:
            self._drop("unknown_id")
            return None
        if len(payload) != size:
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

    def count_frames(self, n, src, seq):
        """``n`` frames decoded elsewhere (a board's machine-code path, ``firmware.hal.fast_tick``), the last from
        ``src`` with sequence number ``seq``: counted, and the sequence goes on from it."""
        self.frames += n
        self._last_seq[src] = seq

    def dropped(self):
        """Frames dropped, every reason together."""
        n = 0
        for r in self.drops:
            n += self.drops[r]
        return n

    def counters(self):
        """Every counter in one dict (drops by reason, frames, gaps, dups)."""
        d = {}
        for r in self.drops:
            d[r] = self.drops[r]
        d["frames"] = self.frames
        d["seq_gaps"] = sum(self.gaps.values())
        d["seq_dups"] = sum(self.dups.values())
        return d
