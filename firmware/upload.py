"""Chunked transfers (HTABLE_* and DIST_* BEGIN/CHUNK/END): in order, CRC-32 checked, into RAM or a file.

BEGIN(total, crc32) opens a transfer (TOO_LARGE above ``max_bytes``); CHUNK(offset, length, data) must
continue at the next offset (a retransmitted chunk already stored is accepted again, anything else is
BAD_SEQUENCE); END(total) checks the length and the CRC-32 (IEEE) and hands the bytes (RAM) or the path of
the finished temporary file over. Errors are ``protocol.table.ERRORS`` codes; nothing is swapped in here.
"""

import os

from protocol import consts

# its own shim, not protocol.compat's: the controller's 32 KB board has no RAM for one more module
try:
    from binascii import crc32 as _crc32
except ImportError:  # pragma: no cover
    from protocol.core import crc32 as _crc32


class Upload:
    """One transfer at a time. ``path`` None keeps it in a bytearray; else it is written to ``path``.
    ``static``: the bytearray of ``max_bytes`` is allocated here, once, and every transfer reuses it (a board whose
    heap would soon be too fragmented for a block that large); ``end`` then hands over a memoryview of it, valid
    until the next BEGIN."""

    def __init__(self, max_bytes, path=None, static=False):
        self.max_bytes = max_bytes
        self.path = path
        self._static = bytearray(max_bytes) if static and path is None else None
        self._buf = None
        self._f = None
        self.active = False
        self.total = 0
        self.crc = 0
        self.got = 0
        self._crc = 0

    def _close(self):
        if self._f is not None:
            self._f.close()
            self._f = None
        self._buf = None
        self.active = False

    def begin(self, total, crc):
        self._close()
        if total < 1 or total > self.max_bytes:
            return consts.E_TOO_LARGE if total > self.max_bytes else consts.E_BAD_VALUE
        if self._static is not None:
            self._buf = memoryview(self._static)[:total]
        elif self.path is None:
            self._buf = bytearray(total)
        else:
            self._f = open(self.path, "wb")
        self.active = True
        self.total = total
        self.crc = crc
        self.got = 0
        self._crc = 0
        return 0

    def chunk(self, offset, length, data):
        if not self.active:
            return consts.E_BAD_SEQUENCE
        if offset + length <= self.got:
            return 0                                   # a retransmission of a stored chunk
        if offset != self.got or offset + length > self.total:
            return consts.E_BAD_SEQUENCE
        part = data[:length]
        if self._buf is not None:
            self._buf[offset:offset + length] = part
        else:
            self._f.write(part)
        self._crc = _crc32(part, self._crc)
        self.got += length
        return 0

    def end(self, total):
        """The bytes (RAM) or the file path, or an error code (int); the transfer is over either way."""
        if not self.active:
            return consts.E_BAD_SEQUENCE
        buf = self._buf
        ok_len = total == self.total and self.got == self.total
        ok_crc = (self._crc & 0xFFFFFFFF) == self.crc
        self._close()
        if not ok_len or not ok_crc:
            if self.path is not None:
                _remove(self.path)
            return consts.E_BAD_SEQUENCE if not ok_len else consts.E_BAD_CRC
        return buf if buf is not None else self.path


def _remove(path):
    try:
        os.remove(path)
    except OSError:
        pass
