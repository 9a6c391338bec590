"""Link HAL for a bare-metal board's console UART: packets framed by ``protocol.frame`` over ``sys.stdin.buffer`` and
``sys.stdout.buffer`` (MicroPython with binary stdio). The PIL image (ground/pil_build.py, MicroPython's qemu port
on a Cortex-M0) has no ``select`` and no ``time``: ``recv_ms`` blocks until a packet is complete whatever its
timeout, so link silence is not counted on this HAL (the lockstep bench always sends the next TICK)."""

import sys

from protocol import frame
from protocol.consts import P_FSM_SPI

_MAX_FRAME = frame.MAX_FRAME


class StdioLink:
    """``serve_controller``'s link on the console UART: ``node``, ``recv_ms``, ``send_raw``, ``closed``,
    ``counters``, ``rx_drops``, ``close``. ``node``: the node address (``protocol.consts.NODE_*``); ``meter``: an
    object with ``now()`` (a 16-bit clock) and ``exchange(t0, work, n)``, told of each TICK exchange: the decoding
    of each of its frame's bytes, then from the frame's end to its FSM_SPI framed, less the UART's own reads and
    writes (on a board an interrupt or a DMA channel moves the bytes while the CPU does other work), in ``n``
    timed intervals (``firmware.pil_main.Meter``); ``read_frame(buf, n)``: a board's UART driver reading a whole
    frame into buf (``firmware.hal.nrf51.read_frame``), in place of ``reader``'s byte at a time."""

    def __init__(self, node, reader=None, writer=None, meter=None, read_frame=None):
        self.node = node
        self._r = reader if reader is not None else sys.stdin.buffer
        self._w = writer if writer is not None else sys.stdout.buffer
        self._buf = bytearray(1)
        self._frame = bytearray(_MAX_FRAME)
        self._i = 0                # bytes of the frame being read (beyond _MAX_FRAME: counted, not kept)
        self._dec = frame.Decoder()
        self._enc = frame.Encoder()
        self._seq = 0
        self.tx_frames = 0
        self.closed = False
        self._meter = meter
        self._read_frame = read_frame
        self._work = 0             # meter ticks spent on the bytes of the frame being read (the waits left out)
        self._n = 0                # the intervals they were timed in
        self._t_frame = 0          # meter's time at the end of the last complete frame
        self._frame_work = 0       # its bytes' ticks and intervals, then less the UART writes since
        self._frame_n = 0

    def recv_ms(self, timeout_ms=None):
        """The packets the next complete frame gives (blocking; [] once the input has ended). The bytes go one by
        one into a frame buffer (no allocation) and the decoder gets the whole frame at its 0x00: fed byte by byte,
        it would copy a slice per byte, and the garbage would run the GC over and over (14,000 instructions a byte
        on the Cortex-M0, measured)."""
        b = self._buf
        fr = self._frame
        mt = self._meter
        if self._read_frame is not None:
            return self._recv_frame(fr, mt)
        while not self.closed:
            if not self._r.readinto(b):
                self.closed = True
                return []
            if mt is not None:
                t = mt.now()
            x = b[0]
            i = self._i
            if i < _MAX_FRAME:
                fr[i] = x
            self._i = i = i + 1
            if x:
                if mt is not None:
                    self._work += (mt.now() - t) & 0xFFFF
                    self._n += 1
                continue
            self._i = 0
            if i > _MAX_FRAME:         # longer than any frame: dropped whole, the next starts after this 0x00
                self._dec.drops["oversize"] += 1
                out = None
            else:
                out = self._dec.feed(fr, i)
            if mt is not None:
                self._t_frame = mt.now()
                self._frame_work = self._work + ((self._t_frame - t) & 0xFFFF)
                self._frame_n = self._n + 1
                self._work = 0
                self._n = 0
            if out:
                return out
        return []

    def _recv_frame(self, fr, mt):
        """``recv_ms`` with a whole frame read by the board's UART driver (``read_frame``)."""
        while True:
            i = self._read_frame(fr, _MAX_FRAME)
            if mt is not None:
                t = mt.now()
            if i > _MAX_FRAME:
                self._dec.drops["oversize"] += 1
                out = None
            else:
                out = self._dec.feed(fr, i)
            if mt is not None:
                self._t_frame = mt.now()
                self._frame_work = (self._t_frame - t) & 0xFFFF
                self._frame_n = 1
            if out:
                return out

    def send_raw(self, pid, src, dst, payload, seq=None):
        if seq is None:
            seq = self._seq
            self._seq = (seq + 1) & 0xFF
        f = self._enc.frame(pid, src, dst, seq, payload)
        mt = self._meter
        if mt is None:
            self._w.write(f)
        else:                      # the UART write left out: on a board a DMA channel or an interrupt sends it
            t = mt.now()
            self._w.write(f)
            self._frame_work -= (mt.now() - t) & 0xFFFF
            self._frame_n -= 1
        self.tx_frames += 1
        if pid == P_FSM_SPI and mt is not None:     # the answer to a TICK: its exchange is over
            mt.exchange(self._t_frame, self._frame_work, self._frame_n + 1)

    def rx_drops(self):
        """Frames the decoder dropped (every ``frame.DROP_REASONS``)."""
        return self._dec.dropped()

    def counters(self):
        d = self._dec.counters()
        d["tx_frames"] = self.tx_frames
        return d

    def close(self):
        self.closed = True
