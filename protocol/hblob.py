"""The H-table blob, the HTABLE upload's bytes: its layout, its checks, and ``Blob``, which reads one in place (pure,
MicroPython; what a board with little RAM loads of the H table: ``protocol.htable`` adds the grid and the
calibration's derivation for the ground and the desktop firmware).

Blob (all little-endian)::

    magic b"FPSH" | version u16 = 1 | nx u8 | ny u8 | nx x f32 axis X (V) | ny x f32 axis Y (V)
    | nx*ny x (a, b, c, d) f32 H in ratio per volt, node (i, j) at index j*nx + i | CRC-32 u32

H = [[a, b], [c, d]] maps FSM tilt volts to quadcell ratios, R = H V (Eq. 7.10).
"""

import struct

from protocol.consts import FLOAT32_MAX   # the blob stores float32

# its own shim, not protocol.compat's: the controller's 32 KB board has no RAM for one more module
try:
    from binascii import crc32 as _crc32
except ImportError:  # pragma: no cover
    from protocol.core import crc32 as _crc32

MAGIC = b"FPSH"
VERSION = 1
HEADER_FMT = "<4sHBB"
HEADER_SIZE = 8
MAX_AXIS = 32
V_RANGE = 2.5        # FSM tilt voltage range, V


class HTableError(ValueError):
    """A calibration table or blob is malformed or out of range."""


def _finite(v):
    return v == v and v - v == 0.0


def _num(v, what):
    try:
        if not isinstance(v, bool) and isinstance(v, (int, float)) and _finite(float(v)):
            return float(v)
        shown = repr(v)
    except OverflowError:            # an integer beyond any float
        shown = "an integer of %d digits" % len(str(abs(v)))
    raise HTableError("%s = %s is not a finite number" % (what, shown))


def validate(ax, ay, h):
    """HTableError unless the axes hold 2..MAX_AXIS strictly increasing volts within the FSM range and h one
    finite float32 (a, b, c, d) per node."""
    for name, axis in (("ax", ax), ("ay", ay)):
        if len(axis) < 2 or len(axis) > MAX_AXIS:
            raise HTableError("H table axis %s has %d values, need 2..%d" % (name, len(axis), MAX_AXIS))
        for k in range(len(axis)):
            v = _num(axis[k], "%s[%d]" % (name, k))
            if v < -V_RANGE or v > V_RANGE:
                raise HTableError("H table %s[%d] = %r V outside the FSM range +-%g V" % (name, k, v, V_RANGE))
            if k and v <= axis[k - 1]:
                raise HTableError("H table %s not strictly increasing at %d: %r <= %r" % (name, k, v,
                                                                                      axis[k - 1]))
    if len(h) != len(ax) * len(ay):
        raise HTableError("H table has %d matrices for a %dx%d grid" % (len(h), len(ax), len(ay)))
    for k in range(len(h)):
        m = h[k]
        if len(m) != 4:
            raise HTableError("H table node %d has %d entries, need 4" % (k, len(m)))
        for e in range(4):
            if abs(_num(m[e], "H[%d][%d]" % (k, e))) > FLOAT32_MAX:
                raise HTableError("H table node %d entry %d = %r does not fit the blob's float32" % (k, e, m[e]))


def blob_size(nx, ny):
    """Bytes of the blob of an nx x ny grid: header, the float32 axes, four float32 of H per node, CRC-32."""
    return HEADER_SIZE + 4 * (nx + ny) + 16 * nx * ny + 4


class Rectilinear:
    """What a rectilinear H table has, whatever holds it: ``ax``, ``ay`` (V, ascending) and ``h`` (node (i, j)'s
    (a, b, c, d) at index j*nx + i) as sequences; ``validate`` and the axis lengths."""

    def validate(self):
        validate(self.ax, self.ay, self.h)

    @property
    def nx(self):
        return len(self.ax)

    @property
    def ny(self):
        return len(self.ay)


class Blob(Rectilinear):
    """A blob's grid read in place (header, length and CRC-32 checked here, values by ``validate``): ``ax``, ``ay``
    (V) and ``h`` (node k's (a, b, c, d)) are sequences unpacked from the blob item by item when asked. What
    ``firmware.hinv.HinvTable`` reads, without a float in RAM per value (a board with 32 KB)."""

    def __init__(self, data):
        mv = memoryview(data)
        if len(mv) < HEADER_SIZE + 4:
            raise HTableError("H table blob truncated: %d bytes" % len(mv))
        magic, ver, nx, ny = struct.unpack_from(HEADER_FMT, mv, 0)
        if magic != MAGIC:
            raise HTableError("H table blob bad magic %r (expected %r)" % (bytes(magic), MAGIC))
        if ver != VERSION:
            raise HTableError("H table blob version %d not supported (expected %d)" % (ver, VERSION))
        size = blob_size(nx, ny)
        if len(mv) != size:
            raise HTableError("H table blob length %d != %d for a %dx%d grid" % (len(mv), size, nx, ny))
        want = struct.unpack_from("<I", mv, size - 4)[0]
        got = _crc32(mv[:size - 4]) & 0xFFFFFFFF
        if want != got:
            raise HTableError("H table blob CRC-32 mismatch: stored 0x%08x, computed 0x%08x" % (want, got))
        self.ax = _View(mv, HEADER_SIZE, nx, "<f", 4)
        self.ay = _View(mv, HEADER_SIZE + 4 * nx, ny, "<f", 4)
        self.h = _View(mv, HEADER_SIZE + 4 * (nx + ny), nx * ny, "<ffff", 16)


class _View:
    """n items of ``fmt`` (``size`` bytes each) at ``off`` in the blob, item k unpacked on each ``[k]`` (a float, or
    a tuple of several)."""

    def __init__(self, mv, off, n, fmt, size):
        self._mv = mv
        self._off = off
        self._n = n
        self._fmt = fmt
        self._size = size

    def __len__(self):
        return self._n

    def __getitem__(self, k):
        if k < 0 or k >= self._n:
            raise IndexError("item %d of %d" % (k, self._n))
        v = struct.unpack_from(self._fmt, self._mv, self._off + self._size * k)
        return v[0] if len(v) == 1 else v
