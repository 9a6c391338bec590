"""The ADCS on CAN: the 1 Hz cycle's cost under MicroPython, the CAN session's speed, and the
pointing the lean flight filters leave on a 600 s session beside the ground filters' on the same scenario.

- Session: ``emulator.adcs_session.AdcsSession`` for 600 s (hold 30 s, then pointing at SatB, t_s = 33 s,
  SatA GNSS + beacon, two-body truth, seed 0): the firmware ``firmware/adcs/main_can.py`` under micropython and
  under CPython, on Lawicel over a pty, python-can's slcan interface on the emulator side. Speed = virtual s
  per wall s (goal of the whole ``fps system`` run: >= 5x real time; this is the ADCS loop alone).
- Pointing: ``ground.adcs.body_pointing.pointing_errors`` on the session's 10 Hz truth after 30 s + 4 t_s (Eq. 6.12-6.21),
  beside ``ground.adcs.body_pointing.simulate`` (the same app in process on the ground's estimators: 41-state APKF,
  full STKF/EAFLS, numpy) on the same spacecraft, sensors
  and seed for the same span (the goal: lean within 25 %), both from the parameter file of the nine
  calibration sets (``fps adcs bps``'s calibration, cached in out/bps_cache).
- Instructions: the session's sensor bursts replayed through ``firmware/adcs/app.py`` (tests/mp/
  firmware_adcs_app.py) under ``valgrind --tool=callgrind``, cycles [0, 110) and [0, 210) differenced:
  100 pointing cycles (goal <= 10 M per cycle; a 20-cycle window catches or misses a full collection of the
  64 MB heap by chance). The filters' hot kernels run in C (firmware/adcs/adcsk.mpy, ``make natmod``) when
  built, and the rest is compiled by the native emitter; beside it the same count with the filters' Python
  forms (no native module: the same results bit for bit), and with those as bytecode only, and the modules'
  .mpy sizes both ways (x64, Cortex-M4F).
  Heap: gc.mem_alloc deltas per cycle, gc off in the cycle.
- Split: the same bursts through the app and its CAN HAL (tests/mp/firmware_adcs_split.py) under micropython,
  ticks_us per part over the pointing cycles; each part's share of the cycle's time applied to the callgrind
  count (an estimate: time shares, not counted instructions). The HAL (slcan ASCII, CAN/ISO-TP, payload
  unpacking, RW_CMD and ADCS_STATUS out) is outside the callgrind figure; it is scaled the same way.
- The same cycle with SatB's GNSS relayed (the STKF's 4 s lag): a 210 s session recorded, callgrind and split.
- The lean APKF's momentum input (``apkf_momentum``): the flown filtered wheel speeds, the raw read-out
  difference and the commanded torques on CPython sessions with the calibrated and the true parameters; then
  the first two over the calibration files of seeds 0-5 (hpop truth, as `fps system` flies).
"""

import json
import os
import shutil
import subprocess
import tempfile
import time

import numpy as np

from bench import mp
from bench.common import missed, timed

from emulator.adcs_session import AdcsSession
from tools import natmod_build
from ground.adcs import body_pointing as bps
from protocol.units import RAD_PER_ARCSEC

ROOT = mp.ROOT
SECONDS = 600
TS = 33.0
HOLD = 30.0
GOAL_INSTR = 10e6
GOAL_SPEED = 5.0
GOAL_RATIO = 1.25
CG = (110, 210)


