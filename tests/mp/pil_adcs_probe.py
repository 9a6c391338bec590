# Runs on the ADCS PIL board (QEMU's mps2-an500: a Cortex-M7 with its FPU, tools/pil_build.py's ADCS image) under
# -icount shift=0, where one instruction takes one virtual ns. ``replay()`` reads a recorded ADCS session from the
# UART, one JSON line at a time (the App's configuration: answered "ready <instructions per timer tick> <1 if the C
# kernels are in>", then per 1 Hz cycle [tick, t_ms, [[pid, src, hex]...]],
# the format of tests/mp/firmware_adcs_app.py), runs each cycle as that script does (the cycle's packets, the
# filters and the control law, the wheel commands) and answers each with a line "c <tick> <instructions> <heap
# bytes allocated>"; then "end <heap in use> <stack high-water bytes> <the last ADCS_STATUS payload, hex>". The instructions are counted
# by the board's timer (``firmware.hal.mps2``) against a calibration of its rate in instructions (``insn_per_tick``), the cycle's
# JSON and hex decoding left out, and a GC before each cycle (not inside it).
import gc
import json
import sys

import machine
import micropython

from firmware.hal import mps2

@micropython.asm_thumb
def spin(r0):
    label(loop)  # noqa: F821
    sub(r0, 1)  # noqa: F821
    bne(loop)  # noqa: F821


def insn_per_tick(n=500000):
    """Instructions per timer tick: a loop of two instructions an iteration, timed."""
    t = mps2.count()
    spin(n)
    return 2 * n / (mps2.count() - t)


def paint_stack(words=12 * 1024):
    """0x5A5A5A5A over ``words`` words of free stack below the current use: the high-water mark is read back."""
    m = machine.mem32
    top = stack_top() - micropython.stack_use() - 256
    a = top - 4 * words
    while a < top:
        m[a] = 0x5A5A5A5A
        a += 4
    return a - 4 * words


def stack_top():
    return 4 * 1024 * 1024          # mps2.ld: the stack starts at the top of the 4 MB SSRAM


def high_water(bottom):
    m = machine.mem32
    a = bottom
    while m[a] == 0x5A5A5A5A:
        a += 4
    return stack_top() - a


def replay():
    from firmware.adcs import linalg
    from firmware.adcs.app import App
    mps2.start()
    k = insn_per_tick()
    app = App(json.loads(sys.stdin.readline()))
    bottom = paint_stack()
    print("ready %.4f %d" % (k, linalg.kernels is not None))
    u = None
    tick = 0
    while True:
        line = sys.stdin.readline()
        if not line or line.startswith("end"):
            break
        tick, t_ms, pkts = json.loads(line)
        pkts = [(pid, src, bytes.fromhex(hx)) for pid, src, hx in pkts]
        gc.collect()
        m0 = gc.mem_alloc()
        t0 = mps2.count()
        for pid, src, pl in pkts:
            app.on_packet(pid, src, pl)
        u = app.cycle(tick, t_ms / 1000.0)
        app.commands(u)
        dt = mps2.count() - t0
        print("c %d %d %d" % (tick, int(dt * k), gc.mem_alloc() - m0))
    gc.collect()
    print("end %d %d %s" % (gc.mem_alloc(), high_water(bottom), app.status_payload(tick).hex()))
