"""Transports in one process: in-process pair, loop://, pty master against pyserial and StreamLink, CAN
virtual; error handling and the peer leaving."""

import itertools
import random
import threading

import pytest

from protocol import core, link
from protocol.stream import StreamLink
from tests import fuzz_frames

_ch = itertools.count()


def every_packet(seed):
    """[(pid, payload)] for every packet type, random valid values."""
    rng = random.Random(seed)
    return [(pid, core.encode_payload(pid, fuzz_frames.random_fields(core.PACKET[pid], rng)))
            for pid in sorted(core.PACKET)]


def all_bytes_chunks():
    """HTABLE_CHUNK payloads whose data covers every byte value (control characters included)."""
    data = bytes(range(256))
    return [(core.PACKET_ID["HTABLE_CHUNK"], core.encode_payload("HTABLE_CHUNK", offset=i, length=48,
                                                                 data=data[i:i + 48].ljust(48, b"\x03")))
            for i in range(0, 256, 48)]


def exchange(a, b, packets, recv_a=None, recv_b=None):
    """Send every packet a -> b and back b -> a; check ids, addresses and payload bytes."""
    recv_a = recv_a or (lambda: a.recv(2.0))
    recv_b = recv_b or (lambda: b.recv(2.0))
    for pid, payload in packets:
        a.send(pid, b.node, payload)
        [(p, src, dst, seq, got)] = recv_b()
        assert (p, src, dst, got) == (pid, a.node, b.node, payload)
        b.send(pid, a.node, payload)
        [(p, src, dst, seq, got)] = recv_a()
        assert (p, src, dst, got) == (pid, b.node, a.node, payload)


def test_inproc_pair_every_packet_and_close():
    a, b = link.inproc_pair("BENCH", "CONTROLLER")
    exchange(a, b, every_packet(1) + all_bytes_chunks())
    assert a.counters()["frames"] == b.counters()["frames"] == len(core.PACKET) + 6
    b.close()
    assert a.recv(0.1) == [] and a.closed


def test_loop_url_counts_damage_and_recovers():
    lp = link.open_link("loop://", "GROUND")
    lp.write(b"\x01\x02garbage\x00")
    seq = lp.send("TICK", "CONTROLLER", tick=9)
    [(pid, src, dst, q, payload)] = lp.recv(1.0)
    assert (pid, src, dst, q) == (core.PACKET_ID["TICK"], 0x01, 0x10, seq)
    assert core.payload_dict(pid, payload)["tick"] == 9
    c = lp.counters()
    assert c["bad_cobs"] + c["bad_crc"] == 1 and c["frames"] == 1 and c["tx_frames"] == 1
    lp.close()


def test_pty_master_and_pyserial_peer():
    m = link.open_link("pty", "BENCH")
    s = link.open_link("serial:" + m.peer_path, "CONTROLLER")
    exchange(s, m, every_packet(2) + all_bytes_chunks())
    assert m.counters()["seq_gaps"] == 0 and sum(m.counters()[r] for r in core.DROP_REASONS) == 0
    s.close()
    assert m.recv(1.0) == [] and m.closed          # EIO on the master: the peer left
    m.close()


def test_pty_master_and_stream_link_peer_both_leave():
    m = link.open_link("pty", "BENCH")
    s = StreamLink(m.peer_path, "CONTROLLER")
    exchange(s, m, every_packet(3) + all_bytes_chunks(), recv_a=lambda: s.recv(2000))
    assert s.counters()["frames"] == len(core.PACKET) + 6
    m.close()
    assert s.recv(1000) == [] and s.closed         # POLLHUP / EIO on the slave
    s.close()


def test_pty_bytes_written_before_the_peer_opens_arrive_raw():
    m = link.open_link("pty", "BENCH")
    pid, payload = all_bytes_chunks()[0]
    m.send(pid, "CONTROLLER", payload)     # before anyone opened the slave
    s = StreamLink(m.peer_path, "CONTROLLER")
    [(p, src, dst, seq, got)] = s.recv(2000)
    assert (p, got) == (pid, payload)
    s.close()
    m.close()


def test_can_virtual_every_packet_single_and_isotp():
    ch = "link-test-%d" % next(_ch)
    a = link.open_link("can:virtual:" + ch, "ADCS")
    b = link.open_link("can:virtual:" + ch, "GNSS")
    packets = every_packet(4)
    got = []

    def echo():   # ISO-TP needs the receiver running while the sender waits for flow control
        while len(got) < len(packets):
            for p in b.recv(2.0):
                got.append(p)
                b.send_raw(p[0], b.node, p[1], p[4])

    t = threading.Thread(target=echo)
    t.start()
    for pid, payload in packets:
        a.send(pid, "GNSS", payload)
        [(p, src, dst, seq, back)] = a.recv(2.0)
        assert (p, src, dst, seq, back) == (pid, b.node, a.node, None, payload)
    t.join(5)
    assert [(p[0], p[4]) for p in got] == packets
    assert a.counters()["frames"] == len(packets) and a.counters()["unknown_id"] == 0
    a.close()
    b.close()


