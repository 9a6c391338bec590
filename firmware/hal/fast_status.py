"""The CTRL_STATUS of a board's machine-code tick path (``firmware.hal.fast_tick``), packed and framed without
allocation in preallocated buffers, by viper code; MicroPython only.

``status`` writes ``Controller.status_payload``'s bytes (``protocol.consts.FMT_CTRL_STATUS``) from the controller's
state slots and counters into the link's ``_stat`` (header, payload, CRC-16), and COBS-frames them into the link's
``_out``, after the tick's FSM_SPI went out from that buffer: the loop's output first, the status after it.
"""

import micropython

from micropython import const
from protocol import fast

# The link's counters (``firmware.hal.stdio``'s ``_ST_*``), the protocol's version, CTRL_STATUS (its id, a frame's
# body: header 5, payload 53) and the controller's slots ``status`` reads (``firmware.controller``'s ``_S_*``),
# restated as this module's constants for viper; tests/test_fast_status.py checks each against its source.
_ST_TX_SEQ = const(0)
_ST_TX_FRAMES = const(1)
_ST_RX_SRC = const(3)
_VERSION = const(1)
_P_CTRL_STATUS = const(0x22)
_STATUS_BODY = const(58)
_S_MODE = const(0)
_S_TICKS = const(1)
_S_VX = const(2)
_S_VY = const(3)
_S_RX = const(4)
_S_RY = const(5)
_S_VS = const(6)
_S_THR = const(8)
_S_SAT_TICK = const(17)
_S_N_LOST = const(18)
_S_N_SAT = const(19)
_S_SAT_RUN = const(28)
_S_SAT_LAST = const(29)
_S_N_SAT_EP = const(30)


@micropython.viper
def _uv(q8: int) -> int:
    """``firmware.controller._uv`` for |q8| < 2^24 in 32-bit integers: round(q8 * 10^7 / 2^25), half away from zero,
    as (|q8| * 78125 + 2^17) >> 18 with |q8| split at bit 12 (each product below 2^29)."""
    sg = 1
    x = q8
    if q8 < 0:
        sg = -1
        x = 0 - q8
    a = (x >> 12) * 78125
    return sg * ((a >> 6) + ((((a & 63) << 12) + (x & 0xFFF) * 78125 + 0x20000) >> 18))


# the payload's fields after mode and flags: (offset in the frame's body, bytes, source), the source a state slot
# (< 100) or one of the codes below, in the packet table's order
_TICK = const(100)
_UV = const(101)                      # 101, 102: the command in uV (x, y)
_RATIO = const(103)                   # 103, 104: rx, ry clamped to int16
_WORD = const(105)                    # 105 .. 108: the AD5664R words' low 16 bits
_N_UNKNOWN = const(109)
_N_DUP = const(110)
_N_GAP = const(111)
_N_RX_DROP = const(112)
_FIELDS = bytes((5, 4, _TICK, 11, 4, _UV, 15, 4, _UV + 1, 19, 2, _RATIO, 21, 2, _RATIO + 1, 23, 2, _S_VS,
                 25, 2, _WORD, 27, 2, _WORD + 1, 29, 2, _WORD + 2, 31, 2, _WORD + 3, 33, 2, _S_N_LOST, 35, 4, _S_N_SAT,
                 39, 2, _N_UNKNOWN, 42, 2, _N_DUP, 44, 2, _N_GAP, 46, 2, _N_RX_DROP, 48, 4, _S_SAT_RUN,
                 52, 4, _S_SAT_LAST, 56, 2, _S_N_SAT_EP))


@micropython.viper
def status(lk, ctl, tick: int) -> int:
    """The CTRL_STATUS of ``tick`` (``Controller.status_payload``'s bytes: the format ``consts.FMT_CTRL_STATUS``,
    ``n_rx_drop`` as the link set it) packed into ``lk._stat`` with its header and framed into ``lk._out``; returns
    the frame's length (its 0x00 included). Allocates nothing; run after the tick's FSM_SPI went out."""
    sb = lk._stat
    b = ptr8(sb)
    st = ptr32(lk._st)
    s = ptr32(ctl._s)
    bb = 1
    bb <<= 30                        # a ptr32 load is zero-extended on a 64-bit port: ((x + 2^30) & m) - 2^30
    m = (bb << 1) - 1                # restores the sign (controller_viper.step)
    t = int(st[_ST_TX_SEQ])
    st[_ST_TX_SEQ] = (t + 1) & 0xFF
    b[0] = _VERSION
    b[1] = _P_CTRL_STATUS
    b[2] = int(lk.node)
    b[3] = int(st[_ST_RX_SRC])
    b[4] = t
    b[9] = int(s[_S_MODE]) & 7
    f = 0
    if int(s[_S_VS]) >= int(s[_S_THR]):
        f = 1                                            # beam present
    if s[_S_SAT_TICK] == s[_S_TICKS]:
        f |= 2                                           # saturated on the last tick
    if ctl.table:                                        # a HinvTable (true) or None
        f |= 4                                           # table loaded
    b[10] = f
    w = ptr32(ctl.words)
    fd = ptr8(_FIELDS)
    i = 0
    while i < 57:                                        # _FIELDS: 19 fields of 3 bytes
        c = fd[i + 2]
        if c < _TICK:
            x = ((s[c] + bb) & m) - bb
        elif c == _TICK:
            x = tick
        elif c < _RATIO:
            x = int(_uv(((s[_S_VX + c - _UV] + bb) & m) - bb))
        elif c < _WORD:
            x = ((s[_S_RX + c - _RATIO] + bb) & m) - bb
            if x < -32768:
                x = -32768
            elif x > 32767:
                x = 32767
        elif c < _N_UNKNOWN:
            x = int(w[c - _WORD])
        elif c == _N_UNKNOWN:
            x = int(ctl.n_unknown)
        elif c == _N_DUP:
            x = int(ctl.n_dup)
        elif c == _N_GAP:
            x = int(ctl.n_gap)
        else:
            x = int(ctl.n_rx_drop)
        o = fd[i]
        j = 0
        while j < int(fd[i + 1]):                        # little-endian (a negative x in two's complement)
            b[o + j] = x >> (8 * j)
            j += 1
        i += 3
    b[41] = int(ctl.why)
    c = int(fast.crc16(sb, _STATUS_BODY, 0xFFFF))
    b[_STATUS_BODY] = c >> 8
    b[_STATUS_BODY + 1] = c & 0xFF
    ob = lk._out
    n = int(fast.cobs_encode(sb, _STATUS_BODY + 2, ob))
    out = ptr8(ob)
    out[n] = 0
    st[_ST_TX_FRAMES] = st[_ST_TX_FRAMES] + 1
    return n + 1
