"""Frame-decoder fuzzing against an independent reference, and random packets for the protocol tests.

    python -m tests.fuzz_frames N [--pure]     (``make fuzz`` runs 10^6 cases)

Each case encodes a few valid frames, damages some (random bytes, single or multiple bit flips,
truncation, insertion, garbage between frames), feeds the stream in random chunks and checks that the
streaming decoder never raises, returns exactly the packets a one-shot reference decoder (split at 0x00,
the ``cobs`` package, crcmod) accepts, counts the same drops by reason, and recovers every intact frame.
"""

import random
import struct
import sys
import time

from cobs import cobs

from protocol import core, host, table

KINDS = ("intact", "random", "flip1", "flipN", "truncate", "insert", "garbage_between",
         "forged_version", "forged_id", "forged_length", "oversize")
UNKNOWN_IDS = [i for i in range(256) if i not in core.PACKET]


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def random_fields(pkt, rng):
    """Random valid raw values for every field of a packet (floats: multiples of 1/1024, exact in float32)."""
    out = {}
    for f in pkt.fields:
        name, fmt = f[0], f[1]
        if fmt.endswith("s"):
            out[name] = rng.randbytes(rng.randint(0, int(fmt[:-1])))
            continue
        lo, hi = core.field_range(f)
        if fmt in ("f", "d"):
            lo = -1e4 if lo is None else lo
            hi = 1e4 if hi is None else hi
            v = round(rng.uniform(lo, hi) * 1024) / 1024   # short decimal, exact in float32
            out[name] = f32(min(max(v, lo), hi))
        else:
            out[name] = rng.randint(lo, hi)
    if "length" in out and "data" in out:
        out["length"] = len(out["data"])
    return out


def random_packet(rng, pool=None):
    """(pid, src, dst, seq, payload) of a random valid packet (payload from ``pool`` if given)."""
    if pool:
        pid, payload = pool[rng.randrange(len(pool))]
    else:
        pid = rng.choice(sorted(core.PACKET))
        payload = core.encode_payload(pid, random_fields(core.PACKET[pid], rng))
    return pid, rng.getrandbits(8), rng.getrandbits(8), rng.getrandbits(8), payload


def reference_decode(stream):
    """One-shot reference: (packets, drops) by splitting at 0x00 and checking in table order."""
    drops = dict((r, 0) for r in core.DROP_REASONS)
    out = []
    for seg in stream.split(b"\x00")[:-1]:
        if not seg:
            continue
        if len(seg) > core.MAX_FRAME:
            drops["oversize"] += 1
            continue
        try:
            raw = cobs.decode(seg)
        except cobs.DecodeError:
            drops["bad_cobs"] += 1
            continue
        if len(raw) < core.HEADER_SIZE + core.CRC_SIZE:
            drops["too_short"] += 1
        elif host.crc16(raw[:-2]) != int.from_bytes(raw[-2:], "big"):
            drops["bad_crc"] += 1
        elif raw[0] != table.PROTOCOL_VERSION:
            drops["bad_version"] += 1
        elif raw[1] not in core.PACKET:
            drops["unknown_id"] += 1
        elif len(raw) - core.HEADER_SIZE - core.CRC_SIZE != core.PACKET[raw[1]].size:
            drops["bad_length"] += 1
        else:
            out.append((raw[1], raw[2], raw[3], raw[4], raw[5:-2]))
    return out, drops


