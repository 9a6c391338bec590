"""Lean flight ADCS: what dropping states costs, heap bytes and instructions per 1 Hz cycle.

Scenario (ground/adcs/lean_scenario.py): the emulator's spacecraft (true J, misaligned wheels with their true
inertias, gravity gradient, a residual dipole) held in an inertial attitude by a PD on the truth for 4000 s,
with the star tracker (20/20/60 arcsec, 1 Hz) and the tachometers (10 rpm). Both filters start from the
parameter file a perfect calibration writes (ground/adcs/body_pointing.py format), attitude from the first star-tracker
output, rate zero:
- lean: firmware/adcs/apkf_lean.py (9 states: attitude, rate, disturbance torque; parameters held; the wheel
  momentum change from the wheel speeds each wheel's Kalman filter estimates from its read-outs and the
  commanded torques, as flown), float64 lists and numpy.float32 scalars; and float64 with the two other
  momentum inputs: the commanded torques less the friction model, and the raw read-out difference;
- ground: ground/adcs/apkf.py (41 states, the parameters estimated on, wheel speeds as states).
The pointing RMS on three more seeds; a diagnostic table runs them on the same truth with noise-free
tachometer read-outs.
Figures over t >= 300 s: attitude (truth minus estimate) and rate (estimate minus truth) error 1 sigma per axis,
and the pointing error of the laser axis (body x): the angle about the two axes perpendicular to it,
sqrt(e_y^2 + e_z^2), RMS and 3 sigma (RMS x 3). The goal: the lean filter within 25 % of the ground
filter's pointing figures.

Heap: gc.mem_alloc() before and after each cycle under micropython (gc off in the cycle), 30 s.
Instructions: ``valgrind --tool=callgrind`` on micropython over 5 and 25 cycles, differenced (includes the
harness's own input copying, a few thousand instructions).

The lean STKF (firmware/adcs/stkf_lean.py: SatA's EKF + SatB's 6-state AFLS) on the Sec. 5.5 inputs of
ground/adcs/lean_scenario.stkf_scenario (two-body truth, SatA GNSS and the beacon each second, SatB's GNSS
through the relay 2-3 s late, so nearly every second generates a node; stated attitude error):
- instructions per cycle: callgrind over 10 and 20 s, differenced, the collector on as in flight (default
  heap); heap bytes per cycle: gc.mem_alloc() around each cycle with the collector off, max over 30 s;
- accuracy beside the ground 12-state STKF + EAFLS (ground/adcs/stkf.py, afls.py) on the same inputs,
  Case 1 (no SatB GNSS) and Case 2, 1200 s: final 1 sigma (sqrt trace of each 3 x 3 block, the thesis's
  figure) and RMS error over t >= 300 s;
- float32 (SatA's covariance path in numpy.float32 scalars) against float64, Case 2, 4000 s.
"""

import json
import os
import shutil
import tempfile

import numpy as np

from bench import mp, verdict
from bench.common import missed, timed

from firmware.adcs import apkf_lean as L
from firmware.adcs import linalg
from ground.adcs import apkf, quat
from ground.adcs.lean_scenario import run_stkf_ground, run_stkf_lean, scenario, stkf_scenario

ROOT = mp.ROOT
SECONDS = 4000
T0 = 300
GOAL_INSTR = 10e6
GOAL_RATIO = 1.25
SEEDS = (1, 2, 3)


class F32(list):
    def __setitem__(self, i, v):
        list.__setitem__(self, i, np.float32(v))


def _errors(sc, qs, ws):
    ea = np.array([2 * quat.error_vec(np.array(sc["q"][k]), qs[k]) for k in range(len(qs))]) / quat.RAD_PER_ARCSEC
    ew = (np.array(ws) - np.array(sc["w"][:len(ws)])) / quat.RAD_PER_ARCSEC
    return ea[T0:], ew[T0:]


def run_lean(sc, f32=False, **kw):
    old = linalg.zeros
    linalg.zeros = (lambda n: F32([np.float32(0.0)] * n)) if f32 else (lambda n: [0.0] * n)
    c = (lambda v: None if v is None else [np.float32(e) for e in v]) if f32 else (lambda v: v)
    try:
        f = L.LeanApkf(sc["params"], sc["qm"][0], [0.0, 0.0, 0.0], sc["wp"][0], **kw)
        qs, ws = [np.array(f.x[0:4], float)], [np.zeros(3)]
        for k in range(1, len(sc["wp"])):
            e = sc["env"][k - 1]
            f.step(c(sc["wp"][k]), c(sc["qm"][k]), (c(e[0]), e[1], c(e[2])), c(sc["u"][k - 1]))
            qs.append(np.array(f.x[0:4], float))
            ws.append(np.array(f.x[4:7], float))
    finally:
        linalg.zeros = old
    return _errors(sc, qs, ws)


