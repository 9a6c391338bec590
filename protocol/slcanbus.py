"""python-can buses on a Lawicel (slcan) ASCII stream: the host's adapter driver and an emulated adapter.

- ``SlcanBus``: python-can's ``slcan`` interface (``can.interfaces.slcan.slcanBus``, subclassed, not forked),
  as a user's real adapter would be driven, with two changes:

  - it reads the port in blocks, as a USB adapter delivers them (python-can reads one byte per call: a 3.2 ms
    round trip on a pty against 75 us for the serial link), and splits the block into lines itself;
  - a malformed line from the adapter (bad length, non-hex, an unknown first character, overlong) is dropped
    and counted by reason (``counters()``, the reasons of ``protocol.lawicel.DROPS``) instead of raising
    ``CanOperationError`` / ``ValueError`` out of ``recv``. Only the port failing (the adapter or its process
    gone) raises, and that ends the link;
  - a channel the adapter keeps closed is opened again: Lawicel's ``O`` opens it, and an adapter answers every
    frame sent to a closed channel with BEL. When refusals come in a row (``REOPEN_AFTER`` BEL answers with no
    transmit acknowledgment between them: one damaged line is refused alone, and a frame acknowledged ends the
    run) the ``O`` goes again just before the next frame, and again at each doubling of the run (2, 4, 8 ...
    refusals): at most one more per doubling, so an adapter that refuses for another reason is not flooded.
    Counted: ``slcan_refused`` (BEL answers), ``slcan_reopened`` (``O`` sent again).

- ``LawicelBus``: be the adapter on a pty master (``protocol.lawicel.Adapter`` answers the host's commands),
  ``.peer_path`` for the process that opens ``slcan:PATH``; frames the host transmits are received here,
  frames sent here reach the host as ``T`` lines.

Both take ``inject_faults(faults, clock)`` (``protocol.faults``, ``SLCAN`` framing): bit flips in the ASCII
stream and whole frame lines dropped, both directions, on this side of the stream.
"""

import collections
import os
import threading
import time
import tty

import can
from can.interfaces.slcan import slcanBus

from protocol import faults as faultmod
from protocol import lawicel
from protocol.fdport import PeerGone, _FdPort

_ANSWERS = (b"", b"z", b"Z")      # OK, transmit acknowledged (std, ext): nothing to deliver


class _Lines:
    """CR- (or BEL-) terminated lines out of a byte stream, malformed ones counted; ``Message`` out."""

    def __init__(self):
        self._buf = bytearray()
        self._skip = False                   # inside an overlong line: drop up to its CR
        self.lines = collections.deque()
        self.drops = dict((r, 0) for r in lawicel.DROPS)
        self.n_refused = 0                   # BEL answers: the adapter refused a command or a frame
        self.refused_run = 0                 # BEL answers since the last transmit acknowledgment
        self.n_frames = 0

    def feed(self, data):
        buf = self._buf
        buf.extend(data)
        while buf:
            i = buf.find(b"\r")
            j = buf.find(b"\a")
            if i < 0 and j < 0:
                if len(buf) > lawicel.LINE_MAX:
                    self.drops["overlong"] += 1
                    self._skip = True
                    buf.clear()
                return
            k = i if j < 0 or 0 <= i < j else j
            end = buf[k]
            line = bytes(buf[:k])
            del buf[:k + 1]
            if self._skip:
                self._skip = False
                continue
            if k > lawicel.LINE_MAX:
                self.drops["overlong"] += 1
                continue
            if end == 7:
                self.n_refused += 1
                self.refused_run += 1
                if line:
                    self.lines.append(line)   # a line cut by a BEL: parsed (and most likely dropped)
                continue
            if line == b"Z" or line == b"z":
                self.refused_run = 0          # a frame acknowledged: the channel is open
            self.lines.append(line)

    def message(self):
        """The next frame as a ``can.Message``, or None when no complete frame line is waiting."""
        while self.lines:
            line = self.lines.popleft()
            line = line.lstrip(b"\n")
            if line in _ANSWERS or line[:1] in (b"V", b"N", b"F"):
                continue
            if line[:1] not in (b"T", b"t", b"R", b"r"):
                self.drops["unknown_command"] += 1
                continue
            f = lawicel.parse_frame(line, len(line))
            if isinstance(f, str):
                self.drops[f] += 1
                continue
            cid, ext, remote, data = f
            self.n_frames += 1
            return can.Message(arbitration_id=cid, is_extended_id=ext, is_remote_frame=remote,
                               dlc=len(data) if not remote else lawicel.hexval(line[9 if ext else 4]),
                               data=bytes(data), timestamp=time.time())
        return None

    def counters(self):
        d = dict(("slcan_" + r, v) for r, v in self.drops.items())
        d["slcan_refused"] = self.n_refused
        d["slcan_frames"] = self.n_frames
        return d


def _serial_fd(ser):
    """select + os.read/os.write on the fd of the pyserial port python-can opened (pyserial closes it)."""
    os.set_blocking(ser.fileno(), False)
    return _FdPort(ser.fileno(), owns=False, spin=False)


class _Stream:
    """What both buses share: the byte port under them (``_io``: an ``_FdPort``, or the ``FaultyPort`` around
    it once faults are injected) and the counters of the faults with their own (``_own_counters``)."""

    faults = None

    def inject_faults(self, faults, clock=None):
        """Faults on this side of the ASCII stream, both directions; returns the ``FaultyPort``."""
        self.faults = faultmod.FaultyPort(self._port(), faults, clock, framing=faultmod.SLCAN)
        self._io = self.faults
        return self.faults

    def counters(self):
        d = self._own_counters()
        if self.faults is not None:
            d.update(self.faults.counters())
        return d


