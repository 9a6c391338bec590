"""Where the controller firmware runs for a ground tool: in this process, or a subprocess over a link.

``open_rig(runtime, link, ...)`` is a context manager yielding a ``ground.rig.Rig``:

- ``inproc`` / ``inproc``: ``firmware.controller.Controller`` called directly;
- ``cpython`` or ``micropython`` with ``serial``: ``python -m firmware.main controller --link serial:PTY``
  (MicroPython: ``micropython -m firmware.main ...``) on the slave of a pseudo-terminal pair whose master
  this process holds (``protocol.link.open_link("pty")``);
- ``cpython can``: the same over CAN, the controller opening ``slcan:PTY`` and this process being the
  slcan device (``open_link("slcan-pty")``); ``--link-faults`` then act on the Lawicel ASCII stream at this
  end of the pty (``protocol.faults.SLCAN``). MicroPython firmware speaks serial only.

- ``qemu`` with ``serial``: the controller frozen into the PIL image (``make pil``, tools/pil_build.py: MicroPython's
  qemu port on a Cortex-M0, QEMU's microbit machine) under ``qemu-system-arm`` with its UART on a pty;
  ``firmware.pil_main`` is started through the raw REPL, then the pty is the board's serial port.

The subprocess is stopped (closed link, then terminate, then kill) when the context ends.
"""

import contextlib
import os
import shutil
import subprocess
import sys
import time

from emulator.bench import RATE_HZ_MAX
from emulator.runtime import check_seed  # noqa: F401  (ground's tools take it from here)
from ground.rig import InprocController, Rig

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUNTIMES = ("inproc", "cpython", "micropython", "board", "qemu")
BAUD_DEFAULT = 115200                 # --runtime board's serial port
BAUD_RANGE = (50, 4000000)
LINKS = ("inproc", "serial", "can")
TICK_TIMEOUT_MS = 3.0      # resend a TICK after this long without its answer (a MicroPython pty round trip: ~0.1 ms)
CAN_TICK_TIMEOUT_MS = 5.0   # the same on CAN: a clean round trip is ~1 ms there (two ISO-TP transfers, flow control each)
CAN_ISOTP_TIMEOUT_MS = 3.0   # N_Bs on the lockstep CAN link (both ends): flow control comes in ~0.3 ms on a pty
QEMU_TICK_TIMEOUT_MS = 1000.0  # the same for the PIL board: a round trip through QEMU's UART is ~1-3 ms; a resend
# there only follows the host's stalls (the pty loses nothing), and it changes what the board counts (its n_dup)
TICK_TRIES = 30            # sends of one TICK (waits doubling up to 0.1 s: 2.6 s) before it is an overrun
MAX_FAILED_TICKS = 2000    # consecutive overruns (a dead link) that end a run: 3.1 s at 637.8 Hz


def link_options(a):
    """``runtime.open_rig`` keywords from the parsed link flags shared by ``fps hil`` and ``fps calibrate``."""
    from protocol.faults import LinkFaults
    return {"port": a.port, "baud": a.baud, "realtime": a.realtime, "rate_hz": a.rate_hz,
            "link_faults": LinkFaults.parse(a.link_faults) if a.link_faults else None,
            "tick_timeout_ms": a.tick_timeout_ms, "tick_tries": a.tick_tries,
            "max_failed_ticks": a.max_failed_ticks}


def default_link(a):
    """``--link`` left out: inproc for the inproc runtime, serial for every other."""
    if a.link is None:
        a.link = "inproc" if a.runtime == "inproc" else "serial"


