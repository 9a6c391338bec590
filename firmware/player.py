"""Disturbance player (the thesis's SimArduino): distfile -> 6-point cubic interpolation -> AD660 codes.

The distfile (``protocol.distfile``) holds body pointing error angles every ``period_us`` = Ts (8.192 ms by
default, any whole us from 95); the player interpolates between them and converts to AD660 codes by Eq. 7.7-7.8
(``firmware.ad660``) at ``rate_hz`` (10.6 kHz by default) for the P-FSM. The thesis's SimArduino interpolated
linearly (Sec. 7.3.1), which plays a tone f at sinc^2(f Ts): x0.875 at 200 Hz for a 1 ms step. This player uses
Keys's 6-point cubic convolution kernel (R. G. Keys, "Cubic convolution interpolation for digital image
processing", IEEE Trans. ASSP 29(6), 1981: its 6-point kernel), with u = |t| / Ts:

    W(u) = 4/3 u^3 - 7/3 u^2 + 1                   0 <= u < 1
           -7/12 u^3 + 3 u^2 - 59/12 u + 5/2       1 <= u < 2
           1/12 u^3 - 2/3 u^2 + 7/4 u - 3/2        2 <= u < 3,    0 beyond.

It interpolates (W(0) = 1, W(k) = 0), is C1 and reproduces cubics. Its frequency response (derived here; the
paper gives none; tests/test_player_kernel.py checks it against quadrature and against the played codes):
W is even, C1 and piecewise cubic with knots at the integers, so its 4th derivative is
sum_k J3(k) delta(u - k) + J2(k) delta_prime(u - k), J2 and J3 the jumps of W's 2nd and 3rd derivatives at k
(J3 = 16, -23/2, 4, -1/2 at k = 0, 1, 2, 3, even in k; J2 = 0, -5/6, 2/3, -1/6, odd in k). Transforming, with
w = 2 pi f Ts: w^4 G = J3(0) + 2 sum_{k>=1} (J3(k) cos kw + w J2(k) sin kw), i.e.

    G(f) = [48 - 69 cos w + 24 cos 2w - 3 cos 3w - w (5 sin w - 4 sin 2w + sin 3w)] / (3 w^4)

G = 1 - O(w^4): 0.9997 at 0.1/Ts, 0.990 at 0.2/Ts, 0.929 at 0.3/Ts, 0.493 at 0.5/Ts; the images at k/Ts -+ f
play at G(k -+ f Ts). ``ground.resample.player_gain`` evaluates it (``kernel="linear"``: sinc^2, the thesis's).

Integer arithmetic (``fill``), every intermediate below 2^30 (a small int on a 32-bit MicroPython board):

- samples: AD660 codes in Q2 (code x 4, 0 .. 262140), converted once per distfile sample from its raw bytes by
  ``ad660.Q2Converter`` (the codes of ``ad660.arcsec_to_code_q2``); a window of six, q[-2] .. q[3], around the
  segment from sample i (q0) to i + 1 (q1); indices are clamped to the file (its end samples repeat);
- per segment: y(x) = q0 + c1 x + c2 x^2 + c3 x^3 for 0 <= x <= 1 (W's pieces summed per tap), with
  12 c1 = q[-2] - 8 q[-1] + 8 q1 - q2, 12 c2 = -2 q[-2] + 15 q[-1] - 28 q0 + 20 q1 - 6 q2 + q3,
  12 c3 = q[-2] - 7 q[-1] + 16 q0 - 16 q1 + 7 q2 - q3, each rounded to an integer C = (12 c + 6) // 12;
- time: a phase accumulator in units of 1/(rate_hz x period_us) s reduced by their gcd with 10^6: each output
  adds ``_inc``; a segment lasts ``_cell`` (10.6 kHz at 8.192 ms: 625 and 54272; at 1 ms: 5 and 53); the
  fraction x = f / 1024, f = (((phase >> s) << 10) + div // 2) // div (Q10, rounded; div = cell >> s < 2^19);
  with s = 0, f and its remainder advance by fixed steps (two additions and a compare, no division);
- output (Horner, each stage rounded): h = (C3 f + (C2 << 10) + 512) >> 10, h = (h f + (C1 << 10) + 512) >> 10,
  code = (h f + ((q0 + 2) << 10) + 512) >> 12, clipped to 0 .. 65535 (the kernel overshoots a step by 9.3 %).
  Bounds, M = 131070 (half the Q2 range; the weights of c1 .. c3 sum to 0): |c3| <= 4 M, |c2 + c3 x| <= 6 M,
  |c1 + c2 x + c3 x^2| <= 2.44 M for 0 <= x <= 1, so every product and sum is below 6 M 2^10 + 2^11 < 2^30.
  A code is within one of the exact kernel's at the Q10 instant (coefficient and stage roundings < 0.63 code
  before the last rounding); the Q10 instant is within Ts / 2048 of the true one (4 us at 8.192 ms).
- cost: per output and axis three multiplies, three adds, three shifts and a range test (linear interpolation
  took one add and one shift); per segment one new sample and six divisions by 12. ``bench/bench_firmware.py``
  reports the rate.
- allocation: none per update, crossings into the next sample included (the sample's bytes are read into the
  reader's preallocated buffer, or indexed in memory; the window is a preallocated list): the 10.6 kHz timer
  path of Sec. 7.3.1 can run with the heap locked (tests/mp/firmware_player_alloc.py).

``emulator.serve.DistfilePlayer`` computes the same codes with numpy (tests/test_player_kernel.py).

Actions (PLAYER_CTRL, ``protocol.table.PLAYER_ACTIONS``): STOP pauses (the DAC holds its last code); START
resumes from where it stopped; LOOP rewinds and plays repeatedly (each pass interpolates its own samples, the
window clamped at both ends); ONESHOT rewinds and plays once, then stops at the last sample. ``fill`` returns how
many codes it wrote: fewer than n (0 when stopped) means the DAC holds the last one.
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


def _coefs(w, out):
    """The segment's Horner terms from its window w (six Q2 codes, q[-2] .. q[3]) into ``out`` (see the module
    doc): C3, (C2 << 10) + 512, (C1 << 10) + 512, ((q0 + 2) << 10) + 512. Small ints only."""
    a = w[0]
    b = w[1]
    q0 = w[2]
    d = w[3]
    e = w[4]
    g = w[5]
    out[0] = (a - 7 * b + 16 * q0 - 16 * d + 7 * e - g + 6) // 12
    out[1] = (((-2 * a + 15 * b - 28 * q0 + 20 * d - 6 * e + g + 6) // 12) << 10) + 512
    out[2] = (((a - 8 * b + 8 * d - e + 6) // 12) << 10) + 512
    out[3] = ((q0 + 2) << 10) + 512


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
        self._wx = [ad660.ZERO_CODE << 2] * 6     # Q2 codes of samples index - 2 .. index + 3
        self._wy = [ad660.ZERO_CODE << 2] * 6
        self._kx = [0, 0, 0, 0]                   # the segment's C3, (C2 << 10) + 512, (C1 << 10) + 512, base
        self._ky = [0, 0, 0, 0]
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
        while (cell >> s) >= (1 << 19):
            s += 1
        # keep the phase's position within the segment when the rate changes
        old = getattr(self, "_cell", 0)
        self._phase = self._phase * cell // old if old else 0
        self.rate_hz = rate_hz
        self._inc = inc
        self._cell = cell
        self._shift = s
        self._div = cell >> s
        self._fq = (inc << 10) // cell if s == 0 else 0     # per-output step of f and its remainder
        self._fr = (inc << 10) - self._fq * cell if s == 0 else 0

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
        """Load segment i (samples i and i + 1, window i - 2 .. i + 3 clamped to the file); ``follow``: it
        follows the loaded one (one new sample)."""
        self.index = i
        r = self.reader
        cv = self._conv
        wx = self._wx
        wy = self._wy
        last = r.count - 1
        if follow:
            for j in range(5):
                wx[j] = wx[j + 1]
                wy[j] = wy[j + 1]
            j = i + 3 if i + 3 < last else last
            o = r.sample_offset(j)
            wx[5] = cv.code(r.raw, o)
            wy[5] = cv.code(r.raw, o + 4)
        else:
            for j in range(6):
                k = i + j - 2
                k = 0 if k < 0 else (last if k > last else k)
                o = r.sample_offset(k)
                wx[j] = cv.code(r.raw, o)
                wy[j] = cv.code(r.raw, o + 4)
        _coefs(wx, self._kx)
        _coefs(wy, self._ky)

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
        half = div >> 1
        fq = self._fq
        fr = self._fr
        kx = self._kx
        ky = self._ky
        last = self.reader.count - 2
        k = 0
        while k < n:
            m = (cell - 1 - ph) // inc + 1               # outputs left in this segment
            if m > n - k:
                m = n - k
            ph = self._codes(xbuf, ybuf, k, m, ph, inc, s, half, div, fq, fr, kx, ky)
            k += m
            if ph >= cell:
                ph -= cell
                i = self.index + 1
                if i > last:
                    if not self.loop:                    # one-shot: hold the last sample and stop
                        if k < n:
                            xbuf[k] = (self._wx[3] + 2) >> 2
                            ybuf[k] = (self._wy[3] + 2) >> 2
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

    @staticmethod
    def _codes(xbuf, ybuf, k, m, ph, inc, s, half, div, fq, fr, kx, ky):
        """The m codes per axis of one segment into xbuf[k:k + m], ybuf[k:k + m] from phase ph; returns the
        phase after them (``firmware.player_viper`` runs this loop as machine code)."""
        x3 = kx[0]
        x2 = kx[1]
        x1 = kx[2]
        x0 = kx[3]
        y3 = ky[0]
        y2 = ky[1]
        y1 = ky[2]
        y0 = ky[3]
        if s:
            for j in range(k, k + m):
                f = (((ph >> s) << 10) + half) // div        # Q10 fraction of the segment
                h = (x3 * f + x2) >> 10
                h = (h * f + x1) >> 10
                c = (h * f + x0) >> 12
                if c >> 16:
                    c = 0 if c < 0 else 65535
                xbuf[j] = c
                h = (y3 * f + y2) >> 10
                h = (h * f + y1) >> 10
                c = (h * f + y0) >> 12
                if c >> 16:
                    c = 0 if c < 0 else 65535
                ybuf[j] = c
                ph += inc
        else:
            t = (ph << 10) + half                    # = f div + r, 0 <= r < div
            f = t // div
            r = t - f * div
            for j in range(k, k + m):
                h = (x3 * f + x2) >> 10
                h = (h * f + x1) >> 10
                c = (h * f + x0) >> 12
                if c >> 16:
                    c = 0 if c < 0 else 65535
                xbuf[j] = c
                h = (y3 * f + y2) >> 10
                h = (h * f + y1) >> 10
                c = (h * f + y0) >> 12
                if c >> 16:
                    c = 0 if c < 0 else 65535
                ybuf[j] = c
                r += fr                              # f advances by fq or fq + 1 per output
                f += fq
                if r >= div:
                    r -= div
                    f += 1
            ph += m * inc
        return ph

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
