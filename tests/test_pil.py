"""Processor in the loop, first part: the controller firmware frozen into MicroPython's qemu port for a Cortex-M0
(``make pil``, tools/pil_build.py) runs on QEMU's microbit machine, and its viper law, compiled for ARMv6-M,
clocks out the same AD5664R words as the bytecode controller on the host, bit for bit; its instructions per
control step are counted under ``-icount``; and the lean ADCS on its Cortex-M7 board (QEMU's mps2-an500, an FPU,
the C kernels built in) replays a recorded session as the unix port does. Skipped, saying why, where the images are
not built."""

import json
import os
import sys

import pytest

from firmware.controller import TRACK, Controller
from tools import pil_board, pil_build
from protocol import consts, htable

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
import firmware_plant as fp  # noqa: E402

needs_image = pytest.mark.skipif(
    not (os.path.exists(pil_build.IMAGE) and os.path.exists(pil_build.LAB_IMAGE)) or bool(pil_build.missing_tools()),
    reason="no PIL image (make pil; it needs %s)" % pil_build.install_hint(pil_build.PACKAGES))


def _fps(*args, timeout=900):
    import subprocess
    p = subprocess.run([sys.executable, "-m", "ground.cli"] + list(args), cwd=ROOT, capture_output=True, text=True,
                       timeout=timeout)
    assert p.returncode == 0, p.stderr[-3000:]
    return p


def _table():
    return htable.grid_from_calibration(fp.calibration())


def _samples(n):
    """Q1 samples of a closed loop on the host (the plant in double precision), as ints."""
    c = Controller(table=_table(), safe_ticks=65535)
    p = fp.Plant(seed=5)
    src = []
    c.step(2048, 2048, 0)
    c.mode = TRACK
    for k in range(n):
        s = p.sample()
        src.extend(int(v) for v in s)
        p.apply(c.on_tick(k, 0, s[0], s[1], s[2]))
    return src


