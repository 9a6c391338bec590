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
def _put(b: ptr8, i: int, x: int, n: int):
    """x's n low bytes into b[i:i + n], little-endian (a negative x in two's complement)."""
    j = 0
    while j < n:
        b[i + j] = (x >> (8 * j)) & 0xFF
        j += 1


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
    _put(sb, 5, tick, 4)
    b[9] = int(s[_S_MODE]) & 7
    f = 0
    if int(s[_S_VS]) >= int(s[_S_THR]):
        f = 1                                            # beam present
    if s[_S_SAT_TICK] == s[_S_TICKS]:
        f |= 2                                           # saturated on the last tick
    if ctl.table:                                        # a HinvTable (true) or None
        f |= 4                                           # table loaded
    b[10] = f
    _put(sb, 11, _uv(((s[_S_VX] + bb) & m) - bb), 4)
    _put(sb, 15, _uv(((s[_S_VY] + bb) & m) - bb), 4)
    i = 0
    while i < 2:                                         # rx, ry: int16, clamped
        r = ((s[_S_RX + i] + bb) & m) - bb
        if r < -32768:
            r = -32768
        elif r > 32767:
            r = 32767
        _put(sb, 19 + 2 * i, r, 2)
        i += 1
    _put(sb, 23, int(s[_S_VS]), 2)
    w = ptr32(ctl.words)
    i = 0
    while i < 4:
        _put(sb, 25 + 2 * i, int(w[i]), 2)
        i += 1
    _put(sb, 33, int(s[_S_N_LOST]), 2)
    _put(sb, 35, int(s[_S_N_SAT]), 4)
    _put(sb, 39, int(ctl.n_unknown), 2)
    b[41] = int(ctl.why)
    _put(sb, 42, int(ctl.n_dup), 2)
    _put(sb, 44, int(ctl.n_gap), 2)
    _put(sb, 46, int(ctl.n_rx_drop), 2)
    _put(sb, 48, int(s[_S_SAT_RUN]), 4)
    _put(sb, 52, int(s[_S_SAT_LAST]), 4)
    _put(sb, 56, int(s[_S_N_SAT_EP]), 2)
    c = int(fast.crc16(sb, _STATUS_BODY, 0xFFFF))
    b[_STATUS_BODY] = c >> 8
    b[_STATUS_BODY + 1] = c & 0xFF
    ob = lk._out
    n = int(fast.cobs_encode(sb, _STATUS_BODY + 2, ob))
    out = ptr8(ob)
    out[n] = 0
    st[_ST_TX_FRAMES] = st[_ST_TX_FRAMES] + 1
    return n + 1
