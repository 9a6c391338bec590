"""``fps emulator serve --devices wheels`` as a subprocess: this test is the flight computer (ADCS) on the pty
(serial) or on python-can's slcan adapter over the pty (CAN); RW_CMD -> RW_TLM from each wheel, NACKs for bad
values, STARTRACKER at 1 Hz, counters at the end, clean stop on SIGTERM."""

import json
import math
import os
import signal
import struct
import subprocess
import sys
import time

import pytest

from protocol import core

from protocol import link as link_mod

ADCS = core.NODE["ADCS"]
RW = [core.NODE["RW%d" % i] for i in range(4)]
RW_CMD, RW_TLM = core.PACKET_ID["RW_CMD"], core.PACKET_ID["RW_TLM"]
NACK, ST = core.PACKET_ID["NACK"], core.PACKET_ID["STARTRACKER"]
DT = 0.1


def _start(tmp_path, link, *extra):
    summary = tmp_path / "wheels.json"
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    proc = subprocess.Popen([sys.executable, "-m", "ground.cli", "emulator", "serve", "--devices", "wheels",
                             "--link", link, "--seed", "3", "--wait", "10", "-o", str(summary)] + list(extra),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), proc.stderr.read() if proc.poll() is not None else path
    try:
        adcs = link_mod.open_link(("serial:" if link == "serial" else "slcan:") + path, "ADCS")
    except Exception:
        proc.kill()
        raise
    return proc, adcs, summary


def _collect(link, want, got, timeout=3.0):
    """Receive into ``got`` until ``want(got)`` holds or ``timeout`` s pass."""
    deadline = time.monotonic() + timeout
    while not want(got) and time.monotonic() < deadline and not link.closed:
        got += link.recv(timeout=0.05)
    return got


def _of(got, pid):
    return [g for g in got if g[0] == pid]


@pytest.mark.parametrize("link", ["serial", "can"])
def test_wheels_served_on_a_link(tmp_path, link):
    duration = 2.8      # the clipped command goes out after the t = 1 s STARTRACKER: 1.8 s left to answer it
    proc, adcs, summary = _start(tmp_path, link, "--duration", str(duration))
    try:
        adcs.send("HELLO", "SPACECRAFT", node=ADCS)                     # the clock starts here
        torques = [1e-6 * (i + 1) * (-1) ** i for i in range(4)]       # small: |w| stays < 0.1 deg/s
        for i in range(4):
            adcs.send("RW_CMD", RW[i], torque=torques[i])
        got = _collect(adcs, lambda g: len(_of(g, RW_TLM)) >= 4, [])      # every packet, in order
        tlm = _of(got, RW_TLM)
        assert sorted(t[1] for t in tlm) == RW and all(t[2] == ADCS for t in tlm)
        for t in tlm:
            d = core.payload_dict(RW_TLM, t[4])
            assert d["torque"] == pytest.approx(torques[RW.index(t[1])], rel=1e-6)
            assert abs(d["speed"]) < 6 * 10.0                            # at rest, 10 rpm 1-sigma read-out

        good = core.encode_payload("RW_CMD", torque=1e-6)
        bad = [(RW[1], struct.pack("<f", math.nan) + good[4:]), (RW[2], struct.pack("<f", -math.inf) + good[4:]),
               (RW[3], good[:4] + b"\x02" + good[5:])]                    # NaN, -inf torque; enable = 2
        seqs = [adcs.send("RW_CMD", dst, payload=p) for dst, p in bad]
        _collect(adcs, lambda g: len(_of(g, NACK)) >= 3, got)
        nacks = _of(got, NACK)
        assert [n[1] for n in nacks] == [b[0] for b in bad]
        for n, seq in zip(nacks, seqs):
            d = core.payload_dict(NACK, n[4])
            assert (d["ref_id"], d["code"]) == (RW_CMD, core.ERROR["BAD_VALUE"])
            assert d["ref_seq"] == (seq if link == "serial" else 0)     # no sequence numbers on CAN

        _collect(adcs, lambda g: len(_of(g, ST)) >= 2, got)               # t = 0 and t = 1 s
        adcs.send("RW_CMD", RW[0], torque=5e-3)                          # over the 1 mN m limit: clipped
        _collect(adcs, lambda g: len(_of(g, RW_TLM)) >= 5, got)
        assert core.payload_dict(RW_TLM, _of(got, RW_TLM)[4][4])["torque"] == pytest.approx(1e-3, rel=1e-6)
        out, err = proc.communicate(timeout=10)
    finally:
        adcs.close()
        proc.kill()
    sts = [core.payload_dict(ST, s[4]) for s in _of(got, ST)]
    assert all(s[1:3] == (core.NODE["STARTRACKER"], ADCS) for s in _of(got, ST))
    assert [s["t_ms"] for s in sts[:2]] == [0, 1000]
    assert sts[0]["valid"] == 1 and sts[1]["valid"] == 1
    for s in sts:
        assert math.sqrt(s["q0"] ** 2 + s["q1"] ** 2 + s["q2"] ** 2 + s["q3"] ** 2) == pytest.approx(1.0, abs=1e-6)

    assert proc.returncode == 0, err
    assert "stopped by duration" in err
    d = json.loads(summary.read_text())
    assert d["stopped_by"] == "duration" and d["steps"] == round(duration / DT)
    assert d["packets_rx"] == {"HELLO": 1, "RW_CMD": 8}
    assert d["packets_tx"] == {"RW_TLM": 5, "NACK": 3, "STARTRACKER": 3}      # t = 0, 1 and 2 s
    assert d["nacks"] == {"BAD_VALUE": 3}
    assert d["clips"]["torque_clip"][0] > 0 and d["clips"]["torque_clip"][1:] == [0, 0, 0]
    from protocol import can as canmap
    lc = d["link_counters"]
    drops = {k: v for k, v in lc.items() if k in canmap.LINK_DROPS or k.startswith(("isotp_", "tx_isotp_"))}
    assert drops and not any(drops.values()), drops


def test_sigterm_stops_the_wheels_cleanly(tmp_path):
    proc, adcs, summary = _start(tmp_path, "serial")
    try:
        adcs.send("RW_CMD", RW[0], torque=2e-6)
        got = _collect(adcs, lambda g: _of(g, RW_TLM) and _of(g, ST), [])
        assert _of(got, RW_TLM) and _of(got, ST)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=5)
    finally:
        adcs.close()
        proc.kill()
    assert proc.returncode == 0, err
    d = json.loads(summary.read_text())
    assert d["stopped_by"] == "SIGTERM" and d["packets_rx"] == {"RW_CMD": 1}
    assert "stopped by SIGTERM" in err
