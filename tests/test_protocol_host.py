"""The host fast path (crcmod, cobs package) and the pure core give identical bytes."""

import random
import zlib

import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import core, host


def test_10k_random_bodies_identical_frames_pure_and_host():
    rng = random.Random(2)
    for i in range(10000):
        n = rng.choice((0, 1, 7, 253, 254, 255)) if i % 10 == 0 else rng.randint(0, core.MAX_PAYLOAD)
        payload = rng.randbytes(n) if i % 3 else bytes(n)  # every third payload all zeros
        pid, src, dst, seq = rng.getrandbits(8), rng.getrandbits(8), rng.getrandbits(8), rng.getrandbits(8)
        body = core.encode_body(pid, src, dst, seq, payload)
        assert core.crc16(body) == host.crc16(body)
        assert core.cobs_encode(body) == host.cobs_encode(body)
        frame = core.encode_frame(pid, src, dst, seq, payload)
        assert frame == host.encode_frame(pid, src, dst, seq, payload)
        assert frame.count(0) == 1 and frame[-1] == 0
        assert core.cobs_decode(frame[:-1]) == host.cobs_decode(frame[:-1]) == body + frame_crc(body)


def test_encoder_buffer_frames_match_host_frames_and_reject_oversize_payload():
    rng = random.Random(5)
    enc = core.Encoder()
    for i in range(2000):
        payload = rng.randbytes(rng.randint(0, core.MAX_PAYLOAD))
        pid, src, dst, seq = rng.getrandbits(8), rng.getrandbits(8), rng.getrandbits(8), i
        assert bytes(enc.frame(pid, src, dst, seq, payload)) == host.encode_frame(pid, src, dst, seq, payload)
    with pytest.raises(ValueError, match="256 bytes > 255"):
        enc.frame(1, 2, 3, 4, bytes(256))


def frame_crc(body):
    c = host.crc16(body)
    return bytes((c >> 8, c & 0xFF))


def test_crc16_check_value_and_crc32_matches_zlib():
    assert core.crc16(b"123456789") == host.crc16(b"123456789") == 0x29B1   # CRC-16/CCITT-FALSE check
    rng = random.Random(3)
    for _ in range(200):
        data = rng.randbytes(rng.randint(0, 300))
        assert core.crc32(data) == zlib.crc32(data)
        half = len(data) // 2
        assert core.crc32(data[half:], core.crc32(data[:half])) == zlib.crc32(data)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_cobs_decode_agrees_on_arbitrary_input(data):
    assert core.cobs_decode(data) == host.cobs_decode(data)
    if core.cobs_decode(data) is not None:
        assert cobs.encode(core.cobs_decode(data)) == core.cobs_encode(core.cobs_decode(data))


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=2000), st.lists(st.integers(1, 97), max_size=40))
def test_pure_and_host_decoders_agree_on_any_stream(data, cuts):
    a, b = core.Decoder(), host.Decoder()
    out_a, out_b = [], []
    i = 0
    for c in cuts + [len(data)]:
        out_a += a.feed(data[i:i + c])
        out_b += b.feed(data[i:i + c])
        i += c
    assert out_a == out_b
    assert a.counters() == b.counters()
