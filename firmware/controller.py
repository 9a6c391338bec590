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
   runs past the mirror's range; the output codes are (V + 128) >> 8, always within +-limit_code. A tick whose
   law hit the clamp on either axis is counted (n_sat) and extends the saturation run (sat_run, below);
7. the four AD5664R words (layout in ``firmware.ad5664r``); the first tick sends the AD5664R's init sequence
   instead.

Default gain g = 0.5 (Q15 16384, the table default). The loop per axis (H^-1 H = I) is the integral law
C(z) = g z / (z - 1) around the MEMS drive as the bench config has it: a 2nd-order Butterworth at 800 Hz, then
the mirror's 2 kHz resonance (emulator.mirrors.MEMS), held from the instant the SPI words land and sampled at each Q1 channel's instant (emulator.timing).
ground.response.LoopModel discretises it exactly (python-control): with the thesis's board (X sampled 351 us
into the tick, words landing 1568 us after the tick start, one tick later at 637.8 Hz) g = 0.5 keeps a gain
margin of 14.2 dB (stable up to g = 2.6) and a phase margin of 69 deg, -3 dB rejection bandwidth 39 Hz; with
zero latency 11.6 dB, 76 deg, 41 Hz. Both exceed the factor 2 wanted for the 12 % spread of H over the grid
(Fig. 7-17), so the default gain stays. ``fps response`` measures it on the bench.

Modes (``protocol.table.MODES``): IDLE ramps the command to the centre; TRACK runs the law; HOLD freezes the
command; CALIBRATE takes voltages from CTRL_SET_FSM; SAFE ramps to the centre and stays there until the
ground commands another mode; SATURATED is TRACK with the command stuck on its clamp; ACQUIRE is TRACK without
the beam (below). Every mode but IDLE and SAFE enters SAFE after ``safe_ticks`` ticks without a packet from the
link: on a board ``tick`` counts the hardware-timer ticks since the last ``handle``d packet; over the link HAL
every TICK is link traffic and the wait between TICKs is counted (``link_silent``). SAFE, commanded or for link
silence, stays until the ground commands another mode.

