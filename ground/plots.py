"""PNG plots like the thesis's Fig. 7-16/7-17 (calibration) and Fig. 7-18/7-19 (HIL run). Agg backend."""

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ground.fileio import write_atomic  # noqa: E402


def save_png(fig, path, dpi=110):
    """Write ``fig`` as a PNG atomically (no half-written file after an interruption) and close it."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    write_atomic(path, buf.getvalue())


def _centre_index(v0):
    return int(np.argmin(np.hypot(v0[:, 0], v0[:, 1])))


def calibration_quivers(cal, path):
    """Fig. 7-16: h_x (blue) and h_y (red), the columns of H, at each nulling point (V0x, V0y)."""
    pts = [p for p in cal["points"] if p.get("H") is not None]
    v0 = np.array([p["v0"] for p in pts])
    h = np.array([p["H"] for p in pts])
    fig, ax = plt.subplots(figsize=(7.6, 5.2))
    ax.quiver(v0[:, 0], v0[:, 1], h[:, 0, 0], h[:, 1, 0], color="b", label="h_x = (a, c)")
    ax.quiver(v0[:, 0], v0[:, 1], h[:, 0, 1], h[:, 1, 1], color="r", label="h_y = (b, d)")
    c = _centre_index(v0)
    ax.plot(v0[c, 0], v0[c, 1], "ko", mfc="none", ms=10, label="centre")
    ax.set_xlabel("V0x (V)")
    ax.set_ylabel("V0y (V)")
    ax.set_title("H calibration: h_x, h_y over (V0x, V0y) (not to scale), cf. Fig. 7-16")
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
        sc = ax.scatter(v0[:, 0], v0[:, 1], c=pct, cmap="viridis", s=40)
        ax.plot(v0[c, 0], v0[c, 1], "ko", mfc="none", ms=10)
        fig.colorbar(sc, ax=ax, label="%% difference of %s from the centre" % name)
        ax.set_xlabel("V0x (V)")
        ax.set_title("%s: %.2f … %.2f %%" % (name, np.delete(pct, c).min() if len(pct) > 1 else 0, pct.max()))
    axs[0].set_ylabel("V0y (V)")
    fig.suptitle("Δh pattern over (V0x, V0y), cf. Fig. 7-17")
    fig.tight_layout()
    save_png(fig, path)


def hil_scatter(series, path, requirement_arcsec=11.98):
    """Fig. 7-18: pointing errors in the X-Y plane with 1-4 arcsec circles. ``series``: {label: (x, y)}."""
    fig, ax = plt.subplots(figsize=(6, 6))
    colors = ("tab:blue", "tab:orange", "tab:green")
    lim = 5.0
    for (label, (x, y)), col in zip(series.items(), colors):
        step = max(1, len(x) // 40000)
        ax.plot(x[::step], y[::step], ".", ms=1.5, color=col, alpha=0.5, label=label)
        if len(x):
            lim = max(lim, float(np.ceil(np.hypot(x, y).max() + 0.5)))
    a = np.linspace(0, 2 * np.pi, 256)
    for r in (1, 2, 3, 4):
        ax.plot(r * np.cos(a), r * np.sin(a), "k-", lw=0.6)
        ax.annotate('%d"' % r, (r * 0.71, r * 0.71), fontsize=8)
    if lim > requirement_arcsec:
        ax.plot(requirement_arcsec * np.cos(a), requirement_arcsec * np.sin(a), "r--", lw=0.8,
                label="requirement %.2f\"" % requirement_arcsec)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("X error (arcsec)")
    ax.set_ylabel("Y error (arcsec)")
    ax.set_title("Pointing errors in the X-Y plane, cf. Fig. 7-18")
    ax.legend(loc="upper right", fontsize=8, markerscale=6)
    save_png(fig, path)


def hil_time_history(series, path):
    """Fig. 7-19: X and Y pointing errors against time. ``series``: {label: (t, x, y)}."""
    fig, axs = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for label, (t, x, y) in series.items():
        step = max(1, len(t) // 60000)
        axs[0].plot(t[::step], x[::step], lw=0.4, label=label)
        axs[1].plot(t[::step], y[::step], lw=0.4, label=label)
    axs[0].set_ylabel("X error (arcsec)")
    axs[1].set_ylabel("Y error (arcsec)")
    axs[1].set_xlabel("time (s)")
    axs[0].legend(loc="upper right", fontsize=8)
    axs[0].set_title("Pointing error time history, cf. Fig. 7-19")
    fig.tight_layout()
    save_png(fig, path)


def system_time_history(series, path, requirement_arcsec=11.98):
    """``fps system``: the body pointing error and the fine pointing error on one time axis (X, Y of each).
    ``series``: {label: (t, x, y)}, the first the body's, the second the fine loop's."""
    items = list(series.items())
    fig, axs = plt.subplots(len(items), 1, figsize=(9, 2.8 * len(items) + 0.6), sharex=True, squeeze=False)
    for ax, (label, (t, x, y)) in zip(axs[:, 0], items):
        step = max(1, len(t) // 60000)
        ax.plot(t[::step], x[::step], lw=0.4, label=label + " X")
        ax.plot(t[::step], y[::step], lw=0.4, label=label + " Y")
        ax.set_ylabel("error (arcsec)")
        ax.legend(loc="upper right", fontsize=8)
    if "fine" in items[-1][0]:
        for s in (-1, 1):
            axs[-1, 0].axhline(s * requirement_arcsec, color="r", lw=0.6, ls="--")
    axs[-1, 0].set_xlabel("time from the start of the collection window (s)")
    axs[0, 0].set_title("Body pointing error (ADCS) and fine pointing error (Q2), one time axis")
    fig.tight_layout()
    save_png(fig, path)


def adcs_can_pointing(h, path):
    """``fps adcs can``: the body pointing error (delta theta 1, 2, Eq. 6.12-6.16) and the ADCS mode per cycle."""
    from protocol.table import ADCS_MODES
    fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    ax[0].plot(h["t"], h["dtheta_arcsec"][:, 0], lw=0.6, label="δθ1")
    ax[0].plot(h["t"], h["dtheta_arcsec"][:, 1], lw=0.6, label="δθ2")
    ax[0].set_ylabel("pointing error (arcsec)")
    ax[0].set_yscale("symlog", linthresh=100)
    ax[0].legend(loc="upper right")
    ax[1].step(np.arange(len(h["status_adcs_mode"])), h["status_adcs_mode"], where="post")
    ax[1].set_yticks([v for _, v in ADCS_MODES], [k for k, _ in ADCS_MODES])
    ax[1].set_xlabel("t (s)")
    fig.tight_layout()
    save_png(fig, path)
