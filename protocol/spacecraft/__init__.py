"""One spacecraft file: the schema, its checker and the presets (pure Python; runs under MicroPython too).

A spacecraft file is a JSON object describing one vehicle as a flight team knows it before flight: mass and
inertia, residual dipole, reaction wheels, star tracker, gyro, GNSS, beacon, orbit, magnetorquers and
magnetometer, and the 1 sigma uncertainty of each figure the filters will estimate (their priors and initial
covariance). Units are in the key names (``_kgm2`` kg m^2, ``_am2`` A m^2, ``_nm`` N m, ``_rpm``, ``_arcsec``,
``_deg``, ``_deg_s`` deg/s, ``_hz``, ``_m``, ``_m_s`` m/s, ``_km``, ``_nt`` nT, ``_s``). ``SCHEMA`` lists every key
with its shape, unit, allowed range and meaning; docs/SPACECRAFT.md is generated from it
(``fps spacecraft schema``).

- ``check(d)``: a checked, normalised copy (numbers as floats, counts as ints, absent optional blocks as None);
  ValueError naming the key path, the value and the allowed range, e.g. ``wheels.speed_limit_rpm = -5: must be
  > 0 and <= 100000 rpm``.
- ``load(name_or_path)``: a preset by name (``presets()``) or a JSON file, checked.
- ``inertia_matrix(d)``, ``wheel_axes(d)``, ``reference_axes(d)``, ``true_figures(d)``, ``principal_moments(j6)``,
  ``beacon_misalignment_deg(d)``: what a filter or a simulator needs from a checked file, as nested lists.

Conventions. Body frame as the emulator's (Yoon 2017, Sec. 4.2). ``inertia_kgm2`` = [Jxx, Jyy, Jzz, Jxy, Jxz,
Jyz] about the centre of mass, the products being the matrix's off-diagonal entries (Jxy = -integral of x y dm,
not the product of inertia +integral x y dm that CAD tools print); the spacecraft with its wheels, less the
rotors' own inertia about their spin axes (emulator.spacecraft.dynamics's J). Wheel misalignment (``wheel_axes``,
Eq. 4.58-4.60 and 4.148): wheel i's axis is c_i = normalise(n_i + d1_i e1_i + d2_i e2_i), n_i the unit nominal
axis, d1_i, d2_i the two angles in radians, e1_i = normalise(n_i x n_j) with j the next wheel in the list (the
last's next is the first; if n_i x n_j vanishes, the body axis least aligned with n_i takes n_j's place),
e2_i = normalise(n_i x e1_i). The angles enter linearly, as in the thesis: the axis tilts by
atan(sqrt(d1^2 + d2^2)), 11.8 deg for 12 deg, the same to 0.1 % below 3 deg.

The ``truth`` block (optional, simulation only): how the simulated vehicle departs from the figures (true =
figure + error), e.g. the thesis's Sec. 4.8 errors. A flight team leaves it out.
"""

import json
import math
import os
import sys

MICROPYTHON = sys.implementation.name == "micropython"
SPAN_MIN = 1e-3        # least eigenvalue of C C^T (unit axes) for the wheels to span three axes

try:
    _DIR = __file__.rsplit("/", 1)[0]
except (NameError, AttributeError):      # frozen into firmware: no presets on the filesystem
    _DIR = "."

# the schema: every key, its kind, unit, range and meaning
from protocol.spacecraft.schema import (ANY, BY_PATH, FORMAT, MAX_WHEELS, NONNEG, POS, SCHEMA, WHEELS,  # noqa: F401
                                        _children, _e, _rng)


# --- formatting ---------------------------------------------------------------------------------------------
def num_text(v):
    """A number as people write it: 10000 (not 10000.0), 3e-06, 0.012, nan."""
    if isinstance(v, float) and v == v and abs(v) < 1e15 and v == int(v):
        return str(int(v))
    return repr(v)


