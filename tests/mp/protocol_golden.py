"""Golden vectors under MicroPython: for each line of golden_frames.txt print
``NAME encoded_hex decoded_then_reencoded_hex fields_ok|fields_differ`` using the pure core only."""

import json
import struct
import sys

from protocol import core


def hexs(b):
    return "".join("%02x" % x for x in b)


for line in open(sys.argv[1]):
    if not line.strip() or line.startswith("#"):
        continue
    name, src, dst, seq, frame, fields = line.split(" ", 5)
    src, dst, seq = int(src), int(dst), int(seq)
    pkt = core.packet_def(name)
    values = json.loads(fields)
    for f in pkt.fields:
        if f[1][-1] == "s":
            values[f[0]] = bytes.fromhex(values[f[0]])
    enc = core.encode_packet(name, src, dst, seq, values)
    dec = core.Decoder()
    got = dec.feed(bytes.fromhex(frame))
    re = b""
    ok = "fields_differ"
    if len(got) == 1:
        pid, s, d, q, payload = got[0]
        re = core.encode_frame(pid, s, d, q, payload)
        vals = core.payload_dict(pid, payload)
        ok = "fields_ok"
        for f in pkt.fields:
            a, b = vals[f[0]], values[f[0]]
            if f[1] == "f":  # compare as float32 bytes (float parsing may differ in the last double bit)
                a, b = struct.pack("<f", a), struct.pack("<f", b)
            if a != b:
                ok = "fields_differ"
    print(name, hexs(enc), hexs(re), ok)
