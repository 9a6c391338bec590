"""The plots, in one house style: every axis labelled with its unit, a legend where there is more than one trace,
the requirement or budget drawn and labelled, scales chosen so the signal shows (a zoomed panel, a 2-D histogram
where points pile up, a log scale), fault and mode windows shaded, the symbols the reports use (δθ1, δθ2), the
thesis's figure number in the file name. The helpers here are what every plot of ``fps`` uses; this module draws
the calibration (Fig. 7-16/7-17), HIL (Fig. 7-18/7-19), ``fps system`` and ``fps adcs can`` figures.
tests/test_plots.py opens every figure and checks its labels and legends. Agg backend."""

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ground.fileio import write_atomic  # noqa: E402

ARCSEC_SIGN = '″'
REQUIREMENT_COLOR = "tab:red"
FAULT_COLOR = "0.85"


def save_png(fig, path, dpi=110):
    """Write ``fig`` as a PNG atomically (no half-written file after an interruption) and close it."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    write_atomic(path, buf.getvalue())


def subplots(nrows=1, ncols=1, width=9.0, row_height=2.8, **kw):
    """``plt.subplots`` in the house size (``row_height`` inches a row, so that one row is not a strip) with a
    light grid on every axes; ``squeeze`` False: always a 2-D array."""
    fig, axs = plt.subplots(nrows, ncols, figsize=(width, row_height * nrows + 0.8), squeeze=False, **kw)
    for ax in axs.flat:
        ax.grid(True, lw=0.3, alpha=0.6)
    return fig, axs


def band(ax, value, label, color=REQUIREMENT_COLOR):
    """A requirement or budget as labelled dashed lines at +-value; when the data sit far inside it (the axis
    zoomed on them), the label says so instead of stretching the axis."""
    lo, hi = ax.get_ylim()
    if hi >= value or lo <= -value:
        for sgn in (-1, 1):
            ax.axhline(sgn * value, color=color, ls="--", lw=0.8, label=label if sgn > 0 else None)
    else:
        ax.plot([], [], color=color, ls="--", lw=0.8, label="%s (beyond this zoomed axis)" % label)


def shade(ax, windows, label):
    """Shade each (t0, t1) window (t1 None: to the end), labelled once in the legend."""
    first = True
    for t0, t1 in windows:
        ax.axvspan(t0, ax.get_xlim()[1] if t1 is None else t1, color=FAULT_COLOR, alpha=0.6, lw=0,
                   label=label if first else None)
        first = False


def zoom(ax, y, lo_share=0.05, margin=1.3):
    """Y limits on the data's bulk (the central 1 - 2 lo_share of |y|'s distribution, widened by ``margin``), so
    that a start-up transient does not hide the steady state."""
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    if len(y) == 0:
        return
    hi = float(np.quantile(np.abs(y), 1 - lo_share)) * margin
    if hi > 0:
        ax.set_ylim(-hi, hi)


def legend(ax, outside=False, **kw):
    """The legend; ``outside``: below the axes ("right": beside them), where it covers no trace."""
    if outside == "right":
        return ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False, **kw)
    if outside:
        return ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=4, fontsize=8, frameon=False, **kw)
    return ax.legend(**dict({"fontsize": 8}, **kw))


def _centre_index(v0):
    return int(np.argmin(np.hypot(v0[:, 0], v0[:, 1])))


def calibration_quivers(cal, path):
    """Fig. 7-16: h_x (blue) and h_y (red), the columns of H, at each nulling point (V0x, V0y)."""
    pts = [p for p in cal["points"] if p.get("H") is not None]
    v0 = np.array([p["v0"] for p in pts])
    h = np.array([p["H"] for p in pts])
    fig, ax = plt.subplots(figsize=(7.6, 5.2))
    ref = float(np.median(np.linalg.norm(h, axis=1)))           # both quivers on one scale: a key says which
    span = float(np.ptp(v0[:, 0])) if len(v0) > 1 else 1.0
    scale = ref / (0.6 * span / max(1, int(np.sqrt(len(v0))) - 1 or 1)) if span > 0 else 1.0
    q = ax.quiver(v0[:, 0], v0[:, 1], h[:, 0, 0], h[:, 1, 0], color="b", label="h_x = (a, c)", angles="xy",
                  scale_units="xy", scale=scale)
    ax.quiver(v0[:, 0], v0[:, 1], h[:, 0, 1], h[:, 1, 1], color="r", label="h_y = (b, d)", angles="xy",
              scale_units="xy", scale=scale)
    ax.quiverkey(q, 1.1, 0.62, ref, "scale: %.1f per V\n(ratio change per volt)" % ref, labelpos="S",
                 coordinates="axes", fontproperties={"size": 8})
    c = _centre_index(v0)
    ax.plot(v0[c, 0], v0[c, 1], "ko", mfc="none", ms=10, label="centre")
    ax.set_xlabel("V0x (V)")
    ax.set_ylabel("V0y (V)")
    ax.set_title("H calibration: h_x, h_y over (V0x, V0y), cf. Fig. 7-16", loc="left", fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    fig.tight_layout()
    save_png(fig, path)


def calibration_difference(cal, path):
    """Fig. 7-17: |h - h_centre| / |h_centre| in percent for h_x and h_y over (V0x, V0y)."""
    pts = [p for p in cal["points"] if p.get("H") is not None]
    v0 = np.array([p["v0"] for p in pts])
    h = np.array([p["H"] for p in pts])
    c = _centre_index(v0)
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.4), sharey=True)
    for k, (ax, name) in enumerate(zip(axs, ("h_x", "h_y"))):
        col = h[:, :, k]
        pct = 100 * np.linalg.norm(col - col[c], axis=1) / np.linalg.norm(col[c])
        sc = ax.scatter(v0[:, 0], v0[:, 1], c=pct, cmap="viridis", s=40, label="%s at each nulling point" % name)
        ax.plot(v0[c, 0], v0[c, 1], "ko", mfc="none", ms=10, label="centre (the reference)")
        fig.colorbar(sc, ax=ax, label="difference of %s from the centre (%%)" % name)
        ax.set_xlabel("V0x (V)")
        ax.set_ylabel("V0y (V)")
        legend(ax, loc="upper left")
        ax.set_title("%s: %.2f … %.2f %%" % (name, np.delete(pct, c).min() if len(pct) > 1 else 0, pct.max()))
    fig.suptitle("Δh pattern over (V0x, V0y), cf. Fig. 7-17")
    fig.tight_layout()
    save_png(fig, path)


def _xy_frame(ax, lim, title):
    """A square X-Y error frame of +-lim arcsec."""
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("X error (arcsec)")
    ax.set_ylabel("Y error (arcsec)")
    ax.set_title(title, fontsize=9)


def hil_scatter(series, path, requirement_arcsec=11.98):
    """Fig. 7-18: the pointing errors in the X-Y plane. Left, at the requirement's scale: the 11.98 arcsec circle
    and the 1-4 arcsec rings, every series' samples as points; right, zoomed on the data: a 2-D histogram of the
    first series (samples per bin, log colour) and the others' outlines (their 99 % radius). ``series``: {label:
    (x, y)}."""
    fig, axs = subplots(1, 2, width=12, row_height=5.4)
    a, z = axs[0]
    colors = ("tab:blue", "tab:orange", "tab:green")
    lim = max(5.0, requirement_arcsec * 1.1)
    ring = np.linspace(0, 2 * np.pi, 256)
    for (label, (x, y)), col in zip(series.items(), colors):
        step = max(1, len(x) // 40000)
        a.plot(x[::step], y[::step], ".", ms=1.5, color=col, alpha=0.5, label=label)
        if len(x):
            lim = max(lim, float(np.ceil(np.hypot(x, y).max() + 0.5)))
    for r in (1, 2, 3, 4):
        a.plot(r * np.cos(ring), r * np.sin(ring), "k-", lw=0.5, label="1-4%s rings" % ARCSEC_SIGN if r == 1 else None)
    a.plot(requirement_arcsec * np.cos(ring), requirement_arcsec * np.sin(ring), "--", color=REQUIREMENT_COLOR,
           lw=0.9, label="requirement %.2f%s" % (requirement_arcsec, ARCSEC_SIGN))
    _xy_frame(a, lim, "at the requirement's scale")
    legend(a, markerscale=6, loc="upper right")
    items = [(k, np.asarray(x), np.asarray(y)) for k, (x, y) in series.items() if len(x)]
    if items:
        k0, x0, y0 = items[0]
        r = max(float(np.quantile(np.hypot(np.concatenate([it[1] for it in items]),
                                           np.concatenate([it[2] for it in items])), 0.999)) * 1.2, 1e-3)
        h = z.hist2d(x0, y0, bins=120, range=[[-r, r], [-r, r]], cmap="Blues", norm=matplotlib.colors.LogNorm())
        fig.colorbar(h[3], ax=z, label="%s samples per bin" % k0)
        z.plot([], [], "s", color="tab:blue", label="%s (histogram)" % k0)
        for (k, x, y), col in zip(items[1:], colors[1:]):
            r99 = float(np.quantile(np.hypot(x - x.mean(), y - y.mean()), 0.99))
            z.plot(x.mean() + r99 * np.cos(ring), y.mean() + r99 * np.sin(ring), color=col, lw=1.0,
                   label="%s: 99 %% within this circle" % k)
        _xy_frame(z, r, "zoomed on the data")
        legend(z, loc="upper right")
    fig.suptitle("Pointing errors in the X-Y plane, cf. Fig. 7-18")
    fig.tight_layout()
    save_png(fig, path)


def hil_time_history(series, path, requirement_arcsec=11.98):
    """Fig. 7-19: X and Y pointing errors against time on the data's scale, the requirement labelled (beyond
    the axis when the data sit far inside it), the legend below the axes (it covers no trace). ``series``:
    {label: (t, x, y)}."""
    fig, axs = subplots(2, 1, sharex=True, row_height=2.6)
    for label, (t, x, y) in series.items():
        step = max(1, len(t) // 60000)
        axs[0, 0].plot(t[::step], x[::step], lw=0.4, label=label)
        axs[1, 0].plot(t[::step], y[::step], lw=0.4, label=label)
    for ax in axs[:, 0]:
        band(ax, requirement_arcsec, "requirement %.2f%s" % (requirement_arcsec, ARCSEC_SIGN))
    axs[0, 0].set_ylabel("X error (arcsec)")
    axs[1, 0].set_ylabel("Y error (arcsec)")
    axs[1, 0].set_xlabel("time (s)")
    legend(axs[1, 0], outside=True)
    axs[0, 0].set_title("Pointing error time history, cf. Fig. 7-19")
    fig.tight_layout()
    save_png(fig, path)


def fault_windows(faults):
    """The (t0, t1) windows and their label of a fault dict (``fps system``/``fps adcs can``: wheel_silent
    [wheel, t0], startracker_blind [t0, t1], gnss_outage [t0, t1], beacon_lost t0), t1 None: to the end."""
    out = []
    for k, v in (faults or {}).items():
        if k == "wheel_silent":
            out.append(((v[1], None), "wheel %d silent" % v[0]))
        elif k in ("startracker_blind", "gnss_outage"):
            out.append(((v[0], v[1]), k.replace("_", " ")))
        elif k == "beacon_lost":
            out.append(((v, None), "beacon lost"))
    return out


def system_time_history(body, fine, path, requirement_arcsec=11.98, budget_3sigma_arcsec=150.0, faults=None):
    """``fps system``: the body pointing error (δθ1, δθ2 of the ADCS) and the fine pointing error (Q2) on one time
    axis, the ADCS's seconds (the fault options' clock); the fine panel zoomed on its data with the requirement
    labelled (beyond the axis when the data sit far inside it), the body panel with its 3σ budget; device
    faults shaded. ``body``, ``fine``: (t, x, y) or None."""
    panels = [p for p in ((body, "body pointing (ADCS)", ("δθ1", "δθ2"), budget_3sigma_arcsec,
                           "3σ budget %.0f%s" % (budget_3sigma_arcsec, ARCSEC_SIGN)),
                          (fine, "fine pointing (Q2)", ("X", "Y"), requirement_arcsec,
                           "requirement %.2f%s" % (requirement_arcsec, ARCSEC_SIGN))) if p[0] is not None]
    fig, axs = subplots(len(panels), 1, sharex=True, width=12)
    for ax, ((t, x, y), name, comps, lim, lim_label) in zip(axs[:, 0], panels):
        step = max(1, len(t) // 60000)
        ax.plot(t[::step], x[::step], lw=0.4, label="%s %s" % (name, comps[0]))
        ax.plot(t[::step], y[::step], lw=0.4, label="%s %s" % (name, comps[1]))
        ax.set_ylabel("%s (arcsec)" % name.split(" (")[0])
        zoom(ax, np.concatenate([x, y]), lo_share=0.001)
        if comps[0] == "δθ1" and len(t) > 1:                  # the body budget is on the 3σ: the window's drawn
            v = 3 * float(np.hypot(np.std(x), np.std(y)))
            ax.set_ylim(min(ax.get_ylim()[0], -1.1 * v), max(ax.get_ylim()[1], 1.1 * v))
            pass_levels(ax, [(t[0], t[-1])], [v], "3σ over the window, both axes: %.1f%s" % (v, ARCSEC_SIGN))
        band(ax, lim, lim_label)
        for (w, label) in fault_windows(faults):
            shade(ax, [w], label)
        legend(ax, outside="right")
    axs[-1, 0].set_xlabel("time from the ADCS's start (s)")
    axs[0, 0].set_title("Body pointing error (ADCS) and fine pointing error (Q2), one time axis; holds where the "
                        "black 3σ lies inside the body budget and every fine sample inside its requirement", fontsize=9)
    fig.tight_layout()
    save_png(fig, path)


def sigma_traces(ax, t, err, sig, names, n=3, lw=0.6, key=True):
    """Each column of ``err`` (solid, named in the legend) with its ±n``sig`` (dashed, the same colour; ``key``:
    a legend entry for the dashes): an estimator's error against its own nσ, colour i the i-th name."""
    for i, name in enumerate(names):
        c = "C%d" % i
        ax.plot(t, err[:, i], color=c, lw=lw, label=name)
        ax.plot(t, n * sig[:, i], color=c, ls="--", lw=lw)
        ax.plot(t, -n * sig[:, i], color=c, ls="--", lw=lw)
    if key:
        ax.plot([], [], color="k", ls="--", lw=lw, label="±%dσ (dashed, each trace's colour)" % n)


