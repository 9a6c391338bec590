"""The disturbance player (firmware/player.py): Keys 6-point interpolation, Eq. 7.8 codes, actions, uploads,
MicroPython."""

import math
import struct
import zlib

import pytest

from firmware import ad660
from firmware.player import ONESHOT, START, STOP, Player
from protocol import core, distfile
from tests.test_firmware_mp import run_mp

P = core.PACKET_ID


def _file(n=62, kind=1, amp=300.0):
    xs = [amp * math.sin(2 * math.pi * 1.3 * k * 0.008192) for k in range(n)]
    ys = [-0.5 * amp * math.cos(2 * math.pi * 0.7 * k * 0.008192) + 20.0 for k in range(n)]
    return xs, ys, distfile.pack(xs, ys, kind=kind, scale=0.001, source="test", seed=1)


def keys6(u):
    """Keys's 6-point cubic convolution kernel (firmware/player.py's doc), floats."""
    u = abs(u)
    if u < 1:
        return (4 / 3 * u - 7 / 3) * u * u + 1
    if u < 2:
        return ((-7 / 12 * u + 3) * u - 59 / 12) * u + 2.5
    if u < 3:
        return ((u / 12 - 2 / 3) * u + 7 / 4) * u - 1.5
    return 0.0


def _q10(k, rate_hz, period_us):
    """Output k's segment and its Q10 fraction, as the player's phase accumulator gives them."""
    g = math.gcd(1000000, rate_hz * period_us)
    inc, cell = 1000000 // g, rate_hz * period_us // g
    s = 0
    while (cell >> s) >= (1 << 19):
        s += 1
    i, ph = divmod(k * inc, cell)
    div = cell >> s
    return i, ((((ph >> s) << 10) + (div >> 1)) // div) / 1024.0


def _reference(xs, ys, rate_hz, m, period_us=8192):
    """Float truth: the Keys 6-point kernel over the file's samples (ends clamped) at each output's Q10 instant,
    then Eq. 7.8 and offset binary, rounded and clipped."""
    out = []
    n = len(xs)
    for k in range(m):
        i, x = _q10(k, rate_hz, period_us)
        i = min(i, n - 2)
        codes = []
        for s in (xs, ys):
            th = sum(s[min(max(i + j, 0), n - 1)] * keys6(x - j) for j in range(-2, 4))
            c = 0x8000 + ad660.V_PER_ARCSEC * th * 65536 / 20.0
            codes.append(max(0, min(65535, int(math.floor(c + 0.5)))))
        out.append(tuple(codes))
    return out


def _play(p, m, block=17):
    xs, ys = [], []
    xb, yb = [0] * block, [0] * block
    while len(xs) < m:
        n = p.fill(xb, yb, min(block, m - len(xs)))
        if n == 0:
            break
        xs += xb[:n]
        ys += yb[:n]
    return list(zip(xs, ys))


def test_eq_7_8_codes():
    assert ad660.arcsec_to_code(0.0) == 0x8000
    assert ad660.arcsec_to_code(100.0) == round(0x8000 + 1.2343 * 3276.8)
    assert ad660.arcsec_to_code(1e6) == 65535 and ad660.arcsec_to_code(-1e6) == 0
    assert ad660.code_to_arcsec(ad660.arcsec_to_code(123.0)) == pytest.approx(123.0, abs=0.03)


@pytest.mark.parametrize("kind, rate", [(1, 10600), (0, 10600), (1, 4000)])
def test_oneshot_matches_the_float_kernel_within_one_code(kind, rate):
    xs, ys, b = _file(kind=kind)
    f = distfile.parse(b)
    p = Player(f, rate_hz=rate)
    p.oneshot()
    got = _play(p, 10 ** 6)
    xs, ys = f.samples()
    # the one-shot plays (count - 1) periods and ends on the last sample
    span = (f.count - 1) * 0.008192 * rate
    assert abs(len(got) - (math.ceil(span) + 1)) <= 1
    ref = _reference(xs, ys, rate, len(got) - 1)
    worst = max(max(abs(a[0] - r[0]), abs(a[1] - r[1])) for a, r in zip(got, ref))
    assert worst <= 1
    assert got[-1] == (ad660.arcsec_to_code(xs[-1]), ad660.arcsec_to_code(ys[-1]))
    assert p.state == STOP and p.fill([0], [0], 1) == 0


def _per_sample(f, rate_hz, loop, m):
    """The module doc's arithmetic one output at a time (phase accumulator, Q10 fraction, Horner in Q2)."""
    period = f.period_us
    q2 = [(ad660.arcsec_to_code_q2(x), ad660.arcsec_to_code_q2(y)) for x, y in (f.sample(i) for i in range(f.count))]
    n = len(q2)
    g = math.gcd(1000000, rate_hz * period)
    inc, cell = 1000000 // g, rate_hz * period // g
    s = 0
    while (cell >> s) >= (1 << 19):
        s += 1
    out, k = [], 0
    while len(out) < m:
        i, ph = divmod(k * inc, cell)         # the phase runs on across segments and loop passes
        if i > n - 2:
            if not loop:
                out.append(tuple((c + 2) >> 2 for c in q2[-1]))
                break
            i %= n - 1
        fr = ((((ph >> s) << 10) + ((cell >> s) >> 1)) // (cell >> s))
        codes = []
        for ax in (0, 1):
            a, b, q0, d, e, g6 = (q2[min(max(i + j, 0), n - 1)][ax] for j in range(-2, 4))
            c1 = (a - 8 * b + 8 * d - e + 6) // 12
            c2 = (-2 * a + 15 * b - 28 * q0 + 20 * d - 6 * e + g6 + 6) // 12
            c3 = (a - 7 * b + 16 * q0 - 16 * d + 7 * e - g6 + 6) // 12
            h = c2 + ((c3 * fr + 512) >> 10)
            h = c1 + ((h * fr + 512) >> 10)
            y = q0 + ((h * fr + 512) >> 10)
            codes.append(min(65535, max(0, (y + 2) >> 2)))
        out.append(tuple(codes))
        k += 1
    return out[:m]


@pytest.mark.parametrize("rate, loop", [(10600, False), (10600, True), (4097, False), (7001, True), (2049, True),
                                        (777, False)])
def test_fill_equals_the_per_sample_arithmetic(rate, loop):
    """fill's segment-wise fast path (s = 0) and general path (s > 0: 4097, 7001 Hz) give exactly the codes of
    the per-sample formula, in blocks of any size."""
    xs, ys, b = _file(n=23, amp=2000.0)
    f = distfile.parse(b)
    p = Player(f, rate_hz=rate)
    assert (p._shift > 0) == (rate in (4097, 7001))
    p.play_loop() if loop else p.oneshot()
    m = int(3.2 * (f.count - 1) * 0.008192 * rate)
    got = []
    blocks = [1, 2, 17, 100, 4255, 3]
    while len(got) < m:
        k = _play(p, min(m - len(got), blocks[len(got) % len(blocks)]), block=4255)
        if not k:
            break
        got += k
    want = _per_sample(f, rate, loop, m)
    assert got == want
    assert (p.x_code, p.y_code) == want[-1]


def test_loop_wraps_and_stop_start_resume():
    xs, ys, b = _file(n=10)
    p = Player(distfile.parse(b))
    assert p.fill([0] * 4, [0] * 4, 4) == 0          # stopped until told
    p.play_loop()
    per_loop = 9 * 0.008192 * 10600
    idx = []
    got = []
    for _ in range(int(2.5 * per_loop)):
        got += _play(p, 1)
        idx.append(p.index)
    wraps = [k for k in range(1, len(idx)) if idx[k] < idx[k - 1]]
    assert len(wraps) == 2 and abs(wraps[0] + 1 - per_loop) <= 1 and abs(wraps[1] - wraps[0] - per_loop) <= 1
    assert abs(got[wraps[0] + 1][0] - got[0][0]) <= 40        # back near the first sample
    p.stop()
    assert p.fill([0], [0], 1) == 0
    held = (p.x_code, p.y_code)
    p.start()
    nxt = _play(p, 1)[0]
    assert abs(nxt[0] - held[0]) <= 30 and abs(nxt[1] - held[1]) <= 30   # resumes where it stopped


def _send(p, name, seq=3, **kw):
    return p.handle(P[name], core.NODE["GROUND"], seq, core.encode_payload(name, **kw))


def _upload(p, blob, crc=None):
    r = _send(p, "DIST_BEGIN", total=len(blob), crc32=zlib.crc32(blob) if crc is None else crc)
    for off in range(0, len(blob), 48):
        part = blob[off:off + 48]
        r += _send(p, "DIST_CHUNK", offset=off, length=len(part), data=part)
    return r + _send(p, "DIST_END", total=len(blob))


@pytest.mark.parametrize("store", [False, True])
def test_upload_then_play_and_bad_uploads_keep_previous(tmp_path, store):
    p = Player(store_path=str(tmp_path / "dist.bin") if store else None)
    r = _send(p, "PLAYER_CTRL", action=START)
    assert r[0][0] == P["NACK"] and r[0][2][2] == core.ERROR["BAD_STATE"]
    xs, ys, b = _file(n=40)
    assert all(x[0] == P["ACK"] for x in _upload(p, b))
    assert p.reader.count == 40
    first = p.reader
    _, _, other = _file(n=20, amp=10.0)
    assert _upload(p, other, crc=5)[-1][2][2] == core.ERROR["BAD_CRC"]
    bad = bytearray(other)
    bad[0:4] = b"NOPE"
    assert _upload(p, bytes(bad))[-1][2][2] == core.ERROR["BAD_CONTENT"]
    assert p.reader is first
    r = _send(p, "PLAYER_CTRL", action=ONESHOT, rate_hz=10600)
    assert r[0][0] == P["ACK"] and r[1][0] == P["PLAYER_STATUS"]
    assert core.payload_dict(P["PLAYER_STATUS"], r[1][2]) == {"state": ONESHOT, "sample": 0, "count": 40}
    got = _play(p, 50)
    assert got[0] == (ad660.arcsec_to_code(xs[0]), ad660.arcsec_to_code(ys[0]))
    if store:
        assert distfile.parse((tmp_path / "dist.bin").read_bytes()).count == 40
        assert not (tmp_path / "dist.bin.part").exists()


def test_bad_rate_refused():
    with pytest.raises(ValueError, match="rate_hz"):
        Player(rate_hz=20)
    xs, ys, b = _file()
    p = Player(distfile.parse(b))
    enc = bytearray(core.encode_payload("PLAYER_CTRL", action=START, rate_hz=10600))
    struct.pack_into("<H", enc, 1, 60000)
    assert p.handle(P["PLAYER_CTRL"], 1, 1, bytes(enc))[0][2][2] == core.ERROR["BAD_VALUE"]


def test_micropython_player_gives_identical_codes(tmp_path):
    xs, ys, b = _file(n=62)
    path = tmp_path / "d.bin"
    path.write_bytes(b)
    res = run_mp("firmware_player.py", path)
    with open(path, "rb") as f:
        p = Player(distfile.Reader(f))
        p.oneshot()
        got = _play(p, 10 ** 6)
    crc = 0
    for x, y in got:
        crc = zlib.crc32(struct.pack("<HH", x, y), crc)
    assert res == {"n": len(got), "crc": crc}


def _f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


def _exact_q2(x):
    """Eq. 7.7-7.8 in exact rational arithmetic: 131072 + K4 x (K4 the double the firmware uses), rounded
    half up, clipped."""
    from fractions import Fraction
    v = 131072 + Fraction(4 * ad660.V_PER_ARCSEC * ad660.CODES_PER_VOLT) * Fraction(x)
    return max(0, min(ad660.Q2_MAX, math.floor(v + Fraction(1, 2))))


def test_integer_q2_conversion_equals_the_float_one():
    """ad660.Q2Converter (integer limbs) gives the codes of arcsec_to_code_q2 (doubles) for float32 and
    int32 samples: random values over and beyond the DAC range, tiny and subnormal ones, signed zeros,
    the int32 extremes, and float32 values next to every rounding tie of a code range (where the exact
    rational value decides)."""
    import random
    assert ad660.K4_C == 4 * ad660.V_PER_ARCSEC * ad660.CODES_PER_VOLT * 2 ** ad660.K4_Q
    rnd = random.Random(8)
    cv = ad660.Q2Converter(1)
    xs = [_f32(rnd.uniform(-1100.0, 1100.0)) for _ in range(30000)]
    xs += [_f32(rnd.uniform(-1.0, 1.0) * 10.0 ** rnd.uniform(-40, 0)) for _ in range(5000)]
    xs += [0.0, -0.0, 1e-45, -1e-45, 1023.99993, -1023.99993, 1024.0, -1024.0, 3.4e38, -3.4e38, 810.2, -810.2]
    for n in list(range(-131072, 131072, 997)) + [-131072, 131070, 131071]:   # ties of Q2 n + 1/2
        t = (n + 0.5) / (4 * ad660.V_PER_ARCSEC * ad660.CODES_PER_VOLT)
        b = struct.unpack("<I", struct.pack("<f", t))[0]
        xs += [struct.unpack("<f", struct.pack("<I", b + d))[0] for d in (-1, 0, 1) if 0 <= b + d < 1 << 32]
    for x in xs:
        x = _f32(x)
        got = cv.code(struct.pack("<f", x), 0)
        assert got == ad660.arcsec_to_code_q2(x), x
        assert got == _exact_q2(x), x
    for scale in (0.001, 1.0, 3e-7, 0.1234, 50.0, 1e-30, 1e30):
        scale = _f32(scale)
        cv0 = ad660.Q2Converter(0, scale)
        ns = [rnd.randint(-2 ** 31, 2 ** 31 - 1) for _ in range(2000)]
        ns += [int(rnd.uniform(-1100, 1100) / scale) for _ in range(3000) if abs(1100 / scale) < 2 ** 31]
        ns += [0, 1, -1, 2 ** 31 - 1, -2 ** 31]
        for n in ns:
            n = max(-2 ** 31, min(2 ** 31 - 1, n))
            got = cv0.code(struct.pack("<i", n), 0)
            assert got == ad660.arcsec_to_code_q2(n * scale), (scale, n)


def test_micropython_player_update_allocates_nothing(tmp_path):
    """Under micropython with the heap locked: 10^5 single-update fill() calls per distfile (float32 and
    int32, streamed from a file and in memory) cross > 1000 distfile samples and wrap the loop, without a
    MemoryError and with gc.mem_alloc() unchanged; the codes hash as under CPython. The float conversion
    the player used before fails under the same lock (the lock does catch allocations)."""
    n = 500
    xs = [1000 * math.sin(0.05 * k) for k in range(n)]          # beyond +-10 V at the peaks: clipped codes
    ys = [300 * math.cos(0.031 * k) + 5 for k in range(n)]
    paths = []
    for kind in (1, 0):
        path = tmp_path / ("d%d.bin" % kind)
        path.write_bytes(distfile.pack(xs, ys, kind=kind, scale=0.001))
        paths.append(str(path))
    updates = 100000
    res = run_mp("firmware_player_alloc.py", updates, *paths)
    assert res["float_path_caught"] is True
    assert len(res["runs"]) == 4
    for r in res["runs"]:
        assert r["error"] is None and r["alloc_bytes"] == 0
        assert r["updates"] == updates + 10 and r["crossings"] > 1000
        with open(r["path"], "rb") as f:
            p = Player(distfile.Reader(f))
            p.play_loop()
            h = 0
            for _ in range(r["updates"]):
                xb, yb = [0], [0]
                assert p.fill(xb, yb, 1) == 1
                h = (h * 31 + xb[0] * 65536 + yb[0]) & 0x3FFFFFF
        assert r["hash"] == h
