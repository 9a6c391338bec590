"""Viper fast paths against the pure reference, under MicroPython: ``protocol_fast.py GOLDEN N``.

Prints one JSON line of counts (cases compared, mismatches by kind) for tests/test_protocol_mp.py.
N random bodies (seeded, zero-heavy every third), COBS of arbitrary bytes, whole frames (Encoder vs
encode_frame with the pure functions), a damaged stream fed in random chunks through the fast and the
pure Decoder, and the golden frames of GOLDEN.
"""

import json
import random
import sys

from protocol import core

PURE_DEC = (core.crc16_pure, core.cobs_decode_pure)
random.seed(7)
bad = {"crc16": 0, "crc16_chain": 0, "cobs_encode": 0, "cobs_decode": 0, "cobs_garbage": 0, "frame": 0,
       "decoder": 0, "counters": 0, "golden_encode": 0, "golden_decode": 0}
n_cases = int(sys.argv[2])
lengths = [0, 1, 2, 253, 254, 255, 256, 262, 507, 508, 509, 600]


def rbytes(n, zeros):
    b = bytearray(n)
    for i in range(n):
        b[i] = 0 if zeros and random.getrandbits(2) == 0 else random.getrandbits(8)
    return bytes(b)


enc = core.Encoder()
stream = bytearray()
for i in range(n_cases):
    n = lengths[i % len(lengths)] if i < 4 * len(lengths) else random.getrandbits(9) % 300
    d = rbytes(n, i % 3 == 0)
    if core.crc16(d) != core.crc16_pure(d):
        bad["crc16"] += 1
    if core.crc16(d, i & 0xFFFF) != core.crc16_pure(d, i & 0xFFFF):
        bad["crc16_chain"] += 1
    e = core.cobs_encode(d)
    if e != core.cobs_encode_pure(d):
        bad["cobs_encode"] += 1
    if core.cobs_decode(e) != core.cobs_decode_pure(e) or core.cobs_decode(e) != d:
        bad["cobs_decode"] += 1
    g = rbytes(n, True)          # arbitrary bytes: mostly invalid COBS, both must say None
    if core.cobs_decode(g) != core.cobs_decode_pure(g):
        bad["cobs_garbage"] += 1
    p = d[:core.MAX_PAYLOAD]
    pid, src, dst, seq = random.getrandbits(8), random.getrandbits(8), random.getrandbits(8), i
    ref = core.encode_frame(pid, src, dst, seq, p, core.crc16_pure, core.cobs_encode_pure)
    if bytes(enc.frame(pid, src, dst, seq, p)) != ref or core.encode_frame(pid, src, dst, seq, p) != ref:
        bad["frame"] += 1
    if i % 4 == 0:               # stream material: valid table packets, some damaged, some garbage
        q = core.PACKET[sorted(core.PACKET)[i % len(core.PACKET)]]
        f = bytearray(enc.frame(q.id, src, dst, seq, rbytes(q.size, i % 8 == 0)))
        if i % 5 == 0:
            f[random.getrandbits(8) % (len(f) - 1)] ^= 1 + random.getrandbits(7)
        stream.extend(f)
        if i % 7 == 0:
            stream.extend(g)
stream.extend(bytes(300) + b"\x01" * 300 + b"\x00")   # also an oversize frame
stream = bytes(stream)
fast, pure = core.Decoder(), core.Decoder(*PURE_DEC)
mv = memoryview(stream)
out_f, out_p = [], []
i = 0
while i < len(stream):
    c = 1 + random.getrandbits(7)
    out_f += fast.feed(mv[i:i + c])
    out_p += pure.feed(stream[i:i + c])
    i += c
bad["decoder"] = int(out_f != out_p)
bad["counters"] = int(fast.counters() != pure.counters())

n_golden = 0
for line in open(sys.argv[1]):
    if not line.strip() or line.startswith("#"):
        continue
    name, src, dst, seq, frame, _ = line.split(" ", 5)
    frame = bytes.fromhex(frame)
    got = core.Decoder().feed(frame)
    if got != core.Decoder(*PURE_DEC).feed(frame) or len(got) != 1:
        bad["golden_decode"] += 1
        continue
    pid, s, d, q, payload = got[0]
    if bytes(enc.frame(pid, s, d, q, payload)) != frame:
        bad["golden_encode"] += 1
    n_golden += 1

print(json.dumps({"fast": core.FAST, "cases": n_cases, "stream_packets": len(out_p),
                  "drops": sum(pure.drops.values()), "golden": n_golden, "bad": bad}))
