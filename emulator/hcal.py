"""The H-matrix calibration's maths (Sec. 7.4), once for the emulator's truth (``emulator.truth``,
``Bench.true_h``) and ``fps calibrate`` (``ground.calibrate``): the P-FSM grid, the eight FSM perturbations around
each null, and the least-squares fit of H (Eq. 7.15-7.16)."""

import numpy as np

STEPS = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1))   # Sec. 7.4, 8 points, in units of dv


def grid(n=11, half_span_v=5.0):
    """The P-FSM grid's volts along one axis: n points from -half_span_v to +half_span_v (-5 V .. +5 V in 1 V
    steps for n = 11, Sec. 7.4), rounded to 1e-12 V so that 0 V is 0. The callers check n and the span against
    their own limits."""
    return [float(v) for v in np.round(np.linspace(-half_span_v, half_span_v, n), 12)]


def fit_h(dv_applied, ratios, offset=True):
    """Least-squares H (Eq. 7.15-7.16), with an offset per ratio when ``offset`` (a measured null is never exactly
    zero; the noiseless truth's is, and fits H alone).

    dv_applied: (n, 2) FSM perturbations (V); ratios: (n, 2) measured (Rx, Ry). Returns (H 2x2, offset (2,),
    residual RMS in ratio units)."""
    dv = np.asarray(dv_applied, dtype=float)
    r = np.asarray(ratios, dtype=float)
    n = len(dv)
    a = np.zeros((2 * n, 6 if offset else 4))
    a[0::2, 0:2] = dv
    a[1::2, 2:4] = dv
    if offset:
        a[0::2, 4] = 1.0
        a[1::2, 5] = 1.0
    b = r.reshape(-1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    resid = float(np.sqrt(np.mean((a @ sol - b) ** 2)))
    return sol[:4].reshape(2, 2), (sol[4:] if offset else np.zeros(2)), resid
