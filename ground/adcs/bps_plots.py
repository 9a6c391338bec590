"""The body pointing simulator's time plots (``fps adcs bps``): Fig. 6-3/6-4 of a thesis-world run and
flight_pointing.png / flight_wheels.png of a flight-world run. Each draws the budgets the run's verdict reads
(``requirements``: the 3σ pointing and stability, the wheels' share of their speed limit), the run's own 3σ
beside them (each pass's in the flight world), every trace named, the axes zoomed past the start-up (slew,
settling) with an inset of it."""

import numpy as np

from ground import plots as gp
from ground.adcs.modes import MODE_CODE, MODES
from ground.plots import ARCSEC_SIGN, FRAME_AXES, band, in_frame, inset, legend, orbit_frame, pass_levels, \
    sigma_traces, subplots, zoom_after
from protocol.spacecraft import THESIS_REQUIREMENTS
from protocol.units import RAD_PER_ARCSEC

# (history key, symbol, unit, the requirement's key, the 3σ figure's key)
QUANTITIES = (("dtheta_arcsec", "δθ", "arcsec", "body_pointing_3sigma_arcsec", "pointing_3sigma_arcsec"),
              ("domega_arcsec_s", "δω", "arcsec/s", "body_stability_3sigma_arcsec_s", "stability_3sigma_arcsec_s"))


def _budget_axes(ax, t, y, t0, budget, unit, t_inset):
    """Zoom past t0 on the data with the budget kept in view, the budget drawn, the start-up inset."""
    lim = zoom_after(ax, t, t0, [y[:, 0], y[:, 1]], q=1.0, margin=1.15) or budget
    top = max(lim, 1.1 * budget)
    ax.set_ylim(-top, 1.5 * top)                                 # headroom above the budget: the legend's
    band(ax, budget, "3σ budget %g %s (the run's 3σ, both axes, must stay inside)" % (budget, unit))
    inset(ax, t_end=t_inset, bounds=(1.02, 0.08, 0.16, 0.84), title="start-up")


def pointing_panels(axs, hist, settle_s, req, figures=None):
    """δθ1, δθ2 and δω1, δω2 (``hist``: t, dtheta_arcsec, domega_arcsec_s) into the two axes ``axs``, zoomed on
    the seconds after ``settle_s`` with the start-up inset, the budgets of ``req`` and the run's 3σ (``figures``'
    pointing_3sigma_arcsec and stability_3sigma_arcsec_s, the ones the verdict compares; without them 3 sqrt(σ1²
    + σ2²) over those seconds) drawn, the collection's start marked."""
    t = hist["t"]
    sel = t >= settle_s
    for a, (key, sym, unit, rk, fk) in zip(axs, QUANTITIES):
        y = hist[key]
        for i in range(2):
            a.plot(t, y[:, i], lw=0.5, color="C%d" % i, label="%s%d" % (sym, i + 1))
        _budget_axes(a, t, y, settle_s, req[rk], unit, settle_s)
        v = (figures or {}).get(fk)
        if v is None and sel.sum() > 1:
            v = 3 * float(np.hypot(*np.std(y[sel], axis=0)))
        if v is not None:
            pass_levels(a, [(settle_s, t[-1])], [v], "the run's 3σ: %.1f %s" % (v, unit))
        a.axvline(settle_s, color="k", lw=0.6, ls=":", label="collection starts (%.0f s)" % settle_s)
        a.set_ylabel("%s1, %s2 (%s)" % (sym, sym, unit))
        legend(a, loc="upper right", ncol=3, fontsize=7, framealpha=0.85)


def plot_history(path, hist, settle_s, title, s=None):
    """Fig. 6-3/6-4 (``pointing_panels``); ``s``: the summary (its ``requirements``, default the thesis's, and
    its 3σ figures)."""
    fig, ax = subplots(2, 1, width=12, row_height=2.8, sharex=True)
    pointing_panels(ax[:, 0], hist, settle_s, (s or {}).get("requirements") or THESIS_REQUIREMENTS, s)
    ax[1, 0].set_xlabel("time (s)")
    fig.suptitle(title + "; holds where the black 3σ lines lie inside the red budget", fontsize=10)
    fig.tight_layout()
    gp.save_png(fig, path, dpi=90)


