"""AD660 16-bit DAC driving the P-FSM (Optics in Motion OIM5001): error angle to offset-binary code.

Eq. 7.7-7.8: theta_P-FSM = 13.33 theta_e, and +-3 deg of P-FSM maps to +-10 V, so
V = 0.012343 V/arcsec x theta_e (arcsec). The AD660's bipolar output is offset binary over +-10 V:
code = 0x8000 + V x 65536 / 20 V, clipped to 0..65535 (the packet table's PFSM_DAC carries the raw codes,
scale 1; its text gives the volts, V = (code - 32768) x 20 / 65536).
"""

V_PER_ARCSEC = 0.012343          # Eq. 7.8
CODES_PER_VOLT = 3276.8          # 65536 codes / 20 V
ZERO_CODE = 0x8000
CODE_MAX = 0xFFFF


def arcsec_to_code_q2(theta_arcsec):
    """The AD660 code for an error angle in Q2 (code x 4, rounded), clipped to 0 .. 4 x 65535."""
    c = (ZERO_CODE + theta_arcsec * (V_PER_ARCSEC * CODES_PER_VOLT)) * 4.0
    if c <= 0.0:
        return 0
    if c >= CODE_MAX * 4:
        return CODE_MAX * 4
    return int(c + 0.5)


def arcsec_to_code(theta_arcsec):
    """The AD660 code for an error angle (rounded, clipped)."""
    return (arcsec_to_code_q2(theta_arcsec) + 2) >> 2


def code_to_arcsec(code):
    """The error angle a code stands for (inverse of Eq. 7.8)."""
    return (code - ZERO_CODE) / (V_PER_ARCSEC * CODES_PER_VOLT)


# --- integer conversion of distfile samples (the player's per-update path: no floats, no allocation) -------
K4_C = 5692204052544925          # 4 x V_PER_ARCSEC x CODES_PER_VOLT as the double it is, times 2^45 (exact)
K4_Q = 45
Q2_MAX = CODE_MAX * 4
_L = 14                           # limb bits: a limb product is < 2^28, three of them and a carry < 2^30
_LM = (1 << _L) - 1
_NL = 8                           # product limbs (the product is below 2^98)


class Q2Converter:
    """Distfile sample bytes -> the AD660 code in Q2, in integer arithmetic, allocation-free per call.

    Gives exactly ``arcsec_to_code_q2`` of the sample's value computed without rounding: Q2 = 131072 + K4 x
    (Eq. 7.7-7.8; K4 = 4 x 0.012343 x 3276.8 as the double ``arcsec_to_code_q2`` uses, held exactly as
    ``K4_C`` / 2^45), rounded half up and clipped to 0 .. 262140. The double arithmetic of
    ``arcsec_to_code_q2`` rounds twice (relative error < 2^-52), so the two differ only if 131072 + K4 x lies
    within ~2^-35 of a half code/4; tests/test_firmware_player.py checks ~60,000 samples, near-ties included.

    kind 1 (float32 arcsec): x = mantissa x 2^(exponent - 150) from the IEEE-754 bits; |x| >= 1024 clips.
    kind 0 (int32 in units of ``scale`` arcsec): x = n x scale; K4 x scale is rounded to 56 bits at load
    (relative error 2^-56).
    The magnitude m (< 2^32) and the constant c (< 2^56) are held in 14-bit limbs; c m is accumulated in
    ``_NL`` limbs, the rounding half is added and the code read off at bit s (value = c m / 2^s).
    """

    def __init__(self, kind=1, scale=1.0):
        self.kind = kind
        c = K4_C
        q = K4_Q
        if kind == 0:
            import struct
            bits = struct.unpack("<I", struct.pack("<f", scale))[0]
            ex = (bits >> 23) & 0xFF
            c = c * ((bits & 0x7FFFFF) | (0x800000 if ex else 0))
            q += 150 - (ex if ex else 1)
            k = 0
            t = c
            while t >> 56:
                t >>= 1
                k += 1
            if k:
                c = (c + (1 << (k - 1))) >> k
                q -= k
                if c >> 56:
                    c >>= 1
                    q -= 1
        self.q = q
        self._c = (c & _LM, (c >> _L) & _LM, (c >> (2 * _L)) & _LM, c >> (3 * _L))   # c's limbs
        self._p = [0] * (_NL + 1)

    def code(self, b, off):
        """Q2 code of the 4-byte little-endian sample at ``b[off]`` (float32 or int32 by ``kind``)."""
        b0 = b[off]
        b1 = b[off + 1]
        b2 = b[off + 2]
        b3 = b[off + 3]
        neg = b3 >> 7
        if self.kind == 1:
            ex = ((b3 & 0x7F) << 1) | (b2 >> 7)
            mant = ((b2 & 0x7F) << 16) | (b1 << 8) | b0
            if ex:
                mant |= 0x800000
            else:
                ex = 1
            if ex >= 137:                       # |x| >= 1024 arcsec: far beyond +-10 V
                return 0 if neg else Q2_MAX
            m0 = mant & _LM
            m1 = mant >> _L
            m2 = 0
            s = self.q + 150 - ex
        else:
            m0 = b0 | ((b1 & 0x3F) << 8)        # bits 0..13, 14..27, 28..31 of the int32
            m1 = (b1 >> 6) | (b2 << 2) | ((b3 & 0x0F) << 10)
            m2 = b3 >> 4
            if neg:                              # magnitude 2^32 - u, limb by limb
                br = 1 if m0 else 0
                m0 = -m0 & _LM
                t = -m1 - br
                m1 = t & _LM
                m2 = 16 - m2 - (1 if t < 0 else 0)
            s = self.q
        if not (m0 or m1 or m2):
            return ZERO_CODE << 2
        if s < 1:
            return 0 if neg else Q2_MAX
        if s > _L * (_NL - 1):                  # c m < 2^98 <= half an LSB
            return ZERO_CODE << 2
        c0, c1, c2, c3 = self._c
        p = self._p
        t = c0 * m0 - neg                        # c m - 1 when negative: ceil(v - 1/2) = floor((c m - 1) / 2^s + 1/2)
        p[0] = t & _LM
        t = c1 * m0 + c0 * m1 + (t >> _L)
        p[1] = t & _LM
        t = c2 * m0 + c1 * m1 + c0 * m2 + (t >> _L)
        p[2] = t & _LM
        t = c3 * m0 + c2 * m1 + c1 * m2 + (t >> _L)
        p[3] = t & _LM
        t = c3 * m1 + c2 * m2 + (t >> _L)
        p[4] = t & _LM
        t = c3 * m2 + (t >> _L)
        p[5] = t & _LM
        p[6] = t >> _L
        p[7] = 0
        p[8] = 0
        k = (s - 1) // _L                        # add 2^(s - 1), carry up
        p[k] += 1 << ((s - 1) - k * _L)
        while p[k] > _LM:
            p[k] -= 1 << _L
            k += 1
            p[k] += 1
        k = s // _L                              # v = floor(sum / 2^s), saturating above 2^18
        r = s - k * _L
        v = p[k] >> r
        if k + 1 < _NL:
            v += p[k + 1] << (_L - r)
            if k + 2 < _NL:
                t = p[k + 2]
                if t and (r < 10 or t >> (r - 10)):
                    return 0 if neg else Q2_MAX
                v += t << (2 * _L - r)
                for j in range(k + 3, _NL):
                    if p[j]:
                        return 0 if neg else Q2_MAX
        v = (ZERO_CODE << 2) - v if neg else (ZERO_CODE << 2) + v
        if v <= 0:
            return 0
        if v >= Q2_MAX:
            return Q2_MAX
        return v
