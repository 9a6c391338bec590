"""``fps calibrate``: the H-matrix calibration over the P-FSM grid (Sec. 7.4, Eq. 7.14-7.16).

Procedure, through the protocol only (CTRL_SETTINGS, CTRL_SET_FSM, HTABLE_*, CTRL_STATUS telemetry):

1. Bootstrap at the centre: in CALIBRATE mode, measure H around the FSM's zero with the 8 perturbations and
   null Q1 by Newton steps V -= H^-1 R; upload that one H as a provisional table so TRACK can run.
2. For each P-FSM grid point (snake order, so each step is one grid step): hold the P-FSM there, let the
   controller null Q1 in TRACK mode (Eq. 7.12), and record (V0x, V0y) as the mean applied FSM voltage.
3. In CALIBRATE mode apply V0 + (+-dV along X, Y and both): 8 data points of the ratios (Rx, Ry), each the
   mean of ``avg_ticks`` telemetry samples after ``settle_ticks``. H = [a b; c d] by least squares
   (Eq. 7.15-7.16) with ΔV taken from the DAC codes actually applied (the AD5664R has 76 uV steps) and one
   offset column per ratio, because the null is only as fine as one DAC code; the pattern is symmetric, so
   the offset does not bias H. ``residual`` is the RMS of the 16 fit residuals (ratio units).

The output JSON has the shape of ``fps emulator truth-h`` (docs/INTERFACES.md) plus the bench config,
timestamps and the runtime used; the controller loads exactly this file. A grid point where the beam is
lost, the FSM saturates or the null does not converge is reported with the point; no calibration is written
then, only NAME.failed.json (the points that did calibrate and a ``failed`` list), and the tool exits 1
naming every such point.
"""

import contextlib
import os
import sys
import time

import numpy as np

from emulator import hcal
from emulator.hcal import STEPS, fit_h
from ground.fileio import output_file, remove_stale, write_json
from protocol import htable



class PointError(ValueError):
    """A grid point could not be calibrated (beam lost, saturation, no null)."""


def grid_points(grid_v):
    """P-FSM grid in snake order (X fastest, reversing every row) so every move is one grid step."""
    pts = []
    for j, vy in enumerate(grid_v):
        row = grid_v if j % 2 == 0 else grid_v[::-1]
        pts.extend((vx, vy) for vx in row)
    return pts


def max_grid():
    """The largest n whose n x n H-table blob (``htable.blob_size``) the controller accepts
    (firmware.controller.MAX_HTABLE_BYTES)."""
    from firmware.controller import MAX_HTABLE_BYTES
    n = 2
    while n < htable.MAX_AXIS and htable.blob_size(n + 1, n + 1) <= MAX_HTABLE_BYTES:
        n += 1
    return n


def sec74_grid(n=11, half_span_v=5.0):
    from firmware.controller import MAX_HTABLE_BYTES
    m = max_grid()
    if not 2 <= n <= m:
        raise ValueError("--grid %r must be in [2, %d] (the controller accepts an H table of %d bytes: %dx%d)"
                         % (n, m, MAX_HTABLE_BYTES, m, m))
    if not 0 < half_span_v <= 10.0:
        raise ValueError("--span %r V must be in (0, 10] (the P-FSM's AD660 range)" % half_span_v)
    return hcal.grid(n, half_span_v)


