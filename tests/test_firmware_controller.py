"""The fixed-point controller (firmware/controller.py) under CPython: words, law, modes, packets, tables."""

import json
import math
import struct
import zlib

import pytest
from hypothesis import given, settings, strategies as st

from firmware import ad5664r
from firmware.controller import _S_VX, _S_VY, ACQUIRE, CALIBRATE, HOLD, SAFE, TRACK, WHY_BEAM, Controller
from firmware.hinv import HINV_MAX, HinvTable
from protocol import core, htable, table
from tests.mp import firmware_plant as fp

TICKS_10S = 6378          # 10 s at 637.8 Hz
E_MAX = 16383 / 32768     # the firmware's dR clamp (just under 0.5)
WHY = dict(table.SAFE_REASONS)   # CTRL_STATUS.why by name


@pytest.fixture(scope="module")
def grid():
    return htable.grid_from_calibration(fp.calibration())


def tracking(grid, **kw):
    c = Controller(table=grid, **kw)
    c.step(2048, 2048, 0)          # the init tick
    c.mode = TRACK
    return c


# --- an independent float reference of the same law ----------------------------------------------------
class FloatReference:
    """Eq. 7.4, 7.12, 7.13 in floats: ratio, dR clamp +-0.5, H^-1 per node (float) interpolated bilinearly at
    the centre of the command's 64-code bin, V -= g H^-1 dR in codes, state clamped at the limit, output rounded."""

    def __init__(self, grid, gain=0.5, limit=32767):
        self.ax = [ad5664r.volts_to_code(v) for v in grid.ax]
        self.ay = [ad5664r.volts_to_code(v) for v in grid.ay]
        self.hinv_nodes = []
        for a, b, c, d in grid.h:
            det = a * d - b * c
            k = ad5664r.CODES_PER_VOLT / det
            self.hinv_nodes.append((d * k, -b * k, -c * k, a * k))
        self.nx = len(self.ax)
        self.g = gain
        self.lim = limit
        self.vx = 0.0
        self.vy = 0.0

    @staticmethod
    def _frac(axis, c):
        i = 0
        while i < len(axis) - 2 and c >= axis[i + 1]:
            i += 1
        return i, min(1.0, max(0.0, (c - axis[i]) / (axis[i + 1] - axis[i])))

    def hinv(self, x, y):
        i, tx = self._frac(self.ax, x)
        j, ty = self._frac(self.ay, y)
        n = self.nx
        m = []
        for e in range(4):
            h00 = self.hinv_nodes[j * n + i][e]
            h10 = self.hinv_nodes[j * n + i + 1][e]
            h01 = self.hinv_nodes[(j + 1) * n + i][e]
            h11 = self.hinv_nodes[(j + 1) * n + i + 1][e]
            top = h00 + (h10 - h00) * tx
            bot = h01 + (h11 - h01) * tx
            m.append(top + (bot - top) * ty)
        return m

    def step(self, vx, vy, vs):
        if vs >= 200:
            ex = max(-E_MAX, min(E_MAX, (2048 - vx) / vs))
            ey = max(-E_MAX, min(E_MAX, (2048 - vy) / vs))
            # H^-1 at the centre of the command's 64-code bin (the firmware's evaluation points)
            m = self.hinv(64 * math.floor(self.vx / 64) + 32, 64 * math.floor(self.vy / 64) + 32)
            self.vx -= self.g * (m[0] * ex + m[1] * ey)
            self.vy -= self.g * (m[2] * ex + m[3] * ey)
            self.vx = max(-self.lim, min(self.lim, self.vx))
            self.vy = max(-self.lim, min(self.lim, self.vy))
        x, y = round(self.vx), round(self.vy)
        return [0x8000 + x, 0x18000 - x, 0x38000 + y, 0x128000 - y]


def _codes(words):
    return [(w & 0xFFFF) for w in words]


