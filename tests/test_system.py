"""``fps system``: the ADCS and the fine-pointing loop in one run. Short runs with ``--adcs ground``;
the firmware code path's bookkeeping against a fake ADCS session defined here (the real one is
``emulator.adcs_session``), and one short run of the real firmware session with the four device faults."""

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
import types

import numpy as np
import pytest

from ground import report, system
from ground.adcs import body_pointing as bps, bps_cli, quat
from ground.cli import main as fps
from ground.resample import to_dist_step

BODY_KEYS = {"pointing_3sigma_arcsec", "stability_3sigma_arcsec_s", "pointing_sigma_arcsec", "samples"}


@pytest.fixture(scope="module")
def params_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("sys_params")
    p = str(d / "params.json")
    bps.write_params(p, bps_cli.calibration(0, str(d / "cache"), progress=False))
    return p


def _args(out, params_file, cal, duration="6", *extra):
    return ["system", "--adcs", "ground", "--duration", duration, "--truth", "two-body", "--params", params_file,
            "--calibration", cal, "--bps-cache", os.path.join(os.path.dirname(params_file), "cache"), "--quiet",
            "-o", str(out)] + list(extra)


def test_a_reused_system_folder_keeps_no_earlier_figures(tmp_path, params_file, inputs):
    """fps system writes fps hil's figures beside its own: a --no-plots run in the folder removes all three."""
    from ground import hil
    out = tmp_path / "run"
    out.mkdir()
    names = list(hil.FIGURES) + [system.FIGURE]
    for n in names:
        (out / n).write_bytes(b"an earlier run's")
    assert fps(_args(out, params_file, inputs[1], "2", "--no-plots")) in (0, 3)
    assert not [n for n in names if (out / n).exists()]


def test_system_ground_run_writes_a_complete_folder(tmp_path, params_file, inputs, capsys):
    out = tmp_path / "run"
    rc = fps(_args(out, params_file, inputs[1]))
    assert rc in (0, 3), capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is True and s["error"] is None and s["duration_s"] == pytest.approx(6.0, abs=0.01)
    assert (rc == 0) == s["requirement_met"]
    assert BODY_KEYS <= set(s["body_pointing"])
    assert s["body_pointing"]["samples"] == 61                           # 10 Hz over [settle, settle + 6 s]
    for k in ("std_arcsec", "max_radial_arcsec", "within_requirement", "pointing_loss_db"):
        assert s["q2"][k] is not None
    assert s["requirement_met"] == (s["q2"]["within_requirement"] == 1.0)
    # --adcs ground: the live slices reproduce bps.simulate's own figures over the same window
    ref = s["ground_reference"]
    for k in ("pointing_3sigma_arcsec", "stability_3sigma_arcsec_s"):
        assert s["body_pointing"][k] == pytest.approx(ref[k], rel=1e-12)
    assert s["estimation"]["attitude_3sigma_arcsec"] == pytest.approx(ref["estimation"]["attitude_3sigma_arcsec"])
    # the disturbance played is the body pointing error, resampled (within the 10 Hz samples' span)
    z = np.load(out / "body.npz")
    sel = (z["t_s"] >= 0) & (z["t_s"] <= 6.0 + 1e-9)
    span = np.abs(z["dtheta_arcsec"][sel]).max()
    assert 0 < s["disturbance"]["max_radial_arcsec"] <= np.sqrt(2) * span * 1.2
    # the fine loop rejects it: the residual on Q2 is far below the body error
    assert s["q2"]["max_radial_arcsec"] < s["disturbance"]["max_radial_arcsec"]
    for name in ("config.json", "calibration.json", "q2_calibration.json", "telemetry.csv", "samples.npz",
                 "report.md", "system_pointing.png"):
        assert (out / name).stat().st_size > 0, name
    md = (out / "report.md").read_text()
    assert "ground filters, same scenario" in md and "body pointing 3σ" in md and "11.98" in md
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]


def test_system_sigterm_leaves_a_valid_partial_folder(tmp_path, params_file, inputs):
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "ground.cli"] + _args(out, params_file, inputs[1], "120",
                                                                          "--no-plots"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 90
    while proc.poll() is None and time.monotonic() < deadline:
        if (out / "summary.json").exists() and json.loads((out / "summary.json").read_text()).get("phase") == "play":
            break
        time.sleep(0.05)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err.decode()
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is False and s["interrupted"] is True and s["requirement_met"] is False
    assert 0 < s["duration_s"] < 120
    z = np.load(out / "samples.npz")
    assert len(z["t_s"]) == s["q2_samples"] > 0
    assert b"partial run" in err and b"Traceback" not in err
    assert (out / "report.md").exists() and (out / "body.npz").exists()
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]


