"""Fixed-point H^-1 table over the rectilinear FSM-voltage grid, for the integral law (Eq. 7.10-7.12).

Built once from a ``protocol.htable.Grid`` (float, at load time); the controller then reads the integer
lists below and interpolates bilinearly (``hinv_into``) when its command enters a new 64-code bin. Q-formats:

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

from firmware import ad5664r
from protocol.htable import HTableError

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
    """Integer lists for the bilinear H^-1 lookup (see the module docstring for their Q-formats)."""

    def __init__(self, grid):
        grid.validate()
        self.nx = grid.nx
        self.ny = grid.ny
        self.ax = self._axis(grid.ax, "ax")
        self.ay = self._axis(grid.ay, "ay")
        self.rdx = [(1 << 24) // (self.ax[i + 1] - self.ax[i]) for i in range(self.nx - 1)]
        self.rdy = [(1 << 24) // (self.ay[j + 1] - self.ay[j]) for j in range(self.ny - 1)]
        inv = []
        big = 0.0
        for k in range(len(grid.h)):
            a, b, c, d = grid.h[k]
            det = a * d - b * c
            scale = max(abs(a), abs(b), abs(c), abs(d))
            where = self._where(grid, k)
            if scale == 0.0 or abs(det) <= SINGULAR_TOL * scale * scale:
                _refuse("H table %s: H is singular: det H = %.4g, condition number %.4g (limit ~%.0g): H = %r"
                        % (where, det, condition(grid.h[k]), 1 / SINGULAR_TOL, grid.h[k]), k)
            # H^-1 in V per unit ratio, then in code per unit ratio
            m = (d / det * ad5664r.CODES_PER_VOLT, -b / det * ad5664r.CODES_PER_VOLT,
                 -c / det * ad5664r.CODES_PER_VOLT, a / det * ad5664r.CODES_PER_VOLT)
            mk = max(abs(m[0]), abs(m[1]), abs(m[2]), abs(m[3]))
            if mk > HINV_MAX:
                _refuse("H table %s: |H^-1| = %.4g V per unit ratio, above %.4g (H too small; det H = %.4g, "
                        "condition number %.4g)" % (where, mk / ad5664r.CODES_PER_VOLT,
                                                    HINV_MAX / ad5664r.CODES_PER_VOLT, det,
                                                    condition(grid.h[k])), k)
            if mk < 1.0:
                _refuse("H table %s: |H^-1| = %.4g V per unit ratio, below one code (H too large; det H = %.4g)"
                        % (where, mk / ad5664r.CODES_PER_VOLT, det), k)
            big = max(big, mk)
            inv.append(m)
        hq = 0
        while hq < HQ_MAX and big * (1 << (hq + 1)) <= HINV_MAX:
            hq += 1
        self._i = 0                       # the cell hinv_into found last (where its next search starts)
        self._j = 0
        self.hq = hq
        self.shift = 7 + hq               # Q(15 + hq) product -> Q8 code state
        self.h = []
        for k in range(len(inv)):
            q = []
            for e in inv[k]:
                v = e * (1 << hq)
                q.append(int(v + 0.5) if v >= 0 else -int(-v + 0.5))
            err = self._quant_error(q, grid.h[k], hq)
            if err > QUANT_TOL:
                _refuse("H table %s: the fixed-point H^-1 (Q%d: %r) does not invert H: |Hq^-1 H - I| = %.3g > %g "
                        "(H near singular beside the table's largest H^-1: det H = %.4g, condition number %.4g)"
                        % (self._where(grid, k), hq, q, err, QUANT_TOL,
                           grid.h[k][0] * grid.h[k][3] - grid.h[k][1] * grid.h[k][2], condition(grid.h[k])), k)
            self.h.extend(q)
        self.grid = grid

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

    def _axis(self, vals, name):
        out = [ad5664r.volts_to_code(v) for v in vals]
        for k in range(1, len(out)):
            if out[k] <= out[k - 1]:
                raise HTableError("H table %s[%d] = %d code not above %d (grid too fine)" % (name, k, out[k],
                                                                                           out[k - 1]))
        return out

    def hinv_into(self, x_code, y_code, out):
        """Write the H^-1 entries (h11, h12, h21, h22; Q``hq``) interpolated bilinearly at tilt codes x, y into
        out[0..3]; outside the grid the edge values hold. Allocation-free (the controller calls it on a tick).
        The cell search starts from the last call's cell (the command moves little between calls)."""
        ax = self.ax
        nx = self.nx
        i = self._i
        while i and x_code < ax[i]:
            i -= 1
        while i < nx - 2 and x_code >= ax[i + 1]:
            i += 1
        self._i = i
        if x_code <= ax[i]:
            tx = 0
        elif x_code >= ax[i + 1]:
            tx = 4096
        else:
            tx = ((x_code - ax[i]) * self.rdx[i]) >> 12          # Q12, product <= 2^24
        ay = self.ay
        j = self._j
        while j and y_code < ay[j]:
            j -= 1
        while j < self.ny - 2 and y_code >= ay[j + 1]:
            j += 1
        self._j = j
        if y_code <= ay[j]:
            ty = 0
        elif y_code >= ay[j + 1]:
            ty = 4096
        else:
            ty = ((y_code - ay[j]) * self.rdy[j]) >> 12
        h = self.h
        k = (j * nx + i) << 2                     # node (i, j); +4 is (i + 1, j); m is (i, j + 1)
        m = k + (nx << 2)
        for e in range(4):
            a = h[k]
            t = a + (((h[k + 4] - a) * tx) >> 12)               # |difference| <= 32000, times 4096 < 2^27
            a = h[m]
            u = a + (((h[m + 4] - a) * tx) >> 12)
            out[e] = t + (((u - t) * ty) >> 12)
            k += 1
            m += 1

    def hinv_at(self, x_code, y_code):
        """``hinv_into`` returning a new list (tests, telemetry)."""
        out = [0, 0, 0, 0]
        self.hinv_into(x_code, y_code, out)
        return out


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
    return HinvTable(htable.parse(data))
