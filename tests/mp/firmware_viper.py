# Runs under micropython: the viper controller (firmware/controller_viper.py) gives the same AD5664R words and
# the same state as the bytecode Controller on every tick of long runs fed identical inputs and packets:
# a closed loop with beam dropouts (a flicker held in TRACK; a loss through ACQUIRE, its hold, its ramp to the
# centre and the return to TRACK), mode, gain, ratio-command and table changes and a sustained saturation
# (SATURATED, a dropout within it, the return to TRACK), and a random-input run on a
# table at the fixed-point limit with a low saturation limit (clamps, saturation, beam threshold edges).
# Also: its tick allocates nothing over 10,000 ticks with the heap locked. Under CPython (tests/test_firmware_mp.py
# imports it) both sides are the bytecode Controller, which gives the reference word CRCs.
import gc
import json
import sys
from binascii import crc32

import firmware_plant as fp
from firmware.controller import CALIBRATE, HOLD, SAFE, TRACK, Controller
from protocol import core, htable

try:
    from firmware.controller_viper import ViperController
except ImportError:  # CPython (no viper): the bytecode controller on both sides gives the reference streams
    ViperController = Controller

P = core.PACKET_ID


class Counted(ViperController):
    """Counts the ticks the viper code hands to the bytecode step."""
    fallbacks = 0

    def step_bytecode(self, vx, vy, vs):
        Counted.fallbacks += 1
        return Controller.step(self, vx, vy, vs)


class Pair:
    """The two controllers side by side: every input goes to both, every output is compared."""

    def __init__(self, **kw):
        self.a = Controller(**kw)
        self.b = Counted(**kw)
        self.ticks = 0
        self.mode_ticks = [0] * 7     # IDLE .. ACQUIRE
        self.mismatch = 0
        self.crc = 0
        self.buf = bytearray(3)

    def step(self, vx, vy, vs):
        na = self.a.step(vx, vy, vs)
        nb = self.b.step(vx, vy, vs)
        wa = self.a.words
        wb = self.b.words
        same = na == nb and wa[0] == wb[0] and wa[1] == wb[1] and wa[2] == wb[2] and wa[3] == wb[3]
        if same:
            sa = self.a._s
            sb = self.b._s
            for k in range(len(sa)):
                if sa[k] != sb[k]:
                    same = False
        if not same:
            self.mismatch += 1
            if self.mismatch < 4:
                print("mismatch at tick", self.ticks, list(wa), list(wb), list(self.a._s), list(self.b._s))
        b = self.buf
        for w in wa:
            b[0] = w >> 16
            b[1] = (w >> 8) & 0xFF
            b[2] = w & 0xFF
            self.crc = crc32(b, self.crc)
        self.ticks += 1
        self.mode_ticks[self.a.mode] += 1
        return tuple(wa)

    def send(self, name, **fields):
        pl = core.encode_payload(name, **fields)
        ra = self.a.handle(P[name], 1, 1, pl)
        rb = self.b.handle(P[name], 1, 1, pl)
        assert ra == rb, (name, ra, rb)
        return ra