@pytest.mark.parametrize("args, needle", [
    (["--duration", "0"], "--duration"),
    (["--duration", "-5"], "--duration"),
    (["--duration", "nan"], "--duration"),
    (["--runtime", "jython"], "invalid choice"),
    (["--ts", "0"], "settling time"),
])
def test_system_bad_input_exits_2_without_traceback(tmp_path, args, needle):
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, "-m", "ground.cli", "system", "--adcs", "ground", "-o", str(out)] + args,
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    assert needle in p.stderr and "Traceback" not in p.stderr
    assert not out.exists()                     # nothing written for bad input


def test_system_refuses_firmware_when_the_session_is_missing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(system.run, "firmware_available", lambda: False)
    rc = fps(["system", "--adcs", "firmware", "--duration", "5", "-o", str(tmp_path / "r")])
    assert rc == 2
    assert "adcs_session" in capsys.readouterr().err and not (tmp_path / "r").exists()


def test_live_disturbance_equals_the_distfile_of_the_whole_history():
    """Samples made as the 10 Hz history arrives equal ``to_dist_step`` of the whole history (the distfile
    ``--source bps`` would write), and the player plays them as it plays that distfile."""
    from firmware.player import Player
    from protocol import distfile
    rng = np.random.default_rng(3)
    t = np.arange(0, 400) / 10.0 + 100.0
    xy = np.cumsum(rng.standard_normal((400, 2)), axis=0) * 3
    live = system.LiveDisturbance(t0=105.0)
    for k in range(0, 400, 10):                         # one ADCS cycle at a time
        live.add(t[k:k + 10], xy[k:k + 10])
    sel = t >= 105.0
    x, y = to_dist_step(t[sel], xy[sel, 0], xy[sel, 1])
    n = live.reader.count
    assert n > 0.95 * len(x)
    np.testing.assert_array_equal(live.x, x[:n])
    np.testing.assert_array_equal(live.y, y[:n])
    p_live, p_file = Player(), Player()
    p_live.load(live.reader)
    p_file.load(distfile.parse(distfile.pack(x[:n], y[:n])))
    out = []
    for p in (p_live, p_file):
        p.oneshot()
        from array import array
        xb, yb = array("H", bytes(2 * 20000)), array("H", bytes(2 * 20000))
        assert p.fill(xb, yb, 20000) == 20000
        out.append((xb.tobytes(), yb.tobytes()))
    assert out[0] == out[1]


def test_live_disturbance_holds_a_sample_beyond_the_pfsm_at_its_edge_and_refuses_a_nan():
    from ground.distfile_cli import MAX_THETA_E_ARCSEC
    live = system.LiveDisturbance(t0=0.0)
    t = np.arange(40) / 10.0
    xy = np.zeros((40, 2))
    xy[25:30, 1] = 900.0                                # 900 arcsec x 13.33 > 3 deg
    live.add(t, xy)
    assert max(live.y) == pytest.approx(MAX_THETA_E_ARCSEC) and live.n_unplayable > 0
    (a, b), = live.unplayable
    assert 2.3 < a < 2.5 and 2.9 < b < 3.2
    xy[35, 0] = np.nan
    with pytest.raises(ValueError, match="not a number"):
        live.add(t + 4.0, xy)


