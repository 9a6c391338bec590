# Under micropython: the flight control functions on the cases in argv[1] (JSON list of inputs); prints the
# outputs as one JSON line, for tests/test_adcs_lean.py to compare with CPython and the ground functions.
import json
import sys

from firmware.adcs import control, linalg

with open(sys.argv[1]) as fh:
    cases = json.load(fh)
z = linalg.zeros
w = control.Work(z)
qc, K, D, tau, u = z(4), z(9), z(9), z(3), z(4)
out = []
for c in cases:
    control.attitude_command(qc, c["ra"], c["va"], c["rb"], w)
    control.gains(K, D, c["J"], c["ts"])
    control.pd_torque(tau, c["q"], c["w"], qc, c["wc"], K, D, c["H"], c["tff"])
    control.wheel_torques(u, tau, c["C"])
    out.append({"qc": list(qc), "tau": list(tau), "u": list(u)})
print(json.dumps({"cases": out}))