def session(runtime, params, record=False, heap_out=None, apkf_momentum="filtered", seed=0, truth="two-body"):
    hist = {k: [] for k in ("q", "w", "ra", "va", "rb", "vb", "t")}
    modes = {}
    blind = []                  # cycles without a valid star-tracker output (the stale bit)
    werr, prev = [], None       # the APKF's rate error per cycle (rad/s)
    t0 = time.perf_counter()
    with AdcsSession(runtime=runtime, duration_s=SECONDS, ts=TS, hold_s=HOLD, record=record, seed=seed,
                     truth=truth, cache_dir=os.path.join(ROOT, "out", "orbit_cache"), heap_out=heap_out,
                     params=params, apkf_momentum=apkf_momentum) as s:
        for k in range(SECONDS):
            c = s.cycle()
            for key in hist:
                hist[key].append(c[key])
            m = c["status"].get("adcs_mode_name", "late")
            modes[m] = modes.get(m, 0) + 1
            if c["status"].get("stale", 0) & 1:
                blind.append(k)
            e = c.get("est") or {}
            if "w" in e and prev is not None:       # the estimate is of the previous cycle's end
                werr.append(np.subtract(e["w"], prev))
            else:
                werr.append(np.full(3, np.nan))
            prev = c["w"][-1]
        wall = time.perf_counter() - t0
        summ = s.summary()
        cfg, rec = s.config(), s.recorded
    h = {k: np.concatenate(v) for k, v in hist.items()}
    dth, dom = bps.pointing_errors(h["q"], h["w"], h["ra"], h["va"], h["rb"], h["vb"])
    sel = h["t"] >= HOLD + 4 * TS
    return {"stats": bps.statistics(dth[sel], dom[sel]), "wall": wall, "summary": summ, "modes": modes,
            "cfg": cfg, "rec": rec, "blind": blind, "w_err": np.array(werr)}


def apkf_input(params):
    """The lean APKF's momentum input in the closed loop: the filtered wheel speeds (flown), the raw read-out
    difference and the commanded torques, each with the calibrated parameter file and with the true parameters
    (CPython sessions)."""
    lines = ["\nThe lean APKF's momentum input in the closed loop (CPython sessions, %d s, seed 0; body pointing "
             "after %.0f s)\n" % (SECONDS, HOLD + 4 * TS), "| input | parameter file | pointing 3σ (arcsec) | "
             "stability 3σ (arcsec/s) | star tracker blind (cycles) | its last blind cycle | APKF rate error, x, mean over "
             "70-100 s (arcsec/s) |", "|---|---|---|---|---|---|---|"]
    runs = {}
    for name, p in (("calibrated (nine sets, seed 0)", params), ("true parameters", None)):
        for mom, label in (("filtered", "wheel speeds filtered on the commands (flown)"),
                           ("tach", "read-out difference"), ("torque", "commanded torques")):
            r = session("cpython", p, apkf_momentum=mom)
            runs[(p is None, mom)] = r["stats"]
            if p is None:
                tru = r["cfg"]["params"]          # what a perfect calibration writes
            st = r["stats"]
            lines.append("| %s | %s | %.1f | %.1f | %d | %s | %.0f |" % (
                label, name, st["pointing_3sigma_arcsec"], st["stability_3sigma_arcsec_s"], len(r["blind"]),
                r["blind"][-1] if r["blind"] else "—", np.nanmean(r["w_err"][70:100, 0]) / RAD_PER_ARCSEC))
    lines.append("Budget: 3σ <= %.0f arcsec and <= %.0f arcsec/s." % (bps.BUDGET_POINTING_3SIGMA,
                                                                    bps.BUDGET_STABILITY_3SIGMA))
    rel = np.abs(np.divide(params["x"]["J5_kgm2"], params["jxx_ref_kgm2"]) /
                 np.divide(tru["x"]["J5_kgm2"], tru["jxx_ref_kgm2"]) - 1)
    dd = np.degrees(np.abs(np.subtract(params["x"]["delta1_rad"] + params["x"]["delta2_rad"],
                                       tru["x"]["delta1_rad"] + tru["x"]["delta2_rad"])))
    lines.append("The calibrated file against the truth: inertia relative to Jxx (Jyy, Jzz, Jxy, Jxz, Jyz) off by "
                 "%s %%; wheel misalignments off by up to %.1f deg." % (
                     ", ".join("%.1f" % (100 * v) for v in rel), dd.max()))
    return "\n".join(lines), runs


