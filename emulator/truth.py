"""The true H field of the emulated bench over the Sec. 7.4 grid, in the calibration JSON shape.

At each P-FSM grid point (both axes over ``grid_v``), the FSM tilt volts V0 that null Q1 are found on the
noiseless reference model, then H = [[a, b], [c, d]] by least squares over the 8 points +-dv along X, Y and
both (Eq. 7.14-7.16). Points are ordered with X varying fastest. Shape (docs/INTERFACES.md):
``{"grid_v": [...], "dv": dv, "points": [{"pfsm_v", "v0", "H", "residual"}, ...]}`` plus ``bench_config``,
``created_utc`` and ``source``.
"""

import time

from emulator import hcal
from emulator.bench import Bench
from protocol.htable import MAX_AXIS


def sec74_grid(n=11, half_span_v=5.0):
    """P-FSM grid volts: -5 V .. +5 V in 1 V steps for n = 11 (Sec. 7.4)."""
    if not 2 <= n <= MAX_AXIS:
        raise ValueError("grid size %r must be in [2, %d] (the controller's H table holds %d per axis)"
                         % (n, MAX_AXIS, MAX_AXIS))
    return hcal.grid(n, half_span_v)


def true_h_field(bench=None, grid_v=None, dv=0.01):
    """The true H at every grid point; returns the calibration-shaped dict."""
    if not 0.0 < dv <= 0.5:
        raise ValueError("dv = %r V is out of range (0, 0.5]" % dv)
    bench = bench if bench is not None else Bench(noise=False)
    grid_v = sec74_grid() if grid_v is None else [float(v) for v in grid_v]
    points = []
    for vy in grid_v:
        for vx in grid_v:
            points.append(bench.true_h((vx, vy), dv))
    return {"grid_v": grid_v, "dv": dv, "points": points, "bench_config": bench.config,
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "source": "emulator truth"}


def format_h(h):
    """H printed one way everywhere: by columns, h_x = dR/dV_x = (H11, H21) and h_y = dR/dV_y = (H12, H22), the
    layout of the thesis's Eq. 7.18 (1/V)."""
    return ("h_x = (%.4f, %.4f), h_y = (%.4f, %.4f) 1/V (H by columns: h_x = dR/dV_x, h_y = dR/dV_y)"
            % (h[0][0], h[1][0], h[0][1], h[1][1]))