def value_text(v, limit=120, depth=0):
    """A JSON value, shortened to ``limit`` characters, for a message: an integer of more than 20 digits by its
    first and last digits and its length, arrays and objects nested beyond 8 levels as "...". ``depth``: the
    nesting level of ``v`` itself."""
    if v is None:
        s = "null"
    elif v is True or v is False:
        s = "true" if v else "false"
    elif isinstance(v, (int, float)):
        s = num_text(v)
        n = len(s) - (s[0] == "-")
        if isinstance(v, int) and n > 20:
            s = "%s...%s (%d digits)" % (s[:len(s) - n + 6], s[-3:], n)
    elif isinstance(v, str):
        s = '"' + v + '"'
    elif isinstance(v, (list, tuple, dict)) and depth >= 8:
        s = "[...]" if isinstance(v, (list, tuple)) else "{...}"
    elif isinstance(v, (list, tuple)):
        s = "[" + ", ".join(value_text(x, limit, depth + 1) for x in v) + "]"
    elif isinstance(v, dict):
        s = "{" + ", ".join('"%s": %s' % (k, value_text(v[k], limit, depth + 1)) for k in sorted(v)) + "}"
    else:
        s = repr(v)
    return s if len(s) <= limit else s[:limit - 3] + "..."


def range_text(rng, unit=""):
    """The allowed range in words: "> 0 rpm", "from -45 to 45 deg", ">= 0 and < 360 deg"."""
    lo, lo_open, hi, hi_open = rng
    if lo is None and hi is None:
        s = "any finite number"
    elif hi is None:
        s = "%s %s" % (">" if lo_open else ">=", num_text(lo))
    elif lo is None:
        s = "%s %s" % ("<" if hi_open else "<=", num_text(hi))
    elif not lo_open and not hi_open:
        s = "from %s to %s" % (num_text(lo), num_text(hi))
    else:
        s = "%s %s and %s %s" % (">" if lo_open else ">=", num_text(lo), "<" if hi_open else "<=", num_text(hi))
    return s + (" " + unit if unit and unit != "1" else "")


def _in(v, rng):
    lo, lo_open, hi, hi_open = rng
    if lo is not None and (v <= lo if lo_open else v < lo):
        return False
    if hi is not None and (v >= hi if hi_open else v > hi):
        return False
    return True


# --- the checker --------------------------------------------------------------------------------------------
def _is_num(v):
    return isinstance(v, (int, float)) and not (v is True or v is False)


def _is_whole(v):
    """v is a finite number with no fraction (an integer of any size included)."""
    return _is_num(v) and v == v and abs(v) != float("inf") and v == int(v)


def _number(path, v, e):
    """v as a float in e's range, else ValueError (showing v as given)."""
    if not _is_num(v):
        raise ValueError("%s = %s: must be a number, %s" % (path, value_text(v), range_text(e["range"], e["unit"])))
    try:
        x = float(v)
    except OverflowError:                  # an integer beyond any float
        x = float("inf")
    if not (x == x and abs(x) != float("inf")):
        raise ValueError("%s = %s: must be a finite number, %s" % (path, value_text(v), range_text(e["range"],
                                                                                                    e["unit"])))
    if not _in(x, e["range"]):
        raise ValueError("%s = %s: must be %s" % (path, value_text(v), range_text(e["range"], e["unit"])))
    return x


def _vector(path, v, n, e):
    if not isinstance(v, list) or len(v) != n:
        raise ValueError("%s = %s: must be a list of %d numbers, each %s" % (
            path, value_text(v), n, range_text(e["range"], e["unit"])))
    return [_number("%s[%d]" % (path, i), x, e) for i, x in enumerate(v)]


def _length(e, out):
    n = e["n"]
    return out["wheels"]["count"] if n == WHEELS else n


