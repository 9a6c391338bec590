"""Magnetorquers (MTQ_CMD -> MTQ_TLM) and the magnetometer (MAGNETOMETER) as CAN devices: the packets from the
table, the devices' models, SpacecraftDevices over a virtual CAN bus, and the ADCS session's truth."""

import copy
import os
import struct
import time

import cantools
import numpy as np
import pytest

from emulator.spacecraft import Spacecraft
from emulator.spacecraft.devices import (MAG_COUNT_NT, MAG_FULL_SCALE_T, Magnetometer, Magnetorquers,
                                         SpacecraftDevices, field_body)
from emulator.spacecraft.dynamics import dcm
from protocol import can as canmap
from protocol import core, table
from protocol import spacecraft as sf

P, N = core.PACKET_ID, core.NODE
NEW = ("MTQ_CMD", "MTQ_TLM", "MAGNETOMETER")
VALUES = {
    "MTQ_CMD": {"mx": 0.125, "my": -0.25, "mz": 1.5, "enable": 1, "cycle": 200},
    "MTQ_TLM": {"mx": 0.125, "my": -0.25, "mz": 0.3125, "saturated": 4, "silent": 2},
    "MAGNETOMETER": {"t_ms": 123456, "bx": 212345, "by": -98765, "bz": 1000000, "valid": 1},
}


def _spacecraft_file(mtq="keep", mag="keep"):
    """thesis-3u, checked, with the magnetorquers and magnetometer blocks given (``"keep"``: the file's)."""
    d = copy.deepcopy(sf.load("thesis-3u"))
    if mtq != "keep":
        d["magnetorquers"] = mtq
    if mag != "keep":
        d["magnetometer"] = mag
    return sf.check(d)


# --- the table ---------------------------------------------------------------------------------------------
def test_new_nodes_and_packets_are_in_the_table():
    nodes = dict((n[0], n[1]) for n in table.NODES)
    assert nodes["MTQ"] == 0x53 and nodes["MAGNETOMETER"] == 0x54
    assert len(set(nodes.values())) == len(nodes)
    assert [P[n] for n in NEW] == [0x48, 0x49, 0x4A]
    for n in NEW:
        d = core.packet_def(n)
        assert canmap.priority(d.id) == canmap.priority(P["RW_CMD"])      # the wheels' and sensors' priority
    assert (core.packet_def("MTQ_CMD").src, core.packet_def("MTQ_CMD").dst) == ("ADCS", "MTQ")
    assert (core.packet_def("MTQ_TLM").src, core.packet_def("MTQ_TLM").dst) == ("MTQ", "ADCS")
    assert (core.packet_def("MAGNETOMETER").src, core.packet_def("MAGNETOMETER").dst) == ("MAGNETOMETER", "ADCS")
    assert core.field_scales("MAGNETOMETER")["bx"] == 0.1 and core.packet_def("MAGNETOMETER").fields[1][2] == "nT"
    assert MAG_FULL_SCALE_T == pytest.approx(1e-4)
    assert len(table.ADCS_STALE) == 8                  # the stale byte is full: no bit for the new packets


@pytest.mark.parametrize("name", NEW)
def test_round_trip_serial_and_can(name):
    values = VALUES[name]
    pid = P[name]
    payload = core.encode_payload(name, values)
    assert core.payload_dict(pid, payload) == values
    src, dst = N[core.packet_def(name).src], N[core.packet_def(name).dst]
    [(pid2, s, d, q, pl)] = core.Decoder().feed(core.encode_packet(name, src, dst, 9, values))
    assert (pid2, s, d, q, pl) == (pid, src, dst, 9, payload)
    frames = canmap.encode_packet(name, src, dst, values)
    assert len(frames) > 1 and not canmap.is_single(pid)        # over 8 bytes with the check: ISO-TP
    dec = canmap.CanDecoder()
    got = [dec.feed(cid, data) for cid, data in frames]
    assert got[:-1] == [None] * (len(frames) - 1) and got[-1] == (pid, src, dst, None, payload)


