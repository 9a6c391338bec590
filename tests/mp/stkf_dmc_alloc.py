# Under micropython: the markov STKF's 9-state kernels (stkf_dmc.KERNELS) called on a DmcStkf's own buffers with
# the heap locked, each once; prints one JSON line: whether the C kernels are loaded, "ok" or the first call's error
# under the lock, and the error of a Python loop of the module (stkf_dmc._phi_vec) under the lock (MemoryError: the
# lock holds).
import json

import micropython

from firmware.adcs import linalg, stkf_dmc

P0 = [1e4] * 3 + [1.0] * 3 + [1e4] * 3 + [1.0] * 3
f = stkf_dmc.DmcStkf([7.0e6, 0.0, 0.0, 0.0, 7.5e3, 0.0, 6.9e6, 1.0e5, 0.0, 0.0, 7.5e3, 1.0], P0, 0.0, 4.0, 6)
for t in range(1, 6):
    f.predict(float(t))
w, ld, m = f.work, f.ld, f.k * stkf_dmc.NA


def locked(call):
    micropython.heap_lock()
    try:
        call()
        err = "ok"
    except Exception as e:              # MemoryError under the lock, or any other
        err = type(e).__name__
    micropython.heap_unlock()
    return err


def kernels():
    stkf_dmc.rows_mul_phi(f.P, ld, 9, 9, m, w.Phi, w.p, w.v)
    stkf_dmc.sandwich_phi(f.P, ld, 0, 9, w.Phi, w.Q, w.T, w.p, w.v)
    stkf_dmc.sandwich_phi(f.Pa, 9, 0, 0, w.Phi, w.Q, f.wa.Pd, w.p, w.v)
    stkf_dmc._joseph_dmc(f.P, ld, m, w.Kt, w.U, w.H, w.R3, w.T, w.p)
    stkf_dmc._hp_rows(w.hp, f.P, ld, 1, 0, m, w.AB, w.pq, w.A, w.B)
    stkf_dmc._s_between(w.S, w.hp, 1, 0, w.A, w.B, w.T, w.Q)


print(json.dumps({"kernels": linalg.kernels is not None, "nodes": f.k, "locked": locked(kernels),
                  "python loop": locked(lambda: stkf_dmc._phi_vec(w.Phi, w.p, w.v, 0))}))
