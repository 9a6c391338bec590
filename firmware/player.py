"""Disturbance player (the thesis's SimArduino): distfile -> linear interpolation -> AD660 codes for the P-FSM.

The distfile (``protocol.distfile``) holds body pointing error angles every ``period_us`` (8.192 ms); the player
interpolates linearly between them (Sec. 7.3.1) and converts to AD660 codes by Eq. 7.7-7.8
(``firmware.ad660``) at ``rate_hz`` (10.6 kHz by default). ``fill(xbuf, ybuf, n)`` is integer arithmetic:

- segment ends c0, c1: AD660 codes Q2 (code x 4, 0 .. 262140), converted once per distfile sample from its
  raw bytes by ``ad660.Q2Converter`` (integer limbs, the same codes as ``ad660.arcsec_to_code_q2``);
- time: a phase accumulator in units of 1/(rate_hz x period_us) s reduced by their gcd with 10^6: each output
  adds ``_inc``; a segment lasts ``_cell`` (10.6 kHz and 8.192 ms: 625 and 54272); the fraction
  f = ((phase >> s) << 12) // (cell >> s) is Q12 (s keeps cell >> s below 2^18, so phase << 12 < 2^30);
- output: (c0 + ((c1 - c0) f + 2048) >> 12 + 2) >> 2, each product <= 262140 x 4096 < 2^30, computed as
  (4096 c0 + 10240 + (c1 - c0) f) >> 14 (the same floor; < 2^30, as it lies between c0 and c1 in Q12);
- speed: with s = 0 the quotient f and remainder of phase << 12 by cell advance by fixed steps, so within a
  segment each output costs two additions and a compare instead of a division (bit-identical codes).
- allocation: none per update, crossings into the next sample included (the sample's bytes are read into
  the reader's preallocated buffer, or indexed in memory): the 10.6 kHz timer path of Sec. 7.3.1 can run
  with the heap locked (tests/mp/firmware_player_alloc.py).

Actions (PLAYER_CTRL, ``protocol.table.PLAYER_ACTIONS``): STOP pauses (the DAC holds its last code); START
resumes from where it stopped; LOOP rewinds and plays repeatedly; ONESHOT rewinds and plays once, then stops
at the last sample. ``fill`` returns how many codes it wrote: fewer than n (0 when stopped) means the DAC
holds the last one.
"""

import os
import struct

from firmware import ad660
from firmware.upload import Upload
from protocol import core, distfile

try:
    from micropython import const
except ImportError:  # CPython
    def const(x):
        return x

STOP = const(0)
START = const(1)
LOOP = const(2)
ONESHOT = const(3)

_P = core.PACKET_ID
_E = core.ERROR
P_CTRL = _P["PLAYER_CTRL"]
P_STATUS = _P["PLAYER_STATUS"]
P_BEGIN = _P["DIST_BEGIN"]
P_CHUNK = _P["DIST_CHUNK"]
P_END = _P["DIST_END"]
P_ACK = _P["ACK"]
P_NACK = _P["NACK"]
_MAX_DIST_BYTES = 1 << 20                 # the packet table's transfer limit
_MAX_RAM_BYTES = 1 << 16                  # uploads kept in RAM when the player has no file store


def _gcd(a, b):
    while b:
        a, b = b, a % b
    return a


