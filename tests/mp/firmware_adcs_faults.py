# Under micropython (or CPython): the ADCS application's fault paths, one function per case, each returning a
# dict of what it saw. tests/test_adcs_app_faults.py calls the functions under CPython and runs this script
# under micropython: ``firmware_adcs_faults.py CONFIG.json CASE [CASE ..]`` prints {case: result} as JSON.
import json
import math
import struct
import sys

from firmware.adcs import apkf_lean, app as A, stkf_lean
from firmware.adcs.health import FAIL_AFTER
from firmware.adcs.intake import NW, RPM
from protocol import core

P = core.PACKET_ID
NODE = core.NODE


def _app(cfg, w=(1e-3, -5e-4, 2e-4)):
    """An App whose APKF runs (at rest attitude, rate w), past no cycle yet."""
    app = A.App(cfg)
    app.est.apkf = apkf_lean.LeanApkf(app.est.params, [0.0, 0.0, 0.0, 1.0], list(w), [0.0] * 4, momentum=app.est.akw["momentum"])
    for i in range(NW):
        app.rd.rw_got[i] = True
    _wheels_in(app)                                 # the allocation's axes, as a cycle sets them first
    return app


def _wheels_in(app):
    """The cycle's first step: the failed wheels, then the allocation's axes."""
    app.health.wheels(app.rd.rw_got)
    app.act.use_wheels(app.health.failed)


def _fail(app, mask):
    """Declare the wheels in mask failed the way the cycle does: 3 cycles without their RW_TLM."""
    for _ in range(FAIL_AFTER):
        for i in range(NW):
            app.rd.rw_got[i] = not (mask >> i & 1)
        _wheels_in(app)


def case_wheels_left_do_not_span(cfg):
    """Two (or three) wheels failed: the rest cannot make a 3-axis torque. The cycle must neither raise nor
    command a torque it cannot allocate: u of the working wheels is their friction compensation only."""
    out = {}
    for mask in (0b0011, 0b1100, 0b0101, 0b0111):
        app = _app(cfg)
        _fail(app, mask)
        res = []
        for t in (5.0, app.modes.hold_s + 10.0):         # rate damping, then pointing
            try:
                u = app.control(t, app.rd.st_ok())
                res.append([float(v) for v in u])
            except Exception as exc:                # noqa: BLE001 - reported, the test says what went wrong
                res.append("%s: %s" % (type(exc).__name__, exc))
        c, v, sm = app.act.fric
        fc = [v * app.rd.wp[i] + c * math.tanh(app.rd.wp[i] / sm) for i in range(NW)]
        out["%d" % mask] = {"failed": app.health.failed, "u": res, "friction": fc}
    return out


def _pk(pid, **kw):
    return core.encode_payload(P[pid], **kw)


def _st(t_ms, q, valid):
    return struct.pack(core.PACKET[P["STARTRACKER"]].fmt, t_ms, q[0], q[1], q[2], q[3], valid)


def _bc(t_ms, y, valid):
    return struct.pack(core.PACKET[P["BEACON"]].fmt, t_ms, y[0], y[1], y[2], valid)


def _gnss(t_ms, sat, x):
    return struct.pack(core.PACKET[P["GNSS"]].fmt, t_ms, sat, int(round(x[0] * 100)), int(round(x[1] * 100)),
                       int(round(x[2] * 100)), int(round(x[3] * 1e4)), int(round(x[4] * 1e4)),
                       int(round(x[5] * 1e4)))


