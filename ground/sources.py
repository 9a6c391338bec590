"""Disturbance sources: body-pointing error histories (X, Y in arcsec) for the distfile.

Each source produces samples at its own rate; ``ground.resample`` brings them to the 8.192 ms distfile step
(Sec. 7.3.1). Sources register by name in ``SOURCES`` (stat, sine, csv; bps, the body pointing simulator of
Ch. 6; jitter) so a new one plugs in with ``register_source``: it needs ``add_arguments(parser)`` (its CLI
options, in a --help group of its own; ``fps distfile generate`` refuses them with another source) and
``from_args(args)`` returning an object with ``generate(duration_s, seed) -> (t_s, x, y)``.
"""

import csv

import numpy as np

from ground.source_registry import SOURCES, get_source, register_source  # noqa: F401  (sources.SOURCES, get_source)

# Ch. 6 "Body pointing" table, ts = 33 s: (mean, 1 sigma) of delta-theta (arcsec), delta-omega (arcsec/s).
BODY_POINTING = {
    "gnss": {  # with SatB GNSS (2-3 s delay)
        "theta": ((0.955, 20.143), (12.795, 33.945)),
        "omega": ((-0.024, 7.054), (-0.128, 8.744)),
    },
    "nognss": {  # without SatB GNSS
        "theta": ((1.261, 21.456), (18.644, 35.919)),
        "omega": ((-0.033, 6.764), (-0.031, 8.617)),
    },
}

def _pair(text, what):
    try:
        vals = [float(v) for v in str(text).split(",")]
    except ValueError:
        raise ValueError("%s: expected 'X,Y' numbers, got %r" % (what, text)) from None
    if len(vals) == 1:
        vals = vals * 2
    if len(vals) != 2 or not all(np.isfinite(vals)):
        raise ValueError("%s: expected 'X,Y' finite numbers, got %r" % (what, text))
    return vals


class GaussMarkov2:
    """Second-order Gauss-Markov error process per axis, fitted to the Ch. 6 body pointing statistics.

    theta'' + 2 zeta wn theta' + wn^2 theta = w (white, density q). Its stationary covariance is diagonal,
    var(theta) = q / (4 zeta wn^3), var(theta') = q / (4 zeta wn), so wn = sigma_omega / sigma_theta
    matches both 1-sigma values of the table. zeta = 1 (critical damping) as the quaternion PD law of
    Eq. 6.5-6.7. The mean of delta-theta is added; the table's mean rates (|mean| < 2 % of 1 sigma) are
    taken as zero, since a stationary angle has zero-mean rate. Discretised exactly at ``rate_hz``:
    x[k+1] = Phi x[k] + w[k], cov(w) = P - Phi P Phi^T with P the stationary covariance.
    """

    name = "stat"

    def __init__(self, case="gnss", rate_hz=10.0, scale=1.0, zeta=1.0):
        if case not in BODY_POINTING:
            raise ValueError("stat case %r unknown (known: %s)" % (case, ", ".join(BODY_POINTING)))
        if not rate_hz > 0:
            raise ValueError("stat rate_hz must be > 0, got %r" % rate_hz)
        if not 1e-6 <= scale < np.inf:
            raise ValueError("stat scale must be finite and >= 1e-6 (at 0 the process is undefined), got %r" % scale)
        if not zeta > 0:
            raise ValueError("stat zeta must be > 0, got %r" % zeta)
        self.case, self.rate_hz, self.scale, self.zeta = case, float(rate_hz), float(scale), float(zeta)
        tab = BODY_POINTING[case]
        self.mean = np.array([tab["theta"][0][0], tab["theta"][1][0]]) * self.scale
        self.sig_theta = np.array([tab["theta"][0][1], tab["theta"][1][1]]) * self.scale
        self.sig_omega = np.array([tab["omega"][0][1], tab["omega"][1][1]]) * self.scale
        self.wn = self.sig_omega / self.sig_theta

    @staticmethod
    def add_arguments(p):
        p.add_argument("--stat-case", default="gnss", choices=sorted(BODY_POINTING),
                       help="Ch. 6 body pointing case, ts = 33 s (default: with SatB GNSS)")
        p.add_argument("--stat-rate-hz", type=float, default=10.0, help="source rate (default 10 Hz, as the BPS)")
        p.add_argument("--stat-scale", type=float, default=1.0, help="multiply mean and 1-sigma by this (>= 1e-6)")

    @classmethod
    def from_args(cls, a):
        return cls(a.stat_case, a.stat_rate_hz, a.stat_scale)

    def transition(self, dt):
        """Phi(dt) for each axis, shape (2, 2, 2) [axis, row, col]."""
        out = np.empty((2, 2, 2))
        for ax, wn in enumerate(self.wn):
            a = np.array([[0.0, 1.0], [-wn * wn, -2.0 * self.zeta * wn]])
            out[ax] = _expm2(a * dt)
        return out

    def generate(self, duration_s, seed):
        dt = 1.0 / self.rate_hz
        n = _n_samples(duration_s, self.rate_hz)
        rng = np.random.default_rng(seed)
        phi = self.transition(dt)
        xs = np.empty((n, 2))
        for ax in range(2):
            p = np.diag([self.sig_theta[ax] ** 2, self.sig_omega[ax] ** 2])
            qd = p - phi[ax] @ p @ phi[ax].T
            lq = np.linalg.cholesky(qd + 1e-12 * np.eye(2) * p.max())
            x = np.linalg.cholesky(p) @ rng.standard_normal(2)
            w = rng.standard_normal((n, 2)) @ lq.T
            for k in range(n):
                xs[k, ax] = x[0]
                x = phi[ax] @ x + w[k]
        t = np.arange(n) * dt
        return t, xs[:, 0] + self.mean[0], xs[:, 1] + self.mean[1]