def test_a_play_that_starts_beyond_the_pfsm_range_walks_to_its_edge_within_the_ad660_range(tmp_path, inputs,
                                                                                             monkeypatch):
    """The live disturbance's first sample held at the P-FSM's edge is a float32 a hair beyond +-10 V: the walk
    to it stops at the AD660's range instead of refusing the play."""
    from ground import hil
    from ground.fileio import read_json
    from protocol import core
    live = system.LiveDisturbance(t0=0.0)
    t = np.arange(40) / 10.0
    live.add(t, np.full((40, 2), -900.0))               # the play starts beyond the P-FSM's range on both axes
    first = live.reader.sample(0)
    assert abs(first[0] * hil.V_PER_ARCSEC) > 10.0

    class Rig:
        rate_hz = 637.8
        last_status = {"mode": core.MODE["SATURATED"], "why": 0}
        volts = []

        def pfsm_v(self, vx, vy):
            for v in (vx, vy):
                if not -10.0 <= v <= 10.0:
                    raise ValueError("P-FSM voltage %r outside the AD660 range +-10 V" % v)
            self.volts.append((vx, vy))

        def upload_htable(self, blob):
            pass

        def settings(self, mode, decim=1):
            pass

        def run(self, n):
            pass

        def take_status(self):
            pass

    class Rec:
        def path(self, name):
            return str(tmp_path / name)

    monkeypatch.setattr(hil, "calibrate_q2", lambda rig, dvp: {"dv": dvp})
    rig = Rig()
    hil.prepare_play(rig, Rec(), read_json(inputs[1], "calibration"), 0.05, lambda: first)
    assert rig.volts[-1] == (-10.0, -10.0) and len(rig.volts) == 1 + 20


# --- the firmware code path against a fake session (the real one: emulator.adcs_session) -------------------
class FakeSession:
    """Holds a fixed attitude with SatA and SatB on fixed orbits; its estimate is the truth at the cycle's start
    plus known offsets (10 arcsec about x, 5 m on rA, 7 m on rB)."""

    instances = []

    def __init__(self, *, runtime="micropython", satb_gnss=False, seed=0, duration_s=600.0, ts=33.0,
                 params=None, faults=None, log=None, truth="two-body", cache_dir=None, link_faults=None,
                 spacecraft=None, world="thesis", stkf_accel=None):
        self.k = 0
        self.closed = False
        self.started = False
        self.kw = dict(runtime=runtime, satb_gnss=satb_gnss, seed=seed, duration_s=duration_s, ts=ts)
        FakeSession.instances.append(self)

    def start(self):
        self.started = True

    def _truth(self, t):
        ra = np.array([7.0e6, 0.0, 0.0]) + np.outer(t, [0.0, 7.5e3, 0.0])
        rb = ra + np.array([0.0, 0.0, 1.0e6])
        va = np.tile([0.0, 7.5e3, 0.0], (len(t), 1))
        return ra, va, rb, va.copy()

    def cycle(self):
        if self.k >= int(np.ceil(self.kw["duration_s"])):
            raise ValueError("the session's %d s are done" % self.k)       # as emulator.adcs_session
        t = self.k + np.arange(1, 11) / 10.0
        ra, va, rb, vb = self._truth(t)
        q = np.tile([0.0, 0.0, 0.0, 1.0], (10, 1))
        w = np.zeros((10, 3))
        ra0, _, rb0, _ = self._truth(np.array([float(self.k)]))
        h = 5 * quat.RAD_PER_ARCSEC                             # half of 10 arcsec
        est = {"q": np.array([np.sin(h), 0.0, 0.0, np.cos(h)]), "w": np.zeros(3),
               "ra": ra0[0] + [5.0, 0, 0], "rb": rb0[0] + [0, 7.0, 0]}
        self.k += 1
        return {"t": t, "q": q, "w": w, "ra": ra, "va": va, "rb": rb, "vb": vb,
                "status": {"mode": 2, "missed": {"wheel0": np.int64(self.k % 2)}}, "est": est}

    def summary(self):
        return {"cycles": self.k, "late_cycles": 0}

    def board(self):
        return None                    # not a PIL board (AdcsSession.board: qemu runs only)

    def close(self):
        self.closed = True


