"""Wheels and star tracker as protocol devices: RW_CMD -> RW_TLM, NACKs, STARTRACKER, determinism, transports."""

import os
import time

import numpy as np
import pytest

from protocol import core
from emulator.spacecraft import Spacecraft, SpacecraftDevices, StarTracker, WheelParams, Wheels
from protocol.units import RAD_PER_ARCSEC
from emulator.spacecraft.dynamics import dcm, quat_mul
from emulator.spacecraft.wheels import RPM

ADCS = core.NODE["ADCS"]
RW = [core.NODE["RW%d" % i] for i in range(4)]
RW_CMD, RW_TLM = core.PACKET_ID["RW_CMD"], core.PACKET_ID["RW_TLM"]
NACK, ST = core.PACKET_ID["NACK"], core.PACKET_ID["STARTRACKER"]


def _devices(seed=0, **kw):
    rng = np.random.default_rng(seed)
    sc = Spacecraft(wheels=Wheels(WheelParams(**kw), rng=rng), orbit=None,
                    omega_rw=np.array([1000.0, -2000.0, 500.0, 0.0]) * RPM)
    return sc, SpacecraftDevices(sc)


def test_rw_cmd_answered_with_telemetry_and_drives_the_wheel():
    sc, dev = _devices()
    out = dev.handle(RW_CMD, ADCS, RW[2], core.encode_payload("RW_CMD", torque=2e-4, enable=1))
    assert len(out) == 1
    pid, src, dst, payload = out[0]
    assert (pid, src, dst) == (RW_TLM, RW[2], ADCS)
    tlm = core.payload_dict(pid, payload)
    assert abs(tlm["speed"] - 500.0) < 6 * 10.0
    assert tlm["torque"] == pytest.approx(2e-4, rel=1e-6)          # float32 on the wire
    w0 = sc.omega_rw.copy()
    sc.run(1.0)
    friction = sc.wheels.friction(w0[2])
    assert sc.omega_rw[2] - w0[2] == pytest.approx((2e-4 - friction) / sc.wheels.j[2] * 1.0, rel=1e-3)


def test_rw_cmd_over_the_limit_reports_the_clipped_torque_and_coast():
    sc, dev = _devices(torque_max=1e-3)
    tlm = core.payload_dict(RW_TLM, dev.handle(RW_CMD, ADCS, RW[0],
                                               core.encode_payload("RW_CMD", torque=-5e-3))[0][3])
    assert tlm["torque"] == pytest.approx(-1e-3, rel=1e-6)
    tlm = core.payload_dict(RW_TLM, dev.handle(RW_CMD, ADCS, RW[0],
                                               core.encode_payload("RW_CMD", torque=-5e-3, enable=0))[0][3])
    assert tlm["torque"] == 0.0
    assert not sc.wheels.enable[0]


def test_bad_packets_get_nacks_and_leave_the_command():
    sc, dev = _devices()
    nan = b"\x00\x00\xc0\x7f" + core.encode_payload("RW_CMD", torque=1.0)[4:]     # float32 NaN torque
    cases = [
        (RW_CMD, nan, "BAD_VALUE"),
        (RW_CMD, b"\x00\x00", "BAD_VALUE"),
        (RW_CMD, core.encode_payload("RW_CMD")[:4] + b"\x02", "BAD_VALUE"),     # enable = 2
        (core.PACKET_ID["HELLO"], core.encode_payload("HELLO"), "UNKNOWN_PACKET"),
    ]
    for pid, payload, code in cases:
        out = dev.handle(pid, ADCS, RW[1], payload, seq=7)
        assert len(out) == 1 and out[0][:3] == (NACK, RW[1], ADCS)
        assert core.payload_dict(NACK, out[0][3]) == {"ref_id": pid, "ref_seq": 7, "code": core.ERROR[code]}
    assert dev.n_nack == 4 and sc.wheels.cmd[1] == 0.0
    assert dev.handle(RW_CMD, ADCS, core.NODE["CONTROLLER"], core.encode_payload("RW_CMD")) == []


def test_telemetry_stream_is_deterministic_per_seed():
    def stream(seed):
        sc, dev = _devices(seed)
        out = []
        for k in range(20):
            for i in range(4):
                out += [p[3] for p in dev.handle(RW_CMD, ADCS, RW[i], core.encode_payload("RW_CMD", torque=1e-5))]
            out.append(dev.startracker()[3])
            sc.run(0.5)
        return out

    a, b, c = stream(5), stream(5), stream(6)
    assert a == b
    assert a != c


