"""Edges of ``fps emulator serve`` and the ADCS session found in review: a run ended early (controller gone,
hung or SIGTERM) still leaves its partial summary, bad durations and rates are refused up front, and what the
session refuses from the firmware, or a hung firmware, is counted and ends the run."""

import json
import os

import pytest

from ground.cli import main as fps


# --- fps emulator serve: a run ended early still leaves its summary ----------------------------------------
def _serve_against(monkeypatch, controller, *args):
    """``fps emulator serve``'s link with ``controller(peer_path, *args)`` on a thread at its other end; returns
    the threads started."""
    import threading

    import protocol.link
    real_open = protocol.link.open_link
    threads = []

    def open_link(spec, node, **kw):
        link = real_open(spec, node, **kw)
        th = threading.Thread(target=controller, args=(link.peer_path,) + args, daemon=True)
        th.start()
        threads.append(th)
        return link
    monkeypatch.setattr(protocol.link, "open_link", open_link)
    return threads


def test_bench_serve_writes_a_partial_summary_when_the_controller_leaves(tmp_path, monkeypatch, capsys):
    from protocol import core
    from protocol.stream import StreamLink

    def controller(path, n):
        """HELLO, then answer n TICKs with an empty FSM_SPI (an overrun each), then leave."""
        s = StreamLink(path, "CONTROLLER")
        s.send("HELLO", "BENCH")
        done = 0
        while done < n and not s.closed:
            for pid, src, dst, seq, payload in s.recv(2000):
                if pid == core.PACKET_ID["TICK"]:
                    s.send("FSM_SPI", "BENCH", tick=core.decode_payload(pid, payload)[0], n=0)
                    done += 1
        s.close()

    peers = _serve_against(monkeypatch, controller, 20)
    out = tmp_path / "serve.json"
    assert fps(["emulator", "serve", "--duration", "5", "--deadline", "2", "--wait", "5", "-o", str(out)]) == 1
    peers[0].join(5)
    assert "link closed" in capsys.readouterr().err
    d = json.loads(out.read_text())
    assert d["complete"] is False and "closed" in d["error"]
    assert d["counters"]["ticks"] >= 20 and d["counters"]["overruns"] >= 20 and d["samples"] > 0
    assert d["packets_from_controller"] == {"HELLO": 1}


def test_bench_serve_ends_on_a_controller_that_stops_answering(tmp_path, monkeypatch, capsys):
    """A controller that is alive but silent (hung) cost --deadline per tick for the whole run, ~15 min until
    the pty filled; --max-failed-ticks consecutive overruns now end the run as a dead link (exit 1), with
    the partial summary."""
    import threading

    from protocol import core
    from protocol.stream import StreamLink
    hang = threading.Event()

    def controller(path):
        """HELLO, answer 20 TICKs with an empty FSM_SPI, then read and answer nothing until the test ends."""
        s = StreamLink(path, "CONTROLLER")
        s.send("HELLO", "BENCH")
        done = 0
        while done < 20 and not s.closed:
            for pid, src, dst, seq, payload in s.recv(2000):
                if pid == core.PACKET_ID["TICK"]:
                    s.send("FSM_SPI", "BENCH", tick=core.decode_payload(pid, payload)[0], n=0)
                    done += 1
        hang.wait(30)
        s.close()

    _serve_against(monkeypatch, controller)
    out = tmp_path / "serve.json"
    try:
        rc = fps(["emulator", "serve", "--duration", "600", "--deadline", "0.2", "--max-failed-ticks", "5",
                  "--wait", "5", "-o", str(out)])
    finally:
        hang.set()
    assert rc == 1
    assert "5 consecutive ticks" in capsys.readouterr().err
    d = json.loads(out.read_text())
    assert d["complete"] is False and "link is down" in d["error"]
    assert 24 <= d["counters"]["ticks"] <= 30                    # 20 answered, 5 failed
    assert fps(["emulator", "serve", "--max-failed-ticks", "0"]) == 2


