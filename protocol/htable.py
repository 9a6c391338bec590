"""The H table on a rectilinear grid, and its compact binary blob for the HTABLE upload (pure, MicroPython).

The calibration JSON (docs/INTERFACES.md) holds one point per P-FSM grid voltage: the FSM voltages V0 that null
the quadcell there and the H measured at V0 (Eq. 7.14-7.16). Those V0 are scattered, because the FSM
answers a P-FSM step along one axis with a little motion along the other. The controller interpolates over
a rectilinear grid, so ``grid_from_calibration`` derives one:

- it finds which P-FSM axis drives each FSM axis (the grouping whose column means of V0 spread widest);
- the FSM X axis values are the means of V0x over each such column, the Y axis values the means of V0y
  over each row; they are sorted ascending;
- node (i, j) takes the H of the grid point in column i and row j. ``max_dev_v`` reports how far the
  points' own V0 lie from their nodes (the cross-coupling the rectilinear grid ignores).

The blob (``pack``, ``parse``) is laid out and checked in ``protocol.hblob``, whose names are this module's too.
"""

import struct

from protocol.hblob import (HEADER_FMT, HEADER_SIZE, MAGIC, MAX_AXIS, V_RANGE, VERSION, Blob,  # noqa: F401
                            HTableError, Rectilinear, _crc32, _num, blob_size, validate)

def _pair(p, key, i):
    v = p.get(key) if isinstance(p, dict) else None
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise HTableError("calibration points[%d].%s must be [x, y], got %r" % (i, key, v))
    return _num(v[0], "points[%d].%s[0]" % (i, key)), _num(v[1], "points[%d].%s[1]" % (i, key))


def _matrix(p, i):
    h = p.get("H")
    if not isinstance(h, (list, tuple)) or len(h) != 2 or not all(isinstance(r, (list, tuple)) and len(r) == 2
                                                                 for r in h):
        raise HTableError("calibration points[%d].H must be [[a, b], [c, d]], got %r" % (i, h))
    return (_num(h[0][0], "points[%d].H[0][0]" % i), _num(h[0][1], "points[%d].H[0][1]" % i),
            _num(h[1][0], "points[%d].H[1][0]" % i), _num(h[1][1], "points[%d].H[1][1]" % i))


def _index(grid, v, what):
    best = 0
    for k in range(1, len(grid)):
        if abs(grid[k] - v) < abs(grid[best] - v):
            best = k
    step = abs(grid[1] - grid[0]) if len(grid) > 1 else 1.0
    if abs(grid[best] - v) > 0.25 * step:
        raise HTableError("%s = %r is not on grid_v" % (what, v))
    return best


def _spread(vals):
    return max(vals) - min(vals)


class Grid(Rectilinear):
    """A rectilinear H table: ``ax``, ``ay`` (V, ascending), ``h`` (list of (a, b, c, d), index j*nx + i)."""

    def __init__(self, ax, ay, h, max_dev_v=0.0):
        self.ax = [float(v) for v in ax]
        self.ay = [float(v) for v in ay]
        self.h = [tuple(float(e) for e in m) for m in h]
        self.max_dev_v = max_dev_v
        self.points = None
        self.validate()


