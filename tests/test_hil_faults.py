"""A HIL that survives a bad link: exactly-once ticks, retries, bounds, the truth in the run folder.

The end-to-end runs drive the real MicroPython controller (``firmware.main``) over a serial pty with faults
injected at the transport (``protocol.faults``); a run with faults must give the same samples and control
telemetry, bit for bit, as the same run without.
"""

import json
import os
import re
import subprocess
import threading
import time

import numpy as np
import pytest

from emulator.bench import Bench
from emulator.lockstep import Lockstep, RemoteController
from emulator.truth import true_h_field
from firmware.controller import SAFE, TRACK, Controller
from ground.cli import main as fps
from ground.hil import mode_changes
from emulator.runtime import micropython_binary
from ground.runtime import ROOT
from protocol import core, htable
from protocol.faults import FaultyPort, LinkFaults

LINK_COLS = ("n_dup", "n_rx_drop")   # telemetry.csv: the link's own counters; every other column is control


def _hil(tmp_path, inputs, name, *extra, duration="3"):
    dist, cal = inputs
    out = tmp_path / name
    rc = fps(["hil", "--distfile", dist, "--calibration", cal, "--duration", duration, "--runtime", "micropython",
              "--no-plots", "--quiet", "-o", str(out)] + list(extra))
    return rc, out, json.loads((out / "summary.json").read_text())


def _control_telemetry(out):
    rows = [line.split(",") for line in (out / "telemetry.csv").read_text().splitlines()]
    keep = [i for i, name in enumerate(rows[0]) if name not in LINK_COLS]
    assert len(keep) == len(rows[0]) - len(LINK_COLS)
    return [",".join(r[i] for i in keep) for r in rows]


# --- the fault injector -------------------------------------------------------------------------------------
def test_fault_spec_is_parsed_and_bad_specs_are_refused():
    f = LinkFaults.parse("bytes=0.01,frames=0.05,seed=3,silence=2:1.5,silence=10:inf")
    assert (f.p_byte, f.p_frame, f.seed) == (0.01, 0.05, 3) and f.silences == [(2.0, 1.5), (10.0, float("inf"))]
    for bad in ("", "bytes", "bytes=2", "frames=-0.1", "bytes=nan", "silence=3", "silence=-1:2", "colour=1",
                "seed=x"):
        with pytest.raises(ValueError, match="--link-faults"):
            LinkFaults.parse(bad)


class _Port:
    def __init__(self):
        self.sent = []

    def write(self, data):
        self.sent.append(bytes(data))

    def read(self, timeout):
        return b""

    def close(self):
        pass


def test_faulty_port_drops_flips_and_silences_whole_frames():
    frame = bytes(range(1, 30)) + b"\x00"
    port = _Port()
    fp = FaultyPort(port, LinkFaults(p_byte=0.02, p_frame=0.1, seed=7))
    for _ in range(2000):
        fp.write(frame)
    c = fp.counters()
    out = b"".join(port.sent)
    assert c["fault_tx_frames"] == 2000 and 140 < c["fault_tx_dropped"] < 260
    assert len(out) == 30 * (2000 - c["fault_tx_dropped"])              # bits flip, bytes are not lost
    flipped = sum(bin(a ^ b).count("1") for a, b in zip(out, frame * 2000))
    assert flipped == c["fault_tx_bits_flipped"] and 0.015 < flipped / len(out) < 0.025
    t = [0.0]
    fp = FaultyPort(_Port(), LinkFaults(silences=[(1.0, 2.0)]), clock=lambda: t[0])
    for t[0] in (0.5, 1.0, 2.9, 3.0):
        fp.write(frame)
    assert fp.counters()["fault_tx_silenced"] == 2 and len(fp.port.sent) == 2


def test_first_drops_the_first_frames_each_way_and_is_checked():
    """first=N: the first N frames of each direction are lost (a lost HELLO), counted with the dropped ones; on
    slcan only CAN frame lines count, so the commands that open the channel pass."""
    from protocol.faults import SLCAN
    f = LinkFaults.parse("first=2,seed=1")
    assert f.first == 2 and f.describe() == "bytes=0,frames=0,seed=1,first=2" and f.as_dict()["first"] == 2
    frame = bytes(range(1, 30)) + b"\x00"
    fp = FaultyPort(_Port(), f)
    for _ in range(5):
        fp.write(frame)
    assert fp.port.sent == [frame] * 3 and fp.counters()["fault_tx_dropped"] == 2
    fp = FaultyPort(_Port(), LinkFaults(first=1), framing=SLCAN)
    fp.write(b"S8\rO\rT0123456780\rT0123456781\r")
    assert fp.port.sent == [b"S8\rO\rT0123456781\r"]
    for bad in ("first=-1", "first=1.5", "first=x", "first=1000001"):
        with pytest.raises(ValueError, match="first"):
            LinkFaults.parse(bad)


