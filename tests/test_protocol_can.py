"""CAN mapping: id layout, DBC decoded by cantools, frame decoder, candump lines."""

import random

import cantools
import pytest

from protocol import can as canmap
from protocol import core
from tests import fuzz_frames

SINGLE = sorted(pid for pid in core.PACKET if canmap.is_single(pid))


def test_id_layout_bits():
    cid = canmap.can_id(0xAB, 0x12, 0x34, iso=True)
    prio = canmap.priority(0xAB)
    assert cid == (prio << 26) | (1 << 25) | (0xAB << 17) | (0x12 << 8) | 0x34
    assert canmap.split_id(cid) == (prio, 1, 0xAB, 0x12, 0x34)
    assert canmap.reply_id(cid) == canmap.can_id(0xAB, 0x34, 0x12, iso=True)
    assert cid & canmap.RESERVED_BIT == 0 and cid <= canmap.EFF_MASK
    rng = random.Random(4)
    for _ in range(1000):
        pid, src, dst = rng.getrandbits(8), rng.getrandbits(8), rng.getrandbits(8)
        iso = rng.random() < 0.5
        assert canmap.split_id(canmap.can_id(pid, src, dst, iso))[1:] == (int(iso), pid, src, dst)


def test_lockstep_wins_arbitration_over_uploads():
    tick = canmap.can_id(core.PACKET_ID["TICK"], 0xFF, 0xFF)
    chunk = canmap.can_id(core.PACKET_ID["HTABLE_CHUNK"], 0, 0)
    status = canmap.can_id(core.PACKET_ID["CTRL_STATUS"], 0, 0)
    assert tick < status < chunk   # lower id = dominant bits = wins arbitration


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    path = tmp_path_factory.mktemp("dbc") / "protocol.dbc"
    path.write_text(canmap.dbc_text())
    return cantools.database.load_file(str(path), frame_id_mask=canmap.PID_MASK | canmap.ISOTP_BIT)


def test_dbc_holds_exactly_the_single_frame_packets(db):
    assert sorted(m.name for m in db.messages) == sorted(core.PACKET[p].name for p in SINGLE)
    for m in db.messages:
        pkt = core.packet_def(m.name)
        assert m.length == pkt.size + canmap.CHECK_BYTES and m.is_extended_frame
        assert [s.name for s in m.signals] == list(pkt.names) + ["e2e_check"]
        for s, f in zip(m.signals, pkt.fields):
            assert (s.unit or "") == f[2] and s.scale == f[3] and s.is_float == (f[1] == "f")


@pytest.mark.parametrize("pid", SINGLE, ids=lambda p: core.PACKET[p].name)
def test_cantools_decodes_our_frames_to_the_same_values(db, pid):
    pkt = core.PACKET[pid]
    rng = random.Random(pid)
    for _ in range(50):
        values = fuzz_frames.random_fields(pkt, rng)
        src, dst = rng.getrandbits(8), rng.getrandbits(8)
        [(cid, data)] = canmap.encode_packet(pid, src, dst, values)
        msg = db.get_message_by_frame_id(cid)
        assert msg.name == pkt.name
        raw = msg.decode(data, scaling=False, decode_choices=False)
        assert raw.pop("e2e_check") == canmap.check(pid, src, dst, core.encode_payload(pid, values))
        assert raw == values
        phys = msg.decode(data, decode_choices=False)
        for f in pkt.fields:
            assert phys[f[0]] == pytest.approx(values[f[0]] * f[3], rel=1e-12, abs=1e-12)


def test_decoder_single_and_isotp_packets_round_trip():
    rng = random.Random(6)
    dec = canmap.CanDecoder()
    sent = []
    frames = []
    for pid in sorted(core.PACKET) * 3:
        payload = core.encode_payload(pid, fuzz_frames.random_fields(core.PACKET[pid], rng))
        src, dst = rng.getrandbits(8), rng.getrandbits(8)
        sent.append((pid, src, dst, None, payload))
        frames += canmap.encode_frames(pid, src, dst, payload)
    got = [p for p in (dec.feed(cid, data) for cid, data in frames) if p is not None]
    assert got == sent
    assert sum(dec.drops.values()) == 0 and dec.frames == len(sent)


