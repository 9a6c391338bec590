"""Lockstep clock, transports, determinism, counters, ADC chains, config and CLI of the bench emulator."""

import json
import os
import subprocess
import sys
import threading
from array import array

import numpy as np
import pytest

from emulator.bench import Bench
from emulator.config import default_config, load_config, validate
from emulator.lockstep import Lockstep, RemoteController
from emulator.lockstep import SinePlayer as Sine
from emulator.mirrors import INIT_WORDS, fsm_words
from protocol import core

V0 = (0.0375, -0.0026)
ZERO_LATENCY = {"board": {"timing": "zero-latency"}}    # the ideal loop these tests were written for       # the default bench's null at P-FSM 0 V


class Integral:
    """Float integral law V <- V - g H^-1 R (Eq. 7.12) with the true centre H; misses ticks in ``skip``."""

    def __init__(self, cfg, gain=0.4, skip=()):
        h = np.array(Bench(cfg, noise=False).true_h((0.0, 0.0))["H"])
        self.hinv = np.linalg.inv(h)
        self.v = np.zeros(2)
        self.cfg = cfg
        self.gain = gain
        self.skip = set(skip)

    def on_tick(self, tick, t_us, vx, vy, vs):
        if tick in self.skip:
            return None
        r = np.array([(2048 - vx) / vs, (2048 - vy) / vs])
        self.v = np.clip(self.v - self.gain * self.hinv @ r, -2.4, 2.4)
        if tick == 0:                   # the AD5664R init sequence, as the firmware sends it
            return list(INIT_WORDS)
        return list(fsm_words(self.v[0], self.v[1], self.cfg))


def _run(seed=1, ticks=400, controller=None, **kw):
    b = Bench(ZERO_LATENCY, seed=seed)
    c = controller or Integral(b.config)
    return Lockstep(b, c, Sine(amp=3000, hz=7.0), record=True, **kw).run(n_ticks=ticks)


