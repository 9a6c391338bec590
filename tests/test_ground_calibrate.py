"""H-matrix calibration (Sec. 7.4): least squares, the CLI against the emulator's truth, bad input."""

import json
import os

import numpy as np
import pytest

from emulator.bench import Bench
from emulator.config import load_config
from emulator.truth import true_h_field
from firmware.controller import Controller
from ground import calibrate
from ground.cli import main as fps

DATA = os.path.join(os.path.dirname(__file__), "data")
ROT30 = os.path.join(DATA, "bench_q1_rot30_unequal.json")


def test_fit_h_recovers_matrix_and_offset():
    rng = np.random.default_rng(2)
    h = np.array([[-8.5, 0.07], [-0.04, 7.7]])
    dv = np.array(calibrate.STEPS, dtype=float) * 0.01
    r = dv @ h.T + [0.003, -0.002]
    got, off, resid = calibrate.fit_h(dv, r)
    np.testing.assert_allclose(got, h, rtol=1e-10)
    np.testing.assert_allclose(off, [0.003, -0.002], atol=1e-12)
    assert resid < 1e-12
    noisy = r + rng.normal(0, 1e-4, r.shape)
    assert calibrate.fit_h(dv, noisy)[2] > 1e-5


def test_grid_points_snake_order_moves_one_step():
    g = calibrate.sec74_grid(11)
    assert g[0] == -5.0 and g[-1] == 5.0 and len(g) == 11
    pts = calibrate.grid_points(g)
    assert len(pts) == 121 and len(set(pts)) == 121
    steps = np.abs(np.diff(np.array(pts), axis=0)).sum(axis=1)
    assert np.allclose(steps, 1.0)


@pytest.mark.parametrize("config", [None, ROT30], ids=["default", "q1-rot30-unequal-gains"])
def test_calibrate_cli_matches_truth_within_1_percent(tmp_path, capsys, config):
    out = tmp_path / "cal.json"
    argv = ["calibrate", "-o", str(out), "--no-truth"] + (["--config", config] if config else [])
    assert fps(argv) == 0
    cal = json.loads(out.read_text())
    assert len(cal["points"]) == 121 and cal["dv"] == 0.01
    assert {"bench_config", "created_utc", "grid_v"} <= set(cal)
    truth = true_h_field(Bench(load_config(config), noise=False), cal["grid_v"], cal["dv"])
    errs = calibrate.compare_truth(cal, truth)
    assert len(errs) == 121
    assert max(e for _, e in errs) < 0.01
    tmap = {tuple(p["pfsm_v"]): p["v0"] for p in truth["points"]}
    for p in cal["points"]:
        assert np.allclose(p["v0"], tmap[tuple(p["pfsm_v"])], atol=2e-3)
    # the controller firmware loads exactly this file; the plots are written beside it
    Controller(table=str(out))
    assert (tmp_path / "cal_fig7-16.png").stat().st_size > 1000
    assert (tmp_path / "cal_fig7-17.png").stat().st_size > 1000


def test_rotated_config_changes_h():
    """The shipped config really is rotated: its true H has large off-diagonal terms."""
    h = np.array(Bench(load_config(ROT30), noise=False).true_h((0.0, 0.0))["H"])
    h0 = np.array(Bench(noise=False).true_h((0.0, 0.0))["H"])
    assert abs(h[0, 1]) > 0.3 * abs(h[0, 0]) and abs(h0[0, 1]) < 0.02 * abs(h0[0, 0])


def test_lost_beam_reported_with_the_point(tmp_path, capsys):
    out = tmp_path / "cal.json"
    rc = fps(["calibrate", "-o", str(out), "--grid", "3", "--span", "10", "--no-plots", "--no-truth"])
    err = capsys.readouterr().err
    assert rc == 1 and not out.exists()
    assert "Traceback" not in err
    assert "P-FSM (10, 10) V" in err or "P-FSM (-10, -10) V" in err
    failed = json.loads((tmp_path / "cal.failed.json").read_text())
    assert failed["failed"] and all("P-FSM" in f["error"] for f in failed["failed"])
    assert len(failed["points"]) + len(failed["failed"]) == 9


def _write(tmp_path, obj, name="bad.json"):
    p = tmp_path / name
    p.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return str(p)