def _host(blob, src):
    """The bytecode controller on the host over the same replay: the board's ``pil_probe.replay`` figures."""
    from binascii import crc32
    c = Controller(table=htable.parse(blob), safe_ticks=65535)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    t = c.table
    tab = crc32(bytes(str([t.nx, t.ny] + list(t.ax) + list(t.ay) + list(t.rdx) + list(t.rdy) + list(t.h)),
                      "ascii"))
    crc = 0
    for k in range(len(src) // 3):
        c.step(src[3 * k], src[3 * k + 1], src[3 * k + 2])
        for w in c.words:
            crc = crc32(bytes([w >> 16, (w >> 8) & 0xFF, w & 0xFF]), crc)
    return {"crc": crc & 0xFFFFFFFF, "words": list(c.words), "table_crc": tab & 0xFFFFFFFF, "mode": c.mode}


@pytest.fixture
def board():
    """A lab board for one test: stopped after it (an idle QEMU board spins a core at ~75 %, which slowed the
    tests after it in the module two-fold)."""
    with pil_board.Board() as b:
        yield b


@needs_image
def test_the_image_boots_on_the_cortex_m0_machine(board):
    assert b"microbit with nRF51" in board.banner
    assert board.run("import sys\nprint(sys.implementation._mpy & 0xff, sys.platform)").split() == ["6", "qemu"]


@needs_image
def test_viper_and_bytecode_on_the_board_clock_out_the_hosts_words(board):
    blob = htable.pack(_table())
    src = _samples(600)
    host = _host(blob, src)
    from array import array
    board.run("import gc, json, pil_probe\nfrom array import array\nb = bytes.fromhex(%r)\n"
              "s = array('H', bytes.fromhex(%r))\ngc.collect()" % (blob.hex(), array("H", src).tobytes().hex()))
    viper, byte = (json.loads(board.run("print(json.dumps(pil_probe.replay(b, s, %s)))\ngc.collect()" % v)
                              .strip().splitlines()[-1]) for v in ("True", "False"))
    for r in (viper, byte):
        assert r["table_crc"] == host["table_crc"]              # H^-1 per grid point: the same integers
        assert (r["crc"], r["words"], r["mode"]) == (host["crc"], host["words"], host["mode"])
    # instructions per step, counted by the nRF51's TIMER0 under -icount (one instruction a virtual ns)
    assert 1000 < viper["insn_per_step_with_crc"] < byte["insn_per_step_with_crc"]


def test_tilt_voltage_conversions_are_exact_integer_rounding():
    """The controller's uV <-> Q8 code conversions are the exact ratio 2^25 / 10^7 rounded half away from zero, in
    integers: the same on every port (a single-precision float on the Cortex-M0 port was 1 uV off)."""
    from fractions import Fraction
    from firmware import controller as c

    def exact(num, den, v):
        f = Fraction(abs(v) * num, den)
        r = int(f + Fraction(1, 2))
        return r if v >= 0 else -r
    for v in list(range(-3000, 3001)) + [-2500000, 2500000, 78125, -78125, 131072 * 3, -131072 * 5]:
        assert c._q8(v) == exact(1 << 25, 10 ** 7, v)
        assert c._uv(v) == exact(10 ** 7, 1 << 25, v)
    assert c._uv(131072) == 39063 and c._uv(-131072) == -39063          # a tie: 39062.5 rounds away from zero


def test_the_stdio_link_frames_and_reads_back_packets():
    """firmware.hal.stdio: what it writes, a peer's decoder reads; what a peer writes, it returns packet by packet
    (blocking reads of one byte), and an ended input closes it."""
    import io
    from protocol import core
    from firmware.hal.stdio import StdioLink
    w = io.BytesIO()
    enc = core.Encoder()
    frames = b"".join(bytes(enc.frame(core.PACKET_ID["TICK"], core.NODE["BENCH"], core.NODE["CONTROLLER"], k,
                                core.encode_payload("TICK", tick=k, vx=2048, vy=2048, vs=1500))) for k in range(3))
    lk = StdioLink(consts.NODE_CONTROLLER, reader=io.BytesIO(frames), writer=w)
    got = [lk.recv_ms(100) for _ in range(3)]
    assert [g[0][4][:4] for g in got] == [core.encode_payload("TICK", tick=k, vx=2048, vy=2048, vs=1500)[:4]
                                          for k in range(3)]
    assert lk.recv_ms(100) == [] and lk.closed
    lk.send_raw(core.PACKET_ID["HELLO"], lk.node, 0xFF, core.encode_payload("HELLO", node=lk.node))
    out = core.Decoder().feed(w.getvalue())
    assert [p[0] for p in out] == [core.PACKET_ID["HELLO"]] and lk.counters()["tx_frames"] == 1


def test_the_stdio_link_decodes_and_counts_as_the_protocols_decoder():
    """firmware.hal.stdio frames with protocol.fast, not protocol.frame: over frames with every kind of damage, its
    packets and counters are protocol.frame.Decoder's, its frames protocol.frame.Encoder's bytes."""
    import io
    from protocol import core, frame
    from firmware.hal import stdio

    def body(pid, payload, seq, src=consts.NODE_BENCH, version=consts.PROTOCOL_VERSION):
        b = bytes((version, pid, src, consts.NODE_CONTROLLER, seq)) + payload
        return b + frame.crc16(b).to_bytes(2, "big")

    tick = core.encode_payload("TICK", tick=1, vx=2048, vy=2048, vs=1500)
    good = [frame.cobs_encode(body(consts.P_TICK, tick, k)) for k in (0, 1, 4, 4, 9)]   # a gap, a repeat
    bad = [b"\x05\x01\x02", frame.cobs_encode(b"\x01\x10"),                           # bad COBS, too short
           frame.cobs_encode(body(consts.P_TICK, tick, 10)[:-1] + b"\x00"),            # bad CRC
           frame.cobs_encode(body(0x7F, tick, 11)), frame.cobs_encode(body(consts.P_TICK, tick[:-1], 12)),
           frame.cobs_encode(body(consts.P_TICK, tick, 13, version=9)), b"\x01" * (stdio._MAX_FRAME + 1)]
    frames = good[:2] + bad + [b""] + good[2:] + [frame.cobs_encode(body(consts.P_HELLO, bytes(6), 3, src=1))]
    wire = b"".join(f + b"\x00" for f in frames)
    lk = stdio.StdioLink(consts.NODE_CONTROLLER, reader=io.BytesIO(wire), writer=io.BytesIO())
    got = []
    while not lk.closed:
        got += lk.recv_ms(100)
    dec = frame.Decoder(max_frame=stdio._MAX_FRAME)
    assert got == dec.feed(wire) and len(got) == 6
    c = lk.counters()
    assert c.pop("tx_frames") == 0 and c == dec.counters() and lk.rx_drops() == dec.dropped() == 7
    assert c["seq_gaps"] == 6 and c["seq_dups"] == 1 and all(c[r] == 1 for r in frame.DROP_REASONS)
    assert stdio._DROPS == frame.DROP_REASONS and stdio._MAX_FRAME == frame.frame_bytes(consts.LARGEST_PAYLOAD)
    w = io.BytesIO()
    lk = stdio.StdioLink(consts.NODE_CONTROLLER, writer=w)
    lk.send_raw(consts.P_CTRL_SET_FSM, lk.node, 1, bytes(8), seq=300)
    assert w.getvalue() == bytes(frame.Encoder(consts.LARGEST_PAYLOAD).frame(consts.P_CTRL_SET_FSM, lk.node, 1, 300,
                                                                             bytes(8)))
    with pytest.raises(ValueError, match="payload is 97 bytes > 96"):
        lk.send_raw(consts.P_CTRL_SET_FSM, lk.node, 1, bytes(97))


@needs_image
def test_fps_hil_and_calibrate_on_the_qemu_board_are_the_micropython_runs_bit_for_bit(tmp_path):
    """The goal: a 20 s fps hil --runtime qemu gives the Q2 samples and the control telemetry of
    --runtime micropython bit for bit (the controller is integer arithmetic; of the telemetry, the link's own
    counters of resent TICKs may differ on a loaded machine), and fps calibrate the same points; its real-time
    factor is reported."""
    import numpy as np
    fps = _fps
    dist = str(tmp_path / "d.dist")
    fps("distfile", "generate", "--source", "stat", "--duration", "20", "--seed", "1", "-o", dist)
    cal = {}
    for r in ("qemu", "micropython"):
        cal[r] = str(tmp_path / ("cal_%s.json" % r))
        fps("calibrate", "--runtime", r, "--grid", "3", "-o", cal[r])
    a, b = (json.load(open(cal[r])) for r in ("qemu", "micropython"))
    assert a["points"] == b["points"] and a["runtime"] == "qemu"
    for r in ("qemu", "micropython"):
        fps("hil", "--distfile", dist, "--calibration", cal["micropython"], "--duration", "20", "--runtime", r,
            "--quiet", "--no-plots", "-o", str(tmp_path / r))
    x, y = (np.load(tmp_path / r / "samples.npz") for r in ("qemu", "micropython"))
    assert x.files == y.files and all(np.array_equal(x[k], y[k]) for k in x.files)
    import csv
    tq, tm = (list(csv.DictReader(open(tmp_path / r / "telemetry.csv"))) for r in ("qemu", "micropython"))
    link = ("n_dup", "n_rx_drop")           # the link's counters: TICKs resent when QEMU answered late
    assert len(tq) == len(tm) > 100
    assert [{k: v for k, v in r.items() if k not in link} for r in tq] == \
        [{k: v for k, v in r.items() if k not in link} for r in tm]
    s = json.load(open(tmp_path / "qemu" / "summary.json"))
    assert s["real_time_factor"] > 0 and s["complete"]
    # the board's own figures, read from its RAM after the run (tools.pil_board.read_target): the thesis's 32 KB,
    # the heap and the stack's high-water within it, and the TICK exchanges counted one for one
    t, ips = s["target"], s["instructions_per_step"]
    assert t["ram_bytes"] == 32768 and "Cortex-M0" in t["core"]
    assert 1000 < t["stack_high_water_bytes"] < t["stack_bytes"]
    assert t["heap_bytes"] + t["stack_high_water_bytes"] <= 32 * 1024 - 1024       # MicroPython's own ~0.8 KB
    assert ips["n"] > 12000 and 0 < ips["mean"] <= ips["max"], ips          # 20 s at 637.8 Hz: 12,756 ticks
    k = ips["kinds"]                  # each kind apart (tools.pil_mailbox); a resend in no total
    assert sum(v["n"] for name, v in k.items() if name != "resend") == ips["n"]
    assert abs(k["status"]["n"] - ips["n"] / 64) <= ips["n"] / 640 and k["bin_change"]["n"] > 0    # every 64th
    assert k["status"]["max"] == ips["max"] and sum(c for _, _, c in k["common"]["histogram"]) == k["common"]["n"]
    # the board's meter laid every tick on the wire (firmware.pil_main.Meter.wire); its worst is within the bound
    # the host's model (tools.pil_wire) gives for the run's worst figures in a row, and above any one tick's bytes
    from tools import pil_wire
    b = t["wire"]["board"]
    assert b["ticks"] == ips["n"] and b["baud"] == 2000000
    sec = 1.6 / 48e6
    bound, _ = pil_wire.schedule(pil_wire.worst_sequence(ips["common"]["max"] * sec, k["status"]["max"] * sec),
                                 b["baud"], 1 / 637.8)
    assert (23 + 30) * 240 < b["worst_cycles"] <= 48e6 * bound + 100, (b, bound)


@needs_image
@pytest.mark.slow(reason="a 5 s fps hil on the 24 KB board under QEMU, ~25 s: FPS_SLOW=1")
def test_the_24_kb_board_runs_the_11x11_table_with_its_stack_above_the_mailbox(tmp_path, monkeypatch):
    """The controller on 24 KB of RAM (``pil_build.SMALL_MEM``) runs a 5 s fps hil with the thesis's 11x11 table,
    and its stack stays above the mailbox at the bottom of its region (``tools.pil_mailbox``: a high-water mark of
    the whole region above it would be a stack that ran into it)."""
    from ground import cli
    from tools import pil_mailbox
    mem = pil_build.SMALL_MEM
    if not os.path.exists(mem.image):
        pytest.skip("no 24 KB image (make pil)")
    dist, cal = str(tmp_path / "d.dist"), str(tmp_path / "cal.json")
    _fps("distfile", "generate", "--source", "stat", "--duration", "5", "--seed", "1", "-o", dist)
    with open(cal, "w") as f:
        json.dump(fp.calibration(), f)
    monkeypatch.setattr(pil_build, "TARGET_MEM", mem)
    assert cli.main(["hil", "--distfile", dist, "--calibration", cal, "--duration", "5", "--runtime", "qemu",
                     "--quiet", "--no-plots", "-o", str(tmp_path / "hil")]) == 0
    s = json.load(open(tmp_path / "hil" / "summary.json"))
    t = s["target"]
    assert s["complete"] and t["ram_bytes"] == 24 * 1024 and t["heap_bytes"] == mem.heap_bytes
    assert 1000 < t["stack_high_water_bytes"] < mem.stack_bytes - 4 * pil_mailbox.WORDS
    assert len(fp.calibration()["points"]) == 121 and s["instructions_per_step"]["n"] > 3000     # 5 s at 637.8 Hz


@pytest.mark.skipif(not os.path.exists(pil_build.ADCS_IMAGE) or bool(pil_build.missing_tools()),
                    reason="no ADCS PIL image (make pil; it needs %s)" % pil_build.install_hint(pil_build.PACKAGES))
def test_the_lean_adcs_on_the_cortex_m7_board_runs_a_recorded_session_as_the_unix_port(tmp_path):
    """The ADCS image (QEMU mps2-an500: a Cortex-M7 with its FPU, single-precision MicroPython floats, the C kernels
    built in) replays a recorded 40 s session through its UART: every cycle is counted, the kernels ran, the heap and
    the stack stay inside the image's, and its last attitude estimate is the float64 unix port's to within 1 arcsec
    (float32 states against float64: 0.2 arcsec after 210 s, bench_pil_adcs)."""
    import subprocess
    from ground.adcs.quat import angle_arcsec
    from emulator.adcs_session import AdcsSession
    from protocol import core
    n = 40
    with AdcsSession(runtime="micropython", duration_s=n, record=True) as s:
        for _ in range(n):
            s.cycle()
        cfg, rec = s.config(), s.recorded
    r = pil_board.replay_adcs(cfg, rec)
    assert [c[0] for c in r["cycles"]] == list(range(n)) and r["kernels"]
    assert all(c[1] > 100000 for c in r["cycles"]) and 20 < r["insn_per_timer_tick"] < 100
    assert 0 < r["heap_bytes"] < pil_build.ADCS_MEM.heap_bytes
    assert 1000 < r["stack_high_water_bytes"] < pil_build.ADCS_MEM.stack_bytes
    cf, rf = tmp_path / "cfg.json", tmp_path / "rec.json"
    cf.write_text(json.dumps(cfg))
    rf.write_text(json.dumps(rec))
    mp = os.path.join(os.path.dirname(sys.executable), "micropython")
    p = subprocess.run([mp, os.path.join(ROOT, "tests", "mp", "firmware_adcs_app.py"), str(cf), str(rf)], cwd=ROOT,
                       env=dict(os.environ, MICROPYPATH=ROOT), capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    ref = json.loads(p.stdout.strip().splitlines()[-1])["status"]
    st = core.payload_dict(core.PACKET_ID["ADCS_STATUS"], r["status"])
    assert st["tick"] == ref["tick"] == n - 1 and st["adcs_mode"] == ref["adcs_mode"]
    assert angle_arcsec([st["q%d" % i] for i in range(4)], [ref["q%d" % i] for i in range(4)]) < 1.0


needs_adcs_image = pytest.mark.skipif(
    not os.path.exists(pil_build.ADCS_IMAGE) or bool(pil_build.missing_tools()),
    reason="no ADCS PIL image (make pil; it needs %s)" % pil_build.install_hint(pil_build.PACKAGES))


@needs_adcs_image
def test_fps_adcs_can_on_the_cortex_m7_board_flies_as_the_unix_port(tmp_path):
    """fps adcs can --runtime qemu: the ADCS image on QEMU's mps2-an500, CAN through Lawicel on its UART (QEMU's pty,
    python-can's slcan on the host): the same modes as the unix port's run, its attitude estimate within an arcsec
    of it (float32 against float64), and the board and its instructions per cycle in summary.json."""
    import numpy as np
    from ground.adcs.quat import angle_arcsec
    runs = {}
    for r in ("qemu", "micropython"):
        p = _fps("adcs", "can", "--runtime", r, "--session", "40", "--no-plots", "-o", str(tmp_path / r))
        runs[r] = json.load(open(tmp_path / r / "summary.json"))
        runs[r]["h"] = np.load(tmp_path / r / "history.npz")
        if r == "qemu":
            assert "the board (ARM Cortex-M7)" in p.stdout
    q, m = runs["qemu"], runs["micropython"]
    assert q["complete"] and q["cycles"] == m["cycles"] == 40 and q["mode_changes"] == m["mode_changes"]
    assert "Cortex-M7" in q["target"]["core"] and "target" not in m
    ipc = q["instructions_per_cycle"]
    assert ipc["n"] == 39 and 1e5 < ipc["mean"] <= ipc["max"] < ipc["filters_start"]     # the APKF's start apart
    assert q["link"].get("tx_isotp_failed", 0) == 0                 # the host waits out the board's computations
    eq, em = q["h"]["est_q"], m["h"]["est_q"]
    assert eq.shape == em.shape and max(angle_arcsec(a, b) for a, b in zip(eq[-5:], em[-5:])) < 1.0


@needs_adcs_image
@pytest.mark.slow(reason="both boards under QEMU, ~35 s: FPS_SLOW=1")
def test_fps_system_runs_both_loops_on_their_boards(tmp_path):
    """fps system --runtime qemu: the controller on the Cortex-M0 board and the ADCS on the Cortex-M7 board, both
    loops within their budgets, each board's figures in summary.json."""
    _fps("system", "--runtime", "qemu", "--duration", "5", "--no-plots", "-o", str(tmp_path / "s"), timeout=900)
    s = json.load(open(tmp_path / "s" / "summary.json"))
    assert s["requirement_met"] and "Cortex-M0" in s["target"]["core"] and s["instructions_per_step"]["n"] > 3000
    a = s["adcs_summary"]
    assert a["runtime"] == "qemu" and "Cortex-M7" in a["target"]["core"] and a["instructions_per_cycle"]["n"] > 100