Acquisition, then tracking: the body pointing brings the beam onto Q1, the fine loop takes it from there.
A beam-lost tick in TRACK or SATURATED holds the command (no integration: there is no dR to integrate). After
``acq_ticks`` (default ``ACQ_TICKS`` = 64, 100.3 ms) beam-lost ticks in a row, the beam is not a flicker: the
controller enters ACQUIRE (``why`` BEAM_LOST). ACQUIRE runs no law; it holds the command where the beam was
last seen (a fade, or a body error that ran past the mirror's range and turns back, brings the beam back there)
until the beam has been lost ``centre_ticks`` ticks in a row (default 638, 1 s), then ramps the command to the
centre by ``ramp_code`` per tick, as SAFE does: the mirror's rest is the boresight the body pointing aims at,
so the beam comes back there once the body error is inside Q1's field. A beam-present tick in ACQUIRE stops the
ramp (the mirror holds while the beam is debounced) and counts; ``acq_ticks`` of them in a row and the
controller returns to TRACK, the law resuming on the next tick from the command as it stands (bumpless: the
integrator is the command itself, Eq. 7.12). A commanded TRACK keeps ACQUIRE; link silence takes it to SAFE.
64 ticks for the same reasons as SAT_TICKS (below): 25 loop time constants, and with decim <= acq_ticks every
stay in ACQUIRE and every return to TRACK between two losses (each at least acq_ticks long) shows in a CTRL_STATUS.

Saturation is an event. The run ``sat_run`` counts the ticks the command has stayed on its clamp: each tick
the law hits it, and each beam-lost hold in TRACK or SATURATED after one (the held command is the clamped
one). TRACK enters SATURATED when the run reaches ``sat_ticks`` (default ``SAT_TICKS`` = 64, 100.3 ms at
637.8 Hz). Why 64: the loop (g = 0.5, -3 dB rejection bandwidth 39 Hz, a time constant of 4.1 ms = 2.6 ticks)
settles in a few ticks, so a transient or a jitter crest holds the clamp for a few ticks only, while 64 ticks
(25 time constants) on it mean the error itself lies beyond the mirror's range; and 64 is the default status
decimation, so with decim <= sat_ticks every sustained saturation shows in a CTRL_STATUS while under way, and
its length (``sat_last``) in the next one, before another can end. SATURATED runs the same law; on the first
law tick whose command stays inside the clamp on both axes the run ends and the controller returns to TRACK
(bumpless: the law never stopped); a new episode needs another full run, so the mode changes at most once each
way per sat_ticks + 1 ticks. A run that reached sat_ticks leaves its length in ``sat_last``;
``n_sat_episodes`` counts the entries. HOLD, SAFE or any other mode ends a run; a CTRL_SETTINGS asking for
TRACK while SATURATED keeps SATURATED. ``why`` says why SAFE or ACQUIRE was last entered: SATURATED is its own
reason.

Speed (bench/bench_firmware.py): the tick's state is one preallocated integer list (slots ``S_*`` below) read
through a local, and ``step`` runs the law (TRACK or SATURATED, beam present) inline with every other case in
``_step_other``. ``firmware.controller_viper.ViperController`` (MicroPython only) runs that common case as
viper machine code over an int32 array with the same slots and gives identical codes.
"""

import struct

from firmware import ad5664r
from firmware import hinv
from firmware.hinv import HinvTable, load_file
from firmware.upload import Upload
from protocol import consts, hblob   # the packet table's numbers: generated from it, no table objects on the board

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

# --- generated by `python -m tools.gen_consts` from protocol/table.py's MODES: do not edit ---
IDLE = const(0)
TRACK = const(1)
HOLD = const(2)
CALIBRATE = const(3)
SAFE = const(4)
SATURATED = const(5)
ACQUIRE = const(6)
# --- end of generated constants ---

# The tick's state lives in one preallocated integer list, ``Controller._s`` (an index load is far cheaper than
# an attribute lookup under MicroPython); the slots, with their Q-formats (private constants: MicroPython folds
# them and keeps no name; firmware.controller_viper restates them, written by python -m tools.gen_consts; S_BXQ
# and S_BYQ are public for the benches, which force a re-evaluation of g H^-1):
_S_MODE = const(0)        # mode, plus _INIT_BIT until the init tick went out
_S_TICKS = const(1)       # ticks since boot (wraps at 2^30)
_S_VX = const(2)          # command state, AD5664R tilt code Q8 (code * 256, 0.298 uV per LSB)
_S_VY = const(3)
_S_RX = const(4)          # last measured ratios, Q15
_S_RY = const(5)
_S_VS = const(6)          # last Q1 sum, counts
_S_LOST = const(7)        # consecutive beam-lost ticks (saturates)
_S_THR = const(8)         # beam threshold, counts
_S_RXC = const(9)         # ratio commands, Q15
_S_RYC = const(10)
_S_LIM = const(11)        # +- saturation limit, code Q8
_S_NLIM = const(12)
S_BXQ = const(13)        # bin of the cached g H^-1, as (bin << 14) in code Q8 (_NO_BIN: none)
S_BYQ = const(14)
_S_SHIFT = const(15)      # 7 + hq: law product Q(15 + hq) -> Q8
_S_ROUND = const(16)      # 128 + (1 << (shift - 1) << 8): both roundings of the law, added before its >> 8
_S_SAT_TICK = const(17)   # last tick the command saturated (-1: never)
_S_N_LOST = const(18)     # telemetry counter, wraps at 2^16
_S_N_SAT = const(19)      # ticks the law hit the clamp (stops at _COUNT_MAX)
_S_GH = const(20)         # cached g H^-1 (_gain_hinv): high parts h11 h12 h21 h22 (Q hq), then low bytes
_S_SAT_RUN = const(28)    # ticks the command has stayed on its clamp (0: off it; stops at _COUNT_MAX)
_S_SAT_LAST = const(29)   # length of the last run that reached sat_ticks, once ended (0: none)
_S_N_SAT_EP = const(30)   # entries into SATURATED, wraps at 2^16
_S_PKT = const(31)        # tick of the last packet from the link
_S_QUIET = const(32)      # ticks the link HAL waited without a TICK (link_silent; stops at _COUNT_MAX)
_S_SEEN = const(33)       # ACQUIRE: beam-present ticks in a row (back to TRACK at acq_ticks)
_S_SIZE = const(34)

_INIT_BIT = const(8)
_E_MAX = const(16383)             # |dR| clamp, Q15 (0.5)
_COUNT_MAX = const(0x3FFFFFFF)    # counters saturate / wrap below 2^30
_NO_BIN = const(1 << 29)          # (v ^ _NO_BIN) >> 14 != 0 for every |v| < 2^29: forces g H^-1 to be evaluated
_FLAG_BEAM = const(1)
_FLAG_SAT = const(2)
_FLAG_TABLE = const(4)
WHY_BEAM = const(1)               # CTRL_STATUS.why (protocol.table.SAFE_REASONS): ACQUIRE's
WHY_LINK = const(2)
WHY_COMMANDED = const(3)
MAX_HTABLE_BYTES = const(8192)    # H-table blob the controller accepts: a 22x22 grid (7.9 kB; 11x11 is 2 kB)
SAT_TICKS = const(64)             # ticks on the clamp in a row before TRACK enters SATURATED (module docstring)
ACQ_TICKS = const(64)             # beam-lost ticks in a row before TRACK enters ACQUIRE, and beam ticks back

FW_VERSION = (1, 0)


class _Slot:
    """Slot i of the state list as an attribute: a descriptor (about 50 bytes of heap each on the board, where a
    property of two closures took 115, measured)."""

    def __init__(self, i):
        self.i = i

    def __get__(self, obj, cls=None):
        return self if obj is None else obj._s[self.i]

    def __set__(self, obj, v):
        obj._s[self.i] = v


class Controller:
    """The fine-pointing controller. ``step`` is the allocation-free tick; ``handle`` the packet side.

    hal: optional HAL (``firmware.hal``) used by ``tick`` (read Q1, write SPI) and to send telemetry.
    max_table_bytes: the largest H-table blob an upload may bring (TOO_LARGE beyond). static: the upload's buffer
    and the table's integer array for that size are allocated here, once, and reused by every upload (a small
    board, ``firmware.pil_main``: later, its heap holds no free block that large).
    """

    ticks = _Slot(_S_TICKS)
    vx_q8 = _Slot(_S_VX)
    vy_q8 = _Slot(_S_VY)
    rx = _Slot(_S_RX)
    ry = _Slot(_S_RY)
    vs = _Slot(_S_VS)
    lost = _Slot(_S_LOST)
    beam_threshold = _Slot(_S_THR)
    rx_cmd = _Slot(_S_RXC)
    ry_cmd = _Slot(_S_RYC)
    n_lost = _Slot(_S_N_LOST)
    n_sat = _Slot(_S_N_SAT)
    sat_run = _Slot(_S_SAT_RUN)
    sat_last = _Slot(_S_SAT_LAST)
    n_sat_episodes = _Slot(_S_N_SAT_EP)

    def __init__(self, hal=None, table=None, gain_q15=16384, beam_threshold=200, safe_ticks=638, decim=64,
                 limit_code=ad5664r.TILT_LIMIT_CODE, ramp_code=64, rx_cmd_q15=0, ry_cmd_q15=0, sat_ticks=SAT_TICKS,
                 acq_ticks=ACQ_TICKS, centre_ticks=638, max_table_bytes=MAX_HTABLE_BYTES, static=False):
        _check_int("gain_q15", gain_q15, 0, 65535)
        _check_int("beam_threshold", beam_threshold, 1, 4095)
        _check_int("safe_ticks", safe_ticks, 1, 65535)
        _check_int("decim", decim, 0, 65535)
        _check_int("limit_code", limit_code, 0, ad5664r.TILT_LIMIT_CODE)
        _check_int("ramp_code", ramp_code, 1, ad5664r.TILT_LIMIT_CODE)
        _check_int("rx_cmd_q15", rx_cmd_q15, -16384, 16384)
        _check_int("ry_cmd_q15", ry_cmd_q15, -16384, 16384)
        _check_int("sat_ticks", sat_ticks, 1, 65535)
        _check_int("acq_ticks", acq_ticks, 1, 65535)
        _check_int("centre_ticks", centre_ticks, 1, 65535)
        self._s = s = self._state()
        s[_S_MODE] = IDLE | _INIT_BIT   # the first tick sends the AD5664R init sequence
        s[_S_THR] = beam_threshold
        s[_S_RXC] = rx_cmd_q15
        s[_S_RYC] = ry_cmd_q15
        s[_S_LIM] = limit_code << 8
        s[_S_NLIM] = -(limit_code << 8)
        s[S_BXQ] = _NO_BIN
        s[_S_SHIFT] = 8
        s[_S_ROUND] = 128 + (128 << 8)
        s[_S_SAT_TICK] = -1
        self.hal = hal
        self.gain = gain_q15
        self.safe_ticks = safe_ticks
        self.sat_ticks = sat_ticks
        self.acq_ticks = acq_ticks
        self.centre_ticks = centre_ticks
        self.decim = decim
        self.ramp_q8 = ramp_code << 8
        self.n_unknown = 0             # telemetry counters, wrap at 2^16
        self.n_dup = 0                 # set by the link HAL: resent TICKs answered from its cache,
        self.n_gap = 0                 # ticks the bench ran without us, frames its decoder dropped
        self.n_rx_drop = 0
        self.why = 0                   # why SAFE or ACQUIRE was last entered (WHY_*)
        self._end = None               # (total, crc, code) of the last finished upload: END is idempotent
        self.words = self._words()     # this tick's AD5664R words
        self._h4 = [0] * 4             # scratch for the interpolated H^-1
        self._q1 = [0, 0, 0]
        self._upload = Upload(max_table_bytes, static=static)
        self._static_t = hinv.arrays(max_table_bytes) if static else None
        self.table = None
        if table is not None:
            self.set_table(table)

    def _state(self):
        return [0] * _S_SIZE

    def _words(self):
        return [0, 0, 0, 0]

    @property
    def mode(self):
        return self._s[_S_MODE] & 7      # IDLE .. ACQUIRE (0..6) fit below _INIT_BIT

    @mode.setter
    def mode(self, m):
        s = self._s
        s[_S_MODE] = m | (s[_S_MODE] & _INIT_BIT)

    # --- table -------------------------------------------------------------------------------------
    def set_table(self, table):
        """Swap in a table: a HinvTable, a protocol.htable.Grid, blob bytes, or a file path (.json or blob).
        Raises HTableError (a ValueError) and keeps the previous table if the new one is refused. With ``static``
        buffers a blob or a Grid is written into the table's own array once every check has passed."""
        if isinstance(table, str):
            t = load_file(table)
        elif isinstance(table, (bytes, bytearray, memoryview)):
            t = HinvTable(hblob.Blob(table), self._static_t)   # straight from the bytes: no Grid of floats in RAM
        elif isinstance(table, HinvTable):
            t = table
        elif isinstance(table, hblob.Rectilinear):                  # a protocol.htable.Grid
            t = HinvTable(table, self._static_t)
        else:
            raise ValueError("table must be a path, blob bytes, Grid or HinvTable, got %r" % type(table))
        self.table = t
        s = self._s
        s[_S_SHIFT] = t.shift
        s[_S_ROUND] = 128 + (1 << (t.shift - 1) << 8)
        s[S_BXQ] = _NO_BIN             # re-evaluate g H^-1 on the next tick

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
        s = self._s
        for e in range(4):
            v = (g * h[e] + 64) >> 7
            s[_S_GH + e] = v >> 8
            s[_S_GH + 4 + e] = v & 255
        s[S_BXQ] = bx << 14
        s[S_BYQ] = by << 14

    def step(self, vx, vy, vs):
        """One control tick from Q1 counts (Eq. 7.4, 7.12, 7.13); words in ``self.words``; returns 4.
        The law (TRACK or SATURATED, beam present) runs inline; every other case is ``_step_other``."""
        s = self._s
        m = s[_S_MODE]
        if (m != TRACK and m != SATURATED) or vs < s[_S_THR]:
            return self._step_other(vx, vy, vs)
        s[_S_TICKS] = (s[_S_TICKS] + 1) & _COUNT_MAX
        s[_S_VS] = vs
        s[_S_LOST] = 0
        r = vs >> 1
        ex = (((2048 - vx) << 15) + r) // vs                # Eq. 7.4: Rx, Q15; |.| <= 2^26 before the division
        ey = (((2048 - vy) << 15) + r) // vs
        s[_S_RX] = ex
        s[_S_RY] = ey
        ex -= s[_S_RXC]                                      # Eq. 7.13: dR, Q15, clamped to +-0.5
        if ex > _E_MAX:
            ex = _E_MAX
        elif ex < -_E_MAX:
            ex = -_E_MAX
        ey -= s[_S_RYC]
        if ey > _E_MAX:
            ey = _E_MAX
        elif ey < -_E_MAX:
            ey = -_E_MAX
        v_x = s[_S_VX]
        v_y = s[_S_VY]
        if ((v_x ^ s[S_BXQ]) | (v_y ^ s[S_BYQ])) >> 14:     # the command left the cached 64-code bin
            self._gain_hinv(v_x >> 14, v_y >> 14)
        # Eq. 7.12: V -= (g H^-1) dR, high parts (<= 31999 * 16383 each, the pair < 2^30) plus the
        # low bytes' share (<= 2 * 255 * 16383 >> 8), Q(15 + hq) -> Q8 code, rounded: r = 128 + (2^(n-1) << 8)
        # <= 2^26 rounds the low bytes' share and, being 2^(n-1) after the >> 8, the whole
        n = s[_S_SHIFT]
        r = s[_S_ROUND]
        v_x -= (s[_S_GH] * ex + s[_S_GH + 1] * ey + ((s[_S_GH + 4] * ex + s[_S_GH + 5] * ey + r) >> 8)) >> n
        v_y -= (s[_S_GH + 2] * ex + s[_S_GH + 3] * ey + ((s[_S_GH + 6] * ex + s[_S_GH + 7] * ey + r) >> 8)) >> n
        r = s[_S_LIM]
        if v_x > r or v_y > r or v_x < s[_S_NLIM] or v_y < s[_S_NLIM]:
            self._run_on()                                  # the law hit the clamp: the run goes on
            return self._out(v_x, v_y)
        if s[_S_SAT_RUN]:                                    # inside the clamp again: the run ends
            self._run_end()
        s[_S_VX] = v_x
        s[_S_VY] = v_y
        w = self.words
        r = (v_x + 128) >> 8
        w[0] = 0x008000 + r             # X+ = bias + x, cmd 000 addr A
        w[1] = 0x018000 - r             # X- = bias - x, cmd 000 addr B
        r = (v_y + 128) >> 8
        w[2] = 0x038000 + r             # Y+ = bias + y, cmd 000 addr D
        w[3] = 0x128000 - r             # Y- = bias - y, cmd 010 addr C (write, update all)
        return 4

    def _step_other(self, vx, vy, vs):
        """``step`` for the init tick, beam loss and the modes other than TRACK and SATURATED (ACQUIRE's
        exit and return: the module docstring)."""
        s = self._s
        m = s[_S_MODE]
        if m & _INIT_BIT:              # first tick after boot: the AD5664R init sequence
            s[_S_MODE] = m & 7
            w = self.words
            w[0], w[1], w[2], w[3] = ad5664r.INIT_WORDS
            return 4
        s[_S_TICKS] = (s[_S_TICKS] + 1) & _COUNT_MAX
        s[_S_VS] = vs
        if vs < s[_S_THR]:
            s[_S_N_LOST] = (s[_S_N_LOST] + 1) & 0xFFFF
            if m == TRACK or m == SATURATED or m == ACQUIRE:   # hold (no integration)
                if s[_S_LOST] < _COUNT_MAX:
                    s[_S_LOST] += 1
                s[_S_SEEN] = 0             # ACQUIRE counts the beam's return from the next beam tick on
                if m != ACQUIRE:
                    if s[_S_SAT_RUN]:       # the held command is the clamped one: the run goes on
                        self._run_on()
                    if s[_S_LOST] >= self.acq_ticks:    # not a flicker: ACQUIRE
                        s[_S_MODE] = ACQUIRE
                        self.why = WHY_BEAM
        else:                          # ratios for telemetry (calibration reads them)
            r = vs >> 1
            s[_S_RX] = (((2048 - vx) << 15) + r) // vs
            s[_S_RY] = (((2048 - vy) << 15) + r) // vs
            if m == ACQUIRE:           # the beam back: hold while it stays acq_ticks in a row, then TRACK
                s[_S_LOST] = 0
                s[_S_SEEN] += 1
                if s[_S_SEEN] >= self.acq_ticks:
                    s[_S_MODE] = TRACK
                    s[_S_SEEN] = 0
        if s[_S_SAT_RUN] and m != TRACK and m != SATURATED:    # no law this tick: the run ends
            self._run_end()
        if m == SAFE or m == IDLE or (m == ACQUIRE and s[_S_LOST] >= self.centre_ticks):
            # move the command toward the centre by ramp_code per tick, never integrating
            r = self.ramp_q8
            v = s[_S_VX]
            s[_S_VX] = v - r if v > r else (v + r if v < -r else 0)
            v = s[_S_VY]
            s[_S_VY] = v - r if v > r else (v + r if v < -r else 0)
        return self._out(s[_S_VX], s[_S_VY])

    def _run_on(self):
        """One more tick on the clamp: TRACK enters SATURATED when the run reaches ``sat_ticks``."""
        s = self._s
        n = s[_S_SAT_RUN]
        if n < _COUNT_MAX:
            n += 1
            s[_S_SAT_RUN] = n
        if n >= self.sat_ticks and s[_S_MODE] == TRACK:
            s[_S_MODE] = SATURATED
            s[_S_N_SAT_EP] = (s[_S_N_SAT_EP] + 1) & 0xFFFF

    def _run_end(self):
        """The command left the clamp (or the law stopped): a sustained run leaves its length in sat_last, and
        SATURATED returns to TRACK."""
        s = self._s
        n = s[_S_SAT_RUN]
        if n >= self.sat_ticks:
            s[_S_SAT_LAST] = n
        s[_S_SAT_RUN] = 0
        if s[_S_MODE] == SATURATED:
            s[_S_MODE] = TRACK

    def _out(self, v_x, v_y):
        """Saturation (the state itself is clamped: anti-windup), then the words of command v_x, v_y (Q8)."""
        s = self._s
        r = s[_S_LIM]
        if v_x > r or v_x < -r or v_y > r or v_y < -r:
            v_x = r if v_x > r else (-r if v_x < -r else v_x)
            v_y = r if v_y > r else (-r if v_y < -r else v_y)
            s[_S_SAT_TICK] = s[_S_TICKS]
            if s[_S_N_SAT] < _COUNT_MAX:
                s[_S_N_SAT] += 1
        s[_S_VX] = v_x
        s[_S_VY] = v_y
        w = self.words
        r = (v_x + 128) >> 8
        w[0] = 0x008000 + r
        w[1] = 0x018000 - r
        r = (v_y + 128) >> 8
        w[2] = 0x038000 + r
        w[3] = 0x128000 - r
        return 4

    @property
    def flags(self):
        """CTRL_STATUS flags: bit0 beam present, bit1 saturated on the last tick, bit2 table loaded."""
        s = self._s
        return ((_FLAG_BEAM if s[_S_VS] >= s[_S_THR] else 0)
                | (_FLAG_SAT if s[_S_SAT_TICK] == s[_S_TICKS] else 0)
                | (_FLAG_TABLE if self.table is not None else 0))

    def tick(self):
        """One tick on a board: read Q1 through the HAL, step, clock the words out, all with the heap locked
        (an allocation would raise MemoryError; MicroPython then keeps even large call frames off the heap)."""
        q = self._q1
        s = self._s
        heap_lock()
        try:
            self.hal.read_q1(q)
            n = self.step(q[0], q[1], q[2])
            self.hal.spi_write(self.words, n)
            m = s[_S_MODE]
            if m != IDLE and m != SAFE and ((s[_S_TICKS] - s[_S_PKT]) & _COUNT_MAX) >= self.safe_ticks:
                s[_S_MODE] = SAFE                            # the ground link fell silent
                self.why = WHY_LINK
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
        the tick it starts, so that tick sees no silence; any other packet to the last tick. (Both counts are
        state slots, not attributes: a board's machine-code TICK path, ``firmware.hal.fast_tick``, sets them.)"""
        s = self._s
        t = s[_S_TICKS]
        s[_S_PKT] = (t + 1) & _COUNT_MAX if tick_packet else t
        s[_S_QUIET] = 0

    def link_silent(self, ticks):
        """The link has been silent for about ``ticks`` ticks with no TICK to step on (link HAL): enter SAFE
        once the total reaches ``safe_ticks`` in TRACK, HOLD or CALIBRATE (the ramp runs on the next ticks)."""
        s = self._s
        s[_S_QUIET] = q = min(s[_S_QUIET] + ticks, _COUNT_MAX)
        if self.mode != IDLE and self.mode != SAFE and q >= self.safe_ticks:
            self.mode = SAFE
            self.why = WHY_LINK

    def status_due(self):
        """On a board: CTRL_STATUS every ``decim`` of the controller's own ticks."""
        return self.decim != 0 and self._s[_S_TICKS] % self.decim == 0

    def status_due_at(self, tick):
        """In lockstep: CTRL_STATUS on the bench ticks k with k % decim == 0, so the bench knows which ticks
        carry one and can ask again for a lost one."""
        d = self.decim
        return d != 0 and tick % d == 0

    # --- packets -----------------------------------------------------------------------------------
    def status_payload(self, tick=None):
        """CTRL_STATUS payload bytes (telemetry path; allocates)."""
        w = self.words
        rx = max(-32768, min(32767, self.rx))
        ry = max(-32768, min(32767, self.ry))
        return struct.pack(consts.FMT_CTRL_STATUS, self.ticks if tick is None else tick & 0xFFFFFFFF, self.mode,
                           self.flags, _uv(self.vx_q8), _uv(self.vy_q8), rx, ry, self.vs,
                           w[0] & 0xFFFF, w[1] & 0xFFFF, w[2] & 0xFFFF, w[3] & 0xFFFF,
                           self.n_lost, self.n_sat, self.n_unknown, self.why, self.n_dup & 0xFFFF,
                           self.n_gap & 0xFFFF, self.n_rx_drop & 0xFFFF, self.sat_run, self.sat_last,
                           self.n_sat_episodes)

    def handle(self, pid, src, seq, payload):
        """One packet from the link (``seq`` None on CAN); returns a list of replies ``(pid, dst, payload)``.

        Commands are ACKed or NACKed with an ``ERRORS`` code; packets this node does not handle are counted
        in n_unknown and ignored (no reply).
        """
        self.heard()
        seq = seq & 0xFF if seq is not None else 0      # CAN frames carry no sequence number
        size = consts.SIZES[pid]
        if size == 0xFF or len(payload) != size:
            return self._unknown()
        if pid == consts.P_CTRL_SETTINGS:
            code = self._settings(struct.unpack(consts.FMT_CTRL_SETTINGS, payload))
        elif pid == consts.P_CTRL_SET_FSM:
            code = self._set_fsm(struct.unpack(consts.FMT_CTRL_SET_FSM, payload))
        elif pid == consts.P_HTABLE_BEGIN:
            total, crc = struct.unpack(consts.FMT_HTABLE_BEGIN, payload)
            code = self._upload.begin(total, crc)
            self._end = None
        elif pid == consts.P_HTABLE_CHUNK:
            offset, length, data = struct.unpack(consts.FMT_HTABLE_CHUNK, payload)
            code = self._upload.chunk(offset, length, data)
        elif pid == consts.P_HTABLE_END:
            code = self._upload_end(struct.unpack(consts.FMT_HTABLE_END, payload)[0])
        elif pid == consts.P_HELLO:
            return [(consts.P_HELLO, src, hello_payload(consts.NODE_CONTROLLER, FW_VERSION))]
        elif pid == consts.P_ACK or pid == consts.P_NACK:
            return []
        else:
            return self._unknown()
        if code:
            return [(consts.P_NACK, src, struct.pack("<BBB", pid, seq, code))]
        return [(consts.P_ACK, src, struct.pack("<BB", pid, seq))]

    def _unknown(self):
        self.n_unknown = (self.n_unknown + 1) & 0xFFFF
        return []

    def _settings(self, v):
        mode, rx_cmd, ry_cmd, gain, decim, safe_ticks = v
        if mode > SAFE or not (-16384 <= rx_cmd <= 16384) or not (-16384 <= ry_cmd <= 16384) or safe_ticks < 1:
            return consts.E_BAD_VALUE
        if mode == TRACK and self.table is None:
            return consts.E_BAD_STATE
        self.rx_cmd = rx_cmd
        self.ry_cmd = ry_cmd
        if gain and gain != self.gain:
            self.gain = gain
            self._s[S_BXQ] = _NO_BIN
        self.decim = decim
        self.safe_ticks = safe_ticks
        if mode != self.mode and not (mode == TRACK and (self.mode == SATURATED or self.mode == ACQUIRE)):
            self.mode = mode          # TRACK starts from the current command: bumpless (SATURATED, ACQUIRE: TRACK's)
            self.lost = 0
            self._s[_S_SEEN] = 0
            if mode == SAFE:
                self.why = WHY_COMMANDED
        return 0

    def _set_fsm(self, v):
        if self.mode != CALIBRATE:
            return consts.E_BAD_STATE
        uvx, uvy = v
        if not (-2500000 <= uvx <= 2500000) or not (-2500000 <= uvy <= 2500000):
            return consts.E_BAD_VALUE
        s = self._s
        s[_S_VX] = max(s[_S_NLIM], min(s[_S_LIM], _q8(uvx)))
        s[_S_VY] = max(s[_S_NLIM], min(s[_S_LIM], _q8(uvy)))
        return 0

    def _upload_end(self, total):
        """END swaps the table in; an END repeated after the transfer finished (its answer was lost) gets the
        same answer again and changes nothing."""
        up = self._upload
        if not up.active and self._end is not None and self._end[0] == total:
            return self._end[2]
        crc = up.crc
        r = up.end(total)
        if isinstance(r, int):
            code = r
        else:
            code = 0
            try:
                self.set_table(r)      # the upload's own buffer, read in place
            except ValueError:
                code = consts.E_BAD_CONTENT
        self._end = (total, crc, code)
        return code


# Q8 codes per uV = CODES_PER_VOLT * 256 / 1e6 = 2^25 / 10^7 exactly: the conversions below are integer, rounded half
# away from zero, so that every port gives the same codes (a single-precision float, as on a Cortex-M0 port, did
# not: 1 uV off in a CTRL_STATUS, measured under QEMU)
_Q8_NUM, _Q8_DEN = 1 << 25, 10000000


def _q8(uv):
    """Q8 tilt code of ``uv`` microvolts."""
    return (uv * _Q8_NUM + _Q8_DEN // 2) // _Q8_DEN if uv >= 0 else -((-uv * _Q8_NUM + _Q8_DEN // 2) // _Q8_DEN)


def _uv(q8):
    """Microvolts of the Q8 tilt code ``q8``."""
    return (q8 * _Q8_DEN + _Q8_NUM // 2) // _Q8_NUM if q8 >= 0 else -((-q8 * _Q8_DEN + _Q8_NUM // 2) // _Q8_NUM)


def hello_payload(node, version):
    """A HELLO payload (the packet table's fields: protocol version, node, firmware major and minor, caps 0)."""
    return struct.pack(consts.FMT_HELLO, consts.PROTOCOL_VERSION, node, version[0], version[1], 0)


def _check_int(name, v, lo, hi):
    if isinstance(v, bool) or not isinstance(v, int) or v < lo or v > hi:
        raise ValueError("controller %s = %r out of range [%d, %d]" % (name, v, lo, hi))
