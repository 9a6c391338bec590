"""Fixed-point H^-1 table over the rectilinear FSM-voltage grid, for the integral law (Eq. 7.10-7.12).

Built once from a ``protocol.htable.Grid`` or a ``protocol.hblob.Blob`` (float, at load time); the controller then
reads the integers below (an int32 array ``HinvTable.t`` and an int16 array ``HinvTable.h16``) and interpolates
bilinearly (``hinv_into``) when its command enters a new 64-code bin. Q-formats:

- ``ax``, ``ay``   grid axes in AD5664R tilt codes (Q0 code, ``firmware.ad5664r.CODES_PER_VOLT``), ascending.
- ``rdx``, ``rdy`` per cell 2^24 // width (Q24 per code): the cell fraction t = ((c - ax[i]) * rdx[i]) >> 12
  is Q12 in [0, 4096]; the product is at most width * 2^24 / width = 2^24.
- ``h``            H^-1 per node in code per unit ratio, Q``hq`` (value * 2^hq), four entries
  (h11, h12, h21, h22) per node at index 4 * (j * nx + i). ``hq`` is the largest of 0..12 keeping every
  |entry| <= HINV_MAX (16000 < 2^14): g h stays below 65535 * 16000 < 2^30, and the law's products
  ((g h) >> 15 <= 31999, times |dR| <= 16383) summed in pairs stay below 2^30 with room for rounding.

A node refuses the whole table (``HTableError`` naming the node, its FSM volts, det H and the condition
number of H) when:

- H is singular or nearly so: |det H| <= 1e-6 max|h|^2, i.e. a 2-norm condition number above ~10^6;
- H^-1 exceeds HINV_MAX at Q0 (|H^-1| > 1.22 V per unit ratio: the quadcell too insensitive to steer by),
  or is below 1 code per unit ratio;
- the fixed-point H^-1 (the Q``hq`` integers) no longer inverts H: the row-sum norm of Hq^-1 H - I is above
  ``QUANT_TOL`` (0.5), so the loop's gain matrix g Hq^-1 H could lose an eigenvalue near g. It happens where
  H^-1 is tiny beside the table's largest and near singular, so rounding to ``hq`` bits destroys it.

The error carries ``node`` (the index j * nx + i) so ground tools can name the calibration point.
"""

import math
from array import array

from firmware import ad5664r
from protocol.hblob import MAX_AXIS, HTableError, blob_size

HINV_MAX = 16000
HQ_MAX = 12
SINGULAR_TOL = 1e-6
QUANT_TOL = 0.5


def condition(h):
    """2-norm condition number of H = (a, b, c, d) (inf when singular): sigma_max / sigma_min from
    sigma_max^2 + sigma_min^2 = a^2 + b^2 + c^2 + d^2 and sigma_max sigma_min = |det H|."""
    a, b, c, d = h
    det = abs(a * d - b * c)
    s = a * a + b * b + c * c + d * d
    if det == 0.0:
        return float("inf")
    return (s + math.sqrt(max(0.0, s * s - 4.0 * det * det))) / (2.0 * det)


def _refuse(msg, k):
    e = HTableError(msg)
    e.node = k
    raise e