@pytest.mark.parametrize("spec, words", [("seed=-1", "seed=-1: a whole number from 0 to 2^32 - 1"),
                                          ("seed=4294967296", "seed=4294967296"), ("seed=1.5", "bad value"),
                                          ("bytes=1", "a probability in [0, 1)"), ("silence=-1:2", "START_S >= 0")])
def test_link_fault_specs_out_of_range_are_refused_naming_the_item(spec, words):
    """A negative seed was taken (random.Random uses its absolute value: seed=-1 was seed=1)."""
    with pytest.raises(ValueError, match=re.escape(words)):
        LinkFaults.parse(spec)
    assert LinkFaults.parse("seed=4294967295").seed == 4294967295


# --- exactly once, in the firmware ---------------------------------------------------------------------------
def test_a_resent_tick_is_answered_again_without_a_second_step():
    from firmware.hal.link import serve_controller
    from firmware.hal.ports import _Ms
    from protocol.link import inproc_pair
    a, b = inproc_pair("BENCH", "CONTROLLER")
    ctl = Controller(table=htable.pack_calibration(true_h_field(Bench(noise=False), None, 0.01)))
    ctl.mode = TRACK
    th = threading.Thread(target=serve_controller, args=(ctl, _Ms(b)), daemon=True)
    th.start()
    assert a.recv(timeout=5)[0][0] == core.PACKET_ID["HELLO"]
    tick = core.PACKET_ID["TICK"]
    answers = []
    for k, n in ((0, 1), (1, 3), (2, 1)):           # TICK 1 three times: its answer was "lost" twice
        for _ in range(n):
            a.send(tick, "CONTROLLER", tick=k, vx=1900, vy=2100, vs=3000)
            got = []
            while not got:
                got = [p for p in a.recv(timeout=5) if p[0] == core.PACKET_ID["FSM_SPI"]]
            answers.append(got[0][4])
    a.close()
    th.join(5)
    assert answers[1] == answers[2] == answers[3]             # the same words for tick 1, thrice
    assert ctl.n_dup == 2 and ctl.ticks == 2    # stepped once per tick number (tick 0 is the uncounted init tick)


def test_upload_end_repeated_after_a_lost_ack_gets_the_same_answer():
    blob = htable.pack_calibration(true_h_field(Bench(noise=False), None, 0.01))
    c = Controller()
    P = core.PACKET_ID
    assert c.handle(P["HTABLE_BEGIN"], 1, 0, core.encode_payload(P["HTABLE_BEGIN"], total=len(blob),
                                                                 crc32=core.crc32(blob) & 0xFFFFFFFF))[0][0] == P["ACK"]
    n = core.PACKET[P["HTABLE_CHUNK"]].size - 6
    for off in range(0, len(blob), n):
        part = blob[off:off + n]
        payload = core.encode_payload(P["HTABLE_CHUNK"], offset=off, length=len(part), data=part + bytes(n - len(part)))
        for _ in range(2):                                    # every chunk twice: idempotent by offset
            assert c.handle(P["HTABLE_CHUNK"], 1, 0, payload)[0][0] == P["ACK"]
    end = core.encode_payload(P["HTABLE_END"], total=len(blob))
    assert c.handle(P["HTABLE_END"], 1, 0, end)[0][0] == P["ACK"]
    table = c.table
    assert c.handle(P["HTABLE_END"], 1, 0, end)[0][0] == P["ACK"] and c.table is table


def test_safe_reason_and_mode_changes():
    c = Controller(table=htable.pack_calibration(true_h_field(Bench(noise=False), None, 0.01)), safe_ticks=5)
    c.mode = TRACK
    for _ in range(7):
        c.step(2048, 2048, 2500)
    c.link_silent(5)                                          # the ground link silent
    assert c.mode == SAFE and c.why == 2
    d = core.payload_dict(core.PACKET_ID["CTRL_STATUS"], c.status_payload(7))
    assert d["why"] == 2 and d["mode"] == SAFE

    class R:
        rate_hz = 100.0
        mode_log = [(0, 1, 0), (50, 2, 0), (300, 1, 0), (420, 4, 2)]
    ch = mode_changes(R(), 100)
    assert [(m["t_s"], m["from"], m["to"], m["why"]) for m in ch] == [
        (2.0, "HOLD", "TRACK", "commanded"), (3.2, "TRACK", "SAFE", "LINK_SILENT")]


