"""Resampling of a source's time history onto the distfile step (Sec. 7.3.1).

The body pointing simulator produces error angles at its own rate (10 Hz in the thesis); they are
resampled by 3rd-order Lagrange interpolation to a step of 8.192 ms (122.07 Hz) before the distfile is
written. Here the input times may be any strictly increasing sequence (a user's CSV need not be uniform).
"""

import numpy as np

DIST_PERIOD_US = 8192  # distfile step, Sec. 7.3.1


def lagrange3(t_in, y_in, t_out):
    """3rd-order (4-point) Lagrange interpolation of ``y_in(t_in)`` at ``t_out``.

    For each output time the four input samples around it are used (``t[i-1] .. t[i+2]`` with
    ``t[i] <= t < t[i+1]``; the stencil is shifted inwards at both ends). Exact for cubics.
    ``y_in`` may be 1-D or (n, k) for k channels sharing the same times.
    """
    t_in = np.asarray(t_in, dtype=float)
    y_in = np.asarray(y_in, dtype=float)
    t_out = np.asarray(t_out, dtype=float)
    n = t_in.size
    if n < 4:
        raise ValueError("lagrange3 needs at least 4 input samples, got %d" % n)
    if y_in.shape[0] != n:
        raise ValueError("lagrange3: %d times but %d samples" % (n, y_in.shape[0]))
    if not np.all(np.diff(t_in) > 0):
        raise ValueError("lagrange3: input times must be strictly increasing")
    if t_out.size and (t_out.min() < t_in[0] or t_out.max() > t_in[-1]):
        raise ValueError("lagrange3: output times [%g, %g] outside the input span [%g, %g]"
                         % (t_out.min(), t_out.max(), t_in[0], t_in[-1]))
    i = np.searchsorted(t_in, t_out, side="right") - 1
    first = np.clip(i - 1, 0, n - 4)              # stencil t[first] .. t[first+3]
    idx = first[:, None] + np.arange(4)[None, :]  # (m, 4)
    tn = t_in[idx]
    out = np.zeros((t_out.size,) + y_in.shape[1:])
    for j in range(4):
        w = np.ones(t_out.size)
        for k in range(4):
            if k != j:
                w *= (t_out - tn[:, k]) / (tn[:, j] - tn[:, k])
        yj = y_in[idx[:, j]]
        out += (w.reshape((-1,) + (1,) * (y_in.ndim - 1))) * yj
    return out


def to_dist_step(t_s, x, y, duration_s=None, period_us=DIST_PERIOD_US):
    """Resample (x, y) given at times ``t_s`` to the distfile step; returns (x, y) arrays.

    The output starts at ``t_s[0]`` and its last sample is at or after ``duration_s`` (default: the whole
    input span, its last sample at or before the span's end).
    """
    t_s = np.asarray(t_s, dtype=float)
    span = t_s[-1] - t_s[0]
    dt = period_us * 1e-6
    if duration_s is None:
        count = int(np.floor(span / dt + 1e-9)) + 1
    else:
        count = int(np.ceil(duration_s / dt - 1e-9)) + 1
    if (count - 1) * dt > span + 1e-9:
        raise ValueError("duration %g s needs the source up to %g s, it has %g s"
                         % (duration_s, (count - 1) * dt, span))
    t_out = t_s[0] + np.arange(count) * dt
    xy = lagrange3(t_s, np.column_stack([x, y]), t_out)
    return xy[:, 0], xy[:, 1]
