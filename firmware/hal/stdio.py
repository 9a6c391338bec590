"""Link HAL for a bare-metal board's console UART: packets framed by ``protocol.frame`` over ``sys.stdin.buffer`` and
``sys.stdout.buffer`` (MicroPython with binary stdio). The PIL image (tools/pil_build.py, MicroPython's qemu port
on a Cortex-M0) has no ``select`` and no ``time``: ``recv_ms`` blocks until a packet is complete whatever its
timeout, so link silence is not counted on this HAL (the lockstep bench always sends the next TICK)."""

import gc
import sys
from array import array

from firmware.controller import heap_lock, heap_unlock
from protocol import frame
from protocol.consts import LARGEST_PAYLOAD, P_CTRL_STATUS, P_FSM_SPI, P_TICK, SIZES

# its own shim, not protocol.compat's: the controller's 32 KB board has no RAM for one more module
try:
    from micropython import const
except ImportError:                    # CPython
    def const(x):
        return x

_MAX_FRAME = frame.frame_bytes(LARGEST_PAYLOAD)     # the packet table's longest frame (not the framing's 255 bytes)
# the link's counters in ``_st`` (the layout ``firmware.hal.fast_tick.answer`` keeps; tests/test_pil.py checks it)
_ST_TX_SEQ = const(0)
_ST_TX_FRAMES = const(1)
_ST_RX_FRAMES = const(2)
_ST_RX_SRC = const(3)
_ST_RX_SEQ = const(4)
_ST_SPI_N = const(5)
_ST_KIND = const(6)                    # the exchange's kind (_K_*): serve_controller sets a resend's or a status's
_ST_RX_GAPS = const(7)                 # sequence gaps in the frames the fast path decoded (the decoder's seq_gaps)
# the kinds of TICK exchange a meter tells apart (in ``_st[_ST_KIND]`` for the bytecode path, which
# ``firmware.hal.link.serve_controller`` sets): the common tick in machine code, the same with a new H^-1 bin, a
# CTRL_STATUS tick, a resent TICK answered from the cache, any other TICK the machine code leaves to the bytecode path
_K_COMMON = const(0)
_K_BIN = const(1)
_K_STATUS = const(2)
_K_RESEND = const(3)
_K_OTHER = const(4)
_S_BXQ = const(13)                     # firmware.controller.S_BXQ, S_BYQ: the cached H^-1 bin's state slots
_S_BYQ = const(14)


