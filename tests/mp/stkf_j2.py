# Under micropython: the lean STKF's kernels with the J2 term (firmware/adcs/stkf_kernels.py) on the states in
# argv[1] (JSON: [[r, v], ...] and the steps dt, s): prints f(x, dt) and phi(x, dt) of each, as JSON.
import json
import sys

from firmware.adcs import stkf_kernels as K

with open(sys.argv[1]) as fh:
    job = json.load(fh)
out = {"f": [], "phi": []}
Phi = K.zeros_d(36)
for x6 in job["x"]:
    for dt in job["dt"]:
        x = K.zeros_d(6)
        for i in range(6):
            x[i] = x6[i]
        K.phi(Phi, x, 0, dt, K.J2_TERM)
        K.f(x, 0, dt, K.J2_TERM)
        out["f"].append([x[i] for i in range(6)])
        out["phi"].append([Phi[i] for i in range(36)])
print(json.dumps(out))
