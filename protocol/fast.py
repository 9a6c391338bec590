"""Viper fast paths of the framing core, MicroPython only (``protocol.frame`` selects them there).

Same arithmetic as the pure functions in ``protocol.frame`` (the reference, used on CPython): CRC-16/CCITT-FALSE
table driven, COBS. They work on caller buffers given as start/length so the per-tick path copies and
allocates nothing; callers check lengths first (viper pointers are unchecked). A .mpy of this module needs
``mpy-cross -march=<port arch>`` (``tools.mpy_build`` passes it).
"""

import micropython

from protocol.consts import CRC16_TABLE

_T16 = bytearray(CRC16_TABLE)   # in RAM, so that its u16 reads are aligned (a Cortex-M0 faults on unaligned ones)


@micropython.viper
def crc16(buf: ptr8, n: int, crc: int) -> int:
    """CRC-16/CCITT-FALSE of buf[0:n], continuing from ``crc``."""
    t = ptr16(_T16)
    i = 0
    while i < n:
        crc = ((crc << 8) & 0xFFFF) ^ int(t[((crc >> 8) ^ int(buf[i])) & 0xFF])
        i += 1
    return crc


@micropython.viper
def cobs_encode(src: ptr8, n: int, dst: ptr8) -> int:
    """COBS of src[0:n] into dst (room for n + n // 254 + 1); returns the encoded length."""
    code_i = 0
    o = 1
    code = 1
    i = 0
    while i < n:
        b = int(src[i])
        i += 1
        if b:
            dst[o] = b
            o += 1
            code += 1
            if code == 0xFF and i < n:
                dst[code_i] = code
                code_i = o
                o += 1
                code = 1
        else:
            dst[code_i] = code
            code_i = o
            o += 1
            code = 1
    dst[code_i] = code
    return o


@micropython.viper
def cobs_decode(src: ptr8, i: int, n: int, dst: ptr8) -> int:
    """Decode COBS src[i:n] into dst (room for n - i); the decoded length, or -1 if the encoding is invalid."""
    o = 0
    while i < n:
        code = int(src[i])
        end = i + code
        if code == 0 or end > n:
            return -1
        i += 1
        while i < end:
            b = int(src[i])
            if b == 0:
                return -1
            dst[o] = b
            o += 1
            i += 1
        if code != 0xFF and i < n:
            dst[o] = 0
            o += 1
    return o


@micropython.viper
def find0(buf: ptr8, i: int, n: int) -> int:
    """Index of the first 0x00 in buf[i:n], or -1."""
    while i < n:
        if int(buf[i]) == 0:
            return i
        i += 1
    return -1


@micropython.viper
def frame(body: ptr8, nbody: int, payload, out: ptr8) -> int:
    """A whole serial frame from body[0:nbody] (the header; room for the payload and CRC after it):
    copies ``payload`` after the header, appends the CRC-16 big-endian, COBS-encodes into ``out`` and
    appends 0x00. Returns the frame length."""
    p = ptr8(payload)
    np = int(len(payload))
    t = ptr16(_T16)
    crc = 0xFFFF
    i = 0
    while i < nbody:
        crc = ((crc << 8) & 0xFFFF) ^ int(t[((crc >> 8) ^ int(body[i])) & 0xFF])
        i += 1
    j = 0
    while j < np:
        b = int(p[j])
        body[i] = b
        crc = ((crc << 8) & 0xFFFF) ^ int(t[((crc >> 8) ^ b) & 0xFF])
        i += 1
        j += 1
    body[i] = crc >> 8
    body[i + 1] = crc & 0xFF
    n = int(cobs_encode(body, i + 2, out))
    out[n] = 0
    return n + 1


@micropython.viper
def unframe(src: ptr8, i: int, n: int, dst: ptr8) -> int:
    """COBS-decode src[i:n] into dst and check the CRC-16 residue (zero over body + CRC big-endian).
    Returns -1 for invalid COBS, else the decoded length, plus 0x10000 if the CRC does not match."""
    k = int(cobs_decode(src, i, n, dst))
    if k < 0:
        return -1
    t = ptr16(_T16)
    crc = 0xFFFF
    j = 0
    while j < k:
        crc = ((crc << 8) & 0xFFFF) ^ int(t[((crc >> 8) ^ int(dst[j])) & 0xFF])
        j += 1
    if crc:
        return k | 0x10000
    return k
