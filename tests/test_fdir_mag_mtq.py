"""The ADCS's fault handling of its magnetic devices (firmware/adcs/health.py, flight.rods_left): a silent
magnetometer flagged after 3 cycles without a reading (the unloading runs on the field model: nothing else
changes), a rod whose driver MTQ_TLM names silent 3 times in a row taken out of the unloading and put back when it
answers; each an event with its reason in ADCS_STATUS.magnetic_failed and the session's health events, in the
ground host (the app in process) and in the firmware (MicroPython over CAN); the fault options' refusals."""

import os
import sys

import numpy as np
import pytest

from emulator.adcs_bus import P, check_faults
from emulator.adcs_session import AdcsSession
from firmware.adcs import flight
from firmware.adcs.health import FAIL_AFTER, MAG_SILENT, Health
from ground.cli import main as fps
from protocol import core

MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")
FIRMWARE = "micropython" if os.path.exists(MICROPYTHON) else "cpython"
T0 = 8                      # both faults begin at 8 s of a 16 s session
ROD = 2


def _torque_fit(m, b, out, limit=np.inf):
    """The rods not in ``out``: their least-squares fit of the torque m x b within +-limit (scipy's bounded
    least squares), the others zero."""
    from scipy.optimize import lsq_linear
    live = [i for i in range(3) if not out >> i & 1]
    A = np.array([np.cross(np.eye(3)[i], b) for i in live]).T * 1e5
    r = np.zeros(3)
    r[live] = lsq_linear(A, np.cross(m, b) * 1e5, bounds=(-limit, limit), method="bvls", tol=1e-14).x
    return r


def test_the_rods_left_give_the_least_squares_torque_within_their_limit():
    rng = np.random.default_rng(4)
    for out in (1, 2, 4, 3, 5, 6):
        for _ in range(40):
            b, h, m_res = rng.normal(size=3) * 3e-5, rng.normal(size=3) * 1e-3, rng.normal(size=3) * 1e-2
            m_all, m = [0.0] * 3, [0.0] * 3
            flight.unloading(m_all, list(b), list(h), 2e-3, 1e9, list(m_res))
            assert flight.unloading(m, list(b), list(h), 2e-3, 1e9, list(m_res), out) == 0
            want = _torque_fit(np.array(m_all), b, out)
            assert np.allclose(m, want, rtol=1e-9, atol=1e-12) and all(m[i] == 0.0 for i in range(3) if out >> i & 1)
            if bin(out).count("1") == 1:            # two rods left: the torque itself
                assert np.allclose(np.cross(m, b), np.cross(m_all, b), rtol=1e-9, atol=1e-22)
            lim = 0.5 * np.abs(want).max()          # beyond the limit: the best torque within it
            sat = flight.unloading(m, list(b), list(h), 2e-3, lim, list(m_res), out)
            tau = np.cross(m_all, b)
            best = np.linalg.norm(np.cross(_torque_fit(np.array(m_all), b, out, lim), b) - tau)
            assert np.linalg.norm(np.cross(m, b) - tau) <= best * (1 + 1e-9) + 1e-12 * np.linalg.norm(tau)
            assert max(abs(v) for v in m) <= lim and sat == sum(1 << i for i in range(3) if abs(m[i]) >= lim)
    m = [0.1, 0.2, 0.3]                             # b along the one rod left: it cannot torque
    assert flight.rods_left(m, [0.0, 0.0, 3e-5], 9e-10, 3, 0.3) == 0 and m == [0.0, 0.0, 0.0]


class _Readings:
    def __init__(self):
        self.mtq_got, self.mtq_silent, self.mag_got = False, 0, False


def test_health_takes_a_rod_out_after_3_silent_replies_and_back_when_it_answers():
    hl, rd = Health(False, 10.0), _Readings()
    seen = []
    for mtq_got, silent, mag in ((1, 0, 0), (1, 2, 0), (1, 2, 1), (0, 0, 1), (1, 2, 1), (1, 0, 0), (1, 0, 0),
                                 (1, 0, 0), (1, 0, 1)):
        rd.mtq_got, rd.mtq_silent, rd.mag_got = bool(mtq_got), silent, bool(mag)
        hl.magnetics(rd)
        seen.append(hl.magnetic)
    # rod 1: silent in 3 MTQ_TLM (a cycle without one counts neither way), back at the first answer;
    # the magnetometer: never flagged before it was heard, then after FAIL_AFTER cycles without a reading
    assert FAIL_AFTER == 3 and seen == [0, 0, 0, 0, 2, 0, 0, MAG_SILENT, 0]


