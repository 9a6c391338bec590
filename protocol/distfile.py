"""The distfile: body pointing error samples for the disturbance player (the thesis's SD-card file).

Pure and MicroPython-compatible: the firmware player and the ground tools share this one definition.
All fields little-endian::

    header (40 B)  magic b"FPSD" | version u16 = 1 | kind u8 | units u8 | period_us u32 | count u32
                   | seed u32 | scale f32 | source 16 s (ASCII, zero padded)
    samples        count x (x, y): kind 0 = int32 in units of ``scale`` arcsec, kind 1 = float32 arcsec
    crc32 u32      CRC-32 (IEEE, zlib) over header + samples

``units`` 0 is the body pointing error angle theta_e in arcsec (what the P-FSM reproduces, Eq. 7.7).
Any bad magic, version, kind, units, period, scale, length, CRC or a non-finite sample raises
``DistfileError`` (a ValueError) naming what is wrong; nothing is half-loaded.
"""

import struct

from protocol.core import FLOAT32_MAX   # largest finite float32 (the scale, kind 1 samples)

from protocol.compat import crc32 as _crc32

MAGIC = b"FPSD"
VERSION = 1
HEADER_FMT = "<4sHBBIIIf16s"
HEADER_SIZE = 40
SAMPLE_SIZE = 8
CRC_SIZE = 4
KIND_INT32 = 0
KIND_FLOAT32 = 1
UNITS_ARCSEC = 0
DEFAULT_PERIOD_US = 8192
SEED_MAX = 0xFFFFFFFF           # the header's u32 seed: every fps seed's range (numpy's legacy seeds too)
MAX_COUNT = 1 << 26             # ~6.4 days at 8.192 ms; keeps sizes well inside 32 bits
_SAMPLE_FMT = ("<ii", "<ff")    # by kind
_CHUNK = 512                    # bytes per read while checking a file's CRC


class DistfileError(ValueError):
    """A distfile is malformed: bad magic, version, length, CRC, field or a non-finite sample."""


def _finite(v):
    return v == v and v - v == 0.0


def _source_bytes(source):
    if isinstance(source, str):
        source = source.encode()
    source = bytes(source)
    if len(source) > 16:
        raise DistfileError("distfile source %r longer than 16 bytes" % source)
    for b in source:
        if b < 0x20 or b > 0x7E:
            raise DistfileError("distfile source %r is not printable ASCII" % source)
    return source + bytes(16 - len(source))


def pack(xs, ys, period_us=DEFAULT_PERIOD_US, kind=KIND_FLOAT32, scale=1.0, source="stat", seed=0):
    """The distfile bytes for error angles ``xs``, ``ys`` (arcsec, equal lengths).

    kind 1 stores float32 arcsec; kind 0 stores round(x / scale) as int32 (scale = arcsec per LSB).
    """
    n = len(xs)
    if len(ys) != n:
        raise DistfileError("distfile xs and ys differ in length: %d != %d" % (n, len(ys)))
    _check_fields(kind, UNITS_ARCSEC, period_us, n, seed, scale)
    if not scale <= FLOAT32_MAX:
        raise DistfileError("distfile scale %r does not fit float32" % (scale,))
    scale = struct.unpack("<f", struct.pack("<f", scale))[0]   # the float32 the reader will see
    if scale == 0.0:
        raise DistfileError("distfile scale underflows float32 to 0")
    fmt = _SAMPLE_FMT[kind]
    out = bytearray(HEADER_SIZE + n * SAMPLE_SIZE + CRC_SIZE)
    struct.pack_into(HEADER_FMT, out, 0, MAGIC, VERSION, kind, UNITS_ARCSEC, period_us, n, seed, scale,
                     _source_bytes(source))
    off = HEADER_SIZE
    for i in range(n):
        x, y = float(xs[i]), float(ys[i])
        if not (_finite(x) and _finite(y)):
            raise DistfileError("distfile sample %d is not finite: (%r, %r)" % (i, x, y))
        if kind == KIND_INT32:
            x, y = _to_int32(x / scale, i), _to_int32(y / scale, i)
        elif abs(x) > FLOAT32_MAX or abs(y) > FLOAT32_MAX:
            raise DistfileError("distfile sample %d = (%r, %r) arcsec does not fit float32" % (i, x, y))
        struct.pack_into(fmt, out, off, x, y)
        off += SAMPLE_SIZE
    struct.pack_into("<I", out, off, _crc32(memoryview(out)[:off]) & 0xFFFFFFFF)
    return bytes(out)