class HinvTable:
    """The integers of the bilinear H^-1 lookup in an int32 array ``t`` and an int16 array ``h16`` (Q-formats in the
    module docstring; every H^-1 entry is within +-HINV_MAX, so 16 bits hold it and the table takes half the RAM)::

        t = [nx, ny, ax[0..nx-1], ay[0..ny-1], rdx[0..nx-2], rdy[0..ny-2]]      h16 = [h[0..4*nx*ny-1]]

    the layout the viper law reads too (``firmware.controller_viper``). Built in three passes over the grid's
    nodes (check each and find the largest |H^-1|; check each fixed-point H^-1; write): nothing per node is kept
    in floats, so a ``protocol.hblob.Blob`` (the upload's bytes, read in place) goes straight into the array on a
    board with little RAM. ``ax``, ``ay``, ``rdx``, ``rdy`` and ``h`` give the parts as lists."""

    def __init__(self, grid, out=None):
        """``out``: the (int32, int16) arrays to build the table in (``arrays(capacity(...))`` for the largest blob a
        board takes; HTableError if this grid needs more), written only once every check has passed, so a refused
        grid leaves the table already in them whole; None: new arrays of the grid's size."""
        grid.validate()
        nx = self.nx = grid.nx
        ny = self.ny = grid.ny
        self._oy = 2 + nx                 # offsets of ay, rdx, rdy, h in t
        self._orx = self._oy + ny
        self._ory = self._orx + nx - 1
        n = self._ory + ny - 1
        nh = 4 * nx * ny
        if out is not None and (len(out[0]) < n or len(out[1]) < nh):
            raise HTableError("H table %dx%d needs %d bytes of table memory, this board has %d"
                              % (nx, ny, 4 * n + 2 * nh, 4 * len(out[0]) + 2 * len(out[1])))
        ax = self._axis(grid.ax, "ax")
        ay = self._axis(grid.ay, "ay")
        big = 0.0                         # pass 1: every node checked, the largest |H^-1|
        for k in range(nx * ny):
            big = max(big, self._inverse(grid, k)[1])
        hq = 0
        while hq < HQ_MAX and big * (1 << (hq + 1)) <= HINV_MAX:
            hq += 1
        q = [0, 0, 0, 0]
        f = 1 << hq
        for k in range(nx * ny):          # pass 2: the fixed-point H^-1 of every node checked
            m = self._inverse(grid, k)[0]
            for e in range(4):
                v = m[e] * f
                q[e] = int(v + 0.5) if v >= 0 else -int(-v + 0.5)
            h = grid.h[k]
            err = self._quant_error(q, h, hq)
            if err > QUANT_TOL:
                _refuse("H table %s: the fixed-point H^-1 (Q%d: %r) does not invert H: |Hq^-1 H - I| = %.3g > %g "
                        "(H near singular beside the table's largest H^-1: det H = %.4g, condition number %.4g)"
                        % (self._where(grid, k), hq, q, err, QUANT_TOL, h[0] * h[3] - h[1] * h[2], condition(h)), k)
        if out is None:
            out = (array("i", range(n)), array("h", range(nh)))
        t = self.t = out[0]
        h16 = self.h16 = out[1]
        t[0] = nx                         # pass 3: written
        t[1] = ny
        for i in range(nx):
            t[2 + i] = ax[i]
        for j in range(ny):
            t[self._oy + j] = ay[j]
        for i in range(nx - 1):
            t[self._orx + i] = (1 << 24) // (ax[i + 1] - ax[i])
        for j in range(ny - 1):
            t[self._ory + j] = (1 << 24) // (ay[j + 1] - ay[j])
        o = 0
        for k in range(nx * ny):          # (the same rounding as pass 2, inline: a call less deep on the stack)
            m = self._inverse(grid, k)[0]
            for e in range(4):
                v = m[e] * f
                h16[o + e] = int(v + 0.5) if v >= 0 else -int(-v + 0.5)
            o += 4
        self._i = 0                       # the cell hinv_into found last (where its next search starts)
        self._j = 0
        self.hq = hq
        self.shift = 7 + hq               # Q(15 + hq) product -> Q8 code state

    @staticmethod
    def _inverse(grid, k):
        """H^-1 of node k in code per unit ratio (a, b, c, d) and its largest |entry|; refuses a bad node."""
        h = grid.h[k]
        a, b, c, d = h
        det = a * d - b * c
        scale = max(abs(a), abs(b), abs(c), abs(d))
        if scale == 0.0 or abs(det) <= SINGULAR_TOL * scale * scale:
            _refuse("H table %s: H is singular: det H = %.4g, condition number %.4g (limit ~%.0g): H = %r"
                    % (HinvTable._where(grid, k), det, condition(h), 1 / SINGULAR_TOL, tuple(h)), k)
        cpv = ad5664r.CODES_PER_VOLT       # H^-1 in V per unit ratio, then in code per unit ratio
        m = (d / det * cpv, -b / det * cpv, -c / det * cpv, a / det * cpv)
        mk = max(abs(m[0]), abs(m[1]), abs(m[2]), abs(m[3]))
        if mk > HINV_MAX:
            _refuse("H table %s: |H^-1| = %.4g V per unit ratio, above %.4g (H too small; det H = %.4g, "
                    "condition number %.4g)" % (HinvTable._where(grid, k), mk / cpv, HINV_MAX / cpv, det,
                                                condition(h)), k)
        if mk < 1.0:
            _refuse("H table %s: |H^-1| = %.4g V per unit ratio, below one code (H too large; det H = %.4g)"
                    % (HinvTable._where(grid, k), mk / cpv, det), k)
        return m, mk

    @staticmethod
    def _where(grid, k):
        i = k % len(grid.ax)
        j = k // len(grid.ax)
        return "node (%d, %d) at FSM (%.4f, %.4f) V" % (i, j, grid.ax[i], grid.ay[j])

    @staticmethod
    def _quant_error(q, h, hq):
        """Row-sum norm of Hq^-1 H - I, Hq^-1 the integer entries q (code per unit ratio, Q hq)."""
        f = 1.0 / ((1 << hq) * ad5664r.CODES_PER_VOLT)
        a, b, c, d = h
        m11 = (q[0] * a + q[1] * c) * f - 1.0
        m12 = (q[0] * b + q[1] * d) * f
        m21 = (q[2] * a + q[3] * c) * f
        m22 = (q[2] * b + q[3] * d) * f - 1.0
        return max(abs(m11) + abs(m12), abs(m21) + abs(m22))

    @staticmethod
    def _axis(vals, name):
        out = [ad5664r.volts_to_code(v) for v in vals]
        for k in range(1, len(out)):
            if out[k] <= out[k - 1]:
                raise HTableError("H table %s[%d] = %d code not above %d (grid too fine)" % (name, k, out[k],
                                                                                           out[k - 1]))
        return out

    @property
    def ax(self):
        return list(self.t[2:self._oy])

    @property
    def ay(self):
        return list(self.t[self._oy:self._orx])

    @property
    def rdx(self):
        return list(self.t[self._orx:self._ory])

    @property
    def rdy(self):
        return list(self.t[self._ory:self._ory + self.ny - 1])

    @property
    def h(self):
        return list(self.h16[:4 * self.nx * self.ny])

    def hinv_into(self, x_code, y_code, out):
        """Write the H^-1 entries (h11, h12, h21, h22; Q``hq``) interpolated bilinearly at tilt codes x, y into
        out[0..3]; outside the grid the edge values hold. Allocation-free (the controller calls it on a tick).
        The cell search starts from the last call's cell (the command moves little between calls)."""
        t = self.t
        nx = self.nx
        i = self._i
        while i and x_code < t[2 + i]:
            i -= 1
        while i < nx - 2 and x_code >= t[3 + i]:
            i += 1
        self._i = i
        a = t[2 + i]
        if x_code <= a:
            tx = 0
        elif x_code >= t[3 + i]:
            tx = 4096
        else:
            tx = ((x_code - a) * t[self._orx + i]) >> 12          # Q12, product <= 2^24
        o = self._oy
        j = self._j
        while j and y_code < t[o + j]:
            j -= 1
        while j < self.ny - 2 and y_code >= t[o + j + 1]:
            j += 1
        self._j = j
        a = t[o + j]
        if y_code <= a:
            ty = 0
        elif y_code >= t[o + j + 1]:
            ty = 4096
        else:
            ty = ((y_code - a) * t[self._ory + j]) >> 12
        h = self.h16
        k = (j * nx + i) << 2                     # node (i, j); +4 is (i + 1, j); m is (i, j + 1)
        m = k + (nx << 2)
        for e in range(4):
            a = h[k]
            u = a + (((h[k + 4] - a) * tx) >> 12)               # |difference| <= 32000, times 4096 < 2^27
            a = h[m]
            v = a + (((h[m + 4] - a) * tx) >> 12)
            out[e] = u + (((v - u) * ty) >> 12)
            k += 1
            m += 1

    def hinv_at(self, x_code, y_code):
        """``hinv_into`` returning a new list (tests, telemetry)."""
        out = [0, 0, 0, 0]
        self.hinv_into(x_code, y_code, out)
        return out