def test_decoder_drops_by_reason_without_raising():
    dec = canmap.CanDecoder()
    ok = canmap.encode_packet("ACK", 1, 2)[0]
    assert dec.feed(0x123, b"\x01\x02", extended=False) is None
    assert dec.feed(ok[0] | canmap.RESERVED_BIT, ok[1]) is None
    assert dec.feed(canmap.can_id(0xEE, 1, 2), b"\x00") is None                 # no packet 0xEE
    assert dec.feed(ok[0], ok[1] + b"\x00") is None                             # ACK is 2 bytes + check
    multi = canmap.encode_packet("GNSS", 0x51, 0x30)
    assert dec.feed(multi[2][0], multi[2][1]) is None                           # CF without FF
    assert dec.feed(*ok) is not None
    d = dec.counters()
    assert (d["not_extended"], d["reserved_bit"], d["unknown_id"], d["bad_length"], d["unexpected_cf"]) \
        == (1, 1, 1, 1, 1)
    assert d["bad_crc"] == 0
    rng = random.Random(7)
    for _ in range(20000):   # random frames never raise
        dec.feed(rng.getrandbits(30), rng.randbytes(rng.randint(0, 8)), rng.random() < 0.9)


def test_damage_is_told_from_slowness_and_from_the_ports_own_sends():
    """rx_damaged counts what arrived damaged (a failed check or table, an ISO-TP frame breaking its rules, a
    malformed Lawicel line, a damaged serial frame); a transfer timed out or cut short on receive is a drop, not
    damage; what a port counts of its own sends (N_Bs timeouts, late flow control, resends) is neither."""
    damage = {"bad_crc": 1, "bad_seq": 1, "slcan_non_hex": 1, "isotp_WrongSequenceNumberError": 1,
              "bad_cobs": 1, "isotp_OverflowError": 1}
    late = {"unexpected_cf": 1, "isotp_ConsecutiveFrameTimeoutError": 1,
            "isotp_ReceptionInterruptedWithFirstFrameError": 1, "isotp_UnexpectedConsecutiveFrameError": 1,
            "slcan_closed": 1}
    own = {"tx_isotp_TimeoutError": 5, "tx_isotp_UnexpectedFlowControlError": 5, "tx_isotp_timeouts": 5,
           "tx_isotp_resent": 5, "tx_isotp_failed": 5, "tx_frames": 50, "other_dst": 5, "slcan_refused": 5,
           "slcan_reopened": 5, "fault_tx_frames": 50, "fault_rx_dropped": 5}
    c = dict(damage, **late, **own)
    assert canmap.rx_damaged(c) == len(damage)
    assert canmap.rx_damaged(dict(late, **own)) == 0
    assert canmap.rx_drops(c, canmap.LINK_DROPS) == len(damage) + len(late)
    assert set(canmap.RX_DAMAGE) | {"unexpected_cf", "slcan_closed"} == set(canmap.RX_DROPS)
    assert all(("tx_isotp_" + n) not in canmap.LINK_DAMAGE for n in canmap.ISOTP_TX)


def test_end_to_end_check_catches_a_damaged_payload_or_id():
    """Every single-bit flip of a frame's data, and a frame delivered to another node or packet id, fails the
    check (a flipped hex digit in an slcan line is still a valid frame: only the check catches it)."""
    dec = canmap.CanDecoder()
    expect = 1
    for name in ("RW_CMD", "ACK", "HELLO"):
        [(cid, data)] = canmap.encode_packet(name, 0x30, 0x40, **({"torque": 1e-3} if name == "RW_CMD" else {}))
        assert dec.feed(cid, data) is not None
        expect += len(data) * 8 + 2
        for i in range(len(data) * 8):
            bad = bytearray(data)
            bad[i // 8] ^= 1 << (i % 8)
            assert dec.feed(cid, bytes(bad)) is None
        assert dec.feed(cid ^ 0x01, data) is None                 # another destination
        assert dec.feed(cid ^ (0x01 << 8), data) is None          # another source
    frames = canmap.encode_packet("GNSS", 0x51, 0x30)
    cid, last = frames[-1]
    frames[-1] = (cid, last[:1] + bytes((last[1] ^ 0x10,)) + last[2:])
    assert [dec.feed(c, d) for c, d in frames] == [None] * len(frames)
    assert dec.drops["bad_crc"] == expect and sum(dec.drops.values()) == expect


def test_candump_lines_round_trip():
    for cid, data in canmap.encode_packet("CTRL_STATUS", 0x10, 0x01, tick=7):
        line = canmap.candump_line(cid, data, t=12.5, channel="vcan0")
        assert line.startswith("(12.500000) vcan0 %08X#" % cid)
        assert canmap.parse_candump(line) == (12.5, "vcan0", cid, True, data)
    assert canmap.parse_candump("(1.0) can0 123#0102")[2:] == (0x123, False, b"\x01\x02")
    for bad in ("", "junk", "(1.0) can0 123#R", "(1.0) can0 123##1"):
        with pytest.raises(ValueError):
            canmap.parse_candump(bad)
