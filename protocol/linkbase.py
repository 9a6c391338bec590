"""``Link``: what every host transport offers (``protocol.link`` opens them; ``protocol.seriallink`` and
``protocol.canlink`` are the transports)."""

from protocol import core


class Link:
    """Common part: addressing, sequence numbers, ``send``; subclasses move frames."""

    def __init__(self, node):
        self.node = core.node_id(node)
        self.closed = False
        self.closed_why = None    # what closed it, when more than the peer leaving (a serial link)
        self.tx_frames = 0
        self._seq = 0

    def send(self, name_or_id, dst, payload=b"", **fields):
        """Send a packet from this node: ``payload`` bytes, or field values (defaults for the rest).

        Returns the sequence number used. Unknown names, bad lengths and out-of-range values raise ValueError.
        """
        pkt = core.packet_def(name_or_id)
        if payload:
            if fields:
                raise ValueError("%s: give payload bytes or fields, not both" % pkt.name)
            if len(payload) != pkt.size:
                raise ValueError("%s payload is %d bytes, expected %d" % (pkt.name, len(payload), pkt.size))
        else:
            payload = core.encode_payload(pkt.id, fields)
        seq = self._seq
        self.send_raw(pkt.id, self.node, core.node_id(dst), payload)
        return seq

    def send_raw(self, pid, src, dst, payload):
        raise NotImplementedError

    def recv(self, timeout=None):
        """Packets ``[(pid, src, dst, seq, payload)]``, waiting up to ``timeout`` s (None = forever) for at
        least one; [] on timeout or once the peer has left (then ``closed`` is True)."""
        raise NotImplementedError

    def counters(self):
        raise NotImplementedError

    def close(self):
        self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