def _replay(cfg, rec, n, callgrind, heap=False, path=None):
    out = mp.run(os.path.join(ROOT, "tests", "mp", "firmware_adcs_app.py"), [cfg, rec, n] + (["heap"] if heap else []),
                 callgrind=callgrind, heap="64M", timeout=1800, path=path)
    return out if callgrind else json.loads(out.strip().splitlines()[-1])


MODULE = natmod_build.TARGET          # the C kernels (make natmod), when built


def _python_tree(d):
    """A copy of firmware/ and protocol/ in d without the C kernels (the filters' Python forms run)."""
    for pkg in ("firmware", "protocol"):
        shutil.copytree(os.path.join(ROOT, pkg), os.path.join(d, pkg),
                        ignore=shutil.ignore_patterns("__pycache__", "*.mpy"))
    return d


def _cycle_instr(cfg, rec, path=None):
    """x86-64 instructions per pointing cycle (callgrind, cycles CG[0]..CG[1] differenced)."""
    return (_replay(cfg, rec, CG[1], True, path=path) - _replay(cfg, rec, CG[0], True, path=path)) / (CG[1] - CG[0])


def _bytecode_tree(d):
    """``_python_tree`` with the ADCS modules' @micropython.native lines dropped (the same code as bytecode, for
    the instruction count without the native emitter)."""
    _python_tree(d)
    adcs = os.path.join(d, "firmware", "adcs")
    for f in os.listdir(adcs):
        if f.endswith(".py"):
            with open(os.path.join(adcs, f)) as fh:
                src = "".join(ln for ln in fh if ln.strip() != "@micropython.native")
            with open(os.path.join(adcs, f), "w") as fh:
                fh.write(src)
    return d


def _split(cfg, rec, k0, k1):
    out = mp.run(os.path.join(ROOT, "tests", "mp", "firmware_adcs_split.py"), [cfg, rec, k0, k1], heap="64M",
                 timeout=1800)
    return json.loads(out.strip().splitlines()[-1])


def _satb_cycle(params, d):
    """The same cycle with SatB's GNSS relayed (lag 4 s, 6 nodes): a 210 s session recorded, then callgrind
    and the split as above over cycles 110-210 / 162-210."""
    with AdcsSession(runtime="micropython", duration_s=CG[1], ts=TS, hold_s=HOLD, record=True, params=params,
                     satb_gnss=True) as s:
        for _ in range(CG[1]):
            s.cycle()
        cfg, rec, summ = s.config(), s.recorded, s.summary()
    cfg_f, rec_f = _write_session(d, cfg, rec, "_b")
    instr = _cycle_instr(cfg_f, rec_f)
    instr_py = _cycle_instr(cfg_f, rec_f, _python_tree(os.path.join(d, "py_b"))) if os.path.exists(MODULE) else instr
    heap = _replay(cfg_f, rec_f, CG[1], False, heap=True)["heap"][int(HOLD + 4 * TS):]
    return (instr, heap, _split(cfg_f, rec_f, int(HOLD + 4 * TS), CG[1]), summ["firmware_missed"]["gnss_b_fused"],
            instr_py)