MAX_SOURCE_SAMPLES = 1 << 24      # ~400 MB of float64 t, x, y: a source longer than this is a mistake


def _n_samples(duration_s, rate_hz):
    """Samples covering the duration plus one distfile step and the resampler's stencil."""
    n = (duration_s + 0.01) * rate_hz
    if not n < MAX_SOURCE_SAMPLES:
        raise ValueError("%g s at %g Hz is %.3g source samples, more than %d: lower the duration or the "
                         "source rate" % (duration_s, rate_hz, n, MAX_SOURCE_SAMPLES))
    return int(np.ceil(n)) + 4


def _expm2(a):
    """Matrix exponential of a small matrix by scaling and squaring of a Taylor series."""
    s = max(0, int(np.ceil(np.log2(max(np.abs(a).sum(axis=1).max(), 1e-300)))) + 1)
    a = a / (2 ** s)
    e = np.eye(a.shape[0])
    term = np.eye(a.shape[0])
    for k in range(1, 20):
        term = term @ a / k
        e = e + term
    for _ in range(s):
        e = e @ e
    return e


class Sine:
    """One sine per axis: theta(t) = amp * sin(2 pi f t + phase) + offset, produced at ``rate_hz``."""

    name = "sine"

    def __init__(self, amp_arcsec=(30.0, 30.0), freq_hz=(0.1, 0.13), phase_deg=(0.0, 90.0),
                 offset_arcsec=(0.0, 0.0), rate_hz=None):
        self.amp = np.asarray(amp_arcsec, dtype=float)
        self.freq = np.asarray(freq_hz, dtype=float)
        self.phase = np.radians(np.asarray(phase_deg, dtype=float))
        self.offset = np.asarray(offset_arcsec, dtype=float)
        if rate_hz is not None and not rate_hz > 0:
            raise ValueError("sine rate_hz must be > 0, got %g" % rate_hz)
        if not np.all(self.amp >= 0):
            raise ValueError("--amp-arcsec %s: amplitudes must be >= 0 arcsec (a sign is a phase: --phase-deg)"
                             % [float(v) for v in self.amp])
        if np.any(self.freq < 0):
            raise ValueError("sine freq_hz %s must be >= 0" % [float(v) for v in self.freq])
        if rate_hz is not None and np.any(self.freq >= rate_hz / 2):
            raise ValueError("sine freq_hz %s must be below its rate's Nyquist frequency %g Hz"
                             % ([float(v) for v in self.freq], rate_hz / 2))
        self.rate_hz = None if rate_hz is None else float(rate_hz)

    def check_rate(self, period_us):
        """Refuse a tone at or above the distfile's Nyquist frequency (it would alias); by default the sine is
        produced at the file's own rate."""
        nyq = 0.5e6 / period_us
        top = float(self.freq.max())
        if top >= nyq:
            need = int(0.5e6 / top / 1.25)
            from ground.resample import MIN_STEP_US as finest
            hint = ("use --step-us %d or finer" % need if need >= finest else
                    "the finest step, %d us, plays tones below %g Hz" % (finest, 0.5e6 / finest))
            raise ValueError("sine %g Hz is at or above the distfile's Nyquist frequency %g Hz (step %d us): it "
                             "would alias; %s" % (top, nyq, period_us, hint))
        if self.rate_hz is None:
            self._file_rate = 1e6 / period_us

    @staticmethod
    def add_arguments(p):
        p.add_argument("--amp-arcsec", default="30,30", help="sine amplitudes X,Y (arcsec)")
        p.add_argument("--freq-hz", default="0.1,0.13", help="sine frequencies X,Y (Hz)")
        p.add_argument("--phase-deg", default="0,90", help="sine phases X,Y (deg)")
        p.add_argument("--offset-arcsec", default="0,0", help="constant offsets X,Y (arcsec)")
        p.add_argument("--sine-rate-hz", type=float, default=None,
                       help="source rate (Hz; default the distfile's own rate; a faster one is low-pass filtered "
                            "before resampling)")

    @classmethod
    def from_args(cls, a):
        return cls(_pair(a.amp_arcsec, "--amp-arcsec"), _pair(a.freq_hz, "--freq-hz"),
                   _pair(a.phase_deg, "--phase-deg"), _pair(a.offset_arcsec, "--offset-arcsec"),
                   a.sine_rate_hz)

    def generate(self, duration_s, seed):
        rate = self.rate_hz or getattr(self, "_file_rate", 1000.0)
        t = np.arange(_n_samples(duration_s, rate)) / rate
        xy = [self.amp[i] * np.sin(2 * np.pi * self.freq[i] * t + self.phase[i]) + self.offset[i]
              for i in range(2)]
        return t, xy[0], xy[1]


