"""The ADCS application (firmware/adcs/app.py) on the lean STKF's public API: the capacity it picks from the
lag, and a refused measurement counted in the status without stopping the cycle."""

import math
import struct

import numpy as np
import pytest

from emulator.adcs_session import AdcsSession
from firmware.adcs import apkf_lean, stkf_lean
from firmware.adcs import app as A
from firmware.adcs.estimation import stkf_cap
from firmware.adcs.lockstep import _drops
from protocol import consts, core

P = core.PACKET_ID


def _cfg(satb):
    return AdcsSession(runtime="cpython", satb_gnss=satb, duration_s=30.0).config()


def _gnss(sat, t_s, x):
    return struct.pack(core.PACKET[P["GNSS"]].fmt, int(round(t_s * 1000)), sat,
                       *[int(round(v / 0.01)) for v in x[0:3]], *[int(round(v / 1e-4)) for v in x[3:6]])


def _status(app, tick):
    return core.payload_dict(P["ADCS_STATUS"], app.status_payload(tick))


def test_stkf_capacity_follows_the_lag():
    assert stkf_cap(4.0) == 6 and stkf_cap(0.0) == 3 and stkf_cap(2.5) == 5
    assert A.App(_cfg(True)).est.stkf.cap == 6 and A.App(_cfg(True)).est.stkf.lag == 4.0
    a = A.App(_cfg(False))
    assert a.est.stkf.cap == 3 and a.est.stkf.lag == 0.0


def test_refused_measurements_are_counted_and_the_cycle_goes_on():
    cfg = _cfg(True)
    app = A.App(cfg)
    xb = cfg["stkf_x0"][6:12]
    x_before = list(app.est.xs)
    app.cycle(0, 0.0)
    # a SatB fix, the same fix again (repeated tag) and one older than the 4 s lag
    for t in (0.4, 0.4):
        app.on_packet(P["GNSS"], core.NODE["GNSS"], _gnss(1, t, xb))
    app.cycle(1, 1.0)
    st = _status(app, 1)
    assert st["n_gnss_b"] == 1 and st["n_refused"] == 1
    for k in range(2, 10):
        app.cycle(k, float(k))
    app.on_packet(P["GNSS"], core.NODE["GNSS"], _gnss(1, 3.0, xb))     # 7 s old at t = 10 s
    # a beacon with a NaN in it (floats on the bus), the star tracker valid so that it would be used
    app.on_packet(P["STARTRACKER"], core.NODE["STARTRACKER"],
                  struct.pack(core.PACKET[P["STARTRACKER"]].fmt, 10000, 0.0, 0.0, 0.0, 1.0, 1))
    app.on_packet(P["BEACON"], core.NODE["BEACON"],
                  struct.pack(core.PACKET[P["BEACON"]].fmt, 10000, float("nan"), 0.0, 1.0, 1))
    u = app.cycle(10, 10.0)
    st = _status(app, 10)
    assert st["n_refused"] == 3 and st["n_gnss_b"] == 1
    assert all(math.isfinite(v) for v in u) and np.all(np.isfinite(list(app.est.xs)))
    assert app.est.xs[0] != x_before[0]                      # the estimate is read from the filter every cycle
    assert np.isfinite([st[k] for k in ("rax", "ray", "raz", "rbx", "rby", "rbz")]).all()
    app.cycle(11, 11.0)                                  # and the next cycle runs as usual
    assert _status(app, 11)["n_refused"] == 3


@pytest.mark.parametrize("satb", [False, True])
def test_app_estimate_is_the_filters(satb):
    app = A.App(_cfg(satb))
    for k in range(3):
        app.cycle(k, float(k))
    x, s = stkf_lean.zeros_d(12), stkf_lean.zeros_d(12)
    app.est.stkf.get(x, s)
    assert list(app.est.xs) == list(x) and app.est.stkf.now == 2.0


def test_a_gap_in_the_ticks_is_propagated_in_steps():
    app = A.App(_cfg(False))
    app.cycle(0, 0.0)
    app.cycle(1, 1500.0)                                 # longer than one prediction step (600 s)
    assert app.est.stkf.now == 1500.0 and app.health.n_refused == 0
    r = math.sqrt(sum(v * v for v in app.est.xs[0:3]))
    assert 6.0e6 < r < 8.0e6                             # still on its orbit


def test_rx_drops_count_each_can_reason_once():
    """ADCS_STATUS.n_rx_drop: every reason the CAN decoder counts (protocol.can.DROP_REASONS, bad_length once,
    it is one counter); the port's own send timeouts and resends are not drops, nor are the serial link's
    reasons a CAN port's."""
    from protocol import can as canmap

    class Port:
        def counters(self):
            d = {k: 1 for k in canmap.DROP_REASONS}
            d.update(tx_isotp_timeouts=1, tx_isotp_resent=2, other_dst=5, tx_packets=9, bad_cobs=7)
            return d

    assert _drops(Port()) == len(set(canmap.DROP_REASONS))