def _passes(s, T):
    ps = [p for p in s.get("passes") or [] if p.get("pointing_3sigma_arcsec") is not None]
    return [(p["t_from_s"] / T, p["t_to_s"] / T) for p in ps], ps


def _estimators(a_att, a_rb, hist, T, t_inset):
    """The APKF's attitude error and the STKF's rB error (SatB's orbit frame) against their ±3σ, 1 Hz."""
    n = len(hist["fsw_est_err"])
    t1 = np.arange(n) / T
    with np.errstate(invalid="ignore"):
        sig = np.sqrt(np.diagonal(hist["fsw_att_cov"].reshape(n, 3, 3), axis1=1, axis2=2)) / RAD_PER_ARCSEC
        sigma_traces(a_att, t1, hist["fsw_est_err"][:, 0:3], sig, ("x", "y", "z"))
        a_att.set_ylabel("APKF attitude error (arcsec)")
        x, P = hist["fsw_x_stkf"], hist["fsw_stkf_P"].reshape(-1, 12, 12)[:, 6:9, 6:9]
        e, s = in_frame(orbit_frame(x[:, 6:9], x[:, 9:12]), hist["fsw_stkf_x_err"][:, 6:9], P)
        sigma_traces(a_rb, t1[:len(e)], e, s, FRAME_AXES)
        a_rb.set_ylabel("STKF rB error (m)")
        for a_, y, sg in ((a_att, hist["fsw_est_err"][:, 0:3], sig), (a_rb, e, s)):
            zoom_after(a_, t1[:len(y)], 1.0, [3 * sg[:, i] for i in range(3)] + [y[:, i] for i in range(3)],
                       q=1.0, margin=1.1)
            inset(a_, t_end=t_inset, bounds=(1.02, 0.08, 0.16, 0.84), title="start-up")
            legend(a_, loc="upper right", ncol=4, fontsize=7, framealpha=0.85)


def plot_flight(paths, hist, s):
    """flight_pointing.png: δθ and δω (10 Hz) with each pass's 3σ (solid, over its seconds) and the budgets,
    the APKF's attitude error and the STKF's rB error (SatB's orbit frame) against their ±3σ, and the mode;
    flight_wheels.png: the wheel speeds and the check's share of their limit, the wheels' momentum and the
    magnetorquers' dipole. The time axis in orbits; the first orbit's start-up in an inset. ``paths``: the
    two files."""
    req = s.get("requirements") or THESIS_REQUIREMENTS
    t, T = hist["t"], s["orbit_period_s"]
    x = t / T
    modes = hist["fsw_mode"][:, 0]
    point = np.flatnonzero(modes == MODE_CODE["POINT"])
    t_inset = min(1.0, 4 * (point[0] if len(point) else T) / T)    # the slew and acquisition, four times over
    spans, ps = _passes(s, T)
    est = "fsw_att_cov" in hist and "fsw_stkf_P" in hist
    fig, ax = subplots(5 if est else 3, 1, width=13, row_height=2.4, sharex=True)
    for a, (key, sym, unit, rk, fk) in zip(ax[:2, 0], QUANTITIES):
        for i in range(2):
            a.plot(x, hist[key][:, i], lw=0.4, color="C%d" % i, label="%s%d" % (sym, i + 1))
        _budget_axes(a, x, hist[key], 1.0, req[rk], unit, t_inset)
        pass_levels(a, spans, [p[fk] for p in ps], "each pass's 3σ (both axes; POINT seconds)")
        a.set_ylabel("%s1, %s2 (%s)" % (sym, sym, unit))
    if est:
        _estimators(ax[2, 0], ax[3, 0], hist, T, t_inset)
    m = ax[-1, 0]
    m.step(np.arange(len(modes)) / T, modes, where="post", lw=0.8, label="the flight app's mode")
    m.set_yticks(range(len(MODES)), MODES)
    m.set_ylabel("mode (-)")
    m.set_xlabel("time (orbits of %.0f s)" % T)
    for a in ax[:, 0]:
        for k in range(1, int(x[-1]) + 1):
            a.axvline(k, color="k", lw=0.5, ls=":", label="a pass starts (each orbit after the first)" if k == 1
                      else None)
        legend(a, loc="upper left", ncol=4, fontsize=7, framealpha=0.85)
    fig.suptitle("Flight world: pointing per pass (POINT %d%% of the seconds); holds where each pass's black 3σ "
                 "lies inside the red budget and each estimator's error inside its dashed ±3σ"
                 % round(100 * np.mean(modes == MODE_CODE["POINT"])), fontsize=10)
    fig.tight_layout()
    gp.save_png(fig, paths[0], dpi=80)
    _wheels(paths[1], hist, s, req)