def _burst(app, k, cfg, skip=(), extra=()):
    """A nominal burst at t = k s (wheels at 100 rpm, identity attitude, SatA's GNSS, a beacon) with
    the packets named in ``skip`` left out and ``extra`` [(pid, src, payload)] added."""
    t_ms = 1000 * k
    x0 = stkf_lean.zeros_d(12)                  # both satellites on their two-body orbits from the STKF's start
    for i in range(12):
        x0[i] = cfg["stkf_x0"][i]
    if k:
        stkf_lean.f(x0, 0, float(k))
        stkf_lean.f(x0, 6, float(k))
    for i in range(NW):
        if "rw%d" % i not in skip:
            app.on_packet(P["RW_TLM"], NODE["RW0"] + i, struct.pack(core.PACKET[P["RW_TLM"]].fmt, 100.0, 0.0))
    if "st" not in skip:
        app.on_packet(P["STARTRACKER"], NODE["STARTRACKER"], _st(t_ms, (0.0, 0.0, 0.0, 1.0), 1))
    if "gnss" not in skip:
        app.on_packet(P["GNSS"], NODE["GNSS"], _gnss(t_ms, 0, x0[0:6]))
    if "bc" not in skip:
        d = [x0[6 + i] - x0[i] for i in range(3)]
        n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        app.on_packet(P["BEACON"], NODE["BEACON"], _bc(t_ms, (d[0] / n, d[1] / n, d[2] / n), 1))
    for pid, src, pl in extra:
        app.on_packet(pid, src, pl)
    u = app.cycle(k, k)
    app.commands(u)


def _state(app):
    return {"x": [float(v) for v in app.est.apkf.x], "P": [float(v) for v in app.est.apkf.P],
            "xs": [float(v) for v in app.est.xs], "u": [float(v) for v in app.act.u],
            "status": [int(v) for v in struct.unpack(core.PACKET[P["ADCS_STATUS"]].fmt,
                                                      app.status_payload(0))[1:17]]}


def case_bad_payloads(cfg):
    """Payloads the table's ranges exclude (a NaN or non-unit quaternion marked valid, valid = 2, a NaN wheel
    speed, a zero beacon vector, a GNSS fix of satellite 2) against the packet they stand for (invalid,
    or not sent), fed at t = 3 s of 6 cycles: the filters must end where the reference ends."""
    nan = float("nan")
    cfg_b = dict(cfg, satb_gnss=True)
    variants = {
        "st_nan": (cfg, [("STARTRACKER", "STARTRACKER", _st(3000, (nan, 0.0, 0.0, 1.0), 1))],
                   [("STARTRACKER", "STARTRACKER", _st(3000, (0.0, 0.0, 0.0, 1.0), 0))], ("st",)),
        "st_zero": (cfg, [("STARTRACKER", "STARTRACKER", _st(3000, (0.0, 0.0, 0.0, 0.0), 1))],
                    [("STARTRACKER", "STARTRACKER", _st(3000, (0.0, 0.0, 0.0, 1.0), 0))], ("st",)),
        "st_valid_2": (cfg, [("STARTRACKER", "STARTRACKER", _st(3000, (0.0, 0.0, 0.0, 1.0), 2))],
                       [("STARTRACKER", "STARTRACKER", _st(3000, (0.0, 0.0, 0.0, 1.0), 0))], ("st",)),
        "rw_nan": (cfg, [("RW_TLM", "RW1", struct.pack(core.PACKET[P["RW_TLM"]].fmt, nan, 0.0))], [],
                   ("rw1",)),
        "bc_zero": (cfg, [("BEACON", "BEACON", _bc(3000, (0.0, 0.0, 0.0), 1))],
                    [("BEACON", "BEACON", _bc(3000, (0.0, 0.0, 1.0), 0))], ("bc",)),
        "gnss_sat_2": (cfg_b, [("GNSS", "GNSS", _gnss(500, 2, [v + 5e3 for v in cfg["stkf_x0"][6:12]]))], [],
                       ()),
    }
    out = {}
    for name in variants:
        c, bad, ref, skip = variants[name]
        res = []
        for pkts in (bad, ref):
            app = A.App(c)
            for k in range(6):
                extra = [(P[p], NODE[s], pl) for p, s, pl in pkts] if k == 3 else ()
                _burst(app, k, c, skip if k == 3 else (), extra)
            res.append(_state(app))
        out[name] = res
    return out


def _quiet(app):
    """Not the controller's torques (they would differ between runs of different tick spacing): each wheel
    gets its friction at the bursts' 100 rpm, so that the read-outs' constant speed is what the wheels do."""
    c, v, sm = app.act.fric
    w = 100.0 * RPM
    for i in range(NW):
        app.act.u[i] = v * w + c * math.tanh(w / sm)

    def control(t, st_ok):
        return app.act.u
    app.control = control
    return app


