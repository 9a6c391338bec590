# Under micropython: the lean STKF, white (stkf_lean.LeanStkf) or markov (stkf_dmc.DmcStkf, argv[2] "markov"), with
# the J2 model over the inputs in argv[1] (JSON, ground/adcs/lean_scenario.stkf_scenario); prints the estimate and
# 1 sigma of every second, and the microseconds per 1 Hz cycle (predict, SatA's GNSS, the beacon, SatB's GNSS).
# argv[3] (optional): run only that many cycles and print nothing (the callgrind count). "bits": a SHA-256 of the
# estimates, 1 sigma and final covariances, exact (the same run with the C kernels and without gives the same).
import binascii
import hashlib
import json
import sys
import time
from array import array

from firmware.adcs import linalg, stkf_dmc, stkf_lean

with open(sys.argv[1]) as fh:
    sc = json.load(fh)
lag = 4.0 if any(st["zb"] for st in sc["steps"]) else 0.0      # as the app: no SatB GNSS, no smoother lag
cap = 6 if lag else 3
if sys.argv[2] == "markov":                                       # bench_stkf_gravity's models
    f = stkf_dmc.DmcStkf(sc["x0"], sc["P0"], 0.0, lag, cap, sigma_a=1e-4, tau=300.0, gravity="j2")
else:
    f = stkf_lean.LeanStkf(sc["x0"], sc["P0"], 0.0, lag, cap, qa=5e-6, gravity="j2")
R, P_att = linalg.zeros(36), linalg.zeros(9)
for i in range(36):
    R[i] = sc["R"][i]
for i in range(9):
    P_att[i] = sc["P_att"][i]
z, y, q = stkf_lean.zeros_d(6), stkf_lean.zeros_d(3), stkf_lean.zeros_d(4)
x, s = stkf_lean.zeros_d(12), stkf_lean.zeros_d(12)
xs, sg, us = [], [], []
n = int(sys.argv[3]) if len(sys.argv) > 3 else len(sc["steps"])
for k, step in enumerate(sc["steps"][:n]):
    for i in range(6):
        z[i] = step["za"][i]
    for i in range(3):
        y[i] = step["y"][i]
    for i in range(4):
        q[i] = step["q"][i]
    t0 = time.ticks_us()
    if k > 0:
        f.predict(step["t"])
    f.update_gnss(z, R, 0)
    f.update_beacon(y, q, P_att, sc["sigma_b"])
    for tm, v in step["zb"]:
        for i in range(6):
            z[i] = v[i]
        f.update_gnss(z, R, 1, tm)
    f.get(x, s)
    if len(sys.argv) > 3:
        continue
    us.append(time.ticks_diff(time.ticks_us(), t0))
    xs.append([x[i] for i in range(12)])
    sg.append([s[i] for i in range(12)])
if len(sys.argv) < 4:
    h = hashlib.sha256()
    for row in xs + sg + [list(f.P), list(f.Pa)]:
        h.update(bytes(array("d", row)))
    print(json.dumps({"x": xs, "sig": sg, "us": us, "generated": f.generated, "refused": f.refused,
                      "kernels": linalg.kernels is not None, "bits": binascii.hexlify(h.digest()).decode()}))