def test_bench_serve_stopped_by_sigterm_leaves_its_partial_summary(tmp_path):
    import signal
    import subprocess
    import sys

    from protocol import core
    from protocol.stream import StreamLink
    out = tmp_path / "serve.json"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen([sys.executable, "-m", "ground.cli", "emulator", "serve", "--duration", "60",
                             "--wait", "10", "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=root, env=dict(os.environ, PYTHONPATH=root))
    try:
        s = StreamLink(proc.stdout.readline().strip(), "CONTROLLER")
        try:
            s.send("HELLO", "BENCH")
            done = 0
            while done < 50:
                for pid, src, dst, seq, payload in s.recv(5000):
                    if pid == core.PACKET_ID["TICK"]:
                        s.send("FSM_SPI", "BENCH", tick=core.decode_payload(pid, payload)[0], n=0)
                        done += 1
            proc.send_signal(signal.SIGTERM)          # a process manager stops the bench mid-run
            _, err = proc.communicate(timeout=20)
        finally:
            s.close()
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    d = json.loads(out.read_text())
    assert d["complete"] is False and d["error"] == "interrupted" and d["counters"]["ticks"] >= 40


# --- fps emulator serve: what cannot run is refused before the link opens ----------------------------------------
def test_bench_serve_refuses_a_duration_whose_samples_outgrow_the_memory(monkeypatch, capsys):
    """--duration was accepted up to 1e6 s; the bench keeps ~400 B a tick until the summary (255 GB at
    637.8 Hz), so a long soak ended hours in with MemoryError and nothing written. Refused up front now."""
    from emulator import cli
    monkeypatch.setattr(cli, "_memory_bytes", lambda: 1e9)       # a 1 GB machine: at most ~3,100 s
    assert fps(["emulator", "serve", "--duration", "4000"]) == 2
    err = capsys.readouterr().err
    assert "--duration 4000 s" in err and "at most 3136 s" in err
    assert fps(["emulator", "serve", "--duration", "3000", "--wait", "0"]) == 1   # within: on to the link
    assert "no controller spoke" in capsys.readouterr().err
    assert fps(["emulator", "serve", "--rate", "1e6"]) == 2      # no --duration: its 10 s (was a TypeError)
    assert "--duration 10 s at 1e+06 Hz" in capsys.readouterr().err


def test_wheels_serve_refuses_more_star_tracker_packets_than_physics_steps(capsys):
    """At 20 Hz with 0.1 s steps the loop sent ~2 packets a step, repeating the same attitude and time, not 20."""
    assert fps(["emulator", "serve", "--devices", "wheels", "--dt", "0.1", "--startracker-hz", "20",
                "--wait", "0"]) == 2
    assert "--startracker-hz 20" in capsys.readouterr().err
    assert fps(["emulator", "serve", "--devices", "wheels", "--dt", "0.1", "--startracker-hz", "10",
                "--wait", "0"]) == 1                  # allowed: it gets as far as waiting for the flight computer


@pytest.mark.parametrize("rate, says", [("1000", "1203.0 us"), ("20000", "P-FSM's update rate")])
def test_bench_serve_refuses_a_rate_before_printing_a_device_path(rate, says, capsys):
    assert fps(["emulator", "serve", "--rate", rate, "--wait", "0"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "waiting" not in err and says in err


# --- the ADCS session: what it refuses from the firmware is counted; a hung firmware ends it ---------------------
def test_adcs_session_counts_rw_cmds_it_refuses():
    import struct
    import time

    from emulator.adcs_session import AdcsSession
    from protocol import core
    P, N = core.PACKET_ID, core.NODE

    class Link:
        node, closed = N["SPACECRAFT"], False

        def __init__(self):
            self.queue, self.sent = [], []

        def recv(self, timeout=None):
            out, self.queue = self.queue, []
            return out

        def send_raw(self, pid, src, dst, payload):
            self.sent.append(pid)

        def counters(self):
            return {}

    class Proc:
        pid = 0

        def poll(self):
            return None

    s = AdcsSession(runtime="cpython", duration_s=2)
    s.link, s.proc, s._t_wall = Link(), Proc(), time.perf_counter()
    s._burst()
    fmt = core.PACKET[P["RW_CMD"]].fmt
    cmds = [struct.pack(fmt, float("nan"), 1, 0), struct.pack(fmt, 1e-4, 2, 0), struct.pack(fmt, 2.0 ** -12, 1, 0),
            struct.pack(fmt, -2.0 ** -12, 0, 0)]          # of cycle 0
    s.link.queue = [(P["RW_CMD"], N["ADCS"], N["RW%d" % i], None, c) for i, c in enumerate(cmds)]
    s.link.queue.append((P["ADCS_STATUS"], N["ADCS"], 0xFF, None, core.encode_payload("ADCS_STATUS", tick=0)))
    s.cycle()
    assert s.summary()["refused_rw_cmd"] == [1, 1, 0, 0] and s.summary()["missed_rw_cmd"] == [0, 0, 0, 0]
    assert list(s.wheels.cmd) == [0.0, 0.0, 2.0 ** -12, -2.0 ** -12]
    assert list(s.wheels.enable) == [True, True, True, False]


def test_adcs_session_ends_when_the_firmware_is_hung():
    """Alive but silent: each cycle waited reply_timeout_s (30 s) for ever, and the unread bursts filled the pty."""
    import time

    from emulator import adcs_session
    from protocol import core

    class Link:
        node, closed = core.NODE["SPACECRAFT"], False

        def recv(self, timeout=None):
            time.sleep(min(timeout or 0.0, 0.01))
            return []

        def send_raw(self, pid, src, dst, payload):
            pass

        def counters(self):
            return {}

    class Proc:                              # emulator.launcher.FirmwareProcess's interface, as used here
        def poll(self):
            return None

        def stderr_tail(self, n_chars=2000):
            return ""

    s = adcs_session.AdcsSession(runtime="cpython", duration_s=10, reply_timeout_s=0.03)
    s.link, s.proc, s._t_wall = Link(), Proc(), time.perf_counter()
    s._burst()
    for _ in range(adcs_session.MAX_LATE_CYCLES - 1):
        s.cycle()                                                   # a late cycle or two: the wheels hold
    with pytest.raises(OSError, match="%d cycles in a row" % adcs_session.MAX_LATE_CYCLES):
        s.cycle()
    assert s.summary()["late_cycles"] == adcs_session.MAX_LATE_CYCLES and s.k == adcs_session.MAX_LATE_CYCLES - 1


def test_bench_serve_says_hello_until_a_controller_whose_own_hello_was_lost_answers(tmp_path, monkeypatch):
    """A controller whose first HELLO never arrived (it does not say it again; it answers each HELLO with its
    own, as the firmware does): the bench's HELLOs reach it and the run completes."""
    from protocol import core
    from protocol.stream import StreamLink

    def controller(path):
        s = StreamLink(path, "CONTROLLER")
        while not s.closed:
            for pid, src, dst, seq, payload in s.recv(200):
                if pid == core.PACKET_ID["HELLO"]:
                    s.send("HELLO", "BENCH", node=core.NODE["CONTROLLER"])
                elif pid == core.PACKET_ID["TICK"]:
                    s.send("FSM_SPI", "BENCH", tick=core.decode_payload(pid, payload)[0], n=0)

    _serve_against(monkeypatch, controller)
    out = tmp_path / "serve.json"
    assert fps(["emulator", "serve", "--duration", "0.2", "--deadline", "0.5", "--wait", "5", "-o", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["complete"] is True and d["hello_tries"] >= 1 and d["packets_from_controller"]["HELLO"] >= 1
    assert d["counters"]["ticks"] > 100
