# Runs under micropython: the viper player (firmware/player_viper.py) writes the same codes as the bytecode Player
# over whole plays of distfiles: LOOP (wraps) and ONESHOT (its held end), blocks of 1, 7 and 64 codes, at 10.6 kHz
# (a phase of fixed steps, shift 0) and at 10,601 Hz (a cell beyond 2^19: a division per code, shift > 0), float32
# and int32 samples with steps that drive the kernel's overshoot into the DAC's clip.
import json
import math
import sys
from array import array

from firmware.player import Player
from firmware.player_viper import ViperPlayer
from protocol import distfile


SPAN = 780.0          # arcsec: within the DAC's +-810, so only the kernel's overshoot at a step clips


def dist(kind, n=300):
    xs = [6.0 * math.sin(0.05 * k) + (SPAN if (k // 40) % 2 else -SPAN) for k in range(n)]   # steps to the clip
    ys = [-45.0 * math.cos(0.03 * k) + 3.0 * math.sin(1.7 * k) for k in range(n)]
    if kind == "int32":
        return distfile.pack(xs, ys, kind=distfile.KIND_INT32, scale=0.001)
    return distfile.pack(xs, ys)


def both(data, rate, block, oneshot, total):
    """The two players side by side, block by block: (codes compared, codes that differ, clipped codes, shift)."""
    pa = Player(distfile.parse(data), rate_hz=rate)
    pb = ViperPlayer(distfile.parse(data), rate_hz=rate)
    for p in (pa, pb):
        if oneshot:
            p.oneshot()
        else:
            p.play_loop()
    xa = [0] * block
    ya = [0] * block
    xb = array("H", [0] * block)
    yb = array("H", [0] * block)
    n = bad = clipped = 0
    while n < total:
        k = pa.fill(xa, ya, block)
        if pb.fill(xb, yb, block) != k or not k:
            bad += k
            break
        for j in range(k):
            if xa[j] != xb[j] or ya[j] != yb[j]:
                bad += 1
            if xa[j] == 0 or xa[j] == 65535:
                clipped += 1
        n += k
    return n, bad, clipped, pa._shift


def main():
    res = []
    for kind in ("float32", "int32"):
        data = dist(kind)
        for rate in (10600, 10601):
            for block in (1, 7, 64):
                for oneshot in (False, True):
                    total = 12000 if not oneshot else 10 ** 6
                    n, bad, clipped, sh = both(data, rate, block, oneshot, 12000 if not oneshot else 10 ** 6)
                    res.append({"kind": kind, "rate": rate, "block": block, "oneshot": oneshot, "shift": sh,
                                "n": n, "bad": bad, "clipped": clipped})
    print(json.dumps({"runs": res}))


main()