def code_size():
    """The ADCS modules' .mpy bytes (mpy-cross): native code for x64 (what the figures above ran) and for a
    Cortex-M4F (armv7emsp), beside the same modules compiled as bytecode only (the native decorators dropped)."""
    from tools import mpy_build
    sizes = {}
    with tempfile.TemporaryDirectory() as d:
        for march in ("host", "armv7emsp"):
            rows = mpy_build.build(os.path.join(d, march), march)
            sizes[march] = {r[0]: r[3] for r in rows if r[0].startswith(os.path.join("firmware", "adcs"))}
        exe, bc = mpy_build.mpy_cross(), _bytecode_tree(os.path.join(d, "bytecode"))
        plain = {}
        for rel in sizes["host"]:
            out = os.path.join(d, "plain.mpy")
            subprocess.run([exe, "-o", out, "-s", rel, os.path.join(bc, rel)], check=True, capture_output=True)
            plain[rel] = os.path.getsize(out)
    lines = ["\nCode size of the ADCS modules (.mpy bytes; native code runs from flash when frozen into the "
             "firmware, from RAM when loaded from a file)\n", "| module | bytecode only | native, x64 | "
             "native, Cortex-M4F (armv7emsp) |", "|---|---|---|---|"]
    for rel in sorted(plain):
        lines.append("| %s | %d | %d | %d |" % (rel, plain[rel], sizes["host"][rel], sizes["armv7emsp"][rel]))
    lines.append("| **total** | %d | %d | %d |" % (sum(plain.values()), sum(sizes["host"].values()),
                                                    sum(sizes["armv7emsp"].values())))
    if os.path.exists(MODULE):
        arm = natmod_build.module_path("armv7emsp")
        lines.append("| firmware/adcs/adcsk.mpy (the C kernels, a native module; besides the above) | — | %d | %s |"
                     % (os.path.getsize(MODULE), os.path.getsize(arm) if os.path.exists(arm) else
                        "not built (`python -m tools.natmod_build --arch armv7emsp` with arm-none-eabi-gcc)"))
    return "\n".join(lines)


ROBUST_SEEDS = (0, 1, 2, 3, 4, 5)


def robustness():
    """The flown momentum input beside the raw read-out difference over the calibration files of seeds 0-5
    (nine sets each, cached), each on its own seed's session (CPython, hpop truth as `fps system` flies)."""
    from ground.adcs import bps_cli
    lines = ["\nThe same over six calibrations (CPython sessions, %d s, hpop truth, seed n with the calibration file of "
             "seed n; body pointing after %.0f s)\n" % (SECONDS, HOLD + 4 * TS),
             "| seed | input | pointing 3σ (arcsec) | stability 3σ (arcsec/s) | star tracker blind (cycles) | "
             "its last blind cycle |", "|---|---|---|---|---|---|"]
    worst = {}
    for seed in ROBUST_SEEDS:
        p = bps_cli.calibration(seed, os.path.join(ROOT, "out", "bps_cache"), progress=False)
        for mom, label in (("filtered", "filtered (flown)"), ("tach", "read-out difference")):
            r = session("cpython", p, apkf_momentum=mom, seed=seed, truth="hpop")
            st = r["stats"]
            w = worst.setdefault(label, [0.0, 0.0])
            w[0], w[1] = max(w[0], st["pointing_3sigma_arcsec"]), max(w[1], st["stability_3sigma_arcsec_s"])
            lines.append("| %d | %s | %.1f | %.1f | %d | %s |" % (
                seed, label, st["pointing_3sigma_arcsec"], st["stability_3sigma_arcsec_s"], len(r["blind"]),
                r["blind"][-1] if r["blind"] else "—"))
    lines.append("Worst of the six: " + "; ".join("%s %.1f arcsec / %.1f arcsec/s" % (k, v[0], v[1])
                                                  for k, v in worst.items()) +
                 " (budget <= %.0f arcsec / <= %.0f arcsec/s)." % (bps.BUDGET_POINTING_3SIGMA,
                                                                   bps.BUDGET_STABILITY_3SIGMA))
    return "\n".join(lines)


def main():
    from ground.adcs import bps_cli
    params, t_cal = timed(bps_cli.calibration, 0, os.path.join(ROOT, "out", "bps_cache"), progress=False)
    f = _measure(params)
    (g, _), g_wall = timed(bps.simulate, ts=TS, duration_s=SECONDS - HOLD - 4 * TS, seed=0, params=params,
                           truth="two-body")
    _print_cost(f)
    _print_split(f["split"], f["instr"])
    if f["satb"] is not None:
        _print_satb(f["satb"], f["kern"])
    print(code_size())
    text, by_input = apkf_input(params)
    print(text)
    print(robustness())
    _print_speed(f["runs"])
    _print_pointing(f["runs"]["micropython"]["stats"], by_input[(False, "tach")], g, g_wall, t_cal)