# --- the clock keeps what it played ---------------------------------------------------------------------------
def test_an_interrupted_lockstep_call_keeps_every_sample_it_played():
    class Stop:
        def __init__(self, config, at):
            self.at = at
            self.inner = Controller()

        def on_tick(self, tick, t_us, vx, vy, vs):
            if tick == self.at:
                raise KeyboardInterrupt
            return self.inner.on_tick(tick, t_us, vx, vy, vs)

    b = Bench(seed=2)
    ref = Lockstep(Bench(seed=2), Controller()).run(n_ticks=1000)
    lock = Lockstep(b, Stop(b.config, 700))
    with pytest.raises(KeyboardInterrupt):
        lock.run(n_ticks=1000)
    part = lock.partial
    assert lock.tick == 700
    n = len(part["q2"])
    assert n > 600 and np.array_equal(part["q2"], ref["q2"][:n])
    assert ref["q2"][n, 1] >= 700 * 1e6 / 637.8 - 1e-6               # the next sample is past the stop


def test_realtime_answers_are_due_within_one_period_in_process_too():
    """--realtime: an answer later than one period is an overrun, as --help says; the in-process controller
    kept Lockstep's default deadline of 1 s."""
    from ground import runtime
    with runtime.open_rig("inproc", "inproc", realtime=True, rate_hz=500.0) as rig:
        assert rig.lockstep.realtime and rig.lockstep.deadline_s == pytest.approx(0.002)
    with runtime.open_rig("inproc", "inproc") as rig:
        assert not rig.lockstep.realtime


def test_remote_controller_resends_and_gives_up_on_a_dead_link():
    from protocol.link import inproc_pair
    a, b = inproc_pair("BENCH", "CONTROLLER")
    waits, recv = [], a.recv

    def timed_recv(timeout=None):            # the waits asked of the link: the tries', not the 10 s bound
        waits.append(timeout)
        return recv(timeout=timeout)
    a.recv = timed_recv
    rc = RemoteController(a, timeout_s=10.0, try_timeout_s=0.001, tries=4, max_failed_ticks=3)
    lock = Lockstep(Bench(seed=1), rc)
    from emulator.lockstep import LinkFailure
    with pytest.raises(LinkFailure, match="3 consecutive ticks"):
        lock.run(n_ticks=10)
    assert waits and max(waits) <= 0.008 + 1e-9                 # 1, 2, 4, 8 ms: doubled at each resend
    assert rc.n_timeout == 3 and rc.n_resent == 3                # 4 sends on the first tick, 1 on each next
    assert len([p for p in b.recv(timeout=0.5) if p[0] == core.PACKET_ID["TICK"]]) == 6
    a.close()


class _CountingLink:
    """A link whose peer answers each TICK ``delay_s`` after its first copy, while the counters named in ``rising``
    go up by one at each of the first ``n_rising`` waits on the link (what a CAN link counts under load, or under
    damage)."""

    def __init__(self, delay_s, rising, n_rising=10 ** 9):
        self.node = core.NODE["BENCH"]
        self.closed = False
        self.delay_s, self.rising, self.n_rising = delay_s, rising, n_rising
        self.c = {"tx_frames": 0}
        self.due = {}

    def send_raw(self, pid, src, dst, payload):
        self.c["tx_frames"] += 1
        tick = core.decode_payload(pid, payload)[0]
        self.due.setdefault(tick, time.perf_counter() + self.delay_s)

    def recv(self, timeout=None):
        time.sleep(min(timeout or 0.0, 0.0005))
        if self.n_rising > 0:
            self.n_rising -= 1
            for k in self.rising:
                self.c[k] = self.c.get(k, 0) + 1
        now = time.perf_counter()
        out = [(core.PACKET_ID["FSM_SPI"], core.NODE["CONTROLLER"], self.node, None,
                core.encode_payload("FSM_SPI", tick=t, n=1, w0=0x380001)) for t, d in self.due.items() if d <= now]
        for p in out:
            del self.due[core.decode_payload(p[0], p[4])[0]]
        return out

    def counters(self):
        return dict(self.c)


@pytest.mark.parametrize("rising", [("tx_isotp_TimeoutError", "tx_isotp_UnexpectedFlowControlError",
                                     "tx_isotp_resent", "tx_isotp_failed"),
                                    ("isotp_ConsecutiveFrameTimeoutError", "isotp_UnexpectedConsecutiveFrameError",
                                     "isotp_ReceptionInterruptedWithFirstFrameError", "slcan_refused",
                                     "fault_tx_frames")])