def test_startracker_noise_and_validity():
    rng = np.random.default_rng(11)
    st = StarTracker(rng)
    q = np.array([0.2, -0.4, 0.1, 0.8])
    q /= np.linalg.norm(q)
    errs = []
    for _ in range(3000):
        qm, valid = st.measure(q, np.radians([0.05, 0.05, 0.0]))
        assert valid
        dq = quat_mul(qm, q * np.array([-1, -1, -1, 1]))          # q_meas (x) q^-1 = q_n (Eq. 4.63)
        errs.append(2 * dq[:3] * np.sign(dq[3]))
    sig = np.array(errs).std(axis=0) / RAD_PER_ARCSEC
    assert np.all(np.abs(sig / np.array([20.0, 20.0, 60.0]) - 1) < 0.06)
    assert st.measure(q, np.radians([0.08, 0.0, 0.07]))[1] is False        # |w| = 0.106 deg/s


def test_startracker_packet_carries_the_attitude():
    sc = Spacecraft(orbit=None, q=(0.3, 0.1, -0.2, 0.9))
    dev = SpacecraftDevices(sc, StarTracker(np.random.default_rng(0), sigma_arcsec=(0.0, 0.0, 0.0)))
    pid, src, dst, payload = dev.startracker()
    assert (pid, src, dst) == (ST, core.NODE["STARTRACKER"], ADCS)
    d = core.payload_dict(pid, payload)
    qm = np.array([d["q0"], d["q1"], d["q2"], d["q3"]])
    assert d["valid"] == 1
    assert np.allclose(dcm(qm), dcm(sc.q), atol=1e-6)
    sc.x[4:7] = np.radians([0.2, 0.0, 0.0])
    assert core.payload_dict(ST, dev.startracker()[3])["valid"] == 0


def _exchange_frames(dev, frames_in):
    """Bytes in, bytes out: the device behind a frame decoder, as a serial link would carry it."""
    dec, out = core.Decoder(), b""
    for pid, src, dst, seq, payload in dec.feed(frames_in):
        for k, (p, s, d, pl) in enumerate(dev.handle(pid, src, dst, payload, seq)):
            out += core.encode_frame(p, s, d, seq + k, pl)
    return out


def test_rw_devices_over_encoded_frames():
    sc, dev = _devices(noise_rpm=0.0)
    frames = b"".join(core.encode_packet("RW_CMD", ADCS, RW[i], i, torque=1e-4 * (i + 1)) for i in range(4))
    replies = core.Decoder().feed(_exchange_frames(dev, frames))
    assert [(r[0], r[1], r[2]) for r in replies] == [(RW_TLM, RW[i], ADCS) for i in range(4)]
    speeds = [core.payload_dict(RW_TLM, r[4])["speed"] for r in replies]
    assert np.allclose(speeds, sc.omega_rw / RPM, rtol=1e-6)
    assert np.allclose(sc.wheels.cmd, [1e-4, 2e-4, 3e-4, 4e-4])


def _serve(links, dev, timeout=1.0):
    """Device side: answer everything that arrives on ``links`` (one pass, waiting up to ``timeout`` each)."""
    n = 0
    for link in links:
        for pid, src, dst, seq, payload in link.recv(timeout=timeout):
            for p, s, d, pl in dev.handle(pid, src, dst, payload, seq):
                link.send_raw(p, s, d, pl)
                n += 1
    return n


def _collect(link, n, timeout=2.0):
    got = []
    deadline = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        got += link.recv(timeout=0.1)
    return got


def test_rw_devices_over_inproc_link():
    from protocol import link
    ground, device = link.inproc_pair("ADCS", "SPACECRAFT")
    sc, dev = _devices()
    for i in range(4):
        ground.send("RW_CMD", RW[i], torque=5e-5 * (i + 1))
    ground.send("RW_CMD", RW[3], payload=b"\x00\x00\xc0\x7f\x01\x00")  # NaN torque: NACK, seq echoed
    served = 0
    while served < 5:
        n = _serve([device], dev)
        assert n, "device got nothing"
        served += n
    got = _collect(ground, 5)
    assert [(g[0], g[1], g[2]) for g in got] == [(RW_TLM, RW[i], ADCS) for i in range(4)] + [(NACK, RW[3], ADCS)]
    assert core.payload_dict(NACK, got[4][4])["ref_seq"] == 4
    assert np.allclose(sc.wheels.cmd, 5e-5 * np.arange(1, 5))
    ground.close()
    device.close()


def test_rw_devices_over_virtual_can():
    from protocol import link
    chan = "fps-rw-%d" % os.getpid()
    adcs = link.open_link("can:virtual:" + chan, "ADCS")
    wheels = [link.open_link("can:virtual:" + chan, "RW%d" % i) for i in range(4)]   # one node per wheel
    try:
        sc, dev = _devices()
        for i in range(4):
            adcs.send("RW_CMD", RW[i], torque=-2e-5 * (i + 1))
        assert _serve(wheels, dev) == 4
        got = _collect(adcs, 4)
        assert sorted((g[0], g[1], g[2]) for g in got) == [(RW_TLM, RW[i], ADCS) for i in range(4)]
        for g in got:
            i = RW.index(g[1])
            assert core.payload_dict(RW_TLM, g[4])["torque"] == pytest.approx(-2e-5 * (i + 1), rel=1e-6)
    finally:
        for lk in [adcs] + wheels:
            lk.close()
