# Under micropython: the exact bits of every ADCS kernel's results on seeded inputs, and of a replayed
# session's every cycle (wheel torques, the APKF's x and P, the STKF's states and covariances), as SHA-256
# digests in one JSON line. Run once with the C kernels (firmware/adcs/adcsk.mpy) on the path and once
# without: tests/test_adcs_natmod.py asserts the digests are equal, kernel by kernel.
# argv: [CONFIG.json RECORD.json] (the session; omitted: the kernels only)
import binascii
import hashlib
import json
import sys
from array import array

from firmware.adcs import apkf_lean, linalg, stkf_dmc, stkf_lean

_state = [12345]


def rnd():
    """A uniform float in [-1, 1) from a 31-bit LCG (the same sequence on every run and runtime)."""
    _state[0] = (_state[0] * 1103515245 + 12345) & 0x7FFFFFFF
    return _state[0] / 1073741824.0 - 1.0


def buf(tc, n, v=None):
    a = array(tc, bytes((4 if tc == "f" else 8) * n))
    for i in range(n):
        a[i] = rnd() if v is None else v[i]
    return a


def spd(tc, n, diag=None):
    """A symmetric positive definite n x n: B B^T + n I (B random)."""
    b = [rnd() for _ in range(n * n)]
    out = [0.0] * (n * n)
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += b[i * n + k] * b[j * n + k]
            out[i * n + j] = s + (n if i == j else 0.0) * (1.0 if diag is None else diag)
    return buf(tc, n * n, out)


def digest(*bufs):
    h = hashlib.sha256()
    for b in bufs:
        if isinstance(b, bool):
            h.update(b"T" if b else b"F")
        elif isinstance(b, list):
            h.update(bytes(array("d", b)))
        else:
            h.update(bytes(array("d", list(b))))
    return binascii.hexlify(h.digest()).decode()


out = {"kernels": linalg.kernels is not None}
for tc in ("f", "d"):
    for n, m, p in ((3, 6, 4), (6, 6, 6), (4, 3, 5), (9, 9, 9)):
        C, A, B = buf(tc, n * p), buf(tc, n * m), buf(tc, m * p)
        linalg.matmul(C, A, B, n, m, p)
        Bt = buf(tc, p * m)
        D = buf(tc, n * p)
        linalg.matmul_bt(D, A, Bt, n, m, p)
        out["matmul %s %d %d %d" % (tc, n, m, p)] = digest(C, D)
    for n in (3, 6, 9):
        A = spd(tc, n)
        L = buf(tc, n * n)
        ok = linalg.cholesky(L, A, n)
        X, Bm = buf(tc, 4 * n), buf(tc, 4 * n)
        linalg.chol_solve_rows(X, L, Bm, n, 4)
        linalg.chol_solve_rows(Bm, L, Bm, n, 4)          # in place
        S = buf(tc, n * n)
        linalg.symmetrize(S, n)
        bad = buf(tc, n * n)
        bad[0] = -1.0
        out["cholesky %s %d" % (tc, n)] = digest(L, [ok], X, Bm, S, [linalg.cholesky(buf(tc, n * n), bad, n)])
    for n, r0, m in ((9, 0, 3), (6, 0, 6), (9, 3, 3), (9, 2, 4)):
        P = spd(tc, n)
        R = spd(tc, m, 0.01)
        Kt, L, W, RK = buf(tc, m * n), buf(tc, m * m), buf(tc, n * n), buf(tc, m * n)
        ok = linalg.joseph_select(P, n, r0, m, list(R) if tc == "d" else R, Kt, L, W, RK)
        Pn = spd(tc, n)
        Pn[r0 * n + r0] = -1e3                           # S not positive definite: P untouched
        ok2 = linalg.joseph_select(Pn, n, r0, m, R, buf(tc, m * n), buf(tc, m * m), buf(tc, n * n), buf(tc, m * n))
        out["joseph %s %d %d %d" % (tc, n, r0, m)] = digest(P, Kt, [ok, ok2], Pn)

