"""The ADCS on CAN: the firmware's slcan adapter HAL against python-can's slcan interface, and the
AdcsSession (emulated spacecraft + the ADCS flight application in its own process) with its faults.

Sessions are short (time compressed: hold 5 s, faults early) to keep the suite fast; each fault test checks
what the status and the summary say and that every cycle's record is there."""

import os
import subprocess
import sys
import time
import tty

import numpy as np
import pytest

from emulator.adcs_bus import check_faults
from emulator.adcs_session import AdcsSession
from emulator.spacecraft.wheels import WheelParams
from protocol import core
from protocol import link as hostlink
from tests.test_firmware_mp import MICROPYTHON, ROOT

ECHO = r"""
import sys
from firmware.hal.slcan import SlcanAdapter, CanPort
ad = SlcanAdapter(int(sys.argv[1]))
port = CanPort(ad, "ADCS")
while not port.closed:
    for pid, src, dst, seq, payload in port.recv_ms(500):
        port.send_raw(pid, dst, src, payload)
"""


def _runtimes():
    out = ["cpython"]
    if os.path.exists(MICROPYTHON):
        out.append("micropython")
    return out


def _adapter_on_pty(script, source, runtime, **popen):
    """``source`` written to ``script`` and run (micropython or CPython) on the master of a raw pty, whose
    path it gets as its argument: (process, the slave's fd, for the host side)."""
    script.write_text(source)
    m, s = os.openpty()
    tty.setraw(s)
    os.set_blocking(m, False)
    exe = MICROPYTHON if runtime == "micropython" else sys.executable
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    p = subprocess.Popen([exe, str(script), str(m)], pass_fds=(m,), cwd=ROOT, env=env, **popen)
    os.close(m)
    return p, s


@pytest.mark.parametrize("runtime", _runtimes())
def test_slcan_adapter_hal_echoes_single_frames_and_isotp_through_python_can(tmp_path, runtime):
    p, s = _adapter_on_pty(tmp_path / "echo.py", ECHO, runtime)
    link = hostlink.open_link("slcan:" + os.ttyname(s), "SPACECRAFT", bitrate=1000000, accept=("STARTRACKER",))
    os.close(s)
    try:
        for i in range(5):
            pl = core.encode_payload(core.PACKET_ID["STARTRACKER"], t_ms=i, q0=0.1, q1=-0.2, q2=0.3, q3=0.9,
                                     valid=1)       # 21 bytes: ISO-TP both ways (flow control both ways)
            link.send_raw(core.PACKET_ID["STARTRACKER"], core.NODE["STARTRACKER"], core.NODE["ADCS"], pl)
            got = link.recv(5.0)
            assert got and got[0][0] == core.PACKET_ID["STARTRACKER"] and got[0][4] == pl
            pl = core.encode_payload(core.PACKET_ID["ADCS_TICK"], tick=i, t_ms=1000 * i)   # one frame
            link.send_raw(core.PACKET_ID["ADCS_TICK"], core.NODE["SPACECRAFT"], core.NODE["ADCS"], pl)
            got = link.recv(5.0)
            assert got and got[0][4] == pl and got[0][2] == core.NODE["SPACECRAFT"]
        c = link.counters()
        assert c["frames"] == 10 and c["bad_seq"] == 0 and c.get("tx_isotp_TimeoutError", 0) == 0
    finally:
        link.close()
        p.wait(5)
    assert p.returncode == 0


def test_slcan_adapter_answers_commands_like_an_adapter(tmp_path):
    """O/C/V/N/S answered; a frame while closed or a malformed one gets BEL; a frame when open Z."""
    from firmware.hal.slcan import SlcanAdapter
    m, s = os.openpty()
    tty.setraw(s)
    os.set_blocking(m, False)
    ad = SlcanAdapter(m)
    try:
        def ask(cmd):
            # poll the adapter until its whole answer (ending in CR or BEL) is back: one 200 ms poll and a
            # blocking read hung for good if the command reached the adapter late or in two pieces (load)
            import select
            os.write(s, cmd)
            frames, out, t_end = [], b"", time.monotonic() + 10.0
            while not out.endswith((b"\r", b"\a")) and time.monotonic() < t_end:
                frames += ad.poll(20)
                if select.select([s], [], [], 0.01)[0]:
                    out += os.read(s, 100)
            return out, frames
        assert ask(b"V\r")[0] == b"V1013\r"
        assert ask(b"N\r")[0] == b"NFPS0\r"
        assert ask(b"S8\r")[0] == b"\r" and ad.bitrate == 8
        assert ask(b"T0A8A603020102\r")[0] == b"\a"                 # closed: refused
        assert ask(b"O\r")[0] == b"\r" and ad.is_open
        out, frames = ask(b"T0A8A60302ABCD\r")
        assert out == b"Z\r" and frames == [(0x0A8A6030, True, bytearray(b"\xab\xcd"))]
        assert ask(b"T0A8A6030ZZ\r")[0] == b"\a" and ad.n_bad == 1     # malformed dlc
        assert ask(b"S4\r")[0] == b"\a"                               # no bit rate change while open
        ad.send_frame(0x0A8A6030, b"\x01\x02")
        out, t_end = b"", time.monotonic() + 10.0
        while not out.endswith(b"\r") and time.monotonic() < t_end:
            out += os.read(s, 100)
        assert out == b"T0A8A603020102\r"
    finally:
        ad.close()
        os.close(s)


