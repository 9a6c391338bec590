"""Edges of protocol/ and emulator/ found in review: files, bad input, the packet table as the one contract."""

import json
import os
import stat

import pytest

from emulator.fileio import write_json
from ground.cli import main as fps


# --- files people keep: written atomically with the umask's permissions -----------------------------------
def test_dbc_and_emulator_json_get_the_umask_not_mkstemps_0600(tmp_path):
    old = os.umask(0o022)
    try:
        assert fps(["protocol", "dbc", "-o", str(tmp_path / "fps.dbc")]) == 0
        write_json(str(tmp_path / "summary.json"), {"complete": True}, make_folder=False)
    finally:
        os.umask(old)
    for name in ("fps.dbc", "summary.json"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644, name
    assert json.loads((tmp_path / "summary.json").read_text()) == {"complete": True}
    assert sorted(os.listdir(tmp_path)) == ["fps.dbc", "summary.json"]      # no temp files left


def test_emulator_json_writer_fsyncs_before_the_rename(tmp_path, monkeypatch):
    p = tmp_path / "truth.json"
    write_json(str(p), {"old": 1}, make_folder=False)

    def fsync(fd):
        raise KeyboardInterrupt       # the machine stops between write and rename
    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(KeyboardInterrupt):
        write_json(str(p), {"new": 2}, make_folder=False)
    assert json.loads(p.read_text()) == {"old": 1} and os.listdir(tmp_path) == ["truth.json"]


# --- the packet table is the one contract ----------------------------------------------------------------
def test_gnss_payload_takes_its_scales_from_the_table(monkeypatch):
    from emulator import adcs_bus
    from protocol import core
    pkt = core.PACKET[core.PACKET_ID["GNSS"]]
    z = (6878137.255, -1234.5678, 42.0, 7612.3456, -0.12345, 0.0)
    names = ("x", "y", "z", "vx", "vy", "vz")
    d = core.payload_dict(pkt.id, adcs_bus.gnss_payload(5, 1, z))
    scale = dict((f[0], f[3]) for f in pkt.fields)
    assert (d["t_ms"], d["sat"]) == (5, 1)
    assert all(abs(d[n] * scale[n] - v) <= 0.5 * scale[n] for n, v in zip(names, z))
    # a table with other scales (cm -> dm, 0.1 mm/s -> mm/s): the emulator follows it, it does not restate it
    other = tuple(f[:3] + ({"m": 0.1, "m/s": 1e-3}[f[2]],) + f[4:] if f[0] in names else f for f in pkt.fields)
    monkeypatch.setattr(pkt, "fields", other)
    d = core.payload_dict(pkt.id, adcs_bus.gnss_payload(5, 1, z))
    assert [d[n] for n in names] == [68781373, -12346, 420, 7612346, -123, 0]


def test_remote_controller_counts_wrong_length_answers_instead_of_raising():
    """A link that does not check payload lengths (a test double, a new transport) hands over a short FSM_SPI
    and CTRL_STATUS: counted as bad, neither applied nor passed to the ground."""
    from emulator.lockstep import RemoteController
    from protocol import core
    rc = RemoteController(link=None)
    spi, status = core.PACKET_ID["FSM_SPI"], core.PACKET_ID["CTRL_STATUS"]
    good = core.encode_payload(spi, tick=7, n=1, w0=0x123456)
    rc._pending.extend([(spi, 0x10, 0x20, 0, good[:-1]), (status, 0x10, 0x01, 1, bytes(8)),
                        (spi, 0x10, 0x20, 2, good)])
    words, got_status = rc._sort(7)
    assert words == [0x123456] and not got_status
    assert rc.n_bad == 2 and len(rc.inbox) == 0


# --- distfile and H-table blobs: what float32 cannot hold is refused by name ------------------------------
@pytest.mark.parametrize("kw, what", [
    (dict(xs=[1e39, 0.0], ys=[0.0, 0.0]), "sample 0"),
    (dict(xs=[0.0, 0.0], ys=[0.0, -1e39]), "sample 1"),
    (dict(xs=[1.0, 0.0], ys=[0.0, 0.0], kind=0, scale=1e-50), "scale"),
    (dict(xs=[1.0, 0.0], ys=[0.0, 0.0], kind=0, scale=1e39), "scale"),
])
def test_distfile_pack_refuses_what_float32_cannot_hold(kw, what):
    from protocol import distfile
    with pytest.raises(distfile.DistfileError, match=what):
        distfile.pack(**kw)


def test_htable_pack_refuses_an_h_beyond_float32():
    from protocol import htable
    with pytest.raises(htable.HTableError, match="float32"):
        htable.pack(htable.Grid([0.0, 1.0], [0.0, 1.0], [(1e39, 0.0, 0.0, 1.0)] + [(1.0, 0.0, 0.0, 1.0)] * 3))


# --- bench config files --------------------------------------------------------------------------------------
def test_bench_config_with_a_huge_integer_is_bad_input_not_an_internal_error(tmp_path, capsys):
    p = tmp_path / "bench.json"
    p.write_text('{"laser": {"power_w": 1%s}}' % ("0" * 400))       # valid JSON, an int no float can hold
    assert fps(["emulator", "config", "--config", str(p)]) == 2
    err = capsys.readouterr().err
    assert "laser.power_w" in err and "internal error" not in err


# --- slcan device (fps emulator serve --link can): Lawicel lines parsed exactly --------------------------------
def test_slcan_device_refuses_malformed_lawicel_lines(tmp_path):
    import select
    import time
    import tty
    from protocol import can as canmap
    from protocol import core, link
    dev = link.open_slcan_device("SPACECRAFT")
    fd = os.open(dev.peer_path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)

    def line(text):
        os.write(fd, text.encode() + b"\r")
        out, end = b"", time.monotonic() + 2.0
        while not out.endswith((b"\r", b"\a")) and time.monotonic() < end:
            if select.select([fd], [], [], 0.05)[0]:
                out += os.read(fd, 256)
        return out

    try:
        assert line("O") == b"\r"
        payload = core.encode_payload("ACK", ref_id=0x45, ref_seq=3)
        [(cid, data)] = canmap.encode_frames(core.PACKET_ID["ACK"], core.NODE["ADCS"], core.NODE["SPACECRAFT"],
                                             payload)
        pl, n = data.hex().upper(), len(data)
        for bad in ("T%08X9%s00" % (cid, pl + "00" * (8 - n)),   # DLC 9: not classic CAN
                    "T%08XF%s" % (cid, pl + "00" * 11),           # DLC F
                    "T%08X%d%s00" % (cid, n, pl),                 # a data byte beyond the DLC
                    "T%08X%d%s" % (cid, n, pl[:-2]),              # one short
                    "T-%07X%d%s" % (cid, n, pl),                  # a sign in the id
                    "T %07X%d%s" % (cid, n, pl),                  # a space in the id
                    "T%08X%d%s" % (0x3FFFFFFF, n, pl),            # beyond 29 bits
                    "t800%d%s" % (n, pl),                         # beyond 11 bits
                    "T%08X%d%sG" % (cid, n, pl[:-1]),             # a non-hex digit
                    "Q12"):                                       # an unknown command
            assert line(bad) == b"\a", bad
        assert dev.recv(0.05) == []
        d = dev.counters()
        assert (d["slcan_overlong"], d["slcan_bad_length"], d["slcan_non_hex"], d["slcan_unknown_command"]) \
            == (2, 2, 5, 1)     # a DLC 9 or F line's data runs past the longest classic line
        assert line("T%08X%d%s" % (cid, n, pl)) == b"Z\r"
        assert dev.recv(2.0) == [(core.PACKET_ID["ACK"], core.NODE["ADCS"], core.NODE["SPACECRAFT"], None,
                                  payload)]
        assert dev.counters()["frames"] == 1 and dev.counters()["reserved_bit"] == 0
        os.write(fd, b"T" * 100000)        # no CR: dropped in a fixed buffer, answered once
        out, end = b"", time.monotonic() + 5.0
        while time.monotonic() < end and not out:
            if select.select([fd], [], [], 0.05)[0]:
                out += os.read(fd, 256)
        assert out == b"\a" and dev.counters()["slcan_overlong"] == 3
        os.write(fd, b"%08X%d%s\r" % (cid, n, pl.encode()))  # the overlong line's end: dropped, unanswered
        assert line("T%08X%d%s" % (cid, n, pl)) == b"Z\r" and len(dev.recv(2.0)) == 1
    finally:
        os.close(fd)
        dev.close()


# --- the orbit truth cache -----------------------------------------------------------------------------------
def test_a_damaged_orbit_truth_cache_is_computed_again_not_trusted_or_fatal(tmp_path):
    import io

    import numpy as np

    from emulator import orbits
    t, x = orbits.truth_samples("two-body", 20.0, cache_dir=str(tmp_path))
    (path,) = [os.path.join(tmp_path, "truth_cache", n) for n in os.listdir(tmp_path / "truth_cache")]
    short = io.BytesIO()
    np.savez(short, t=t[:5], x=x[:5])
    for damage in (b"", b"not a zip file", short.getvalue()):
        with open(path, "wb") as f:
            f.write(damage)
        t2, x2 = orbits.truth_samples("two-body", 20.0, cache_dir=str(tmp_path))
        assert np.array_equal(t2, t) and np.array_equal(x2, x)
        with np.load(path) as z:                      # and the file is whole again
            assert z["x"].shape == x.shape


def test_emulator_readme_names_every_module_and_the_default_board_timing():
    import re
    root = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "emulator")
    text = open(os.path.join(root, "README.md")).read()
    listed = set(re.findall(r"^\| `(\w+\.py)` \|", text, re.M))
    assert {n for n in os.listdir(root) if n.endswith(".py") and n != "__init__.py"} <= listed
    from emulator.config import default_config
    from emulator.timing import board_timing
    t = board_timing(default_config()).as_dict()
    assert t["timing"] in text and "%.0f us" % t["land_us"] in text
    assert "%.0f, %.0f and %.0f us" % tuple(t["sample_us"]) in text


