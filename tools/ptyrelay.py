"""A serial port stand-in for a board: two pseudo-terminals whose masters are relayed byte for byte by a separate
process (so the relay never waits on the test's GIL). One slave goes to the board's firmware, the other to
``fps hil --runtime board --port``.

``python -m tools.ptyrelay`` prints the two slave paths on one line and relays until stdin closes.
``python -m tools.ptyrelay --slcan-damage PATH N`` relays between the tty PATH and a new pty (its slave path
printed) and damages one CR-terminated line in N at random (seed 0), each way, with one of: a data character
made 0xC5, a non-hex 'G', 40 characters with no CR, the line dropped (an external fault on an slcan stream,
not the project's own).
"""

import contextlib
import os
import select
import subprocess
import sys
import tty


def _pump(a, b, through=None, stop_on_error=False):
    """Relay the fds ``a`` and ``b`` both ways until stdin closes: ``through(fd, data)`` gives what goes on of
    what ``fd`` sent (all of it by default); a read error is skipped, or ends the relay (``stop_on_error``)."""
    fds = [a, b, sys.stdin.fileno()]
    while True:
        r, _, _ = select.select(fds, [], [])
        for fd in r:
            if fd == fds[2]:
                if not os.read(fd, 100):
                    return
                continue
            try:
                data = os.read(fd, 65536)
            except OSError:
                if stop_on_error:
                    return               # one end closed: the relay (the harness) is gone
                continue
            try:                      # a full receiver loses bytes, as a UART without flow control overruns
                os.write(b if fd == a else a, data if through is None else through(fd, data))
            except BlockingIOError:
                pass


def _relay():
    m1, s1 = os.openpty()
    m2, s2 = os.openpty()
    for fd in (s1, s2):
        tty.setraw(fd)
    for fd in (m1, m2):
        os.set_blocking(fd, False)
    print(os.ttyname(s1), os.ttyname(s2), flush=True)
    _pump(m1, m2)


@contextlib.contextmanager
def relay_pair():
    """(board_path, host_path): the two ends of the relayed pty pair, for as long as the context lasts (the relay
    dies with this process)."""
    from emulator.runtime import child_options
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen([sys.executable, "-m", "tools.ptyrelay"], cwd=root, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, **child_options())
    try:
        board, host = proc.stdout.readline().decode().split()
        yield board, host
    finally:
        proc.stdin.close()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def _damage(line, k):
    """The k-th kind of damage to one Lawicel line (CR included)."""
    kind = k % 4
    if kind == 0 and len(line) > 12:
        return line[:11] + b"\xc5" + line[12:]
    if kind == 1 and len(line) > 12:
        return line[:11] + b"G" + line[12:]
    if kind == 2:
        return b"7" * 40 + line
    return b""


def _slcan_damage(path, every):
    import random
    rng = random.Random(0)
    fa = os.open(path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fa)
    m, s = os.openpty()
    tty.setraw(s)
    os.set_blocking(m, False)
    print(os.ttyname(s), flush=True)
    bufs = {fa: b"", m: b""}

    def damage(fd, data):
        bufs[fd] += data
        out = []
        while b"\r" in bufs[fd]:
            i = bufs[fd].index(b"\r")
            line, bufs[fd] = bufs[fd][:i + 1], bufs[fd][i + 1:]
            out.append(_damage(line, rng.randrange(4)) if rng.randrange(every) == 0 else line)
        return b"".join(out)

    _pump(fa, m, damage, stop_on_error=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--slcan-damage":
        _slcan_damage(sys.argv[2], int(sys.argv[3]))
    else:
        _relay()
