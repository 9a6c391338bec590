"""Host (CPython) transports carrying packets: pyserial, pseudo-terminals, python-can, in-process.

``open_link(spec, node)`` returns a ``Link``; specs:

- ``inproc``: an in-process pair; the returned Link's ``.peer`` is the other end (see ``inproc_pair``).
- ``loop://`` or ``serial:PATH`` or any pyserial URL/path (``/dev/ttyUSB0``, ``serial:/dev/pts/3``).
- ``pty``: create a pseudo-terminal pair; the Link holds the master, ``.peer_path`` is the slave for
  another process (``serial:PATH`` or ``protocol.stream.StreamLink``). The slave is in raw mode before any
  byte is written; this side keeps it open until the peer's first byte arrives, after which EIO on the
  master means the peer left (``closed``).
- ``can:virtual:CHANNEL`` (or ``can:INTERFACE:CHANNEL``): python-can.
- ``slcan:PATH``: python-can's slcan adapter on a serial device or pty slave, read in blocks and dropping
  malformed lines (``protocol.slcanbus.SlcanBus``).
- ``slcan-pty``: be the slcan *device*: create a pty, speak Lawicel ASCII on the master
  (``protocol.slcanbus.LawicelBus``), ``.peer_path`` for the process that opens ``slcan:PATH``.

Serial links frame with ``protocol.host`` (COBS + CRC-16). CAN links send a packet (payload and its end-to-end
check) of up to 8 bytes as one frame and longer ones with ISO-TP (PyPI ``can-isotp``), ids per
``protocol.can``; a receive thread answers ISO-TP flow control at once, and ``accept=(nodes...)`` makes a CAN
link also deliver packets addressed to the nodes it serves (see ``CanLink``).
"""

from protocol.canlink import CanLink, isotp_msg, open_can, open_slcan_device  # noqa: F401  (the transports' names)
from protocol.fdport import PeerGone  # noqa: F401
from protocol.linkbase import Link  # noqa: F401
from protocol.seriallink import SerialLink, inproc_pair, open_pty, open_serial  # noqa: F401


def open_link(spec, node, **kw):
    """A Link for ``spec`` (see the module docstring); ``node`` is a node name or address.

    ``accept``: further destination nodes a CAN link delivers (see ``CanLink``); serial links deliver every
    packet whatever its destination, so it changes nothing there."""
    accept = kw.pop("accept", ())
    if spec == "inproc":
        a, _ = inproc_pair(node, kw.get("peer_node", "BROADCAST"))
        return a
    if spec == "pty":
        return open_pty(node)
    if spec == "slcan-pty":
        return open_slcan_device(node, accept, **kw)
    if spec.startswith("slcan:"):
        return open_can("slcan", spec[len("slcan:"):], node, accept, **kw)
    if spec.startswith("can:"):
        parts = spec.split(":", 2)
        if len(parts) != 3 or not parts[1] or not parts[2]:
            raise ValueError("CAN link spec %r: expected can:INTERFACE:CHANNEL" % spec)
        return open_can(parts[1], parts[2], node, accept, **kw)
    if spec.startswith("serial:"):
        return open_serial(spec[len("serial:"):], node, **kw)
    if "://" in spec or spec.startswith("/") or spec.upper().startswith("COM"):
        return open_serial(spec, node, **kw)
    raise ValueError("unknown link spec %r (inproc, pty, loop://, serial:PATH, can:virtual:CH, slcan:PATH, "
                     "slcan-pty)" % spec)


def first_contact(send_hello, recv, wait_s, gap_s=0.05, gap_max_s=None, check=None, stop=None):
    """Say HELLO (``send_hello()``) until the peer speaks: again after ``gap_s``, the gap doubling up to
    ``gap_max_s`` (None: fixed), so a HELLO lost either way costs one retry. ``recv(timeout_s)`` returns the
    packets that came; ``check()`` (each try) raises OSError for a dead peer or a closed link; ``stop(packets)``
    says whether these packets are the answer (default: any packet). Returns (HELLOs sent, every packet received
    up to and with the answer), or (HELLOs sent, None) after ``wait_s`` seconds."""
    import time
    deadline = time.monotonic() + wait_s
    gap, tries, got = gap_s, 0, []
    stop = stop or bool
    while True:
        if check is not None:
            check()
        now = time.monotonic()
        if now >= deadline:
            return tries, None
        send_hello()
        tries += 1
        end = min(deadline, now + gap)
        gap = gap if gap_max_s is None else min(2 * gap, gap_max_s)
        while True:
            left = end - time.monotonic()
            if left <= 0:
                break
            pkts = recv(left)
            got.extend(pkts)
            if pkts and stop(pkts):
                return tries, got
