# Runs under micropython: the player's per-update path allocates nothing. Plays distfiles (argv: paths) in
# LOOP mode one update per fill() call, as a 10.6 kHz timer would, with the heap locked (any allocation
# raises MemoryError): streamed from the filesystem (Reader) and from memory (parse), float32 and int32
# kinds, through many segment crossings and loop wraps. gc.mem_alloc() must not grow either. A positive
# control: the float conversion this replaced (ad660.arcsec_to_code_q2) fails under the lock.
import gc
import json
import sys

import micropython

from firmware import ad660
from firmware.player import Player
from protocol import distfile


def play(p, xb, yb, n, st):
    # st: [crc, crossings, last index, updates]; small ints only
    crc = st[0]
    crossings = st[1]
    last = st[2]
    done = 0
    while done < n:
        if not p.fill(xb, yb, 1):
            break
        crc = (crc * 31 + xb[0] * 65536 + yb[0]) & 0x3FFFFFF
        if p.index != last:
            crossings += 1
            last = p.index
        done += 1
    st[0] = crc
    st[1] = crossings
    st[2] = last
    st[3] += done


def float_conversion(x, out):
    out[0] = ad660.arcsec_to_code_q2(x)


def main():
    n = int(sys.argv[1])
    res = []
    for path in sys.argv[2:]:
        for mode in ("file", "memory"):
            if mode == "file":
                f = open(path, "rb")
                p = Player(distfile.Reader(f))
            else:
                with open(path, "rb") as f:
                    p = Player(distfile.parse(f.read()))
            p.play_loop()
            xb = [0]
            yb = [0]
            st = [0, 0, p.index, 0]
            play(p, xb, yb, 10, st)          # warm up (first calls may intern or cache)
            gc.collect()
            a0 = gc.mem_alloc()
            micropython.heap_lock()
            err = None
            try:
                play(p, xb, yb, n, st)
            except MemoryError:
                err = "MemoryError"
            micropython.heap_unlock()
            a1 = gc.mem_alloc()
            res.append({"path": path, "mode": mode, "kind": p.reader.kind, "updates": st[3],
                        "crossings": st[1], "alloc_bytes": a1 - a0, "error": err, "hash": st[0]})
    out = [0]
    caught = False
    micropython.heap_lock()
    try:
        float_conversion(123.456, out)
    except MemoryError:
        caught = True
    micropython.heap_unlock()
    print(json.dumps({"runs": res, "float_path_caught": caught}))


main()
