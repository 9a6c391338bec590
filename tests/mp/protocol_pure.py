"""Pure protocol modules under MicroPython and CPython: prints one line per result so the test can
compare both interpreters byte for byte (deterministic LCG data, no random module)."""

from protocol import can, core, isotp, stream  # noqa: F401  (stream: must import on both)

_state = [12345]


def lcg_bytes(n):
    out = bytearray(n)
    for i in range(n):
        _state[0] = (_state[0] * 1103515245 + 12345) & 0x7FFFFFFF
        out[i] = (_state[0] >> 16) & 0xFF
    return bytes(out)


def hexs(b):
    return "".join("%02x" % x for x in b)


for n in (0, 1, 5, 100, 253, 254, 255, 600):
    d = lcg_bytes(n)
    if n % 2:
        d = d[: n // 2] + bytes(n - n // 2)
    print("crc", n, core.crc16(d), core.crc32(d), hexs(core.cobs_encode(d)))
    print("cobs_rt", n, core.cobs_decode(core.cobs_encode(d)) == d)
for pid in sorted(core.PACKET):
    pkt = core.PACKET[pid]
    payload = lcg_bytes(pkt.size)
    frames = can.encode_frames(pid, 0x10, 0x01, payload)
    print("can", pkt.name, " ".join("%08x:%s" % (cid, hexs(f)) for cid, f in frames))
    dec = can.CanDecoder()
    got = [dec.feed(cid, f) for cid, f in frames][-1]
    print("can_rt", pkt.name, got == (pid, 0x10, 0x01, None, payload))
    print("frame", pkt.name, hexs(core.encode_frame(pid, 0x10, 0x01, pid, payload)))
ch = isotp.IsoTp()
out = None
for f in isotp.segment(lcg_bytes(300)):
    out = ch.feed(f)
print("isotp", len(out), hexs(out[:16]), ch.errors["bad_seq"])