def run_ground(sc):
    d = sc["params"]["x"]
    model = apkf.Model(dt=1.0, jxx=sc["params"]["jxx_ref_kgm2"])
    x0 = apkf.initial_state(np.array(sc["qm"][0]), np.zeros(3), np.array(sc["wp"][0]))
    x0[7:30] = np.concatenate([d["tau_d_nm"], d["J5_kgm2"], d["dipole_am2"], d["delta1_rad"], d["delta2_rad"],
                               d["jrw_kgm2"]])
    flt = apkf.APKF(x0, model=model, case=1)
    flt.P[apkf.PARAMS, apkf.PARAMS] = np.array(sc["params"]["P"])
    qs, ws = [x0[0:4].copy()], [np.zeros(3)]
    for k in range(1, len(sc["wp"])):
        qm = sc["qm"][k]
        flt.step(float(k - 1), np.array(sc["wp"][k]), None if qm is None else np.array(qm))
        qs.append(flt.x[0:4].copy())
        ws.append(flt.x[4:7].copy())
    return _errors(sc, qs, ws)


def figures(ea, ew):
    p = np.sqrt(ea[:, 1] ** 2 + ea[:, 2] ** 2)
    rms = float(np.sqrt(np.mean(p ** 2)))
    return {"att": ea.std(0), "rate": ew.std(0), "pointing_rms": rms, "pointing_3sigma": 3 * rms}


def _mp(args, callgrind=False, script="firmware_adcs.py"):
    heap = "64M" if script == "firmware_stkf.py" and not callgrind else None   # gc off per cycle
    out = mp.run(os.path.join(ROOT, "tests", "mp", script), args, callgrind=callgrind, heap=heap)
    return out if callgrind else json.loads([ln for ln in out.splitlines() if ln.startswith("{")][-1])


def main():
    sc, t_truth = timed(scenario, SECONDS)
    _print_accuracy(_accuracy(sc), t_truth)
    _print_other_seeds()
    _print_noise_free()
    _print_cost(*_cycle_cost(sc))
    stkf_main()


def _accuracy(sc):
    """{filter: ``figures`` and its wall time (s)} of the lean filter's forms and the ground's on scenario ``sc``."""
    runs = {}
    for name, fn in (("lean (float64)", lambda: run_lean(sc)), ("lean (float32)", lambda: run_lean(sc, True)),
                     ("lean, commanded torques", lambda: run_lean(sc, momentum="torque")),
                     ("lean, read-out difference", lambda: run_lean(sc, momentum="tach")),
                     ("ground 41-state", lambda: run_ground(sc))):
        errors, wall = timed(fn)
        runs[name] = figures(*errors)
        runs[name]["wall"] = wall
    return runs


def _print_accuracy(runs, t_truth):
    g = runs["ground 41-state"]
    print("Accuracy, %d s emulated inertial hold (truth %.1f s wall), t >= %d s; arcsec, arcsec/s\n"
          % (SECONDS, t_truth, T0))
    print("| filter | attitude 1σ x / y / z | rate 1σ x / y / z | pointing RMS | pointing 3σ | "
          "pointing vs ground (goal <= %.2f) | wall |" % GOAL_RATIO)
    print("|---|---|---|---|---|---|---|")
    for name, r in runs.items():
        ratio = r["pointing_rms"] / g["pointing_rms"]
        print("| %s | %.1f / %.1f / %.1f | %.1f / %.1f / %.1f | %.1f | %.1f | %.2f%s | %.1f s |" % (
            name, *r["att"], *r["rate"], r["pointing_rms"], r["pointing_3sigma"], ratio,
            "" if name.startswith("ground") else verdict(ratio, GOAL_RATIO), r["wall"]))


