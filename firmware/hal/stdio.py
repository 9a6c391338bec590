"""Link HAL for a bare-metal board's console UART: packets framed by ``protocol.core`` over ``sys.stdin.buffer`` and
``sys.stdout.buffer`` (MicroPython with binary stdio). The PIL image (ground/pil_build.py, MicroPython's qemu port
on a Cortex-M0) has no ``select`` and no ``time``: ``recv_ms`` blocks until a packet is complete whatever its
timeout, so link silence is not counted on this HAL (the lockstep bench always sends the next TICK)."""

import sys

from protocol import core


class StdioLink:
    """``serve_controller``'s link on the console UART: ``node``, ``recv_ms``, ``send_raw``, ``closed``,
    ``counters``, ``close``."""

    def __init__(self, node, reader=None, writer=None):
        self.node = core.node_id(node)
        self._r = reader if reader is not None else sys.stdin.buffer
        self._w = writer if writer is not None else sys.stdout.buffer
        self._buf = bytearray(1)
        self._dec = core.Decoder()
        self._enc = core.Encoder()
        self._seq = 0
        self.tx_frames = 0
        self.closed = False

    def recv_ms(self, timeout_ms=None):
        """The packets the next complete frame gives (blocking; [] once the input has ended)."""
        while not self.closed:
            n = self._r.readinto(self._buf)
            if not n:
                self.closed = True
                return []
            out = self._dec.feed(self._buf, n)
            if out:
                return out
        return []

    def send_raw(self, pid, src, dst, payload, seq=None):
        if seq is None:
            seq = self._seq
            self._seq = (seq + 1) & 0xFF
        self._w.write(self._enc.frame(pid, src, dst, seq, payload))
        self.tx_frames += 1

    def counters(self):
        d = self._dec.counters()
        d["tx_frames"] = self.tx_frames
        return d

    def close(self):
        self.closed = True