def _parse_epoch(path, s):
    """(y, mo, d, h, mi, s) from "YYYY-MM-DDThh:mm:ss[.fff]" (a trailing Z allowed)."""
    bad = ValueError('%s = %s: must be a UTC time "YYYY-MM-DDThh:mm:ss[.s]" from 1957 to 2200'
                     % (path, value_text(s)))
    if not isinstance(s, str) or len(s) < 19 or len(s) > 40:
        raise bad
    t = s[:-1] if s.endswith("Z") else s
    if t[4] != "-" or t[7] != "-" or t[10] != "T" or t[13] != ":" or t[16] != ":":
        raise bad
    try:
        parts = [t[0:4], t[5:7], t[8:10], t[11:13], t[14:16]]
        for p in parts:
            if not p.isdigit():
                raise bad
        y, mo, d, h, mi = [int(p) for p in parts]
        sec = t[17:]
        if not sec[:2].isdigit() or (len(sec) > 2 and (sec[2] != "." or not sec[3:].isdigit())):
            raise bad
        sec = float(sec)
    except (ValueError, IndexError):
        raise bad
    mdays = (31, 29 if (y % 4 == 0 and (y % 100 != 0 or y % 400 == 0)) else 28, 31, 30, 31, 30, 31, 31, 30, 31,
             30, 31)
    if not (1957 <= y <= 2200 and 1 <= mo <= 12 and 1 <= d <= mdays[mo - 1] and h <= 23 and mi <= 59
            and sec < 61.0):
        raise bad
    return (y, mo, d, h, mi, sec)


def _walk(block, d, out):
    """Check the keys of ``block`` in ``d`` into ``out`` (schema order); unknown keys first."""
    kids = _children(block)
    names = [e["path"].split(".")[-1] for e in kids]
    for k in sorted(d):
        if k not in names:
            where = block or "the top level"
            raise ValueError("%s: unknown key (%s takes: %s)" % (
                (block + "." if block else "") + str(k), where, ", ".join(names)))
    for e, k in zip(kids, names):
        path = e["path"]
        if k not in d or (d[k] is None and e["optional"] and e["kind"] in ("num", "vec")):    # null: as absent
            if e["optional"]:
                out[k] = {} if e["kind"] == "sources" else None
                continue
            raise ValueError("%s: missing (%s%s)" % (path, e["doc"], ", " + _shape_text(e) if e["kind"] in
                                                     ("num", "int", "vec", "axes") else ""))
        v = d[k]
        kind = e["kind"]
        if kind == "block":
            if v is None and e["nullable"]:
                out[k] = None
                continue
            if not isinstance(v, dict):
                raise ValueError("%s = %s: must be an object (%s)%s" % (
                    path, value_text(v), e["doc"], " or null" if e["nullable"] else ""))
            out[k] = {}
            _walk(path, v, out[k])
        elif kind == "str":
            if not isinstance(v, str) or not v.strip() or len(v) > 2000:
                raise ValueError("%s = %s: must be a non-empty string (%s)" % (path, value_text(v), e["doc"]))
            out[k] = v
        elif kind == "int":
            if not _is_whole(v) or not _in(v, e["range"]):
                raise ValueError("%s = %s: must be a whole number %s" % (path, value_text(v),
                                                                         range_text(e["range"])))
            out[k] = int(v)
        elif kind == "num":
            out[k] = _number(path, v, e)
        elif kind == "vec":
            out[k] = _vector(path, v, _length(e, _ROOT[0]), e)
        elif kind == "axes":
            n = _length(e, _ROOT[0])
            if not isinstance(v, list) or len(v) != n:
                raise ValueError("%s = %s: must be a list of %d vectors [x, y, z]" % (path, value_text(v), n))
            out[k] = [_vector("%s[%d]" % (path, i), a, 3, e) for i, a in enumerate(v)]
        elif kind == "epoch":
            _parse_epoch(path, v)
            out[k] = v
        elif kind == "sources":
            if not isinstance(v, dict):
                raise ValueError("%s = %s: must be an object of key path -> text" % (path, value_text(v)))
            out[k] = {}
            for s in sorted(v):
                if s not in BY_PATH or s == "sources":
                    raise ValueError("sources.%s: not a key of the schema (sources name a block or a key, e.g. "
                                     "\"wheels\" or \"wheels.tach_noise_rpm\")" % s)
                if not isinstance(v[s], str) or not v[s].strip():
                    raise ValueError("sources.%s = %s: must be a non-empty string" % (s, value_text(v[s])))
                out[k][s] = v[s]


_ROOT = [None]     # the top-level output while checking (vectors sized by wheels.count read it)


