"""The disturbance player with its per-update loop (``Player._codes``: one segment's codes, Horner per axis) compiled
by MicroPython's viper emitter to machine code. MicroPython only; the .mpy needs ``mpy-cross -march``.

The same integers in the same order as the bytecode loop, so the same codes (tests/mp/firmware_player_viper.py
checks it). On the thesis's 48 MHz Cortex-M0+ the bytecode loop takes about 6,400 instructions an update in blocks
of 64, above the 4,528 cycles of a 10.6 kHz update; this one fits (``make bench``'s PIL table). Buffers are
``array('H')`` (the DAC codes), the segment's coefficients the player's lists; the segment change, the one-shot's
end and every packet stay the bytecode ``Player``'s.
"""

import micropython
from array import array

from firmware.player import Player


class ViperPlayer(Player):
    """``Player`` whose ``fill`` writes each segment's codes in viper (``xbuf``, ``ybuf``: ``array('H')``)."""

    def __init__(self, *args, **kw):
        self._v = array("i", [0] * 16)
        Player.__init__(self, *args, **kw)

    def _codes(self, xbuf, ybuf, k, m, ph, inc, s, half, div, fq, fr, kx, ky):
        v = self._v
        v[0] = ph
        v[1] = inc
        v[2] = s
        v[3] = half
        v[4] = div
        v[5] = fq
        v[6] = fr
        v[7] = m
        for i in range(4):
            v[8 + i] = kx[i]
            v[12 + i] = ky[i]
        _codes_viper(v, xbuf, ybuf, k)
        return v[0]


@micropython.viper
def _codes_viper(v: ptr32, xbuf: ptr16, ybuf: ptr16, k: int):
    """``Player._codes`` over v = [ph, inc, s, half, div, fq, fr, m, x3, x2, x1, x0, y3, y2, y1, y0] (int32, each
    within +-2^30: a ptr32 load is zero-extended on a 64-bit port, ((x + 2^30) & (2^31 - 1)) - 2^30 restores its
    sign); the phase after the segment goes back in v[0]."""
    b = 1
    b <<= 30                           # 2^30 and 2^31 - 1 built at run time (a folded 1 << 30 is an object)
    msk = (b << 1) - 1
    ph = int(v[0])
    inc = int(v[1])
    s = int(v[2])
    half = int(v[3])
    div = int(v[4])
    fq = int(v[5])
    fr = int(v[6])
    m = int(v[7])
    x3 = ((v[8] + b) & msk) - b
    x2 = ((v[9] + b) & msk) - b
    x1 = ((v[10] + b) & msk) - b
    x0 = ((v[11] + b) & msk) - b
    y3 = ((v[12] + b) & msk) - b
    y2 = ((v[13] + b) & msk) - b
    y1 = ((v[14] + b) & msk) - b
    y0 = ((v[15] + b) & msk) - b
    j = k
    end = k + m
    if s:                                          # a loop per way to find f, as in Player._codes (one loop
        while j < end:                             # testing s per output: 2-4 % slower, measured)
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
            j += 1
    else:
        t = (ph << 10) + half                    # = f div + r, 0 <= r < div
        f = t // div
        r = t - f * div
        while j < end:
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
            j += 1
        ph += m * inc
    v[0] = ph
