# Under micropython (or CPython): the ADCS application's fault paths, one function per case, each returning a
# dict of what it saw. tests/test_adcs_app_faults.py calls the functions under CPython and runs this script
# under micropython: ``firmware_adcs_faults.py CONFIG.json CASE [CASE ..]`` prints {case: result} as JSON.
import json
import math
import struct
import sys

from firmware.adcs import apkf_lean, app as A
from protocol import core

P = core.PACKET_ID
NODE = core.NODE


def _app(cfg, w=(1e-3, -5e-4, 2e-4)):
    """An App whose APKF runs (at rest attitude, rate w), past no cycle yet."""
    app = A.App(cfg)
    app.apkf = apkf_lean.Lean(app.params, [0.0, 0.0, 0.0, 1.0], list(w), [0.0] * 4, momentum=app.momentum)
    return app


def _fail(app, mask):
    """Declare the wheels in mask failed the way the cycle does: 3 cycles without their RW_TLM."""
    for _ in range(A.FAIL_AFTER):
        for i in range(A.NW):
            app.rw_got[i] = not (mask >> i & 1)
        app._wheels_in()


def case_wheels_left_do_not_span(cfg):
    """Two (or three) wheels failed: the rest cannot make a 3-axis torque. The cycle must neither raise nor
    command a torque it cannot allocate: u of the working wheels is their friction compensation only."""
    out = {}
    for mask in (0b0011, 0b1100, 0b0101, 0b0111):
        app = _app(cfg)
        _fail(app, mask)
        res = []
        for t in (5.0, app.hold_s + 10.0):         # rate damping, then pointing
            try:
                u = app._control(t)
                res.append([float(v) for v in u])
            except Exception as exc:                # noqa: BLE001 - reported, the test says what went wrong
                res.append("%s: %s" % (type(exc).__name__, exc))
        c, v, sm = app.fric
        fc = [v * app.wp[i] + c * math.tanh(app.wp[i] / sm) for i in range(A.NW)]
        out["%d" % mask] = {"failed": app.failed, "u": res, "friction": fc}
    return out


CASES = dict((k[5:], v) for k, v in globals().items() if k.startswith("case_"))

if __name__ == "__main__":
    with open(sys.argv[1]) as fh:
        config = json.load(fh)
    print(json.dumps(dict((name, CASES[name](config)) for name in sys.argv[2:])))