def test_firmware_path_bookkeeping_with_a_fake_session(monkeypatch, params_file):
    mod = types.ModuleType("emulator.adcs_session")
    mod.AdcsSession = FakeSession
    monkeypatch.setitem(sys.modules, "emulator.adcs_session", mod)
    spec = {"adcs": "firmware", "runtime": "micropython", "satb_gnss": True, "seed": 4, "ts": 10.0,
            "truth": "two-body", "duration_s": 3.0, "adcs_duration_s": 3.0 + system.LEAD_S,
            "params": bps.load_params(params_file)[-1], "bps_cache": None, "cache_dir": None}
    q = queue.Queue()
    system._send_firmware(spec, spec["params"], q, threading.Event())
    sess = FakeSession.instances[-1]
    assert sess.started and sess.closed
    # duration_s is the session's number of cycles: the 30 s hold, 4 t_s of settling, the play and the lead
    assert sess.kw == {"runtime": "micropython", "satb_gnss": True, "seed": 4, "duration_s": 75.0, "ts": 10.0}
    msgs = []
    while not q.empty():
        msgs.append(q.get())
    cycles = [d for k, d in msgs if k == "cycle"]
    n = int(np.ceil(30 + 4 * 10.0 + 5.0))
    assert len(cycles) == sess.k == n
    assert [k for k, _ in msgs][-2:] == ["adcs_summary", "reference"]
    assert msgs[-2][1] == {"cycles": n, "late_cycles": 0}
    assert BODY_KEYS <= set(msgs[-1][1]) and msgs[-1][1]["estimation"]["samples"] > 0   # the ground filters
    # body pointing error of each step by Eq. 6.12-6.16 on the session's truth: SatB straight above SatA
    # along inertial z, the body held at identity: the laser axis's offset from z
    c = cycles[3]
    assert c["dtheta"].shape == (10, 2) and np.all(np.isfinite(c["dtheta"]))
    want, _ = bps.pointing_errors(np.tile([0.0, 0, 0, 1], (1, 1)), np.zeros((1, 3)), np.zeros((1, 3)),
                                  np.zeros((1, 3)), np.array([[0, 0, 1e6]]), np.zeros((1, 3)))
    np.testing.assert_allclose(c["dtheta"], np.tile(want / quat.RAD_PER_ARCSEC, (10, 1)), atol=1e-6)
    assert c["t_est"] == pytest.approx(3.0)
    # the estimate is compared with the truth at the cycle's start: exactly the offsets put in
    assert np.all(np.isnan(cycles[0]["est_err"]))
    e = cycles[5]["est_err"]
    assert e[0] == pytest.approx(10.0, rel=1e-6) and abs(e[1]) < 1e-6 and abs(e[2]) < 1e-6
    assert e[6] == pytest.approx(5.0) and e[7] == pytest.approx(7.0)
    assert c["status"]["missed"]["wheel0"] in (0, 1) and type(c["status"]["missed"]["wheel0"]) is int
    acc = system.estimation_accuracy([d["t_est"] for d in cycles], [d["est_err"] for d in cycles], 0.0, 1e9)
    assert acc["ra_rms_m"] == pytest.approx(5.0) and acc["rb_rms_m"] == pytest.approx(7.0)
    assert acc["attitude_3sigma_arcsec"] == pytest.approx(0.0, abs=1e-6)     # a constant offset has no spread


def test_report_table_puts_the_figures_side_by_side():
    s = {"adcs": "firmware", "thesis_body": system.thesis_body(),
         "body_pointing": {"pointing_3sigma_arcsec": 120.5}, "ground_reference": {"pointing_3sigma_arcsec": 99.25},
         "q2": {"within_requirement": 0.5, "max_radial_arcsec": 13.0}, "estimation": None}
    md = system.side_by_side(s)
    assert "| body pointing 3σ (arcsec) | 120.50 | 99.25 | ≤ 150 (budget); 125.5 (Sec. 6.4.4, 4000 s) |" in md
    assert "50.0000 %" in md and report.THESIS["max_radial_arcsec"] == 3.9103


def test_adcs_feed_keeps_the_session_counters_and_fails_on_an_adcs_error():
    got = []
    feed = system.AdcsFeed({}, lambda t, d: got.append((t, d)))
    feed._handle("cycle", {"t": np.arange(1, 11) / 10.0, "dtheta": np.ones((10, 2)), "domega": np.zeros((10, 2)),
                           "t_est": 0.0, "est_err": np.full(8, np.nan), "status": {"mode": 3, "stale": ["gnss"]}})
    feed._handle("adcs_summary", {"missed": {"wheel2": 4}})
    assert feed.t_last == pytest.approx(1.0) and len(got) == 1
    assert feed.last_status == {"mode": 3, "stale": ["gnss"]} and feed.adcs_summary == {"missed": {"wheel2": 4}}
    with pytest.raises(OSError, match="ADCS .*failed: ValueError: boom"):
        feed._handle("error", "ValueError: boom")
    feed._handle("end", {})
    with pytest.raises(OSError, match="ended at t = 1.0 s"):
        feed.take(until_t=5.0, timeout_s=1.0)
    feed.close()                                    # never started: nothing to stop
    s = {"adcs": "firmware", "thesis_body": system.thesis_body(), "adcs_summary": feed.adcs_summary,
         "adcs_last_status": feed.last_status, "duration_s": 1.0}
    md = system.report_md(s)
    assert '| missed | `{"wheel2": 4}` |' in md and '| stale | `["gnss"]` |' in md
    md = "\n".join(system.adcs_session_md({"mode_changes": [{"t_s": 30.0, "from": "HOLD", "to": "SLEW",
                                                             "reason": "the hold is over"}]},
                                         {"wheels_failed": 2, "adcs_mode_name": "DEGRADED"}))
    assert "| 30 | HOLD -> SLEW | the hold is over |" in md and "| wheels_failed | RW1 (bit mask 2) |" in md