def _shape_text(e):
    n = e["n"]
    if e["kind"] == "vec":
        return "%s numbers, each %s" % ("wheels.count" if n == WHEELS else n, range_text(e["range"], e["unit"]))
    if e["kind"] == "axes":
        return "%s vectors [x, y, z]" % ("wheels.count" if n == WHEELS else n)
    if e["kind"] == "int":
        return "a whole number " + range_text(e["range"])
    return "a number " + range_text(e["range"], e["unit"])


def check(d):
    """A checked, normalised copy of the spacecraft dict ``d``; ValueError naming the key, the value and the
    allowed range. Checks beyond each key's range: the inertia (nominal and true) is a rigid body's, the wheels
    (nominal and true) and the magnetorquers span three axes, the laser axis is not zero, |r| and |v| of the
    orbit states, the relay delay's min <= max; then physical plausibility (``protocol.spacecraft.plausible``: mass,
    inertia, rotor inertia and lengths against each other and the vehicle's size, catching a unit slip)."""
    if not isinstance(d, dict):
        raise ValueError("a spacecraft file must be a JSON object, got %s" % value_text(d, 40))
    out = {}
    _ROOT[0] = out
    try:
        _walk("", d, out)
    finally:
        _ROOT[0] = None
    if out["format"] != FORMAT:
        raise ValueError('format = %s: must be "%s"' % (value_text(out["format"]), FORMAT))
    for ch in out["name"]:
        if not (ch.isalpha() or ch.isdigit() or ch in "-_.") or len(out["name"]) > 64:
            raise ValueError("name = %s: must be 1 to 64 letters, digits, - _ ." % value_text(out["name"]))
    _check_inertia("inertia_kgm2", out["inertia_kgm2"])
    _nonzero("laser_axis", out["laser_axis"])
    w = out["wheels"]
    for i, a in enumerate(w["nominal_axes"]):
        _nonzero("wheels.nominal_axes[%d]" % i, a)
    _check_span("wheels.nominal_axes = %s (with wheels.delta1_deg = %s, wheels.delta2_deg = %s)" % (
        value_text(w["nominal_axes"]), value_text(w["delta1_deg"]), value_text(w["delta2_deg"])), wheel_axes(out))
    t = out["truth"]
    if t is not None:
        tf = true_figures(out)
        j = tf["inertia_kgm2"]
        _check_inertia("truth.inertia_error_kgm2", j, "the true inertia inertia_kgm2 + truth.inertia_error_kgm2 "
                       "= %s" % value_text(j))
        for i, v in enumerate(tf["rotor_inertia_kgm2"]):
            if not v > 0:
                raise ValueError("truth.rotor_inertia_error_kgm2[%d] = %s: the true rotor inertia %s must be "
                                 "> 0 kg m^2" % (i, num_text(t["rotor_inertia_error_kgm2"][i]),
                                                 num_text(float("%.6g" % v))))
        for k in ("delta1", "delta2"):
            for i, v in enumerate(tf[k + "_deg"]):
                if not -45.0 <= v <= 45.0:
                    raise ValueError("truth.%s_error_deg[%d] = %s: the true angle %s must be from -45 to 45 deg"
                                     % (k, i, num_text(t[k + "_error_deg"][i]), num_text(float("%.6g" % v))))
        _check_span("truth.delta1_error_deg = %s, truth.delta2_error_deg = %s: the true wheel axes" % (
            value_text(t["delta1_error_deg"]), value_text(t["delta2_error_deg"])), wheel_axes(out, True))
        for i, v in enumerate(beacon_misalignment_deg(out)):
            if not -5.0 <= v <= 5.0:
                raise ValueError("truth.beacon_misalignment_error_deg[%d] = %s: the true angle %s must be from -5 to "
                                 "5 deg" % (i, num_text(t["beacon_misalignment_error_deg"][i]),
                                            num_text(float("%.6g" % v))))
    s = out["orbit"]["state"]
    rn = _norm(s["position_m"])
    if not 6478e3 <= rn <= 1e8:
        raise ValueError("orbit.state.position_m = %s: |r| = %s m must be from 6478000 to 100000000 m"
                         % (value_text(s["position_m"]), num_text(rn)))
    vn = _norm(s["velocity_m_s"])
    if not 0 < vn < 12e3:
        raise ValueError("orbit.state.velocity_m_s = %s: |v| = %s m/s must be > 0 and < 12000 m/s"
                         % (value_text(s["velocity_m_s"]), num_text(vn)))
    p = out["partner"]
    if p is not None:
        if _norm(p["position_m"]) < 6478e3:
            raise ValueError("partner.position_m = %s: |r| must be >= 6478000 m" % value_text(p["position_m"]))
        dr = _norm([a - b for a, b in zip(p["position_m"], s["position_m"])])
        if not dr > 0:
            raise ValueError("partner.position_m = %s: must differ from orbit.state.position_m"
                             % value_text(p["position_m"]))
        lo, hi = p["relay_delay_s"]
        if lo > hi:
            raise ValueError("partner.relay_delay_s = %s: must be [min, max] with min <= max"
                             % value_text(p["relay_delay_s"]))
    m = out["magnetorquers"]
    if m is not None:
        for i, a in enumerate(m["axes"]):
            _nonzero("magnetorquers.axes[%d]" % i, a)
        _check_span("magnetorquers.axes = %s" % value_text(m["axes"]), [_unit(a) for a in m["axes"]])
    from protocol.spacecraft.plausible import check_plausible
    check_plausible(out, principal_moments)
    return out


