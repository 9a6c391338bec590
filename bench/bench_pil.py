"""Processor in the loop: the controller on the PIL images (``make pil``: MicroPython's qemu port on QEMU's microbit
machine, a Cortex-M0) under ``-icount shift=0`` (one instruction a virtual ns, counted by the nRF51's TIMER0 at
16 MHz: 62.5 instructions a tick), in cycles at a stated cycles-per-instruction range for a Cortex-M0+ (1.2-1.6:
most Thumb instructions take one cycle, loads, stores and taken branches two; MicroPython's interpreter is load-
and branch-heavy), against the thesis's tick at 637.8 Hz on a 48 MHz SAMD21 (75,263 cycles).

- The law alone, viper (armv6m machine code) and bytecode, each less the replay loop's own
  (``tests/mp/pil_probe.py``, on the instruments' image).
- The 32 KB board (what ``--runtime qemu`` runs) in a 20 s ``fps hil`` with the thesis's 11x11 table: its RAM
  (the GC heap it reserves and the stack's high-water mark) and each TICK exchange (decoding, step, framing), all
  of them and the common ones that ``firmware.hal.fast_tick`` answers in machine code, read from the board after the
  run (``tools.pil_board.read_target``); the real-time factor.

- The disturbance player (``tests/mp/pil_player_probe.py``, on the instruments' image): bytecode and viper, one
  update per call and in blocks of 64, against the 10.6 kHz update.

Skipped, saying why, without the images."""

import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CPI = (1.2, 1.6)
CLOCK_HZ = 48e6
RATE_HZ = 637.8
PLAYER_HZ = 10600.0


def _fps(*args):
    p = subprocess.run([sys.executable, "-m", "ground.cli"] + list(args), cwd=ROOT, capture_output=True, text=True,
                       timeout=1800)
    if p.returncode != 0:
        raise RuntimeError("fps %s failed: %s" % (" ".join(args[:2]), p.stderr.strip()[-500:]))
    return p


