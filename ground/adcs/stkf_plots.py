"""The STKF campaign's figures (``fps adcs stkf``): Fig. 5-4/5-6, each state's error against its ±3σ, SatA's
in J2000 and SatB's in its orbit's along-track, cross-track and radial frame (its covariance is long along the
track, where the beacon's bearing does not reach it; resolved on J2000's axes that ellipse's shadow on an axis
pinches whenever the track turns across it); Fig. 5-5/5-7, the pointing vector's error in the body frame. Each
panel zoomed past the start-up transient, which an inset shows, the first run coloured and the others grey."""

import os

import numpy as np

from ground import plots as gp
from ground.plots import FRAME_AXES, in_frame, inset, legend, orbit_frame, subplots, zoom_after

TRANSIENT_SHARE = 0.2                  # the first 20 % of the run: the start-up transient the inset shows


def _load(run_dirs):
    hs = []
    for d in run_dirs:
        p = os.path.join(d, "history.npz")
        if os.path.exists(p):
            with np.load(p) as z:
                hs.append({k: z[k] for k in z.files})
    return hs


def states_in_frames(h):
    """(err, sig) of [rA, vA, rB, vB] (n, 12): SatA's on J2000's x, y, z, SatB's on its orbit's (along-track,
    cross-track, radial) from its estimate and covariance (history ``xB``, ``PB``); without them J2000's."""
    err, sig = np.array(h["err"], float), np.array(h["sig"], float)
    if "xB" in h and "PB" in h:
        M = orbit_frame(h["xB"][:, 0:3], h["xB"][:, 3:6])
        P = h["PB"].reshape(-1, 6, 6)
        for j, sl in ((6, slice(0, 3)), (9, slice(3, 6))):
            err[:, j:j + 3], sig[:, j:j + 3] = in_frame(M, h["err"][:, j:j + 3], P[:, sl, sl])
    return err, sig


def _panel(a, hs, cols, i, t0, bounds=(0.6, 0.62, 0.37, 0.34)):
    """One component: the other runs grey, the first run's error blue, its ±3σ red dashed; zoomed past t0 on
    the first run's envelope and error, the transient inset."""
    for h, (e, _) in zip(hs[1:], cols[1:]):
        a.plot(h["t"], e[:, i], color="0.75", lw=0.5)
    (e, s), t = cols[0], hs[0]["t"]
    a.plot(t, e[:, i], "b", lw=0.7)
    a.plot(t, 3 * s[:, i], "r--", lw=0.8)
    a.plot(t, -3 * s[:, i], "r--", lw=0.8)
    if zoom_after(a, t, t0, [3 * s[:, i], e[:, i]], q=1.0, margin=1.25):
        inset(a, t_end=t0, bounds=bounds, title="first %.0f s" % t0)


def _keys(a, hs):
    a.plot([], [], "b", label="error" + (" (first run)" if len(hs) > 1 else ""))
    if len(hs) > 1:
        a.plot([], [], color="0.75", label="the other run" if len(hs) == 2 else "the other %d runs" % (len(hs) - 1))
    a.plot([], [], "r--", label="±3σ (the filter's)")
    legend(a, outside=True)


def plot_states(path, hs, case):
    """Fig. 5-4/5-6: rA, vA (J2000) and rB, vB (SatB's along-track, cross-track, radial) errors with ±3σ."""
    cols = [states_in_frames(h) for h in hs]
    framed = "xB" in hs[0]
    t = hs[0]["t"]
    t0 = t[int(len(t) * TRANSIENT_SHARE)]
    fig, ax = subplots(3, 4, width=15, row_height=2.5, sharex=True)
    for c, (what, unit) in enumerate((("rA", "m"), ("vA", "m/s"), ("rB", "m"), ("vB", "m/s"))):
        axes = FRAME_AXES if c >= 2 and framed else ("x (J2000)", "y (J2000)", "z (J2000)")
        for r in range(3):
            a = ax[r, c]
            _panel(a, hs, cols, 3 * c + r, t0)
            a.set_ylabel("%s %s (%s)" % (what, axes[r], unit), fontsize=8)
        ax[0, c].set_title("%s error%s" % (what, ", SatB's orbit frame" if c >= 2 and framed else ", J2000"),
                           fontsize=9)
        ax[2, c].set_xlabel("time (s)")
    _keys(ax[2, 0], hs)
    fig.suptitle("STKF Case %d: state errors against the filter's ±3σ, zoomed past the first %.0f s (inset); holds "
                 "where the blue trace stays inside the red dashes" % (case, t0), fontsize=10)
    fig.tight_layout()
    gp.save_png(fig, path, dpi=90)


def plot_pointing(path, hs, case):
    """Fig. 5-5/5-7: the pointing vector's error in the body frame (two angles) with ±3σ."""
    t = hs[0]["t"]
    t0 = t[int(len(t) * TRANSIENT_SHARE)]
    cols = [(h["perr"], h["psig"]) for h in hs]
    fig, ax = subplots(2, 1, width=11, row_height=2.6, sharex=True)
    for j in range(2):
        _panel(ax[j, 0], hs, cols, j, t0, bounds=(1.08, 0.05, 0.25, 0.9))       # beside the axes
        ax[j, 0].set_ylabel("angle %d (arcsec)" % (j + 1))
    ax[1, 0].set_xlabel("time (s)")
    _keys(ax[1, 0], hs)
    fig.suptitle("STKF Case %d: pointing vector error in the body frame against ±3σ, zoomed past the first "
                 "%.0f s (inset)" % (case, t0), fontsize=10)
    fig.tight_layout()
    gp.save_png(fig, path, dpi=90)


def plots(out_dir, run_dirs, case, names):
    """Both figures of the runs' histories into ``out_dir`` (``names``: stkf_sim.FIGURES); the names written."""
    hs = _load(run_dirs)
    if not hs:
        return []
    files = [names[0 if case == 1 else 2], names[1 if case == 1 else 3]]
    plot_states(os.path.join(out_dir, files[0]), hs, case)
    plot_pointing(os.path.join(out_dir, files[1]), hs, case)
    return files