def test_init_sequence_then_differential_words(grid):
    c = Controller(table=grid)
    assert c.step(2048, 2048, 2500) == 4
    assert c.words == list(ad5664r.INIT_WORDS)
    c.step(2048, 2048, 2500)
    assert [ad5664r.decode(w)[:2] for w in c.words] == [(0, 0), (0, 1), (0, 3), (2, 2)]
    c.mode = CALIBRATE
    c.handle(core.PACKET_ID["CTRL_SET_FSM"], 1, 0, core.encode_payload("CTRL_SET_FSM", vx=1000000, vy=-500000))
    c.step(2048, 2048, 2500)
    xp, xn, yp, yn = _codes(c.words)
    assert ad5664r.pair_to_code(xp, xn) == ad5664r.volts_to_code(1.0)
    assert ad5664r.pair_to_code(yp, yn) == ad5664r.volts_to_code(-0.5)
    assert ad5664r.code_to_volts(ad5664r.pair_to_code(xp, xn)) == pytest.approx(1.0, abs=0.5 / 13107.2)
    ref = [0] * 4
    ad5664r.command_words(ad5664r.volts_to_code(1.0), ad5664r.volts_to_code(-0.5), ref)
    assert c.words == ref                     # the inlined hot-loop words match the driver module's


def test_tracks_plant_and_matches_float_reference_within_one_lsb(grid):
    """10 s closed loop: fixed point and the float law each drive their own copy of the same plant."""
    c = tracking(grid)
    ref = FloatReference(grid)
    p_fix, p_ref = fp.Plant(seed=3), fp.Plant(seed=3)
    worst_lsb = 0
    worst_res = 0.0
    for k in range(TICKS_10S):
        words = c.on_tick(k, 0, *p_fix.sample())
        rwords = ref.step(*p_ref.sample())
        p_fix.apply(words)
        p_ref.apply(rwords)
        worst_lsb = max(worst_lsb, max(abs(a - b) for a, b in zip(_codes(words), _codes(rwords))))
        if k > 600:
            worst_res = max(worst_res, max(abs(v) for v in p_fix.residual_v()))
    assert worst_lsb <= 1
    assert worst_res < 0.03        # volts: the loop follows a 0.6 V disturbance
    assert c.mode == TRACK and c.n_sat == 0


def test_bilinear_lookup_matches_float_interpolation(grid):
    t = HinvTable(grid)
    ref = FloatReference(grid)
    for x, y in ((-20000, 14000), (0, 0), (3100, -2800), (40000, -40000), (-16383, 16383)):
        got = [v / (1 << t.hq) for v in t.hinv_at(x, y)]
        want = ref.hinv(x, y)
        for e in range(4):
            assert got[e] == pytest.approx(want[e], abs=2.0 / (1 << t.hq) + 1e-3 * abs(want[e]))


def test_bilinear_cell_search_from_last_cell_matches_fresh_search(grid):
    """hinv_into starts its cell search where the last call ended: any sequence of points, jumps across the
    grid and points outside it included, gives what a fresh table (searching from cell 0) gives."""
    t = HinvTable(grid)
    x = y = 0
    xs = []
    cells = set()
    for k in range(400):
        x = (x * 7 + 12345 + 911 * k) % 80001 - 40000 if k % 50 == 0 else x + (k * 37) % 3001 - 1500
        y = (y * 5 + 23456 + 577 * k) % 80001 - 40000 if k % 60 == 0 else y - (k * 53) % 2801 + 1400
        xs.append(x)
        assert t.hinv_at(x, y) == HinvTable(grid).hinv_at(x, y)
        cells.add((t._i, t._j))
    assert min(xs) < t.ax[0] and max(xs) > t.ax[-1]     # the walk left the grid on both sides
    assert len(cells) > 20                              # and the search moved both ways between many cells


# --- every intermediate inside +-2^30 -------------------------------------------------------------------
class Bounded(int):
    """An int whose arithmetic results must stay inside the 32-bit MicroPython small-int range."""

    def _chk(self, v):
        assert -(1 << 30) <= v < (1 << 30), "intermediate %d outside +-2^30" % v
        return Bounded(v)


for _op in ("add", "sub", "mul", "floordiv", "lshift", "rshift", "and", "or", "mod"):
    for _name in ("__%s__" % _op, "__r%s__" % _op):
        def _f(self, o, _m=getattr(int, _name)):
            r = _m(int(self), int(o) if isinstance(o, int) else o)
            return r if r is NotImplemented else Bounded._chk(self, r)
        setattr(Bounded, _name, _f)
Bounded.__neg__ = lambda self: Bounded._chk(self, -int(self))