def zoom_after(ax, t, t0, ys, q=0.5, margin=1.5):
    """Y limits on the steady state: ±``margin`` x the largest ``q`` quantile of |y| over t >= t0 among ``ys``
    (a start-up transient, and with a low ``q`` recurring excursions, run off the axis: ``inset`` shows them).
    Returns the limit (None: no finite data there)."""
    t = np.asarray(t, float)
    sel = t >= t0
    lim = 0.0
    for y in ys:
        v = np.abs(np.asarray(y, float)[sel])
        v = v[np.isfinite(v)]
        if v.size:
            lim = max(lim, float(np.quantile(v, q)))
    if not lim > 0:
        return None
    ax.set_ylim(-margin * lim, margin * lim)
    return margin * lim


def beyond(ax, t, ys, label, mask=False):
    """Shade where any of ``ys`` runs off the axes' y range, labelled once: what the zoom leaves out (``inset``
    shows it). ``mask``: the axes' traces over ``t`` are left out there too (made before ``inset`` copies them, the
    inset keeps them), so that a trace off the axis outside the shading is one beyond its own envelope."""
    t = np.asarray(t, float)
    hi = ax.get_ylim()[1]
    off = np.zeros(len(t), bool)
    for y in ys:
        off |= np.abs(np.nan_to_num(np.asarray(y, float))) > hi
    edges = np.flatnonzero(np.diff(np.concatenate([[0], off.astype(int), [0]])))
    spans = [(t[a], t[b - 1]) for a, b in zip(edges[::2], edges[1::2])]
    for k, (t0, t1) in enumerate(spans):
        ax.axvspan(t0, t1, color="0.9", lw=0, zorder=0, label=label if k == 0 else None)
    if mask and off.any():
        for ln in ax.lines:
            y = np.array(ln.get_ydata(), float)
            if len(y) == len(t):
                y[off] = np.nan
                ln.set_ydata(y)
    return spans