for tc in ("f", "d"):                                    # the STKF's 6 x 6 block kernels, ld = 30
    ld = 30
    P = spd(tc, ld)
    F, Q, T = buf("d", 36), spd("d", 6, 0.1), buf(tc, 36)
    stkf_lean.rows_mul_mirror(P, ld, 0, 6, 24, F)
    stkf_lean.rows_mul_mirror(P, ld, 12, 6, 30, list(F))
    stkf_lean.sandwich(P, ld, 0, F, Q, T)
    stkf_lean.sandwich(P, ld, 6, F, Q, T, 18)
    G, KRK = [rnd() for _ in range(18)], [rnd() for _ in range(36)]
    stkf_lean._ikh_rows(P, ld, 6, 30, G)
    stkf_lean._ikh_sandwich(P, ld, G, KRK, [0.0] * 36)
    out["stkf blocks %s" % tc] = digest(P, T)

for tc in ("f", "d"):                                    # the markov STKF's 9-state kernels (stkf_dmc), ld = 54
    ld, p, v = 54, [0.0] * 9, [0.0] * 9
    P = spd(tc, ld)
    F, Q, T = buf("d", 81), spd("d", 9, 0.1), buf(tc, 81)
    stkf_dmc.rows_mul_phi(P, ld, 9, 9, 45, F, p, v)
    stkf_dmc.sandwich_phi(P, ld, 0, 9, F, Q, T, p, v)
    stkf_dmc.sandwich_phi(P, ld, 18, 18, F, Q, T, p, v)
    Kt, U, W = buf("d", 27), buf("d", 27), buf("d", 81)
    stkf_dmc._joseph_dmc(P, ld, 45, Kt, U, [rnd() for _ in range(9)], [rnd() for _ in range(9)], W, p)
    Hp = [buf("d", ld) for _ in range(6)]
    A, B = buf("d", 81), buf("d", 81)
    stkf_dmc._hp_rows(Hp, P, ld, 1, 4, 45, [[0.0] * 18 for _ in range(6)], [0.0] * 18, A, B)
    S = buf("d", 36)
    stkf_dmc._s_between(S, Hp, 1, 4, A, B, buf("d", 81), spd("d", 9, 0.1))
    out["stkf dmc blocks %s" % tc] = digest(P, T, W, S, *Hp)

work = apkf_lean.Work()                                  # the APKF's Phi series and covariance predict
for k in range(54):
    if k // 9 >= 3 or k in (1, 2, 9, 11, 18, 19):        # F's entries that can be non-zero (rows 0-5)
        work.F[k] = 0.01 * rnd()
apkf_lean.phi(work.Phi, work.F, 1.0, work)
P = spd("f", 9)
apkf_lean.covariance_predict(P, work.Phi, work.W)
out["apkf phi, covariance"] = digest(work.Phi, work.T1, P, work.W)

if len(sys.argv) > 2:
    from firmware.adcs.app import App
    with open(sys.argv[1]) as fh:
        cfg = json.load(fh)
    with open(sys.argv[2]) as fh:
        rec = json.load(fh)
    app = App(cfg)
    h = hashlib.sha256()
    for tick, t_ms, pkts in rec:
        for pid, src, hx in pkts:
            app.on_packet(pid, src, bytes.fromhex(hx))
        u = app.cycle(tick, t_ms / 1000.0)
        app.commands(u)
        s = app.est.stkf
        v = list(u) + (list(app.est.apkf.x) + list(app.est.apkf.P) if app.est.apkf else [])
        h.update(bytes(array("d", v + list(s.X) + list(s.P) + list(s.xa) + list(s.Pa))))
    out["session"] = binascii.hexlify(h.digest()).decode()
    out["session cycles"] = len(rec)
    out["satb fused"] = app.health.n_gnss_b
print(json.dumps(out))