def _nonzero(path, v):
    if not _norm(v) > 0:
        raise ValueError("%s = %s: must not be zero (a direction)" % (path, value_text(v)))


def _check_inertia(path, j6, what=None):
    lam = principal_moments(j6)
    J = inertia_matrix({"inertia_kgm2": j6})
    minors = (J[0][0], J[0][0] * J[1][1] - J[0][1] * J[0][1], _det3(J))
    head = "%s = %s: " % (path, value_text(j6)) if what is None else "%s: %s: " % (path, what)
    if not (minors[0] > 0 and minors[1] > 0 and minors[2] > 0 and lam[0] > 0):
        raise ValueError(head + "not positive definite (principal moments %s kg m^2); must be a rigid body's "
                         "inertia: positive definite, each principal moment <= the sum of the other two"
                         % value_text([float("%.6g" % x) for x in lam]))
    if lam[2] > (lam[0] + lam[1]) * (1.0 + 1e-9):
        raise ValueError(head + "no rigid body's: its largest principal moment %s exceeds the sum of the other two, "
                         "%s kg m^2 (triangle inequality, e.g. Jxx + Jyy >= Jzz for principal moments)"
                         % (num_text(float("%.6g" % lam[2])), num_text(float("%.6g" % (lam[0] + lam[1])))))


def _check_span(head, axes):
    """ValueError starting with ``head`` unless the unit vectors ``axes`` span three axes."""
    g = [[sum(a[r] * a[c] for a in axes) for c in range(3)] for r in range(3)]
    lam = _eig_sym3(g)
    if not lam[0] >= SPAN_MIN:
        raise ValueError("%s: do not span three axes: the least eigenvalue of C C^T (C: the unit axes) is %s, must "
                         "be >= %s (every body axis needs a share of the torque)"
                         % (head, num_text(float("%.3g" % lam[0])), num_text(SPAN_MIN)))


# --- helpers ------------------------------------------------------------------------------------------------
def _norm(v):
    return math.sqrt(sum(x * x for x in v))


def _unit(v):
    n = _norm(v)
    return [x / n for x in v]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _det3(m):
    return (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))


def _eig_sym3(m):
    """Eigenvalues of a symmetric 3 x 3 (nested lists), ascending (the trigonometric closed form)."""
    a, b, c, d, e, f = m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]
    p1 = b * b + c * c + e * e
    if p1 == 0:
        return sorted([a, d, f])
    q = (a + d + f) / 3.0
    p2 = (a - q) ** 2 + (d - q) ** 2 + (f - q) ** 2 + 2.0 * p1
    p = math.sqrt(p2 / 6.0)
    B = [[(a - q) / p, b / p, c / p], [b / p, (d - q) / p, e / p], [c / p, e / p, (f - q) / p]]
    r = max(-1.0, min(1.0, _det3(B) / 2.0))
    phi = math.acos(r) / 3.0
    e1 = q + 2.0 * p * math.cos(phi)
    e3 = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return sorted([e3, 3.0 * q - e1 - e3, e1])


