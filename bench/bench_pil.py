"""Processor in the loop: the controller on the PIL images (``make pil``: MicroPython's qemu port on QEMU's microbit
machine, a Cortex-M0) under ``-icount shift=0`` (one instruction a virtual ns, counted by the nRF51's TIMER0 at
16 MHz: 62.5 instructions a tick), in cycles at a stated cycles-per-instruction range for a Cortex-M0+ (1.2-1.6:
most Thumb instructions take one cycle, loads, stores and taken branches two; MicroPython's interpreter is load-
and branch-heavy), against the thesis's tick at 637.8 Hz on a 48 MHz SAMD21 (75,263 cycles).

- The law alone, viper (armv6m machine code) and bytecode, each less the replay loop's own
  (``tests/mp/pil_probe.py``, on the instruments' image).
- The 32 KB board (what ``--runtime qemu`` runs) in two identical 60 s ``fps hil`` runs with the thesis's 11x11
  table: its RAM (the GC heap it reserves and the stack's high-water mark) and each kind of TICK exchange
  (decoding, step, framing; ``tools.pil_mailbox``), read from the board after the run
  (``tools.pil_board.read_target``), the two runs' counts side by side, the worst tick against 47,000 instructions
  (75,259 cycles at CPI 1.6), the link's bytes on the wire and the baud closing the loop (``tools.pil_wire``); the
  real-time factor.
- Each image's flash and RAM against its board (``make pil``'s build/pil/summary.json), and the 24 KB board with the
  11x11 table.

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
    board_rows(budget)
    image_rows()


HIL_S = 60
WORST_INSN = 47000                # 75,259 cycles at CPI 1.6: the worst tick's goal


def _hil_runs(tmp, n):
    """``n`` runs of the same fps hil --runtime qemu (HIL_S, the thesis's 11x11 grid): their summaries, the wall
    time of the first."""
    dist = os.path.join(tmp, "d.dist")
    _fps("distfile", "generate", "--source", "stat", "--duration", str(HIL_S), "--seed", "1", "-o", dist)
    cal = os.path.join(tmp, "cal.json")
    _fps("calibrate", "--runtime", "micropython", "-o", cal)           # the thesis's 11x11 grid
    out, wall = [], None
    for k in range(n):
        t0 = time.perf_counter()
        _fps("hil", "--distfile", dist, "--calibration", cal, "--duration", str(HIL_S), "--runtime", "qemu",
             "--quiet", "--no-plots", "-o", os.path.join(tmp, "hil%d" % k))
        wall = wall or time.perf_counter() - t0
        out.append(json.load(open(os.path.join(tmp, "hil%d" % k, "summary.json"))))
    return out, wall


def board_rows(budget):
    """The 32 KB board in two identical 60 s fps hil runs: RAM, each kind of tick, the worst, the wire."""
    with tempfile.TemporaryDirectory() as tmp:
        runs, wall = _hil_runs(tmp, 2)
    s = runs[0]
    t, ips = s["target"], s["instructions_per_step"]
    ram = t["heap_bytes"] + t["stack_high_water_bytes"]

    def share(insn, goal=budget / 2):
        c0, c1 = insn * CPI[0], insn * CPI[1]
        return "%.0f, %.0f-%.0f, %.0f-%.0f %% (%s)" % (insn, c0, c1, 100 * c0 / budget, 100 * c1 / budget,
                                                   "met" if c1 <= goal else "missed")
    print("\nThe controller on the 32 KB board (fps hil --runtime qemu, %d s, twice, the thesis's 11x11 H table; the "
          "board's own figures from its summary.json: %s)\n" % (HIL_S, ips["what"]))
    print("| figure | thesis / goal | ours |\n|---|---|---|")
    print("| RAM: GC heap (reserved) + stack high-water, of the board's %d KB | <= 31 KB (SAMD21G18: 32 KB, "
          "MicroPython's variables 0.8 KB) | %.1f KB + %.1f KB = %.1f KB (%s) |" % (
              t["ram_bytes"] // 1024, t["heap_bytes"] / 1024, t["stack_high_water_bytes"] / 1024, ram / 1024,
              "met" if ram <= 31 * 1024 else "missed"))
    k0, k1 = (r["instructions_per_step"]["kinds"] for r in runs)
    for name, v in k0.items():
        if v["n"]:
            print("| %s ticks: n; mean, largest instructions (cycles at CPI %.1f-%.1f, share of the tick) | <= 50 %% "
                  "| %d; %.0f; %s |" % (name, CPI[0], CPI[1], v["n"], v["mean"], share(v["max"])))
    same = all((k0[n]["n"], k0[n]["sum"]) == (k1[n]["n"], k1[n]["sum"]) for n in k0 if n != "resend")
    resent = [r["link"]["bench"]["controller_resent"] for r in runs]
    print("| two runs of the same input: n and sum per kind (resends apart; the host resent %d and %d TICKs) | the "
          "same | %s (%s) |" % (resent[0], resent[1], "; ".join(
              "%s %d/%d, %.0f/%.0f" % (n, k0[n]["n"], k1[n]["n"], k0[n]["sum"], k1[n]["sum"]) for n in k0
              if n != "resend"), "met" if same else "missed" + (
              "" if resent[0] == resent[1] else ": a resent TICK is the board's input too (its n_dup)")))
    worst = max(r["instructions_per_step"]["max"] for r in runs)
    print("| the worst tick over both runs, at CPI 1.6 and 48 MHz (one flash wait state) | <= %d instructions "
          "(75,259 cycles) | %.0f, %.0f cycles (%s) |" % (WORST_INSN, worst, worst * CPI[1],
                                                          "met" if worst <= WORST_INSN else "missed"))
    w = t["wire"]
    print("| the UART's bytes a tick (common; status; mean) and their time at 115,200 baud | - | %d; %d; %.1f B; "
          "%.1f ms, %.1f ticks |" % (w["bytes_per_tick"]["common"], w["bytes_per_tick"]["status"],
                                     w["bytes_per_tick"]["mean"], 1e3 * w["wire_s_common"],
                                     w["ticks_on_the_wire_common"]))
    print("| the least baud closing the loop: a common tick alone (its mean); the run's worst figures in a row (a "
          "status tick among common ticks at their largest, tools.pil_wire.worst_sequence) | - | %s (standard %s); "
          "%s (standard %s) |" % (
              "%.0f" % w["least_baud_common"] if w["least_baud_common"] else "none", w["least_standard_baud_common"],
              "%.0f" % w["least_baud_worst"] if w["least_baud_worst"] else "none", w["least_standard_baud_worst"]))
    for k, r in enumerate(runs):
        b = r["target"]["wire"]["board"]
        print("| run %d: the worst tick with the UART at %d baud (the board's meter: every tick on the wire, "
              "firmware.pil_main.Meter.wire), cycles at CPI 1.6 from the TICK's first byte to the FSM_SPI's last; "
              "ticks late | <= %d cycles; 0 | %d (%.0f %%); %d of %d (%s) |" % (
                  k + 1, b["baud"], b["period_cycles"], b["worst_cycles"], 100.0 * b["worst_cycles"] /
                  b["period_cycles"], b["late_ticks"], b["ticks"],
                  "met" if b["worst_cycles"] <= b["period_cycles"] and not b["late_ticks"] else "missed"))
    print("| fps hil --runtime qemu, %d s: real-time factor of the play (the whole command %.0f s wall) | >= 1x | "
          "%.2fx (%s) |" % (HIL_S, wall, s["real_time_factor"], "met" if s["real_time_factor"] >= 1 else "missed"))


def image_rows():
    """Each image's flash and RAM against its board (make pil's build/pil/summary.json), and the 24 KB board on the
    11x11 table (a 5 s fps hil run on it, in this process)."""
    from tools import pil_build
    with open(os.path.join(pil_build.OUT, "summary.json")) as f:
        figs = json.load(f)
    print("\nThe images against their boards (make pil: flash .text + .data, RAM .data + .bss + stack region)\n")
    print("| image | flash: goal, ours | RAM: board, ours |\n|---|---|---|")
    for name, f in figs.items():
        print("| %s | %s, %d B | %d B, %d B (%s) |" % (
            name, "<= %d B" % f["flash_limit_bytes"] if f["flash_limit_bytes"] else "-", f["flash_bytes"],
            f["ram_limit_bytes"], f["ram_bytes"], "fits" if f["flash_fits"] and f["ram_fits"] else "does not fit"))
    print("| %s on the 11x11 table (fps hil, 5 s) | runs | %s |" % (pil_build.SMALL_MEM.name, _small_board_run()))


def _small_board_run():
    """A 5 s fps hil with the 11x11 table on the 24 KB board: "runs", or the error it stopped with."""
    import contextlib
    import io
    from ground import cli
    from tools import pil_build
    sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
    import firmware_plant
    target = pil_build.TARGET_MEM
    err = io.StringIO()
    with tempfile.TemporaryDirectory() as tmp:
        with open(os.path.join(tmp, "cal.json"), "w") as f:
            json.dump(firmware_plant.calibration(), f)
        _fps("distfile", "generate", "--source", "stat", "--duration", "5", "--seed", "1", "-o",
             os.path.join(tmp, "d.dist"))
        pil_build.TARGET_MEM = pil_build.SMALL_MEM
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                rc = cli.main(["hil", "--distfile", os.path.join(tmp, "d.dist"), "--calibration",
                               os.path.join(tmp, "cal.json"), "--duration", "5", "--runtime", "qemu", "--quiet",
                               "--no-plots", "-o", os.path.join(tmp, "hil")])
            summary = os.path.join(tmp, "hil", "summary.json")
            t = (json.load(open(summary)).get("target") or {}) if os.path.exists(summary) else {}
        finally:
            pil_build.TARGET_MEM = target
    text = err.getvalue().strip()
    if rc != 0:
        return "exit %d: %s (missed)" % (rc, text[text.find("File"):].split(" [")[0] if "File" in text else text[-200:])
    from tools import pil_mailbox
    room = pil_build.SMALL_MEM.stack_bytes - 4 * pil_mailbox.WORDS      # the stack region above the mailbox
    hw = t.get("stack_high_water_bytes")
    if hw is None or hw >= room:
        return "runs, but its stack reached the mailbox (high water %s of %d B above it) (missed)" % (hw, room)
    return "runs, its stack's high water %d of the %d B above the mailbox (met)" % (hw, room)


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
