"""Pure-path frame throughput, for bench/bench_protocol.py: ``protocol_bench.py NAME N`` prints
``frames_per_s`` for N frames of packet NAME encoded (core.encode_frame) and decoded (core.Decoder,
one feed per frame). Runs under MicroPython and CPython."""

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
pkt = core.packet_def(name)
payload = core.encode_payload(pkt.id)
dec = core.Decoder()
got = 0
t0 = ticks_us()
for i in range(n):
    got += len(dec.feed(core.encode_frame(pkt.id, 0x20, 0x10, i & 0xFF, payload)))
dt = ticks_diff(ticks_us(), t0)
assert got == n
print("frames_per_s %d" % (n * 1000000 // dt))