def test_bad_fault_specs_are_refused():
    for bad in ({"wheel_silent": [4, 10]}, {"startracker_blind": [50, 10]}, {"gnss_outage": "x"},
                {"beacon_lost": -1}, {"meteor": 3}, [1, 2], {"wheel_silent": "12"},
                {"startracker_blind": "19"}, {"beacon_lost": True}, {"wheel_silent": [True, 1]},
                {"beacon_lost": "3"}, {"wheel_silent": ["1", 5]}, {"gnss_outage": [1, "5"]}, {"beacon_lost": 10 ** 400},
                {"wheel_silent": [10 ** 400, 5]}, {"startracker_blind": [1, 10 ** 400]}, {"beacon_lost": None}):
        with pytest.raises(ValueError):
            check_faults(bad, 100)
    assert check_faults({"wheel_silent": [1, 5]}, 100) == {"wheel_silent": [1, 5.0]}
    assert check_faults({"wheel_silent": [2.0, np.float64(5)], "beacon_lost": np.int64(7)}, 100) == {
        "wheel_silent": [2, 5.0], "beacon_lost": 7.0}
    for late in ({"wheel_silent": [1, 100]}, {"startracker_blind": [120, 180]}, {"beacon_lost": 100.5}):
        with pytest.raises(ValueError, match="never happen"):
            check_faults(late, 100)
    assert check_faults({"gnss_outage": [99, 400]}, 100) == {"gnss_outage": [99.0, 400.0]}
    with pytest.raises(ValueError, match="runtime"):
        AdcsSession(runtime="java")


def _run(duration, faults=None, runtime="micropython", hold_s=None, **kw):
    """A session of ``duration`` s; by default held (rate damping) throughout, so that a fault is the only
    thing that degrades it (the slew to SatB blinds the star tracker for ~60 s, as it would in orbit)."""
    hold_s = duration + 1.0 if hold_s is None else hold_s
    if runtime == "micropython" and not os.path.exists(MICROPYTHON):
        runtime = "cpython"
    log = []
    cycles = []
    with AdcsSession(runtime=runtime, duration_s=duration, faults=faults, hold_s=hold_s, log=log.append,
                     **kw) as s:
        for _ in range(int(duration)):
            cycles.append(s.cycle())
        summary = s.summary()
    return cycles, summary, log


def _check_intact(cycles, summary, duration):
    assert summary["complete"] and summary["cycles"] == duration and summary["late_cycles"] == 0
    t = np.concatenate([c["t"] for c in cycles])
    assert np.allclose(t, np.arange(1, 10 * duration + 1) / 10.0)              # no step lost
    for c in cycles:
        assert c["q"].shape == (10, 4) and np.all(np.isfinite(c["q"])) and c["status"]
    assert [c["status"]["tick"] for c in cycles] == list(range(duration))   # a status every cycle


def test_session_nominal_status_estimates_and_counters():
    cycles, summary, log = _run(110, hold_s=5.0)
    _check_intact(cycles, summary, 110)
    st = cycles[-1]["status"]
    assert st["adcs_mode_name"] == "POINT" and st["stale"] == 0
    assert summary["firmware_missed"]["rw"] == [0, 0, 0, 0] and summary["missed_rw_cmd"] == [0, 0, 0, 0]
    assert summary["link"]["bad_seq"] == 0 and summary["firmware_missed"]["rx_damaged"] == 0   # late: load
    assert 0 <= summary["firmware_missed"]["rx_damaged"] <= summary["firmware_missed"]["rx_drops"]
    # the estimates track the truth: SatA's GNSS-fed position within 100 m, attitude within 0.05 deg
    est = cycles[-1]["est"]
    ra_true = cycles[-2]["ra"][-1]
    assert np.linalg.norm(est["ra"] - ra_true) < 100.0
    q_true = cycles[-2]["q"][-1]
    assert 2 * np.degrees(np.arccos(min(1.0, abs(np.dot(est["q"], q_true))))) < 0.05
    assert any("ADCS mode POINT" in m for m in log)
    # the slew to SatB passes the star tracker's 0.1 deg/s: the ADCS says so (DEGRADED, stale star tracker)
    assert any(c["status"]["adcs_mode_name"] == "DEGRADED" and "STARTRACKER" in c["status"]["stale_names"]
               for c in cycles[5:100])


