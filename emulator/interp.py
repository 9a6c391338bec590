"""Piecewise Lagrange interpolation on numpy: the orbit truth's 10th-order interpolation (Sec. 6.4.1) and the
distfile's 3rd-order resampling (Sec. 7.3.1). Here, not in ground, because the emulator's truth uses it and
nothing below ground imports ground (docs/INTERFACES.md); ``ground.resample`` takes it from here.
"""

import numpy as np


def lagrange(t_in, y_in, t_out, order=3):
    """Lagrange interpolation of ``order`` (``order + 1`` points) of ``y_in(t_in)`` at ``t_out``.

    For each output time the stencil is the ``order + 1`` input samples around it (``t[i - (order-1)//2]``
    onwards, with ``t[i] <= t < t[i+1]``; shifted inwards at both ends). Exact for polynomials of degree
    ``order``. ``y_in`` may be 1-D or (n, ...) for channels sharing the same times. Order 3 is the distfile
    resampling of Sec. 7.3.1, order 10 the orbit interpolation of Sec. 6.4.1.
    """
    t_in = np.asarray(t_in, dtype=float)
    y_in = np.asarray(y_in, dtype=float)
    t_out = np.asarray(t_out, dtype=float)
    scalar = t_out.ndim == 0
    t_out = np.atleast_1d(t_out)
    n = t_in.size
    m = int(order) + 1
    if order < 1:
        raise ValueError("lagrange: order must be >= 1, got %r" % (order,))
    if n < m:
        raise ValueError("lagrange%d needs at least %d input samples, got %d" % (order, m, n))
    if y_in.shape[0] != n:
        raise ValueError("lagrange%d: %d times but %d samples" % (order, n, y_in.shape[0]))
    if not np.all(np.diff(t_in) > 0):
        raise ValueError("lagrange%d: input times must be strictly increasing" % order)
    if not np.all(np.isfinite(t_out)):
        raise ValueError("lagrange%d: output times must be finite" % order)
    if t_out.size and (t_out.min() < t_in[0] or t_out.max() > t_in[-1]):
        raise ValueError("lagrange%d: output times [%g, %g] outside the input span [%g, %g]"
                         % (order, t_out.min(), t_out.max(), t_in[0], t_in[-1]))
    i = np.searchsorted(t_in, t_out, side="right") - 1
    first = np.clip(i - (order - 1) // 2, 0, n - m)  # stencil t[first] .. t[first+order]
    idx = first[:, None] + np.arange(m)[None, :]
    tn = t_in[idx]
    out = np.zeros((t_out.size,) + y_in.shape[1:])
    for j in range(m):
        w = np.ones(t_out.size)
        for k in range(m):
            if k != j:
                w *= (t_out - tn[:, k]) / (tn[:, j] - tn[:, k])
        out += (w.reshape((-1,) + (1,) * (y_in.ndim - 1))) * y_in[idx[:, j]]
    return out[0] if scalar else out


def lagrange3(t_in, y_in, t_out):
    """3rd-order (4-point) Lagrange interpolation (Sec. 7.3.1); see ``lagrange``."""
    return lagrange(t_in, y_in, t_out, order=3)