def main():
    from tools import pil_board, pil_build
    missing = pil_build.missing_tools()
    if missing or not (os.path.exists(pil_build.IMAGE) and os.path.exists(pil_build.LAB_IMAGE)):
        print("PIL benchmark skipped: no image (make pil)%s" % (
            "; missing %s (%s)" % (", ".join(missing), pil_build.install_hint(missing)) if missing else ""))
        return
    with pil_board.Board() as b:               # the instruments' image: the same code, room for the recordings
        rows = [json.loads(b.run("import json, pil_probe, gc\ngc.collect()\nprint(json.dumps(pil_probe.counts(%d, %s)))"
                                 % (n, v)).strip().splitlines()[-1]) for n, v in ((2000, "True"), (500, "False"))]
        player = [json.loads(b.run("import json, pil_player_probe as pp, gc\ngc.collect()\nprint(json.dumps(%s))" % c)
                             .strip().splitlines()[-1])
                  for c in ("pp.counts(2000, False)", "pp.block_counts(100, 64, False)", "pp.counts(2000, True)",
                            "pp.block_counts(100, 64, True)")]
    budget = CLOCK_HZ / RATE_HZ
    print("Control law on the Cortex-M0 (QEMU microbit, -icount), the replay loop taken off; cycles at a Cortex-M0+ "
          "CPI of %.1f-%.1f against the 48 MHz tick of %.0f cycles\n" % (CPI[0], CPI[1], budget))
    print("| law | instructions per step | cycles per step (CPI %.1f-%.1f) | share of the tick |" % CPI)
    print("|---|---|---|---|")
    for r in rows:
        c0, c1 = r["insn_per_step"] * CPI[0], r["insn_per_step"] * CPI[1]
        print("| %s | %.0f | %.0f-%.0f | %.0f-%.0f %% |" % ("viper (armv6m)" if r["viper"] else "bytecode",
                                                         r["insn_per_step"], c0, c1, 100 * c0 / budget,
                                                         100 * c1 / budget))
    upd = CLOCK_HZ / PLAYER_HZ
    print("\nThe disturbance player (the thesis's SimArduino, taken as the same 48 MHz Cortex-M0+ class) on the "
          "Cortex-M0 (QEMU microbit, -icount): instructions per 10.6 kHz update (%.0f cycles at 48 MHz), playing a "
          "distfile from memory; the DACs' SPI writes not in it; one at a time (a timer interrupt's call) or in "
          "blocks of 64 (a buffer that an interrupt or DMA empties)\n" % upd)
    print("| player | instructions per update, mean | largest | cycles, mean (CPI %.1f-%.1f) | share of the update |"
          % CPI)
    print("|---|---|---|---|---|")
    for r in player:
        c0, c1 = r["insn_mean"] * CPI[0], r["insn_mean"] * CPI[1]
        what = "%s, %s" % ("viper" if r["viper"] else "bytecode",
                           "blocks of %d" % r["size"] if "size" in r else "one at a time")
        print("| %s | %.0f | %.0f%s | %.0f-%.0f | %.0f-%.0f %% (%s) |"
              % (what, r["insn_mean"], r["insn_max"], " (a new segment)" if "size" not in r else " (a block with one)",
                 c0, c1, 100 * c0 / upd, 100 * c1 / upd, "fits" if c1 <= upd else "does not fit"))
    print("\nPlayer heap (its object and a 400-sample distfile in memory): %.1f KB" % (player[0]["heap_bytes"] / 1024))
    with tempfile.TemporaryDirectory() as tmp:
        dist = os.path.join(tmp, "d.dist")
        _fps("distfile", "generate", "--source", "stat", "--duration", "20", "--seed", "1", "-o", dist)
        cal = os.path.join(tmp, "cal.json")
        _fps("calibrate", "--runtime", "micropython", "-o", cal)           # the thesis's 11x11 grid
        t0 = time.perf_counter()
        _fps("hil", "--distfile", dist, "--calibration", cal, "--duration", "20", "--runtime", "qemu", "--quiet",
             "--no-plots", "-o", os.path.join(tmp, "hil"))
        wall = time.perf_counter() - t0
        s = json.load(open(os.path.join(tmp, "hil", "summary.json")))
    t, ips = s["target"], s["instructions_per_step"]
    ram = t["heap_bytes"] + t["stack_high_water_bytes"]
    x0, x1 = ips["max"] * CPI[0], ips["max"] * CPI[1]

    def share(insn):
        c0, c1 = insn * CPI[0], insn * CPI[1]
        return "%.0f, %.0f-%.0f, %.0f-%.0f %% (%s)" % (insn, c0, c1, 100 * c0 / budget, 100 * c1 / budget,
                                                   "met" if c1 <= budget / 2 else "missed")
    print("\nThe controller on the 32 KB board (fps hil --runtime qemu, 20 s, the thesis's 11x11 H table; the board's "
          "own figures from its summary.json: %s)\n" % ips["what"])
    print("| figure | thesis / goal | ours |\n|---|---|---|")
    print("| RAM: GC heap (reserved) + stack high-water, of the board's %d KB | <= 24 KB (SAMD21G18: 32 KB) | "
          "%.1f KB + %.1f KB = %.1f KB (%s) |" % (t["ram_bytes"] // 1024, t["heap_bytes"] / 1024,
                                                 t["stack_high_water_bytes"] / 1024, ram / 1024,
                                                 "met" if ram <= 24 * 1024 else "missed"))
    print("| TICK exchange, mean over all %d: instructions, cycles (CPI %.1f-%.1f), share of the tick | <= 50 %% of "
          "%.0f cycles | %s |" % (ips["n"], CPI[0], CPI[1], budget, share(ips["mean"])))
    c = ips["common"]
    if c["n"]:
        print("| TICK exchange, mean over the %d common ones (machine code: no CTRL_STATUS due, in sequence) | <= 50 %% "
              "| %s |" % (c["n"], share(c["mean"])))
        print("| TICK exchange, the largest common one (a new H^-1 bin) | <= 50 %% | %s |" % share(c["max"]))
    print("| TICK exchange, the largest of all (a CTRL_STATUS tick in bytecode, the GC running in it) | - | "
          "%.0f, %.0f-%.0f, %.0f-%.0f %% |"
          % (ips["max"], x0, x1, 100 * x0 / budget, 100 * x1 / budget))
    print("| fps hil --runtime qemu, 20 s: real-time factor of the play (the whole command %.0f s wall) | >= 1x | "
          "%.2fx (%s) |" % (wall, s["real_time_factor"], "met" if s["real_time_factor"] >= 1 else "missed"))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
