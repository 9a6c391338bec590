"""protocol.consts, the packet table's numbers generated for the firmware (protocol.gen), and protocol.frame, the
framing that needs only them: current with the table, and the same as protocol.core's lookups."""

import struct

from protocol import consts, core, frame, gen, table


def test_consts_is_what_the_table_gives_now():
    with open(gen.PATH) as f:
        assert f.read() == gen.source(), "protocol/consts.py is stale: run python -m protocol.gen"
    assert gen.main(["--check"]) == 0


def test_consts_agree_with_cores_lookups():
    for pid in range(256):
        d = core.PACKET.get(pid)
        assert consts.SIZES[pid] == (0xFF if d is None else d.size)
        if d is not None:
            assert getattr(consts, "P_" + d.name) == pid and getattr(consts, "FMT_" + d.name) == d.fmt
    for name, addr in core.NODE.items():
        assert getattr(consts, "NODE_" + name) == addr
    for name, code in core.ERROR.items():
        assert getattr(consts, "E_" + name) == code
    assert consts.PROTOCOL_VERSION == table.PROTOCOL_VERSION
    t = [struct.unpack_from("<H", consts.CRC16_TABLE, 2 * i)[0] for i in range(256)]
    assert t == gen.crc16_table() and frame.crc16_pure(b"123456789") == 0x29B1    # CRC-16/CCITT-FALSE check value


def test_a_stale_consts_is_caught(tmp_path, monkeypatch, capsys):
    stale = tmp_path / "consts.py"
    stale.write_text(gen.source().replace("P_TICK = 0x10", "P_TICK = 0x11"))
    monkeypatch.setattr(gen, "PATH", str(stale))
    assert gen.main(["--check"]) == 1 and "stale" in capsys.readouterr().err
    assert gen.main([]) == 0 and stale.read_text() == gen.source()


def test_the_decoder_counts_a_packet_the_table_lacks_and_a_wrong_length():
    d = frame.Decoder()
    good = core.encode_payload("TICK", tick=1, vx=1, vy=2, vs=3)
    frames = (core.encode_frame(0x10, 1, 2, 0, good) + core.encode_frame(0xEE, 1, 2, 1, b"\x00")
              + core.encode_frame(0x10, 1, 2, 2, good[:-1]))
    out = d.feed(frames)
    assert [p[0] for p in out] == [0x10] and d.drops["unknown_id"] == 1 and d.drops["bad_length"] == 1
    assert d.dropped() == 2
