"""A byte stream on a file descriptor (a pty master, a posix serial port), under every link that has one
(``protocol.link``'s serial and pty links, ``protocol.slcanbus``'s buses): select and os.read, writes that wait
while the peer reads, and ``PeerGone`` when the other end closes."""

import errno
import os
import select
import time

class PeerGone(Exception):
    """The other end of a byte stream closed."""


SPIN_S = 300e-6   # longest busy-poll before a blocking read on a pty or serial port
STALL_S = 5.0     # a pty peer that reads nothing for this long while our writes wait is gone (hung)


class _FdPort:
    """A file descriptor (pty master, posix serial port): select + os.read; writes wait while the peer reads,
    and a pty master we own is non-blocking so that a peer which stops reading (alive but hung, its pty buffer
    full) ends the link after ``STALL_S`` instead of blocking the writer for ever."""

    def __init__(self, fd, hold_fd=None, owns=True, spin=True):
        self.fd = fd
        self._hold = hold_fd   # our copy of a pty slave, closed once the peer has spoken
        self._owns = owns
        self._spin = spin      # busy-poll before blocking (a reader thread sharing the GIL should not)
        if owns:
            os.set_blocking(fd, False)

    def read(self, timeout):
        r = None
        if timeout and self._spin:
            # Busy-poll up to SPIN_S first: a lockstep peer answers within ~100 us, and a blocked wake-up
            # across cores costs tens of us on a VM (10x -> 15x real time for the MicroPython HIL).
            end = time.perf_counter() + min(SPIN_S, timeout)
            while not r and time.perf_counter() < end:
                r, _, _ = select.select((self.fd,), (), (), 0)
        if not r:
            r, _, _ = select.select((self.fd,), (), (), timeout)
        if not r:
            return b""
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise PeerGone() from None
            raise
        if not data:
            raise PeerGone()
        if self._hold is not None:
            os.close(self._hold)
            self._hold = None
        return data

    def write(self, data):
        mv = memoryview(data)
        end = None
        try:
            while mv:
                try:
                    n = os.write(self.fd, mv)
                except BlockingIOError:
                    n = 0
                if n:
                    mv = mv[n:]
                    end = None
                    continue
                now = time.monotonic()
                if end is None:
                    end = now + STALL_S
                elif now >= end:
                    raise PeerGone("the peer read nothing for %g s" % STALL_S)
                select.select((), (self.fd,), (), end - now)
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise PeerGone() from None
            raise

    def close(self):
        if self._hold is not None:
            os.close(self._hold)
            self._hold = None
        if self._owns:
            os.close(self.fd)