def arrays(blob_bytes):
    """The (int32, int16) arrays that hold the table of any grid whose blob fits ``blob_bytes``
    (``HinvTable(out=...)``): ``t`` takes 2 (nx + ny) entries, ``h16`` 4 nx ny, each at its largest over those
    grids."""
    nt = nh = 0
    for nx in range(2, MAX_AXIS + 1):
        for ny in range(2, MAX_AXIS + 1):
            if blob_size(nx, ny) <= blob_bytes:
                nt = max(nt, 2 * (nx + ny))
                nh = max(nh, 4 * nx * ny)
    if not nh:
        raise ValueError("an H-table blob of %d bytes holds no grid (2x2 takes %d)" % (blob_bytes, blob_size(2, 2)))
    return array("i", range(nt)), array("h", range(nh))


def load_file(path):
    """A ``HinvTable`` from a calibration JSON file (``.json``) or an H-table blob on the filesystem."""
    from protocol import htable
    with open(path, "rb") as f:
        data = f.read()
    if path.endswith(".json"):
        import json
        try:
            cal = json.loads(data)
        except ValueError as exc:
            raise HTableError("calibration %s is not valid JSON: %s" % (path, exc))
        return HinvTable(htable.grid_from_calibration(cal))
    return HinvTable(htable.Blob(data))
