"""The link HAL's links on a desktop: ``open_link`` gives ``firmware.hal.link.serve_controller`` and
``serve_player`` a ``protocol.stream.StreamLink`` for ``serial:PATH`` under MicroPython's unix port and, under
CPython, any ``protocol.link`` spec (``serial:PATH`` through pyserial, ``slcan:PATH`` for CAN). Apart from
``firmware.hal.link`` so that a board with little RAM (``firmware.pil_main``) does not load them."""

import sys

_MICROPYTHON = sys.implementation.name == "micropython"


class _Ms:
    """Adapter giving a ``protocol.link.Link`` (timeout in s) the StreamLink's ``recv_ms``."""

    def __init__(self, link):
        self.link = link
        self.node = link.node

    def recv_ms(self, timeout_ms):
        return self.link.recv(None if timeout_ms is None else timeout_ms / 1000.0)

    def send_raw(self, pid, src, dst, payload):
        self.link.send_raw(pid, src, dst, payload)

    @property
    def closed(self):
        return self.link.closed

    @property
    def closed_why(self):
        return getattr(self.link, "closed_why", None)

    def close(self):
        self.link.close()

    def counters(self):
        return self.link.counters()

    def rx_drops(self):
        """What the link dropped on receive (``protocol.can.rx_drops`` over its counters: a serial link's decoder
        or a CAN link's, ISO-TP included)."""
        from protocol import can     # host and unix port only: a bare-metal board's link HAL counts its own
        return can.rx_drops(self.link.counters(), can.LINK_DROPS)


class _StreamMs(_Ms):
    """A StreamLink already speaks ms: its own bound methods, one call less per packet."""

    def __init__(self, link):
        _Ms.__init__(self, link)
        self.recv_ms = link.recv
        self.send_raw = link.send_raw


def open_link(spec, node, isotp_ms=None):
    """A link for ``spec`` with ``recv_ms``/``send_raw``/``closed``/``close``; ``isotp_ms``: a CAN link's
    ISO-TP N_Bs (None: ISO's 1000 ms)."""
    if _MICROPYTHON:
        if not spec.startswith("serial:"):
            raise ValueError("link %r: MicroPython speaks serial:PATH only" % spec)
        from protocol.stream import StreamLink
        return _StreamMs(StreamLink(spec[len("serial:"):], node))
    from protocol import link as hostlink
    kw = {}
    if isotp_ms is not None and not spec.startswith("serial:"):
        kw["isotp_timeout_s"] = isotp_ms / 1000.0
    return _Ms(hostlink.open_link(spec, node, **kw))