def grid_from_calibration(cal):
    """A ``Grid`` from the calibration JSON dict (see the module docstring for the axis choice)."""
    if not isinstance(cal, dict):
        raise HTableError("calibration must be a JSON object, got %r" % type(cal).__name__)
    grid = cal.get("grid_v")
    points = cal.get("points")
    if not isinstance(grid, (list, tuple)) or len(grid) < 2:
        raise HTableError("calibration grid_v must list >= 2 P-FSM voltages, got %r" % (grid,))
    if not isinstance(points, (list, tuple)):
        raise HTableError("calibration points must be a list, got %r" % type(points).__name__)
    grid = [_num(grid[k], "grid_v[%d]" % k) for k in range(len(grid))]
    n = len(grid)
    if len(points) != n * n:
        raise HTableError("calibration has %d points, a full %dx%d P-FSM grid needs %d" % (len(points), n, n,
                                                                                           n * n))
    cells = [None] * (n * n)     # by P-FSM index (p, q): p along P-FSM x, q along P-FSM y
    for i in range(len(points)):
        pt = points[i]
        pv = _pair(pt, "pfsm_v", i)
        v0 = _pair(pt, "v0", i)
        if abs(v0[0]) > V_RANGE or abs(v0[1]) > V_RANGE:
            raise HTableError("calibration points[%d].v0 = %r outside the FSM range +-%g V" % (i, v0, V_RANGE))
        h = _matrix(pt, i)
        p = _index(grid, pv[0], "points[%d].pfsm_v[0]" % i)
        q = _index(grid, pv[1], "points[%d].pfsm_v[1]" % i)
        if cells[q * n + p] is not None:
            raise HTableError("calibration points[%d] repeats P-FSM grid point (%r, %r)" % (i, pv[0], pv[1]))
        cells[q * n + p] = (v0, h, i)
    # means[a][axis][k]: mean of V0[axis] over the points whose P-FSM index along a is k
    means = [[[0.0] * n, [0.0] * n], [[0.0] * n, [0.0] * n]]
    for q in range(n):
        for p in range(n):
            v0 = cells[q * n + p][0]
            for axis in (0, 1):
                means[0][axis][p] += v0[axis] / n
                means[1][axis][q] += v0[axis] / n
    drive_x = 0 if _spread(means[0][0]) >= _spread(means[1][0]) else 1
    drive_y = 0 if _spread(means[0][1]) > _spread(means[1][1]) else 1
    if drive_x == drive_y:
        raise HTableError("calibration: FSM X and Y both follow P-FSM axis %d; no rectilinear grid" % drive_x)
    ox = sorted(range(n), key=lambda k: means[drive_x][0][k])   # P-FSM indices in ascending FSM X
    oy = sorted(range(n), key=lambda k: means[drive_y][1][k])
    ax = [means[drive_x][0][k] for k in ox]
    ay = [means[drive_y][1][k] for k in oy]
    h = []
    src = []
    dev = 0.0
    for j in range(n):
        for i in range(n):
            pq = [0, 0]
            pq[drive_x] = ox[i]
            pq[drive_y] = oy[j]
            v0, m, k = cells[pq[1] * n + pq[0]]
            dev = max(dev, abs(v0[0] - ax[i]), abs(v0[1] - ay[j]))
            h.append(m)
            src.append(k)
    g = Grid(ax, ay, h, dev)
    g.points = src          # node -> index in the calibration's points (to name a refused node's point)
    return g


def pack(g):
    """The blob bytes of a ``Grid``."""
    g.validate()
    nx, ny = g.nx, g.ny
    out = bytearray(blob_size(nx, ny))
    struct.pack_into(HEADER_FMT, out, 0, MAGIC, VERSION, nx, ny)
    off = HEADER_SIZE
    for v in g.ax + g.ay:
        struct.pack_into("<f", out, off, v)
        off += 4
    for m in g.h:
        struct.pack_into("<ffff", out, off, m[0], m[1], m[2], m[3])
        off += 16
    struct.pack_into("<I", out, off, _crc32(memoryview(out)[:off]) & 0xFFFFFFFF)
    return bytes(out)


def parse(data):
    """A ``Grid`` from blob bytes; HTableError on a bad magic, version, size, CRC or value."""
    b = Blob(data)
    return Grid([b.ax[k] for k in range(b.nx)], [b.ay[k] for k in range(b.ny)], [b.h[k] for k in range(len(b.h))])


def pack_calibration(cal):
    """Blob bytes straight from the calibration JSON dict (what ground uploads)."""
    return pack(grid_from_calibration(cal))