def test_encoders_refuse_values_out_of_range():
    bad = [("MTQ_CMD", "enable", 2), ("MTQ_CMD", "mx", float("nan")), ("MTQ_CMD", "my", float("inf")),
           ("MTQ_CMD", "cycle", 256), ("MTQ_TLM", "saturated", 8), ("MTQ_TLM", "mz", 1e39),
           ("MAGNETOMETER", "bx", 1000001), ("MAGNETOMETER", "bz", -1000001), ("MAGNETOMETER", "valid", 2),
           ("MAGNETOMETER", "by", 0.5)]
    for name, field, v in bad:
        with pytest.raises(ValueError, match=field):
            core.encode_payload(name, dict(VALUES[name], **{field: v}))


def test_dbc_names_the_new_nodes_and_lists_only_single_frame_packets(tmp_path):
    path = tmp_path / "fps.dbc"
    path.write_text(canmap.dbc_text())
    db = cantools.database.load_file(str(path), frame_id_mask=canmap.PID_MASK | canmap.ISOTP_BIT)
    assert {"MTQ", "MAGNETOMETER"} <= set(n.name for n in db.nodes)
    names = set(m.name for m in db.messages)
    for n in NEW:                                       # in the DBC exactly when the packet is one frame
        assert (n in names) == canmap.is_single(P[n])
    assert names == set(core.PACKET[p].name for p in core.PACKET if canmap.is_single(p))


# --- the devices' models -----------------------------------------------------------------------------------
def test_magnetometer_bias_is_constant_and_noise_has_its_sigma():
    mag = Magnetometer(np.random.default_rng(3), noise_nt=50.0, bias_nt=200.0)
    bias = mag.bias.copy()
    b = np.array([20e-6, -5e-6, 35e-6])
    z = np.array([mag.measure(b)[0] for _ in range(20000)])
    assert np.array_equal(mag.bias, bias)                                       # drawn once
    err_nt = (z - b - bias) * 1e9
    assert np.all(np.abs(err_nt.std(axis=0) / 50.0 - 1.0) < 0.03)
    assert np.all(np.abs(err_nt.mean(axis=0)) < 4 * 50.0 / np.sqrt(len(z)))
    biases = np.array([Magnetometer(np.random.default_rng(s), 50.0, 200.0).bias for s in range(3000)]) * 1e9
    assert abs(biases.std() / 200.0 - 1.0) < 0.04 and abs(biases.mean()) < 4 * 200.0 / np.sqrt(biases.size)
    a, c = Magnetometer(np.random.default_rng(7), 50.0, 200.0), Magnetometer(np.random.default_rng(7), 50.0, 200.0)
    assert np.array_equal(a.measure(b)[0], c.measure(b)[0])                    # seeded: the same stream
    assert mag.measure(b)[1] is True
    assert mag.measure([MAG_FULL_SCALE_T * 1.01, 0.0, 0.0])[1] is False          # beyond full scale
    with pytest.raises(ValueError):
        Magnetometer(np.random.default_rng(0), -1.0, 0.0)