def test_fault_wheel_stops_answering():
    cycles, summary, _ = _run(20, {"wheel_silent": [2, 8]})
    _check_intact(cycles, summary, 20)
    st = cycles[-1]["status"]
    assert st["wheels_failed"] == 1 << 2 and st["adcs_mode_name"] == "DEGRADED" and "RW2" in st["stale_names"]
    assert st["miss_rw2"] == 12 and st["miss_rw0"] == st["miss_rw1"] == st["miss_rw3"] == 0
    assert cycles[9]["status"]["wheels_failed"] == 0 and cycles[10]["status"]["wheels_failed"] == 4
    assert {"t_s": 8.0, "event": "wheel_silent begins (wheel 2)"} in summary["fault_log"]
    assert summary["wheels_failed"] == 4


def test_fault_startracker_blinded_for_60_s():
    cycles, summary, _ = _run(80, {"startracker_blind": [10, 70]})
    _check_intact(cycles, summary, 80)
    blind = [c["status"] for c in cycles[10:70]]
    assert all("STARTRACKER" in s["stale_names"] for s in blind)
    assert blind[-1]["adcs_mode_name"] == "DEGRADED"
    assert cycles[-1]["status"]["n_st_invalid"] >= 60 and cycles[-1]["status"]["miss_st"] == 0
    # propagating without the star tracker the attitude covariance grows, and falls again once it is back
    assert blind[-1]["att_sigma"] > 3 * cycles[9]["status"]["att_sigma"]
    assert cycles[-1]["status"]["att_sigma"] < blind[-1]["att_sigma"]
    assert {"t_s": 70.0, "event": "startracker_blind ends"} in summary["fault_log"]


def test_fault_gnss_outage_of_5_minutes():
    cycles, summary, _ = _run(320, {"gnss_outage": [10, 310]})
    _check_intact(cycles, summary, 320)
    st = cycles[305]["status"]
    assert "GNSS_A" in st["stale_names"] and st["adcs_mode_name"] == "DEGRADED" and st["gnss_age_s"] >= 290
    assert cycles[-1]["status"]["miss_gnss"] == 300 and cycles[-1]["status"]["gnss_age_s"] == 0
    assert cycles[9]["status"]["adcs_mode_name"] == "HOLD" and cycles[-1]["status"]["adcs_mode_name"] == "HOLD"
    # SatA's position propagated through the outage stays within a few km of the truth
    assert np.linalg.norm(cycles[309]["est"]["ra"] - cycles[308]["ra"][-1]) < 5e3


def test_fault_beacon_lost():
    cycles, summary, _ = _run(30, {"beacon_lost": 12})
    _check_intact(cycles, summary, 30)
    st = cycles[-1]["status"]
    assert "BEACON" in st["stale_names"] and st["adcs_mode_name"] == "DEGRADED"
    assert st["n_beacon_invalid"] == 18 and st["miss_beacon"] == 0
    assert cycles[11]["status"]["n_beacon_invalid"] == 0


