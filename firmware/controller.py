"""Fine-pointing controller (the thesis's CtrlArduino): quadcell Q1 -> ratios -> integral law -> MEMS FSM.

Each tick (``step``), in integer arithmetic with every intermediate inside +-2^30 (a MicroPython small int
on a 32-bit MCU, so the tick allocates nothing and is bit-identical under CPython and MicroPython):

1. beam present when the sum vs >= ``beam_threshold`` counts, else the sample is rejected (hold);
2. ratios (Eq. 7.4) from the inverted Q1 channels (docs/INTERFACES.md): Rx = (2048 - vx) / vs, in Q15
   (ratio * 32768), rounded, clamped to +-1.0;
3. error (Eq. 7.13): dR = R - R_cmd (Q15), clamped per axis to +-0.5 (16383), a slew limit far outside the
   quadcell's linear range; then g dR with g in Q15 (0..65535 = 0..2.0): Q15, |g dR| <= 32767;
4. H^-1 (Eq. 7.10-7.11) interpolated bilinearly at the current command from ``firmware.hinv.HinvTable``
   (Q``hq`` code per unit ratio, cell fractions Q12);
5. integral law (Eq. 7.12): V[k+1] = V[k] - g H^-1 dR; the state V is the tilt command in AD5664R codes Q8
   (code * 256, 0.298 uV per LSB); the product H^-1 (g dR) is Q(15 + hq), shifted by 7 + hq to Q8, rounded;
6. saturation with anti-windup: the state itself is clamped to +-limit_code (Q8), so the integrator never
   runs past the mirror's range; the output codes are (V + 128) >> 8, always within +-limit_code;
7. the four AD5664R words (``firmware.ad5664r.command_words``), preceded on the first tick by the init sequence.

Default gain g = 0.5 (Q15 16384, the table default). The driver/mirror is taken as a first-order lag
sampled at T = 1/637.8 Hz, pole b = exp(-T/tau) = 0.14 for tau = 0.8 ms (the 200 Hz drive filter); with H^-1 H = I
the loop per axis is u[k] = u[k-1] - g p[k - d], p[k+1] = b p[k] + (1 - b) u[k]. Lockstep (d = 0: the sample
sees the previous command through the lag): z^2 - (1 + b - g (1 - b)) z + b = 0, stable for g < 2(1 + b)/(1 - b)
= 2.66. One more tick of delay (d = 1, a board whose ADC, arithmetic and SPI fill the tick):
z^2 - (1 + b) z + b + g (1 - b) = 0, stable for g < 1. g = 0.5 gives poles of radius 0.38 and 0.76 and keeps a
gain margin of 2 in the worse case, wide enough for the 12 % spread of H over the grid (Fig. 7-17).

Modes (``protocol.table.MODES``): IDLE ramps the command to the centre; TRACK runs the law; HOLD freezes the
command; CALIBRATE takes voltages from CTRL_SET_FSM; SAFE ramps to the centre and stays there until the
ground commands another mode. TRACK enters SAFE after ``safe_ticks`` consecutive beam-lost ticks (holding
meanwhile); TRACK, HOLD and CALIBRATE enter SAFE after ``safe_ticks`` ticks without a packet from the link
(``on_tick``/``handle`` count as link traffic; a board's hardware-timer ``tick`` does not).
"""

import struct

from firmware import ad5664r
from firmware.hinv import HinvTable, load_file
from firmware.upload import Upload
from protocol import core, htable

try:
    from micropython import const
except ImportError:  # CPython
    def const(x):
        return x

IDLE = const(0)
TRACK = const(1)
HOLD = const(2)
CALIBRATE = const(3)
SAFE = const(4)

_Q15_ONE = const(32768)
_E_MAX = const(16383)             # |dR| clamp, Q15 (0.5)
_COUNT_MAX = const(0x3FFFFFFF)    # counters saturate / wrap below 2^30
_FLAG_BEAM = const(1)
_FLAG_SAT = const(2)
_FLAG_TABLE = const(4)
_MAX_UPLOAD = const(8192)         # bytes of H-table blob the controller accepts (32x32 grid fits 16 kB; 11x11 is 2 kB)