def _extreme_table(sign=1.0):
    """A grid whose H^-1 sits at the fixed-point limit (smallest accepted H) with cross terms."""
    m = HINV_MAX * 0.9999 / ad5664r.CODES_PER_VOLT      # H^-1 entries in V per unit ratio
    a, b, c, d = sign * m, 0.3 * m, -0.2 * m, m
    det = a * d - b * c
    h = [(d / det, -b / det, -c / det, a / det)] * 4
    return htable.Grid([-2.4, 2.4], [-2.4, 2.4], h)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 4095), st.integers(0, 4095), st.integers(0, 4095)), min_size=1,
                max_size=40),
       st.integers(1, 65535), st.integers(-16384, 16384), st.integers(-16384, 16384), st.sampled_from([1.0, -1.0]))
def test_intermediates_within_2_30_and_codes_in_safe_range(samples, gain, rxc, ryc, sign):
    t = HinvTable(_extreme_table(sign))
    t.t = [Bounded(v) for v in t.t]
    t.h16 = [Bounded(v) for v in t.h16]
    c = Controller(table=t, gain_q15=Bounded(gain), rx_cmd_q15=Bounded(rxc), ry_cmd_q15=Bounded(ryc),
                   limit_code=30000)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    c._s[_S_VX] = Bounded(c.vx_q8)
    c._s[_S_VY] = Bounded(c.vy_q8)
    for vx, vy, vs in samples * 3:
        c.heard(True)
        c.step(Bounded(vx), Bounded(vy), Bounded(vs))
        for w in c.words:
            assert 0x8000 - 30000 <= (w & 0xFFFF) <= 0x8000 + 30000
        assert ad5664r.pair_to_code(c.words[0] & 0xFFFF, c.words[1] & 0xFFFF) == (c.vx_q8 + 128) >> 8


# --- modes --------------------------------------------------------------------------------------------
def _code_x(words):
    return ad5664r.pair_to_code(words[0] & 0xFFFF, words[1] & 0xFFFF)


def _tracked(grid, ticks=400, **kw):
    """A controller that has followed the plant's disturbance for ``ticks`` (the mirror off centre)."""
    c = tracking(grid, **kw)
    p = fp.Plant(seed=5)
    for k in range(ticks):
        p.apply(c.on_tick(k, 0, *p.sample()))
    assert c.words[0] & 0xFFFF != 0x8000
    return c, p


def test_beam_loss_holds_then_acquire_holds_then_centres_without_windup(grid):
    c, p = _tracked(grid, acq_ticks=50, centre_ticks=300, ramp_code=100)
    held = list(c.words)
    p.beam = False
    for k in range(49):                          # a flicker: TRACK holds the command
        c.on_tick(k, 0, *p.sample())
        assert c.words == held and c.mode == TRACK
    c.on_tick(49, 0, *p.sample())                # acq_ticks lost in a row: ACQUIRE, BEAM_LOST
    assert (c.mode, c.why, c.words) == (ACQUIRE, WHY_BEAM, held)
    st_ = core.payload_dict(P["CTRL_STATUS"], c.status_payload())
    assert (st_["mode"], st_["why"], st_["flags"] & 1) == (core.MODE["ACQUIRE"], WHY["BEAM_LOST"], 0)
    for k in range(50, 299):                     # ACQUIRE holds where the beam was last seen
        c.on_tick(k, 0, *p.sample())
        assert c.words == held and c.mode == ACQUIRE
    x_prev = abs(_code_x(held))
    for k in range(2000):                        # centre_ticks lost in a row: back to the centre, no windup
        c.on_tick(k, 0, *p.sample())
        x = abs(_code_x(c.words))
        assert x_prev - 100 <= x <= x_prev and c.mode == ACQUIRE
        x_prev = x
    assert _codes(c.words) == [0x8000] * 4 and c.vx_q8 == 0 and c.vy_q8 == 0
    assert c.n_lost == 49 + 1 + 249 + 2000 and c.lost == 2299