def _ticks(cfg, times, st_from=2, skip_at=()):
    """An App (torques off) cycled at ``times`` (tick numbers 0, 1, ..), nominal bursts, the star tracker
    blind from ``st_from`` s on, nothing at all received before the ticks in ``skip_at``."""
    app = _quiet(A.App(cfg))
    for k, t in enumerate(times):
        if k in skip_at:
            app.cycle(k, t)
            app.commands(app.act.u)
            continue
        t_ms = int(t * 1000)
        _burst(app, t, cfg, ("st",) if t >= st_from else (),
               [(P["STARTRACKER"], NODE["STARTRACKER"], _st(t_ms, (0.0, 0.0, 0.0, 1.0), 1 if t < st_from else 0))])
    return app


def case_tick_gap(cfg):
    """Ticks every second to 12 s, against ticks to 4 s and then 12 s (an 8 s gap), star tracker blind from
    2 s: the APKF's attitude, rate and time at 12 s."""
    out = []
    for times in (list(range(13)), [0, 1, 2, 3, 4, 12]):
        app = _ticks(cfg, times)
        out.append({"x": [float(v) for v in app.est.apkf.x], "Ptr": float(app.est.apkf.P[0] + app.est.apkf.P[10]
                                                                      + app.est.apkf.P[20]),
                    "t_stkf": float(app.est.stkf.now), "n_refused": app.health.n_refused})
    return out


def case_tick_repeat(cfg):
    """A tick whose time repeats the last one's (t = 3 s twice, nothing received before the repeat), against
    the same ticks without it: the filters end in the same state."""
    out = []
    for times, skip in (([0, 1, 2, 3, 4, 5], ()), ([0, 1, 2, 3, 3, 4, 5], (4,))):
        app = _ticks(cfg, times, skip_at=skip)
        out.append(_state(app))
    return out


def case_tick_backwards(cfg):
    """A tick whose time goes back (t = 5 s after 6 s) with a full burst: the status still packs, nothing of
    that burst is fused at the wrong time (SatA's GNSS and the beacon refused), and the filters go on."""
    app = _ticks(cfg, [0, 1, 2, 3, 4, 5, 6])
    x6 = [float(v) for v in app.est.apkf.x]
    xs6 = [float(v) for v in app.est.xs]
    err = None
    try:
        _burst(app, 5, cfg, (), ())
        st = struct.unpack(core.PACKET[P["ADCS_STATUS"]].fmt, app.status_payload(7))
    except Exception as exc:                         # noqa: BLE001 - reported to the test
        err = "%s: %s" % (type(exc).__name__, exc)
        st = None
    res = {"err": err, "x_same": [float(v) for v in app.est.apkf.x] == x6, "xs_same": [float(v) for v in app.est.xs] == xs6,
           "n_refused": app.health.n_refused, "age": None if st is None else st[16]}
    _burst(app, 7, cfg, (), ())
    res["t_apkf"], res["t_stkf"] = app.est.t_apkf, float(app.est.stkf.now)
    return res


def case_beacon_without_attitude(cfg):
    """Before the APKF starts, a valid fix at 0 s, then a cycle at 1 s without a star-tracker packet but with
    the beacon: the beacon has no attitude of this cycle to go with (the tracker's last is 1 s old). Against
    the same cycle without the beacon packet: the STKF's estimate."""
    out = []
    for skip in (("st",), ("st", "bc")):
        app = A.App(cfg)
        _burst(app, 0, cfg)
        _burst(app, 1, cfg, skip)
        out.append({"xs": [float(v) for v in app.est.xs], "apkf": app.est.apkf is not None})
    return out


