"""Minimal ISO-TP (ISO 15765-2) for classic CAN: segmentation, reassembly, flow control.

Pure Python for CPython and MicroPython; proven against the PyPI ``can-isotp`` package in
``tests/test_protocol_isotp.py``. Normal addressing (the CAN ids are the caller's business), 8-byte
frames, 12-bit lengths (up to 4095 bytes), no padding sent (padding received is ignored).

Protocol control information (first byte, high nibble):
  0 single frame  (SF)  low nibble = length 1..7, data follows
  1 first frame   (FF)  12-bit length, first 6 data bytes
  2 consecutive   (CF)  low nibble = sequence number 1, 2, ... 15, 0, 1 ..., up to 7 data bytes
  3 flow control  (FC)  low nibble 0 = continue, 1 = wait, 2 = overflow; then block size, STmin
"""

try:
    from time import sleep_us
except ImportError:
    try:  # CPython
        from time import sleep

        def sleep_us(us):
            sleep(us * 1e-6)
    except ImportError:  # a port without a time module (the PIL image): it frames, it never paces a send

        def sleep_us(us):
            raise OSError("this port has no time module: ISO-TP cannot pace its consecutive frames")

MAX_LEN = 4095
ERRORS = ("bad_pci", "bad_length", "unexpected_cf", "bad_seq", "overflow")


def segment(payload):
    """The data fields of the SF, or FF + CFs, carrying ``payload`` (no flow control)."""
    n = len(payload)
    if n > MAX_LEN:
        raise ValueError("ISO-TP payload of %d bytes > %d" % (n, MAX_LEN))
    if n <= 7:
        return [bytes((n,)) + payload]
    frames = [bytes((0x10 | (n >> 8), n & 0xFF)) + payload[:6]]
    sn = 1
    for i in range(6, n, 7):
        frames.append(bytes((0x20 | sn,)) + payload[i:i + 7])
        sn = (sn + 1) & 0x0F
    return frames


def _stmin_us(b):
    """STmin byte to microseconds (0x00-0x7F ms, 0xF1-0xF9 100-900 us, reserved values as 127 ms)."""
    if b <= 0x7F:
        return b * 1000
    if 0xF1 <= b <= 0xF9:
        return (b - 0xF0) * 100
    return 127000


class IsoTp:
    """One ISO-TP channel (one rx id, one tx id).

    ``tx(data)`` sends one CAN data field on the tx id; ``tx=None`` listens only (no flow control sent,
    for reading logs). Feed every frame received on the rx id to ``feed``; it returns a completed
    payload or None. ``send(payload)`` starts a transfer: a single frame goes at once, a longer one
    sends its FF and the CFs follow as flow control frames arrive through ``feed`` (``sending`` is True
    until the last CF). Errors abort the reception and are counted in ``errors[reason]``.
    """

    def __init__(self, tx=None, block_size=0, stmin=0):
        self.tx = tx
        self.block_size = block_size
        self.stmin = stmin
        self.errors = {}
        for r in ERRORS:
            self.errors[r] = 0
        self._rx = None        # bytearray being reassembled
        self._rx_len = 0
        self._rx_sn = 0
        self._rx_block = 0
        self._tx_frames = None  # remaining CF data fields
        self._tx_i = 0

    @property
    def sending(self):
        return self._tx_frames is not None

    def abort(self):
        """Give up the transfer being sent (its receiver's flow control did not come)."""
        self._tx_frames = None

    def _error(self, reason):
        self.errors[reason] += 1
        self._rx = None
        return None

    def send(self, payload):
        frames = segment(payload)
        self.tx(frames[0])
        if len(frames) > 1:
            self._tx_frames = frames
            self._tx_i = 1

    def _flow_control(self):
        if self.tx is not None:
            self.tx(bytes((0x30, self.block_size, self.stmin)))

    def feed(self, data):
        n = len(data)
        if n == 0:
            return self._error("bad_pci")
        kind = data[0] >> 4
        if kind == 0:
            ln = data[0] & 0x0F
            if ln == 0 or ln > n - 1:
                return self._error("bad_length")
            if self._rx is not None:
                self._error("unexpected_cf")  # a new transfer interrupts the old one
            return bytes(data[1:1 + ln])
        if kind == 1:
            if n < 8:
                return self._error("bad_length")
            ln = ((data[0] & 0x0F) << 8) | data[1]
            if ln < 8:
                return self._error("bad_length")
            if self._rx is not None:
                self.errors["unexpected_cf"] += 1     # a new transfer interrupts the old one (as for a SF)
            self._rx = bytearray(data[2:8])
            self._rx_len = ln
            self._rx_sn = 1
            self._rx_block = 0
            self._flow_control()
            return None
        if kind == 2:
            if self._rx is None:
                return self._error("unexpected_cf")
            if data[0] & 0x0F != self._rx_sn:
                return self._error("bad_seq")
            take = self._rx_len - len(self._rx)
            if take > 7:
                take = 7
            if n - 1 < take:
                return self._error("bad_length")
            self._rx.extend(data[1:1 + take])
            self._rx_sn = (self._rx_sn + 1) & 0x0F
            if len(self._rx) >= self._rx_len:
                out = bytes(self._rx)
                self._rx = None
                return out
            self._rx_block += 1
            if self.block_size and self._rx_block == self.block_size:
                self._rx_block = 0
                self._flow_control()
            return None
        if kind == 3:
            self._on_fc(data)
            return None
        return self._error("bad_pci")

    def _on_fc(self, data):
        if self._tx_frames is None or len(data) < 3:
            return
        status = data[0] & 0x0F
        if status == 1:
            return  # wait
        if status != 0:
            self.errors["overflow"] += 1
            self._tx_frames = None
            return
        bs = data[1]
        st_us = _stmin_us(data[2])
        frames = self._tx_frames
        sent = 0
        while self._tx_i < len(frames) and (bs == 0 or sent < bs):
            if sent and st_us:
                sleep_us(st_us)
            self.tx(frames[self._tx_i])
            self._tx_i += 1
            sent += 1
        if self._tx_i >= len(frames):
            self._tx_frames = None