def closed_loop(ticks, seed):
    """`ticks` of closed loop on the test plant; packets, beam dropouts and a sustained saturation along the way."""
    grid = htable.grid_from_calibration(fp.calibration())
    pr = Pair(table=grid, safe_ticks=400, centre_ticks=300)
    pr.step(2048, 2048, 0)
    pr.send("CTRL_SETTINGS", mode=TRACK, safe_ticks=400)
    p = fp.Plant(seed=seed)
    other = htable.Grid(grid.ax, grid.ay, [(a * 1.05, b, c, d * 0.97) for a, b, c, d in grid.h])
    for k in range(ticks):
        ph = k % 6000
        p.beam = not (2000 <= ph < 2040 or 4000 <= ph < 4500)     # a flicker (hold) and a loss (ACQUIRE)
        if ph == 4200:                                             # TRACK asked in ACQUIRE: kept
            pr.send("CTRL_SETTINGS", mode=TRACK, safe_ticks=400)
        elif ph == 4640:                                           # back in TRACK since 4564: SAFE commanded
            pr.send("CTRL_SETTINGS", mode=SAFE, safe_ticks=400)
        elif ph == 4700:
            pr.send("CTRL_SETTINGS", mode=CALIBRATE, safe_ticks=400)
            pr.send("CTRL_SET_FSM", vx=300000, vy=-200000)
        elif ph == 4800:
            pr.send("CTRL_SETTINGS", mode=HOLD, safe_ticks=400)
        elif ph == 4900:
            g = 8192 + (k // 6000) * 12000
            pr.send("CTRL_SETTINGS", mode=TRACK, gain=g, rx_cmd=300 - k // 100, ry_cmd=-200, safe_ticks=400)
        elif ph == 5500:
            pr.a.set_table(other if (k // 6000) % 2 == 0 else grid)
            pr.b.set_table(other if (k // 6000) % 2 == 0 else grid)
        smp = p.sample()
        if 5600 <= ph < 5900:     # a far-off spot drives the law onto its clamp (SATURATED; a dropout within)
            smp = (2048 - 1500, 2048 + 1500, 10 if 5800 <= ph < 5830 else 2500)
        p.apply(pr.step(*smp))
    return pr


def random_run(ticks, seed, gain_q15, limit_code, sign, cmd_q15):
    """Random Q1 samples against a table at the fixed-point limit (dR clamps, beam threshold edges; with a
    high gain and a low limit_code, saturation on most ticks)."""
    m = 16000 * 0.9999 / 13107.2            # H^-1 entries at HINV_MAX (V per unit ratio), with cross terms
    a, b, c, d = sign * m, 0.3 * m, -0.2 * m, m
    det = a * d - b * c
    pr = Pair(table=htable.Grid([-2.4, 2.4], [-2.4, 2.4], [(d / det, -b / det, -c / det, a / det)] * 4),
              gain_q15=gain_q15, limit_code=limit_code, rx_cmd_q15=cmd_q15, ry_cmd_q15=-cmd_q15, safe_ticks=65535)
    pr.step(2048, 2048, 0)
    pr.a.mode = TRACK
    pr.b.mode = TRACK
    x = seed
    for k in range(ticks):
        x = (1103515245 * x + 12345) & 0x7FFFFFFF
        vx = (x >> 4) & 4095
        x = (1103515245 * x + 12345) & 0x7FFFFFFF
        vy = (x >> 4) & 4095
        x = (1103515245 * x + 12345) & 0x7FFFFFFF
        vs = 195 + ((x >> 4) & 15) if k % 3 == 0 else (x >> 4) & 4095    # often right at the threshold
        pr.step(vx, vy, vs)
    return pr


def locked_alloc(n):
    """gc.mem_alloc() over n viper ticks with the heap locked (an allocation would raise MemoryError)."""
    import micropython
    from pil_probe import recorded_loop           # the PIL board's replay, on this port's viper controller
    c, src = recorded_loop(ViperController, 2000)
    m = len(src)
    gc.collect()
    a0 = gc.mem_alloc()
    micropython.heap_lock()
    i = 0
    for k in range(n):
        c.step(src[i], src[i + 1], src[i + 2])
        i += 3
        if i >= m:
            i = 0
    micropython.heap_unlock()
    return gc.mem_alloc() - a0


if __name__ == "__main__":
    ticks = int(sys.argv[1]) if len(sys.argv) > 1 else 19134
    cl = closed_loop(ticks, 3)
    fb_closed = Counted.fallbacks
    out = {"closed": {"ticks": cl.ticks, "mismatch": cl.mismatch, "crc": cl.crc & 0xFFFFFFFF,
                      "fallbacks": fb_closed, "n_lost": cl.a.n_lost, "mode_ticks": cl.mode_ticks}}
    for name, gain, lim, sign, cmd in (("saturating", 65535, 3000, 1.0, 16384), ("moderate", 1500, 32767, -1.0, 0)):
        f0 = Counted.fallbacks
        rr = random_run(ticks, 7, gain, lim, sign, cmd)
        out[name] = {"ticks": rr.ticks, "mismatch": rr.mismatch, "crc": rr.crc & 0xFFFFFFFF,
                     "fallbacks": Counted.fallbacks - f0, "n_sat": rr.a.n_sat, "n_lost": rr.a.n_lost,
                     "mode_ticks": rr.mode_ticks, "n_sat_episodes": rr.a.n_sat_episodes}
    out["alloc_bytes"] = locked_alloc(10000)
    print(json.dumps(out))