# --- lockstep --------------------------------------------------------------------------------------------
def test_closed_loop_nulls_q1_and_q2_runs_at_630_hz():
    res = _run(ticks=638)
    q2 = res["q2"]
    assert len(q2) == int(np.ceil(638 / 637.8 * 630))
    assert np.all(np.diff(q2[:, 0]) == 1)
    assert np.all(np.abs(np.diff(q2[:, 1]) - 1e6 / 630) <= 1)
    err = res["truth_arcsec"][len(q2) // 2:]
    hold = _run(ticks=638, controller=Integral(default_config(), gain=0.0))
    open_loop = hold["truth_arcsec"][len(q2) // 2:]
    assert np.max(np.abs(open_loop)) > 20.0
    assert np.max(np.abs(err)) < 0.2 * np.max(np.abs(open_loop))   # the loop rejects the disturbance
    assert np.std(res["fsm_v"][300:, 0]) > 0.05                      # ... by moving the mirror
    assert res["counters"]["overruns"] == 0


def test_on_q2_sees_every_sample_as_it_falls():
    seen = []
    res = _run(ticks=100, on_q2=seen.append)
    assert len(seen) == len(res["q2"]) > 90
    assert [s[:5] for s in seen] == [tuple(r) for r in res["q2"].tolist()]
    assert np.array_equal(np.array([s[5:] for s in seen]), res["truth_arcsec"])


def test_same_seed_is_bit_identical_and_seeds_differ():
    a, b, c = _run(seed=5), _run(seed=5), _run(seed=6)
    assert np.array_equal(a["q1"], b["q1"]) and np.array_equal(a["q2"], b["q2"])
    assert np.array_equal(a["truth_arcsec"], b["truth_arcsec"])
    assert not np.array_equal(a["q1"], c["q1"])


def test_block_size_does_not_change_the_physics():
    a, b = _run(block_ticks=256), _run(block_ticks=7)
    assert np.array_equal(a["q1"], b["q1"]) and np.array_equal(a["q2"], b["q2"])


def test_fused_block_loop_matches_the_per_tick_path():
    """Bench.run_ticks (the lockstep's loop) against q1_sample / spi_words / step tick by tick (taken when
    ``on_q2`` is set): bit-identical samples, truth, records and counters, with missed ticks and MEMS clipping."""
    class Clipping(Integral):
        def on_tick(self, tick, t_us, vx, vy, vs):
            if 100 <= tick < 105:                   # beyond the MEMS range for a while: clipped ticks
                return list(fsm_words(2.6, 0.0, self.cfg))
            return super().on_tick(tick, t_us, vx, vy, max(vs, 1))

    def go(per_tick):
        b = Bench(ZERO_LATENCY, seed=7)
        c = Clipping(b.config, gain=0.9, skip=range(50, 60))
        seen = []
        res = Lockstep(b, c, Sine(amp=3000, hz=7.0), record=True, block_ticks=33,
                       on_q2=seen.append if per_tick else None).run(n_ticks=300)
        return res, b
    (a, ba), (b, bb) = go(False), go(True)
    for key in ("q1", "fsm_v", "q2", "truth_arcsec"):
        assert np.array_equal(a[key], b[key]), key
    assert a["counters"] == b["counters"]
    assert a["counters"]["overruns"] == 10 and a["counters"]["mems_clip_ticks"] > 0
    sa, sb = ba.m, bb.m
    assert (sa.zmx1, sa.zmy2, sa.tpx, ba.q2_next, ba.chain1.noise.i) == (sb.zmx1, sb.zmy2, sb.tpx, bb.q2_next,
                                                                       bb.chain1.noise.i)


def test_missing_commands_are_overruns_and_the_mirror_holds():
    b = Bench(ZERO_LATENCY, seed=2)
    ctrl = Integral(b.config, skip=range(100, 110))
    res = Lockstep(b, ctrl, Sine(amp=3000, hz=7.0), record=True).run(n_ticks=200)
    assert res["counters"]["overruns"] == 10
    fsm = res["fsm_v"]
    assert np.all(fsm[100:110] == fsm[99])
    assert not np.all(fsm[110:120] == fsm[99])


def test_player_running_short_holds_the_last_code():
    class Short:
        def fill(self, xbuf, ybuf, n):
            m = min(n, 30)
            xbuf[:m] = array("H", [40000] * m)
            ybuf[:m] = array("H", [30000] * m)
            return m
    b = Bench(ZERO_LATENCY, noise=False)
    loaded, load = [], b.load_pfsm

    def load_pfsm(xa, ya, counts):          # what the P-FSM is given to play: the player's 30, then held
        loaded.append((np.array(xa), np.array(ya)))
        return load(xa, ya, counts)
    b.load_pfsm = load_pfsm
    lock = Lockstep(b, Integral(b.config), Short(), block_ticks=4)
    lock.run(n_ticks=400)
    assert lock.counters()["player_short_blocks"] == 100 and len(loaded) == 100
    assert all(len(x) > 30 and set(x.tolist()) == {40000} and set(y.tolist()) == {30000} for x, y in loaded)


def test_realtime_slow_controller_overruns():
    import time

    class Slow(Integral):
        def on_tick(self, tick, t_us, vx, vy, vs):
            time.sleep(0.004)
            return Integral.on_tick(self, tick, t_us, vx, vy, vs)

    b = Bench(ZERO_LATENCY)
    res = Lockstep(b, Slow(b.config), deadline_s=0.001, realtime=True).run(n_ticks=5)
    assert res["counters"]["overruns"] == 5
    assert b.counters()["spi_words"] == 0


def test_unknown_spi_words_counted_and_ignored():
    b = Bench(ZERO_LATENCY, noise=False)
    b.spi_words(INIT_WORDS)
    b.spi_words(fsm_words(0.5, 0.2, b.config))
    before = b.fsm_v
    b.spi_words([(0 << 19) | (5 << 16) | 123, 1 << 24, (2 << 19) | (6 << 16)])
    b.spi_words([(0 << 19) | (5 << 16) | 123, 1 << 24, (2 << 19) | (6 << 16)])   # memoized repeat
    assert b.counters()["spi_unknown"] == 6
    assert b.fsm_v == before


# --- transports ------------------------------------------------------------------------------------------
def _serve_controller(recv, send, ctrl, n):
    """Peer side: HELLO and a CTRL_STATUS, then answer n TICKs with one FSM_SPI each (<= 4 words)."""
    tick_id = core.PACKET_ID["TICK"]
    done = 0
    send("HELLO", core.NODE["BENCH"])
    send("CTRL_STATUS", core.NODE["BENCH"], tick=0)
    while done < n:
        for pid, src, dst, seq, payload in recv():
            if pid != tick_id:
                continue
            tick, t_us, vx, vy, vs = core.decode_payload(pid, payload)
            words = ctrl.on_tick(tick, t_us, vx, vy, vs)
            send("FSM_SPI", src, tick=tick, n=len(words), **{"w%d" % j: w for j, w in enumerate(words)})
            done += 1


def _remote_run(link, peer_recv, peer_send, ticks):
    b = Bench(ZERO_LATENCY, seed=3)
    th = threading.Thread(target=_serve_controller, args=(peer_recv, peer_send, Integral(b.config), ticks))
    th.start()
    rc = RemoteController(link, timeout_s=5.0)
    res = Lockstep(b, rc, Sine(amp=3000, hz=7.0), record=True).run(n_ticks=ticks)
    th.join(5)
    return res, rc


def test_physics_does_not_depend_on_the_transport():
    from protocol.link import inproc_pair, open_link
    from protocol.stream import StreamLink
    ticks = 150
    b = Bench(ZERO_LATENCY, seed=3)
    ref = Lockstep(b, Integral(b.config), Sine(amp=3000, hz=7.0), record=True).run(n_ticks=ticks)

    a, peer = inproc_pair("BENCH", "CONTROLLER")
    res_in, rc = _remote_run(a, lambda: peer.recv(timeout=0.5), peer.send, ticks)
    assert any(p[0] == core.PACKET_ID["CTRL_STATUS"] for p in rc.inbox)
    a.close()

    link = open_link("pty", "BENCH")
    slave = StreamLink(link.peer_path, "CONTROLLER")
    try:
        res_pty, _ = _remote_run(link, lambda: slave.recv(500), slave.send, ticks)
    finally:
        slave.close()
        link.close()

    can_a = open_link("can:virtual:emulator-test", "BENCH")
    can_b = open_link("can:virtual:emulator-test", "CONTROLLER")
    try:
        res_can, _ = _remote_run(can_a, lambda: can_b.recv(timeout=0.5), can_b.send, ticks)
    finally:
        can_a.close()
        can_b.close()
    for res in (res_in, res_pty, res_can):
        assert np.array_equal(res["q1"], ref["q1"])
        assert np.array_equal(res["q2"], ref["q2"])
        assert np.array_equal(res["truth_arcsec"], ref["truth_arcsec"])
        assert res["counters"]["overruns"] == 0


def test_remote_timeout_is_an_overrun_and_late_answers_are_dropped():
    from protocol.link import inproc_pair
    a, peer = inproc_pair("BENCH", "CONTROLLER")
    b = Bench(ZERO_LATENCY, seed=1)
    rc = RemoteController(a, timeout_s=0.05)
    lock = Lockstep(b, rc)
    lock.run(n_ticks=1)                                   # nobody answers tick 0
    assert lock.counters()["overruns"] == 1
    assert [p[0] for p in peer.recv(timeout=1.0)] == [core.PACKET_ID["TICK"]]
    peer.send("FSM_SPI", core.NODE["BENCH"], tick=0, n=1, w0=0x380001)   # too late
    rc.timeout_s = 5.0      # the peer thread answers now: 50 ms would race its start on a loaded machine
    th = threading.Thread(target=_serve_controller,
                          args=(lambda: peer.recv(timeout=0.5), peer.send, Integral(b.config), 2))
    th.start()
    lock.run(n_ticks=2)
    th.join(5)
    c = lock.counters()
    assert c["overruns"] == 1 and c["controller_late"] == 1 and c["controller_timeouts"] == 1


@pytest.mark.parametrize("link", ["serial", "can"])
def test_serve_cli_over_a_pty(tmp_path, link):
    from protocol.link import open_link
    from protocol.stream import StreamLink
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    summary = tmp_path / "run.json"
    proc = subprocess.Popen([sys.executable, "-m", "ground.cli", "emulator", "serve", "--link", link,
                             "--duration", "0.2", "--pfsm-v", "1.0", "0.5", "-o", str(summary)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        if link == "serial":
            slave = StreamLink(path, "CONTROLLER")
            recv = lambda: slave.recv(500)
        else:
            slave = open_link("slcan:" + path, "CONTROLLER")
            recv = lambda: slave.recv(timeout=0.5)
        try:
            _serve_controller(recv, slave.send, Integral(default_config()),
                              int(round(0.2 * 637.8)))
            out, err = proc.communicate(timeout=20)
        finally:
            slave.close()
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    d = json.loads(summary.read_text())
    assert d["counters"]["ticks"] == 128 and d["counters"]["overruns"] == 0
    assert d["packets_from_controller"] == {"HELLO": 1, "CTRL_STATUS": 1}
    assert d["samples"] == 127
    assert d["max_abs_arcsec"] > 80.0                       # the P-FSM starts 91 arcsec off ...
    assert np.hypot(*d["last_arcsec"]) < 1.0                # ... and the loop closed through the pty


# --- ADC chains ------------------------------------------------------------------------------------------
def test_q1_counts_follow_the_interfaces_convention_and_quantize():
    b = Bench(ZERO_LATENCY, noise=False)
    b.spi_words(INIT_WORDS)
    for fv in ((0.0375, -0.0026), (0.06, 0.01), (0.0, -0.05)):
        b.spi_words(fsm_words(fv[0], fv[1], b.config))
        b.settle((0.0, 0.0))
        vx, vy, vs = b.q1_sample()
        rx, ry, vs_v = b.static_q1((0.0, 0.0), b.fsm_v, model="fast")
        k = b.config["q1"]["amp_gain"] / 3.3 * 4096
        assert vs == round(k * vs_v)
        assert vx == round(2048 - k * rx * vs_v) and vy == round(2048 - k * ry * vs_v)
        assert (2048 - vx) / vs == pytest.approx(rx, abs=1.0 / vs)
    assert b.counters()["q1_adc_clips"] == 0


def test_adc_clipping_is_counted():
    cfg = default_config()
    cfg["q1"]["amp_gain"] = 3.0                              # 3 x 1.5 V sum > 3.3 V full scale
    hot = Bench(cfg, noise=False)
    assert hot.q1_sample()[2] == 4095
    assert hot.counters()["q1_adc_clips"] == 1
    cfg["q2"]["amp_gain"] = 5.0                              # 5 x 1.5 V > 2 VREF = 5 V
    hot2 = Bench(cfg, noise=False)
    hot2.advance_tick([0x8000] * 17, [0x8000] * 17)
    q2 = hot2.advance_tick([0x8000] * 17, [0x8000] * 17)
    assert q2 and q2[0][4] == 0x7FFFFF
    assert hot2.counters()["q2_adc_clips"] >= 1


def test_q2_counts_are_ads1256_twos_complement():
    b = Bench(ZERO_LATENCY, noise=False)
    q2 = b.advance_tick([0x8000] * 17, [0x8000] * 17)
    m, t_us, vx, vy, vs = q2[0][:5]
    k = b.config["q2"]["amp_gain"] / 5.0 * 0x800000
    assert vs == round(k * b.q2.outputs_fast(*b._spot(b.q2, 0, 0, 0, 0))[2])
    assert -0x800000 <= vx <= 0x7FFFFF and vs > 0


# --- config ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("over, key", [
    ({"laser": {"wavelength_nm": 633}}, "laser.wavelength_nm"),
    ({"laser": {"waist_radius_m": -1e-3}}, "laser.waist_radius_m"),
    ({"q1": {"distance_m": "far"}}, "q1.distance_m"),
    ({"mems": {"gain_error": [0.1]}}, "mems.gain_error"),
    ({"pfsm": {"damping": 1.5}}, "pfsm.damping"),
    ({"adc_q1": {"bits": 12.5}}, "adc_q1.bits"),
    ({"adc_q1": {"bits": 10}}, "adc_q1.bits"),      # the controller is 12-bit: another width cannot close the loop
    ({"bogus": 1}, "bogus"),
    ({"resizer": {"z1_m": 0.2}}, "resizer.z1_m"),
    ({"q1": {"noise_v": float("nan")}}, "q1.noise_v"),
])
def test_malformed_config_is_refused_naming_the_key(over, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        validate(over)


def test_config_file_roundtrip_and_cli(tmp_path):
    p = tmp_path / "bench.json"
    p.write_text(json.dumps({"q1": {"rotation_deg": 30.0}, "mems": {"gain_error": [0.1, -0.1]}}))
    cfg = load_config(str(p))
    assert cfg["q1"]["rotation_deg"] == 30.0 and cfg["q2"] == default_config()["q2"]
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="bad.json"):
        load_config(str(tmp_path / "bad.json"))
    out = subprocess.run([sys.executable, "-m", "ground.cli", "emulator", "config"], capture_output=True,
                         text=True, check=True, env=dict(os.environ, PYTHONPATH=os.getcwd()))
    assert json.loads(out.stdout) == default_config()


def test_truth_h_cli_writes_the_calibration_shape(tmp_path):
    out = tmp_path / "h.json"
    subprocess.run([sys.executable, "-m", "ground.cli", "emulator", "truth-h", "--grid", "3", "--dv", "0.01",
                    "-o", str(out)], check=True, capture_output=True, env=dict(os.environ, PYTHONPATH=os.getcwd()))
    d = json.loads(out.read_text())
    assert d["grid_v"] == [-5.0, 0.0, 5.0] and d["dv"] == 0.01 and len(d["points"]) == 9
    for p in d["points"]:
        assert set(p) >= {"pfsm_v", "v0", "H", "residual"}
        assert np.array(p["H"]).shape == (2, 2)
    centre = d["points"][4]
    assert centre["pfsm_v"] == [0.0, 0.0]
    assert centre["v0"] == pytest.approx(V0, abs=1e-3)
    assert d["bench_config"] == default_config()


def test_bad_timing_and_codes_are_refused_or_counted():
    b = Bench(ZERO_LATENCY, noise=False)
    with pytest.raises(RuntimeError, match="load_pfsm"):
        b.step()
    with pytest.raises(ValueError, match="load_pfsm"):
        b.load_pfsm([0x8000] * 3, [0x8000] * 3, [4])
    b.advance_tick([70000] * 17, [-5] * 17)              # beyond the AD660's 16 bits: clipped, counted
    assert b.counters()["pfsm_code_clips"] == 34
    assert b.m.tpx > 0 > b.m.tpy
    for kw in ({"pfsm_hz": 50.0}, {"deadline_s": 0.0}, {"block_ticks": 0}, {"rate_hz": 0.5}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            Lockstep(Bench(ZERO_LATENCY), Integral(default_config()), **kw)


def test_distfile_player_interpolates_and_converts_by_eq_7_8():
    """The emulator's player: the Keys 6-point kernel (firmware/player.py) within one code of the float
    kernel, Eq. 7.8 codes, a one-shot that holds the last sample."""
    from emulator.serve import DistfilePlayer
    from protocol import distfile
    from tests.test_firmware_player import _reference
    d = distfile.parse(distfile.pack([0.0, 40.0, -20.0], [10.0, 10.0, 10.0]))
    b = Bench(ZERO_LATENCY)
    p = DistfilePlayer(d, pfsm_hz=10600.0)
    n = p.n_total + 50
    xb, yb = array("H", bytes(2 * n)), array("H", bytes(2 * n))
    got = p.fill(xb, yb, n)
    assert got == p.n_total < n                          # one-shot: fewer codes at the end
    ref = _reference([0.0, 40.0, -20.0], [10.0] * 3, 10600, got - 1)
    assert max(abs(xb[k] - r[0]) for k, r in enumerate(ref)) <= 1
    from firmware import ad660                       # the firmware's codes: Q2 rounded, then the code
    assert xb[got - 1] == ad660.arcsec_to_code(-20.0)
    assert set(yb[:got]) == {ad660.arcsec_to_code(10.0)}
    assert abs(ad660.arcsec_to_code(10.0) - b.pfsm.v_to_code(b.pfsm_v_for_error(10.0))) <= 1