def test_replay_of_a_session_gives_its_status_under_micropython_and_cpython(tmp_path):
    """The sensor bursts a session sent, replayed through the application without CAN, give the status the
    firmware process sent (same runtime: equal; the other runtime: within float32 tolerance)."""
    import json
    with AdcsSession(runtime="micropython" if os.path.exists(MICROPYTHON) else "cpython", duration_s=40,
                     hold_s=20.0, record=True) as s:
        for _ in range(40):
            last = s.cycle()["status"]
        cfg, rec = s.config(), s.recorded
    (tmp_path / "cfg.json").write_text(json.dumps(cfg))
    (tmp_path / "rec.json").write_text(json.dumps(rec))
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    script = os.path.join(ROOT, "tests", "mp", "firmware_adcs_app.py")
    for exe in [sys.executable] + ([MICROPYTHON] if os.path.exists(MICROPYTHON) else []):
        p = subprocess.run([exe, script, str(tmp_path / "cfg.json"), str(tmp_path / "rec.json")], cwd=ROOT,
                           env=env, capture_output=True, text=True, timeout=120)
        assert p.returncode == 0, p.stderr
        st = json.loads(p.stdout.strip().splitlines()[-1])["status"]
        assert st["adcs_mode"] == last["adcs_mode"] and st["stale"] == last["stale"]
        for k in ("q0", "q1", "q2", "q3", "rax", "rbx"):
            assert st[k] == pytest.approx(last[k], rel=1e-5, abs=1e-6), k
    # the bench's split of the cycle (bench_adcs_can) runs on the same bursts through the app and its CAN HAL
    split = os.path.join(ROOT, "tests", "mp", "firmware_adcs_split.py")
    exe = MICROPYTHON if os.path.exists(MICROPYTHON) else sys.executable
    p = subprocess.run([exe, split, str(tmp_path / "cfg.json"), str(tmp_path / "rec.json"), "30", "40"], cwd=ROOT,
                       env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    acc = json.loads(p.stdout.strip().splitlines()[-1])
    assert acc["cycles"] == 10 and acc["hal"] > 0 and acc["counters"]["frames"] > 0
    assert 0 < acc["apkf"] + acc["stkf"] + acc["control"] <= acc["cycle"]


def test_session_with_satb_relayed_gnss_fuses_the_late_fixes():
    """SatB's GNSS, relayed 2-3 s late, goes through the AFLS (nodes generated at its time tags)."""
    cycles, summary, _ = _run(20, satb_gnss=True)
    _check_intact(cycles, summary, 20)
    st = cycles[-1]["status"]
    assert st["n_gnss_b"] >= 15 and "GNSS_B" not in st["stale_names"] and st["adcs_mode_name"] == "HOLD"
    assert np.linalg.norm(cycles[-1]["est"]["rb"] - cycles[-2]["rb"][-1]) < 100.0   # from a 4 km prior


def test_the_firmware_is_told_the_wheels_datasheet_not_the_truth():
    """The friction compensation and torque limit the firmware gets are the datasheet's: a truth wheel with
    5x the friction does not change them (it used to be compensated exactly)."""
    s = AdcsSession(runtime="cpython", duration_s=5)
    before = s.config()
    s.wheels.p.friction_coulomb *= 5.0
    s.wheels.p.friction_viscous *= 5.0
    s.wheels.p.torque_max *= 2.0
    after = s.config()
    assert after["friction"] == before["friction"] and after["torque_max"] == before["torque_max"]
    assert before["friction"][0] == WheelParams().friction_coulomb and before["torque_max"] == WheelParams().torque_max


def test_session_refuses_to_cycle_before_start_and_close_is_idempotent():
    s = AdcsSession(runtime="cpython", duration_s=5)
    with pytest.raises(OSError, match="not started"):
        s.cycle()
    s.close()
    s.close()
    with pytest.raises(ValueError, match="parameter file"):
        AdcsSession(runtime="cpython", duration_s=5, params={"format": "nope"})


def test_fps_adcs_can_writes_a_run_folder_and_refuses_bad_input(tmp_path):
    import json
    from ground import cli
    out = tmp_path / "run"
    rc = cli.main(["adcs", "can", "--session", "12", "--runtime", "cpython", "--beacon-lost", "1", "--quiet",
                   "-o", str(out)])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] and s["cycles"] == 12 and s["last_mode"] == "DEGRADED"
    assert s["firmware_missed"]["beacon_invalid"] == 11 and "pointing" not in s      # too short to settle
    h = np.load(out / "history.npz")
    assert h["t"].shape == (120,) and h["dtheta_arcsec"].shape == (120, 2) and h["status_tick"].tolist() == list(range(12))
    assert (out / "pointing.png").stat().st_size > 0
    for bad in (["--wheel-silent", "7:3"], ["--gnss-outage", "50"], ["--session", "0"]):
        assert cli.main(["adcs", "can", "--runtime", "cpython", "--quiet", "-o", str(tmp_path / "b")] + bad) == 2


def test_fps_adcs_can_interrupted_leaves_a_valid_partial_folder(tmp_path, monkeypatch):
    import json
    from emulator import adcs_session
    from ground import cli
    real = adcs_session.AdcsSession.cycle

    def cycle(self):
        if self.k == 5:
            raise KeyboardInterrupt
        return real(self)
    monkeypatch.setattr(adcs_session.AdcsSession, "cycle", cycle)
    out = tmp_path / "run"
    assert cli.main(["adcs", "can", "--session", "30", "--runtime", "cpython", "--quiet", "-o", str(out)]) == 130
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is False and s["cycles"] == 5
    assert np.load(out / "history.npz")["t"].shape == (50,)