def test_refuses_malformed_calibration_files(tmp_path):
    good = true_h_field(Bench(noise=False), [-5.0, 5.0], 0.01)
    good.pop("bench_config")
    assert calibrate.load_calibration(_write(tmp_path, good, "good.json"))["grid_v"] == [-5.0, 5.0]
    bad_nan = json.loads(json.dumps(good))
    bad_nan["points"][1]["H"][0][0] = float("nan")
    missing = json.loads(json.dumps(good))
    missing["points"].pop()
    no_resid = json.loads(json.dumps(good))
    del no_resid["points"][0]["residual"]
    cases = {"not json {": "not valid JSON", json.dumps({"grid_v": [1]}): "grid_v",
             json.dumps(bad_nan).replace("NaN", "NaN"): "finite", json.dumps(missing): "points",
             json.dumps(no_resid): "residual"}
    for text, needle in cases.items():
        with pytest.raises(ValueError, match=needle):
            calibrate.load_calibration(_write(tmp_path, text))


class _FakeRealBench:
    """Stands in for a real bench on a serial port: the emulator free-running in real time with the
    controller and the player firmware in-process, answering GROUND on the slave side of a pty."""

    def __init__(self):
        import threading
        from emulator.lockstep import Lockstep
        from firmware.player import Player
        from protocol import core
        from protocol.link import open_link
        self.core = core
        self.link = open_link("pty", "BENCH")
        self.ctrl = Controller()
        self.player = Player()
        self.lockstep = Lockstep(Bench(seed=3), self, self.player, realtime=True, block_ticks=8)
        self.stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop and not self.link.closed:
            self.lockstep.run(0.05)

    def on_tick(self, tick, t_us, vx, vy, vs):
        core = self.core
        for pid, src, dst, seq, payload in self.link.recv(timeout=0):
            node = self.ctrl if dst == core.NODE["CONTROLLER"] else self.player
            for rpid, rdst, rp in node.handle(pid, src, seq, payload):
                self.link.send_raw(rpid, core.NODE["CONTROLLER" if node is self.ctrl else "PLAYER"], rdst, rp)
        words = self.ctrl.on_tick(tick, t_us, vx, vy, vs)
        if self.ctrl.mode != 1 and vs > 0:    # see test_status_reports_ratios_outside_track
            self.ctrl.rx = ((2048 - vx) << 15) // vs
            self.ctrl.ry = ((2048 - vy) << 15) // vs
        if self.ctrl.status_due():
            self.link.send_raw(core.PACKET_ID["CTRL_STATUS"], core.NODE["CONTROLLER"], core.NODE["GROUND"],
                               self.ctrl.status_payload(tick))
        return words

    def close(self):
        self.stop = True
        self.thread.join(5)
        self.link.close()


def test_calibrate_real_bench_port_same_code_path(tmp_path, capsys):
    """``--port``: wall-clock bench, P-FSM held through DIST uploads to the player, H from telemetry."""
    fake = _FakeRealBench()
    try:
        out = tmp_path / "cal.json"
        rc = fps(["calibrate", "--port", "serial:" + fake.link.peer_path, "--grid", "2", "--span", "1",
                  "--no-plots", "-o", str(out)])
        err = capsys.readouterr().err
        assert rc == 0, err
    finally:
        fake.close()
    cal = json.loads(out.read_text())
    assert len(cal["points"]) == 4 and cal["bench_config"]["port"].endswith(fake.link.peer_path)
    truth = true_h_field(Bench(noise=False), [-1.0, 1.0], 0.01)
    assert max(e for _, e in calibrate.compare_truth(cal, truth)) < 0.03


def test_status_reports_ratios_outside_track():
    """The calibration reads (Rx, Ry) from CTRL_STATUS in CALIBRATE mode (Sec. 7.4 through the protocol)."""
    from protocol import core
    c = Controller()
    c.mode = 3
    for k in range(3):
        c.on_tick(k, 0, 2048 - 300, 2048 + 150, 1500)
    st = core.payload_dict(core.PACKET_ID["CTRL_STATUS"], c.status_payload())
    assert st["rx"] == pytest.approx(300 / 1500 * 32768, abs=2)
    assert st["ry"] == pytest.approx(-150 / 1500 * 32768, abs=2)