def add_link_arguments(p):
    """The runtime/link/fault flags of ``fps hil`` and ``fps calibrate``."""
    p.add_argument("--runtime", default="inproc", choices=RUNTIMES,
                   help="where the controller firmware runs: in this process, a CPython or MicroPython "
                        "subprocess, a board flashed with firmware/ on --port, or qemu: the PIL image (make pil) on "
                        "an emulated Cortex-M0 (default inproc)")
    p.add_argument("--link", default=None, choices=LINKS,
                   help="link to the controller (default: inproc for inproc, serial otherwise)")
    p.add_argument("--port", help="--runtime board: the board's serial port, e.g. /dev/ttyACM0")
    p.add_argument("--baud", type=int, default=BAUD_DEFAULT, help="--runtime board: baud rate in bit/s (default "
                   "%d)" % BAUD_DEFAULT)
    p.add_argument("--realtime", action="store_true",
                   help="pace ticks by the wall clock; an answer later than one period is an overrun "
                        "(for a board whose loop runs from its own timer)")
    p.add_argument("--rate-hz", type=float, default=637.8, help="control loop rate in Hz (default 637.8)")
    p.add_argument("--link-faults", metavar="SPEC",
                   help="inject faults on the link, both directions: bytes=P (a bit flip per byte: of the COBS "
                        "stream on serial, of the slcan ASCII stream on CAN), frames=P (a frame dropped: a COBS "
                        "frame, or a CAN frame's Lawicel line), seed=N, silence=START_S:LENGTH_S (no traffic for "
                        "that span of virtual seconds, counted from the play's start in fps hil and from the "
                        "run's start in fps calibrate; LENGTH_S may be inf), first=N (the first N frames each "
                        "way dropped: a lost HELLO), e.g. bytes=0.01,frames=0.05,seed=1")
    p.add_argument("--tick-timeout-ms", type=float, default=None,
                   help="resend a TICK after this many ms without its answer (default %g on serial, %g on CAN, "
                        "%g with --runtime qemu)" % (TICK_TIMEOUT_MS, CAN_TICK_TIMEOUT_MS, QEMU_TICK_TIMEOUT_MS))
    p.add_argument("--tick-tries", type=int, default=TICK_TRIES,
                   help="sends of one TICK, the wait doubling from --tick-timeout-ms up to 100 ms, before the "
                        "tick counts as an overrun, the mirror holding (default %d: 2.6 s)" % TICK_TRIES)
    p.add_argument("--max-failed-ticks", type=int, default=MAX_FAILED_TICKS,
                   help="consecutive overruns on a silent link that end the run (default %d: 3.1 s at "
                        "637.8 Hz)" % MAX_FAILED_TICKS)


def check(runtime, link):
    if runtime not in RUNTIMES:
        raise ValueError("runtime %r not one of %s" % (runtime, ", ".join(RUNTIMES)))
    if link not in LINKS:
        raise ValueError("link %r not one of %s" % (link, ", ".join(LINKS)))
    if runtime in ("board", "qemu"):
        if link != "serial":
            raise ValueError("runtime %s with link %s: a board is reached on its serial port (--link serial)"
                             % (runtime, link))
        return
    if (runtime == "inproc") != (link == "inproc"):
        raise ValueError("runtime %s with link %s: inproc goes with inproc, cpython/micropython with serial "
                         "or can" % (runtime, link))
    if runtime == "micropython" and link == "can":
        raise ValueError("runtime micropython with link can: the MicroPython firmware speaks serial only "
                         "(firmware.hal.link); use --link serial, or --runtime cpython for CAN")


class RemoteEndpoint:
    """A ``RemoteController`` plus ``send_ground`` (packets from GROUND on the same link)."""

    def __init__(self, link, proc, timeout_s, try_timeout_s=None, tries=1, max_failed_ticks=None):
        from emulator.lockstep import RemoteController
        from protocol import core
        self.link, self.proc = link, proc
        self.faults = None
        self.rc = RemoteController(link, timeout_s=timeout_s, try_timeout_s=try_timeout_s, tries=tries,
                                   max_failed_ticks=max_failed_ticks)
        self.inbox = self.rc.inbox
        self._ground = core.NODE["GROUND"]
        self._ctrl = core.NODE["CONTROLLER"]

    def on_tick(self, tick, t_us, vx, vy, vs):
        return self.rc.on_tick(tick, t_us, vx, vy, vs)

    def send_ground(self, pid, payload, seq, dst=None):
        """Send from GROUND; the frame's sequence number (the link's own), None on CAN."""
        return self.link.send_raw(pid, self._ground, self._ctrl if dst is None else dst, payload)

    def poll(self, timeout_s):
        self.rc.poll(timeout_s)

    @property
    def timeout_s(self):          # real-time mode sets each tick's patience from its deadline
        return self.rc.timeout_s

    @timeout_s.setter
    def timeout_s(self, v):
        self.rc.timeout_s = v

    def counters(self):
        """The lockstep's counters, the link's (``link_``: its decoder, ISO-TP, the slcan adapter's lines) and the
        injected faults' (``fault_*``, once: an slcan bus counts its faults among its own too)."""
        c = dict(self.rc.counters())
        try:
            c.update(("link_" + k, v) for k, v in self.link.counters().items()
                     if self.faults is None or not k.startswith("fault_"))
        except AttributeError:
            pass
        if self.faults is not None:
            c.update(self.faults.counters())
        return c