def principal_moments(j6):
    """The principal moments (kg m^2, ascending) of [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz]."""
    return _eig_sym3(inertia_matrix({"inertia_kgm2": j6}))


def true_figures(d, true=True):
    """The figures a simulation flies (true = figure + the truth block's error; the figures themselves without a
    truth block or with ``true=False``): inertia_kgm2, residual_dipole_am2, rotor_inertia_kgm2, delta1_deg,
    delta2_deg (lists of floats)."""
    w = d["wheels"]
    out = {"inertia_kgm2": list(d["inertia_kgm2"]), "residual_dipole_am2": list(d["residual_dipole_am2"]),
           "rotor_inertia_kgm2": list(w["rotor_inertia_kgm2"]), "delta1_deg": list(w["delta1_deg"]),
           "delta2_deg": list(w["delta2_deg"])}
    t = d.get("truth")
    if true and t:
        for k, e in (("inertia_kgm2", "inertia_error_kgm2"), ("residual_dipole_am2", "residual_dipole_error_am2"),
                     ("rotor_inertia_kgm2", "rotor_inertia_error_kgm2"), ("delta1_deg", "delta1_error_deg"),
                     ("delta2_deg", "delta2_error_deg")):
            out[k] = [a + b for a, b in zip(out[k], t[e])]
    return out


def beacon_misalignment_deg(d, true=True):
    """The beacon camera's misalignment of a checked file ``d``, the rotation vector [x, y, z] in deg
    (``beacon.misalignment_deg``, schema): the figure plus, with ``true``, the truth block's error; an absent
    figure or error is zero."""
    out = list(d["beacon"].get("misalignment_deg") or [0.0, 0.0, 0.0])
    t = d.get("truth")
    e = t.get("beacon_misalignment_error_deg") if true and t else None
    return [a + b for a, b in zip(out, e)] if e else out


def beacon_misalignment_sigma_deg(d):
    """1 sigma of each angle of ``beacon_misalignment_deg`` (``uncertainty.beacon_misalignment_sigma_deg``;
    absent: 0)."""
    return d["uncertainty"].get("beacon_misalignment_sigma_deg") or 0.0


def inertia_matrix(d, true=False):
    """The 3 x 3 inertia (kg m^2, nested lists) of a checked file ``d`` (with ``true``: the truth block's)."""
    j = true_figures(d)["inertia_kgm2"] if true else d["inertia_kgm2"]
    return [[j[0], j[3], j[4]], [j[3], j[1], j[5]], [j[4], j[5], j[2]]]


def misalignment_axes(n):
    """(e1, e2) per wheel for the unit nominal axes ``n`` (list of 3-lists): the module docstring's convention
    (Eq. 4.148 for a pyramid)."""
    e1, e2 = [], []
    for i, a in enumerate(n):
        b = n[(i + 1) % len(n)]
        v = _cross(a, b)
        if _norm(v) < 1e-6:                       # parallel neighbours: the least aligned body axis instead
            k = min(range(3), key=lambda j: abs(a[j]))
            v = _cross(a, [1.0 if j == k else 0.0 for j in range(3)])
        v = _unit(v)
        e1.append(v)
        e2.append(_unit(_cross(a, v)))
    return e1, e2


def reference_axes(d):
    """Each wheel's unit nominal axis n_i (count x 3, body frame): the reference every misalignment angle is
    measured from, the file's ``wheels.delta*_deg`` and the truth's alike (``wheel_axes`` with all angles zero,
    the same arithmetic). A filter that estimates the angles starts from these axes and the file's angles as
    its prior, so that a nominal tilt is counted once."""
    return [_unit([x + 0.0 for x in _unit(a)]) for a in d["wheels"]["nominal_axes"]]


