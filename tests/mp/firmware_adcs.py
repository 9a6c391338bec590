# Under micropython: run the lean APKF over a scripted scenario (JSON file argv[1]: params, wp, qm, u, env) and print its final state,
# covariance and the heap bytes allocated per 1 Hz cycle (gc.mem_alloc deltas, gc off during each cycle).
# argv[2] (optional): run only that many cycles, without the gc calls (bench/bench_adcs_lean.py's callgrind count).
import gc
import json
import sys

from firmware.adcs import apkf_lean, linalg

with open(sys.argv[1]) as fh:
    sc = json.load(fh)
f = apkf_lean.LeanApkf(sc["params"], sc["qm"][0], [0.0, 0.0, 0.0], sc["wp"][0])
wp = linalg.zeros(4)
qm = linalg.zeros(4)
u = linalg.zeros(4)
heap = []
plain = len(sys.argv) > 2
n = int(sys.argv[2]) + 1 if plain else len(sc["wp"])
for k in range(1, n):
    for i in range(4):
        wp[i] = sc["wp"][k][i]
    q = sc["qm"][k]
    if q is not None:
        for i in range(4):
            qm[i] = q[i]
    env = sc["env"][k - 1]
    for i in range(4):
        u[i] = sc["u"][k - 1][i]
    if plain:
        f.step(wp, qm if q is not None else None, env, u)
        continue
    gc.collect()
    gc.disable()
    m0 = gc.mem_alloc()
    f.step(wp, qm if q is not None else None, env, u)
    m1 = gc.mem_alloc()
    gc.enable()
    heap.append(m1 - m0)
if plain:
    print(json.dumps({"x": list(f.x)}))
    sys.exit(0)
L = linalg.zeros(81)
pd = linalg.cholesky(L, f.P, 9)
print(json.dumps({"x": list(f.x), "P": list(f.P), "heap_max": max(heap), "heap_mean": sum(heap) / len(heap),
                  "pd": pd, "skipped": f.skipped}))