class SlcanBus(_Stream, slcanBus):
    """python-can's slcan interface reading in blocks, dropping malformed lines and opening a channel the
    adapter keeps closed again (module docstring)."""

    REOPEN_AFTER = 2            # BEL answers in a row that send the open command again (then 4, 8, ...)

    def __init__(self, channel, **kw):
        kw.setdefault("sleep_after_open", 0)
        self._io = None
        self._lines = _Lines()
        self._reopen_at = self.REOPEN_AFTER   # the refusal run that sends the next ``O``
        self.n_reopened = 0
        self.peer_gone = False      # the adapter's end closed (or stalled: then ``fail_why`` says so)
        self.fail_why = None
        slcanBus.__init__(self, channel, **kw)

    def _port(self):
        if self._io is None:
            self._io = _serial_fd(self.serialPortOrig)
        return self._io

    def _write(self, string):
        try:
            self._port().write(string.encode() + self.LINE_TERMINATOR)
        except PeerGone as exc:
            self.peer_gone = True
            self.fail_why = str(exc) or None
            raise can.CanOperationError("the slcan adapter's port failed: %s" % (exc or "closed")) from None

    def _fill(self, wait):
        """What the port has within ``wait`` s, split into lines; CanOperationError once the adapter is gone."""
        try:
            data = self._port().read(wait)
        except PeerGone:
            self.peer_gone = True
            raise can.CanOperationError("the slcan adapter closed its port") from None
        if data:
            self._lines.feed(data)
        return bool(data)

    def _read(self, timeout):
        """One line (with its terminator, as python-can's ``_read``), or None after ``timeout``."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._lines.lines:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            if not self._fill(wait) and deadline is not None and time.monotonic() >= deadline:
                return None
        return self._lines.lines.popleft().decode("latin-1") + "\r"

    def _recv_internal(self, timeout):
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            msg = self._lines.message()
            if msg is not None:
                return msg, False
            wait = None if deadline is None else deadline - time.monotonic()
            if wait is not None and wait <= 0:
                return None, False
            self._fill(wait)

    def send(self, msg, timeout=None):
        """python-can's send, after the open command when the adapter's refusals say the channel is closed
        (the module docstring); called with the link's send lock held, as every write to the port is."""
        run = self._lines.refused_run
        if run < self.REOPEN_AFTER:
            self._reopen_at = self.REOPEN_AFTER
        elif run >= self._reopen_at:
            while self._reopen_at <= run:
                self._reopen_at *= 2
            self.n_reopened += 1
            self.open()
        slcanBus.send(self, msg, timeout)

    def _own_counters(self):
        d = self._lines.counters()
        d["slcan_reopened"] = self.n_reopened
        return d

    def shutdown(self):
        """Close the channel (``C``) if the adapter is still there, and the port in any case."""
        if self._is_shutdown:
            return
        can.BusABC.shutdown(self)
        try:
            self.close()
        except can.CanOperationError:     # the adapter already gone
            pass
        try:
            self.serialPortOrig.close()
        except Exception:                 # noqa: BLE001 - pyserial's errors on a vanished port: nothing to keep
            pass


class LawicelBus(_Stream, can.BusABC):
    """The device side of an slcan adapter on a pty master: Lawicel ASCII in and out (module docstring)."""

    def __init__(self, channel="slcan-pty", **kw):
        master, slave = os.openpty()
        tty.setraw(slave)
        self.peer_path = os.ttyname(slave)
        self._io = _FdPort(master, hold_fd=slave, spin=False)
        self._rx = collections.deque()
        self._tline = bytearray(lawicel.LINE_MAX)
        self.lw = lawicel.Adapter(self._write)
        self.peer_gone = False      # the host's end closed (or stalled: then ``fail_why`` says so)
        self.fail_why = None
        self._wlock = threading.Lock()   # answers from the receive thread, frames from any thread
        can.BusABC.__init__(self, channel, **kw)

    @property
    def is_open(self):
        return self.lw.is_open

    def _port(self):
        return self._io

    def _write(self, data):
        with self._wlock:
            try:
                self._io.write(bytes(data))
            except PeerGone as exc:
                self.peer_gone = True
                self.fail_why = str(exc) or None

    def _recv_internal(self, timeout):
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._rx:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                data = self._io.read(wait)
            except PeerGone:
                self.peer_gone = True
                raise can.CanOperationError("the slcan host closed the pty") from None
            if data:
                out = []
                self.lw.feed(data, len(data), out)
                for cid, ext, d in out:
                    self._rx.append(can.Message(arbitration_id=cid, is_extended_id=ext, data=bytes(d),
                                                timestamp=time.time()))
            if deadline is not None and time.monotonic() >= deadline:
                break
        if self._rx:
            return self._rx.popleft(), False
        return None, False

    def send(self, msg, timeout=None):
        if msg.is_remote_frame:
            line = ("R%08X%d\r" if msg.is_extended_id else "r%03X%d\r") % (msg.arbitration_id, msg.dlc)
            self._write(line.encode())
            return
        n = lawicel.frame_line(self._tline, msg.arbitration_id, msg.data, msg.is_extended_id)
        self._write(self._tline[:n])

    def _own_counters(self):
        return self.lw.counters()

    def shutdown(self):
        can.BusABC.shutdown(self)
        self._io.close()
