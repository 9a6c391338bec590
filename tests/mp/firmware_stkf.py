# Under micropython: the lean STKF with the AFLS over the scripted GNSS sequence in argv[1] (JSON); prints the
# current node's state, covariance, node count and the heap bytes per 1 Hz cycle (gc off in each cycle).
import gc
import json
import sys

from firmware.adcs import linalg, stkf_lean

with open(sys.argv[1]) as fh:
    sc = json.load(fh)
f = stkf_lean.Afls(sc["x0"], sc["P0"], 0.0, sc["lag"])
R = linalg.zeros(36)
for i in range(36):
    R[i] = sc["R"][i]
za = stkf_lean.zeros_d(6)
heap = []
for step in sc["steps"]:
    gc.collect()
    gc.disable()
    m0 = gc.mem_alloc()
    f.predict(step["t"])
    for i in range(6):
        za[i] = step["za"][i]
    f.update_gnss(za, R, 0)
    if step.get("zb") is not None:
        for i in range(6):
            za[i] = step["zb"][i]
        f.update_gnss(za, R, 1, step["tb"])
    m1 = gc.mem_alloc()
    gc.enable()
    heap.append(m1 - m0)
ld = f.ld
print(json.dumps({"x": [f.X[i] for i in range(12)], "P": [f.P[i * ld + j] for i in range(12) for j in range(12)],
                  "k": f.k, "generated": f.generated, "heap_max": max(heap)}))
