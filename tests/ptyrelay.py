"""A serial port stand-in for a board: two pseudo-terminals whose masters are relayed byte for byte by a separate
process (so the relay never waits on the test's GIL). One slave goes to the board's firmware, the other to
``fps hil --runtime board --port``.

``python -m tests.ptyrelay`` prints the two slave paths on one line and relays until stdin closes.
"""

import contextlib
import os
import select
import subprocess
import sys
import tty


def _relay():
    m1, s1 = os.openpty()
    m2, s2 = os.openpty()
    for fd in (s1, s2):
        tty.setraw(fd)
    for fd in (m1, m2):
        os.set_blocking(fd, False)
    print(os.ttyname(s1), os.ttyname(s2), flush=True)
    fds = [m1, m2, sys.stdin.fileno()]
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
                continue
            try:                      # a full receiver loses bytes, as a UART without flow control overruns
                os.write(m2 if fd == m1 else m1, data)
            except BlockingIOError:
                pass


@contextlib.contextmanager
def relay_pair():
    """(board_path, host_path): the two ends of the relayed pty pair, for as long as the context lasts."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen([sys.executable, "-m", "tests.ptyrelay"], cwd=root, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE)
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


if __name__ == "__main__":
    _relay()
