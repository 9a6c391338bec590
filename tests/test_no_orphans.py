"""No process outlives an ``fps`` run, and a child's failure names it.

Each test starts an ``fps`` command in its own interpreter, waits until its children exist (the controller's or
the ADCS's firmware process, QEMU, fps system's ADCS process and multiprocessing's resource tracker: every process
whose parent chain leads to the command), then sends the command SIGKILL (none of its code runs: the kernel ends
its children, ``emulator.runtime.die_with_parent``) or SIGTERM (an interrupt: exit 130, the run folder valid with
what was done so far). Within ``GONE_S`` of the command's end no process of the run is left. QEMU's runs are
skipped, saying why, where qemu-system-arm or the PIL images (make pil) are missing."""

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from emulator import launcher

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GONE_S = 2.0            # the run's processes are gone this long after the command's end
START_S = 60.0          # the children exist, and the run has reached the point the test waits for, within this
END_S = 60.0            # a command given SIGTERM ends within this (it stops its children first)


def _qemu(image):
    """The reason to skip a qemu run, or None."""
    if shutil.which("qemu-system-arm") is None:
        return "qemu-system-arm is not installed (make pil installs it as root)"
    if not os.path.exists(image):
        return "no PIL image at %s (make pil)" % os.path.relpath(image, ROOT)
    return None


CONTROLLER_QEMU = pytest.mark.skipif(_qemu(launcher.PIL_IMAGE) is not None, reason=str(_qemu(launcher.PIL_IMAGE)))
ADCS_QEMU = pytest.mark.skipif(_qemu(launcher.ADCS_IMAGE) is not None, reason=str(_qemu(launcher.ADCS_IMAGE)))
SIGNALS = pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])


# --- the process tree ------------------------------------------------------------------------------------------
def _processes():
    """{pid: (parent pid, command name)} of every live process (a zombie, dead but not yet reaped, is not)."""
    out = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open("/proc/%s/stat" % d) as f:
                stat = f.read()
        except OSError:
            continue
        head, _, rest = stat.rpartition(")")
        fields = rest.split()
        if fields and fields[0] != "Z":
            out[int(d)] = (int(fields[1]), head.partition("(")[2])
    return out


def _tree(root):
    """{pid: command name} of the processes whose parent chain leads to ``root`` (``root`` left out)."""
    procs = _processes()
    kids, found, grew = {}, {root}, True
    while grew:
        grew = False
        for pid, (ppid, name) in procs.items():
            if ppid in found and pid not in found:
                found.add(pid)
                kids[pid] = name
                grew = True
    return kids


def _alive(pids):
    procs = _processes()
    return {p: procs[p][1] for p in pids if p in procs}


class Fps:
    """``fps ARGS`` in its own interpreter, its stderr to a file; ``seen`` every process of its tree so far."""

    def __init__(self, args, tmp_path):
        self.err_path = tmp_path / "stderr.txt"
        with open(self.err_path, "wb") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "ground.cli"] + list(args), cwd=ROOT,
                                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
        self.seen = {}

    def look(self):
        kids = _tree(self.proc.pid)
        self.seen.update(kids)
        return kids

    def wait_for(self, what, ready):
        """Until ``ready(children's names)`` is true (the tree looked at every 50 ms); fails naming ``what``."""
        deadline = time.monotonic() + START_S
        while time.monotonic() < deadline:
            names = list(self.look().values())
            if ready(names):
                return
            if self.proc.poll() is not None:
                pytest.fail("fps ended (%s) before %s: %s" % (self.proc.returncode, what, self.stderr()[-1500:]))
            time.sleep(0.05)
        pytest.fail("no %s within %g s (children: %s)" % (what, START_S, sorted(self.seen.values())))

    def wait_text(self, what, pattern):
        """Until its stderr matches the regex ``pattern`` (its tree looked at meanwhile); fails naming ``what``."""
        import re
        deadline = time.monotonic() + START_S
        while time.monotonic() < deadline:
            self.look()
            if re.search(pattern, self.stderr()):
                return
            if self.proc.poll() is not None:
                pytest.fail("fps ended (%s) before %s: %s" % (self.proc.returncode, what, self.stderr()[-1500:]))
            time.sleep(0.05)
        pytest.fail("no %s within %g s: %s" % (what, START_S, self.stderr()[-1500:]))

    def pause(self, seconds):
        """``seconds`` of the run, its tree looked at meanwhile."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.look()
            time.sleep(0.05)

    def send(self, sig):
        """``sig`` to the command, still running; its exit status once it ended (within ``END_S``)."""
        self.look()
        assert self.seen, "the command had no child"
        if self.proc.poll() is not None:
            pytest.fail("fps ended (%s) before its %s: %s" % (self.proc.returncode, sig.name, self.stderr()[-1500:]))
        self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(END_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            pytest.fail("fps did not end within %g s of %s" % (END_S, sig.name))
        return rc

    def assert_none_left(self):
        """None of the processes seen in its tree runs ``GONE_S`` after the command ended (any left is killed,
        and the test fails naming it)."""
        deadline = time.monotonic() + GONE_S
        while _alive(self.seen) and time.monotonic() < deadline:
            time.sleep(0.02)
        left = _alive(self.seen)
        _kill(left)                          # not left to the other tests
        assert not left, "left running %g s after fps ended: %s" % (GONE_S, left)

    def stderr(self):
        return self.err_path.read_text(errors="replace")

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        _kill(_alive(self.seen))


def _kill(pids):
    for pid in pids:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)


@pytest.fixture
def fps_run(tmp_path):
    runs = []

    def start(*args):
        runs.append(Fps(args, tmp_path))
        return runs[-1]
    yield start
    for r in runs:
        r.close()


def _summary(out):
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)


def _phase(out):
    """The run's phase as its summary.json says it (None while it cannot be read)."""
    try:
        return _summary(out).get("phase")
    except (OSError, ValueError):
        return None