def _write_session(d, cfg, rec, tag=""):
    """A session's configuration and recorded bursts as d/cfg<tag>.json and d/rec<tag>.json: their paths."""
    paths = os.path.join(d, "cfg%s.json" % tag), os.path.join(d, "rec%s.json" % tag)
    for path, obj in zip(paths, (cfg, rec)):
        with open(path, "w") as fh:
            json.dump(obj, fh)
    return paths


def _measure(params):
    """The CAN session under micropython (recorded) and CPython, and its bursts replayed: {"runs": {runtime:
    ``session``'s}, "heap_session": heap bytes per cycle in the session, "kern": whether the C kernels are built,
    "instr", "instr_py", "instr_bc": instructions per pointing cycle with the C kernels, the Python forms and as
    bytecode only (NaN without valgrind), "heap": heap bytes per replayed cycle, "split": ``_split``'s, "satb":
    ``_satb_cycle``'s (None without valgrind)}."""
    runs = {}
    with tempfile.TemporaryDirectory() as d:
        heap_file = os.path.join(d, "heap.json")
        runs["micropython"] = session("micropython", params, record=True, heap_out=heap_file)
        runs["cpython"] = session("cpython", params)
        with open(heap_file) as fh:
            heap_session = json.load(fh)["heap_bytes"]
        cfg, rec = _write_session(d, runs["micropython"]["cfg"], runs["micropython"]["rec"])
        have_vg = shutil.which("valgrind") is not None
        kern = os.path.exists(MODULE)
        instr = _cycle_instr(cfg, rec) if have_vg else float("nan")
        instr_py = (_cycle_instr(cfg, rec, _python_tree(os.path.join(d, "py"))) if have_vg and kern else
                    instr)
        instr_bc = _cycle_instr(cfg, rec, _bytecode_tree(os.path.join(d, "bytecode"))) if have_vg else float("nan")
        return {"runs": runs, "heap_session": heap_session, "kern": kern, "instr": instr, "instr_py": instr_py,
                "instr_bc": instr_bc, "heap": _replay(cfg, rec, SECONDS, False, heap=True)["heap"],
                "split": _split(cfg, rec, int(HOLD + 4 * TS), SECONDS),
                "satb": _satb_cycle(params, d) if have_vg else None}


def _print_cost(f):
    """The cycle's instructions and heap (``_measure``'s figures ``f``)."""
    kern, instr, instr_py = f["kern"], f["instr"], f["instr_py"]
    hs = np.array(f["heap"][int(HOLD + 4 * TS):])
    print("Cost of one 1 Hz ADCS cycle (APKF + STKF + control, no CAN) under micropython (unix x64 port)%s\n"
          % ("" if kern else "; the C kernels (firmware/adcs/adcsk.mpy) are not built: `make natmod` says why"))
    print("| item | goal | ours |")
    print("|---|---|---|")
    print("| x86-64 instructions per cycle, pointing (callgrind, cycles %d-%d)%s | <= %.0f M | %.2f M%s |"
          % (CG[0], CG[1], ", with the C kernels (flown)" if kern else ", Python kernels", GOAL_INSTR / 1e6,
             instr / 1e6, missed(instr, GOAL_INSTR)))
    if kern:
        print("| the same, the filters' Python forms (no native module; same results bit for bit) | <= %.0f M | "
              "%.2f M%s |" % (GOAL_INSTR / 1e6, instr_py / 1e6, missed(instr_py, GOAL_INSTR)))
    print("| the same, Python forms as bytecode only (no native module, no native emitter) | — | %.2f M |"
          % (f["instr_bc"] / 1e6))
    print("| heap bytes per cycle, pointing (max / mean) | measured, bounded | %d / %d |" % (hs.max(), hs.mean()))
    print("| heap bytes per cycle in the CAN session (max over %d cycles, incl. status) | measured | %d |"
          % (len(f["heap_session"]), max(f["heap_session"])))


