# Runs under micropython (the unix port, and frozen on the PIL lab board): the machine-code CTRL_STATUS
# (firmware.hal.fast_status.status) frames Controller.status_payload's bytes, over states drawn to reach every
# field's range (negative tilt codes, ratios beyond int16, counters past 16 bits, the clamp's ends, no table), with a
# valid CRC-16 and header, and allocates nothing (heap locked).
import json
import sys
from array import array

import micropython

import firmware_plant as fp
from firmware.controller import Controller
from firmware.controller_viper import ViperController
from firmware.hal import fast_status
from protocol import consts, frame, htable

ME = consts.NODE_CONTROLLER


class Link:
    """The link's buffers ``status`` uses (firmware.hal.stdio.StdioLink's)."""

    def __init__(self):
        self.node = ME
        self._stat = bytearray(frame.HEADER_SIZE + consts.SIZES[consts.P_CTRL_STATUS] + frame.CRC_SIZE)
        self._out = bytearray(frame.frame_bytes(consts.LARGEST_PAYLOAD))
        self._st = array("i", [0, 0, 0, -1, -1, 0, 4, 0])


class Draw:
    """A linear congruential generator: the same draws on every port."""

    def __init__(self, seed):
        self.x = seed

    def __call__(self, lo, hi):
        self.x = (self.x * 1103515245 + 12345) & 0x7FFFFFFF
        return lo + (self.x >> 4) % (hi - lo + 1)


def pick(r, lo, hi):
    """A value in [lo, hi], its ends and 0 drawn often."""
    k = r(0, 5)
    return (lo, hi, 0 if lo <= 0 <= hi else lo, lo + 1 if lo < hi else lo)[k] if k < 4 else r(lo, hi)


def state(c, r):
    """Draw the controller's telemetry state."""
    s = c._s
    lim = 32767 << 8
    s[0] = r(0, 6)                                   # mode (the init bit off)
    s[1] = pick(r, 0, 0x3FFFFFFF)                    # ticks
    s[2] = pick(r, -lim, lim)                        # command, Q8
    s[3] = pick(r, -lim, lim)
    s[4] = pick(r, -(1 << 26), 1 << 26)              # ratios, Q15 (beyond int16: clamped)
    s[5] = pick(r, -(1 << 26), 1 << 26)
    s[6] = r(0, 4095)                                # vs
    s[8] = r(1, 4095)                                # beam threshold
    s[17] = s[1] if r(0, 1) else pick(r, -1, 100)    # saturated on the last tick, or not
    s[18] = pick(r, 0, 0xFFFF)
    s[19] = pick(r, 0, 0x3FFFFFFF)
    s[28] = pick(r, 0, 0x3FFFFFFF)
    s[29] = pick(r, 0, 0x3FFFFFFF)
    s[30] = pick(r, 0, 0xFFFF)
    w = c.words
    for i in range(4):
        w[i] = r(0, 0x1FFFFF)
    c.n_unknown = pick(r, 0, 0xFFFF)
    c.why = r(0, 3)
    c.n_dup = pick(r, 0, 1 << 20)                    # the status keeps their low 16 bits
    c.n_gap = pick(r, 0, 1 << 20)
    c.n_rx_drop = pick(r, 0, 1 << 20)


def check(n, seed):
    grid = htable.grid_from_calibration(fp.calibration())
    c = ViperController(table=grid)
    lk = Link()
    r = Draw(seed)
    bad = 0
    fields = 0
    for k in range(n):
        state(c, r)
        table = c.table
        if k % 7 == 3:
            c.table = None                           # flags without the table
        tick = pick(r, 0, 0x3FFFFFFF)
        lk._st[3] = r(0, 255)                        # the TICK's source: the status's destination
        micropython.heap_lock()
        try:
            m = fast_status.status(lk, c, tick)
        finally:
            micropython.heap_unlock()
        body = frame.cobs_decode_pure(bytes(lk._out[:m - 1]))
        want = Controller.status_payload(c, tick)
        c.table = table
        ok = (lk._out[m - 1] == 0 and frame.crc16_pure(body[:-2]) == (body[-2] << 8 | body[-1])
              and body[:5] == bytes((consts.PROTOCOL_VERSION, consts.P_CTRL_STATUS, ME, lk._st[3], k & 0xFF))
              and body[5:-2] == want)
        if not ok:
            bad += 1
        fields += len(want)
    return {"n": n, "mismatch": bad, "bytes": fields, "tx_frames": lk._st[1], "tx_seq": lk._st[0]}


ARGV = getattr(sys, "argv", None) or []
print(json.dumps(check(int(ARGV[1]) if len(ARGV) > 1 else 400, 7)))