def _start(runtime, link_kind, rate_hz):
    from emulator.launcher import FirmwareProcess, command
    from protocol.link import open_link
    # one link carries the BENCH (TICK/FSM_SPI) and the GROUND (commands, ACK/NACK, status): CAN must deliver both
    if link_kind == "serial":
        link = open_link("pty", "BENCH")
    else:
        link = open_link("slcan-pty", "BENCH", accept=("GROUND",), isotp_timeout_s=CAN_ISOTP_TIMEOUT_MS / 1000.0)
    spec = ("serial:" if link_kind == "serial" else "slcan:") + link.peer_path
    extra = [] if link_kind == "serial" else ["--isotp-timeout-ms", repr(CAN_ISOTP_TIMEOUT_MS)]
    argv, env = command(runtime, "firmware.main", ["controller", "--link", spec, "--rate", repr(rate_hz)] + extra)
    return link, FirmwareProcess(argv, env=env, stdout=subprocess.DEVNULL, name="the controller (%s)" % runtime)


BOOT_WORDS_S = 10.0          # wall seconds the PIL board has from its start to its first frame (its HELLO)


def check_pil(board="controller"):
    """``emulator.launcher.PilUnavailable`` (exit 2) unless qemu-system-arm is at hand and ``board``'s image
    ("controller": the Cortex-M0's, "adcs": the Cortex-M7's) is built from the tree's sources
    (``tools.pil_build.stale``: the digest it carries): every command that takes ``--runtime qemu`` asks first."""
    import shutil
    from emulator.launcher import PilUnavailable
    from tools import pil_build
    if shutil.which("qemu-system-arm") is None:
        raise PilUnavailable("runtime qemu needs qemu-system-arm (install: %s) and the PIL images (make pil)"
                             % pil_build.install_hint(["qemu-system-arm"]))
    why = pil_build.stale(pil_build.ADCS_MEM if board == "adcs" else pil_build.TARGET_MEM)
    if why:
        raise PilUnavailable("runtime qemu: %s" % why)


def _start_qemu(boot_s=60.0):
    """QEMU with the PIL image, its UART on a pty; ``firmware.pil_main`` started through the raw REPL. Returns (the
    bench's serial link on that pty, the QEMU process). ``emulator.launcher.PilUnavailable`` (a ValueError) without
    QEMU or with an image that is not the tree's (``check_pil``); OSError when the board does not start."""
    from emulator.launcher import qemu_command, start_board
    from tools import pil_build
    from protocol.link import open_serial
    check_pil("controller")
    import tempfile
    mem = pil_build.TARGET_MEM
    mon_dir = tempfile.mkdtemp(prefix="fps-qemu-")
    monitor = os.path.join(mon_dir, "monitor.sock")
    try:
        proc, link = start_board(qemu_command(mem.image, serial="pty", icount=True, monitor=monitor,
                                              ram_bytes=mem.ram_bytes),
                                 "import firmware.pil_main", lambda path: open_serial(path, "BENCH", baudrate=115200),
                                 name="qemu-system-arm (the controller's PIL board)", boot_s=boot_s,
                                 console_log=False, speaks_first_s=BOOT_WORDS_S)
    except BaseException:
        shutil.rmtree(mon_dir, ignore_errors=True)
        raise
    proc.monitor_path, proc.monitor_dir, proc.mem = monitor, mon_dir, mem
    proc.console = lambda: bytes(link.rx_tail)
    return link, proc


def stderr_tail(proc, n_chars=2000):
    """The last ``n_chars`` the controller process wrote to stderr (``FirmwareProcess.stderr_tail``)."""
    return proc.stderr_tail(n_chars)


def exit_note(proc, wait_s=1.0):
    """``FirmwareProcess.exit_note``: ``"; "`` and the process named, how it ended and its last stderr lines, or
    a board's traceback (``""`` without a process, a board on a port, or while it runs)."""
    return "" if proc is None else proc.exit_note(wait_s)