def _session(runtime, faults, n=16):
    """n cycles of the flight world with ``faults``: (the session, the MTQ_CMD dipole each cycle, the last
    ADCS_STATUS's magnetic_failed each cycle)."""
    s = AdcsSession(runtime=runtime, duration_s=float(n), world="flight", faults=faults)
    m, bits = [], []
    with s:
        for _ in range(n):
            s.cycle()
            d = core.payload_dict(P["MTQ_CMD"], s.wait.mtq_cmd)
            m.append([d["mx"], d["my"], d["mz"]])
            bits.append(s.watch.last["magnetic_failed"])
    return s, np.array(m), bits


@pytest.mark.parametrize("runtime", ["inproc", FIRMWARE])
def test_each_fault_is_an_event_with_its_reason_within_its_cycles(runtime):
    """The ground host (inproc) and the firmware over CAN: the magnetometer silent from T0 is flagged at
    T0 + 2 (its third cycle without a reading), the dead rod at T0 + 3 (the MTQ_TLM of T0's command is the first
    to name it); from then on the rod is absent from the commanded dipole."""
    s, m, bits = _session(runtime, {"magnetorquer_dead": [ROD, T0], "magnetometer_silent": T0})
    ev = s.watch.health_events
    assert [(e["t_s"], e["event"]) for e in ev] == [(T0 + 2.0, "magnetometer silent"),
                                                     (T0 + 3.0, "rod %d out of the unloading" % ROD)]
    assert "field model" in ev[0]["reason"] and "silent in 3 MTQ_TLM" in ev[1]["reason"]
    assert bits[T0 + 1] == 0 and bits[T0 + 2] == MAG_SILENT and bits[-1] == MAG_SILENT | 1 << ROD
    assert all(e in s.summary()["fault_log"] for e in ev)
    assert np.all(m[T0 + 3:, ROD] == 0.0) and np.all(m[1:T0 + 3, ROD] != 0.0)     # (none before the APKF starts)
    assert np.all(np.abs(m[T0 + 3:, [i for i in range(3) if i != ROD]]).sum(axis=1) > 0)


def test_the_unloading_does_not_need_the_magnetometer():
    """The unloading's field is the model's: with the magnetometer silent the run is the clean one bit for bit,
    only the status's flag and the event differ."""
    clean, mc, bc = _session("inproc", None)
    mute, mm, bm = _session("inproc", {"magnetometer_silent": T0})
    assert np.array_equal(mc, mm) and np.array_equal(clean.sc.q, mute.sc.q) and not any(bc)
    assert bm[-1] == MAG_SILENT and clean.watch.health_events == []


def test_bad_fault_values_exit_2_naming_the_option(tmp_path, capsys):
    for args, what in ((["--magnetorquer-dead", "3:10"], "--magnetorquer-dead 3:10"),
                       (["--magnetorquer-dead", "x"], "--magnetorquer-dead 'x': expected ROD:T0"),
                       (["--magnetorquer-dead", "1:-5"], "--magnetorquer-dead 1:-5"),
                       (["--magnetometer-silent", "nan"], "--magnetometer-silent nan"),
                       (["--magnetometer-silent", "1e9"], "--magnetometer-silent 1e+09"),
                       (["--faults", '{"magnetorquer_dead": [1, "a"]}'], '"magnetorquer_dead": [1, "a"]'),
                       (["--magnetorquer-dead", "1:5", "--world", "thesis"], "no magnetic devices")):
        argv = ["adcs", "can", "--runtime", "inproc", "--session", "20", "--quiet", "--no-plots",
                "-o", str(tmp_path / "x")]
        argv += [] if "--world" in args else ["--world", "flight"]
        rc = fps(argv + args)
        err = capsys.readouterr().err
        assert rc == 2 and what in err and "Traceback" not in err, (args, err)
    with pytest.raises(ValueError, match=r'"magnetometer_silent" starts at 30 s, not before the run'):
        check_faults({"magnetometer_silent": 30}, 30)
    assert check_faults({"magnetorquer_dead": [2.0, 5], "magnetometer_silent": 7}, 30) == {
        "magnetorquer_dead": [2, 5.0], "magnetometer_silent": 7.0}
