"""The pure ISO-TP (protocol.isotp) against the PyPI can-isotp package over python-can's virtual bus."""

import itertools
import random
import time

import can
import isotp as canisotp
import pytest

from protocol import can as canmap
from protocol import isotp

LENGTHS = (1, 6, 7, 8, 13, 62, 111, 255, 1000, 4095)
_channels = itertools.count()


@pytest.fixture(params=[(0, 0, 0), (3, 1, 2)], ids=["bs0", "bs3-stmin1ms"])
def pair(request):
    """(host can-isotp stack, pure IsoTp, pure bus, pure rx id); host params blocksize/stmin, pure blocksize."""
    bs, stmin, pure_bs = request.param
    ch = "isotp-test-%d" % next(_channels)
    host_bus = can.Bus(interface="virtual", channel=ch)
    pure_bus = can.Bus(interface="virtual", channel=ch)
    to_host = canmap.can_id(0x24, 0x01, 0x10, iso=True)   # pure (GROUND) -> host (CONTROLLER)
    to_pure = canmap.reply_id(to_host)
    stack = canisotp.CanStack(host_bus, address=canisotp.Address(
        canisotp.AddressingMode.Normal_29bits, txid=to_pure, rxid=to_host),
        params={"blocksize": bs, "stmin": stmin, "max_frame_size": 4095})
    stack.start()

    def tx(data):
        pure_bus.send(can.Message(arbitration_id=to_host, data=data, is_extended_id=True))

    pure = isotp.IsoTp(tx, block_size=pure_bs)
    yield stack, pure, pure_bus, to_pure
    stack.stop()
    host_bus.shutdown()
    pure_bus.shutdown()


def pump(pure, bus, rxid, until, timeout=10.0):
    """Feed the pure side every frame on its rx id until ``until(result)``; returns the payloads seen."""
    got = []
    t_end = time.monotonic() + timeout
    while not until(got):
        assert time.monotonic() < t_end, "timeout"
        msg = bus.recv(0.05)
        if msg is not None and msg.arbitration_id == rxid:
            p = pure.feed(msg.data)
            if p is not None:
                got.append(p)
    return got


def test_host_to_pure_identical_payloads(pair):
    stack, pure, bus, rxid = pair
    rng = random.Random(1)
    for n in LENGTHS:
        payload = rng.randbytes(n)
        stack.send(payload)
        [got] = pump(pure, bus, rxid, lambda g: len(g) == 1)
        assert got == payload
    assert sum(pure.errors.values()) == 0


def test_pure_to_host_identical_payloads(pair):
    stack, pure, bus, rxid = pair
    rng = random.Random(2)
    for n in LENGTHS:
        payload = rng.randbytes(n)
        pure.send(payload)
        pump(pure, bus, rxid, lambda g: not pure.sending)
        got = stack.recv(block=True, timeout=5)
        assert got == payload


def test_segment_layout_and_limits():
    assert isotp.segment(b"abc") == [b"\x03abc"]
    frames = isotp.segment(bytes(range(20)))
    assert frames[0] == b"\x10\x14" + bytes(range(6))
    assert [f[0] for f in frames[1:]] == [0x21, 0x22]
    assert b"".join(f[1:] for f in frames[1:]) == bytes(range(6, 20))
    sns = [f[0] & 0x0F for f in isotp.segment(bytes(200))[1:]]
    assert sns[:16] == [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 0]
    with pytest.raises(ValueError, match="4096 bytes > 4095"):
        isotp.segment(bytes(4096))


def test_receiver_errors_counted_and_recovered():
    sent = []
    ch = isotp.IsoTp(sent.append)
    frames = isotp.segment(bytes(range(30)))
    assert ch.feed(frames[0]) is None and sent == [b"\x30\x00\x00"]   # FF answered by flow control
    assert ch.feed(frames[2]) is None                                  # CF 2 before CF 1
    assert ch.errors["bad_seq"] == 1
    assert ch.feed(frames[1]) is None and ch.errors["unexpected_cf"] == 1  # transfer was aborted
    assert ch.feed(b"") is None and ch.feed(b"\x08" + bytes(7)) is None and ch.feed(b"\x40") is None
    assert (ch.errors["bad_pci"], ch.errors["bad_length"]) == (2, 1)
    out = None
    for f in frames:
        out = ch.feed(f)
    assert out == bytes(range(30))
    assert ch.feed(b"\x02ab\xcc\xcc\xcc\xcc\xcc") == b"ab"   # padding ignored


def test_sender_honours_block_size_and_overflow():
    sent = []
    ch = isotp.IsoTp(sent.append)
    ch.send(bytes(100))          # FF + 14 CFs
    assert len(sent) == 1 and ch.sending
    ch.feed(b"\x30\x04\x00")     # 4 CFs, then wait for the next FC
    assert len(sent) == 5 and ch.sending
    ch.feed(b"\x31\x00\x00")     # wait
    assert len(sent) == 5
    ch.feed(b"\x30\x00\x00")     # the rest
    assert len(sent) == 15 and not ch.sending
    ch.send(bytes(100))
    ch.feed(b"\x32\x00\x00")     # overflow: abort
    assert not ch.sending and ch.errors["overflow"] == 1
