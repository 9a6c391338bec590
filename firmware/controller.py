"""Fine-pointing controller (the thesis's CtrlArduino): quadcell Q1 -> ratios -> integral law -> MEMS FSM.

Each tick (``step``), in integer arithmetic with every intermediate inside +-2^30 (a MicroPython small int
on a 32-bit MCU, so the tick allocates nothing and is bit-identical under CPython and MicroPython):

1. beam present when the sum vs >= ``beam_threshold`` counts, else the sample is rejected (hold);
2. ratios (Eq. 7.4) from the inverted Q1 channels (docs/INTERFACES.md): Rx = (2048 - vx) / vs, in Q15
   (ratio * 32768), rounded; |(2048 - vx) << 15| <= 2^26 before the division;
3. error (Eq. 7.13): dR = R - R_cmd (Q15), clamped per axis to +-16383 (just under 0.5), a slew limit far
   outside the quadcell's linear range that also bounds the products below;
4. g H^-1 (Eq. 7.10-7.11): H^-1 interpolated bilinearly from ``firmware.hinv.HinvTable`` at the centre of the
   command's 64-code bin (4.9 mV), times g (Q15, 0..65535 = 0..2.0), kept as a high part Q``hq`` (|.| <= 31999)
   and a low byte (8 more fractional bits); cached, and re-evaluated only when the command changes bin;
5. integral law (Eq. 7.12): V[k+1] = V[k] - g H^-1 dR; the state V is the tilt command in AD5664R codes Q8
   (code * 256, 0.298 uV per LSB); high parts times dR (each <= 31999 * 16383, the pair < 2^30) plus the low
   bytes' share, Q(15 + hq), shifted by 7 + hq to Q8 and rounded;
6. saturation with anti-windup: the state itself is clamped to +-limit_code (Q8), so the integrator never
   runs past the mirror's range; the output codes are (V + 128) >> 8, always within +-limit_code;
7. the four AD5664R words (layout in ``firmware.ad5664r``), preceded on the first tick by the init sequence.

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
meanwhile); TRACK, HOLD and CALIBRATE enter SAFE after ``safe_ticks`` ticks without a packet from the link:
on a board ``tick`` counts the hardware-timer ticks since the last ``handle``d packet; over the link HAL
every TICK is link traffic and the wait between TICKs is counted (``link_silent``).
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
try:
    from micropython import heap_lock, heap_unlock
except ImportError:  # CPython: nothing to lock
    def heap_lock():
        return 0

    def heap_unlock():
        return 0

IDLE = const(0)
TRACK = const(1)
HOLD = const(2)
CALIBRATE = const(3)
SAFE = const(4)

_E_MAX = const(16383)             # |dR| clamp, Q15 (0.5)
_COUNT_MAX = const(0x3FFFFFFF)    # counters saturate / wrap below 2^30
_NO_BIN = const(1 << 20)          # no command bin (forces g H^-1 to be evaluated)
_FLAG_BEAM = const(1)
_FLAG_SAT = const(2)
_FLAG_TABLE = const(4)
_MAX_UPLOAD = const(8192)         # bytes of H-table blob the controller accepts (32x32 grid fits 16 kB; 11x11 is 2 kB)

_P = core.PACKET_ID
_E = core.ERROR
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
        self.ticks = 0                 # ticks since boot (wraps at 2^30)
        self.lost = 0                  # consecutive beam-lost ticks (saturates)
        self._pkt = 0                  # tick of the last packet from the link
        self._quiet = 0                # ticks the link HAL waited without a TICK (link_silent)
        self._sat_tick = -1            # last tick the command saturated
        self.n_lost = 0                # telemetry counters, wrap at 2^16
        self.n_sat = 0
        self.n_unknown = 0
        self.words = [0, 0, 0, 0]      # this tick's AD5664R words
        self._init = True
        self._bx = _NO_BIN             # 64-code bin of the command where g H^-1 was last evaluated
        self._by = _NO_BIN
        self._h4 = [0] * 4             # scratch for the interpolated H^-1
        self._gh = [0] * 8             # cached g H^-1: high parts h11 h12 h21 h22, then low bytes (_gain_hinv)
        self._shift = 8
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
        self.table = t
        self._shift = t.shift
        self._bx = _NO_BIN             # re-evaluate g H^-1 on the next tick

    # --- the tick ----------------------------------------------------------------------------------
    def _gain_hinv(self, bx, by):
        """g H^-1 for the 64-code bin (bx, by) of the command, evaluated at the bin centre (bilinear over the
        grid, ``HinvTable.hinv_at``, Q``hq``) and cached: the tick re-evaluates it only when the command changes
        bin (4.9 mV, far below the table's resolution). g h is kept in Q(hq + 8), (g h + 64) >> 7 <= 2^23, and
        split into a high part (>> 8, Q``hq``, |.| <= 31999) and a low byte (& 255), so the law multiplies
        16-bit by 15-bit numbers yet keeps 8 more fractional bits of the small cross terms."""
        h = self._h4
        self.table.hinv_into((bx << 6) + 32, (by << 6) + 32, h)
        g = self.gain
        k = self._gh
        for e in range(4):
            v = (g * h[e] + 64) >> 7
            k[e] = v >> 8
            k[e + 4] = v & 255
        self._bx = bx
        self._by = by

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
        t = (self.ticks + 1) & _COUNT_MAX
        self.ticks = t
        self.vs = vs
        v_x = self.vx_q8
        v_y = self.vy_q8
        mode = self.mode
        if mode == TRACK:
            if vs >= self.beam_threshold:
                if self.lost:
                    self.lost = 0
                r = vs >> 1
                ex = (((2048 - vx) << 15) + r) // vs        # Eq. 7.4: Rx, Q15; |.| <= 2^26 before the division
                ey = (((2048 - vy) << 15) + r) // vs
                self.rx = ex
                self.ry = ey
                ex -= self.rx_cmd                           # Eq. 7.13: dR, Q15, clamped to +-0.5
                if ex > _E_MAX:
                    ex = _E_MAX
                elif ex < -_E_MAX:
                    ex = -_E_MAX
                ey -= self.ry_cmd
                if ey > _E_MAX:
                    ey = _E_MAX
                elif ey < -_E_MAX:
                    ey = -_E_MAX
                if (v_x >> 14) != self._bx or (v_y >> 14) != self._by:
                    self._gain_hinv(v_x >> 14, v_y >> 14)
                # Eq. 7.12: V -= (g H^-1) dR, high parts (<= 31999 * 16383 each, the pair < 2^30) plus the
                # low bytes' share (<= 2 * 255 * 16383 >> 8), Q(15 + hq) -> Q8 code
                k = self._gh
                n = self._shift
                r = 1 << (n - 1)
                v_x -= (k[0] * ex + k[1] * ey + ((k[4] * ex + k[5] * ey + 128) >> 8) + r) >> n
                v_y -= (k[2] * ex + k[3] * ey + ((k[6] * ex + k[7] * ey + 128) >> 8) + r) >> n
            else:
                self._beam_lost()
        else:
            if vs < self.beam_threshold:
                self.n_lost = (self.n_lost + 1) & 0xFFFF
            else:                                           # ratios for telemetry (calibration reads them)
                r = vs >> 1
                self.rx = (((2048 - vx) << 15) + r) // vs
                self.ry = (((2048 - vy) << 15) + r) // vs
            if mode == SAFE or mode == IDLE:
                self._ramp()
            v_x = self.vx_q8
            v_y = self.vy_q8
        # saturation: clamp the state itself (anti-windup)
        r = self.lim_q8
        if v_x > r or v_x < -r or v_y > r or v_y < -r:
            v_x = r if v_x > r else (-r if v_x < -r else v_x)
            v_y = r if v_y > r else (-r if v_y < -r else v_y)
            self._sat_tick = t
            self.n_sat = (self.n_sat + 1) & 0xFFFF
        self.vx_q8 = v_x
        self.vy_q8 = v_y
        r = (v_x + 128) >> 8
        w[0] = 0x008000 + r             # X+ = bias + x, cmd 000 addr A
        w[1] = 0x018000 - r             # X- = bias - x, cmd 000 addr B
        r = (v_y + 128) >> 8
        w[2] = 0x038000 + r             # Y+ = bias + y, cmd 000 addr D
        w[3] = 0x128000 - r             # Y- = bias - y, cmd 010 addr C (write, update all)
        return 4

    def _ramp(self):
        """IDLE and SAFE: move the command toward the centre by ramp_code per tick, never integrating."""
        r = self.ramp_q8
        v = self.vx_q8
        self.vx_q8 = v - r if v > r else (v + r if v < -r else 0)
        v = self.vy_q8
        self.vy_q8 = v - r if v > r else (v + r if v < -r else 0)

    def _beam_lost(self):
        """TRACK without the beam: hold (no integration); SAFE after ``safe_ticks`` consecutive lost ticks."""
        self.n_lost = (self.n_lost + 1) & 0xFFFF
        if self.lost < _COUNT_MAX:
            self.lost += 1
        if self.lost >= self.safe_ticks:
            self.mode = SAFE

    @property
    def flags(self):
        """CTRL_STATUS flags: bit0 beam present, bit1 saturated on the last tick, bit2 table loaded."""
        return ((_FLAG_BEAM if self.vs >= self.beam_threshold else 0)
                | (_FLAG_SAT if self._sat_tick == self.ticks else 0)
                | (_FLAG_TABLE if self.table is not None else 0))

    def tick(self):
        """One tick on a board: read Q1 through the HAL, step, clock the words out, all with the heap locked
        (an allocation would raise MemoryError; MicroPython then keeps even large call frames off the heap)."""
        q = self._q1
        heap_lock()
        try:
            self.hal.read_q1(q)
            n = self.step(q[0], q[1], q[2])
            self.hal.spi_write(self.words, n)
            m = self.mode
            if m != IDLE and m != SAFE and ((self.ticks - self._pkt) & _COUNT_MAX) >= self.safe_ticks:
                self.mode = SAFE                            # the ground link fell silent
        finally:
            heap_unlock()
        return n

    def on_tick(self, tick, t_us, vx, vy, vs):
        """A TICK from the lockstep clock (in-process or over the link): step and return the words (a new
        tuple). A TICK is link traffic, so it resets the link-silence count."""
        self.heard(True)
        n = self.step(vx, vy, vs)
        return tuple(self.words[:n])

    def heard(self, tick_packet=False):
        """A packet arrived from the link: the silence count starts again. A TICK (``tick_packet``) belongs to
        the tick it starts, so that tick sees no silence; any other packet to the last tick."""
        self._pkt = (self.ticks + 1) & _COUNT_MAX if tick_packet else self.ticks
        self._quiet = 0

    def link_silent(self, ticks):
        """The link has been silent for about ``ticks`` ticks with no TICK to step on (link HAL): enter SAFE
        once the total reaches ``safe_ticks`` in TRACK, HOLD or CALIBRATE (the ramp runs on the next ticks)."""
        self._quiet = min(self._quiet + ticks, _COUNT_MAX)
        if self.mode != IDLE and self.mode != SAFE and self._quiet >= self.safe_ticks:
            self.mode = SAFE

    def status_due(self):
        return self.decim != 0 and self.ticks % self.decim == 0

    # --- packets -----------------------------------------------------------------------------------
    def status_payload(self, tick=None):
        """CTRL_STATUS payload bytes (telemetry path; allocates)."""
        w = self.words
        rx = max(-32768, min(32767, self.rx))
        ry = max(-32768, min(32767, self.ry))
        return struct.pack(_STATUS_FMT, self.ticks if tick is None else tick & 0xFFFFFFFF, self.mode,
                           self.flags, _uv(self.vx_q8), _uv(self.vy_q8), rx, ry, self.vs,
                           w[0] & 0xFFFF, w[1] & 0xFFFF, w[2] & 0xFFFF, w[3] & 0xFFFF,
                           self.n_lost, self.n_sat, self.n_unknown)

    def handle(self, pid, src, seq, payload):
        """One packet from the link (``seq`` None on CAN); returns a list of replies ``(pid, dst, payload)``.

        Commands are ACKed or NACKed with an ``ERRORS`` code; packets this node does not handle are counted
        in n_unknown and ignored (no reply).
        """
        self.heard()
        seq = seq & 0xFF if seq is not None else 0      # CAN frames carry no sequence number
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
            return [(P_NACK, src, struct.pack("<BBB", pid, seq, code))]
        return [(P_ACK, src, struct.pack("<BB", pid, seq))]

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
        if gain and gain != self.gain:
            self.gain = gain
            self._bx = _NO_BIN
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