def wheel_axes(d, true=False):
    """Each wheel's unit spin axis (count x 3, body frame) from the nominal axes and the misalignment angles
    (with ``true``: the truth block's angles): c_i = normalise(n_i + d1_i e1_i + d2_i e2_i), angles in radians
    (module docstring; Eq. 4.58-4.60)."""
    w = d["wheels"]
    f = true_figures(d, true)
    n = [_unit(a) for a in w["nominal_axes"]]
    e1, e2 = misalignment_axes(n)
    out = []
    for i in range(len(n)):
        d1, d2 = math.radians(f["delta1_deg"][i]), math.radians(f["delta2_deg"][i])
        out.append(_unit([n[i][r] + e1[i][r] * d1 + e2[i][r] * d2 for r in range(3)]))
    return out


# the thesis's budgets: body pointing and stability (Sec. 6.4), the fine loop's requirement (Ch. 2: half the
# beam's FWHM), and the flight world's wheel speed share
THESIS_REQUIREMENTS = {"body_pointing_3sigma_arcsec": 150.0, "body_stability_3sigma_arcsec_s": 35.0,
                       "fine_pointing_arcsec": 11.98, "wheel_speed_share": 0.8}


def requirements(d):
    """The budgets of the checked file ``d``: its ``requirements`` block, or the thesis's
    (``THESIS_REQUIREMENTS``) where it has none; with ``source`` "file" or "thesis"."""
    r = d.get("requirements") if d is not None else None
    if r:
        return dict(r, source="file")
    return dict(THESIS_REQUIREMENTS, source="thesis")


def epoch_tuple(d):
    """orbit.state.epoch_utc as (year, month, day, hour, minute, second) (emulator.orbits.EPOCH_UTC's form)."""
    return _parse_epoch("orbit.state.epoch_utc", d["orbit"]["state"]["epoch_utc"])


# --- presets and files --------------------------------------------------------------------------------------
def presets():
    """The preset names (the .json files beside this module), sorted."""
    try:
        names = os.listdir(_DIR)
    except OSError:
        return []
    return sorted(n[:-5] for n in names if n.endswith(".json"))


def preset_path(name):
    """The file of preset ``name``; ValueError naming the presets if there is none."""
    if name not in presets():
        raise ValueError("no preset %s (presets: %s)" % (value_text(name), ", ".join(presets())))
    return _DIR + "/" + name + ".json"


def _no_duplicates(pairs):
    d = {}
    for k, v in pairs:
        if k in d:
            raise ValueError("key %s appears twice in one object" % value_text(k))
        d[k] = v
    return d


def read(path):
    """The JSON object in file ``path``, unchecked; ValueError naming the file if it cannot be read or parsed.
    Under CPython through protocol.fileio.read_json (size-limited; a key twice in one object is refused)."""
    if not MICROPYTHON:
        from protocol.fileio import read_json
        try:
            return read_json(path, "spacecraft file", object_pairs_hook=_no_duplicates)
        except ValueError as exc:
            if str(exc).startswith("spacecraft file "):
                raise
            raise ValueError("spacecraft file %s: %s" % (path, exc))     # a key twice
    try:
        with open(path) as f:
            text = f.read()
    except OSError as exc:
        raise ValueError("spacecraft file %s: cannot read it (%s)" % (path, exc))
    try:
        return json.loads(text)
    except ValueError as exc:
        raise ValueError("spacecraft file %s: not valid JSON (%s)" % (path, exc))


def _exists(path):
    try:
        os.stat(path)
        return True
    except OSError:
        return False


def load(name_or_path):
    """A checked spacecraft (``check``'s copy) from a preset name or a JSON file path. ValueError: the file
    cannot be read, is not JSON, or fails the check (the message starts with the file)."""
    if not isinstance(name_or_path, str) or not name_or_path:
        raise ValueError("name a preset (%s) or a spacecraft file" % ", ".join(presets()))
    if name_or_path in presets() and not _exists(name_or_path):
        path = preset_path(name_or_path)
    elif _exists(name_or_path) or "/" in name_or_path or name_or_path.endswith(".json"):
        path = name_or_path
    else:
        raise ValueError("%s is neither a preset (%s) nor a file" % (value_text(name_or_path),
                                                                     ", ".join(presets())))
    d = read(path)
    try:
        return check(d)
    except ValueError as exc:
        raise ValueError("spacecraft file %s: %s" % (path, exc))