def _stop(link, proc):
    """The link closed (the firmware leaves when it closes), then ``FirmwareProcess.stop``. The PIL board's RAM is
    read first, while QEMU still runs (``proc.target``: ``tools.pil_board.read_target``)."""
    if getattr(proc, "monitor_path", None):
        from tools import pil_board
        try:
            proc.target = pil_board.read_target(proc.monitor_path, proc.mem) if proc.poll() is None else None
            ips = (proc.target or {}).get("instructions_per_step")
            if ips:                    # the link's bytes on the wire and the baud that closes the loop
                from tools import pil_wire
                k = ips["kinds"]
                proc.target["wire"] = dict(pil_wire.figures(k["common"]["mean"], k["status"]["max"],
                                                            common_max=ips["common"]["max"]), board=ips["wire"])
        except (OSError, pil_board.BoardError) as exc:
            proc.target = dict(pil_board.TARGET, error="the board's RAM could not be read: %s" % exc)
        shutil.rmtree(proc.monitor_dir, ignore_errors=True)
    proc.stopped_by_us = proc.poll() is None
    with contextlib.suppress(Exception):
        link.close()
    stopped = proc.stopped_by_us
    proc.stop()
    proc.stopped_by_us = stopped


def check_board(config, rate_hz=637.8):
    """ValueError (naming board.adc_read_us) if the config's board cannot sample its channels within one tick at
    ``rate_hz``: refused before a run starts, not at its first tick."""
    from emulator.config import default_config
    from emulator.timing import board_timing
    board_timing(config if config is not None else default_config()).split(1.0 / rate_hz)


def tick_timeout(link, tick_timeout_ms=None, runtime=None):
    """The TICK resend timeout in ms: ``tick_timeout_ms``, or the link's (the runtime's, for qemu) default."""
    if tick_timeout_ms is not None:
        return tick_timeout_ms
    if runtime == "qemu":
        return QEMU_TICK_TIMEOUT_MS
    return CAN_TICK_TIMEOUT_MS if link == "can" else TICK_TIMEOUT_MS


