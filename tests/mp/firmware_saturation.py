# Runs under micropython (tests/test_firmware_saturation.py also imports it under CPython for the reference):
# a Q1 spot far off centre drives the integral law onto its clamp; the bytecode Controller and the
# ViperController, fed the same samples, step with the heap locked (an allocation raises MemoryError) through
# the saturation run, the entry into SATURATED, a beam dropout on the clamp, the return to TRACK when the error
# reverses, and a second, short run; with the argument ``acquire``, the beam lost on the clamp (ACQUIRE: the run
# ends, the hold, the ramp to the centre), a dropout within the beam's return, and TRACK again. Prints one JSON
# line: per-tick modes, counters, CTRL_STATUS at three instants, word CRCs, state mismatches between the two
# controllers, bytes allocated while locked.
import gc
import json
import sys
from binascii import crc32

import firmware_plant as fp
from firmware.controller import TRACK, Controller, heap_lock, heap_unlock   # micropython's, or no-ops
from protocol import core, htable

try:
    from firmware.controller_viper import ViperController
except ImportError:  # CPython: the bytecode controller on both sides gives the reference
    ViperController = Controller

LIMIT_CODE = 2000
FAR = (2048 - 500, 2048 + 500, 2500)       # Rx = +0.2, Ry = -0.2: the law walks off one way every tick
BACK = (2048 + 500, 2048 - 500, 2500)      # the error reversed: the command comes off the clamp at once
DARK = (2048 - 500, 2048 + 500, 10)        # the beam below threshold: hold
CENTRE = (2048, 2048, 2500)
SCRIPT = ((CENTRE, 40), (FAR, 150), (DARK, 20), (FAR, 100), (BACK, 3), (FAR, 30), (BACK, 5), (CENTRE, 40))
STATUS_AT = (250, 311)                     # CTRL_STATUS after these ticks (SATURATED, back in TRACK) and at the end
ACQUIRE_SCRIPT = ((CENTRE, 40), (FAR, 150), (DARK, 400), (CENTRE, 30), (DARK, 1), (CENTRE, 100), (FAR, 20))
ACQUIRE_STATUS_AT = (300, 600)             # in ACQUIRE holding on the clamp, then ramping to the centre
ACQUIRE_KW = {"centre_ticks": 300}


def samples(script=SCRIPT):
    flat = []
    for smp, n in script:
        for _ in range(n):
            flat.extend(smp)
    return flat


def run(acquire=False):
    grid = htable.grid_from_calibration(fp.calibration())
    kw = ACQUIRE_KW if acquire else {}
    a = Controller(table=grid, limit_code=LIMIT_CODE, safe_ticks=1000, **kw)
    b = ViperController(table=grid, limit_code=LIMIT_CODE, safe_ticks=1000, **kw)
    for c in (a, b):
        c.step(2048, 2048, 0)              # the init tick
        c.mode = TRACK
    src = samples(ACQUIRE_SCRIPT if acquire else SCRIPT)
    n = len(src) // 3
    modes = bytearray(n)
    words = [0] * (8 * n)
    bad = [0]
    statuses = []
    sa = a._s
    sb = b._s
    size = len(sa)
    alloc = 0
    k = 0
    for stop in (ACQUIRE_STATUS_AT if acquire else STATUS_AT) + (n,):
        gc.collect()
        m0 = gc.mem_alloc() if hasattr(gc, "mem_alloc") else 0
        heap_lock()
        try:
            while k < stop:
                i = 3 * k
                a.step(src[i], src[i + 1], src[i + 2])
                b.step(src[i], src[i + 1], src[i + 2])
                modes[k] = a.mode
                wa = a.words
                wb = b.words
                j = 8 * k
                for e in range(4):
                    words[j + e] = wa[e]
                    words[j + 4 + e] = wb[e]
                e = 0
                while e < size:
                    if sa[e] != sb[e]:
                        bad[0] += 1
                    e += 1
                k += 1
        finally:
            heap_unlock()
        alloc += (gc.mem_alloc() if hasattr(gc, "mem_alloc") else 0) - m0
        pa = a.status_payload(stop)
        statuses.append(core.payload_dict(core.PACKET_ID["CTRL_STATUS"], pa))
        if pa != b.status_payload(stop):
            bad[0] += 1
    crc_a = 0
    crc_b = 0
    buf = bytearray(3)
    for k in range(n):
        for e in range(4):
            for w, which in ((words[8 * k + e], 0), (words[8 * k + 4 + e], 1)):
                buf[0] = w >> 16
                buf[1] = (w >> 8) & 0xFF
                buf[2] = w & 0xFF
                if which == 0:
                    crc_a = crc32(buf, crc_a)
                else:
                    crc_b = crc32(buf, crc_b)
    return {"ticks": n, "modes": list(modes), "mismatch": bad[0], "alloc_bytes": alloc,
            "crc": crc_a & 0xFFFFFFFF, "crc_viper": crc_b & 0xFFFFFFFF, "status": statuses,
            "counters": [a.n_sat, a.sat_run, a.sat_last, a.n_sat_episodes, a.mode, a.why, a.n_lost]}


if __name__ == "__main__":
    print(json.dumps(run(len(sys.argv) > 1 and sys.argv[1] == "acquire")))
