"""Frame throughput, for bench/bench_protocol.py: ``protocol_bench.py NAME N [pure|fast]`` prints
``frames_per_s`` for N frames of packet NAME encoded and decoded (one feed per frame). ``pure`` (default):
core.encode_frame and core.Decoder with the pure reference functions; ``fast``: the per-tick path,
core.Encoder into its buffer and core.Decoder fed a memoryview (viper under MicroPython, the same pure
code under CPython). Runs under MicroPython and CPython."""

import sys

from protocol import core

try:
    from time import ticks_diff, ticks_us
except ImportError:
    from time import perf_counter

    def ticks_us():
        return int(perf_counter() * 1e6)

    def ticks_diff(a, b):
        return a - b

name, n = sys.argv[1], int(sys.argv[2])
fast = len(sys.argv) > 3 and sys.argv[3] == "fast"
pkt = core.packet_def(name)
payload = core.encode_payload(pkt.id)
got = 0
if fast:
    dec = core.Decoder()
    enc = core.Encoder()
    t0 = ticks_us()
    for i in range(n):
        got += len(dec.feed(enc.frame(pkt.id, 0x20, 0x10, i & 0xFF, payload)))
else:
    dec = core.Decoder(core.crc16_pure, core.cobs_decode_pure)
    crc, cobs = core.crc16_pure, core.cobs_encode_pure
    t0 = ticks_us()
    for i in range(n):
        got += len(dec.feed(core.encode_frame(pkt.id, 0x20, 0x10, i & 0xFF, payload, crc, cobs)))
dt = ticks_diff(ticks_us(), t0)
assert got == n
print("frames_per_s %d" % (n * 1000000 // dt))
