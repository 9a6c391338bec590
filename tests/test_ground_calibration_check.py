"""A calibration whose H the controller would refuse (singular, near-singular, or not invertible in its fixed
point) is refused when the file is loaded, naming the grid point, by the controller's own criterion
(firmware.hinv): load_calibration refuses exactly the tables the controller NACKs after an upload."""

import json
import os
import sys
import zlib

import pytest

from firmware import hinv
from firmware.controller import Controller
from ground import calibrate
from protocol import core, htable

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "mp"))
try:
    import firmware_plant as fp
finally:
    sys.path.pop(0)

P = core.PACKET_ID


def _write(tmp_path, cal, name="cal.json"):
    path = tmp_path / name
    path.write_text(json.dumps(cal))
    return str(path)


def _upload(cal):
    """Upload the calibration's blob to a controller as ground would; the last reply's packet id and code."""
    blob = htable.pack_calibration(cal)
    c = Controller()

    def send(name, **kw):
        return c.handle(P[name], core.NODE["GROUND"], 1, core.encode_payload(name, **kw))

    r = send("HTABLE_BEGIN", total=len(blob), crc32=zlib.crc32(blob))
    for off in range(0, len(blob), 48):
        part = blob[off:off + 48]
        r += send("HTABLE_CHUNK", offset=off, length=len(part), data=part)
    r += send("HTABLE_END", total=len(blob))
    assert all(x[0] == P["ACK"] for x in r[:-1])
    return r[-1][0], (r[-1][2][2] if r[-1][0] == P["NACK"] else 0)


def _with_h(cal, k, h):
    out = json.loads(json.dumps(cal))
    out["points"][k]["H"] = [[h[0], h[1]], [h[2], h[3]]]
    return out


def test_good_calibration_loads_and_uploads(tmp_path):
    cal = fp.calibration(5)
    assert calibrate.load_calibration(_write(tmp_path, cal))["grid_v"] == cal["grid_v"]
    assert _upload(cal) == (P["ACK"], 0)


@pytest.mark.parametrize("residual", [float("nan"), float("inf"), -0.1, True, "0.01", None, 10 ** 400])
def test_a_residual_that_is_not_a_fit_rms_is_refused_naming_it(tmp_path, residual):
    """The report prints each point's residual: NaN, infinite, negative, a boolean or a string is refused."""
    cal = json.loads(json.dumps(fp.calibration(5)))
    cal["points"][3]["residual"] = residual
    with pytest.raises(ValueError, match=r"points\[3\]\.residual must be a finite number >= 0"):
        calibrate.load_calibration(_write(tmp_path, cal))


def test_singular_h_refused_at_load_naming_the_point(tmp_path):
    cal = fp.calibration(5)
    k = 7
    pv = cal["points"][k]["pfsm_v"]
    bad = _with_h(cal, k, (-8.5, 0.07, -17.0, 0.14))         # second row = 2 x first: det H = 0
    with pytest.raises(ValueError) as e:
        calibrate.load_calibration(_write(tmp_path, bad))
    msg = str(e.value)
    assert "points[%d] at P-FSM grid point (%g, %g) V" % (k, pv[0], pv[1]) in msg
    assert "singular" in msg and "det H = 0" in msg and "condition number inf" in msg
    assert "node (" in msg and "at FSM (" in msg
    assert _upload(bad) == (P["NACK"], core.ERROR["BAD_CONTENT"])     # what the controller did, after upload