def case_refused_measurements_are_stale(cfg):
    """From 2 s on the beacon says valid but carries a NaN (the STKF refuses it every cycle); against a beacon
    that says invalid: the status's mode and stale bits at 15 s (stale_s 10 s)."""
    nan = float("nan")
    out = []
    for y, valid in (((nan, 0.0, 1.0), 1), ((0.0, 0.0, 1.0), 0)):
        app = A.App(cfg)
        for k in range(16):
            if k < 2:
                _burst(app, k, cfg)
            else:
                _burst(app, k, cfg, ("bc",), [(P["BEACON"], NODE["BEACON"], _bc(1000 * k, y, valid))])
        st = struct.unpack(core.PACKET[P["ADCS_STATUS"]].fmt, app.status_payload(15))
        out.append({"mode": st[1], "stale": st[2], "n_refused": st[14]})
    return out


def case_apkf_refused_fix_is_stale(cfg):
    """Valid star-tracker fixes throughout; from 4 s the APKF's attitude variance is made negative, so S is
    not positive definite and every fix is refused: the status's stale bits, mode and n_st_invalid at 15 s."""
    app = A.App(cfg)
    for k in range(16):
        if k == 4:
            for i in range(3):
                app.est.apkf.P[i * 9 + i] = -1.0
        _burst(app, k, cfg)
    st = struct.unpack(core.PACKET[P["ADCS_STATUS"]].fmt, app.status_payload(15))
    return {"skipped": app.est.apkf.skipped, "mode": st[1], "stale": st[2], "n_st_invalid": st[11]}


def case_gnss_b_silent(cfg):
    """SatB's GNSS on, but no fix of SatB ever: per cycle from 8 to 12 s, the mode and the GNSS_B stale bit."""
    app = A.App(dict(cfg, satb_gnss=True))
    out = []
    for k in range(13):
        _burst(app, k, cfg)
        if k >= 8:
            st = struct.unpack(core.PACKET[P["ADCS_STATUS"]].fmt, app.status_payload(k))
            out.append([k, st[1], st[2] >> 2 & 1])
    return out


def case_command_singular(cfg):
    """SatB's estimate straight behind SatA (along -vA): the laser axis's minimum rotation onto the line of
    sight is not unique (control.min_rotation raises). After the hold, the cycle must go on, damping the
    rate (mode HOLD) instead of pointing."""
    app = _app(cfg)
    f = app.est.stkf
    v = f.xa[3:6]
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    for i in range(3):
        f.X[i] = f.xa[i] - 1e5 * v[i] / n
    f.get(app.est.xs, app.est.sig)
    t = app.modes.hold_s + 10.0
    try:
        u = [float(x) for x in app.control(t, app.rd.st_ok())]
    except Exception as exc:                         # noqa: BLE001 - reported to the test
        return {"err": "%s: %s" % (type(exc).__name__, exc)}
    return {"err": None, "u": u, "qc_is_q": [float(x) for x in app.modes.qc] == [float(x) for x in app.est.apkf.x[0:4]],
            "wc": [float(x) for x in app.modes.wc], "no_command": app.modes.no_command}


def case_satb_backlog(cfg):
    """After ticks 0 .. 9 without SatB's GNSS, six of its fixes arrive before the tick at 10 s (a backlog, as
    after a gap in the ticks), tagged 4.5 .. 9.5 s: with the 4 s lag the four newest can be fused."""
    c = dict(cfg, satb_gnss=True)
    app = A.App(c)
    for k in range(10):
        _burst(app, k, cfg)
    x = stkf_lean.zeros_d(12)
    extra = []
    for j in range(6):
        tj = 4.5 + j
        for i in range(12):
            x[i] = cfg["stkf_x0"][i]
        stkf_lean.f(x, 6, tj)
        extra.append((P["GNSS"], NODE["GNSS"], _gnss(int(tj * 1000), 1, x[6:12])))
    _burst(app, 10, cfg, (), extra)
    return {"n_gnss_b": app.health.n_gnss_b, "n_refused": app.health.n_refused, "t_last": float(app.est.stkf.t_last)}


CASES = dict((k[5:], v) for k, v in globals().items() if k.startswith("case_"))

if __name__ == "__main__":
    with open(sys.argv[1]) as fh:
        config = json.load(fh)
    print(json.dumps(dict((name, CASES[name](config)) for name in sys.argv[2:])))