def test_a_slow_link_waits_for_its_tries_never_resending_early(rising):
    """The bench's own ISO-TP send timeouts and transfers timed out on receive (a loaded machine) are slowness, not
    damage: the TICK is resent as its tries run out (3 ms, doubling), never at once, and the tick is answered
    (they triggered the early resend, 30 tries went in under 1 s and the run stopped as too noisy)."""
    from emulator.lockstep import RemoteController
    rc = RemoteController(_CountingLink(0.2, rising), timeout_s=10.0, try_timeout_s=0.003, tries=30)
    assert rc.on_tick(5, 0, 2048, 2048, 1600) == [0x380001]
    assert rc.n_early == 0 and 4 <= rc.n_resent <= 8                # 3, 6, 12, 24, 48, 96 ms: ~0.2 s


def test_damage_resends_at_once_and_a_link_that_delivers_only_damage_is_too_noisy():
    from emulator.lockstep import LinkFailure, RemoteController
    rc = RemoteController(_CountingLink(0.05, ("bad_crc",), 3), timeout_s=10.0, try_timeout_s=0.003, tries=30)
    assert rc.on_tick(5, 0, 2048, 2048, 1600) == [0x380001] and rc.n_early == 3
    rc = RemoteController(_CountingLink(5.0, ("isotp_WrongSequenceNumberError",)), timeout_s=10.0,
                          try_timeout_s=0.003, tries=30)
    with pytest.raises(LinkFailure, match="kept delivering damaged frames"):
        rc.on_tick(5, 0, 2048, 2048, 1600)
    assert rc.n_early == 30 and rc.n_resent == 29              # every try cut short by damage


# --- end to end, MicroPython over a pty ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def clean(tmp_path_factory, inputs):
    rc, out, s = _hil(tmp_path_factory.mktemp("clean"), inputs, "clean")
    assert rc == 0 and s["complete"] and s["requirement_met"] and s["error"] is None
    return out, s


@pytest.mark.slow(reason="~20 s under faults: FPS_SLOW=1 make test runs it")
def test_faults_cost_time_not_correctness(tmp_path, inputs, clean):
    out0, s0 = clean
    rc, out, s = _hil(tmp_path, inputs, "faulty", "--link-faults", "bytes=0.01,frames=0.05,seed=1")
    assert rc == 0 and s["complete"] and s["requirement_met"] and s["error"] is None
    a, b = np.load(out0 / "samples.npz"), np.load(out / "samples.npz")
    for k in a.files:
        assert np.array_equal(a[k], b[k]), k
    assert _control_telemetry(out) == _control_telemetry(out0)
    bench, ctl = s["link"]["bench"], s["link"]["controller"]
    assert bench["controller_resent"] > 100 and bench["overruns"] == 0 and bench["command_retries"] > 0
    assert 0 <= bench["stale_replies"] <= bench["command_retries"]    # each from a resent command
    assert bench["controller_fault_tx_dropped"] > 0 and bench["controller_fault_rx_bits_flipped"] > 0
    assert ctl["resent_ticks_answered"] > 0 and ctl["rx_frames_dropped"] > 0 and ctl["gap_ticks"] == 0
    assert s["link_faults"]["bytes"] == 0.01 and s0["link_faults"] is None


def test_a_lost_first_frame_each_way_costs_a_retry_not_the_run(tmp_path, inputs, clean):
    """--link-faults first=1 on serial: the controller's HELLO and the bench's first HELLO are lost; HELLO is said
    again until answered and the run is the clean run, bit for bit."""
    out0, _ = clean
    rc, out, s = _hil(tmp_path, inputs, "first", "--link-faults", "first=1")
    assert rc == 0 and s["complete"] and s["error"] is None and s["overruns"] == 0
    a, b = np.load(out0 / "samples.npz"), np.load(out / "samples.npz")
    for k in a.files:
        assert np.array_equal(a[k], b[k]), k
    bench = s["link"]["bench"]
    assert bench["controller_fault_tx_dropped"] == bench["controller_fault_rx_dropped"] == 1
    assert bench["hello_tries"] >= 2 and s["link_faults"]["first"] == 1