def test_magnetorquers_clip_each_rod():
    mtq = Magnetorquers([[1, 0, 0], [0, 1, 0], [0, 0, 1]], 0.3)
    applied, sat = mtq.command([0.1, -0.5, 0.2])
    assert np.allclose(applied, [0.1, -0.3, 0.2]) and list(sat) == [False, True, False]
    assert np.allclose(mtq.applied, applied) and mtq.saturated_bits() == 2
    applied, sat = mtq.command([0.9, 0.3, -0.31])
    assert np.allclose(applied, [0.3, 0.3, -0.3]) and list(sat) == [True, False, True]
    assert mtq.saturated_bits() == 5
    with pytest.raises(ValueError):
        mtq.command([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError):
        Magnetorquers([[1, 0, 0], [0, 1, 0]], 0.3)
    with pytest.raises(ValueError):
        Magnetorquers([[1, 0, 0], [0, 1, 0], [0, 0, 1]], 0.0)


def test_magnetorquers_share_by_least_squares_on_skewed_rods():
    axes = [[1, 0, 0], [1, 1, 0], [0, 1, 1]]                     # not orthogonal, not unit: normalised
    A = np.array(axes, float) / np.linalg.norm(axes, axis=1)[:, None]
    m = np.array([0.05, -0.12, 0.07])
    mtq = Magnetorquers(axes, 10.0)
    applied, sat = mtq.command(m)
    assert np.allclose(applied, m, atol=1e-12) and not sat.any()
    assert np.allclose(mtq.share, np.linalg.solve(A.T, m))
    s = np.linalg.solve(A.T, m)                                   # each rod's share, unclipped
    lim = 0.5 * np.sort(np.abs(s))[1]                             # clips the two larger shares
    mtq = Magnetorquers(axes, lim)
    applied, sat = mtq.command(m)
    assert list(sat) == list(np.abs(s) > lim) and sat.sum() == 2
    assert np.allclose(mtq.share, np.clip(s, -lim, lim)) and np.allclose(applied, A.T @ np.clip(s, -lim, lim))


def test_devices_from_the_spacecraft_file_and_null_blocks():
    d = _spacecraft_file(mtq={"axes": [[0, 0, 2], [0, 3, 0], [1, 0, 0]], "dipole_limit_am2": 0.4},
                         mag={"noise_nt": 30.0, "bias_nt": 0.0, "rate_hz": 5.0})
    mtq = Magnetorquers.from_spacecraft(d, np.random.default_rng(0))
    assert mtq.limit == 0.4 and np.allclose(mtq.axes, [[0, 0, 1], [0, 1, 0], [1, 0, 0]])
    mag = Magnetometer.from_spacecraft(d, np.random.default_rng(0))
    assert mag.noise == pytest.approx(30e-9) and np.all(mag.bias == 0) and mag.rate_hz == 5.0
    null = _spacecraft_file(mtq=None, mag=None)
    assert Magnetorquers.from_spacecraft(null, None) is None
    assert Magnetometer.from_spacecraft(null, np.random.default_rng(0)) is None


# --- SpacecraftDevices -------------------------------------------------------------------------------------
def _devices(mag=None, limit=0.3, dipole=(0.01, -0.02, 0.03)):
    sc = Spacecraft(q=(0.1, -0.3, 0.2, 0.9), dipole=dipole)       # the thesis's circular orbit and dipole field
    return sc, SpacecraftDevices(sc, magnetometer=mag,
                                 magnetorquers=Magnetorquers([[1, 0, 0], [0, 1, 0], [0, 0, 1]], limit))


def test_mtq_cmd_answered_with_mtq_tlm_and_sets_the_dipole():
    sc, dev = _devices()
    out = dev.handle(P["MTQ_CMD"], N["ADCS"], N["MTQ"],
                     core.encode_payload("MTQ_CMD", mx=0.1, my=-0.5, mz=0.25, cycle=3))
    [(pid, src, dst, payload)] = out
    assert (pid, src, dst) == (P["MTQ_TLM"], N["MTQ"], N["ADCS"])
    tlm = core.payload_dict(pid, payload)
    assert [tlm["mx"], tlm["my"], tlm["mz"]] == pytest.approx([0.1, -0.3, 0.25], rel=1e-6)
    assert tlm["saturated"] == 2
    assert np.allclose(sc.dipole, [0.11, -0.32, 0.28])                         # residual + applied
    out = dev.handle(P["MTQ_CMD"], N["ADCS"], N["MTQ"], core.encode_payload("MTQ_CMD", mx=0.1, enable=0))
    assert core.payload_dict(P["MTQ_TLM"], out[0][3]) == {"mx": 0.0, "my": 0.0, "mz": 0.0, "saturated": 0,
                                                          "silent": 0}
    assert np.allclose(sc.dipole, [0.01, -0.02, 0.03]) and dev.n_mtq_cmd == 2


def test_bad_mtq_cmds_get_nacks_and_leave_the_dipole():
    sc, dev = _devices()
    dev.handle(P["MTQ_CMD"], N["ADCS"], N["MTQ"], core.encode_payload("MTQ_CMD", mz=0.2))
    nan = struct.pack("<fffBB", float("nan"), 0.0, 0.0, 1, 0)
    cases = [(P["MTQ_CMD"], nan, "BAD_VALUE"), (P["MTQ_CMD"], b"\x00" * 5, "BAD_VALUE"),
             (P["MTQ_CMD"], struct.pack("<fffBB", 0.1, 0.0, 0.0, 2, 0), "BAD_VALUE"),
             (P["RW_CMD"], core.encode_payload("RW_CMD"), "UNKNOWN_PACKET")]
    for pid, payload, code in cases:
        [(npid, src, dst, pl)] = dev.handle(pid, N["ADCS"], N["MTQ"], payload, seq=4)
        assert (npid, src, dst) == (P["NACK"], N["MTQ"], N["ADCS"])
        assert core.payload_dict(npid, pl) == {"ref_id": pid, "ref_seq": 4, "code": core.ERROR[code]}
    assert np.allclose(sc.dipole, [0.01, -0.02, 0.23]) and dev.n_nack == 4
    plain = SpacecraftDevices(Spacecraft())                                     # no magnetorquers: not on the bus
    assert plain.handle(P["MTQ_CMD"], N["ADCS"], N["MTQ"], core.encode_payload("MTQ_CMD")) == []
    assert plain.magnetometer() is None


def test_magnetometer_packet_carries_the_true_body_field():
    mag = Magnetometer(np.random.default_rng(0), noise_nt=0.0, bias_nt=0.0)
    sc, dev = _devices(mag=mag)
    sc.run(3.0)
    pid, src, dst, payload = dev.magnetometer()
    assert (pid, src, dst) == (P["MAGNETOMETER"], N["MAGNETOMETER"], N["ADCS"])
    d = core.payload_dict(pid, payload)
    b = dcm(sc.q) @ sc.field.field(sc.orbit.position(sc.t), sc.t)
    assert np.allclose(field_body(sc), b)
    assert d["valid"] == 1 and d["t_ms"] == 3000
    got = np.array([d["bx"], d["by"], d["bz"]]) * MAG_COUNT_NT * 1e-9
    assert np.all(np.abs(got - b) <= 0.5 * MAG_COUNT_NT * 1e-9 + 1e-15) and np.linalg.norm(b) > 1e-5


def _collect(link, n, timeout=3.0):
    got = []
    deadline = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        got += link.recv(timeout=0.1)
    return got


def test_mtq_over_virtual_can():
    """ADCS and MTQ as two nodes on a python-can virtual bus: MTQ_CMD and MTQ_TLM both go by ISO-TP."""
    from protocol import link
    chan = "fps-mtq-%d" % os.getpid()
    adcs = link.open_link("can:virtual:" + chan, "ADCS")
    mtq = link.open_link("can:virtual:" + chan, "MTQ")
    try:
        sc, dev = _devices()
        adcs.send("MTQ_CMD", N["MTQ"], mx=-0.4, my=0.125, mz=0.0, cycle=7)
        [(pid, src, dst, seq, payload)] = _collect(mtq, 1)
        assert (pid, src, dst, seq) == (P["MTQ_CMD"], N["ADCS"], N["MTQ"], None)
        for p, s, d, pl in dev.handle(pid, src, dst, payload, seq):
            mtq.send_raw(p, s, d, pl)
        [(pid, src, dst, _, payload)] = _collect(adcs, 1)
        assert (pid, src, dst) == (P["MTQ_TLM"], N["MTQ"], N["ADCS"])
        tlm = core.payload_dict(pid, payload)
        assert [tlm["mx"], tlm["my"], tlm["mz"]] == pytest.approx([-0.3, 0.125, 0.0]) and tlm["saturated"] == 1
        assert np.allclose(sc.dipole, [-0.29, 0.105, 0.03])
        c = adcs.counters()
        assert c.get("tx_isotp_TimeoutError", 0) == 0 and c["bad_crc"] == 0
    finally:
        adcs.close()
        mtq.close()


# --- the ADCS session --------------------------------------------------------------------------------------
class _Link:
    """The session's link without a firmware: what it sends is kept, ``queue`` is what it receives next."""
    node, closed = N["SPACECRAFT"], False

    def __init__(self):
        self.queue, self.sent = [], []

    def recv(self, timeout=None):
        out, self.queue = self.queue, []
        return out

    def send_raw(self, pid, src, dst, payload):
        self.sent.append((pid, src, dst, payload))

    def counters(self):
        return {}


class _Proc:
    pid = 0

    def poll(self):
        return None


def _session(**kw):
    from emulator.adcs_session import AdcsSession
    s = AdcsSession(runtime="cpython", duration_s=3, **kw)
    s.link, s.proc, s._t_wall = _Link(), _Proc(), time.perf_counter()
    return s


def _replies(k, mtq=None):
    """The firmware's replies of cycle k: RW_CMD x4 (zero torque), an MTQ_CMD if given, ADCS_STATUS(k)."""
    q = [(P["RW_CMD"], N["ADCS"], N["RW%d" % i], None, core.encode_payload("RW_CMD", cycle=k & 0xFF))
         for i in range(4)]
    if mtq is not None:
        q.append((P["MTQ_CMD"], N["ADCS"], N["MTQ"], None, mtq))
    q.append((P["ADCS_STATUS"], N["ADCS"], N["SPACECRAFT"], None, core.encode_payload("ADCS_STATUS", tick=k)))
    return q


def test_session_without_magnetic_devices_sends_the_thesis_burst():
    d = _spacecraft_file(mtq={"axes": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "dipole_limit_am2": 0.3},
                         mag={"noise_nt": 50.0, "bias_nt": 200.0, "rate_hz": 10.0})
    s = _session(spacecraft=d)                           # the file has both, but the default is off
    s._burst()
    assert s.devices is None and s.summary()["magnetic_devices"] is None
    assert P["MAGNETOMETER"] not in [p[0] for p in s.link.sent]


def test_session_magnetometer_in_the_burst_unnamed_and_first():
    d = _spacecraft_file(mag={"noise_nt": 50.0, "bias_nt": 200.0, "rate_hz": 10.0})
    plain, s = _session(spacecraft=d), _session(spacecraft=d, magnetic_devices=True)
    plain._burst()
    s._burst()
    pids = [p[0] for p in s.link.sent]
    assert pids[0] == P["ADCS_TICK"] and pids[1] == P["MAGNETOMETER"]
    assert pids[2:] == [p[0] for p in plain.link.sent][1:]          # the named packets as without it
    assert s.link.sent[0][3] == plain.link.sent[0][3]                # ADCS_TICK names the same burst
    assert [p[3] for p in s.link.sent[2:]] == [p[3] for p in plain.link.sent[1:]]   # the world's streams unchanged
    _, src, dst, payload = s.link.sent[1]
    assert (src, dst) == (N["MAGNETOMETER"], N["ADCS"])
    z = core.payload_dict(P["MAGNETOMETER"], payload)
    b = field_body(s.sc) + s.devices.mag.bias
    got = np.array([z["bx"], z["by"], z["bz"]]) * MAG_COUNT_NT * 1e-9
    assert z["valid"] == 1 and z["t_ms"] == 0 and np.all(np.abs(got - b) < 6 * 50e-9)
    other = _session(spacecraft=d, magnetic_devices=True, seed=1)
    assert not np.array_equal(other.devices.mag.bias, s.devices.mag.bias)


def test_session_mtq_cmd_sets_the_truth_dipole_and_the_torque_follows():
    d = _spacecraft_file(mtq={"axes": [[1, 0, 0], [1, 1, 0], [0, 1, 1]], "dipole_limit_am2": 0.2}, mag=None)
    s = _session(spacecraft=d, magnetic_devices=True)
    assert s.devices.mag is None
    residual = s.sc.dipole
    s._burst()
    assert P["MAGNETOMETER"] not in [p[0] for p in s.link.sent]
    t0, x0 = s.sc.t, s.sc.x.copy()
    tau0 = s.sc.external_torque(t0, x0)
    late = core.encode_payload("MTQ_CMD", mx=0.2, my=0.2, mz=0.2, cycle=255)     # not of cycle 0: ignored
    cmd = core.encode_payload("MTQ_CMD", mx=0.1, my=-0.05, mz=0.3, cycle=0)
    s.link.queue = [(P["MTQ_CMD"], N["ADCS"], N["MTQ"], None, late)] + _replies(0, cmd)
    s.cycle()
    applied = s.devices.mtq.applied
    assert np.allclose(s.sc.dipole, residual + applied)
    assert s.devices.mtq.saturated.any() and not np.allclose(applied, [0.1, -0.05, 0.3])   # clipped rods
    b = dcm(x0[0:4]) @ s.sc.field.field(s.sc.orbit.position(t0), t0)
    tau1 = s.sc.external_torque(t0, x0)                                          # same time and state
    assert np.allclose(tau1 - tau0, np.cross(applied, b), rtol=1e-9, atol=1e-15)
    assert np.linalg.norm(np.cross(applied, b)) > 1e-7
    pids = [p[0] for p in s.link.sent]                                           # the next burst: MTQ_TLM first
    k1 = len(pids) - 1 - pids[::-1].index(P["ADCS_TICK"])
    assert pids[k1 + 1] == P["MTQ_TLM"]
    tlm = core.payload_dict(P["MTQ_TLM"], s.link.sent[k1 + 1][3])
    assert [tlm["mx"], tlm["my"], tlm["mz"]] == pytest.approx(list(applied), rel=1e-6, abs=1e-7)
    assert tlm["saturated"] == s.devices.mtq.saturated_bits() != 0
    s.link.queue = _replies(1)                                                   # no MTQ_CMD: the rods hold
    s.cycle()
    assert np.allclose(s.sc.dipole, residual + applied)
    assert P["MTQ_TLM"] not in [p[0] for p in s.link.sent[len(pids):]]
    bad = struct.pack("<fffBB", float("nan"), 0.0, 0.0, 1, 2)
    s.link.queue = _replies(2, bad)
    s.cycle()                                                                    # the last cycle: refused, held
    assert np.allclose(s.sc.dipole, residual + applied)
    assert s.summary()["magnetic_devices"] == {"magnetometer": False, "magnetorquers": True, "mtq_cmd": 1,
                                               "refused_mtq_cmd": 1}


def test_session_with_the_flight_firmware_over_slcan_is_unchanged_by_the_magnetometer():
    """The real firmware on the pty: MAGNETOMETER crosses slcan and ISO-TP each cycle (its flow control comes
    back to MAGNETOMETER), the lean ADCS ignores it, and truth and estimates are the thesis session's bit for bit."""
    from emulator.adcs_session import AdcsSession
    from tests.test_firmware_mp import MICROPYTHON
    runtime = "micropython" if os.path.exists(MICROPYTHON) else "cpython"
    d = _spacecraft_file(mtq={"axes": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "dipole_limit_am2": 0.3},
                         mag={"noise_nt": 50.0, "bias_nt": 200.0, "rate_hz": 10.0})
    runs = []
    for magnetic in (False, True):
        with AdcsSession(runtime=runtime, duration_s=12, hold_s=5.0, spacecraft=d, magnetic_devices=magnetic) as s:
            outs = [s.cycle() for _ in range(12)]
            runs.append((outs, s.summary(), s.link.counters(), s.wait.retries["hello_tries"]))
    (plain, sp, cp, hp), (mag, sm, cm, hm) = runs
    for a, b in zip(plain, mag):
        assert np.array_equal(a["q"], b["q"]) and np.array_equal(a["est"]["q"], b["est"]["q"])
    assert sm["late_cycles"] == 0 and sm["retries"]["tick_resent"] == 0 and sm["firmware_missed"]["rx_drops"] == 0
    # HELLO is sent every 50 ms until the firmware answers: how many depends on its start-up time, not the bus
    assert cm["tx_frames"] - hm == cp["tx_frames"] - hp + 12 and cm.get("tx_isotp_TimeoutError", 0) == 0
    assert sm["magnetic_devices"] == {"magnetometer": True, "magnetorquers": True, "mtq_cmd": 0,
                                      "refused_mtq_cmd": 0}
