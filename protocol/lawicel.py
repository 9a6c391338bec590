"""Lawicel (slcan) ASCII: the adapter's side, once, for the firmware HAL and the host's test adapter.

Pure Python for CPython and MicroPython. An slcan adapter (CANable, USBtin, CANUSB) sits between a host's
serial port and the CAN bus; the host speaks ASCII lines ending in CR, the adapter answers CR (OK) or BEL
(error). ``Adapter`` is that adapter's command interpreter: ``firmware.hal.slcan.SlcanAdapter`` runs it on a
pty master or a UART, ``protocol.slcanbus.LawicelBus`` on a pty master for a host-side test; python-can's
``slcan`` interface (``protocol.slcanbus.SlcanBus``) is the host, as a user's real adapter would have.

Commands supported (what a CANable's slcan firmware answers):

===========  =====================================================  ==================================
command      meaning                                                answer
===========  =====================================================  ==================================
``O``        open the channel (normal)                              CR
``L``        open the channel listen-only (frames still delivered)  CR
``C``        close the channel                                      CR
``S0``-``S8``  bit rate 10 k - 1 M (only while closed)               CR; BEL while open or out of range
``s``        BTR registers (accepted, not applied)                  CR
``V``        version                                                ``V1013`` CR
``N``        serial number                                          ``NFPS0`` CR
``F``        status flags (none: no bus errors on an emulated bus)  ``F00`` CR
``Z0/Z1``    timestamps off/on (accepted, never sent)               CR
``tiiildd``  transmit an 11-bit frame (``T``: 29-bit, 8 id digits)  ``z`` CR (``Z`` CR); BEL if closed
``riiil``    transmit a remote frame (``R``: 29-bit)                ``z`` CR (``Z`` CR), not delivered
(empty)      nothing                                                CR
===========  =====================================================  ==================================

A frame line is exact: the id's hex digits (3 or 8; a 29-bit id at most ``1FFFFFFF``), one DLC digit 0-8,
then 2 x DLC hex digits (none for a remote frame) and nothing after them. Hex digits of either case are read;
frames received from the bus go to the host as upper-case ``T``/``t`` lines (``frame_line``).

Malformed input is dropped and counted by reason (``DROPS``), never fatal: ``overlong`` (no CR within
``LINE_MAX`` characters: dropped up to the next CR, answered once with BEL), ``bad_length`` (a frame line's
length disagrees with its DLC, or the DLC is not 0-8), ``non_hex`` (a character that is not a hex digit where
one must be, or an id beyond 29/11 bits), ``unknown_command`` (a first character not in the table, answered
BEL), ``closed`` (a frame while the channel is closed, answered BEL). A LF is ignored (CR LF line ends).
"""

LINE_MAX = 27                  # 'T', 8 id digits, the DLC, 16 data digits: 26; one spare
DROPS = ("overlong", "bad_length", "non_hex", "unknown_command", "closed")
OK = b"\r"
ERR = b"\a"
_HEX = b"0123456789ABCDEF"
_ACK_EXT = b"Z\r"
_ACK_STD = b"z\r"


def hexval(c):
    """The value of one hex digit's byte (either case), -1 if it is not one."""
    if 48 <= c <= 57:
        return c - 48
    c |= 0x20
    if 97 <= c <= 102:
        return c - 87
    return -1


def hexnum(b, i, n):
    """int of the n hex digits at b[i:], -1 if any is not hex."""
    v = 0
    for k in range(i, i + n):
        d = hexval(b[k])
        if d < 0:
            return -1
        v = (v << 4) | d
    return v


def parse_frame(b, n):
    """A frame line ``b[:n]`` (``t``/``T``/``r``/``R``, without its CR): ``(cid, ext, remote, data)``, or the
    drop reason (a str of ``DROPS``). ``data`` is a bytearray (empty for a remote frame)."""
    c = b[0]
    ext = c == 84 or c == 82            # T, R
    remote = c == 114 or c == 82        # r, R
    w = 8 if ext else 3
    if n < w + 2:
        return "bad_length"
    dlc = hexval(b[1 + w])
    if dlc < 0 or dlc > 8:
        return "bad_length"
    if n != 2 + w + (0 if remote else 2 * dlc):
        return "bad_length"
    cid = hexnum(b, 1, w)
    if cid < 0 or cid > (0x1FFFFFFF if ext else 0x7FF):
        return "non_hex"
    data = bytearray(0 if remote else dlc)
    if not remote:
        i = 2 + w
        for k in range(dlc):
            hi = hexval(b[i])
            lo = hexval(b[i + 1])
            if hi < 0 or lo < 0:
                return "non_hex"
            data[k] = (hi << 4) | lo
            i += 2
    return (cid, ext, remote, data)