def test_heavy_faults_stop_with_a_clear_error(tmp_path, inputs, capsys):
    rc, out, s = _hil(tmp_path, inputs, "heavy", "--link-faults", "bytes=0.05,frames=0.20,seed=1")
    err = capsys.readouterr().err
    if rc == 0:                            # it may complete: then it must be exact (not with this seed today)
        pytest.fail("completed under heavy faults: compare it bit for bit before accepting")
    assert rc == 1 and s["complete"] is False and s["requirement_met"] is False and s["duration_s"] < 3.0
    assert "micropython over serial" in s["error"] and "bench counters" in s["error"]
    assert "Traceback" not in err and "fps hil: error:" in err
    assert s["link"]["bench"]["command_retries"] > 0 or s["link"]["bench"].get("controller_resent", 0) > 0


def test_a_silence_is_ridden_through_and_a_permanent_one_ends_the_run(tmp_path, inputs):
    rc, out, s = _hil(tmp_path, inputs, "silence", "--link-faults", "silence=1:2", duration="4")
    assert s["complete"] and s["error"] is None
    # 2 s at 637.8 Hz: the mirror held, the clock went on; the controller never saw those 1276 ticks. Right after
    # the silence the bench gives each tick one 3 ms try until the controller answers in time: on a loaded
    # machine an answer can miss it (1277 overruns, 1 in 6 runs beside three busy loops), and that answer is
    # then dropped as late; controller_late also counts the second answers to resent TICKs.
    bench = s["link"]["bench"]
    assert s["link"]["controller"]["gap_ticks"] == 1276
    assert s["overruns"] == bench["controller_timeouts"]
    assert 1276 <= s["overruns"] <= 1276 + bench["controller_late"], (s["overruns"], bench["controller_late"])
    assert rc == (0 if s["requirement_met"] else 3)
    rc, out, s = _hil(tmp_path, inputs, "dead", "--link-faults", "silence=1:inf", "--max-failed-ticks", "500",
                      duration="4")
    assert rc == 1 and not s["complete"] and "500 consecutive ticks" in s["error"]
    z = np.load(out / "samples.npz")
    assert len(z["t_s"]) >= 630 and z["t_s"][-1] >= 1.0        # what was played before the stop is kept
    assert 1.0 < s["duration_s"] < 1.0 + 600 / 637.8              # stopped at the 500th failed tick, not at 4 s


@pytest.mark.slow(reason="~50 s under faults: FPS_SLOW=1 make test runs it")
def test_calibration_under_faults_gives_the_same_h(tmp_path):
    outs = []
    for name, extra in (("clean", []), ("faulty", ["--link-faults", "bytes=0.01,frames=0.05,seed=2"])):
        out = tmp_path / (name + ".json")
        assert fps(["calibrate", "--runtime", "micropython", "--grid", "2", "--span", "2", "--no-plots",
                    "--no-truth", "-o", str(out)] + extra) == 0
        outs.append(json.loads(out.read_text()))
    assert [p["H"] for p in outs[0]["points"]] == [p["H"] for p in outs[1]["points"]]
    assert outs[1]["link_counters"]["bench"]["controller_resent"] > 0


# --- a board on a serial port: a pty pair relayed, MicroPython running firmware.main on one end ------------
@pytest.fixture
def board():
    from tools.ptyrelay import relay_pair
    with relay_pair() as (board_path, host_path):
        env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen")
        proc = subprocess.Popen([micropython_binary(), "-m", "firmware.main", "controller", "--link",
                                 "serial:" + board_path], cwd=ROOT, env=env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        yield host_path
        proc.terminate()
        proc.wait(5)


def test_a_board_on_a_serial_port_in_lockstep_and_in_real_time(tmp_path, inputs, board):
    dist, cal = inputs
    base = ["hil", "--distfile", dist, "--calibration", cal, "--runtime", "board", "--port", board,
            "--no-plots", "--quiet"]
    assert fps(base + ["--duration", "2", "-o", str(tmp_path / "lock")]) == 0
    s = json.loads((tmp_path / "lock" / "summary.json").read_text())
    assert s["complete"] and s["overruns"] == 0 and s["requirement_met"]
    cfg = json.loads((tmp_path / "lock" / "config.json").read_text())
    assert cfg["runtime"] == "board" and cfg["port"] == board
    # the same board again (a new session: its tick numbers start over), paced by the wall clock
    rc = fps(base + ["--duration", "1", "--realtime", "-o", str(tmp_path / "rt")])
    s = json.loads((tmp_path / "rt" / "summary.json").read_text())
    assert s["complete"] and rc == (0 if s["requirement_met"] else 3)
    assert s["duration_s"] == pytest.approx(1.0, abs=0.01) and s["overruns"] < 638     # 638 ticks in 1 s
    assert fps(["hil", "--distfile", dist, "--calibration", cal, "--runtime", "board", "-o",
                str(tmp_path / "x")]) == 2                                   # no --port: bad input