def _print_split(split, instr):
    """Each part's share of the cycle's time (``_split``'s ``split``) and of ``instr`` instructions."""
    n, cyc = split["cycles"], split["cycle"]
    other = cyc - split["apkf"] - split["stkf"] - split["control"]
    print("\nWhere the cycle goes (micropython, ticks_us over the %d pointing cycles %d-%d; M instructions = the "
          "part's share of the cycle's time x the callgrind figure above, an estimate)\n" % (n, SECONDS - n, SECONDS))
    print("| part | us per cycle | share of the cycle | ~M x86-64 instructions |")
    print("|---|---|---|---|")
    rows = (("lean APKF (step, attitude covariance)", split["apkf"]),
            ("lean STKF (predict, GNSS, get)", split["stkf"] - split["beacon"]),
            ("beacon update (LeanStkf.update_beacon)", split["beacon"]),
            ("control (command, rate, PD, allocation)", split["control"]),
            ("rest of the cycle (wheels, modes, commands)", other))
    for name, us in rows:
        print("| %s | %.0f | %.0f %% | %.2f |" % (name, us / n, 100.0 * us / cyc, instr * us / cyc / 1e6))
    print("| **cycle (callgrind)** | %.0f | 100 %% | %.2f |" % (cyc / n, instr / 1e6))
    print("| CAN HAL, outside the cycle (slcan, ISO-TP, unpack, RW_CMD + status out) | %.0f | %.0f %% of the "
          "cycle | %.2f |" % (split["hal"] / n, 100.0 * split["hal"] / cyc, instr * split["hal"] / cyc / 1e6))


def _print_satb(satb, kern):
    """The cycle with SatB's GNSS relayed (``_satb_cycle``'s ``satb``)."""
    ib, hb, sb, fused, ib_py = satb
    n, cyc = sb["cycles"], sb["cycle"]
    print("\nThe same cycle with SatB's GNSS relayed 2-3 s late (STKF lag 4 s, 6 nodes; a %d s session, %s SatB "
          "fixes fused; callgrind cycles %d-%d, time shares over %d-%d)\n" % (CG[1], fused, CG[0], CG[1],
                                                                             CG[1] - n, CG[1]))
    print("| part | share of the cycle | ~M x86-64 instructions |")
    print("|---|---|---|")
    for name, us in (("lean APKF", sb["apkf"]),
                     ("lean STKF (predict, GNSS A and B, get)", sb["stkf"] - sb["beacon"]),
                     ("beacon update", sb["beacon"]), ("control", sb["control"]),
                     ("rest of the cycle", cyc - sb["apkf"] - sb["stkf"] - sb["control"])):
        print("| %s | %.0f %% | %.2f |" % (name, 100.0 * us / cyc, ib * us / cyc / 1e6))
    print("| **cycle (callgrind%s; goal <= %.0f M)** | 100 %% | %.2f%s |" % (
        ", C kernels" if kern else "", GOAL_INSTR / 1e6, ib / 1e6, missed(ib, GOAL_INSTR)))
    if kern:
        print("| the same cycle, the filters' Python forms (no native module) | | %.2f%s |" % (
            ib_py / 1e6, missed(ib_py, GOAL_INSTR)))
    print("| CAN HAL, outside the cycle | %.0f %% of the cycle | %.2f |" % (100.0 * sb["hal"] / cyc,
                                                                           ib * sb["hal"] / cyc / 1e6))
    print("| heap bytes per cycle, pointing (max / mean) | | %d / %d |" % (max(hb), sum(hb) / len(hb)))