def test_rx_damaged_counts_what_arrived_damaged_not_what_came_late():
    """ADCS_STATUS.n_rx_damaged: of the drops, those that arrived damaged; an ISO-TP reception that timed out
    (a slow host) is a drop, not damage."""
    from firmware.adcs.lockstep import _damaged

    class Port:
        def __init__(self, c):
            self.c = c

        def counters(self):
            return self.c
    late = Port({"isotp_ConsecutiveFrameTimeoutError": 3})
    bad = Port({"bad_crc": 2, "isotp_ConsecutiveFrameTimeoutError": 3})
    assert _drops(late) == 3 and _damaged(late) == 0
    assert _drops(bad) == 5 and _damaged(bad) == 2


@pytest.mark.parametrize("momentum", ["torque", "filtered"])
def test_the_apkf_input_is_a_checked_option(momentum):
    """apkf_momentum chooses the lean APKF's momentum input (filtered by default); the commanded torques and
    which wheels were heard reach the filter."""
    with pytest.raises(ValueError, match="apkf_momentum"):
        AdcsSession(runtime="cpython", duration_s=30.0, apkf_momentum="gyro")
    with pytest.raises(ValueError, match="apkf_momentum"):
        A.App(dict(_cfg(False), apkf_momentum="gyro"))
    assert A.App(_cfg(False)).est.akw["momentum"] == "filtered"
    cfg = AdcsSession(runtime="cpython", duration_s=30.0, apkf_momentum=momentum).config()
    app = A.App(cfg)
    app.est.apkf = apkf_lean.LeanApkf(app.est.params, [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0] * 4,
                                momentum=app.est.akw["momentum"])
    seen = []
    step = app.est.apkf.step
    app.est.apkf.step = lambda wp, q, env, u=None, got=None: (seen.append((list(u), list(got))),
                                                          step(wp, q, env, u, got))
    for i in range(4):
        app.act.u[i] = 1e-5 * (i + 1)
    app.rd.rw_got[:] = [True, False, True, True]
    app.rd.st_got = app.rd.st_valid = False
    app.est.run_apkf(1.0, app.act.u)
    assert (app.est.apkf.model.torque, app.est.apkf.model.filtered) == (momentum == "torque", momentum == "filtered")
    assert seen == [([pytest.approx(1e-5 * (i + 1)) for i in range(4)], [True, False, True, True])]


def test_first_acquisition_damps_the_rate_until_the_star_tracker_answers():
    """After the hold, once the estimate is within acquire_deg (1 deg) of the command and the star tracker has
    not answered, the app damps the rate (q_c = q, w_c = 0) and says HOLD; the first valid fix ends that for
    good, and a far command (the slew itself) is flown as commanded."""
    app = A.App(_cfg(False))
    app.health.wheels(app.rd.rw_got)
    app.act.use_wheels(app.health.failed)
    app.est.apkf = apkf_lean.LeanApkf(app.est.params, [0.0, 0.0, 0.0, 1.0], [1e-3, 0.0, 0.0], [0.0] * 4)
    target = [0.0, 0.0, 0.0, 1.0]

    def command(X):
        for i in range(4):
            app.modes.qc[i] = target[i]
        for i in range(3):
            app.modes.wc[i] = 1e-3
    app.modes.command_rate = command
    t = app.modes.hold_s + 10.0

    def rot(deg):
        return [math.sin(math.radians(deg) / 2), 0.0, 0.0, math.cos(math.radians(deg) / 2)]
    app.rd.st_got, app.rd.st_valid = True, False
    target[:] = rot(5.0)                       # slewing: flown as commanded
    app.control(t, app.rd.st_ok())
    assert not app.modes.acquiring and list(app.modes.wc) == pytest.approx([1e-3] * 3)
    target[:] = rot(0.5)                       # done by the estimate, tracker not back: rate damping
    app.control(t, app.rd.st_ok())
    assert app.modes.acquiring and list(app.modes.wc) == [0.0] * 3 and list(app.modes.qc) == list(app.est.apkf.x[0:4])
    app.rd.rw_got[:] = [True] * 4
    for k in app.health.last_ok:                      # no sensor silent for long (that would say DEGRADED)
        app.health.last_ok[k] = t
    app.est.t_apkf = t - 1.0                       # the filter put in above is one step behind the cycle
    app.cycle(0, t)
    assert app.mode == consts.MODE_HOLD
    app.rd.st_got = app.rd.st_valid = True           # a valid fix: acquired, the pointing command from then on
    app.control(t, app.rd.st_ok())
    assert app.modes.acquired and not app.modes.acquiring and list(app.modes.wc) == pytest.approx([1e-3] * 3)
    app.rd.st_got = app.rd.st_valid = False
    app.control(t, app.rd.st_ok())
    assert not app.modes.acquiring and list(app.modes.wc) == pytest.approx([1e-3] * 3)


def test_a_broken_attitude_covariance_gates_the_beacon_and_the_cycle_goes_on():
    """A diverged APKF whose attitude covariance has a negative trace (an extreme drawn vehicle spun up by a
    dipole its rods cannot cancel) gates the beacon like a large one; the flight app does not stop on it."""
    app = A.App(AdcsSession(runtime="cpython", world="flight", duration_s=30.0).config())
    assert app.est.fly
    attitude = app.est.attitude

    def broken():
        q = attitude()
        for i in (0, 4, 8):
            app.est.Patt[i] = -1e-6
        return q
    app.est.attitude = broken
    for k in range(5):
        u = app.cycle(k, float(k))
    assert all(math.isfinite(v) for v in u) and not app.est.beacon_used
