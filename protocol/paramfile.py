"""The calibration parameter file ("fps-bps-params/1") and its one checker, for the ground and the flight firmware
alike (pure Python; runs under MicroPython too).

The file carries what the calibration maneuvers taught the APKF into the pointing phase (Yoon 2017, Sec. 6.4.2):
ground/adcs/body_pointing.py writes it (``calibrate``), ``emulator.spacecraft.scenario.truth_params`` writes a perfect
one, and both the ground's pointing run and the lean flight APKF (firmware/adcs/apkf_lean.py) start from it.
Keys:

- ``format``: "fps-bps-params/1";
- ``wheels``: the number of wheels (4; with a spacecraft file, its ``wheels.count``);
- ``jxx_ref_kgm2``: the APKF's fixed reference Jxx (Sec. 4.6.2), kg m^2;
- ``torque_scale`` (optional, default 1): s, the filter's relative scale (ground/adcs/body_pointing.py ``torque_scale``);
  the controller divides the filter's J, Jrw, m and tau_d by it;
- ``x``: the APKF's parameters in its relative units: ``tau_d_nm`` [3], ``J5_kgm2`` [Jyy, Jzz, Jxy, Jxz, Jyz],
  ``dipole_am2`` [3], ``delta1_rad`` [4], ``delta2_rad`` [4], ``jrw_kgm2`` [4] (one per wheel);
- ``P``: their 23 x 23 covariance, in the same order (symmetric positive definite);
- ``calibration`` (optional): an object, the calibration's own record (seed, sets, duration, ...), not checked
  further.

``check(d, spacecraft=None)``: a checked copy (numbers as floats, ``torque_scale`` and ``calibration`` filled
in), or ValueError naming the key, the value and the allowed range, e.g. ``x.jrw_kgm2[0] = 0.01: must be from
3e-07 to 3e-05 kg m^2``. The ranges say what a file may hold and still describe the vehicle: the wheels'
inertia within 10x of the vehicle's rotor inertia (the thesis's errors are 25 %), tau_d under the wheels' torque
limit, misalignments under 45 deg, a dipole under 10 A m^2, the inertia [Jxx ref, J5] a rigid body's, s in
(0.2, 5). Without ``spacecraft`` (a checked ``protocol.spacecraft`` file; of it only ``wheels.count``,
``wheels.rotor_inertia_kgm2`` and ``wheels.torque_limit_nm`` are read, so the flight firmware passes its
configuration's wheels block) the vehicle is the thesis's 3U (rotor inertia 3e-6 kg m^2, torque limit 1e-3 N m,
four wheels).
"""

import math

from protocol import spacecraft as sf

FORMAT = "fps-bps-params/1"
X_PARTS = (("tau_d_nm", 3), ("J5_kgm2", 5), ("dipole_am2", 3), ("delta1_rad", 4), ("delta2_rad", 4),
           ("jrw_kgm2", 4))
N_PARAMS = 23
KEYS = ("format", "wheels", "jxx_ref_kgm2", "torque_scale", "x", "P", "calibration")
OPTIONAL = ("torque_scale", "calibration")
THESIS_ROTOR_KGM2 = 3e-6      # the thesis's nominal rotor inertia and torque limit (Sec. 4.8; wheels datasheet)
THESIS_TORQUE_NM = 1e-3


def _g(v):
    return float("%.3g" % v)


def entries(spacecraft=None):
    """The schema entries (``protocol.spacecraft``'s form) of the numbers in a parameter file for ``spacecraft``
    (None: the thesis's 3U), keyed by path."""
    if spacecraft is None:
        jrw, tmax = [THESIS_ROTOR_KGM2], THESIS_TORQUE_NM
    else:
        jrw, tmax = spacecraft["wheels"]["rotor_inertia_kgm2"], spacecraft["wheels"]["torque_limit_nm"]
    quarter = math.pi / 4
    e = sf._e
    return dict((x["path"], x) for x in (
        e("jxx_ref_kgm2", "num", "kg m^2", sf._rng(0, 1e4, True), "the APKF's fixed reference Jxx"),
        e("torque_scale", "num", "1", sf._rng(0.2, 5, True, True), "the filter's relative scale s"),
        e("x.tau_d_nm", "vec", "N m", sf._rng(-tmax, tmax), "disturbance torque (within the wheels' torque "
          "limit)", n=3),
        e("x.J5_kgm2", "vec", "kg m^2", sf._rng(-1e4, 1e4), "[Jyy, Jzz, Jxy, Jxz, Jyz]", n=5),
        e("x.dipole_am2", "vec", "A m^2", sf._rng(-10, 10), "residual dipole", n=3),
        e("x.delta1_rad", "vec", "rad", sf._rng(-quarter, quarter), "misalignment angle 1 per wheel", n=4),
        e("x.delta2_rad", "vec", "rad", sf._rng(-quarter, quarter), "misalignment angle 2 per wheel", n=4),
        e("x.jrw_kgm2", "vec", "kg m^2", sf._rng(_g(min(jrw) / 10), _g(max(jrw) * 10)),
          "each wheel's inertia (within 10x of the vehicle's rotor inertia)", n=4)))


