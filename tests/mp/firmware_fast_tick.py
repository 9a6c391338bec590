# Runs under micropython: a board's link with the common TICK in machine code (firmware.hal.fast_tick through
# firmware.hal.stdio's answer_ticks) answers a stream of bench frames with the same bytes, the same controller
# state and the same link counters as the same link without it (serve_controller's bytecode path), through
# everything a harness does to a stream: a resent TICK, a gap, a stale TICK, a damaged frame, a sequence gap, a
# TICK beyond the ADC, one to another node and one broadcast, a settings change, a new session (HELLO, ticks from
# 0), an oversized frame, and CTRL_STATUS every 64 ticks. And the common tick allocates nothing (heap locked).
import json
import struct
import sys
from array import array

import micropython

import firmware_plant as fp
from firmware.controller import S_BXQ, S_BYQ, TRACK, Controller
from firmware.controller_viper import ViperController
from firmware.hal import fast_status, fast_tick
from firmware.hal.link import serve_controller
from firmware.hal.stdio import StdioLink
from protocol import consts, core, frame, htable

BENCH = consts.NODE_BENCH
ME = consts.NODE_CONTROLLER


class End(Exception):
    pass


class Wire:
    """A board's UART driver over a list of frames: ``read_frame`` copies the next into buf (bytes beyond n
    dropped, its length returned, as ``firmware.hal.nrf51.read_frame``); ``write_frame`` keeps what is sent. Neither
    allocates: the link's machine-code path runs them with the heap locked."""

    def __init__(self, frames):
        self.frames = frames
        self.i = 0
        self.buf = bytearray(64 * 1024)
        self.n = 0
        self.end = End()

    def read_frame(self, buf, n):
        if self.i >= len(self.frames):
            raise self.end
        f = self.frames[self.i]
        self.i += 1
        j = 0
        while j < len(f) and j < n:
            buf[j] = f[j]
            j += 1
        return len(f)

    def write_frame(self, buf, n):
        j = 0
        k = self.n
        while j < n:
            self.buf[k + j] = buf[j]
            j += 1
        self.n = k + n

    @property
    def out(self):
        return self.buf[:self.n]


def samples(n, seed):
    """Q1 samples of a closed loop on the test plant (a reference controller)."""
    grid = htable.grid_from_calibration(fp.calibration())
    c = Controller(table=grid, safe_ticks=65535)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    p = fp.Plant(seed=seed)
    out = array("H", bytearray(6 * n))
    for k in range(n):
        s = p.sample()
        out[3 * k:3 * k + 3] = array("H", s)
        p.apply(c.on_tick(k, 0, s[0], s[1], s[2]))
    return out


def stream(n, seed, events=True):
    """The bench's frames: n TICKs, with the harness's events along the way if ``events``."""
    enc = core.Encoder()
    q1 = samples(n, seed)
    frames = []
    seq = [0]

    def pkt(name, dst=ME, src=BENCH, payload=None, **f):
        seq[0] = (seq[0] + 1) & 0xFF
        if payload is None:
            payload = core.encode_payload(name, **f)
        frames.append(bytes(enc.frame(core.PACKET_ID[name], src, dst, seq[0], payload)))

    def tick(k, dst=ME, vs=None):
        vx, vy, v = q1[3 * (k % n):3 * (k % n) + 3]
        pkt("TICK", dst=dst, payload=struct.pack(consts.FMT_TICK, k, 0, vx, vy, v if vs is None else vs))

    base = 0
    for k in range(n):
        t = k - base
        if not events:
            tick(t)
            continue
        if k == 100:
            tick(t - 1)                              # the answer to t - 1 was lost: resent
        if 200 <= k < 203:
            continue                                 # three ticks the bench ran without us
        if k == 300:
            tick(t - 50)                             # a stale TICK
        if k == 400:
            tick(t)
            f = bytearray(frames[-1])
            f[6] ^= 0x40                             # damaged on the wire: dropped (bad CRC), then resent
            frames[-1] = bytes(f)
        if k == 500:
            pkt("CTRL_SETTINGS", src=consts.NODE_GROUND, mode=TRACK, gain=12000, safe_ticks=638)
        if k == 600:
            seq[0] = (seq[0] + 2) & 0xFF             # two frames lost: a sequence gap
        if k == 700:
            tick(t, vs=4096)                         # beyond the 12-bit ADC: dropped, then the right one
        if k == 800:
            tick(t, dst=consts.NODE_PLAYER)          # to another node: not ours
        if k == 900:
            pkt("HELLO", node=BENCH)                 # a new session: ticks start again
            base = k
            t = 0
        if k == 1000:
            frames.append(b"\x01" * 300 + b"\x00")   # longer than any frame
        if k == 1100:
            tick(t, dst=consts.NODE_BROADCAST)
            continue
        tick(t)
    return frames


