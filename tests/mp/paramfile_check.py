"""protocol.paramfile under MicroPython and CPython alike: the checker's verdict on a good parameter file and on
each bad one, one line each (tests/test_paramfile.py runs this script under both and compares the lines).
argv[1], if given: a parameter file (JSON) that must pass too."""

import json
import sys

from protocol import paramfile as pf
from protocol import spacecraft as sf
from tests.mp.mutate import DELETE, copy, put

NAN = float("nan")
INF = float("inf")
SIGMA = [1e-8] * 3 + [7.8e-5] * 5 + [0.002] * 3 + [0.001] * 8 + [6e-9] * 4


def good():
    n = len(SIGMA)
    return {"format": pf.FORMAT, "wheels": 4, "jxx_ref_kgm2": 0.012, "torque_scale": 1.02,
            "x": {"tau_d_nm": [0.0, 1e-7, -2e-7], "J5_kgm2": [0.047, 0.045, 0.001, 0.002, 0.003],
                  "dipole_am2": [0.1, 0.15, 0.2], "delta1_rad": [0.19, -0.12, -0.19, 0.14],
                  "delta2_rad": [-0.21, 0.21, 0.16, 0.17], "jrw_kgm2": [3.4e-6, 3.3e-6, 2.2e-6, 2.4e-6]},
            "P": [[SIGMA[i] * SIGMA[j] * (1.0 if i == j else 0.3) for j in range(n)] for i in range(n)],
            "calibration": {"seed": 0, "sets": 9}}


BAD = (   # (label, [(key path, new value or DELETE), ...]) applied to good()
    ("format", [("format", "fps-bps-params/2")]),
    ("3 wheels", [("wheels", 3)]),
    ("wheels a string", [("wheels", "4")]),
    ("missing key", [("jxx_ref_kgm2", DELETE)]),
    ("missing x part", [("x.jrw_kgm2", DELETE)]),
    ("unknown key", [("colour", "red")]),
    ("unknown x part", [("x.gyro_bias", [0.0, 0.0, 0.0])]),
    ("x not an object", [("x", [1, 2, 3])]),
    ("jxx 0", [("jxx_ref_kgm2", 0)]),
    ("jxx NaN", [("jxx_ref_kgm2", NAN)]),
    ("scale 10", [("torque_scale", 10.0)]),
    ("scale inf", [("torque_scale", INF)]),
    ("scale a bool", [("torque_scale", True)]),
    ("NaN in J5", [("x.J5_kgm2.1", NAN)]),
    ("-inf in delta2", [("x.delta2_rad.3", -INF)]),
    ("short jrw", [("x.jrw_kgm2", [3e-6, 3e-6, 3e-6])]),
    ("jrw not a list", [("x.jrw_kgm2", 3e-6)]),
    ("jrw 100x", [("x.jrw_kgm2.0", 3e-4)]),
    ("jrw negative", [("x.jrw_kgm2.0", -1.0)]),
    ("tau_d 1 N m", [("x.tau_d_nm.2", -1.0)]),
    ("dipole 50", [("x.dipole_am2.1", 50.0)]),
    ("delta1 1e300", [("x.delta1_rad.0", 1e300)]),
    ("not positive definite", [("x.J5_kgm2", [-0.05, 0.05, 0.0, 0.0, 0.0])]),
    ("no rigid body", [("x.J5_kgm2", [0.012, 0.036, 0.0, 0.0, 0.0])]),
    ("P short", [("P", [[1.0] * 23] * 22)]),
    ("P row short", [("P.5", [1.0] * 22)]),
    ("P NaN", [("P.2.2", NAN)]),
    ("P asymmetric", [("P.3.5", 1e-5)]),
    ("P negative", [("P.0.0", -1.0)]),
    ("calibration 5", [("calibration", 5)]),
    ("no optional keys", [("torque_scale", DELETE), ("calibration", DELETE)]),
    ("integers", [("wheels", 4.0), ("torque_scale", 1), ("x.tau_d_nm", [0, 0, 0])]),
)


def verdict(label, d, spacecraft=None):
    try:
        c = pf.check(d, spacecraft)
        print("accepted", label, c["torque_scale"], c["calibration"] == d.get("calibration", {}))
    except ValueError as exc:
        print("refused", label, "|", str(exc))


def main():
    verdict("good", good())
    for label, changes in BAD:
        d = good()
        for path, value in changes:
            put(d, path, value)
        verdict(label, d)
    for bad in ([], "x", None, 3):
        verdict(repr(bad), bad)
    six = sf.load("generic-6u")
    verdict("good on generic-6u", good(), six)
    d = good()
    d["x"]["jrw_kgm2"] = [4.8e-5, 4.9e-5, 4.7e-5, 4.8e-5]
    d["x"]["tau_d_nm"] = [0.0015, 0.0, 0.0]
    verdict("6U wheels, tau_d 1.5 mN m on generic-6u", d, six)
    verdict("6U wheels on the thesis's 3U", copy(d))
    if len(sys.argv) > 1:
        with open(sys.argv[1]) as f:
            verdict("file", json.load(f))


main()
