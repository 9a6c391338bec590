"""The common TICK exchange as machine code (viper), for a board's link (``firmware.hal.stdio``); MicroPython only.

``firmware.hal.link.serve_controller`` answers a TICK in bytecode: the decoder's packet tuple, ``struct``, the
exactly-once checks, the encoder. On the thesis's Cortex-M0 that took about 107,000 instructions a tick (measured,
``make bench``'s PIL table), more than the whole 1.568 ms tick at 48 MHz. ``answer`` does the common tick in one
viper call: the next TICK in sequence, to this node, in the ADC's range, with no CTRL_STATUS due, from the same
source with the next sequence number. It decodes the frame (COBS and CRC-16, ``protocol.fast``), steps the
controller (``ctl.heard(True)`` inline, then ``ctl.step``: the same steps, in the same order, as ``serve_controller``), and
frames the FSM_SPI answer; anything else it leaves untouched for the bytecode path (returns 0), which answers it as
it always did. So the codes and the answers are the same, bit for bit (tests/test_pil.py runs both).
"""

import micropython

from micropython import const
from protocol import fast

# The packet table's numbers again (viper needs them as constants of this module; tests/test_pil.py checks them
# against protocol.consts).
_VERSION = const(1)
_P_TICK = const(0x10)
_P_FSM_SPI = const(0x11)
_BROADCAST = const(0xFF)
_TICK_RAW = const(21)                # header 5 + TICK 14 + CRC 2
# the controller's state slots ``Controller.heard`` sets (firmware.controller's, checked likewise)
_S_TICKS = const(1)
_S_PKT = const(31)
_S_QUIET = const(32)
_COUNT_MAX = const(0x3FFFFFFF)
_SPI_BODY = const(26)                # header 5 + FSM_SPI 21

# The link's counters ``answer`` keeps (``StdioLink._st``, an array('i'); firmware.hal.stdio's ``_ST_*``, checked
# by tests/test_pil.py): the sequence number of the next frame sent, the frames sent, the frames received since the
# decoder last heard of them with the last one's source and sequence number (-1: none yet), and the words' count
# the last step returned.
_ST_TX_SEQ = const(0)
_ST_TX_FRAMES = const(1)
_ST_RX_FRAMES = const(2)
_ST_RX_SRC = const(3)
_ST_RX_SEQ = const(4)
_ST_SPI_N = const(5)


@micropython.viper
def answer(lk, ctl, n: int, last: int) -> int:
    """Answer the frame ``lk._frame[0:n]`` (its 0x00 included) if it is the common TICK ``last + 1``: the FSM_SPI
    frame goes into ``lk._out`` and its length is returned. 0 if it is not one (nothing changed, nothing sent).
    ``lk``: the link (``_frame``, ``_raw``, ``_out``, ``_st``, ``node``); ``ctl``: the controller, its ``words`` an array('i') (``ViperController``)."""
    if n < 2 or n > _TICK_RAW + 4:   # a TICK's frame is 22 or 23 bytes with its 0x00
        return 0
    rb = lk._raw
    raw = ptr8(rb)
    if int(fast.unframe(lk._frame, 0, n - 1, rb)) != _TICK_RAW:   # bad COBS, bad CRC, or another length
        return 0
    st = ptr32(lk._st)
    me = int(lk.node)
    src = int(raw[2])
    seq = int(raw[4])
    if int(raw[0]) != _VERSION or int(raw[1]) != _P_TICK or (int(raw[3]) != me and int(raw[3]) != _BROADCAST):
        return 0
    if src != int(st[_ST_RX_SRC]) or seq != ((int(st[_ST_RX_SEQ]) + 1) & 0xFF):
        return 0                     # a sequence gap or a new source: the decoder counts it
    if int(raw[8]) >= 0x40:          # ticks from 2^30 on: beyond a small int on a 32-bit port
        return 0
    tick = int(raw[5]) | (int(raw[6]) << 8) | (int(raw[7]) << 16) | (int(raw[8]) << 24)
    if tick != last + 1:
        return 0
    vx = int(raw[13]) | (int(raw[14]) << 8)
    vy = int(raw[15]) | (int(raw[16]) << 8)
    vs = int(raw[17]) | (int(raw[18]) << 8)
    if (vx | vy | vs) >> 12:
        return 0
    d = int(ctl.decim)
    if d != 0 and tick % d == 0:     # a CTRL_STATUS is due: the bytecode path sends it
        return 0
    st[_ST_RX_FRAMES] = st[_ST_RX_FRAMES] + 1
    st[_ST_RX_SEQ] = seq
    s = ptr32(ctl._s)                # ctl.heard(True), inline
    s[_S_PKT] = (s[_S_TICKS] + 1) & _COUNT_MAX
    s[_S_QUIET] = 0
    k = int(ctl.step(vx, vy, vs))
    st[_ST_SPI_N] = k
    w = ptr32(ctl.words)
    t = int(st[_ST_TX_SEQ])
    st[_ST_TX_SEQ] = (t + 1) & 0xFF
    raw[0] = _VERSION
    raw[1] = _P_FSM_SPI
    raw[2] = me
    raw[3] = src
    raw[4] = t
    # the payload, FSM_SPI '<IBIIII': the tick, the words' count, the four words (little-endian)
    raw[5] = tick & 0xFF
    raw[6] = (tick >> 8) & 0xFF
    raw[7] = (tick >> 16) & 0xFF
    raw[8] = tick >> 24
    raw[9] = k
    i = 0
    while i < 4:
        x = int(w[i])
        j = 10 + 4 * i
        raw[j] = x & 0xFF
        raw[j + 1] = (x >> 8) & 0xFF
        raw[j + 2] = (x >> 16) & 0xFF
        raw[j + 3] = (x >> 24) & 0xFF
        i += 1
    c = int(fast.crc16(rb, _SPI_BODY, 0xFFFF))
    raw[_SPI_BODY] = c >> 8
    raw[_SPI_BODY + 1] = c & 0xFF
    ob = lk._out
    out = ptr8(ob)
    m = int(fast.cobs_encode(rb, _SPI_BODY + 2, ob))
    out[m] = 0
    st[_ST_TX_FRAMES] = st[_ST_TX_FRAMES] + 1
    return m + 1