def inset(ax, t_end=None, bounds=(0.07, 0.56, 0.3, 0.4), title="full scale", log_ratio=20.0):
    """An inset of the axes' traces (lines of more than two points) at their full scale, up to ``t_end`` (None:
    all): the transient the zoomed axes leave out, the main axes' y range shaded. Symlog y (linear within the
    main range) when the traces reach ``log_ratio`` x beyond it. Labelled "<inset>"."""
    ins = ax.inset_axes(bounds)
    ins.set_label("<inset>")
    hi = ax.get_ylim()[1]
    top = 0.0
    for ln in ax.lines:
        x, y = np.asarray(ln.get_xdata(), float), np.asarray(ln.get_ydata(), float)
        if len(x) <= 2:
            continue
        m = np.ones(len(x), bool) if t_end is None else x <= t_end
        ins.plot(x[m], y[m], color=ln.get_color(), ls=ln.get_linestyle(), lw=0.5)
        v = np.abs(y[m][np.isfinite(y[m])])
        top = max(top, float(v.max()) if v.size else 0.0)
    if hi > 0 and top > log_ratio * hi:
        ins.set_yscale("symlog", linthresh=hi)
    ins.axhspan(-hi, hi, color="gold", alpha=0.25, lw=0)
    ins.tick_params(labelsize=6, pad=1)
    ins.text(0.98, 0.95, title, transform=ins.transAxes, ha="right", va="top", fontsize=6)
    return ins