class Player:
    """Plays a distfile (a ``protocol.distfile.Distfile`` or streaming ``Reader``) into AD660 codes.

    store_path: where DIST uploads are kept on the filesystem (the SD card); None keeps them in RAM.
    """

    def __init__(self, reader=None, rate_hz=10600, store_path=None):
        self.reader = None
        self.store_path = store_path
        self._file = None
        self.state = STOP
        self.loop = False
        self.index = 0                  # segment start sample
        self.x_code = ad660.ZERO_CODE   # last codes written
        self.y_code = ad660.ZERO_CODE
        self._phase = 0
        self._c0x = self._c1x = self._c0y = self._c1y = ad660.ZERO_CODE << 2
        self._upload = Upload(_MAX_DIST_BYTES if store_path else _MAX_RAM_BYTES,
                              None if store_path is None else store_path + ".part")
        self.set_rate(rate_hz)
        if reader is not None:
            self.load(reader)

    # --- configuration -----------------------------------------------------------------------------
    def set_rate(self, rate_hz, period_us=None):
        if isinstance(rate_hz, bool) or not isinstance(rate_hz, int) or not 100 <= rate_hz <= 50000:
            raise ValueError("player rate_hz = %r out of range [100, 50000]" % (rate_hz,))
        if period_us is None:
            period_us = self.reader.period_us if self.reader is not None else distfile.DEFAULT_PERIOD_US
        g = _gcd(1000000, rate_hz * period_us)
        inc = 1000000 // g
        cell = rate_hz * period_us // g
        if inc > cell:
            raise ValueError("player rate %d Hz is slower than the distfile's samples (%d us)" % (rate_hz,
                                                                                              period_us))
        s = 0
        while (cell >> s) >= (1 << 18):
            s += 1
        # keep the phase's position within the segment when the rate changes
        old = getattr(self, "_cell", 0)
        self._phase = self._phase * cell // old if old else 0
        self.rate_hz = rate_hz
        self._inc = inc
        self._cell = cell
        self._shift = s
        self._div = cell >> s
        self._fq = (inc << 12) // cell if s == 0 else 0     # per-output step of f and its remainder
        self._fr = (inc << 12) - self._fq * cell if s == 0 else 0

    def load(self, reader):
        """Play ``reader`` (stopped, rewound). Needs at least 2 samples (the distfile format ensures it)."""
        if reader.count < 2:
            raise distfile.DistfileError("distfile needs >= 2 samples, has %d" % reader.count)
        old = self.reader
        self.reader = reader
        try:
            self.set_rate(self.rate_hz, reader.period_us)
        except ValueError:
            self.reader = old
            raise
        self._conv = ad660.Q2Converter(reader.kind, reader.scale)
        self.state = STOP
        self.rewind()

    def rewind(self):
        self._phase = 0
        self._segment(0)

    def _segment(self, i, follow=False):
        """Load segment i (samples i and i + 1); ``follow``: it follows the loaded one, whose end it starts at."""
        self.index = i
        r = self.reader
        cv = self._conv
        if follow:
            self._c0x = self._c1x
            self._c0y = self._c1y
        else:
            o = r.sample_offset(i)
            self._c0x = cv.code(r.raw, o)
            self._c0y = cv.code(r.raw, o + 4)
        o = r.sample_offset(i + 1)
        self._c1x = cv.code(r.raw, o)
        self._c1y = cv.code(r.raw, o + 4)

    # --- actions -----------------------------------------------------------------------------------
    def start(self):
        if self.reader is not None:
            self.state = START if not self.loop else LOOP

    def stop(self):
        self.state = STOP

    def play_loop(self):
        if self.reader is not None:
            self.loop = True
            self.rewind()
            self.state = LOOP

    def oneshot(self):
        if self.reader is not None:
            self.loop = False
            self.rewind()
            self.state = ONESHOT

    # --- output ------------------------------------------------------------------------------------
    def fill(self, xbuf, ybuf, n):
        """Write up to n codes per axis; returns how many (fewer at the end of a one-shot, 0 when stopped)."""
        if self.state == STOP or self.reader is None:
            return 0
        ph = self._phase
        inc = self._inc
        cell = self._cell
        s = self._shift
        div = self._div
        fq = self._fq
        fr = self._fr
        last = self.reader.count - 2
        k = 0
        while k < n:
            m = (cell - 1 - ph) // inc + 1               # outputs left in this segment
            if m > n - k:
                m = n - k
            c0x = self._c0x
            c0y = self._c0y
            dx = self._c1x - c0x
            dy = self._c1y - c0y
            bx = (c0x << 12) + 10240                     # c0 Q12 plus both roundings (2048 and 2 << 12)
            by = (c0y << 12) + 10240
            if s:
                for j in range(k, k + m):
                    f = ((ph >> s) << 12) // div         # Q12 fraction of the segment
                    xbuf[j] = (bx + dx * f) >> 14
                    ybuf[j] = (by + dy * f) >> 14
                    ph += inc
            else:
                f = (ph << 12) // div                    # phase << 12 = f div + r, 0 <= r < div
                r = (ph << 12) - f * div
                ax = bx + dx * f
                ay = by + dy * f
                xbuf[k] = ax >> 14
                ybuf[k] = ay >> 14
                if m > 1:                                # so inc < cell, fq < 4096: |dx| (fq + 1) < 2^30
                    sx = dx * fq                         # f advances by fq or fq + 1 per output
                    sy = dy * fq
                    sx1 = sx + dx
                    sy1 = sy + dy
                    for j in range(k + 1, k + m):
                        r += fr
                        if r >= div:
                            r -= div
                            ax += sx1
                            ay += sy1
                        else:
                            ax += sx
                            ay += sy
                        xbuf[j] = ax >> 14
                        ybuf[j] = ay >> 14
                ph += m * inc
            k += m
            if ph >= cell:
                ph -= cell
                i = self.index + 1
                if i > last:
                    if not self.loop:                    # one-shot: hold the last sample and stop
                        if k < n:
                            xbuf[k] = (self._c1x + 2) >> 2
                            ybuf[k] = (self._c1y + 2) >> 2
                            k += 1
                        self.state = STOP
                        self.index = last + 1
                        break
                    i = 0
                self._segment(i, i > 0)
        self._phase = ph
        if k:
            self.x_code = xbuf[k - 1]
            self.y_code = ybuf[k - 1]
        return k

    # --- packets -----------------------------------------------------------------------------------
    def status_payload(self):
        return struct.pack(core.PACKET[P_STATUS].fmt, self.state, self.index,
                           self.reader.count if self.reader is not None else 0)

    def handle(self, pid, src, seq, payload):
        """One packet; returns replies ``[(pid, dst, payload)]`` (ACK/NACK, PLAYER_STATUS after PLAYER_CTRL)."""
        seq = seq & 0xFF if seq is not None else 0      # CAN frames carry no sequence number
        d = core.PACKET.get(pid)
        if d is None or len(payload) != d.size:
            return []
        if pid == P_CTRL:
            action, rate = struct.unpack(d.fmt, payload)
            code = self._ctrl(action, rate)
        elif pid == P_BEGIN:
            code = self._upload.begin(*struct.unpack(d.fmt, payload))
        elif pid == P_CHUNK:
            code = self._upload.chunk(*struct.unpack(d.fmt, payload))
        elif pid == P_END:
            code = self._upload_end(struct.unpack(d.fmt, payload)[0])
        else:
            return []
        if code:
            return [(P_NACK, src, struct.pack("<BBB", pid, seq, code))]
        out = [(P_ACK, src, struct.pack("<BB", pid, seq))]
        if pid == P_CTRL:
            out.append((P_STATUS, src, self.status_payload()))
        return out

    def _ctrl(self, action, rate):
        if action > ONESHOT:
            return _E["BAD_VALUE"]
        if action != STOP and self.reader is None:
            return _E["BAD_STATE"]
        if rate != self.rate_hz:
            try:
                self.set_rate(rate)
            except ValueError:
                return _E["BAD_VALUE"]
        if action == STOP:
            self.stop()
        elif action == START:
            self.start()
        elif action == LOOP:
            self.play_loop()
        else:
            self.oneshot()
        return 0

    def _upload_end(self, total):
        r = self._upload.end(total)
        if isinstance(r, int):
            return r
        try:
            if self.store_path is None:
                self.load(distfile.parse(bytes(r)))
                return 0
            with open(r, "rb") as f:
                distfile.Reader(f)              # validate before replacing the stored file
            if self._file is not None:
                self._file.close()
                self._file = None
            os.rename(r, self.store_path)
            self.open_file(self.store_path)
        except ValueError:
            if self.store_path is not None:
                try:
                    os.remove(r)
                except OSError:
                    pass
            return _E["BAD_CONTENT"]
        return 0

    def open_file(self, path):
        """Play the distfile at ``path`` (checked in full, then streamed from the file)."""
        f = open(path, "rb")
        try:
            self.load(distfile.Reader(f))
        except ValueError:
            f.close()
            raise
        if self._file is not None:
            self._file.close()
        self._file = f