CSV_MAX_BYTES = 1 << 30
CSV_MAX_GAP = 10.0        # largest spacing, in median spacings, a CSV may have (uneven times are fine below it)


class CsvSource:
    """A user's own history: CSV with columns t_s, x_arcsec, y_arcsec (header optional), any rate,
    strictly increasing times (not necessarily uniform, but no gap over CSV_MAX_GAP median spacings)."""

    name = "csv"

    def __init__(self, path):
        self.path = path
        self.t, self.x, self.y = read_csv(path)

    @staticmethod
    def add_arguments(p):
        p.add_argument("--csv", dest="csv_path", help="input CSV for --source csv (t_s, x_arcsec, y_arcsec)")

    @classmethod
    def from_args(cls, a):
        if not a.csv_path:
            raise ValueError("--source csv needs --csv FILE")
        return cls(a.csv_path)

    def generate(self, duration_s, seed):
        return self.t - self.t[0], self.x, self.y


def read_csv(path):
    """Read (t_s, x_arcsec, y_arcsec) columns; a non-numeric first row is a header."""
    import io
    from ground.fileio import read_input
    rows = []
    with io.StringIO(read_input(path, "csv", CSV_MAX_BYTES), newline="") as f:
        for lineno, row in enumerate(csv.reader(f), 1):
            if not row or row[0].lstrip().startswith("#"):
                continue
            try:
                vals = [float(v) for v in row[:3]]
            except ValueError:
                if not rows and lineno == 1:
                    continue  # header
                raise ValueError("%s line %d: expected numbers t_s,x_arcsec,y_arcsec, got %r"
                                 % (path, lineno, row)) from None
            if len(vals) < 3:
                raise ValueError("%s line %d: expected 3 columns, got %d" % (path, lineno, len(vals)))
            rows.append(vals)
    a = np.array(rows, dtype=float).reshape(-1, 3)
    if len(a) < 4:
        raise ValueError("%s: need at least 4 samples, got %d" % (path, len(a)))
    if not np.all(np.isfinite(a)):
        bad = int(np.argwhere(~np.isfinite(a))[0][0])
        raise ValueError("%s: non-finite value in sample %d" % (path, bad))
    if not np.all(np.diff(a[:, 0]) > 0):
        bad = int(np.argmax(np.diff(a[:, 0]) <= 0)) + 1
        raise ValueError("%s: times must be strictly increasing (sample %d, t_s=%g)" % (path, bad, a[bad, 0]))
    dt = np.diff(a[:, 0])
    med = float(np.median(dt))
    if dt.max() > CSV_MAX_GAP * med:
        k = int(np.argmax(dt))
        raise ValueError("%s: a gap of %g s after sample %d (t_s=%g), %.0f times the median spacing %g s: the "
                         "3rd-order interpolation would invent the samples across it; fill the gap or split the "
                         "file" % (path, dt[k], k, a[k, 0], dt[k] / med, med))
    return a[:, 0], a[:, 1], a[:, 2]


register_source("stat", GaussMarkov2)
register_source("sine", Sine)
register_source("csv", CsvSource)



def _register_bps():
    from ground.adcs.bps_source import BpsSource   # the body pointing simulator of Sec. 6.4
    register_source("bps", BpsSource)


_register_bps()

from ground.jitter import WheelJitter  # noqa: E402  (it takes its --jitter-base from the registry)

register_source("jitter", WheelJitter)