def test_can_link_ignores_other_destinations():
    ch = "link-test-%d" % next(_ch)
    a = link.open_link("can:virtual:" + ch, "ADCS")
    b = link.open_link("can:virtual:" + ch, "RW0")
    a.send("RW_CMD", "RW1", torque=0.5)
    a.send("RW_CMD", "BROADCAST", torque=0.25)
    [(pid, src, dst, seq, payload)] = b.recv(1.0)
    assert dst == 0xFF and core.payload_dict(pid, payload)["torque"] == 0.25
    assert b.counters()["other_dst"] == 1
    a.close()
    b.close()


def test_can_link_accepts_the_nodes_it_serves():
    """A HIL host's BENCH link also takes GROUND's packets (single frames and ISO-TP flow control): it can
    send as GROUND and get the answers, and still drops other destinations."""
    ch = "link-test-%d" % next(_ch)
    host = link.open_link("can:virtual:" + ch, "BENCH", accept=("GROUND",))
    ctrl = link.open_link("can:virtual:" + ch, "CONTROLLER")
    serial = link.open_link("inproc", "BENCH", accept=("GROUND",))   # serial links deliver all: no-op there
    assert serial.node == core.NODE["BENCH"]
    serial.close()
    [(pid, chunk)] = all_bytes_chunks()[:1]
    ground = core.NODE["GROUND"]
    host.send_raw(pid, ground, ctrl.node, chunk)       # ISO-TP: ctrl's flow control goes to GROUND
    [(p, src, dst, seq, got)] = ctrl.recv(2.0)
    assert (p, src, dst, got) == (pid, ground, ctrl.node, chunk)
    ack = core.encode_payload("ACK", ref_id=pid, ref_seq=0)
    ctrl.send_raw(core.PACKET_ID["ACK"], ctrl.node, ground, ack)
    ctrl.send_raw(pid, ctrl.node, ground, chunk)
    ctrl.send("RW_CMD", "RW1", torque=0.5)
    got = []
    while len(got) < 2:
        got += host.recv(2.0)
    assert [(p[0], p[2], p[4]) for p in got] == [(core.PACKET_ID["ACK"], ground, ack), (pid, ground, chunk)]
    assert host.recv(0.1) == [] and host.counters()["other_dst"] == 1
    host.close()
    ctrl.close()


def test_can_isotp_flow_control_answered_while_receiver_busy():
    """The receive thread answers flow control: a long packet gets through while the receiver is not in recv."""
    ch = "link-test-%d" % next(_ch)
    a = link.open_link("can:virtual:" + ch, "GROUND")
    b = link.open_link("can:virtual:" + ch, "CONTROLLER")
    chunks = all_bytes_chunks()
    for pid, payload in chunks:
        a.send(pid, "CONTROLLER", payload)             # would raise TimeoutError without flow control
    got = []
    while len(got) < len(chunks):
        got += b.recv(2.0)
    assert [(p[0], p[4]) for p in got] == chunks
    assert not any(k.startswith("isotp_") for k in a.counters())
    a.close()
    b.close()
    assert b.recv(0.1) == [] and b.closed


def test_send_and_spec_errors():
    a, b = link.inproc_pair("GROUND", "CONTROLLER")
    with pytest.raises(ValueError, match="unknown packet name 'NOPE'"):
        a.send("NOPE", "CONTROLLER")
    with pytest.raises(ValueError, match="TICK payload is 3 bytes, expected 14"):
        a.send("TICK", "CONTROLLER", b"abc")
    with pytest.raises(ValueError, match="CTRL_SETTINGS.mode = 9 out of range"):
        a.send("CTRL_SETTINGS", "CONTROLLER", mode=9)
    with pytest.raises(ValueError, match="unknown node 'MARS'"):
        a.send("ACK", "MARS")
    with pytest.raises(ValueError, match="unknown link spec 'tcp:1'"):
        link.open_link("tcp:1", "GROUND")
    with pytest.raises(ValueError, match="expected can:INTERFACE:CHANNEL"):
        link.open_link("can:virtual", "GROUND")
    assert b.recv(0.05) == [] and a.tx_frames == 0