def frame_line(out, cid, data, ext=True):
    """Write the ``T`` (``ext``) or ``t`` line of a data frame, CR included, into the bytearray ``out`` (at
    least ``LINE_MAX`` long); returns its length."""
    w = 8 if ext else 3
    out[0] = 84 if ext else 116
    for k in range(w):
        out[1 + k] = _HEX[(cid >> (4 * (w - 1 - k))) & 0xF]
    n = len(data)
    out[1 + w] = 48 + n
    i = 2 + w
    for k in range(n):
        v = data[k]
        out[i] = _HEX[v >> 4]
        out[i + 1] = _HEX[v & 0xF]
        i += 2
    out[i] = 13
    return i + 1


class Adapter:
    """The adapter's command interpreter (see the module docstring).

    ``feed(buf, n, out)`` takes ``n`` bytes the host sent, answers each completed line through ``write``
    (a callable taking bytes), and appends the frames the host asked to transmit to ``out`` as
    ``(cid, ext, data)``. Counters: ``n_rx`` frames taken, ``n_remote`` remote frames (acknowledged, not
    delivered: the packet layer uses none), ``drops[reason]``.
    """

    def __init__(self, write):
        self.write = write
        self.is_open = False
        self.listen_only = False
        self.bitrate = None
        self.timestamps = False
        self._line = bytearray(LINE_MAX)
        self._n = 0                      # characters of the line so far; -1 inside an overlong line
        self.n_rx = 0
        self.n_remote = 0
        self.drops = {}
        for r in DROPS:
            self.drops[r] = 0

    def feed(self, buf, n, out):
        line = self._line
        for k in range(n):
            c = buf[k]
            if c == 13:
                if self._n < 0:          # the end of an overlong line, already answered
                    self._n = 0
                elif self._n:
                    self._command(self._n, out)
                    self._n = 0
                else:
                    self.write(OK)       # an empty command (python-can flushes with one)
            elif c == 10 or self._n < 0:
                pass                     # LF of a CR LF; the rest of an overlong line
            elif self._n < LINE_MAX:
                line[self._n] = c
                self._n += 1
            else:
                self._n = -1
                self.drops["overlong"] += 1
                self.write(ERR)

    def _drop(self, reason):
        self.drops[reason] += 1
        self.write(ERR)

    def _command(self, n, out):
        b = self._line
        c = b[0]
        if c == 84 or c == 116 or c == 82 or c == 114:          # T t R r
            f = parse_frame(b, n)
            if isinstance(f, str):
                self._drop(f)
                return
            if not self.is_open:
                self._drop("closed")
                return
            cid, ext, remote, data = f
            if remote:
                self.n_remote += 1
            else:
                self.n_rx += 1
                out.append((cid, ext, data))
            self.write(_ACK_EXT if ext else _ACK_STD)
        elif (c == 79 or c == 76) and n == 1:                   # O, L
            self.is_open = True
            self.listen_only = c == 76
            self.write(OK)
        elif c == 67 and n == 1:                                # C
            self.is_open = False
            self.write(OK)
        elif c == 83:                                           # S0..S8
            d = hexval(b[1]) if n == 2 else -1
            if 0 <= d <= 8 and not self.is_open:
                self.bitrate = d
                self.write(OK)
            else:
                self.write(ERR)
        elif c == 115:                                          # s: BTR registers
            self.write(OK)
        elif c == 86 and n == 1:                                # V
            self.write(b"V1013\r")
        elif c == 78 and n == 1:                                # N
            self.write(b"NFPS0\r")
        elif c == 70 and n == 1:                                # F
            self.write(b"F00\r")
        elif c == 90 and n == 2 and b[1] in (48, 49):           # Z0 / Z1
            self.timestamps = b[1] == 49
            self.write(OK)
        else:
            self._drop("unknown_command")

    def counters(self):
        d = {"slcan_rx": self.n_rx, "slcan_remote": self.n_remote}
        for r in DROPS:
            d["slcan_" + r] = self.drops[r]
        return d