def _interrupted(f, rc):
    """SIGTERM taken as an interrupt: exit 130 and no traceback."""
    err = f.stderr()
    assert rc == 130, err[-2000:]
    assert "Traceback" not in err


def _stopped(f, sig):
    """Send ``sig``; no process of the run is left. SIGKILL: the run died of it (False: nothing more to check);
    SIGTERM: taken as an interrupt (True: the folder is to be checked)."""
    rc = f.send(sig)
    f.assert_none_left()
    if sig == signal.SIGKILL:
        assert rc == -signal.SIGKILL
        return False
    _interrupted(f, rc)
    return True


def _count(name, n=1):
    """A ``wait_for`` condition: at least ``n`` children named ``name``."""
    return lambda names: names.count(name) >= n


# --- fps hil ---------------------------------------------------------------------------------------------------
def _hil(fps_run, inputs, out, runtime, sig):
    """fps hil given ``sig`` once its controller's process runs (SIGTERM: in the play): none of its processes is
    left; SIGTERM: exit 130, the samples played so far in the folder."""
    dist, cal = inputs
    f = fps_run("hil", "--distfile", dist, "--calibration", cal, "--duration", "30", "--runtime", runtime, "--quiet",
                "--no-plots", "-o", out)
    name = "qemu-system-arm" if runtime == "qemu" else "micropython"
    f.wait_for("the controller's process", _count(name))
    if sig == signal.SIGTERM:                 # in the play, so that it has samples to keep
        f.wait_for("the play", lambda names: os.path.exists(os.path.join(out, "q2_calibration.json")))
    f.pause(1.0)
    if not _stopped(f, sig):
        return
    s = _summary(out)
    assert s["complete"] is False and s["interrupted"] is True and s["q2_samples"] > 0
    assert len(np.load(os.path.join(out, "samples.npz"))["q2_err_arcsec"]) == s["q2_samples"]


@SIGNALS
def test_fps_hil_micropython_leaves_no_process(fps_run, inputs, tmp_path, sig):
    _hil(fps_run, inputs, str(tmp_path / "run"), "micropython", sig)


@CONTROLLER_QEMU
@pytest.mark.parametrize("sig", [signal.SIGKILL], ids=["SIGKILL"])
def test_fps_hil_qemu_leaves_no_qemu(fps_run, inputs, tmp_path, sig):
    _hil(fps_run, inputs, str(tmp_path / "run"), "qemu", sig)


# --- fps adcs can ----------------------------------------------------------------------------------------------
def _adcs_can(fps_run, out, runtime, sig):
    """fps adcs can given ``sig`` 3 s after its firmware's process started: none of its processes is left;
    SIGTERM: exit 130, the history of every cycle flown so far in the folder."""
    f = fps_run("adcs", "can", "--session", "3000", "--runtime", runtime, "--quiet", "--no-plots", "-o", out)
    f.wait_for("the ADCS firmware's process", _count("qemu-system-arm" if runtime == "qemu" else "micropython"))
    f.pause(3.0)
    if not _stopped(f, sig):
        return
    s = _summary(out)
    assert s["complete"] is False and s["interrupted"] is True and s["cycles"] < 3000
    assert s["cycles"] > 0 or runtime == "qemu"           # the ADCS board boots for seconds
    assert np.load(os.path.join(out, "history.npz"))["t"].shape == (10 * s["cycles"],)      # every cycle flown kept


@SIGNALS
def test_fps_adcs_can_micropython_leaves_no_process_and_keeps_its_history(fps_run, tmp_path, sig):
    _adcs_can(fps_run, str(tmp_path / "run"), "micropython", sig)


@ADCS_QEMU
@SIGNALS
def test_fps_adcs_can_qemu_leaves_no_qemu(fps_run, tmp_path, sig):
    _adcs_can(fps_run, str(tmp_path / "run"), "qemu", sig)