def _print_speed(runs):
    """The CAN session's speed under each runtime (``session``'s results ``runs``)."""
    print("\nSpeed of the %d s CAN session (ADCS loop alone; the goal: the whole `fps system` run >= %gx)\n" % (
        SECONDS, GOAL_SPEED))
    print("| firmware runtime | wall | virtual s per wall s | late cycles | missed replies (fw) | modes (cycles) |")
    print("|---|---|---|---|---|---|")
    for name, r in runs.items():
        s = r["summary"]
        fm = s["firmware_missed"]
        print("| %s | %.1f s | %.1f | %d | rw %s, st %s, gnss %s, beacon %s | %s |" % (
            name, r["wall"], SECONDS / r["wall"], s["late_cycles"], fm["rw"], fm["startracker"], fm["gnss"],
            fm["beacon"], ", ".join("%s %d" % kv for kv in sorted(r["modes"].items()))))


def _print_pointing(st, tach, g, g_wall, t_cal):
    """Body pointing of the lean flight filters (``st``: the micropython session's statistics; ``tach``: the
    CPython session's on the read-out difference) beside the ground's estimators (``g``, its wall ``g_wall``)."""
    print("\nBody pointing after %.0f s (hold + 4 t_s), t_s = %g s, %d s session; arcsec, arcsec/s\n"
          % (HOLD + 4 * TS, TS, SECONDS))
    th = bps.THESIS[False]
    print("| filters | pointing σ x / y | pointing 3σ | max | stability 3σ | lean vs ground (goal <= %.2f) |"
          % GOAL_RATIO)
    print("|---|---|---|---|---|---|")
    ratio = st["pointing_3sigma_arcsec"] / g["pointing_3sigma_arcsec"]
    print("| lean flight (CAN session, micropython) | %.1f / %.1f | %.1f | %.1f | %.1f | %.2f%s |" % (
        *st["pointing_sigma_arcsec"], st["pointing_3sigma_arcsec"], st["pointing_max_arcsec"],
        st["stability_3sigma_arcsec_s"], ratio, " (missed: worse than the ground's)" if ratio > GOAL_RATIO else
        " (better than the ground's by more than 25 %: the flown momentum input, next row)" if ratio < 1 / GOAL_RATIO
        else " (met)"))
    rt = tach["pointing_3sigma_arcsec"] / g["pointing_3sigma_arcsec"]
    print("| lean flight on the ground APKF's momentum input, the read-out difference (CPython session) | %.1f / %.1f "
          "| %.1f | %.1f | %.1f | %.2f%s |" % (
              *tach["pointing_sigma_arcsec"], tach["pointing_3sigma_arcsec"], tach["pointing_max_arcsec"],
              tach["stability_3sigma_arcsec_s"], rt, " (met)" if 1 / GOAL_RATIO <= rt <= GOAL_RATIO else " (missed)"))
    print("| the app on the ground's estimators (bps.simulate, 41-state APKF, %.0f s wall) | %.1f / %.1f | %.1f | %.1f "
          "| %.1f | 1 |" % (
        g_wall, *g["pointing_sigma_arcsec"], g["pointing_3sigma_arcsec"], g["pointing_max_arcsec"],
        g["stability_3sigma_arcsec_s"]))
    print("| thesis Sec. 6.4.4 (t_s = 33 s, 4000 s) | %.1f / %.1f | %.1f | | %.1f | |" % (
        th["theta"][0][1], th["theta"][1][1], *bps.thesis_3sigma(False)))
    print("| budget | | <= %.0f | | <= %.0f | |" % (bps.BUDGET_POINTING_3SIGMA, bps.BUDGET_STABILITY_3SIGMA))
    print("\nBoth from the parameter file of the nine calibration sets (seed 0, %.1f s, `fps adcs bps`'s cache). "
          "The same app, modes and laws; only the estimators differ: the lean APKF holds the calibrated parameters "
          "(9 states) where the ground APKF estimates them on (41), and the lean STKF updates in sequence where the "
          "ground's takes the GNSS and the beacon in one update; the figures are over %d s, not the thesis's "
          "4000 s." % (t_cal, SECONDS - HOLD - 4 * TS))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