def _print_other_seeds():
    """Runs the ground and lean filters on the scenario with each of ``SEEDS`` and prints their pointing RMS."""
    print("\nOther seeds (the same scenario, its random draws changed): pointing RMS, arcsec\n")
    print("| seed | ground 41-state | lean | lean/ground | lean, commanded torques | its ratio | "
          "lean, read-out difference | its ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for seed in SEEDS:
        sk = scenario(SECONDS, seed=seed)
        gk, lk, uk, tk = (figures(*run_ground(sk))["pointing_rms"], figures(*run_lean(sk))["pointing_rms"],
                          figures(*run_lean(sk, momentum="torque"))["pointing_rms"],
                          figures(*run_lean(sk, momentum="tach"))["pointing_rms"])
        print("| %d | %.1f | %.1f | %.2f%s | %.1f | %.2f | %.1f | %.2f |" % (
            seed, gk, lk, lk / gk, verdict(lk / gk, GOAL_RATIO), uk, uk / gk, tk, tk / gk))


def _print_noise_free():
    """Runs the filters on the same truth with noise-free tachometer read-outs and prints their figures (a
    diagnostic)."""
    sc0 = scenario(SECONDS, tach_rpm=0.0)
    diag = {"ground 41-state": figures(*run_ground(sc0)),
            "lean": figures(*run_lean(sc0)),
            "lean, commanded torques": figures(*run_lean(sc0, momentum="torque")),
            "lean, read-out difference, its Q for 0.1 rpm": figures(*run_lean(sc0, momentum="tach", tach_rpm=0.1)),
            "lean, read-out difference, its Q for 10 rpm": figures(*run_lean(sc0, momentum="tach"))}
    g0 = diag["ground 41-state"]
    print("\nDiagnostic: the same truth with noise-free tachometer read-outs. Differencing two 10 rpm read-outs per "
          "second (Eq. 4.95) is a white torque of sqrt(2) 10 rpm Jrw per wheel; the lean filter smooths each "
          "wheel's read-outs on its commanded torques (their error taken as 5 %), the torque input takes the "
          "commands alone where 5 % of them is below the read-out noise:\n")
    print("| filter (tachometer noise-free) | attitude 1σ x / y / z | rate 1σ x / y / z | pointing RMS | "
          "vs ground on these inputs |")
    print("|---|---|---|---|---|")
    for name, r in diag.items():
        print("| %s | %.1f / %.1f / %.1f | %.1f / %.1f / %.1f | %.1f | %.2f |" % (
            name, *r["att"], *r["rate"], r["pointing_rms"], r["pointing_rms"] / g0["pointing_rms"]))


def _cycle_cost(sc):
    """Under micropython: the APKF's result on the first 30 s of ``sc`` (heap per cycle), the APKF's and the
    STKF's instructions per cycle (callgrind, NaN without valgrind) and the STKF's result (heap per cycle)."""
    with tempfile.TemporaryDirectory() as d:
        p = os.path.join(d, "sc.json")
        short = {k: sc[k][:31] if isinstance(sc[k], list) else sc[k] for k in ("params", "wp", "qm", "u", "env")}
        with open(p, "w") as fh:
            json.dump(short, fh)
        res = _mp([p])
        have_vg = shutil.which("valgrind") is not None
        instr = (_mp([p, 25], True) - _mp([p, 5], True)) / 20.0 if have_vg else float("nan")
        ins = []
        for n in (10, 20, 30):
            q = os.path.join(d, "seq%d.json" % n)
            with open(q, "w") as fh:
                json.dump(stkf_scenario(n, case=2), fh)
            if n < 30:
                ins.append(_mp([q, "cycles"], True, "firmware_stkf.py") if have_vg else 0)
        st = _mp([q], False, "firmware_stkf.py")
        instr_stkf = (ins[1] - ins[0]) / 10.0 if have_vg else float("nan")
    return res, instr, st, instr_stkf


def _print_cost(res, instr, st, instr_stkf):
    from tools.natmod_build import TARGET
    kern = os.path.exists(TARGET)
    print("\nCost of one 1 Hz cycle (predict + star-tracker update) under micropython (unix x64 port; %s)\n"
          % ("the hot kernels in C, firmware/adcs/adcsk.mpy" if kern else
             "the Python kernels: firmware/adcs/adcsk.mpy is not built"))
    print("| item | goal | ours |")
    print("|---|---|---|")
    print("| x86-64 instructions per cycle (callgrind) | <= %.0f M | %.2f M%s |"
          % (GOAL_INSTR / 1e6, instr / 1e6, missed(instr, GOAL_INSTR)))
    print("| heap bytes per cycle (gc.mem_alloc delta, max over 30 s) | measured, bounded | %d |" % res["heap_max"])
    print("| STKF cycle (predict, SatA GNSS, beacon, SatB GNSS 2-3 s late: nodes generated), instructions "
          "| (10 M for the whole ADCS) | %.2f M (the first lean STKF: 515 M) |" % (instr_stkf / 1e6))
    print("| APKF + STKF cycle (control not counted) | <= %.0f M | %.2f M%s |" % (
        GOAL_INSTR / 1e6, (instr + instr_stkf) / 1e6, missed(instr_stkf + instr, GOAL_INSTR)))
    print("| STKF cycle, heap bytes (max over 30 s) | measured, bounded | %d (the first lean STKF: 15.5 M) |" % st["heap_max"])
    print("\nOn this port every float result is a 16-byte heap object (float64, object representation A); a board "
          "port with single-precision floats packed in the object word (representation C) allocates none for them.")


STKF_S = 1200
STKF_F32_S = 4000
STKF_T0 = 300
BLOCKS = (("rA", 0, "m"), ("vA", 3, "m/s"), ("rB", 6, "m"), ("vB", 9, "m/s"))


def _stkf_figures(x, sig, truth, t0=STKF_T0):
    out = {}
    for name, i, _ in BLOCKS:
        out[name] = (float(np.sqrt((sig[-1, i:i + 3] ** 2).sum())),
                     float(np.sqrt(((x - truth)[t0:, i:i + 3] ** 2).sum(1).mean())))
    return out


def stkf_main():
    from ground.adcs.stkf_sim import THESIS
    keys = {"rA": "final_sigma_ra_m", "vA": "final_sigma_va_m_s", "rB": "final_sigma_rb_m", "vB": "final_sigma_vb_m_s"}
    print("\nLean STKF beside the ground STKF + EAFLS, same inputs (two-body truth, %d s, seed 0); final 1 sigma "
          "(sqrt trace) and RMS error over t >= %d s\n" % (STKF_S, STKF_T0))
    print("| case | block | thesis 1σ | ground 1σ | lean 1σ | lean/ground 1σ | ground RMS err | lean RMS err | "
          "lean/ground RMS |")
    print("|---|---|---|---|---|---|---|---|---|")
    for case in (1, 2):
        sc = stkf_scenario(STKF_S, case=case)
        truth = np.array([s["x"] for s in sc["steps"]])
        xl, sl, f, refused = run_stkf_lean(sc)
        xg, sg = run_stkf_ground(sc)
        fl, fg = _stkf_figures(xl, sl, truth), _stkf_figures(xg, sg, truth)
        for name, _, unit in BLOCKS:
            print("| %d | %s (%s) | %g | %.4g | %.4g | %.3f | %.4g | %.4g | %.3f |" % (
                case, name, unit, THESIS[case][keys[name]], fg[name][0], fl[name][0], fl[name][0] / fg[name][0],
                fg[name][1], fl[name][1], fl[name][1] / fg[name][1]))
        if refused:
            print("| %d | SatB solutions refused | | | %d | | | | |" % (case, refused))

    sc = stkf_scenario(STKF_F32_S, case=2)
    truth = np.array([s["x"] for s in sc["steps"]])
    pd = {"ok": True}

    def check(f):
        Pa = np.reshape(np.array(f.Pa, dtype=float), (6, 6))
        try:
            np.linalg.cholesky(Pa)
        except np.linalg.LinAlgError:
            pd["ok"] = False
        pd["ok"] = pd["ok"] and bool(np.array_equal(Pa, Pa.T))

    r64 = _stkf_figures(*run_stkf_lean(sc, zeros=lambda n: [0.0] * n)[:2], truth)
    r32 = _stkf_figures(*run_stkf_lean(sc, zeros=lambda n: F32([np.float32(0.0)] * n), every=check)[:2], truth)
    print("\nLean STKF, float32 (SatA's covariance path in numpy.float32 scalars) vs float64, Case 2, %d s; "
          "RMS error over t >= %d s; P symmetric and PD at every step: %s\n" % (STKF_F32_S, STKF_T0, pd["ok"]))
    print("| block | float64 RMS | float32 RMS | float32/float64 (goal within 10 %) |")
    print("|---|---|---|---|")
    for name, _, unit in BLOCKS:
        ratio = r32[name][1] / r64[name][1]
        print("| %s (%s) | %.4g | %.4g | %.3f%s |" % (name, unit, r64[name][1], r32[name][1], ratio,
                                                       " (met)" if abs(ratio - 1) <= 0.10 else " (missed)"))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