def _wheels(path, hist, s, req):
    T = s["orbit_period_s"]
    x = hist["t"] / T
    x1 = np.arange(len(hist["fsw_mode"])) / T
    fig, ax = subplots(3, 1, width=12, row_height=2.4, sharex=True)
    w = ax[0, 0]
    for i in range(hist["w_rel"].shape[1]):
        w.plot(x, hist["w_rel"][:, i] * 60 / (2 * np.pi), lw=0.6, label="wheel %d" % (i + 1))
    lim, share = s["wheel_speed_limit_rpm"], req["wheel_speed_share"]
    w.set_ylim(-1.1 * lim, 1.1 * lim)
    band(w, share * lim, "the check: %.0f %% of the %.0f rpm limit (after the first orbit)" % (100 * share, lim))
    for v in (-lim, lim):
        w.axhline(v, color="k", lw=0.6, label="the wheels' speed limit" if v > 0 else None)
    spans, ps = _passes(s, T)
    pass_levels(w, spans, [p.get("max_wheel_speed_rpm") for p in ps], "each pass's largest wheel speed")
    w.set_ylabel("wheel speed (rpm)")
    ax[1, 0].plot(x1, 1e3 * np.linalg.norm(hist["fsw_h_w"], axis=1), lw=0.6, label="|h| of the wheels")
    ax[1, 0].set_ylabel("wheels' momentum (mN m s)")
    for i in range(3):
        ax[2, 0].plot(x1, hist["fsw_m_cmd"][:, i], lw=0.6, label="rod %s (commanded)" % "xyz"[i])
    ax[2, 0].set_ylabel("magnetorquer dipole (A m²)")
    ax[2, 0].set_xlabel("time (orbits of %.0f s)" % T)
    for a in ax[:, 0]:
        legend(a, outside="right")
    fig.suptitle("Flight world: wheels (holds where every wheel stays inside the red dashes after the first "
                 "orbit) and momentum unloading", fontsize=10)
    fig.tight_layout()
    gp.save_png(fig, path, dpi=80)


def adcs_can_pointing(h, path, faults=None, s=None):
    """``fps adcs can``: the body pointing error δθ1, δθ2 and stability δω1, δω2 (Eq. 6.12-6.16) against the 3σ
    budgets and the run's 3σ after the settling, zoomed on it with the start-up inset (``pointing_panels``), and the
    ADCS mode per cycle; device faults shaded. ``s``: the summary (settle_s, requirements, pointing); without
    it the thesis's budgets, the whole run."""
    from protocol.table import ADCS_MODES
    s = s or {}
    t = np.asarray(h["t"], float)
    fig, ax = subplots(3 if "domega_arcsec_s" in h else 2, 1, width=11, sharex=True)
    hist = {"t": t, "dtheta_arcsec": h["dtheta_arcsec"],
            "domega_arcsec_s": h.get("domega_arcsec_s", np.zeros_like(h["dtheta_arcsec"]))}
    pointing_panels(ax[:-1, 0], hist, s.get("settle_s", t[0] if len(t) else 0.0),
                    s.get("requirements") or THESIS_REQUIREMENTS, s.get("pointing"))
    m = ax[-1, 0]
    for a in ax[:, 0]:
        for (w, label) in gp.fault_windows(faults):
            gp.shade(a, [w], label)
        legend(a, loc="upper right", ncol=3, fontsize=7, framealpha=0.85)
    m.step(np.arange(len(h["status_adcs_mode"])), h["status_adcs_mode"], where="post", label="ADCS mode")
    m.set_yticks([v for _, v in ADCS_MODES], [k for k, _ in ADCS_MODES])
    m.set_ylabel("ADCS mode (-)")
    m.set_xlabel("time (s)")
    legend(m, loc="upper right", fontsize=7)
    ax[0, 0].set_title("ADCS on CAN: body pointing error and stability, mode; holds where the black 3σ lines lie "
                       "inside the red budget", fontsize=10)
    fig.tight_layout()
    gp.save_png(fig, path)
