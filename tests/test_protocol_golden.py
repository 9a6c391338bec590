"""Golden byte vectors: one serial frame per packet in tests/data/golden_frames.txt, checked on the host
path, the pure path, and under the MicroPython binary.

The file is written once (``python -m tests.test_protocol_golden --write`` only adds lines for packets
that have none; existing vectors are never rewritten: a changed byte is a protocol change).
Line format: ``NAME SRC DST SEQ FRAME_HEX FIELDS_JSON`` (byte-string fields as hex).
"""

import json
import os
import random
import subprocess
import sys

import pytest

from protocol import core, host
from tests import fuzz_frames

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOLDEN = os.path.join(ROOT, "tests", "data", "golden_frames.txt")
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")


def read_golden():
    rows = []
    with open(GOLDEN) as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                name, src, dst, seq, frame, fields = line.split(" ", 5)
                rows.append((name, int(src), int(dst), int(seq), bytes.fromhex(frame), json.loads(fields)))
    return rows


def raw_fields(name, fields):
    """JSON field values to encoder values (hex strings back to bytes)."""
    pkt = core.packet_def(name)
    out = dict(fields)
    for f in pkt.fields:
        if f[1].endswith("s"):
            out[f[0]] = bytes.fromhex(fields[f[0]])
    return out


def test_every_packet_has_a_golden_vector():
    names = [r[0] for r in read_golden()]
    assert sorted(names) == sorted(core.PACKET_ID), "run python -m tests.test_protocol_golden --write"


@pytest.mark.parametrize("row", read_golden(), ids=lambda r: r[0])
def test_golden_encode_decode_host_and_pure(row):
    name, src, dst, seq, frame, fields = row
    values = raw_fields(name, fields)
    assert host.encode_packet(name, src, dst, seq, values) == frame
    assert core.encode_packet(name, src, dst, seq, values) == frame
    for dec in (host.Decoder(), core.Decoder()):
        [(pid, s, d, q, payload)] = dec.feed(frame)
        assert (core.PACKET[pid].name, s, d, q) == (name, src, dst, seq)
        got = core.payload_dict(pid, payload)
        assert got == values


def test_golden_under_micropython():
    """The pure core under the micropython binary encodes and decodes every vector to the same bytes."""
    rows = read_golden()
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen")
    r = subprocess.run([MICROPYTHON, os.path.join(ROOT, "tests", "mp", "protocol_golden.py"), GOLDEN],
                       capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 0, r.stderr
    out = [line.split() for line in r.stdout.splitlines()]
    assert len(out) == len(rows)
    for (name, _, _, _, frame, _), (mp_name, mp_encoded, mp_reencoded, mp_fields_ok) in zip(rows, out):
        assert mp_name == name
        assert mp_encoded == frame.hex(), name
        assert mp_reencoded == frame.hex(), name
        assert mp_fields_ok == "fields_ok", name


def write_missing(path=GOLDEN):
    """Append a vector for every packet without one (fixed seed per packet id)."""
    have = set(r[0] for r in read_golden()) if os.path.exists(path) else set()
    lines = []
    for pid in sorted(core.PACKET):
        pkt = core.PACKET[pid]
        if pkt.name in have:
            continue
        rng = random.Random(pid)
        values = fuzz_frames.random_fields(pkt, rng)
        src, dst, seq = core.NODE.get(pkt.src, 0x01), core.NODE.get(pkt.dst, 0xFF), rng.randrange(256)
        frame = host.encode_packet(pid, src, dst, seq, values)
        js = dict((k, v.hex() if isinstance(v, bytes) else v) for k, v in values.items())
        lines.append("%s %d %d %d %s %s\n" % (pkt.name, src, dst, seq, frame.hex(), json.dumps(js)))
    with open(path, "a") as f:
        if not have:
            f.write("# NAME SRC DST SEQ FRAME_HEX FIELDS_JSON (tests/test_protocol_golden.py)\n")
        f.writelines(lines)
    return len(lines)


if __name__ == "__main__":
    if sys.argv[1:] == ["--write"]:
        print("added %d vectors" % write_missing())