# --- fps calibrate, fps response ---------------------------------------------------------------------------------
@SIGNALS
def test_fps_calibrate_leaves_no_process_and_no_calibration(fps_run, tmp_path, sig):
    """The controller on the PIL board where QEMU and the image are here (else micropython): stopped or killed
    halfway through the grid, no QEMU is left and no calibration is written."""
    runtime = "micropython" if _qemu(launcher.PIL_IMAGE) else "qemu"
    out = str(tmp_path / "cal.json")
    f = fps_run("calibrate", "--runtime", runtime, "--grid", "11", "--no-plots", "--no-truth", "-o", out)
    f.wait_for("the controller's process", _count("qemu-system-arm" if runtime == "qemu" else "micropython"))
    f.pause(1.0)
    rc = f.send(sig)
    f.assert_none_left()
    assert not os.path.exists(out)
    if sig == signal.SIGTERM:
        _interrupted(f, rc)


@SIGNALS
def test_fps_response_leaves_no_process_and_keeps_the_tones_measured(fps_run, tmp_path, sig):
    """Stopped halfway through its tones: summary.json holds those measured (interrupted, no error)."""
    out = str(tmp_path / "run")
    f = fps_run("response", "--runtime", "micropython", "--from", "0.2", "--points", "60", "--no-plots", "-o", out)
    f.wait_for("the controller's process", _count("micropython"))
    f.wait_text("a tone measured (its progress bar)", r"\b[1-9][0-9]*/60\b")    # however loaded the machine
    rc = f.send(sig)
    f.assert_none_left()
    if sig == signal.SIGKILL:
        return
    _interrupted(f, rc)
    s = _summary(out)
    assert s["complete"] is False and s["interrupted"] is True and s["error"] is None
    assert 0 < s["tones_measured"] < 60 and len(s["freq_hz"]) == len(s["s_measured"]) == s["tones_measured"]


# --- fps system --------------------------------------------------------------------------------------------------
def _system(fps_run, system_inputs, out):
    """fps system with the ADCS firmware and the controller under micropython, started and waited for: both
    firmware processes (the ADCS's under fps system's ADCS process)."""
    params, cal, cache = system_inputs
    f = fps_run("system", "--adcs", "firmware", "--runtime", "micropython", "--world", "thesis", "--duration", "60",
                "--truth", "two-body", "--params", params, "--calibration", cal, "--bps-cache", cache, "--quiet",
                "--no-plots", "-o", out)
    f.wait_for("the controller's and the ADCS's firmware processes", _count("micropython", 2))
    return f


@SIGNALS
def test_fps_system_leaves_no_process(fps_run, system_inputs, tmp_path, sig):
    """The ADCS process (multiprocessing, spawn), its firmware, the controller and the resource tracker: none is
    left, whether fps system is killed or stopped."""
    out = str(tmp_path / "run")
    f = _system(fps_run, system_inputs, out)
    if sig == signal.SIGTERM:                 # in the play, so that it has samples to keep
        f.wait_for("the play", lambda names: _phase(out) == "play")
        f.pause(1.0)
    rc = f.send(sig)
    f.assert_none_left()
    assert len(f.seen) >= 4, f.seen           # the firmware processes, the ADCS process, the resource tracker
    if sig == signal.SIGKILL:
        return
    _interrupted(f, rc)
    s = _summary(out)
    assert s["complete"] is False and s["interrupted"] is True and s["stopped_in"] == "play" and s["q2_samples"] > 0


def _adcs_process(fps_pid):
    """fps system's ADCS process: its child that runs multiprocessing's spawn and has a child of its own."""
    procs = _processes()
    for pid, (ppid, _) in procs.items():
        if ppid != fps_pid:
            continue
        try:
            with open("/proc/%d/cmdline" % pid, "rb") as fh:
                cmd = fh.read()
        except OSError:
            continue
        if b"spawn_main" in cmd and any(pp == pid for pp, _ in procs.values()):
            return pid
    return None


def test_fps_system_names_the_adcs_process_and_its_signal_when_it_is_stopped(fps_run, system_inputs, tmp_path):
    """SIGTERM to the ADCS process alone: the run fails (exit 1) saying the ADCS process was killed by SIGTERM,
    without the fine loop's link or the bench's counters in front or behind; nothing is left."""
    out = str(tmp_path / "run")
    f = _system(fps_run, system_inputs, out)
    pid = _adcs_process(f.proc.pid)
    assert pid is not None, f.seen
    os.kill(pid, signal.SIGTERM)
    try:
        rc = f.proc.wait(END_S)
    except subprocess.TimeoutExpired:
        pytest.fail("fps system did not end within %g s of its ADCS process's SIGTERM" % END_S)
    f.assert_none_left()
    err = f.stderr()
    assert rc == 1 and "Traceback" not in err, err[-2000:]
    line = [ln for ln in err.splitlines() if ln.startswith("fps system: error:")]
    assert line and line[0].startswith("fps system: error: the ADCS process was killed by SIGTERM "), err[-2000:]
    assert "over serial:" not in line[0] and "bench counters" not in line[0] and "exited (status" not in line[0]
    s = _summary(out)
    assert s["complete"] is False and s["error"].startswith("the ADCS process was killed by SIGTERM")