def test_system_with_the_four_device_faults_degrades_the_adcs_and_keeps_the_fine_loop(tmp_path, params_file, inputs):
    """The whole terminal (firmware ADCS over CAN, fine loop over serial) with a wheel that stops answering, the
    star tracker blinded, a GNSS outage and the beacon lost during the play: the ADCS says so (mode, stale
    sensors, fault log in the summary and the report), every 0.1 s of the body record is there, and the fine
    loop holds (every Q2 sample within 11.98 arcsec) or leaves TRACK by its own rules (its mode changes)."""
    if not system.firmware_available():
        pytest.skip("no ADCS-on-CAN session in this build")
    out = tmp_path / "run"
    faults = {"wheel_silent": [1, 168], "startracker_blind": [165, 225], "gnss_outage": [164, 200],
              "beacon_lost": 166}
    args = _args(out, params_file, inputs[1], "12", "--runtime", "cpython", "--faults", json.dumps(faults),
                 "--world", "thesis")                # the fault windows are in the thesis world's seconds
    args[args.index("ground")] = "firmware"
    rc = fps(args)
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is True and s["error"] is None, s["error"]
    events = [e["event"] for e in s["adcs_summary"]["fault_log"]]
    for begins in ("wheel_silent begins (wheel 1)", "startracker_blind begins", "gnss_outage begins",
                   "beacon_lost begins"):
        assert any(e.startswith(begins) for e in events), (begins, events)
    st = s["adcs_last_status"]
    assert st["adcs_mode_name"] == "DEGRADED" and st["wheels_failed"] == 1 << 1
    assert {"RW1", "STARTRACKER", "GNSS_A", "BEACON"} <= set(st["stale_names"])
    assert s["body_pointing"]["samples"] == 121                          # 10 Hz over the 12 s played: none lost
    held = s["q2"]["within_requirement"] == 1.0
    left = any(m["to"] in ("SATURATED", "ACQUIRE", "SAFE") for m in s["mode_changes"])
    assert (rc == 0) == held and (held or left)
    assert json.loads((out / "config.json").read_text())["faults"] == {
        "wheel_silent": [1, 168.0], "startracker_blind": [165.0, 225.0], "gnss_outage": [164.0, 200.0],
        "beacon_lost": 166.0}
    md = (out / "report.md").read_text()
    assert "wheel_silent begins" in md and "startracker_blind begins" in md


