"""Host (CPython) fast path of the framing core: crcmod's C CRC and the ``cobs`` package.

Same names and behaviour as ``protocol.core`` (``encode_frame``, ``encode_packet``, ``Decoder`` with the
same drop counters); only the CRC-16 and COBS functions are swapped. ``tests/test_protocol_host.py``
proves both paths give identical bytes.
"""

import crcmod.predefined
from cobs import cobs

from protocol import core

crc16 = crcmod.predefined.mkCrcFun("crc-ccitt-false")
cobs_encode = cobs.encode


def cobs_decode(data):
    """COBS decode; None if the encoding is invalid (never raises on bytes)."""
    try:
        return cobs.decode(data)
    except cobs.DecodeError:
        return None


def encode_frame(pid, src, dst, seq, payload):
    """One serial frame: COBS(body + CRC16 big-endian) + 0x00 (see ``protocol.core``)."""
    return core.encode_frame(pid, src, dst, seq, payload, crc16, cobs_encode)


def encode_packet(name_or_id, src, dst, seq=0, values=None, **kw):
    """Encode a whole frame from raw field values in one call."""
    pkt = core.packet_def(name_or_id)
    return encode_frame(pkt.id, src, dst, seq, core.encode_payload(pkt.id, values, **kw))


class Decoder(core.Decoder):
    """``core.Decoder`` with crcmod and ``cobs`` plugged in."""

    def __init__(self):
        core.Decoder.__init__(self, crc16, cobs_decode)
