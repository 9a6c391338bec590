# Under micropython: the lean STKF (SatA's GNSS, the beacon, SatB's delayed GNSS through the AFLS) over the
# inputs in argv[1] (JSON, ground/adcs/lean_scenario.stkf_scenario); prints the estimate and 1 sigma of every
# second, the node count, and the heap bytes per 1 Hz cycle (gc off in each cycle). argv[2] (optional):
# "cycles" - only the cycles with the collector on as in flight, no output (the callgrind count).
import gc
import json
import sys

from firmware.adcs import linalg, stkf_lean

with open(sys.argv[1]) as fh:
    sc = json.load(fh)
quiet = len(sys.argv) > 2
f = stkf_lean.LeanStkf(sc["x0"], sc["P0"], 0.0)
R, P_att = linalg.zeros(36), linalg.zeros(9)
for i in range(36):
    R[i] = sc["R"][i]
for i in range(9):
    P_att[i] = sc["P_att"][i]
sb = sc["sigma_b"]
z, y, q = stkf_lean.zeros_d(6), stkf_lean.zeros_d(3), stkf_lean.zeros_d(4)
x, s = stkf_lean.zeros_d(12), stkf_lean.zeros_d(12)
heap, xs, sg = [], [], []
for k, step in enumerate(sc["steps"]):
    for i in range(6):
        z[i] = step["za"][i]
    for i in range(3):
        y[i] = step["y"][i]
    for i in range(4):
        q[i] = step["q"][i]
    zb = step["zb"]
    if not quiet:                       # (a collection on a 64 MB heap costs tens of M instructions)
        gc.collect()
        gc.disable()
    m0 = gc.mem_alloc()
    if k > 0:
        f.predict(step["t"])
    f.update_gnss(z, R, 0)
    f.update_beacon(y, q, P_att, sb)
    for tm, v in zb:
        for i in range(6):
            z[i] = v[i]
        f.update_gnss(z, R, 1, tm)
    f.get(x, s)
    m1 = gc.mem_alloc()
    if not quiet:
        gc.enable()
    heap.append(m1 - m0)
    if not quiet:
        xs.append([x[i] for i in range(12)])
        sg.append([s[i] for i in range(12)])
if not quiet:
    print(json.dumps({"x": xs, "sig": sg, "k": f.k, "generated": f.generated, "heap_max": max(heap[1:]),
                      "heap_first": heap[0]}))