def check_options(runtime, link, port=None, link_faults=None, tick_timeout_ms=None,
                  tick_tries=TICK_TRIES, max_failed_ticks=MAX_FAILED_TICKS, rate_hz=637.8, baud=BAUD_DEFAULT, **_):
    """ValueError naming the flag for a runtime/link/option combination ``open_rig`` would refuse; for runtime qemu,
    QEMU missing or the image not the tree's (``check_pil``: make pil)."""
    check(runtime, link)
    if isinstance(baud, bool) or not isinstance(baud, int) or not BAUD_RANGE[0] <= baud <= BAUD_RANGE[1]:
        raise ValueError("--baud %r: must be a whole number of bit/s from %d to %d" % ((baud,) + BAUD_RANGE))
    if runtime != "board" and baud != BAUD_DEFAULT:
        raise ValueError("--baud %d goes with --runtime board (the other runtimes' links have no baud rate to "
                         "set)" % baud)
    tick_timeout_ms = tick_timeout(link, tick_timeout_ms)
    for name, v, lo, hi in (("--tick-timeout-ms", tick_timeout_ms, 0.05, 1e7), ("--tick-tries", tick_tries, 1, 1e6),
                            ("--max-failed-ticks", max_failed_ticks, 1, 1e9),
                            ("--rate-hz", rate_hz, 100.0, RATE_HZ_MAX)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
            raise ValueError("%s = %r: must be a number from %g to %g" % (name, v, lo, hi))
    if runtime == "board" and not port:
        raise ValueError("--runtime board needs --port (the board's serial port, e.g. /dev/ttyACM0)")
    if runtime != "board" and port:
        raise ValueError("--port %s goes with --runtime board" % port)
    if link_faults is not None and runtime == "inproc":
        raise ValueError("--link-faults needs a link: use --runtime cpython|micropython|board with --link serial, "
                         "or --runtime cpython with --link can")
    if runtime == "qemu":              # the options first: their messages name the flag
        check_pil("controller")


def _set_realtime(rig, realtime, rate_hz):
    """``realtime``: ticks paced by the wall clock, each answer due within one period."""
    if realtime:
        rig.lockstep.realtime = True
        rig.lockstep.deadline_s = 1.0 / rate_hz


@contextlib.contextmanager
def open_rig(runtime="inproc", link="inproc", config=None, seed=0, first_wait_s=30.0, port=None, baud=115200,
             link_faults=None, tick_timeout_ms=None, tick_tries=TICK_TRIES,
             max_failed_ticks=MAX_FAILED_TICKS, realtime=False, rate_hz=637.8, **kw):
    """A ``Rig`` with the controller in the chosen runtime; see the module docstring.

    ``board``: a controller board flashed with ``firmware/`` on the serial port ``port`` at ``baud``.
    ``link_faults``: a ``protocol.faults.LinkFaults`` injected on the serial link or the slcan stream
    (``rig.faults`` is the ``FaultyPort``; set its ``clock``). TICKs are resent after ``tick_timeout_ms``
    (None: the link's default, ``tick_timeout``), ``tick_tries`` times, and
    ``max_failed_ticks`` consecutive overruns end the run (``emulator.lockstep.RemoteController``).
    ``realtime``: ticks paced by the wall clock, each answer due within one period (overruns counted)."""
    check_options(runtime, link, port=port, link_faults=link_faults, tick_timeout_ms=tick_timeout_ms,
                  tick_tries=tick_tries, max_failed_ticks=max_failed_ticks, rate_hz=rate_hz)
    if runtime == "inproc":
        from firmware.controller import Controller
        rig = Rig(InprocController(Controller()), config=config, seed=seed, rate_hz=rate_hz, **kw)
        rig.runtime_name, rig.link_name = "inproc", "inproc"
        rig.process = None
        rig.faults = None
        _set_realtime(rig, realtime, rate_hz)
        yield rig
        return
    try_s = tick_timeout(link, tick_timeout_ms, runtime) / 1000.0
    patience_s = 3600.0         # the tries bound a tick (RemoteController backs off to 0.1 s per try)
    if runtime == "board":
        from protocol.link import open_serial
        try:
            lk = open_serial(port, "BENCH", baudrate=baud)
        except Exception as exc:       # pyserial's SerialException is an IOError subclass, but say which port
            raise OSError("cannot open the board's port %s: %s" % (port, exc)) from None
        proc = None
        name = "board %s" % port
    elif runtime == "qemu":
        lk, proc = _start_qemu()
        name = "qemu (Cortex-M0, QEMU microbit) over serial"
    else:
        lk, proc = _start(runtime, link, rate_hz)
        name = "%s over %s" % (runtime, link)
    try:
        ep = RemoteEndpoint(lk, proc, patience_s, try_timeout_s=try_s, tries=tick_tries,
                            max_failed_ticks=max_failed_ticks)
        if link_faults is not None:
            from protocol.faults import inject
            ep.faults = inject(lk, link_faults)
        rig = Rig(ep, config=config, seed=seed, rate_hz=rate_hz, deadline_s=1.0, **kw)
        rig.runtime_name, rig.link_name = runtime, link
        if runtime == "qemu":          # a command's ACK waits on QEMU as a TICK's answer does (a retry is input too)
            rig.cmd_timeout_s = QEMU_TICK_TIMEOUT_MS / 1000.0
        rig.link_desc = name + (" (%s)" % port if port and runtime != "board" else "")
        rig.process = proc
        rig.faults = ep.faults
        try:
            _first_contact(rig, ep, proc, first_wait_s)
        except OSError as exc:
            exc.rig = rig          # the caller reports the link counters of a failed start
            raise
        _set_realtime(rig, realtime, rate_hz)
        yield rig
    finally:
        if proc is not None:
            _stop(lk, proc)
        else:
            with contextlib.suppress(Exception):
                lk.close()


def _first_contact(rig, ep, proc, wait_s):
    """HELLO to the controller, repeated every 50 ms until it answers (its own HELLO counts: it says one when
    its link opens); a HELLO also starts a new session in the firmware (tick numbers from 0 again)."""
    from protocol import core
    from protocol.link import first_contact
    hello = core.PACKET_ID["HELLO"]
    payload = core.encode_payload(hello, node=core.NODE["GROUND"])

    def check():
        if proc is not None and proc.poll() is not None:
            raise OSError(proc.death(when=" before it said HELLO"))
        if ep.link.closed:
            raise OSError("the controller's link closed before it said HELLO")
    tries, got = first_contact(lambda: ep.send_ground(hello, payload, 0), lambda t: ep.link.recv(timeout=t),
                               wait_s, 0.05, None, check, lambda pkts: any(p[0] == hello for p in pkts))
    if got is None:
        raise OSError("controller did not answer HELLO within %g s (%d tries)" % (wait_s, tries))
    rig.hello_tries = tries
    if tries > 1:
        rig.n_cmd_retries += tries - 1
    ep.inbox.clear()