def _to_int32(v, i):
    r = int(v + 0.5) if v >= 0 else -int(-v + 0.5)
    if r < -0x80000000 or r > 0x7FFFFFFF:
        raise DistfileError("distfile sample %d = %r LSB does not fit int32 (raise scale)" % (i, v))
    return r


def _check_fields(kind, units, period_us, count, seed, scale):
    if kind != KIND_INT32 and kind != KIND_FLOAT32:
        raise DistfileError("distfile kind %r not 0 (int32) or 1 (float32)" % (kind,))
    if units != UNITS_ARCSEC:
        raise DistfileError("distfile units %r not 0 (arcsec)" % (units,))
    if not isinstance(period_us, int) or period_us < 1 or period_us > 10000000:
        raise DistfileError("distfile period_us %r out of range [1, 10000000]" % (period_us,))
    if count < 2 or count > MAX_COUNT:
        raise DistfileError("distfile count %r out of range [2, %d]" % (count, MAX_COUNT))
    if not isinstance(seed, int) or seed < 0 or seed > SEED_MAX:
        raise DistfileError("distfile seed %r out of range [0, 2**32-1]" % (seed,))
    if not (_finite(scale) and scale > 0.0):
        raise DistfileError("distfile scale %r must be finite and > 0" % (scale,))


class Header:
    """The parsed header: ``period_us count seed source kind scale units version``."""

    def __init__(self, raw):
        if len(raw) < HEADER_SIZE:
            raise DistfileError("distfile truncated: %d bytes < %d-byte header" % (len(raw), HEADER_SIZE))
        (magic, self.version, self.kind, self.units, self.period_us, self.count, self.seed, self.scale,
         src) = struct.unpack_from(HEADER_FMT, raw, 0)
        if magic != MAGIC:
            raise DistfileError("distfile bad magic %r (expected %r)" % (magic, MAGIC))
        if self.version != VERSION:
            raise DistfileError("distfile version %d not supported (expected %d)" % (self.version, VERSION))
        _check_fields(self.kind, self.units, self.period_us, self.count, self.seed, self.scale)
        end = 0
        while end < 16 and src[end]:
            end += 1
        self.source = _source_bytes(src[:end]).decode()[:end]
        self.size = HEADER_SIZE + self.count * SAMPLE_SIZE + CRC_SIZE
        self._fmt = _SAMPLE_FMT[self.kind]

    def duration_us(self):
        return (self.count - 1) * self.period_us

    def _to_arcsec(self, x, y, i):
        if self.kind == KIND_INT32:
            return x * self.scale, y * self.scale
        if not (_finite(x) and _finite(y)):
            raise DistfileError("distfile sample %d is not finite: (%r, %r)" % (i, x, y))
        return x, y


class Distfile(Header):
    """A whole distfile in memory (``parse``): ``.sample(i) -> (x, y)`` arcsec, ``.samples()``."""

    def __init__(self, data):
        mv = memoryview(data)
        Header.__init__(self, mv)
        if len(mv) != self.size:
            raise DistfileError("distfile length %d != %d for %d samples" % (len(mv), self.size, self.count))
        body = self.size - CRC_SIZE
        want = struct.unpack_from("<I", mv, body)[0]
        got = _crc32(mv[:body]) & 0xFFFFFFFF
        if got != want:
            raise DistfileError("distfile CRC-32 mismatch: stored 0x%08x, computed 0x%08x" % (want, got))
        self._mv = mv
        self.raw = mv
        if self.kind == KIND_FLOAT32:
            for i in range(self.count):
                self.sample(i)   # raises on a non-finite sample

    def sample(self, i):
        if i < 0 or i >= self.count:
            raise IndexError("distfile sample %d out of range [0, %d)" % (i, self.count))
        x, y = struct.unpack_from(self._fmt, self._mv, HEADER_SIZE + i * SAMPLE_SIZE)
        return self._to_arcsec(x, y, i)

    def sample_offset(self, i):
        """Where sample i's 8 raw bytes (x then y, little-endian) start in ``raw`` (no allocation)."""
        if i < 0 or i >= self.count:
            raise IndexError("distfile sample %d out of range [0, %d)" % (i, self.count))
        return HEADER_SIZE + i * SAMPLE_SIZE

    def samples(self):
        """(xs, ys) lists in arcsec."""
        xs = []
        ys = []
        for i in range(self.count):
            x, y = self.sample(i)
            xs.append(x)
            ys.append(y)
        return xs, ys