def test_the_beam_back_for_acq_ticks_returns_to_track_bumpless_and_tracks(grid):
    c, p = _tracked(grid, acq_ticks=50, centre_ticks=100)
    p.beam = False
    for k in range(130):                         # ACQUIRE, partway to the centre
        p.apply(c.on_tick(k, 0, *p.sample()))
    assert c.mode == ACQUIRE and c.vx_q8 != 0
    p.beam = True
    held = list(c.words)
    for k in range(49):                          # the beam back, debounced: the mirror holds, no law
        p.apply(c.on_tick(k, 0, *p.sample()))
        assert c.mode == ACQUIRE and c.words == held and c.lost == 0
    ref = tracking(grid)                         # the law from the same command: what the first step must be
    ref._s[_S_VX], ref._s[_S_VY] = c.vx_q8, c.vy_q8
    p.apply(c.on_tick(49, 0, *p.sample()))
    assert (c.mode, c.words, c.why) == (TRACK, held, WHY_BEAM)    # TRACK again; why stays the loss's reason
    smp = p.sample()
    ref.step(*smp)
    p.apply(c.on_tick(50, 0, *smp))
    assert c.words == ref.words and (c.vx_q8, c.vy_q8) == (ref.vx_q8, ref.vy_q8)    # bumpless: the law resumes
    for k in range(2000):
        p.apply(c.on_tick(k, 0, *p.sample()))
    assert c.mode == TRACK and max(abs(v) for v in p.residual_v()) < 0.01          # and follows the disturbance


def test_a_beam_dropout_restarts_the_debounce_and_the_hold(grid):
    c, p = _tracked(grid, acq_ticks=20, centre_ticks=60, ramp_code=100)
    dark, lit = (2048, 2048, 10), (2048 - 40, 2048 + 30, 2500)
    for _ in range(20):
        c.step(*dark)
    assert c.mode == ACQUIRE
    held = list(c.words)
    for _ in range(19):
        c.step(*lit)
    c.step(*dark)                                # one dark tick: the count starts again
    for _ in range(19):
        c.step(*lit)
    assert c.mode == ACQUIRE and c.words == held
    for _ in range(59):                          # the hold counts from the dropout's start again
        c.step(*dark)
    assert c.words == held
    c.step(*dark)
    assert c.words != held and c.mode == ACQUIRE
    for _ in range(20):
        c.step(*lit)
    assert c.mode == TRACK


def test_safe_commanded_or_for_link_silence_stays_while_acquire_returns(grid):
    c, p = _tracked(grid, acq_ticks=20, safe_ticks=1000)
    for _ in range(20):
        c.step(2048, 2048, 10)
    assert c.mode == ACQUIRE
    assert _send(c, "CTRL_SETTINGS", mode=TRACK, safe_ticks=1000)[0][0] == P["ACK"] and c.mode == ACQUIRE
    for _ in range(20):                          # TRACK asked in ACQUIRE keeps it: the beam decides
        c.step(2048, 2048, 10)
    assert c.mode == ACQUIRE
    c.link_silent(1000)                          # link silence: SAFE from ACQUIRE
    assert (c.mode, c.why) == (SAFE, WHY["LINK_SILENT"])
    for _ in range(200):                         # the beam back: SAFE stays until commanded
        c.on_tick(0, 0, 2048, 2048, 2500)
    assert (c.mode, c.why) == (SAFE, WHY["LINK_SILENT"])
    c, p = _tracked(grid, acq_ticks=20, safe_ticks=1000)
    for _ in range(20):
        c.step(2048, 2048, 10)
    assert _send(c, "CTRL_SETTINGS", mode=SAFE, safe_ticks=1000)[0][0] == P["ACK"]
    for _ in range(200):
        c.step(2048, 2048, 2500)
    assert (c.mode, c.why) == (SAFE, WHY["COMMANDED"])
    assert _send(c, "CTRL_SETTINGS", mode=TRACK, safe_ticks=1000)[0][0] == P["ACK"] and c.mode == TRACK
    for _ in range(20):                          # from a commanded TRACK, the next loss enters ACQUIRE again
        c.step(2048, 2048, 10)
    assert (c.mode, c.why) == (ACQUIRE, WHY_BEAM)
    bad = bytearray(core.encode_payload("CTRL_SETTINGS", mode=1))
    bad[0] = ACQUIRE                             # ACQUIRE cannot be commanded
    assert c.handle(P["CTRL_SETTINGS"], 1, 3, bytes(bad))[0][2][2] == core.ERROR["BAD_VALUE"]


