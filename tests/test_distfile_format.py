"""The distfile format (protocol/distfile.py): round trips, refusals, and the same bytes under MicroPython."""

import io
import math
import struct
import zlib

import pytest
from hypothesis import given, settings, strategies as st

from protocol import distfile as d
from tests.test_firmware_mp import run_mp

finite = st.floats(min_value=-2000.0, max_value=2000.0, allow_nan=False, width=32)


def _sample_file(kind=1, n=50):
    xs = [100.0 * math.sin(0.1 * i) for i in range(n)]
    ys = [-50.0 * math.cos(0.07 * i) for i in range(n)]
    return xs, ys, d.pack(xs, ys, kind=kind, scale=0.001, source="stat", seed=42)


def test_layout_matches_documented_header_and_zlib_crc():
    xs, ys, b = _sample_file(kind=1, n=10)
    assert len(b) == 40 + 10 * 8 + 4
    magic, ver, kind, units, period, count, seed, scale, src = struct.unpack_from("<4sHBBIIIf16s", b)
    assert (magic, ver, kind, units, period, count, seed) == (b"FPSD", 1, 1, 0, 8192, 10, 42)
    assert src.rstrip(b"\0") == b"stat"
    assert struct.unpack_from("<I", b, len(b) - 4)[0] == zlib.crc32(b[:-4])
    assert struct.unpack_from("<ff", b, 40 + 8 * 3) == pytest.approx((xs[3], ys[3]), rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(finite, finite), min_size=2, max_size=40), st.sampled_from([0, 1]),
       st.integers(0, 2**32 - 1), st.integers(1, 100000))
def test_round_trip(samples, kind, seed, period_us):
    xs = [s[0] for s in samples]
    ys = [s[1] for s in samples]
    b = d.pack(xs, ys, period_us=period_us, kind=kind, scale=0.01, source="hyp", seed=seed)
    f = d.parse(b)
    r = d.Reader(io.BytesIO(b))
    assert (f.count, f.seed, f.period_us, f.kind, f.source) == (len(xs), seed, period_us, kind, "hyp")
    tol = 0.0051 if kind == 0 else 1e-3   # half an LSB of 0.01 arcsec; float32 of values up to 2000
    for i in range(len(xs)):
        assert f.sample(i) == r.sample(i)
        assert f.sample(i)[0] == pytest.approx(xs[i], abs=tol)
        assert f.sample(i)[1] == pytest.approx(ys[i], abs=tol)


@pytest.mark.parametrize("mutate, match", [
    (lambda b: b"XPSD" + b[4:], "magic"),
    (lambda b: b[:4] + struct.pack("<H", 2) + b[6:], "version"),
    (lambda b: b[:6] + b"\x07" + b[7:], "kind"),
    (lambda b: b[:7] + b"\x03" + b[8:], "units"),
    (lambda b: b[:-1], "length"),
    (lambda b: b + b"\0", "length"),
    (lambda b: b[:20], "truncated"),
    (lambda b: b[:60] + bytes([b[60] ^ 1]) + b[61:], "CRC"),
    (lambda b: b[:12] + struct.pack("<I", 1) + b[16:], "count"),
])
def test_defects_refused_with_named_error(mutate, match):
    _, _, b = _sample_file()
    bad = mutate(b)
    with pytest.raises(d.DistfileError, match=match):
        d.parse(bad)
    with pytest.raises(d.DistfileError, match=match):
        d.Reader(io.BytesIO(bad))


def test_nan_sample_refused_even_with_valid_crc():
    _, _, b = _sample_file()
    bad = bytearray(b)
    struct.pack_into("<f", bad, 40 + 8 * 7 + 4, float("nan"))
    struct.pack_into("<I", bad, len(bad) - 4, zlib.crc32(bytes(bad[:-4])))
    for reader in (d.parse, lambda x: d.Reader(io.BytesIO(x))):
        with pytest.raises(d.DistfileError, match="sample 7 is not finite"):
            reader(bytes(bad))


def test_pack_refuses_bad_arguments():
    with pytest.raises(d.DistfileError, match="differ in length"):
        d.pack([1.0, 2.0], [1.0])
    with pytest.raises(d.DistfileError, match="not finite"):
        d.pack([1.0, float("inf")], [0.0, 0.0])
    with pytest.raises(d.DistfileError, match="int32"):
        d.pack([1e9, 0.0], [0.0, 0.0], kind=0, scale=1e-3)
    with pytest.raises(d.DistfileError, match="source"):
        d.pack([1.0, 2.0], [1.0, 2.0], source="x" * 17)
    with pytest.raises(d.DistfileError, match="scale"):
        d.pack([1.0, 2.0], [1.0, 2.0], scale=0.0)


@pytest.mark.parametrize("kind", [0, 1])
def test_micropython_reads_and_writes_the_same_bytes(tmp_path, kind):
    xs, ys, b = _sample_file(kind=kind, n=300)
    p = tmp_path / "x.dist"
    p.write_bytes(b)
    res = run_mp("firmware_distfile.py", p)
    f = d.parse(b)
    assert (res["count"], res["seed"], res["source"], res["kind"]) == (300, 42, "stat", kind)
    assert res["same"] and res["repacked_equal"]
    assert [tuple(h) for h in res["head"]] == [f.sample(i) for i in range(3)]
    assert res["refused"] == res["tried"] > 80