@pytest.mark.slow(reason="a 135 s play, 40-60 s each: FPS_SLOW=1 runs it")
@pytest.mark.parametrize("bench", ["thesis", "small_q1"])
def test_a_blind_star_tracker_takes_the_fine_loop_out_of_track_and_back_after_point(tmp_path, params_file, inputs,
                                                                                  bench, capsys):
    """The star tracker blind from 230 to 400 s (the flight world's play from 277 s): the body error grows past
    the FSM's range and the P-FSM's (played at its edge), the ADCS points again at ~408 s. The fine loop is out of
    TRACK whenever the body error is beyond the P-FSM's range (SATURATED on the thesis bench, where the FSM's
    range plus Q1's field exceeds the P-FSM's and the beam stays on Q1; ACQUIRE on a bench with a 4 mm Q1, where
    the beam leaves it), is in TRACK again within 30 s of the ADCS's POINT and stays there; the availability
    names the outage; the exit status is the budgets' (3: the body loop misses them), never 1."""
    if not system.firmware_available():
        pytest.skip("no ADCS-on-CAN session in this build")
    out = tmp_path / "run"
    args = ["system", "--startracker-blind", "230:400", "--duration", "135", "--truth", "two-body", "--params",
            params_file, "--calibration", inputs[1], "--bps-cache", os.path.join(os.path.dirname(params_file), "cache"),
            "--quiet", "--no-plots", "-o", str(out)]
    if bench == "small_q1":
        cfg = tmp_path / "bench.json"
        cfg.write_text(json.dumps({"q1": {"radius_m": 2.0e-3}}))
        args += ["--config", str(cfg)]
    rc = fps(args)
    printed = capsys.readouterr().out
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is True and s["error"] is None, s["error"]
    assert rc == (3 if s["verdict"]["missed"] else 0) and any(v.startswith("body:") for v in s["verdict"]["missed"])
    settle = s["settle_s"]
    # the body error beyond the P-FSM's range (and so beyond the FSM's) during the play
    beyond = s["disturbance"]["beyond_pfsm_range"]["windows_s"]
    assert beyond and s["disturbance"]["beyond_pfsm_range"]["seconds"] > 5
    # the controller's modes over the play, from its mode changes: out of TRACK all through each window
    changes = s["mode_changes"]
    spans, mode, t0 = [], "TRACK", 0.0
    for m in changes:
        assert m["from"] == mode
        spans.append((t0, m["t_s"], mode))
        mode, t0 = m["to"], m["t_s"]
    spans.append((t0, s["duration_s"], mode))
    for a, b in beyond:
        assert all(m != "TRACK" for t, u, m in spans if t < b and u > a), (a, b, spans)
    outside = {m for _, _, m in spans if m != "TRACK"}
    assert outside == ({"SATURATED"} if bench == "thesis" else {"SATURATED", "ACQUIRE"})
    if bench == "small_q1":
        acq = [m for m in changes if m["to"] == "ACQUIRE"]
        assert acq and all(m["why"] == "BEAM_LOST" for m in acq)
        assert any(m["from"] == "ACQUIRE" and m["to"] == "TRACK" and m["why"].startswith("beam back on Q1")
                   for m in changes)
        assert "controller went from SATURATED to ACQUIRE" in printed and "beam lost: ACQUIRE" in printed
    # TRACK again within 30 s of the ADCS's POINT after the blind window, and to the end
    point = [e["t_s"] for e in s["adcs_summary"]["fault_log"] if e["event"] == "ADCS mode POINT" and e["t_s"] > 400]
    assert point, s["adcs_summary"]["fault_log"]
    back = spans[-1]
    assert back[2] == "TRACK" and back[0] - (point[0] - settle) <= 30.0
    assert s["adcs_last_status"]["adcs_mode_name"] == "POINT"
    # the availability states the outage, its cause and its end
    av = s["availability"]
    assert 0.5 < av["availability"] < 1.0 and av["n_outages"] >= 1 and all(o["ended"] for o in av["outages"])
    big = max(av["outages"], key=lambda o: o["length_s"])
    assert big["cause"] and big["start_s"] <= beyond[0][0] and big["start_s"] + big["length_s"] >= beyond[-1][1]
    assert "availability %.2f %%" % (100 * av["availability"]) in printed


def test_system_faults_are_refused_when_malformed(tmp_path, params_file, inputs, capsys):
    for extra, needle in ((["--faults", "{beacon"], "--faults must be a JSON object"),
                          (["--faults", '{"meteor": 3}'], "unknown fault")):
        args = _args(tmp_path / "r", params_file, inputs[1], "6", *extra)
        if "meteor" in extra[1]:
            if not system.firmware_available():
                continue
            args[args.index("ground")] = "firmware"
        assert fps(args) == 2
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err
        assert not (tmp_path / "r").exists()


def test_the_ground_adcs_flies_the_device_faults_too(tmp_path, params_file, inputs):
    """--adcs ground flies the same app in process against the same emulated devices: a wheel silent from 60 s
    (before the play) is failed there as with the firmware ADCS, and the run completes."""
    out = tmp_path / "r"
    rc = fps(_args(out, params_file, inputs[1], "6", "--wheel-silent", "1:60", "--no-plots"))
    s = json.loads((out / "summary.json").read_text())
    assert rc in (0, 3) and s["complete"] is True
    a = s["adcs_summary"]
    assert a["faults"] == {"wheel_silent": [1, 60.0]} and a["wheels_failed"] == 2