class StdioLink:
    """``serve_controller``'s link on the console UART: ``node``, ``recv_ms``, ``send_raw``, ``closed``,
    ``counters``, ``rx_drops``, ``close``. ``node``: the node address (``protocol.consts.NODE_*``); ``meter``: an
    object with ``now()`` (a 16-bit clock), ``start()`` (the same read at its next step, where the machine-code path
    times from) and ``exchange(t0, work, n, kind)``, told of each TICK exchange (``_K_*``;
``_st[_ST_KIND]``: the bytecode path's, which ``serve_controller`` sets for a resend or a status): the decoding
    of each of its frame's bytes, then from the frame's end to its FSM_SPI framed (a status tick's: to the
    CTRL_STATUS framed after it), less the UART's own reads and
    writes (on a board an interrupt or a DMA channel moves the bytes while the CPU does other work), in ``n``
    timed intervals (``firmware.pil_main.Meter``); ``read_frame(buf, n)``: a board's UART driver reading a whole
    frame into buf (``firmware.hal.nrf51.read_frame``), in place of ``reader``'s byte at a time; ``write_frame(buf,
    n)``: its writer of buf[0:n], in place of ``writer``; ``fast``: the common TICK's machine-code path
    (``firmware.hal.fast_tick.answer``), which ``serve_controller`` runs through ``answer_ticks`` (needs
    ``read_frame``, and ``status``: its CTRL_STATUS packer, ``firmware.hal.fast_status.status``)."""

    def __init__(self, node, reader=None, writer=None, meter=None, read_frame=None, write_frame=None, fast=None,
                 status=None):
        self.node = node
        self._r = reader if reader is not None else sys.stdin.buffer
        self._w = writer if writer is not None else sys.stdout.buffer
        self._buf = bytearray(1) if read_frame is None else None
        self._frame = bytearray(_MAX_FRAME)
        self._i = 0                # bytes of the frame being read (beyond _MAX_FRAME: counted, not kept)
        # decoded in place, and sized for the packet table (32 KB of RAM: nothing twice, nothing unused)
        self._dec = frame.Decoder(raw=self._frame, max_frame=_MAX_FRAME)
        self._enc = frame.Encoder(LARGEST_PAYLOAD)
        self._st = array("i", [0, 0, 0, -1, -1, 0, _K_OTHER, 0])    # and the exchange's kind, the gaps
        self.closed = False
        self._meter = meter
        self._read_frame = read_frame
        self._wf = write_frame if write_frame is not None else self._stream_write   # (buf, n): buf[0:n] out
        self._fast = fast
        if fast is not None:
            if read_frame is None or status is None or not self._dec._fast:
                raise ValueError("the fast TICK path needs read_frame, status and the decoder's viper path")
            self._status = status
            self.answer_ticks = self._answer_ticks
            self._raw = self._enc._body    # a TICK decoded (the frame kept for recv_ms), then its answer's body
            self._out = self._enc._out     # the answer's frame: the encoder's
            # a CTRL_STATUS's body (header, payload, CRC), kept after it went out: a resend of its tick sends it again
            self._stat = bytearray(frame.HEADER_SIZE + SIZES[P_CTRL_STATUS] + frame.CRC_SIZE)
        self._held = 0             # a frame the fast path read and left (its length), for recv_ms
        self._t_held = 0
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
            if self._held:                 # left by the fast path: it was read (and timed from) there
                i = self._held
                t = self._t_held
                self._held = 0
            else:
                i = self._read_frame(fr, _MAX_FRAME)
                if mt is not None:
                    t = mt.now()
            self._sync()
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
                st = self._st
                p = out[-1]                # the TICKs' source and its sequence, which the fast path takes up from
                if p[0] == P_TICK or p[1] == st[_ST_RX_SRC]:
                    st[_ST_RX_SRC] = p[1]
                    st[_ST_RX_SEQ] = p[3]
                return out

    def _answer_ticks(self, ctl, last):
        """Answer TICKs ``last + 1``, ``last + 2``, ... in machine code (``fast``) while each is the common one (a
        CTRL_STATUS due included: after its FSM_SPI, ``firmware.hal.fast_status.status``); return the last tick
        answered, and the words' count its step returned. The first frame that is not one is kept, undecoded, for
        ``recv_ms``. The heap is collected first, between two exchanges (the bytecode path before allocated), then
        locked: an allocation would raise MemoryError, so no tick here runs the GC, and a bytecode exchange after
        starts from a collected heap.
        Each exchange is timed as ``recv_ms`` and ``send_raw`` time theirs: from the frame's end to its answer
        framed (a status tick: to its CTRL_STATUS framed), the UART writes left out."""
        gc.collect()
        heap_lock()
        try:
            last = self._fast_loop(ctl, last)
        finally:
            heap_unlock()
        return last, self._st[_ST_SPI_N]

    def _fast_loop(self, ctl, last):
        fr = self._frame
        rd = self._read_frame
        wf = self._wf
        ans = self._fast
        mt = self._meter
        s = ctl._s
        while True:
            i = rd(fr, _MAX_FRAME)
            bx = s[_S_BXQ]                     # the cached H^-1 bin: another after the step is a new bin
            by = s[_S_BYQ]
            t = mt.start() if mt is not None else 0
            k = ans(self, ctl, i, last)
            if not k:
                self._held = i
                self._t_held = t
                return last
            last += 1
            if k > 0:
                if mt is not None:
                    mt.exchange(t, 0, 1, _K_BIN if bx != s[_S_BXQ] or by != s[_S_BYQ] else _K_COMMON)
                wf(self._out, k)
                continue
            w = (mt.now() - t) & 0xFFFF if mt is not None else 0
            wf(self._out, -k)                  # the loop's output first, then its status
            t = mt.start() if mt is not None else 0
            k = self._status(self, ctl, last)
            if mt is not None:
                mt.exchange(t, w, 2, _K_STATUS)
            wf(self._out, k)

    def _sync(self):
        """Tell the decoder of the frames the fast path decoded (its counters, and the sequence to go on from)."""
        st = self._st
        if st[_ST_RX_FRAMES]:
            self._dec.count_frames(st[_ST_RX_FRAMES], st[_ST_RX_SRC], st[_ST_RX_SEQ])
            st[_ST_RX_FRAMES] = 0
        if st[_ST_RX_GAPS]:
            g = self._dec.gaps
            g[st[_ST_RX_SRC]] = g.get(st[_ST_RX_SRC], 0) + st[_ST_RX_GAPS]
            st[_ST_RX_GAPS] = 0

    def status_sent(self):
        """The payload of the last CTRL_STATUS the machine-code path sent (a new bytes)."""
        return bytes(memoryview(self._stat)[frame.HEADER_SIZE:frame.HEADER_SIZE + SIZES[P_CTRL_STATUS]])

    @property
    def tx_frames(self):
        return self._st[_ST_TX_FRAMES]

    def _stream_write(self, buf, n):
        self._w.write(buf if n == len(buf) else memoryview(buf)[:n])

    def send_raw(self, pid, src, dst, payload, seq=None):
        st = self._st
        if seq is None:
            seq = st[_ST_TX_SEQ]
            st[_ST_TX_SEQ] = (seq + 1) & 0xFF
        f = self._enc.frame(pid, src, dst, seq, payload)
        mt = self._meter
        if mt is None:
            self._wf(f, len(f))
        else:                      # the UART write left out: on a board a DMA channel or an interrupt sends it
            t = mt.now()
            self._wf(f, len(f))
            self._frame_work -= (mt.now() - t) & 0xFFFF
            self._frame_n -= 1
        st[_ST_TX_FRAMES] += 1
        k = st[_ST_KIND]
        if mt is not None and (pid == P_CTRL_STATUS if k == _K_STATUS else pid == P_FSM_SPI):
            # the answer to a TICK (a status tick's: its CTRL_STATUS, after the FSM_SPI): its exchange is over
            mt.exchange(self._t_frame, self._frame_work, self._frame_n + 1, k)
            st[_ST_KIND] = _K_OTHER                  # the next one's, unless serve_controller says otherwise

    def rx_drops(self):
        """Frames the decoder dropped (every ``frame.DROP_REASONS``)."""
        return self._dec.dropped()

    def counters(self):
        self._sync()
        d = self._dec.counters()
        d["tx_frames"] = self.tx_frames
        return d

    def close(self):
        self.closed = True