def damage(frame, kind, rng):
    """The damaged bytes for one frame (its delimiter kept unless truncated away)."""
    body = bytearray(frame[:-1])
    if kind == "random":
        return rng.randbytes(rng.randint(1, 80)) + b"\x00"
    if kind.startswith("forged_"):  # valid COBS and CRC, wrong content: a confused sender
        raw = bytearray(cobs.decode(bytes(body))[:-2])
        if kind == "forged_version":
            raw[0] = rng.choice([v for v in range(256) if v != table.PROTOCOL_VERSION])
        elif kind == "forged_id":
            raw[1] = rng.choice(UNKNOWN_IDS)
        elif rng.random() < 0.5 and len(raw) > core.HEADER_SIZE:
            del raw[rng.randrange(core.HEADER_SIZE, len(raw)):]
        else:
            raw += rng.randbytes(rng.randint(1, 8))
        c = host.crc16(bytes(raw))
        return cobs.encode(bytes(raw) + bytes((c >> 8, c & 0xFF))) + b"\x00"
    if kind == "oversize":
        return rng.randbytes(core.MAX_FRAME + rng.randint(1, 300)).replace(b"\x00", b"\x01") + b"\x00"
    if kind == "flip1" or kind == "flipN":
        for _ in range(1 if kind == "flip1" else rng.randint(2, 8)):
            i = rng.randrange(len(body))
            body[i] ^= 1 << rng.randrange(8)
        return bytes(body) + b"\x00"
    if kind == "truncate":
        return bytes(body[:rng.randrange(len(body))]) + (b"\x00" if rng.random() < 0.5 else b"")
    if kind == "insert":
        i = rng.randrange(len(body) + 1)
        ins = rng.randbytes(rng.randint(1, 6))
        return bytes(body[:i]) + ins + bytes(body[i:]) + b"\x00"
    if kind == "garbage_between":  # garbage after the frame, sometimes closed by a delimiter
        junk = rng.randbytes(rng.randint(1, 40))
        return frame + junk + (b"\x00" if rng.random() < 0.5 else b"")
    return frame


def one_case(rng, decoder_cls, pool=None, encode=host.encode_frame):
    """Build, feed and check one case; returns (decoder, kinds used). AssertionError on a violation."""
    frames = []
    kinds = []
    intact_after = []   # intact frames that follow a delimiter: every one must come out
    for i in range(rng.randint(1, 5)):
        p = random_packet(rng, pool)
        fr = encode(*p)
        kind = "intact" if rng.random() < 0.4 else rng.choice(KINDS[1:])
        kinds.append(kind)
        if kind in ("intact", "garbage_between") and (not frames or frames[-1].endswith(b"\x00")):
            intact_after.append(p)
        frames.append(damage(fr, kind, rng))
    # Whatever came before, a frame after a delimiter must survive.
    p = random_packet(rng, pool)
    frames.append(b"\x00" + encode(*p))
    intact_after.append(p)
    stream = b"".join(frames)
    dec = decoder_cls()
    got = []
    i = 0
    while i < len(stream):
        n = rng.randint(1, 64)
        got.extend(dec.feed(stream[i:i + n]))
        i += n
    ref, drops = reference_decode(stream)
    assert got == ref, (stream.hex(), got, ref)
    for r in core.DROP_REASONS:
        assert dec.drops[r] == drops[r], (r, dec.drops[r], drops[r], stream.hex())
    assert got[-1] == intact_after[-1], "frame after the damage not recovered"
    missing = [q for q in intact_after if q not in got]
    assert not missing, ("intact frames lost", missing, stream.hex())
    return dec, kinds


def run(n, seed=1, decoder_cls=host.Decoder):
    """Run ``n`` cases; returns counts: damage kinds used, drops by reason, packets decoded."""
    rng = random.Random(seed)
    pool = [random_packet(rng)[::4] for _ in range(2000)]  # (pid, payload)
    counts = dict((k, 0) for k in KINDS)
    for r in core.DROP_REASONS:
        counts["drop_" + r] = 0
    counts["packets"] = 0
    for _ in range(n):
        dec, kinds = one_case(rng, decoder_cls, pool)
        for k in kinds:
            counts[k] += 1
        for r in core.DROP_REASONS:
            counts["drop_" + r] += dec.drops[r]
        counts["packets"] += dec.frames
    return counts


def _cases(text):
    n = float(text)                 # "1e6" is accepted
    if not (n >= 1 and n == int(n)):
        raise ValueError(text)
    return int(n)


def main(argv=None):
    import argparse
    ap = argparse.ArgumentParser(prog="python -m tests.fuzz_frames", description="fuzz the frame decoder")
    ap.add_argument("n", nargs="?", type=_cases, default=100000, help="cases, a whole number >= 1 (default 100000)")
    ap.add_argument("--pure", action="store_true", help="the pure core decoder (default: the host path)")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    n = args.n
    cls = core.Decoder if args.pure else host.Decoder
    t0 = time.perf_counter()
    counts = run(n, decoder_cls=cls)
    dt = time.perf_counter() - t0
    print("| %s fuzz, %d cases, %.1f s | count |" % ("pure" if cls is core.Decoder else "host", n, dt))
    print("|---|---|")
    for k in counts:
        print("| %s | %d |" % (k, counts[k]))
    print("\nno violations (decoder == reference, every intact frame recovered)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