# --- fps protocol decode: one strict JSON line per packet ----------------------------------------------------
def test_decode_writes_strict_json_for_non_finite_float_fields(tmp_path, capsys):
    import struct

    from protocol import core, host
    pid = core.PACKET_ID["RW_TLM"]
    cap = tmp_path / "cap.bin"
    cap.write_bytes(host.encode_frame(pid, 0x40, 0x30, 0, struct.pack("<ff", float("nan"), float("-inf")))
                    + host.encode_frame(pid, 0x40, 0x30, 1, struct.pack("<ff", 1.5, 0.0)))
    assert fps(["protocol", "decode", "--serial", str(cap)]) == 0

    def refuse(name):
        raise ValueError("not JSON: %s" % name)
    lines = [json.loads(ln, parse_constant=refuse) for ln in capsys.readouterr().out.splitlines()]
    assert [ln["fields"] for ln in lines[:2]] == [{"speed": "nan", "torque": "-inf"}, {"speed": 1.5, "torque": 0.0}]
    assert lines[2]["summary"]["frames"] == 2


# --- fps emulator serve: a run ended early still leaves its summary ----------------------------------------
def test_bench_serve_writes_a_partial_summary_when_the_controller_leaves(tmp_path, monkeypatch, capsys):
    import threading

    import protocol.link
    from protocol import core
    from protocol.stream import StreamLink
    real_open = protocol.link.open_link
    peers = []

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

    def open_link(spec, node, **kw):
        link = real_open(spec, node, **kw)
        th = threading.Thread(target=controller, args=(link.peer_path, 20), daemon=True)
        th.start()
        peers.append(th)
        return link
    monkeypatch.setattr(protocol.link, "open_link", open_link)
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

    import protocol.link
    from protocol import core
    from protocol.stream import StreamLink
    real_open = protocol.link.open_link
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

    def open_link(spec, node, **kw):
        link = real_open(spec, node, **kw)
        threading.Thread(target=controller, args=(link.peer_path,), daemon=True).start()
        return link
    monkeypatch.setattr(protocol.link, "open_link", open_link)
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