def parse(data):
    """A ``Distfile`` from bytes; DistfileError on any defect."""
    return Distfile(data)


def read_header(f):
    """The ``Header`` at the current position of a binary file (no CRC check)."""
    return Header(f.read(HEADER_SIZE))


def _read_full(f, mv):
    n = 0
    while n < len(mv):
        k = f.readinto(mv[n:])
        if not k:
            break
        n += k
    return n


class Reader(Header):
    """Streaming reader over a seekable binary file (the player's SD card): checks length, CRC and
    finiteness in one pass of ``_CHUNK``-byte reads at open, then reads samples on demand by seeking.

    ``sample(i) -> (x, y)`` arcsec reads into one preallocated buffer; ``sample_offset(i)`` reads sample i's
    raw bytes into ``raw`` (that buffer) without allocating and returns 0.
    """

    def __init__(self, f):
        f.seek(0)
        Header.__init__(self, f.read(HEADER_SIZE))
        self._f = f
        self._buf = bytearray(SAMPLE_SIZE)
        self.raw = self._buf
        self._verify()

    def _verify(self):
        f = self._f
        f.seek(0)
        body = self.size - CRC_SIZE
        buf = bytearray(_CHUNK)
        mv = memoryview(buf)
        crc = 0
        pos = 0
        while pos < body:
            want = body - pos
            if want > _CHUNK:
                want = _CHUNK
            n = _read_full(f, mv[:want])
            if n < want:
                raise DistfileError("distfile truncated: %d bytes < %d for %d samples" % (pos, self.size,
                                                                                          self.count))
            if self.kind == KIND_FLOAT32:
                self._check_finite(mv, pos, n)
            crc = _crc32(mv[:n], crc)
            pos += n
        tail = f.read(CRC_SIZE + 1)
        if len(tail) != CRC_SIZE:
            raise DistfileError("distfile length %d != %d for %d samples" % (pos + len(tail), self.size,
                                                                           self.count))
        want = struct.unpack("<I", tail)[0]
        if want != crc & 0xFFFFFFFF:
            raise DistfileError("distfile CRC-32 mismatch: stored 0x%08x, computed 0x%08x" % (want, crc))

    def _check_finite(self, mv, pos, n):
        # 4-byte floats from HEADER_SIZE on; chunk starts are 4-aligned because _CHUNK and HEADER_SIZE are.
        start = HEADER_SIZE - pos if pos < HEADER_SIZE else 0
        for off in range(start, n - 3, 4):
            v = struct.unpack_from("<f", mv, off)[0]
            if not _finite(v):
                raise DistfileError("distfile sample %d is not finite: %r" % ((pos + off - HEADER_SIZE) // 8, v))

    def sample(self, i):
        if i < 0 or i >= self.count:
            raise IndexError("distfile sample %d out of range [0, %d)" % (i, self.count))
        self._f.seek(HEADER_SIZE + i * SAMPLE_SIZE)
        self._f.readinto(self._buf)
        x, y = struct.unpack_from(self._fmt, self._buf, 0)
        return self._to_arcsec(x, y, i)

    def sample_offset(self, i):
        if i < 0 or i >= self.count:
            raise IndexError("distfile sample %d out of range [0, %d)" % (i, self.count))
        self._f.seek(HEADER_SIZE + i * SAMPLE_SIZE)
        if self._f.readinto(self._buf) != SAMPLE_SIZE:
            raise DistfileError("distfile sample %d: short read" % i)
        return 0