def test_acquire_on_a_board_enters_safe_when_the_link_falls_silent(grid):
    c = tracking(grid, acq_ticks=5, safe_ticks=40)
    c.hal = _DarkHal()
    for _ in range(39):
        c.tick()
    assert c.mode == ACQUIRE
    c.tick()
    assert (c.mode, c.why) == (SAFE, WHY["LINK_SILENT"])


class _DarkHal:
    def read_q1(self, out):
        out[0], out[1], out[2] = 2048, 2048, 0

    def spi_write(self, words, n):
        pass


class _StillHal:
    def read_q1(self, out):
        out[0], out[1], out[2] = 2048, 2048, 2500

    def spi_write(self, words, n):
        pass


def test_link_silence_enters_safe_from_track_hold_and_calibrate(grid):
    for mode in (TRACK, HOLD, CALIBRATE):
        c = tracking(grid, safe_ticks=20)
        c.hal = _StillHal()
        c.mode = mode
        for _ in range(19):
            c.tick()
        assert c.mode == mode
        c.handle(core.PACKET_ID["HELLO"], 1, 0, core.encode_payload("HELLO"))    # traffic resets the count
        for _ in range(19):
            c.tick()
        assert c.mode == mode
        c.tick()
        assert c.mode == SAFE
    c = tracking(grid, safe_ticks=30)            # over the link HAL: the waits between TICKs add up
    c.link_silent(20)
    assert c.mode == TRACK
    c.on_tick(0, 0, 2048, 2048, 2500)
    c.link_silent(20)
    assert c.mode == TRACK
    c.link_silent(10)
    assert c.mode == SAFE


def test_saturation_clamps_state_no_windup(grid):
    c = tracking(grid, limit_code=2000)
    for k in range(300):                            # a constant far-off spot drives the law into the limit
        c.on_tick(k, 0, 2048 - 500, 2048 + 500, 2500)
    assert c.flags & 2 and c.n_sat > 200
    assert abs(c.vx_q8) == 2000 << 8 and abs(c.vy_q8) == 2000 << 8
    x_sat = c.vx_q8
    c.on_tick(0, 0, 2048 + 500, 2048 - 500, 2500)    # the error reverses: the command leaves the limit at once
    assert abs(c.vx_q8) < abs(x_sat)


# --- packets ------------------------------------------------------------------------------------------
P = core.PACKET_ID


def _send(c, name, seq=7, **kw):
    return c.handle(P[name], core.NODE["GROUND"], seq, core.encode_payload(name, **kw))


def test_settings_ack_nack_and_unknown_counted(grid):
    c = Controller()
    r = _send(c, "CTRL_SETTINGS", mode=TRACK)
    assert r == [(P["NACK"], 1, struct.pack("<BBB", P["CTRL_SETTINGS"], 7, core.ERROR["BAD_STATE"]))]
    c.set_table(grid)
    r = _send(c, "CTRL_SETTINGS", mode=TRACK, rx_cmd=100, ry_cmd=-100, gain=8192, decim=10, safe_ticks=99)
    assert r == [(P["ACK"], 1, struct.pack("<BB", P["CTRL_SETTINGS"], 7))]
    assert (c.mode, c.rx_cmd, c.ry_cmd, c.gain, c.decim, c.safe_ticks) == (TRACK, 100, -100, 8192, 10, 99)
    _send(c, "CTRL_SETTINGS", mode=HOLD, gain=0)
    assert c.gain == 8192 and c.mode == HOLD                     # gain 0 keeps the gain
    bad = bytearray(core.encode_payload("CTRL_SETTINGS", mode=1))
    bad[0] = 9
    assert c.handle(P["CTRL_SETTINGS"], 1, 3, bytes(bad))[0][2][2] == core.ERROR["BAD_VALUE"]
    assert _send(c, "CTRL_SET_FSM", vx=1)[0][2][2] == core.ERROR["BAD_STATE"]   # not in CALIBRATE
    assert c.handle(P["RW_CMD"], 0x30, 1, core.encode_payload("RW_CMD")) == []
    assert c.handle(0xEE, 1, 1, b"xx") == []
    assert c.handle(P["CTRL_SETTINGS"], 1, 1, b"short") == []
    assert c.n_unknown == 3