_P = core.PACKET_ID
_E = core.ERROR
P_TICK = _P["TICK"]
P_FSM_SPI = _P["FSM_SPI"]
P_SETTINGS = _P["CTRL_SETTINGS"]
P_SET_FSM = _P["CTRL_SET_FSM"]
P_STATUS = _P["CTRL_STATUS"]
P_HT_BEGIN = _P["HTABLE_BEGIN"]
P_HT_CHUNK = _P["HTABLE_CHUNK"]
P_HT_END = _P["HTABLE_END"]
P_ACK = _P["ACK"]
P_NACK = _P["NACK"]
P_HELLO = _P["HELLO"]
_STATUS_FMT = core.PACKET[P_STATUS].fmt
_Q8_PER_UV = ad5664r.CODES_PER_VOLT * 256 / 1e6
FW_VERSION = (1, 0)


class Controller:
    """The fine-pointing controller. ``step`` is the allocation-free tick; ``handle`` the packet side.

    hal: optional HAL (``firmware.hal``) used by ``tick`` (read Q1, write SPI) and to send telemetry.
    """

    def __init__(self, hal=None, table=None, gain_q15=16384, beam_threshold=200, safe_ticks=638, decim=64,
                 limit_code=ad5664r.TILT_LIMIT_CODE, ramp_code=64, rx_cmd_q15=0, ry_cmd_q15=0):
        _check_int("gain_q15", gain_q15, 0, 65535)
        _check_int("beam_threshold", beam_threshold, 1, 4095)
        _check_int("safe_ticks", safe_ticks, 1, 65535)
        _check_int("decim", decim, 0, 65535)
        _check_int("limit_code", limit_code, 0, ad5664r.TILT_LIMIT_CODE)
        _check_int("ramp_code", ramp_code, 1, ad5664r.TILT_LIMIT_CODE)
        _check_int("rx_cmd_q15", rx_cmd_q15, -16384, 16384)
        _check_int("ry_cmd_q15", ry_cmd_q15, -16384, 16384)
        self.hal = hal
        self.gain = gain_q15
        self.beam_threshold = beam_threshold
        self.safe_ticks = safe_ticks
        self.decim = decim
        self.lim_q8 = limit_code << 8
        self.ramp_q8 = ramp_code << 8
        self.rx_cmd = rx_cmd_q15
        self.ry_cmd = ry_cmd_q15
        self.mode = IDLE
        self.vx_q8 = 0                 # command state, AD5664R tilt code Q8
        self.vy_q8 = 0
        self.rx = 0                    # last measured ratios, Q15
        self.ry = 0
        self.vs = 0
        self.flags = 0
        self.ticks = 0                 # ticks since boot (wraps at 2^30)
        self.lost = 0                  # consecutive beam-lost ticks (saturates)
        self.silent = 0                # ticks since the last packet from the link (saturates)
        self.n_lost = 0                # telemetry counters, wrap at 2^16
        self.n_sat = 0
        self.n_unknown = 0
        self.words = [0, 0, 0, 0]      # this tick's AD5664R words
        self._init = True
        self._ci = 0                   # current grid cell (search starts here)
        self._cj = 0
        self._q1 = [0, 0, 0]
        self._upload = Upload(_MAX_UPLOAD)
        self.table = None
        if table is not None:
            self.set_table(table)

    # --- table -------------------------------------------------------------------------------------
    def set_table(self, table):
        """Swap in a table: a HinvTable, a protocol.htable.Grid, blob bytes, or a file path (.json or blob).
        Raises HTableError (a ValueError) and keeps the previous table if the new one is refused."""
        if isinstance(table, str):
            t = load_file(table)
        elif isinstance(table, (bytes, bytearray)):
            t = HinvTable(htable.parse(table))
        elif isinstance(table, htable.Grid):
            t = HinvTable(table)
        elif isinstance(table, HinvTable):
            t = table
        else:
            raise ValueError("table must be a path, blob bytes, Grid or HinvTable, got %r" % type(table))
        self._ci = 0
        self._cj = 0
        self.table = t

    # --- the tick ----------------------------------------------------------------------------------
    def step(self, vx, vy, vs):
        """One control tick from Q1 counts (Eq. 7.4, 7.12, 7.13); words in ``self.words``; returns 4."""
        w = self.words
        if self._init:                 # first tick after boot: the AD5664R init sequence
            self._init = False
            w[0] = 0x280001
            w[1] = 0x380001
            w[2] = 0x20000F
            w[3] = 0x300000
            return 4
        self.ticks = (self.ticks + 1) & _COUNT_MAX
        if self.silent < _COUNT_MAX:
            self.silent += 1
        self.vs = vs
        beam = vs >= self.beam_threshold
        if beam:
            self.lost = 0
            rx = (((2048 - vx) << 15) + (vs >> 1)) // vs       # Eq. 7.4, Q15; |.| <= 2^26 before the division
            if rx > _Q15_ONE:
                rx = _Q15_ONE
            elif rx < -_Q15_ONE:
                rx = -_Q15_ONE
            ry = (((2048 - vy) << 15) + (vs >> 1)) // vs
            if ry > _Q15_ONE:
                ry = _Q15_ONE
            elif ry < -_Q15_ONE:
                ry = -_Q15_ONE
            self.rx = rx
            self.ry = ry
        else:
            self.n_lost = (self.n_lost + 1) & 0xFFFF
            if self.lost < _COUNT_MAX:
                self.lost += 1
        v_x = self.vx_q8
        v_y = self.vy_q8
        mode = self.mode
        if mode != IDLE and mode != SAFE and self.silent >= self.safe_ticks:
            mode = self.mode = SAFE
        if mode == TRACK:
            if not beam:
                if self.lost >= self.safe_ticks:
                    self.mode = SAFE           # held until now; the ramp starts next tick
            else:
                ex = rx - self.rx_cmd           # Eq. 7.13, Q15
                if ex > _E_MAX:
                    ex = _E_MAX
                elif ex < -_E_MAX:
                    ex = -_E_MAX
                ey = ry - self.ry_cmd
                if ey > _E_MAX:
                    ey = _E_MAX
                elif ey < -_E_MAX:
                    ey = -_E_MAX
                g = self.gain
                ex = (g * ex + 16384) >> 15     # g dR, Q15; |g ex| <= 65535 * 16383
                ey = (g * ey + 16384) >> 15
                # H^-1 at the current command: cell search from the last cell, then bilinear (Q12 fractions)
                t = self.table
                c = (v_x + 128) >> 8
                ax = t.ax
                i = self._ci
                while i > 0 and c < ax[i]:
                    i -= 1
                n = t.nx - 2
                while i < n and c >= ax[i + 1]:
                    i += 1
                self._ci = i
                if c <= ax[i]:
                    tx = 0
                elif c >= ax[i + 1]:
                    tx = 4096
                else:
                    tx = ((c - ax[i]) * t.rdx[i]) >> 12
                c = (v_y + 128) >> 8
                ay = t.ay
                j = self._cj
                while j > 0 and c < ay[j]:
                    j -= 1
                n = t.ny - 2
                while j < n and c >= ay[j + 1]:
                    j += 1
                self._cj = j
                if c <= ay[j]:
                    ty = 0
                elif c >= ay[j + 1]:
                    ty = 4096
                else:
                    ty = ((c - ay[j]) * t.rdy[j]) >> 12
                h = t.h
                k = (j * t.nx + i) << 2
                m = k + (t.nx << 2)             # the node above (j + 1)
                a = h[k]
                b = a + (((h[k + 4] - a) * tx) >> 12)
                a = h[m]
                a = a + (((h[m + 4] - a) * tx) >> 12)
                h11 = b + (((a - b) * ty) >> 12)
                a = h[k + 1]
                b = a + (((h[k + 5] - a) * tx) >> 12)
                a = h[m + 1]
                a = a + (((h[m + 5] - a) * tx) >> 12)
                h12 = b + (((a - b) * ty) >> 12)
                a = h[k + 2]
                b = a + (((h[k + 6] - a) * tx) >> 12)
                a = h[m + 2]
                a = a + (((h[m + 6] - a) * tx) >> 12)
                h21 = b + (((a - b) * ty) >> 12)
                a = h[k + 3]
                b = a + (((h[k + 7] - a) * tx) >> 12)
                a = h[m + 3]
                a = a + (((h[m + 7] - a) * tx) >> 12)
                h22 = b + (((a - b) * ty) >> 12)
                # Eq. 7.12: V -= H^-1 (g dR); each product <= 16000 * 32767, the pair sum < 2^30
                n = t.shift
                r = 1 << (n - 1)
                v_x -= (h11 * ex + h12 * ey + r) >> n
                v_y -= (h21 * ex + h22 * ey + r) >> n
        elif mode == SAFE or mode == IDLE:
            r = self.ramp_q8                    # ramp to the centre, never integrating
            if v_x > r:
                v_x -= r
            elif v_x < -r:
                v_x += r
            else:
                v_x = 0
            if v_y > r:
                v_y -= r
            elif v_y < -r:
                v_y += r
            else:
                v_y = 0
        # saturation: clamp the state itself (anti-windup)
        lim = self.lim_q8
        flags = _FLAG_BEAM if beam else 0
        if v_x > lim:
            v_x = lim
            flags = flags | _FLAG_SAT
        elif v_x < -lim:
            v_x = -lim
            flags = flags | _FLAG_SAT
        if v_y > lim:
            v_y = lim
            flags = flags | _FLAG_SAT
        elif v_y < -lim:
            v_y = -lim
            flags = flags | _FLAG_SAT
        if flags & _FLAG_SAT:
            self.n_sat = (self.n_sat + 1) & 0xFFFF
        if self.table is not None:
            flags = flags | _FLAG_TABLE
        self.flags = flags
        self.vx_q8 = v_x
        self.vy_q8 = v_y
        c = (v_x + 128) >> 8
        w[0] = 0x000000 | (0x8000 + c)          # X+ = bias + x, cmd 000 addr A
        w[1] = 0x010000 | (0x8000 - c)          # X- = bias - x, cmd 000 addr B
        c = (v_y + 128) >> 8
        w[2] = 0x030000 | (0x8000 + c)          # Y+ = bias + y, cmd 000 addr D
        w[3] = 0x120000 | (0x8000 - c)          # Y- = bias - y, cmd 010 addr C (write, update all)
        return 4

    def tick(self):
        """One tick on a board: read Q1 through the HAL, step, clock the words out (allocation-free)."""
        q = self._q1
        self.hal.read_q1(q)
        n = self.step(q[0], q[1], q[2])
        self.hal.spi_write(self.words, n)
        return n

    def on_tick(self, tick, t_us, vx, vy, vs):
        """A TICK from the lockstep clock (in-process or over the link): step and return the words (a new
        tuple). A TICK is link traffic, so it resets the link-silence count."""
        self.silent = 0
        n = self.step(vx, vy, vs)
        return tuple(self.words[:n])

    def link_silent(self, ticks):
        """The link has been silent for about ``ticks`` ticks with no TICK to step on (link HAL): enter SAFE
        once the total reaches ``safe_ticks`` in TRACK, HOLD or CALIBRATE (the ramp runs on the next ticks)."""
        self.silent = min(self.silent + ticks, _COUNT_MAX)
        if self.mode != IDLE and self.mode != SAFE and self.silent >= self.safe_ticks:
            self.mode = SAFE

    def status_due(self):
        return self.decim != 0 and self.ticks % self.decim == 0

    # --- packets -----------------------------------------------------------------------------------
    def status_payload(self, tick=None):
        """CTRL_STATUS payload bytes (telemetry path; allocates)."""
        w = self.words
        rx = self.rx if self.rx < 32767 else 32767
        ry = self.ry if self.ry < 32767 else 32767
        return struct.pack(_STATUS_FMT, self.ticks if tick is None else tick & 0xFFFFFFFF, self.mode,
                           self.flags, _uv(self.vx_q8), _uv(self.vy_q8), rx, ry, self.vs,
                           w[0] & 0xFFFF, w[1] & 0xFFFF, w[2] & 0xFFFF, w[3] & 0xFFFF,
                           self.n_lost, self.n_sat, self.n_unknown)

    def handle(self, pid, src, seq, payload):
        """One packet from the link; returns a list of replies ``(pid, dst, payload)``.

        Commands are ACKed or NACKed with an ``ERRORS`` code; packets this node does not handle are counted
        in n_unknown and ignored (no reply).
        """
        self.silent = 0
        d = core.PACKET.get(pid)
        if d is None or len(payload) != d.size:
            return self._unknown()
        if pid == P_SETTINGS:
            code = self._settings(struct.unpack(d.fmt, payload))
        elif pid == P_SET_FSM:
            code = self._set_fsm(struct.unpack(d.fmt, payload))
        elif pid == P_HT_BEGIN:
            total, crc = struct.unpack(d.fmt, payload)
            code = self._upload.begin(total, crc)
        elif pid == P_HT_CHUNK:
            offset, length, data = struct.unpack(d.fmt, payload)
            code = self._upload.chunk(offset, length, data)
        elif pid == P_HT_END:
            code = self._upload_end(struct.unpack(d.fmt, payload)[0])
        elif pid == P_HELLO:
            return [(P_HELLO, src, core.encode_payload(P_HELLO, node=core.NODE["CONTROLLER"],
                                                       fw_major=FW_VERSION[0], fw_minor=FW_VERSION[1]))]
        elif pid == P_ACK or pid == P_NACK:
            return []
        else:
            return self._unknown()
        if code:
            return [(P_NACK, src, struct.pack("<BBB", pid, seq & 0xFF, code))]
        return [(P_ACK, src, struct.pack("<BB", pid, seq & 0xFF))]

    def _unknown(self):
        self.n_unknown = (self.n_unknown + 1) & 0xFFFF
        return []

    def _settings(self, v):
        mode, rx_cmd, ry_cmd, gain, decim, safe_ticks = v
        if mode > SAFE or not (-16384 <= rx_cmd <= 16384) or not (-16384 <= ry_cmd <= 16384) or safe_ticks < 1:
            return _E["BAD_VALUE"]
        if mode == TRACK and self.table is None:
            return _E["BAD_STATE"]
        self.rx_cmd = rx_cmd
        self.ry_cmd = ry_cmd
        if gain:
            self.gain = gain
        self.decim = decim
        self.safe_ticks = safe_ticks
        if mode != self.mode:
            self.mode = mode          # TRACK starts from the current command: bumpless
            self.lost = 0
        return 0

    def _set_fsm(self, v):
        if self.mode != CALIBRATE:
            return _E["BAD_STATE"]
        uvx, uvy = v
        if not (-2500000 <= uvx <= 2500000) or not (-2500000 <= uvy <= 2500000):
            return _E["BAD_VALUE"]
        lim = self.lim_q8
        self.vx_q8 = max(-lim, min(lim, _q8(uvx)))
        self.vy_q8 = max(-lim, min(lim, _q8(uvy)))
        return 0

    def _upload_end(self, total):
        r = self._upload.end(total)
        if isinstance(r, int):
            return r
        try:
            self.set_table(bytes(r))
        except ValueError:
            return _E["BAD_CONTENT"]
        return 0


def _q8(uv):
    v = uv * _Q8_PER_UV
    return int(v + 0.5) if v >= 0 else -int(-v + 0.5)


def _uv(q8):
    v = q8 / _Q8_PER_UV
    return int(v + 0.5) if v >= 0 else -int(-v + 0.5)


def _check_int(name, v, lo, hi):
    if isinstance(v, bool) or not isinstance(v, int) or v < lo or v > hi:
        raise ValueError("controller %s = %r out of range [%d, %d]" % (name, v, lo, hi))