def _keys(where, d, names, optional=()):
    for k in sorted(d):
        if k not in names:
            raise ValueError("%s: unknown key (%s takes: %s)" % ((where + "." if where else "") + str(k),
                                                               where or "a parameter file", ", ".join(names)))
    for k in names:
        if k not in d and k not in optional:
            raise ValueError("%s: missing (%s has: %s)" % ((where + "." if where else "") + k,
                                                       where or "a parameter file", ", ".join(names)))


def check(d, spacecraft=None):
    """A checked copy of the parameter-file dict ``d`` for ``spacecraft`` (a checked spacecraft file; None: the
    thesis's 3U); ValueError naming the key, the value and the allowed range (the module docstring)."""
    if not isinstance(d, dict):
        raise ValueError("a parameter file must be a JSON object, got %s" % sf.value_text(d, 40))
    _keys("", d, KEYS, OPTIONAL)
    if d["format"] != FORMAT:
        raise ValueError('format = %s: must be "%s" (a calibration parameter file)' % (sf.value_text(d["format"]),
                                                                                      FORMAT))
    nw = 4 if spacecraft is None else spacecraft["wheels"]["count"]
    w = d["wheels"]
    if not sf._is_num(w) or w != nw:
        raise ValueError("wheels = %s: must be %d (the spacecraft's %d wheels)" % (sf.value_text(w), nw, nw))
    if nw != 4:
        raise ValueError("wheels.count = %d of the spacecraft: a parameter file's x and P hold four wheels" % nw)
    ent = entries(spacecraft)
    out = {"format": FORMAT, "wheels": nw,
           "jxx_ref_kgm2": sf._number("jxx_ref_kgm2", d["jxx_ref_kgm2"], ent["jxx_ref_kgm2"]),
           "torque_scale": sf._number("torque_scale", d.get("torque_scale", 1.0), ent["torque_scale"])}
    cal = d.get("calibration", {})
    if not isinstance(cal, dict):
        raise ValueError("calibration = %s: must be an object (the calibration's record: seed, sets, ...)"
                         % sf.value_text(cal))
    out["calibration"] = cal
    x = d["x"]
    if not isinstance(x, dict):
        raise ValueError("x = %s: must be an object of %s" % (sf.value_text(x), ", ".join(k for k, _ in X_PARTS)))
    _keys("x", x, [k for k, _ in X_PARTS])
    out["x"] = dict((k, sf._vector("x." + k, x[k], n, ent["x." + k])) for k, n in X_PARTS)
    j5 = out["x"]["J5_kgm2"]
    j6 = [out["jxx_ref_kgm2"], j5[0], j5[1], j5[2], j5[3], j5[4]]
    sf._check_inertia("x.J5_kgm2", j6, "with jxx_ref_kgm2, the inertia [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz] = %s"
                      % sf.value_text(j6))
    out["P"] = _covariance(d["P"])
    return out


def _fits(v):
    """The number v converts to a float (an integer beyond any float does not)."""
    try:
        float(v)
    except OverflowError:
        return False
    return True


def _covariance(P):
    """P as nested lists of floats: N_PARAMS x N_PARAMS, finite, symmetric, positive definite (Cholesky)."""
    n = N_PARAMS
    what = "must be the symmetric positive definite %d x %d covariance of x" % (n, n)
    if not isinstance(P, list) or len(P) != n:
        raise ValueError("P = %s: %s (a list of %d rows)" % (sf.value_text(P), what, n))
    out = []
    for i, row in enumerate(P):
        if not isinstance(row, list) or len(row) != n:
            raise ValueError("P[%d] = %s: %s (each row %d numbers)" % (i, sf.value_text(row), what, n))
        for j, v in enumerate(row):
            if not (sf._is_num(v) and v == v and abs(v) != float("inf") and _fits(v)):
                raise ValueError("P[%d][%d] = %s: must be a finite number (%s)" % (i, j, sf.value_text(v), what[8:]))
        out.append([float(v) for v in row])
    big = max(abs(v) for row in out for v in row)
    for i in range(n):
        for j in range(i):
            if abs(out[i][j] - out[j][i]) > 1e-9 * big:
                raise ValueError("P[%d][%d] = %s, P[%d][%d] = %s: %s (equal within 1e-9 of its largest entry)"
                                 % (i, j, sf.num_text(out[i][j]), j, i, sf.num_text(out[j][i]), what))
    L = [[0.0] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            s = out[i][j] - sum(L[i][k] * L[j][k] for k in range(j))
            if i == j:
                if not s > 0:
                    raise ValueError("P: %s; not positive definite (Cholesky pivot %d = %s)"
                                     % (what, i, sf.num_text(s)))
                L[i][i] = math.sqrt(s)
            else:
                L[i][j] = s / L[j][j]
    return out