def test_status_payload_and_decimation(grid):
    c = tracking(grid, decim=8)
    p = fp.Plant()
    due = []
    for k in range(40):
        p.apply(c.on_tick(k, 0, *p.sample()))
        due.append(c.status_due())
    assert sum(due) == 5
    st_ = core.payload_dict(P["CTRL_STATUS"], c.status_payload())
    assert st_["mode"] == TRACK and st_["flags"] & 1 and st_["flags"] & 4
    assert st_["code_xp"] == c.words[0] & 0xFFFF and st_["code_yn"] == c.words[3] & 0xFFFF
    assert st_["vx"] == pytest.approx(c.vx_q8 / 256 / ad5664r.CODES_PER_VOLT * 1e6, abs=1)
    c.mode = CALIBRATE                               # ratios are reported outside TRACK too (calibration)
    c.on_tick(0, 0, 2048 - 250, 2048 + 125, 2500)
    st_ = core.payload_dict(P["CTRL_STATUS"], c.status_payload())
    assert (st_["rx"], st_["ry"]) == (round(0.1 * 32768), round(-0.05 * 32768))
    assert c.handle(P["HELLO"], 1, None, core.encode_payload("HELLO"))[0][0] == P["HELLO"]   # CAN: no seq
    assert c.handle(P["CTRL_SETTINGS"], 1, None, core.encode_payload("CTRL_SETTINGS", mode=HOLD))[0][0] == P["ACK"]


# --- tables -------------------------------------------------------------------------------------------
def _upload(c, blob, crc=None, chunks=None):
    replies = _send(c, "HTABLE_BEGIN", total=len(blob), crc32=zlib.crc32(blob) if crc is None else crc)
    offs = list(range(0, len(blob), 48)) if chunks is None else chunks
    for off in offs:
        part = blob[off:off + 48]
        replies += _send(c, "HTABLE_CHUNK", offset=off, length=len(part), data=part)
    replies += _send(c, "HTABLE_END", total=len(blob))
    return replies


def test_htable_upload_swaps_in_and_refusals_keep_previous(grid):
    c = Controller()
    blob = htable.pack(grid)
    r = _upload(c, blob)
    assert all(pid == P["ACK"] for pid, _, _ in r)
    assert c.table is not None and c.table.h == HinvTable(grid).h
    first = c.table
    other = htable.pack(htable.Grid([-1, 1], [-1, 1], [(-8, 0, 0, 8)] * 4))
    assert _upload(c, other, crc=123)[-1][2][2] == core.ERROR["BAD_CRC"]
    assert _upload(c, other, chunks=[0])[-1][2][2] == core.ERROR["BAD_SEQUENCE"]       # partial
    r = _upload(c, other, chunks=[48, 0])                                              # out of order
    assert r[1][2][2] == core.ERROR["BAD_SEQUENCE"] and r[-1][2][2] == core.ERROR["BAD_SEQUENCE"]
    nan = bytearray(other)
    struct.pack_into("<f", nan, 8 + 16 + 4, float("nan"))
    struct.pack_into("<I", nan, len(nan) - 4, zlib.crc32(bytes(nan[:-4])))
    assert _upload(c, bytes(nan))[-1][2][2] == core.ERROR["BAD_CONTENT"]
    tiny = htable.pack(htable.Grid([-1, 1], [-1, 1], [(-0.5, 0, 0, 0.5)] * 4))   # H too small to steer by
    assert _upload(c, tiny)[-1][2][2] == core.ERROR["BAD_CONTENT"]
    big = _send(c, "HTABLE_BEGIN", total=100000, crc32=0)
    assert big[0][2][2] == core.ERROR["TOO_LARGE"]
    assert c.table is first
    assert _upload(c, other)[-1][0] == P["ACK"] and c.table is not first