def pass_levels(ax, spans, values, label, color="k"):
    """A figure per span (each pointing pass's 3σ) as solid ± segments over it, labelled once."""
    for (t0, t1), v in zip(spans, values):
        if v is not None:
            ax.hlines([v, -v], t0, t1, colors=color, lw=1.6, label=label, zorder=5)
            label = None


def orbit_frame(r, v):
    """The rows (along-track, cross-track, radial) of each orbit state's frame, (n, 3, 3) from positions and
    velocities (n, 3): radial r/|r|, cross-track along r x v, along-track their cross product (the velocity's
    direction on a circular orbit)."""
    r, v = np.asarray(r, float), np.asarray(v, float)
    rad = r / np.linalg.norm(r, axis=1)[:, None]
    h = np.cross(r, v)
    cross = h / np.linalg.norm(h, axis=1)[:, None]
    return np.stack([np.cross(cross, rad), cross, rad], axis=1)


def in_frame(M, err, P):
    """Errors (n, 3) and their 1σ from covariances (n, 3, 3) resolved in the frames M (n, 3, 3): (M e, sqrt(diag(M
    P M^T)))."""
    e = np.einsum("nij,nj->ni", M, err)
    s = np.sqrt(np.einsum("nij,njk,nik->ni", M, P, M))
    return e, s


FRAME_AXES = ("along-track", "cross-track", "radial")
