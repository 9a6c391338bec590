# Runs on the PIL lab board (QEMU's microbit machine, a Cortex-M0; tools/pil_build.py) under -icount shift=0: the
# disturbance player (firmware/player.py, the thesis's SimArduino) playing a distfile from memory, one update per
# fill() call as its 10.6 kHz timer would run it. ``counts(n)`` gives the instructions per update (mean and the
# largest, a new segment's), each less the same loop without the update, and the heap in use once it plays; the
# DAC's SPI writes are not in it.
import gc
import math

from array import array

from firmware.hal import nrf51
from firmware.player import Player
from firmware.player_viper import ViperPlayer
from protocol import distfile

INSN_PER_TICK = nrf51.INSN_PER_TICK


def _distfile(n=400, period_us=8192):
    """A two-tone pointing error, 400 samples at Ts = 8.192 ms (3.3 s), float32 samples."""
    xs = [20.0 * math.sin(2 * math.pi * 0.7 * k * period_us * 1e-6) + 2.0 * math.sin(0.9 * k) for k in range(n)]
    ys = [-15.0 * math.cos(2 * math.pi * 0.5 * k * period_us * 1e-6) + 1.5 * math.sin(1.3 * k) for k in range(n)]
    return distfile.pack(xs, ys, period_us=period_us)


def _now():
    return nrf51.now() & 0xFFFF


def _buffers(viper, size):
    if viper:
        return array("H", [0] * size), array("H", [0] * size)
    return [0] * size, [0] * size


def counts(n=2000, viper=False):
    """Instructions per update: mean over n and the largest, one fill(xb, yb, 1) at a time (the loop's own cost
    taken off); the heap the player holds."""
    gc.collect()
    h0 = gc.mem_alloc()
    p = (ViperPlayer if viper else Player)(distfile.parse(_distfile()))
    p.play_loop()
    gc.collect()
    heap = gc.mem_alloc() - h0
    xb, yb = _buffers(viper, 1)
    fill = p.fill
    nrf51.start(16)
    total = 0
    worst = 0
    empty = 0
    for k in range(n):
        t = _now()
        fill(xb, yb, 1)
        d = (_now() - t) & 0xFFFF
        total += d
        if d > worst:
            worst = d
        t = _now()
        d = (_now() - t) & 0xFFFF
        empty += d
    own = empty / n
    return {"insn_mean": (total / n - own) * INSN_PER_TICK, "insn_max": (worst - own) * INSN_PER_TICK,
            "heap_bytes": heap, "n": n, "last": [xb[0], yb[0]], "viper": viper}


def block_counts(blocks=100, size=64, viper=False):
    """Instructions per update when the player fills blocks of ``size`` codes (a DMA channel or a timer interrupt
    then moves each code to the DACs): mean over ``blocks`` blocks, the largest block's per update."""
    p = (ViperPlayer if viper else Player)(distfile.parse(_distfile()))
    p.play_loop()
    xb, yb = _buffers(viper, size)
    fill = p.fill
    nrf51.start(32)
    total = 0
    worst = 0
    for k in range(blocks):
        t = nrf51.now() & 0xFFFFFFF
        fill(xb, yb, size)
        d = ((nrf51.now() & 0xFFFFFFF) - t) & 0xFFFFFFF
        total += d
        if d > worst:
            worst = d
    return {"insn_mean": total / blocks / size * INSN_PER_TICK, "insn_max": worst / size * INSN_PER_TICK,
            "size": size, "blocks": blocks, "viper": viper}
