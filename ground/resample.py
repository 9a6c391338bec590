"""Resampling of a source's time history onto the distfile step (Sec. 7.3.1).

The body pointing simulator produces error angles at its own rate (10 Hz in the thesis); they are
resampled by 3rd-order Lagrange interpolation to a step of 8.192 ms (122.07 Hz) before the distfile is
written. Here the input times may be any strictly increasing sequence (a user's CSV need not be uniform).
"""

import numpy as np

from emulator.interp import lagrange3

DIST_PERIOD_US = 8192  # distfile step, Sec. 7.3.1


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


# --- bandwidth: what a distfile step can hold and what the player plays -------------------------------------
PFSM_PERIOD_US = 1e6 / 10600.0    # the P-FSM update period (94.34 us): no distfile step below it plays
MIN_STEP_US = int(np.ceil(PFSM_PERIOD_US))   # the finest distfile step, a whole number of us (95)
AA_ORDER = 8                      # anti-aliasing filter: Butterworth, applied forward and backward (zero phase)
AA_FRACTION = 0.8                 # its cutoff, as a fraction of the file's Nyquist frequency
AA_TAG = "+aa"                    # appended to the distfile's source name when the filter was applied


def nyquist_hz(period_us):
    return 0.5e6 / period_us


def antialias_gain(f_hz, period_us):
    """Amplitude response of the anti-aliasing filter for a file of step period_us: the Butterworth of order
    AA_ORDER at AA_FRACTION x Nyquist, forward and backward, |H|^2 = 1 / (1 + (f / fc)^(2 n))."""
    fc = AA_FRACTION * nyquist_hz(period_us)
    return 1.0 / (1.0 + (np.asarray(f_hz, float) / fc) ** (2 * AA_ORDER))


# Keys's 6-point kernel (firmware/player.py), pieces on [0, 1), [1, 2), [2, 3) in u = |t| / Ts: x^3 .. x^0
KEYS6 = ((4 / 3, -7 / 3, 0.0, 1.0), (-7 / 12, 3.0, -59 / 12, 2.5), (1 / 12, -2 / 3, 7 / 4, -1.5))
_GL_X, _GL_W = np.polynomial.legendre.leggauss(32)


def keys6_kernel(u):
    """Keys's 6-point cubic convolution kernel W(u) (firmware/player.py), u in units of the step."""
    u = np.abs(np.asarray(u, float))
    out = np.zeros_like(u)
    for k, c in enumerate(KEYS6):
        m = (u >= k) & (u < k + 1)
        out[m] = np.polyval(c, u[m])
    return out


def keys6_gain_closed(nu):
    """The kernel's transform in closed form (firmware/player.py derives it), nu = f Ts: with w = 2 pi nu,
    G = [48 - 69 cos w + 24 cos 2w - 3 cos 3w - w (5 sin w - 4 sin 2w + sin 3w)] / (3 w^4). It cancels to
    rounding error at small nu (w^4 in the denominator): ``player_gain`` integrates instead."""
    w = 2 * np.pi * np.asarray(nu, float)
    return (48 - 69 * np.cos(w) + 24 * np.cos(2 * w) - 3 * np.cos(3 * w)
            - w * (5 * np.sin(w) - 4 * np.sin(2 * w) + np.sin(3 * w))) / (3 * w ** 4)


def player_gain(f_hz, period_us, kernel="keys6"):
    """The disturbance player's gain on a tone f in a file of step Ts = period_us (firmware/player.py): the
    transform of its interpolation kernel at nu = f Ts; its images at k/Ts -+ f come out at the gain of
    k -+ f Ts. ``keys6`` (the player): G = 2 int_0^3 W(u) cos(2 pi nu u) du, by 32-point Gauss-Legendre per
    piece (exact to rounding for nu < 3; equal to ``keys6_gain_closed``): 0.990 at nu = 0.2. ``linear`` (the
    thesis's SimArduino, Sec. 7.3.1): the triangle kernel's sinc^2(nu) (np.sinc(x) = sin(pi x) / (pi x))."""
    nu = np.asarray(f_hz, float) * period_us * 1e-6
    if kernel == "linear":
        return np.sinc(nu) ** 2
    if kernel != "keys6":
        raise ValueError("player kernel %r: keys6 or linear" % (kernel,))
    g = np.zeros_like(nu)
    for k, c in enumerate(KEYS6):
        u = k + 0.5 * (_GL_X + 1.0)
        g = g + np.cos(2 * np.pi * nu[..., None] * u) @ (0.5 * _GL_W * np.polyval(c, u))
    return 2.0 * g


def antialias(t_s, x, y, period_us, what="source"):
    """Keep a source from aliasing when it is resampled to ``period_us``.

    Returns (x, y, filtered). A source no faster than the file needs nothing (its content is below its own
    Nyquist frequency, at most the file's). A faster uniform source is low-pass filtered (``antialias_gain``,
    scipy.signal.butter + sosfiltfilt) before resampling; a faster non-uniform one is refused, naming its
    highest representable frequency and the file's Nyquist frequency.
    """
    t_s = np.asarray(t_s, float)
    dt = np.diff(t_s)
    step = float(np.median(dt))
    file_step = period_us * 1e-6
    if step >= file_step * (1 - 1e-9):
        return x, y, False
    nyq = nyquist_hz(period_us)
    if np.max(np.abs(dt - step)) > 1e-6 * step + 1e-12:
        raise ValueError("%s: its samples are not uniform and come faster (median step %.6g s, content up to "
                         "%.4g Hz) than the distfile step %d us can hold (Nyquist %.4g Hz): resample it "
                         "uniformly (it is then low-pass filtered) or use a finer --step-us"
                         % (what, step, 0.5 / step, period_us, nyq))
    from scipy import signal
    sos = signal.butter(AA_ORDER, AA_FRACTION * nyq, fs=1.0 / step, output="sos")
    if len(x) <= 3 * (2 * len(sos) + 1):
        raise ValueError("%s: too few samples (%d) to low-pass filter before resampling" % (what, len(x)))
    return signal.sosfiltfilt(sos, x), signal.sosfiltfilt(sos, y), True
