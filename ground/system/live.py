"""The live disturbance of ``fps system``: the ADCS's 10 Hz body pointing error turned into distfile samples for the P-FSM player as the run goes."""

import struct

import numpy as np


# --- the live disturbance: 10 Hz body pointing error -> distfile samples -> the P-FSM player ------------------
class LiveDistfile:
    """A float32 distfile (``protocol.distfile`` kind 1) growing in memory, read by ``firmware.player.Player``
    exactly as a file: ``raw``, ``count``, ``sample_offset(i)``, ``period_us``, ``kind``, ``scale``."""

    kind = 1
    scale = 1.0

    def __init__(self, period_us):
        self.period_us = int(period_us)
        self.raw = bytearray()
        self.count = 0

    def append(self, x, y):
        xy = np.empty(2 * len(x), dtype="<f4")
        xy[0::2], xy[1::2] = x, y
        self.raw += xy.tobytes()
        self.count += len(x)

    def sample_offset(self, i):
        if i < 0 or i >= self.count:
            raise IndexError("live distfile sample %d out of range [0, %d)" % (i, self.count))
        return 8 * i

    def sample(self, i):
        return struct.unpack_from("<ff", self.raw, self.sample_offset(i))


class LiveDisturbance:
    """The body pointing error (t in s of the ADCS, dtheta in arcsec, 10 Hz) from ``t0`` on, resampled to the
    distfile step as it arrives (3rd-order Lagrange, Sec. 7.3.1; a sample is made once its 4-point stencil is
    known, so it equals ``ground.resample.to_dist_step`` of the whole history) and appended to ``reader``.
    ``covered_s`` is the play time known so far. A sample beyond the P-FSM's range (a bench limit, not the
    spacecraft's) is played at the range's edge and counted: ``unplayable`` holds the (start, end) play times
    of each such window, ``n_unplayable`` the samples; a sample that is not a number raises ValueError."""

    def __init__(self, t0, period_us=None):
        from ground.resample import DIST_PERIOD_US
        self.t0 = float(t0)
        self.reader = LiveDistfile(period_us or DIST_PERIOD_US)
        self.dt = self.reader.period_us * 1e-6
        self.t = np.zeros(0)
        self.xy = np.zeros((0, 2))
        self.x, self.y = [], []       # what was made, arcsec (for the summary)
        self.unplayable = []          # (start, end) s of the play with the body error beyond the P-FSM's range
        self.n_unplayable = 0

    def add(self, t, dtheta_arcsec):
        keep = np.asarray(t) >= self.t0 - 1e-9
        if not keep.any():
            return
        self.t = np.concatenate([self.t, np.asarray(t, float)[keep]])
        self.xy = np.vstack([self.xy, np.asarray(dtheta_arcsec, float)[keep]])
        self._make()

    @property
    def covered_s(self):
        return (self.reader.count - 1) * self.dt if self.reader.count else -1.0

    def _make(self):
        from ground.resample import lagrange3
        n = len(self.t)
        if n < 4:
            return
        j0 = self.reader.count
        j1 = j0
        while self.t0 + j1 * self.dt < self.t[n - 2] - 1e-9:     # stencil t[i-1] .. t[i+2] all known
            j1 += 1
        if j1 == j0:
            return
        t_out = self.t0 + np.arange(j0, j1) * self.dt
        i = int(np.searchsorted(self.t, t_out[0], side="right")) - 1
        w = max(0, i - 1)
        xy = lagrange3(self.t[w:], self.xy[w:], t_out)
        if not np.isfinite(xy).all():
            k = j0 + int(np.flatnonzero(~np.isfinite(xy).all(axis=1))[0])
            raise ValueError("the live body pointing error cannot be played: sample %d (t = %.3f s of the play) "
                             "is not a number" % (k, k * self.dt))
        self._clip(xy, j0)
        self.x.extend(xy[:, 0].tolist())
        self.y.extend(xy[:, 1].tolist())
        self.reader.append(xy[:, 0], xy[:, 1])

    def _clip(self, xy, j0):
        """Hold the samples beyond the P-FSM's range at its edge (in place), recording their windows."""
        from ground.distfile_cli import MAX_THETA_E_ARCSEC as lim
        out = np.flatnonzero((np.abs(xy) > lim).any(axis=1))
        if not out.size:
            return
        np.clip(xy, -lim, lim, out=xy)
        self.n_unplayable += int(out.size)
        for k in (j0 + out).tolist():
            t = k * self.dt
            if self.unplayable and t - self.unplayable[-1][1] <= self.dt * 1.5:
                self.unplayable[-1][1] = t + self.dt
            else:
                self.unplayable.append([t, t + self.dt])