class Calibrator:
    """Runs the Sec. 7.4 procedure on a ``ground.rig.Rig``."""

    def __init__(self, rig, dv=0.01, settle_ticks=8, avg_ticks=24, track_ticks=48, null_tol=2e-3, walk_v=0.5,
                 log=None):
        if not 0 < dv <= 0.5:
            raise ValueError("dv = %r V out of range (0, 0.5]" % dv)
        self.rig, self.dv = rig, float(dv)
        self.settle_ticks, self.avg_ticks, self.track_ticks = settle_ticks, avg_ticks, track_ticks
        self.null_tol = null_tol
        self.walk_v = walk_v
        self.pfsm_at = (0.0, 0.0)          # where the P-FSM is held now
        self.good = ((0.0, 0.0), (0.0, 0.0))   # last (P-FSM, V0) nulled: where to recover from
        self.log = log or (lambda msg: None)

    def _average(self, n_ticks, what):
        rig = self.rig
        rig.take_status()
        rig.run(n_ticks)
        st = rig.take_status()
        if not st:
            raise PointError("%s: no CTRL_STATUS telemetry received in %d ticks" % (what, n_ticks))
        lost = [s for s in st if not s["beam"]]
        if lost:
            raise PointError("%s: beam lost (Q1 sum %d counts in %d of %d ticks)" % (what, lost[-1]["vs"],
                                                                                     len(lost), len(st)))
        sat = [s for s in st if s["sat"]]
        if sat:
            raise PointError("%s: FSM command saturated at %s V" % (what, _fmt_v(sat[-1]["v_applied"])))
        r = np.mean([(s["rx"], s["ry"]) for s in st], axis=0)
        v = np.mean([s["v_applied"] for s in st], axis=0)
        return r, v

    def measure(self, v0, what):
        """The 8 perturbations around v0 in CALIBRATE mode; returns (H, offset, residual)."""
        dvs, rs = [], []
        for sx, sy in STEPS:
            self.rig.set_fsm(v0[0] + sx * self.dv, v0[1] + sy * self.dv)
            self.rig.run(self.settle_ticks)
            r, v = self._average(self.avg_ticks, what)
            dvs.append(v)
            rs.append(r)
        dvs = np.array(dvs)
        dvs -= dvs.mean(axis=0)
        h, off, resid = fit_h(dvs, rs)
        return h, off, resid

    def bootstrap(self):
        """H at the centre by Newton nulling in CALIBRATE mode; uploads it as a provisional table."""
        rig = self.rig
        rig.pfsm_v(0.0, 0.0)
        rig.settings("CALIBRATE", decim=1)
        v = np.zeros(2)
        for _ in range(4):
            h, off, _ = self.measure(v, "bootstrap at P-FSM (0, 0) V")
            step = np.linalg.solve(h, off)
            v = np.clip(v - step, -2.0, 2.0)
            if np.abs(off).max() < self.null_tol:
                break
        self.good = ((0.0, 0.0), tuple(v))
        self.log("bootstrap: H at the centre %s, null at %s V" % (np.round(h, 4).tolist(), _fmt_v(v)))
        prov = {"grid_v": [-1.0, 1.0], "dv": self.dv,
                "points": [{"pfsm_v": [px, py], "v0": [v[0] + 0.5 * px, v[1] + 0.5 * py], "H": h.tolist(),
                            "residual": 0.0} for py in (-1.0, 1.0) for px in (-1.0, 1.0)]}
        try:
            check_calibration(prov)
        except htable.HTableError as exc:
            raise PointError("bootstrap at P-FSM (0, 0) V: %s" % exc) from None
        rig.upload_htable(htable.pack_calibration(prov))
        return v

    def walk(self, target, what):
        """Move the P-FSM to ``target`` in steps of at most ``walk_v`` while TRACK follows, so the spot
        never leaves Q1 (a 5 V jump would throw it off the detector)."""
        a = np.array(self.pfsm_at)
        b = np.array(target, dtype=float)
        n = max(1, int(np.ceil(np.abs(b - a).max() / self.walk_v - 1e-9)))
        for k in range(1, n + 1):
            p = a + (b - a) * k / n
            self.rig.pfsm_v(*p)
            self.pfsm_at = tuple(p)
            if k < n:
                self.rig.run(self.track_ticks // 2)

    def recover(self):
        """After a failed point: back to the last good null in CALIBRATE mode."""
        (px, py), v0 = self.good
        self.rig.settings("CALIBRATE", decim=1)
        self.rig.set_fsm(*v0)
        self.rig.pfsm_v(px, py)
        self.pfsm_at = (px, py)
        self.rig.run(self.track_ticks)

    def point(self, pfsm_v):
        """Null in TRACK, then the 8 perturbations in CALIBRATE: one calibration point dict."""
        rig = self.rig
        what = "grid point P-FSM (%g, %g) V" % pfsm_v
        rig.settings("TRACK", decim=1)
        self.walk(pfsm_v, what)
        rig.run(self.track_ticks)
        r, v0 = self._average(self.avg_ticks, what + " (TRACK null)")
        if np.abs(r).max() > self.null_tol:
            raise PointError("%s: TRACK did not null Q1: R = (%.4f, %.4f)" % (what, r[0], r[1]))
        rig.settings("CALIBRATE", decim=1)
        h, off, resid = self.measure(v0, what)
        self.good = (pfsm_v, tuple(v0))
        return {"pfsm_v": [float(pfsm_v[0]), float(pfsm_v[1])], "v0": [float(v0[0]), float(v0[1])],
                "H": h.tolist(), "residual": resid}

    def run(self, grid_v, progress=None):
        """Calibrate every grid point; returns (points ordered X fastest, failures [(pfsm_v, message)])."""
        order = grid_points(grid_v)
        self.bootstrap()
        got, failed = {}, []
        for k, p in enumerate(order):
            try:
                got[p] = self.point(p)
            except PointError as exc:
                failed.append((p, str(exc)))
                self.log("FAILED %s" % exc)
                self.recover()
            if progress:
                progress(k + 1, len(order))
        self.rig.settings("IDLE", decim=0)
        points = [got[(vx, vy)] for vy in grid_v for vx in grid_v if (vx, vy) in got]
        return points, failed


def _fmt_v(v):
    return "(%.4f, %.4f)" % (v[0], v[1])


def compare_truth(cal, truth):
    """Relative Frobenius error of each point's H against the truth at the same P-FSM point: list of
    (pfsm_v, rel_err)."""
    tmap = {tuple(p["pfsm_v"]): np.array(p["H"]) for p in truth["points"]}
    out = []
    for p in cal["points"]:
        ht = tmap.get(tuple(p["pfsm_v"]))
        if ht is None:
            continue
        out.append((tuple(p["pfsm_v"]), float(np.linalg.norm(np.array(p["H"]) - ht) / np.linalg.norm(ht))))
    return out


def check_calibration(cal):
    """The controller's own check of a calibration dict, before any upload: the grid (protocol.htable) and
    the fixed-point H^-1 table (firmware.hinv.HinvTable) built from the very blob the controller would get
    (float32 H). A refused node is named by its calibration point: index, P-FSM volts, then the node, det H
    and condition number. Raises HTableError (a ValueError); returns the Grid."""
    from firmware.controller import MAX_HTABLE_BYTES
    from firmware.hinv import HinvTable
    grid = htable.grid_from_calibration(cal)
    blob = htable.pack(grid)
    if len(blob) > MAX_HTABLE_BYTES:           # the upload would be refused (TOO_LARGE)
        raise htable.HTableError("a %dx%d grid makes a %d-byte H table, above the %d bytes the controller "
                                 "accepts (%dx%d at most)" % (grid.nx, grid.ny, len(blob), MAX_HTABLE_BYTES,
                                                              max_grid(), max_grid()))
    try:
        HinvTable(htable.parse(blob))
    except htable.HTableError as exc:
        k = getattr(exc, "node", None)
        if k is None or grid.points is None:
            raise
        i = grid.points[k]
        pv = cal["points"][i]["pfsm_v"]
        raise htable.HTableError("points[%d] at P-FSM grid point (%g, %g) V refused: %s" % (i, pv[0], pv[1],
                                                                                          exc)) from None
    return grid


def load_calibration(path):
    """Read and validate a calibration JSON (the controller's own check, ``check_calibration``); returns the
    dict. A singular or fixed-point non-invertible H is refused here, naming its grid point, not after the
    upload."""
    from ground.fileio import read_json
    cal = read_json(path, "calibration")
    try:
        check_calibration(cal)
    except htable.HTableError as exc:
        raise ValueError("calibration %s: %s" % (path, exc)) from None
    for i, p in enumerate(cal["points"]):
        r = p.get("residual")
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0 <= r <= sys.float_info.max:
            from protocol.spacecraft import value_text
            raise ValueError("calibration %s: points[%d].residual must be a finite number >= 0 (the fit's RMS), "
                             "got %s" % (path, i, value_text(r)))
    return cal


def run_calibration(rig, grid_v, dv, log=print, progress=None, **kw):
    """Calibrate on ``rig``; returns (calibration dict, failures, wall seconds)."""
    t0 = time.perf_counter()
    cal = Calibrator(rig, dv=dv, log=log, **kw)
    points, failed = cal.run(grid_v, progress)
    wall = time.perf_counter() - t0
    out = {"grid_v": list(grid_v), "dv": dv, "points": points,
           "bench_config": rig.config, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
           "source": "fps calibrate", "wall_s": wall, "bench_s": rig.elapsed_s()}
    if failed:
        out["failed"] = [{"pfsm_v": list(p), "error": m} for p, m in failed]
    return out, failed, wall


class CalibrationFailed(OSError):
    """Grid points failed (beam lost, no null found) or the link went down: no calibration written."""


def _cmd(a):
    from ground import plots, runtime
    grid_v = sec74_grid(a.grid, a.span)
    if not 0 < a.dv <= 0.5:            # bad input (exit 2), refused before a rig or a process starts
        raise ValueError("--dv %r V must be in (0, 0.5]" % a.dv)
    runtime.check_seed(a.seed)
    cfg = None
    if a.config is not None:
        from emulator.config import load_config
        cfg = load_config(a.config)
    runtime.default_link(a)
    if a.port is not None and a.runtime != "board":      # a real, free-running bench: wall-clock time
        if not a.port:
            raise ValueError("--port: empty path")
        if a.runtime != "inproc":
            raise ValueError("--port %s with --runtime %s: --port alone is a real, free-running bench, and a "
                             "flashed controller board is --runtime board --port PORT; the %s runtime takes no "
                             "--port" % (a.port, a.runtime, a.runtime))
        from ground.rig import LiveRig
        rig_cm = contextlib.closing(LiveRig(a.port))
        a.no_truth = True
    else:
        opts = runtime.link_options(a)
        runtime.check_options(a.runtime, a.link, **opts)
        runtime.check_board(cfg, opts.get("rate_hz", 637.8))
        rig_cm = runtime.open_rig(a.runtime, a.link, config=cfg, seed=a.seed, **opts)
    rig = None
    try:
        with rig_cm as rig:
            if getattr(rig, "faults", None) is not None:      # silence windows in virtual seconds of the run
                rc = rig.endpoint.rc
                rig.faults.clock = lambda: rc.tick_now / rig.rate_hz
            log = (lambda m: print(m, file=sys.stderr)) if a.verbose else (lambda m: None)
            cal, failed, wall = run_calibration(rig, grid_v, a.dv, log=log)
            cal["runtime"] = getattr(rig, "runtime_name", "bench")
            cal["link"] = getattr(rig, "link_name", a.port)
            from ground.link_report import link_counters
            cal["link_counters"] = link_counters(rig) if hasattr(rig, "lockstep") else None
    except (OSError, ValueError) as exc:     # the inputs were checked: this is the run failing (link, process)
        from ground.runtime import exit_note   # and what the firmware said, if it stopped (a board: its traceback)
        rig = rig if rig is not None else getattr(exc, "rig", None)
        note = "" if "process exited" in str(exc) else exit_note(getattr(rig, "process", None), wait_s=0.5)
        raise CalibrationFailed("calibration stopped: %s%s; no calibration written" % (exc, note)) from None
    base = os.path.splitext(a.output)[0]
    if failed:
        write_json(base + ".failed.json", cal)
        for p, msg in failed:
            print("calibration failed at %s" % msg, file=sys.stderr)
        raise CalibrationFailed("%d of %d grid points failed (details in %s.failed.json); no calibration "
                                "written" % (len(failed), len(grid_v) ** 2, base))
    try:
        check_calibration(cal)          # what the controller would refuse is not written as a calibration
    except htable.HTableError as exc:
        write_json(base + ".failed.json", cal)
        raise CalibrationFailed("the measured H table would be refused by the controller: %s (details in "
                                "%s.failed.json); no calibration written" % (exc, base)) from None
    write_json(a.output, cal)
    # the earlier calibration's figures and an earlier failure's details no longer describe this file
    remove_stale(os.path.dirname(os.path.abspath(a.output)),
                 [os.path.basename(base) + s for s in ("_fig7-16.png", "_fig7-17.png", ".failed.json")])
    print("wrote %s: %d points, dv %g V, %.2f s wall (%s, %s)" % (a.output, len(cal["points"]), a.dv, wall,
                                                                cal["runtime"], cal["link"]))
    c = next(p for p in cal["points"] if p["pfsm_v"] == [0.0, 0.0]) if 0.0 in grid_v else cal["points"][0]
    from emulator.config import default_config
    from emulator.truth import format_h
    thesis = (cfg is None or cfg == default_config()) and not a.port   # Eq. 7.18 is the thesis preset's figure
    print("centre: V0 = %s V, %s%s" % (_fmt_v(c["v0"]), format_h(c["H"]),
                                       "; thesis Eq. 7.18: h_x = (-8.5221, 0.0717), h_y = (-0.0370, 7.6871)"
                                       if thesis else ""))
    if not a.no_plots:
        plots.calibration_quivers(cal, base + "_fig7-16.png")
        plots.calibration_difference(cal, base + "_fig7-17.png")
        print("plots: %s_fig7-16.png, %s_fig7-17.png" % (base, base))
    if not a.no_truth:
        _say_truth(cal, cfg, grid_v, a.dv)
    return 0


def _say_truth(cal, cfg, grid_v, dv):
    """The calibration against the emulator's true H field: its worst and mean relative errors."""
    from emulator.bench import Bench
    from emulator.truth import true_h_field
    errs = compare_truth(cal, true_h_field(Bench(cfg, noise=False), grid_v, dv))
    worst = max(errs, key=lambda e: e[1])
    print("against the emulator's true H: worst relative error %.3f %% at P-FSM (%g, %g) V, mean %.3f %%"
          % (100 * worst[1], worst[0][0], worst[0][1], 100 * np.mean([e[1] for e in errs])))


def register(sub, name, help_):
    import argparse
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="--port without --runtime board: a real, free-running bench (the controller and the player "
                              "answer there,\ntime is the wall clock).\nexit status: 0 calibration written; 1 the run failed (grid points failed, link "
                              "down): nothing written\nbut NAME.failed.json for failed points; 2 bad input.")
    p.add_argument("-o", "--output", required=True, type=output_file, help="calibration JSON to write")
    p.add_argument("--grid", type=int, default=11, help="grid points per axis (default 11: 121 points)")
    p.add_argument("--span", type=float, default=5.0, help="P-FSM grid half span in V (default 5: -5..+5 V)")
    p.add_argument("--dv", type=float, default=0.01, help="FSM perturbation in V (default 0.01)")
    p.add_argument("--config", help="bench config JSON (default: the thesis bench preset)")
    p.add_argument("--seed", type=int, default=0, help="the emulator's seed, >= 0 (default 0)")
    from ground.runtime import add_link_arguments
    add_link_arguments(p)
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-truth", action="store_true", help="skip the comparison with the emulator's true H")
    p.add_argument("-v", "--verbose", action="store_true")
    p.set_defaults(func=_cmd)