# --- link specs: python-can's errors become the project's ValueError / OSError ----------------------------
def test_can_link_spec_errors_are_value_or_os_errors(tmp_path, capsys):
    from firmware import main as fw_main
    from protocol.link import open_link
    with pytest.raises(ValueError, match="bogus"):
        open_link("can:bogus:x", "GROUND")
    with pytest.raises(OSError, match="nonexistent"):
        open_link("slcan:%s" % (tmp_path / "nonexistent"), "GROUND")
    assert fw_main.main(["controller", "--link", "slcan:%s" % (tmp_path / "nonexistent")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "nonexistent" in err


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


# --- --link-faults with a vanishing bit-flip probability -----------------------------------------------------
@pytest.mark.parametrize("p", ["1e-17", "1e-320"])
def test_link_faults_with_a_tiny_byte_probability_pass_frames_unharmed(p):
    from protocol import host
    from protocol.faults import FaultyPort, LinkFaults

    class Port:
        def __init__(self):
            self.sent = b""

        def write(self, data):
            self.sent += data
    port = Port()
    fp = FaultyPort(port, LinkFaults.parse("bytes=%s,seed=3" % p))     # ZeroDivisionError before
    frame = host.encode_packet("HELLO", 1, 0x10)
    fp.write(frame * 3)
    assert port.sent == frame * 3 and fp.counters()["fault_tx_bits_flipped"] == 0


# --- a pty peer that is alive but reads nothing (hung firmware) ---------------------------------------------
def test_a_pty_peer_that_stops_reading_closes_the_link_instead_of_blocking_the_writer(monkeypatch):
    import threading
    import tty

    from protocol import fdport
    from protocol import link as hostlink
    monkeypatch.setattr(fdport, "STALL_S", 0.3)
    lk = hostlink.open_link("pty", "BENCH")
    fd = os.open(lk.peer_path, os.O_RDWR | os.O_NOCTTY)      # the peer: open, says one byte, never reads
    tty.setraw(fd)
    try:
        os.write(fd, b"\x00")
        lk.recv(0.5)
        sent = []

        def writer():
            while not lk.closed and len(sent) < 100000:
                sent.append(lk.send("TICK", "CONTROLLER", tick=len(sent)))
        th = threading.Thread(target=writer, daemon=True)
        th.start()
        th.join(10.0)
        assert not th.is_alive(), "the writer blocked for ever on a full pty"
        assert lk.closed and "read nothing" in lk.closed_why and 100 < len(sent) < 100000
    finally:
        os.close(fd)
        lk.close()


# --- the ADCS session: what it refuses from the firmware is counted ------------------------------------------
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


# --- ISO-TP: every drop counted ------------------------------------------------------------------------------
def test_isotp_counts_a_transfer_cut_short_by_a_new_first_frame():
    from protocol import isotp
    a, b = bytes(range(20)), bytes(range(100, 130))
    fa, fb = isotp.segment(a), isotp.segment(b)
    rx = isotp.IsoTp()
    assert rx.feed(fa[0]) is None and rx.feed(fa[1]) is None          # a: FF and one CF, then cut off
    got = [rx.feed(f) for f in fb]
    assert got[-1] == b and rx.errors["unexpected_cf"] == 1           # a's loss is counted, as a SF's cut is
    assert sum(rx.errors.values()) == 1


# --- CAN: an ISO-TP send the receiver refuses is not reported as sent ----------------------------------------
def test_can_isotp_send_refused_by_overflow_flow_control_is_tried_again_then_lost():
    """An overflow answer is a failed try (a damaged flow control frame can say overflow: they carry no check):
    the packet is sent again, and counted lost after the link's tries, never reported sent and never raised."""
    import threading

    import can

    from protocol import can as canmap
    from protocol.link import open_link
    lk = open_link("can:virtual:fps-edges-overflow", "BENCH", isotp_timeout_s=0.2, isotp_tries=3)
    raw = can.Bus(interface="virtual", channel="fps-edges-overflow")
    firsts = []

    def receiver():                       # answers every first frame with FC overflow (status 2)
        while len(firsts) < 3:
            m = raw.recv(2.0)
            if m is None:
                return
            firsts.append(m)
            raw.send(can.Message(arbitration_id=canmap.reply_id(m.arbitration_id), data=bytes((0x32, 0, 0)),
                                 is_extended_id=True))
    th = threading.Thread(target=receiver)
    th.start()
    try:
        lk.send("TICK", "CONTROLLER", tick=1)          # 14 bytes + check: ISO-TP
        c = lk.counters()
        assert lk.last_sent is False and c["tx_frames"] == 0
        assert c["isotp_OverflowError"] == 3 and c["tx_isotp_resent"] == 2 and c["tx_isotp_failed"] == 1
        assert len(firsts) == 3 and all(m.data[0] >> 4 == 1 for m in firsts)     # three first frames
    finally:
        th.join(3)
        raw.shutdown()
        lk.close()


def test_can_link_makes_no_isotp_stack_for_ids_outside_the_table():
    """CanLink made a can-isotp stack (kept for good) for every ISO-TP id addressed to it: a bus carrying
    garbage ids (any packet id, any source) piled up to 65,536 of them per node. An id whose packet or source
    the table does not name is now dropped as unknown_id; a real transfer still arrives."""
    import can

    from protocol import can as canmap
    from protocol import core
    from protocol.link import open_link
    lk = open_link("can:virtual:fps-edges-stacks", "CONTROLLER")
    raw = can.Bus(interface="virtual", channel="fps-edges-stacks")
    try:
        me = core.NODE["CONTROLLER"]
        bad_pid = next(p for p in range(256) if p not in core.PACKET)
        bad_src = next(n for n in range(256) if n not in core.NODE_NAME)
        ids = [canmap.can_id(bad_pid, src, me, True) for src in range(200)]
        ids += [canmap.can_id(core.PACKET_ID["TICK"], bad_src, me, True)]
        for cid in ids:
            raw.send(can.Message(arbitration_id=cid, data=bytes((0x10, 14, 0, 0, 0, 0, 0, 0)),
                                 is_extended_id=True))           # an ISO-TP first frame
        sender = open_link("can:virtual:fps-edges-stacks", "BENCH")
        try:
            sender.send("TICK", "CONTROLLER", tick=7)              # 14 bytes: ISO-TP
        finally:
            sender.close()
        got = lk.recv(3.0)
        assert [core.decode_payload(p[0], p[4])[0] for p in got] == [7]
        assert lk.counters()["unknown_id"] == len(ids) and len(lk._stacks) == 1
    finally:
        raw.shutdown()
        lk.close()


ISOTP_STRAY_CF = """
import time
import can
from protocol import can as canmap
from protocol import core
from protocol.link import open_link
lk = open_link("can:virtual:x", "CONTROLLER")
raw = can.Bus(interface="virtual", channel="x")
cid = canmap.can_id(core.PACKET_ID["TICK"], core.NODE["BENCH"], core.NODE["CONTROLLER"], True)
raw.send(can.Message(arbitration_id=cid, data=bytes((0x21, 1, 2, 3, 4, 5, 6, 7)), is_extended_id=True))
end = time.monotonic() + 5.0
n = 0
while not n and time.monotonic() < end:
    time.sleep(0.01)
    n = sum(v for k, v in lk.counters().items() if k.startswith("isotp_"))
raw.shutdown()
lk.close()
print(n)
"""


def test_isotp_errors_are_counted_not_printed():
    """A consecutive frame with no first frame before it: can-isotp's error is counted in the link's
    isotp_* counters; it was also printed on stderr by Python's last-resort logging handler (a process that
    configures no logging, as fps does not). Run in a subprocess: pytest's own log capture hides it."""
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-c", ISOTP_STRAY_CF], capture_output=True, text=True, timeout=60,
                       cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert r.returncode == 0 and r.stdout.split() == ["1"], r.stderr
    assert r.stderr == ""


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