def test_a_small_boards_static_table_is_rewritten_in_place_only_once_a_new_one_passes(grid):
    """static=True (the 32 KB board, firmware.pil_main): the upload buffer and the table's arrays are allocated at
    construction and reused; an upload is read in place (protocol.hblob.Blob) into the same arrays, the same
    integers as from a Grid; a refused table (bad content, or larger than the board holds) leaves the loaded one
    whole, its arrays untouched."""
    from protocol.hblob import Blob, blob_size
    blob = htable.pack(grid)
    c = Controller(max_table_bytes=blob_size(grid.nx, grid.ny), static=True)
    t, h16 = c._static_t
    assert all(pid == P["ACK"] for pid, _, _ in _upload(c, blob))
    assert c.table.t is t and c.table.h16 is h16 and c.table.h == HinvTable(grid).h == HinvTable(Blob(blob)).h
    before = (list(t), list(h16))
    singular = htable.pack(htable.Grid(grid.ax, grid.ay, [(1.0, 2.0, 2.0, 4.0)] * len(grid.h)))
    assert _upload(c, singular)[-1][2][2] == core.ERROR["BAD_CONTENT"]
    wide = htable.pack(htable.Grid([-2.0 + 0.1 * k for k in range(grid.nx + 1)], grid.ay,
                                   list(grid.h) + list(grid.h[:grid.ny])))
    assert _send(c, "HTABLE_BEGIN", total=len(wide), crc32=zlib.crc32(wide))[0][2][2] == core.ERROR["TOO_LARGE"]
    with pytest.raises(htable.HTableError, match="table memory"):      # past the upload's check, the arrays' own
        HinvTable(htable.parse(wide), c._static_t)
    assert (list(t), list(h16)) == before and c.table.h == HinvTable(grid).h
    other = htable.pack(htable.Grid([-1, 1], [-1, 1], [(-8, 0, 0, 8)] * 4))
    assert _upload(c, other)[-1][0] == P["ACK"] and c.table.t is t and c.table.h == HinvTable(htable.parse(other)).h


def test_table_from_calibration_json_file(tmp_path, grid):
    p = tmp_path / "calibration.json"
    p.write_text(json.dumps(fp.calibration()))
    c = Controller(table=str(p))
    assert c.table.h == HinvTable(grid).h
    assert c.table.ax[0] < c.table.ax[-1] and c.table.ay[0] < c.table.ay[-1]   # FSM Y ran reversed: sorted


@pytest.mark.parametrize("mutate, match", [
    (lambda cal: cal["points"].pop(), "points"),
    (lambda cal: cal["points"][5]["H"][0].__setitem__(0, float("nan")), "finite"),
    (lambda cal: cal["points"][5]["v0"].__setitem__(0, 9.0), "FSM range"),
    (lambda cal: cal["points"][5].__setitem__("H", [[1.0, 2.0], [2.0, 4.0]]), "singular"),
    (lambda cal: cal["points"][5].__setitem__("pfsm_v", [0.37, 0.0]), "grid_v"),
    (lambda cal: cal.__setitem__("grid_v", "abc"), "grid_v"),
])
def test_bad_calibration_refused_and_previous_kept(tmp_path, grid, mutate, match):
    cal = fp.calibration()
    mutate(cal)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(cal))
    c = Controller(table=grid)
    before = c.table
    with pytest.raises(ValueError, match=match):
        c.set_table(str(p))
    assert c.table is before


def test_constructor_refuses_bad_settings():
    with pytest.raises(ValueError, match="gain_q15"):
        Controller(gain_q15=70000)
    with pytest.raises(ValueError, match="beam_threshold"):
        Controller(beam_threshold=0)
    with pytest.raises(ValueError, match="limit_code"):
        Controller(limit_code=40000)


def test_the_state_slots_read_by_name_are_the_state_lists():
    """``ctl.ticks``, ``ctl.vx_q8``, ... read the state list's slots (no attribute object per slot on the board);
    a name that is no slot nor attribute raises AttributeError."""
    from firmware import controller as m
    c = Controller()
    for k, name in enumerate(m._SLOT_NAMES):
        c._s[m._SLOT_AT[k]] = 1000 + k
    assert [getattr(c, n) for n in m._SLOT_NAMES] == list(range(1000, 1000 + len(m._SLOT_NAMES)))
    assert (c.ticks, c.vx_q8, c.n_sat_episodes) == (c._s[m._S_TICKS], c._s[m._S_VX], c._s[m._S_N_SAT_EP])
    assert len(set(m._SLOT_AT)) == len(m._SLOT_NAMES) == 15 and not hasattr(c, "no_such_slot")