@pytest.mark.parametrize("runtime", _runtimes())
def test_a_lost_hello_either_way_costs_a_retry_not_the_session(tmp_path, runtime):
    """--link-faults first=1: the firmware's HELLO and this side's first HELLO are lost; the session says HELLO
    again until the firmware answers, and the run completes with the retries counted."""
    import json
    from ground import cli
    out = tmp_path / "run"
    assert cli.main(["adcs", "can", "--session", "3", "--runtime", runtime, "--quiet", "--no-plots",
                     "--link-faults", "first=1", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] and s["cycles"] == 3 and s["retries"]["hello_tries"] >= 2
    assert s["link"]["fault_tx_dropped"] == s["link"]["fault_rx_dropped"] == 1


def test_a_firmware_that_never_answers_hello_is_named_with_the_link_not_the_input_files(tmp_path, monkeypatch,
                                                                                         capsys):
    """Every frame lost (first=1000000): after the wait, the message says the firmware did not answer HELLO over
    which link, with the link's counters, in the folder's summary.json too; no traceback, exit 1."""
    import json
    from emulator import adcs_session
    from ground import cli
    monkeypatch.setattr(adcs_session, "HELLO_WAIT_S", 1.5)
    out = tmp_path / "run"
    assert cli.main(["adcs", "can", "--session", "3", "--runtime", "cpython", "--quiet", "--no-plots",
                     "--link-faults", "first=1000000", "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "did not answer HELLO over CAN (slcan on /dev/pts/" in err and "within 1.5 s" in err
    assert "link counters:" in err and "fault_tx_dropped=" in err and "fault_rx_dropped=" in err
    assert "parameter" not in err and "spacecraft" not in err and "Traceback" not in err
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is False and "did not answer HELLO" in s["error"] and s["retries"]["hello_tries"] >= 5
    assert s["link"]["fault_tx_dropped"] == s["retries"]["hello_tries"]      # every HELLO sent was lost


def test_the_firmware_answers_each_hello_and_the_in_process_app_too():
    from emulator.adcs_session import AdcsSession
    from firmware.adcs.lockstep import InProcess
    s = AdcsSession(runtime="inproc", duration_s=2)
    s.start()
    try:
        assert isinstance(s.link, InProcess)
        P, N = core.PACKET_ID, core.NODE
        s.link.send_raw(P["HELLO"], N["SPACECRAFT"], N["ADCS"], core.encode_payload("HELLO", node=N["SPACECRAFT"]))
        [(pid, src, dst, _, payload)] = [p for p in s.link.recv() if p[0] == P["HELLO"]]
        assert (src, dst, core.payload_dict(pid, payload)["node"]) == (N["ADCS"], N["SPACECRAFT"], N["ADCS"])
    finally:
        s.close()


ADAPTER = r"""
import json, sys
from firmware.hal.slcan import SlcanAdapter
ad = SlcanAdapter(int(sys.argv[1]))
frames = []
for _ in range(25):                  # a frame, or 5 s
    if ad.closed or frames:
        break
    frames += ad.poll(200)
res = {"open": ad.is_open, "bad": ad.n_bad, "frames": [[c, e, list(d)] for c, e, d in frames]}
for _ in range(25):                  # then the host's C (it has read the answers), or 5 s
    if ad.closed or not ad.is_open:
        break
    ad.poll(200)
print(json.dumps(res))
"""


@pytest.mark.parametrize("runtime", _runtimes())
def test_slcan_adapter_drops_an_overlong_line_whole(tmp_path, runtime):
    """A line longer than the adapter's buffer is dropped up to its CR and answered BEL once. (Its tail used to
    be parsed as a command of its own: 'C' there closed the channel, and every frame after it was refused.)"""
    p, s = _adapter_on_pty(tmp_path / "adapter.py", ADAPTER, runtime, stdout=subprocess.PIPE, text=True)
    try:
        os.write(s, b"O\r")
        os.write(s, b"x" * 65 + b"C\r")            # overlong, its tail a command letter
        os.write(s, b"T0A8A603020102\r")
        import select
        answers, t_end = b"", time.monotonic() + 10.0
        while len(answers) < 4 and time.monotonic() < t_end:
            if select.select([s], [], [], 0.2)[0]:
                answers += os.read(s, 100)
        os.write(s, b"C\r")
        out, _ = p.communicate(timeout=20)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        os.close(s)
    import json
    r = json.loads(out.strip().splitlines()[-1])
    assert r["open"] and r["bad"] == 1
    assert r["frames"] == [[0x0A8A6030, True, [1, 2]]]
    assert answers == b"\r\aZ\r"
