"""Processor in the loop for the ADCS: the lean ADCS (APKF, STKF + AFLS, the control law, the C kernels built in)
on the ADCS board's image (``make pil``: MicroPython's qemu port on QEMU's mps2-an500, a Cortex-M7 with a
double-precision FPU; MicroPython's floats single precision) under ``-icount shift=0``.

A 210 s session of the thesis's spacecraft is recorded on the unix port (``emulator.adcs_session``, the calibrated
parameter file of ``bench_adcs_can``), then replayed on the board cycle by cycle through its UART
(``tools.pil_board.replay_adcs``): instructions per 1 Hz cycle (the cycle's packets, the filters, the control law,
the wheel commands; counted by the board's CMSDK timer against a calibration of its rate), the heap each cycle
allocates and the heap in use, the stack's high-water mark; the x86-64 figure of the same cycles beside it
(callgrind on the unix port, as ``bench_adcs_can``); the last ADCS_STATUS against the unix port's (float64) replay
of the same recording. Cycles at a Cortex-M7's 216 MHz (an STM32F7's top clock; ADCS computers run at 100-480 MHz)
and a stated CPI range (1.0-2.0: the M7 issues two instructions a cycle at best, QEMU models no caches, and an
interpreter's loads and branches stall).

Skipped, saying why, without the image."""

import json
import os
import shutil
import tempfile

import numpy as np

from bench import mp
from ground.adcs.quat import angle_arcsec

ROOT = mp.ROOT
CLOCK_HZ = 216e6
CPI = (1.0, 2.0)
GOAL_SHARE = 0.10


def main():
    from tools import pil_board, pil_build
    missing = pil_build.missing_tools()
    if missing or not os.path.exists(pil_build.ADCS_IMAGE):
        print("ADCS PIL benchmark skipped: no image (make pil)%s" % (
            "; missing %s (%s)" % (", ".join(missing), pil_build.install_hint(missing)) if missing else ""))
        return
    from bench import bench_adcs_can as bac
    from emulator.adcs_session import AdcsSession
    from ground.adcs import bps_cli
    from protocol import core
    params = bps_cli.calibration(0, os.path.join(ROOT, "out", "bps_cache"), progress=False)
    k0, k1 = bac.CG
    with AdcsSession(runtime="micropython", duration_s=k1, ts=bac.TS, hold_s=bac.HOLD, record=True,
                     params=params) as s:
        for _ in range(k1):
            s.cycle()
        cfg, rec = s.config(), s.recorded
    r = pil_board.replay_adcs(cfg, rec)
    cyc = [c for c in r["cycles"] if k0 <= c[0] < k1]
    insn = sum(c[1] for c in cyc) / len(cyc)
    worst = max(c[1] for c in cyc)
    first = max(c[1] for c in r["cycles"][:3])
    alloc = sum(c[2] for c in cyc) / len(cyc)
    with tempfile.TemporaryDirectory() as d:
        cfg_f, rec_f = os.path.join(d, "cfg.json"), os.path.join(d, "rec.json")
        with open(cfg_f, "w") as fh:
            json.dump(cfg, fh)
        with open(rec_f, "w") as fh:
            json.dump(rec, fh)
        x86 = bac._cycle_instr(cfg_f, rec_f) if shutil.which("valgrind") else float("nan")
        ref = bac._replay(cfg_f, rec_f, k1, False)["status"]
    st = core.payload_dict(core.PACKET_ID["ADCS_STATUS"], r["status"])
    dq = angle_arcsec([st["q%d" % i] for i in range(4)], [ref["q%d" % i] for i in range(4)])

    def share(n):
        c0, c1 = n * CPI[0], n * CPI[1]
        return "%.2f M, %.2f-%.2f M cycles, %.1f-%.1f %% of 1 s" % (n / 1e6, c0 / 1e6, c1 / 1e6, 100 * c0 / CLOCK_HZ,
                                                                   100 * c1 / CLOCK_HZ)
    print("The lean ADCS on the Cortex-M7 with its FPU (QEMU mps2-an500, -icount; %d cycles of a %d s session of the "
          "thesis's spacecraft replayed, cycles %d-%d: pointing), at %.0f MHz and a CPI of %.1f-%.1f\n"
          % (len(r["cycles"]), k1, k0, k1, CLOCK_HZ / 1e6, CPI[0], CPI[1]))
    print("| figure | goal / x86-64 | Cortex-M7 |\n|---|---|---|")
    print("| 1 Hz cycle, mean: instructions, cycles, share of the period | <= %.0f %% of 1 s; x86-64 %.2f M "
          "instructions (callgrind) | %s (%s) |" % (100 * GOAL_SHARE, x86 / 1e6, share(insn),
                                                    "met" if insn * CPI[1] <= GOAL_SHARE * CLOCK_HZ else "missed"))
    print("| 1 Hz cycle, the largest of cycles %d-%d | <= %.0f %% | %s |" % (k0, k1, 100 * GOAL_SHARE, share(worst)))
    print("| the first cycles (the filters' start) | - | %s |" % share(first))
    print("| heap: in use after the run; allocated per cycle (mean, collected between cycles) | - | %.1f KB of %d KB; "
          "%.1f KB |" % (r["heap_bytes"] / 1024, pil_build.ADCS_MEM.heap_bytes // 1024, alloc / 1024))
    print("| stack high-water | - | %.1f KB |" % (r["stack_high_water_bytes"] / 1024))
    print("| last ADCS_STATUS, float32 board against the float64 unix port: attitude; 1-sigma | - | %.3g arcsec apart; "
          "%.4g vs %.4g rad |" % (dq, st["att_sigma"], ref["att_sigma"]))
    system_rows()


SYSTEM_S = 120


def system_rows():
    """fps system --runtime qemu for SYSTEM_S: both boards, the ADCS's CAN through ISO-TP; its transfers failed
    (the goal: none), resent and timed out, and the filters' start apart from the cycles."""
    import subprocess
    import sys
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "s")
        p = subprocess.run([sys.executable, "-m", "ground.cli", "system", "--runtime", "qemu", "--duration",
                            str(SYSTEM_S), "--quiet", "--no-plots", "-o", out], cwd=ROOT, capture_output=True,
                           text=True, timeout=7200)
        if p.returncode != 0:
            print("\nfps system --runtime qemu --duration %d failed: %s" % (SYSTEM_S, p.stderr.strip()[-300:]))
            return
        with open(os.path.join(out, "summary.json")) as fh:
            a = json.load(fh)["adcs_summary"]
    lk, ipc = a["link"], a["instructions_per_cycle"]
    print("\nfps system --runtime qemu --duration %d (both boards; the ADCS's CAN through Lawicel on its UART, ISO-TP "
          "beyond 8 bytes, the host's N_Bs and N_Cr 1000 ms on a PIL board)\n" % SYSTEM_S)
    print("| figure | goal | ours |\n|---|---|---|")
    print("| ISO-TP transfers failed | 0 | %d (%s) |" % (lk.get("tx_isotp_failed", 0),
                                                        "met" if not lk.get("tx_isotp_failed") else "missed"))
    print("| ISO-TP transfers resent; host timeouts | - | %d; %d |" % (
        lk.get("tx_isotp_resent", 0), sum(v for k, v in lk.items() if "Timeout" in k)))
    print("| the board's cycle, mean and largest (the filters' start apart) | - | %.2f M, %.2f M instructions; the "
          "filters' start %.2f M |" % (ipc["mean"] / 1e6, ipc["max"] / 1e6, (ipc["filters_start"] or 0) / 1e6))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