def serve(frames, fast):
    grid = htable.grid_from_calibration(fp.calibration())
    c = ViperController(table=grid, safe_ticks=638)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    w = Wire(frames)
    answered = [0]

    def counted(lk, ctl, n, last):
        r = fast_tick.answer(lk, ctl, n, last)
        if r:
            answered[0] += 1
        return r
    lk = StdioLink(ME, read_frame=w.read_frame, write_frame=w.write_frame, fast=counted if fast else None,
                   status=fast_status.status)
    try:
        serve_controller(c, lk)
    except End:
        pass
    return c, lk, w, answered[0]


def locked(ticks):
    """The common tick with the heap locked, over ``ticks`` ticks (bins change along the way; a CTRL_STATUS every
    64th, left to the bytecode path): the ticks answered and the new H^-1 bins among them."""
    frames = stream(ticks, 3, events=False)
    c, lk, w, _ = serve(frames[:2], True)            # the first ticks through the bytecode path: the sequence known
    c.decim = 0                                      # no CTRL_STATUS: every tick is a common one
    n_ok = 0
    bins = 0
    last = 1
    s = c._s
    for f in frames[2:]:
        fr = lk._frame
        for j in range(len(f)):
            fr[j] = f[j]
        b = (s[S_BXQ], s[S_BYQ])
        micropython.heap_lock()
        try:
            k = fast_tick.answer(lk, c, len(f), last)
        finally:
            micropython.heap_unlock()
        if k:
            n_ok += 1
            last += 1
        if b != (s[S_BXQ], s[S_BYQ]):
            bins += 1
    return n_ok, bins


def status_resend():
    """A resent CTRL_STATUS tick (128: its answer lost) answered by both paths: the same bytes, twice the status."""
    frames = stream(140, 5, events=False)
    frames.insert(129, frames[128])                  # TICK 128 again: the bench resends it
    a, b = serve(frames, True)[2], serve(frames, False)[2]
    ids = [frame.cobs_decode_pure(f)[1] for f in bytes(a.out).split(b"\x00")[:-1]]
    return bytes(a.out) == bytes(b.out) and ids.count(consts.P_CTRL_STATUS) == 4    # ticks 0, 64, 128 and 128


def main(n):
    frames = stream(n, 1)
    ca, la, wa, fast_n = serve(frames, True)
    cb, lb, wb, _ = serve(frames, False)
    same = {
        "bytes": bytes(wa.out) == bytes(wb.out),
        "state": list(ca._s) == list(cb._s),
        "counters": la.counters() == lb.counters(),
        "telemetry": [ca.n_dup, ca.n_gap, ca.n_rx_drop, ca.mode] == [cb.n_dup, cb.n_gap, cb.n_rx_drop, cb.mode],
    }
    print(json.dumps({"same": same, "frames": len(frames), "answered_fast": fast_n, "tx_bytes": len(wa.out),
                      "counters": la.counters(), "n_dup": ca.n_dup, "n_gap": ca.n_gap, "mode": ca.mode,
                      "locked": locked(600), "status_resend": status_resend()}))


main(int(sys.argv[1]) if len(sys.argv) > 1 else 1300)