def test_near_singular_h_refused_at_load(tmp_path):
    cal = fp.calibration(5)
    k = 12
    a, b = -8.5, 0.07
    eps = 1e-7                                              # rows parallel to 1e-7: condition number ~1e8
    bad = _with_h(cal, k, (a, b, a * (1 + eps), b * (1 - eps)))
    assert hinv.condition((a, b, a * (1 + eps), b * (1 - eps))) > 1e7
    with pytest.raises(ValueError, match=r"points\[12\] at P-FSM grid point \(0, 0\) V refused: .*singular.*"
                                         r"condition number [0-9.e+]+"):
        calibrate.load_calibration(_write(tmp_path, bad))
    assert _upload(bad)[0] == P["NACK"]
    # condition number ~140: invertible, but |H^-1| ~ 8 V per unit ratio is beyond what the Q format holds
    mild = _with_h(cal, k, (a, 1.0, a * 1.03, 0.9))
    with pytest.raises(ValueError, match=r"points\[12\] .*above 1.221 \(H too small; det H = .*condition number"):
        calibrate.load_calibration(_write(tmp_path, mild))
    assert _upload(mild)[0] == P["NACK"]


def test_fixed_point_non_invertible_refused(tmp_path):
    """H^-1 of ~1.3 codes per unit ratio, nearly singular, beside a node at the Q-format's top (so Q0):
    rounding leaves an integer H^-1 [[1, 1], [1, 1]]-like that no longer inverts H."""
    cal = fp.calibration(3)
    cpv = 13107.2
    cal = _with_h(cal, 0, (cpv / 15200, 0.0, 0.0, cpv / 15200))     # |H^-1| = 15200 codes at node 0: Q0
    hinv_codes = (1.4, 1.2, 1.2, 1.1)                       # det 0.1 code^2: condition number ~65
    m = [e / cpv for e in hinv_codes]
    det = m[0] * m[3] - m[1] * m[2]
    h = (m[3] / det, -m[1] / det, -m[2] / det, m[0] / det)
    bad = _with_h(cal, 4, h)
    assert hinv.condition(h) < 100
    with pytest.raises(ValueError, match=r"points\[4\] at P-FSM grid point \(0, 0\) V refused: .*fixed-point "
                                         r"H\^-1 \(Q0"):
        calibrate.load_calibration(_write(tmp_path, bad))
    assert _upload(bad)[0] == P["NACK"]
    assert _upload(cal) == (P["ACK"], 0)


def test_load_and_controller_agree_across_conditioning(tmp_path):
    """Rows made parallel step by step, H scaled up and down: load_calibration refuses iff the controller
    NACKs the upload, and both accept the well-conditioned end."""
    cal = fp.calibration(3)
    seen = set()
    for i, eps in enumerate([1.0, 0.3, 0.1, 3e-2, 1e-2, 1e-3, 1e-5, 3e-7, 1e-7, 0.0]):
        for s in (1e-3, 1.0, 1e2, 1e4):
            a, b, c, d = -8.5 * s, 0.07 * s, -0.04 * s, 7.7 * s
            h = (a, b, (1 - eps) * a * -0.5 + eps * c, (1 - eps) * b * -0.5 + eps * d)
            t = _with_h(cal, 4, h)
            try:
                calibrate.load_calibration(_write(tmp_path, t))
                loaded = True
            except ValueError as e:
                assert "points[4]" in str(e)
                loaded = False
            assert loaded == (_upload(t) == (P["ACK"], 0)), (eps, s)
            seen.add(loaded)
    assert seen == {True, False}


@pytest.mark.parametrize("where, msg", [(("grid_v", 0), "grid_v[0]"), (("points", 2, "pfsm_v", 1), "points[2].pfsm_v[1]"),
                                        (("points", 4, "H", 1, 0), "points[4].H[1][0]")])
def test_an_integer_beyond_any_float_is_refused_naming_it(tmp_path, where, msg):
    cal = json.loads(json.dumps(fp.calibration(5)))
    at = cal
    for k in where[:-1]:
        at = at[k]
    at[where[-1]] = 10 ** 400
    path = _write(tmp_path, cal)
    with pytest.raises(ValueError) as e:
        calibrate.load_calibration(path)
    assert str(e.value) == "calibration %s: %s = an integer of 401 digits is not a finite number" % (path, msg)
