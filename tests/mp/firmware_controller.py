# Runs under micropython: the controller's unit checks on this runtime, and a 10 s closed-loop run whose
# AD5664R word stream (CRC-32 over the 24-bit words) the CPython side recomputes and compares.
import json
import sys
from binascii import crc32

import firmware_plant as fp
from firmware import ad5664r
from firmware.controller import ACQUIRE, CALIBRATE, TRACK, Controller
from protocol import core, htable

P = core.PACKET_ID
checks = 0


def check(cond, what):
    global checks
    if not cond:
        raise AssertionError(what)
    checks += 1


def closed_loop(ticks, seed):
    """The CRC-32 of every word sent over `ticks` ticks of TRACK against the test plant, and the last words."""
    c = Controller(table=htable.grid_from_calibration(fp.calibration()))
    c.step(2048, 2048, 0)
    c.mode = TRACK
    p = fp.Plant(seed=seed)
    crc = 0
    b = bytearray(3)
    for k in range(ticks):
        words = c.on_tick(k, 0, *p.sample())
        for w in words:
            b[0] = w >> 16
            b[1] = (w >> 8) & 0xFF
            b[2] = w & 0xFF
            crc = crc32(b, crc)
        p.apply(words)
    return crc & 0xFFFFFFFF, list(c.words), c.mode


if __name__ == "__main__":
    ticks = int(sys.argv[1]) if len(sys.argv) > 1 else 6378
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    grid = htable.grid_from_calibration(fp.calibration())

    c = Controller(table=grid)
    c.step(2048, 2048, 2500)
    check(c.words == list(ad5664r.INIT_WORDS), "init sequence first")
    c.step(2048, 2048, 2500)
    check([ad5664r.decode(w)[:2] for w in c.words] == [(0, 0), (0, 1), (0, 3), (2, 2)], "word order")
    r = c.handle(P["CTRL_SETTINGS"], 1, 5, core.encode_payload("CTRL_SETTINGS", mode=CALIBRATE))
    check(r[0][0] == P["ACK"], "settings ACK")
    c.handle(P["CTRL_SET_FSM"], 1, 6, core.encode_payload("CTRL_SET_FSM", vx=2500000, vy=-2500000))
    c.step(2048, 2048, 2500)
    codes = [w & 0xFFFF for w in c.words]
    check(codes == [0x8000 + 32767, 0x8000 - 32767, 0x8000 - 32767, 0x8000 + 32767], "full-scale codes")
    check(c.handle(0x77, 1, 1, b"") == [] and c.n_unknown == 1, "unknown counted")
    # a corrupt upload keeps the table
    before = c.table
    blob = bytearray(htable.pack(grid))
    blob[20] ^= 0xFF
    c.handle(P["HTABLE_BEGIN"], 1, 1, core.encode_payload("HTABLE_BEGIN", total=len(blob), crc32=crc32(blob)))
    for off in range(0, len(blob), 48):
        part = bytes(blob[off:off + 48])
        c.handle(P["HTABLE_CHUNK"], 1, 1, core.encode_payload("HTABLE_CHUNK", offset=off, length=len(part),
                                                              data=part))
    r = c.handle(P["HTABLE_END"], 1, 1, core.encode_payload("HTABLE_END", total=len(blob)))
    check(r[0][0] == P["NACK"] and r[0][2][2] == core.ERROR["BAD_CONTENT"] and c.table is before, "refused")
    # beam loss -> ACQUIRE -> the beam back -> TRACK
    c = Controller(table=grid, acq_ticks=10)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    for k in range(10):
        c.on_tick(k, 0, 2048, 2048, 3)
    m = c.mode
    for k in range(10):
        c.on_tick(k, 0, 2048, 2048, 2500)
    check(m == ACQUIRE and c.mode == TRACK and c.why == 1, "beam loss enters ACQUIRE, the beam back TRACK")
    # hinv reference path agrees with the inlined one: a single TRACK step from the centre
    t = c.table
    h = t.hinv_at(0, 0)
    c = Controller(table=grid, gain_q15=32768)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    c.on_tick(0, 0, 2048 - 100, 2048, 2000)   # Rx = 100/2000 = 0.05 -> 1638 Q15
    dv = -((h[0] * 1638 + (1 << (t.shift - 1))) >> t.shift)
    check(c.vx_q8 == dv, "law step %d != %d" % (c.vx_q8, dv))

    table = None
    if len(sys.argv) > 3:        # the calibration JSON file, loaded from this runtime's filesystem
        t = Controller(table=sys.argv[3]).table
        table = {"h": t.h, "ax": t.ax, "ay": t.ay, "hq": t.hq}
    crc, last, mode = closed_loop(ticks, seed)
    print(json.dumps({"checks": checks, "crc": crc, "last": last, "mode": mode, "table": table}))
