"""Every plot the tools write, opened as a figure object (``ground.plots.save_png`` caught): each axes with data has
a y label with its unit, the figure an x label, and a legend wherever an axes draws more than one trace (in it, or one its panels share); the
requirement or budget is drawn and named where a plot has one; a start-up transient does not set the scale."""

import os
import sys

import numpy as np
import pytest

from ground import plots
from ground.adcs import bps_plots

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
import firmware_plant as fp  # noqa: E402


@pytest.fixture
def figs(monkeypatch):
    """The figures the plot functions save, by file name (not written)."""
    got = {}
    monkeypatch.setattr(plots, "save_png", lambda fig, path, dpi=110: got.__setitem__(os.path.basename(path), fig))
    return got


def _unit(label):
    return ("(" in label and label.rstrip().endswith(")")) or ("[" in label and "]" in label)


def _legend_texts(fig, ax):
    texts = []
    for lg in ([ax.get_legend()] if ax.get_legend() else []) + list(fig.legends):
        texts += [t.get_text() for t in lg.get_texts()]
    return texts


def check(fig):
    """The house rules on every axes of ``fig`` that draws data (colorbars, insets and switched-off axes left
    out): units on every label, and every trace named (in a legend, or the colour of a named trace of its axes:
    an envelope's other half, a ring of a family, a key the panels share)."""
    data = [ax for ax in fig.axes if ax.axison and ax.get_label() not in ("<colorbar>", "<inset>") and
            (ax.lines or ax.collections or ax.images or ax.patches)]
    assert data, "no axes with data"
    assert any(ax.get_xlabel() for ax in data), "no x label"
    for ax in data:
        for lab in (ax.get_ylabel(), ax.get_xlabel()):
            if lab:
                assert _unit(lab), "label without a unit: %r" % lab
        assert ax.get_ylabel(), "an axes without a y label (title %r)" % ax.get_title()
        traces = [ln for ln in ax.lines if len(ln.get_xdata())] + list(ax.collections)
        if len(traces) > 1:                   # named in this axes' legend, or in one the panels share
            assert any(_legend_texts(fig, a) for a in fig.axes), \
                "%d traces and no legend (y label %r)" % (len(traces), ax.get_ylabel())
        named = {_rgb(ln.get_color()) for a in fig.axes for ln in a.lines if not ln.get_label().startswith("_")}
        for ln in ax.lines:
            if len(ln.get_xdata()) > 2 and ln.get_label().startswith("_") and len(traces) > 1:
                assert _rgb(ln.get_color()) in named, "an unnamed trace (y label %r)" % ax.get_ylabel()


def _rgb(c):
    from matplotlib.colors import to_rgb
    return tuple(round(x, 3) for x in to_rgb(c))


def insets(ax):
    return [c for c in ax.child_axes if c.get_label() == "<inset>"]


def level_at(ax, value, rel=1e-6):
    """True when a horizontal line or segment of ``ax`` stands at ``value``."""
    for ln in ax.lines:
        y = np.asarray(ln.get_ydata(), float)
        if len(y) and np.allclose(y, value, rtol=rel):
            return True
    for col in ax.collections:
        for seg in getattr(col, "get_segments", lambda: [])():
            if len(seg) and np.allclose(seg[:, 1], value, rtol=rel):
                return True
    return False


def legend_of(fig, ax):
    return " | ".join(_legend_texts(fig, ax))


def test_calibration_figures(figs, tmp_path):
    cal = fp.calibration(5)
    plots.calibration_quivers(cal, str(tmp_path / "calibration_fig7-16.png"))
    plots.calibration_difference(cal, str(tmp_path / "calibration_fig7-17.png"))
    for f in figs.values():
        check(f)
    q = figs["calibration_fig7-16.png"].axes[0]
    assert "not to scale" not in q.get_title()
    assert any("per V" in a.text.get_text() for a in q.artists if hasattr(a, "text"))   # the quivers' scale key


def test_the_hil_scatter_shows_the_requirement_and_a_zoom_on_the_data(figs, tmp_path):
    rng = np.random.default_rng(1)
    x, y = rng.normal(0, 0.03, 50000), rng.normal(0, 0.03, 50000)
    plots.hil_scatter({"Q2": (x, y), "truth": (x * 0.9, y * 0.9)}, str(tmp_path / "fig7-18_scatter.png"))
    f = figs["fig7-18_scatter.png"]
    check(f)
    full, zoom = f.axes[0], f.axes[1]
    assert full.get_xlim()[1] > 11.98 and any("requirement 11.98" in t for t in _legend_texts(f, full))
    assert zoom.get_xlim()[1] < 1.0                                # the data's own scale: not two dots


def test_the_hil_time_history_keeps_its_legend_off_the_traces(figs, tmp_path):
    t = np.linspace(0, 10, 2000)
    plots.hil_time_history({"Q2": (t, np.sin(t), np.cos(t)), "truth": (t, np.sin(t), np.cos(t))},
                           str(tmp_path / "fig7-19_time.png"))
    f = figs["fig7-19_time.png"]
    check(f)
    lg = f.axes[1].get_legend()
    assert lg is not None and lg.get_bbox_to_anchor().y0 < f.axes[1].get_position().y0 * f.bbox.height
    assert "requirement 11.98″ (beyond this zoomed axis)" in legend_of(f, f.axes[1])
    big = {"Q2": (t, 20 * np.sin(t), np.cos(t))}
    plots.hil_time_history(big, str(tmp_path / "fig7-19_time.png"), requirement_arcsec=12.5)
    assert level_at(figs["fig7-19_time.png"].axes[0], 12.5)       # drawn where the data reach it


def test_the_system_plot_zooms_on_the_fine_error_and_shades_the_faults(figs, tmp_path):
    t = np.linspace(162, 172, 3000)
    body = (t, 40 * np.sin(t), 30 * np.cos(t))
    fine = (t, 0.03 * np.sin(50 * t), 0.03 * np.cos(50 * t))
    plots.system_time_history(body, fine, str(tmp_path / "system_pointing.png"), 11.98, 150.0,
                              {"startracker_blind": [165, 168], "wheel_silent": [1, 170]})
    f = figs["system_pointing.png"]
    check(f)
    b, fa = f.axes
    assert fa.get_ylim()[1] < 1.0 and any("beyond this zoomed axis" in x for x in _legend_texts(f, fa))
    assert any("δθ1" in x for x in _legend_texts(f, b)) and any("startracker blind" in x for x in _legend_texts(f, b))
    assert "ADCS's start" in fa.get_xlabel() and fa.get_xlim()[0] >= 160
    assert level_at(b, 3 * np.hypot(np.std(body[1]), np.std(body[2])))        # the window's 3σ beside the budget


def test_the_adcs_can_plot(figs, tmp_path):
    n = 400
    h = {"t": np.arange(n) / 10, "dtheta_arcsec": np.column_stack([np.linspace(5000, 20, n), np.zeros(n)]),
         "status_adcs_mode": np.array([0] * 5 + [1] * 20 + [2] * 15)}
    bps_plots.adcs_can_pointing(h, str(tmp_path / "pointing.png"), {"gnss_outage": [10, 20]})
    f = figs["pointing.png"]
    check(f)
    assert f.axes[0].get_title() and f.axes[1].get_ylabel().startswith("ADCS mode")
    h["dtheta_arcsec"] = np.column_stack([5000 * np.exp(-h["t"]) + 20 * np.sin(h["t"]), np.zeros(n)])
    h["domega_arcsec_s"] = h["dtheta_arcsec"] / 10
    s = {"settle_s": 20.0, "requirements": {"body_pointing_3sigma_arcsec": 140.0, "body_stability_3sigma_arcsec_s":
                                            30.0}, "pointing": {"pointing_3sigma_arcsec": 60.0,
                                                                "stability_3sigma_arcsec_s": 6.0}}
    bps_plots.adcs_can_pointing(h, str(tmp_path / "pointing.png"), {"gnss_outage": [10, 20]}, s)
    f = figs["pointing.png"]
    check(f)
    p, st = [ax for ax in f.axes if ax.get_label() != "<inset>"][:2]
    assert level_at(p, 140.0) and level_at(p, 60.0) and level_at(st, 30.0) and level_at(st, 6.0)
    assert p.get_ylim()[1] < 1000 and insets(p)[0].get_ylim()[1] > 4000     # past the start-up, which it insets
    assert "gnss outage" in legend_of(f, p)


@pytest.mark.parametrize("name, width", [("apkf", 33), ("mekf", 6)])
def test_the_filter_error_plot_zooms_past_the_transient(figs, tmp_path, name, width):
    from ground.adcs import report
    t = np.arange(900.0)
    err = np.full((len(t), width), 1e-5) * np.sin(t)[:, None]
    err[:50] = 0.05                                               # a start-up transient, 1000x the steady state
    sig = np.full((len(t), width), 1e-5)
    sig[:50] = 0.1
    p = tmp_path / "series.npz"
    np.savez(p, t=t, error=err, sigma=sig)
    report.plot_run(str(p), name, str(tmp_path / "fig4-5_errors.png"))
    f = figs["fig4-5_errors.png"]
    check(f)
    att = f.axes[0]
    assert att.get_ylim()[1] < 100 * 2 / (np.pi / 180 / 3600) * 1e-5   # zoomed on the steady state, not the start
    assert f.get_size_inches()[1] >= 3.4                          # not a squat strip


def test_the_monte_carlo_plot_labels_its_runs_and_the_nees_start(figs, tmp_path):
    from ground.adcs import report
    rng = np.random.default_rng(2)
    results = [{"series": {"att_err": rng.normal(0, 10, (300, 3)).tolist(), "nees": (3 + rng.normal(0, 1, 300)).tolist()}}
               for _ in range(3)]
    report._plot_spread(results, {"filter": "apkf", "case": 1, "nees": {"band": [2.0, 4.5], "from_s": 210}},
                        str(tmp_path / "monte_carlo.png"))
    f = figs["monte_carlo.png"]
    check(f)
    assert any("each run" in x for x in _legend_texts(f, f.axes[0]))
    assert any("counted from 210" in x for x in _legend_texts(f, f.axes[3]))


@pytest.mark.parametrize("n_runs", [1, 3])
def test_the_stkf_plots(figs, tmp_path, n_runs):
    from ground.adcs import stkf_sim
    dirs = []
    for k in range(n_runs):
        d = tmp_path / ("run_%d" % k)
        d.mkdir()
        t = np.arange(200.0)
        np.savez(d / "history.npz", t=t, err=np.sin(t)[:, None] * np.ones(12), sig=np.ones((200, 12)),
                 perr=np.sin(t)[:, None] * np.ones(2), psig=np.ones((200, 2)))
        dirs.append(str(d))
    stkf_sim.plots(str(tmp_path), dirs, 2)
    for name in ("fig5-6_states.png", "fig5-7_pointing.png"):
        check(figs[name])
    f = figs["fig5-6_states.png"]
    names = [x for ax in f.axes for x in _legend_texts(f, ax)]
    assert any("the other 2 runs" in x for x in names) == (n_runs > 1)


def test_the_body_pointing_plots(figs, tmp_path):
    from ground.adcs import bps_cli
    t = np.arange(0, 300, 0.1)
    hist = {"t": t, "dtheta_arcsec": np.column_stack([np.sin(t), np.cos(t)]) * 30,
            "domega_arcsec_s": np.column_stack([np.sin(t), np.cos(t)]) * 5}
    bps_cli.plot_history(str(tmp_path / "fig6-3_pointing.png"), hist, 162.0, "Body pointing, cf. Fig. 6-3")
    bps_cli.plot_sweep(str(tmp_path / "fig6-2_sweep.png"), {"ts_s": [10, 20, 33, 50], "J": [3e-9, 2e-9, 1.8e-9, 2.5e-9],
                                                           "ts_best_s": 33})
    for f in figs.values():
        check(f)
    sweep = figs["fig6-2_sweep.png"].axes[0]
    labelled = [t.get_text() for t in sweep.get_yticklabels(minor=True) + sweep.get_yticklabels() if t.get_text()]
    assert len(labelled) >= 2                                     # J spans less than a decade: more than one tick


def test_the_bode_plots_name_the_loop_and_the_nyquist_line(figs, tmp_path):
    from emulator.config import default_config
    from ground import response
    m = response.LoopModel(default_config(), 637.8, 0.5, 0)
    f = np.geomspace(1, 300, 8)
    summary = {"timing": {"timing": "arduino-zero"}, "gain_margin_db": 10.0, "phase_margin_deg": 50.0,
               "bandwidth_hz": 40.0}
    response._plot(str(tmp_path), f, m.s_truth(f), m, summary)
    for name in response.FIGURES:
        check(figs[name])
    loop = figs["bode_loop.png"]
    texts = [t.get_text() for t in loop.texts] + ([loop._suptitle.get_text()] if loop._suptitle else [])
    assert not any("sys[" in x for x in texts)
    assert any("Nyquist frequency" in x for ax in loop.axes for x in _legend_texts(loop, ax))


def test_the_docs_show_every_figure_with_its_command():
    from ground import figures
    text = open(os.path.join(ROOT, "docs", "FIGURES.md")).read()
    for _, _, dest, cmd, thesis in figures.FIGURES:
        assert "(figures/%s)" % dest in text and os.path.exists(os.path.join(ROOT, "docs", "figures", dest)), dest
        if cmd is not None:
            assert "`fps %s`" % " ".join(cmd).replace("{d}/", "") in text
        if thesis:
            assert thesis in text
    for section in text.split("\n## ")[1:]:                     # each says how to read the requirement
        assert "holds" in section or "No requirement" in section, section.splitlines()[0]


def test_the_filter_error_plot_names_each_panels_components_and_insets_the_transient(figs, tmp_path):
    from ground.adcs import report
    t = np.arange(600.0)
    err, sig = np.full((600, 41), 1e-6) * np.sin(t)[:, None], np.full((600, 41), 1e-6)
    sig[:100], err[:100] = 1e-2, 5e-3                             # the transient, 10^4 x the steady state
    sig[400:410] = 1e-3                                           # a maneuver past the first third
    np.savez(tmp_path / "series.npz", t=t, error=err, sigma=sig)
    with open(tmp_path / "result.json", "w") as f:
        f.write('{"param_scale": 2.0}')
    report.plot_run(str(tmp_path / "series.npz"), "apkf", str(tmp_path / "fig4-5_errors.png"))
    f = figs["fig4-5_errors.png"]
    check(f)
    panels = [ax for ax in f.axes if ax.axison and ax.get_label() != "<inset>" and ax.lines]
    assert len(panels) == 10
    own = [[x.get_text() for x in ax.get_legend().get_texts()] for ax in panels]
    assert own[0] == ["x", "y", "z"] and own[3] == ["Jyy", "Jzz"] and own[9] == ["wheel 1", "wheel 2", "wheel 3",
                                                                                  "wheel 4"]
    assert "±3σ" in legend_of(f, panels[0])                       # the dashes' key, shared
    assert all(len(insets(ax)) == 1 for ax in panels)
    att = panels[0]
    assert att.get_ylim()[1] < 3 * 1e-6 * 2 / (np.pi / 180 / 3600) * 2.01       # twice the steady 3σ
    ins = insets(att)[0]
    assert ins.get_yscale() == "symlog" and ins.get_ylim()[1] > 1000          # the transient at full scale
    y = np.asarray(att.lines[0].get_ydata())
    assert np.isnan(y[405]) and np.isfinite(y[300])               # the maneuver left out of the zoom, shaded
    assert "physical" in f.texts[0].get_text() and "Jxx-rel" not in panels[2].get_ylabel()


def test_the_monte_carlo_plot_zooms_past_the_maneuvers(figs, tmp_path):
    from ground.adcs import report
    rng = np.random.default_rng(3)
    a = rng.normal(0, 10, (3, 600, 3))
    a[:, 50:80] *= 300                                            # a maneuver's excursion
    results = [{"series": {"att_err": a[k].tolist(), "nees": (3 + rng.normal(0, 0.3, 600)).tolist()}} for k in range(3)]
    report._plot_spread(results, {"filter": "apkf", "case": 1, "nees": {"band": [2.0, 4.5], "from_s": 210}},
                        str(tmp_path / "monte_carlo.png"))
    f = figs["monte_carlo.png"]
    check(f)
    x = f.axes[0]
    assert x.get_ylim()[1] < 200 and insets(x) and insets(x)[0].get_ylim()[1] > 3000
    assert any("left out" in t for t in _legend_texts(f, x))


def _circular_history(n=600):
    """An STKF history whose SatB covariance is long along the track (1 km against 10 m): in J2000 its y
    component's 1σ pinches as the track turns across y; in the orbit's frame it stays."""
    t = np.arange(float(n))
    th = 2 * np.pi * t / 2400.0
    r = 7e6 * np.column_stack([np.cos(th), np.sin(th), 0 * th])
    v = 7.5e3 * np.column_stack([-np.sin(th), np.cos(th), 0 * th])
    M = np.stack([v / 7.5e3, np.tile([0, 0, 1.0], (n, 1)), r / 7e6], axis=1)        # along, cross, radial
    Pr = np.einsum("nji,jk,nkl->nil", M, np.diag([1e6, 100.0, 100.0]), M)
    PB = np.zeros((n, 6, 6))
    PB[:, 0:3, 0:3] = PB[:, 3:6, 3:6] = Pr
    sig = np.ones((n, 12))
    sig[:, 6:9] = np.sqrt(np.diagonal(Pr, axis1=1, axis2=2))
    sig[:60] *= 50                                                # the start-up transient
    err = 0.5 * sig * np.sin(t)[:, None]
    return dict(t=t, err=err, sig=sig, perr=np.sin(t)[:, None] * np.ones(2), psig=np.ones((n, 2)),
                xB=np.column_stack([r, v]), PB=PB.reshape(n, 36))


def test_the_stkf_envelope_is_in_satb_s_orbit_frame(figs, tmp_path):
    from ground.adcs import stkf_sim
    d = tmp_path / "run_0"
    d.mkdir()
    h = _circular_history()
    assert h["sig"][300:, 7].min() < 0.2 * h["sig"][300:, 7].max()     # J2000's y pinches
    np.savez(d / "history.npz", **h)
    stkf_sim.plots(str(tmp_path), [str(d)], 1)
    f = figs["fig5-4_states.png"]
    check(f)
    panels = [ax for ax in f.axes if ax.get_label() != "<inset>"]
    along = panels[2]                                             # row 0, column rB
    assert "along-track" in along.get_ylabel() and "radial" in panels[3 * 4 - 2].get_ylabel()
    up = np.asarray(along.lines[1].get_ydata())[200:]             # the +3σ
    assert np.allclose(up, 3000.0, rtol=1e-6)                     # no pinch: 3 x 1 km all along
    for ax in panels:
        assert len(insets(ax)) == 1 and ax.get_ylim()[1] < 40 * np.abs(ax.lines[1].get_ydata()[-1])


def _flight(n=3000, T=1000.0):
    t = np.arange(n * 10) / 10.0
    rng = np.random.default_rng(4)
    th = 2 * np.pi * np.arange(n) / T
    r = 7e6 * np.column_stack([np.cos(th), np.sin(th), 0 * th])
    v = 7.5e3 * np.column_stack([-np.sin(th), np.cos(th), 0 * th])
    P = np.tile(np.eye(12) * 100.0, (n, 1, 1))
    dth = rng.normal(0, 20, (len(t), 2))
    dth[:500] = 5000.0                                            # the slew
    from ground.adcs.modes import MODE_CODE
    mode = np.full((n, 1), float(MODE_CODE["POINT"]))
    mode[:50] = MODE_CODE["SLEW"]
    hist = {"t": t, "dtheta_arcsec": dth, "domega_arcsec_s": rng.normal(0, 3, (len(t), 2)),
            "w_rel": np.full((len(t), 4), 100.0), "fsw_mode": mode, "fsw_h_w": np.zeros((n, 3)),
            "fsw_m_cmd": np.zeros((n, 3)), "fsw_est_err": rng.normal(0, 5, (n, 8)),
            "fsw_att_cov": np.tile((np.eye(3) * (5 * 4.848e-6) ** 2).ravel(), (n, 1)),
            "fsw_x_stkf": np.column_stack([r, v, r * 1.001, v]), "fsw_stkf_x_err": rng.normal(0, 10, (n, 12)),
            "fsw_stkf_P": P.reshape(n, 144)}
    s = {"orbit_period_s": T, "wheel_speed_limit_rpm": 6000.0,
         "requirements": {"body_pointing_3sigma_arcsec": 120.0, "body_stability_3sigma_arcsec_s": 30.0,
                          "wheel_speed_share": 0.7},
         "passes": [{"t_from_s": 1000.0, "t_to_s": 2000.0, "pointing_3sigma_arcsec": 61.0,
                     "stability_3sigma_arcsec_s": 9.0, "max_wheel_speed_rpm": 100.0},
                    {"t_from_s": 2000.0, "t_to_s": 2999.0, "pointing_3sigma_arcsec": 64.0,
                     "stability_3sigma_arcsec_s": 9.5, "max_wheel_speed_rpm": 100.0}]}
    return hist, s


def test_the_flight_plots_draw_the_budgets_and_each_pass(figs, tmp_path):
    from ground.adcs import bps_report
    hist, s = _flight()
    bps_report.plot_flight(str(tmp_path), hist, s)
    f, w = figs["flight_pointing.png"], figs["flight_wheels.png"]
    check(f)
    check(w)
    p, st, att, rb = [ax for ax in f.axes if ax.get_label() != "<inset>"][:4]
    assert level_at(p, 120.0) and level_at(st, 30.0)              # the file's budgets, not the thesis's
    assert level_at(p, 61.0) and level_at(p, 64.0) and level_at(st, 9.5)     # each pass's 3σ
    assert "δθ1" in legend_of(f, p) and "each pass's 3σ" in legend_of(f, p)
    assert p.get_ylim()[1] < 1000 and insets(p) and insets(p)[0].get_ylim()[1] > 4000    # past the slew
    assert "±3σ" in legend_of(f, att) and level_at(att, 15.0, rel=1e-3)     # 3 x 5 arcsec
    assert legend_of(f, rb).startswith("along-track | cross-track | radial")
    wh = w.axes[0]
    assert level_at(wh, 0.7 * 6000.0) and all("wheel %d" % k in legend_of(w, wh) for k in (1, 2, 3, 4))
    assert all("rod %s" % c in legend_of(w, w.axes[2]) for c in "xyz")


def test_the_thesis_world_plot_draws_the_budget_and_the_run_s_3sigma(figs, tmp_path):
    from ground.adcs import bps_report
    t = np.arange(0, 400, 0.1)
    d = np.column_stack([np.sin(t), np.cos(t)]) * 30
    d[t < 100] = 3000.0
    hist = {"t": t, "dtheta_arcsec": d, "domega_arcsec_s": d / 10}
    s = {"requirements": {"body_pointing_3sigma_arcsec": 140.0, "body_stability_3sigma_arcsec_s": 33.0},
         "pointing_3sigma_arcsec": 127.0, "stability_3sigma_arcsec_s": 12.7}
    bps_report.plot_history(str(tmp_path / "fig6-3_pointing.png"), hist, 162.0, "Body pointing, cf. Fig. 6-3", s)
    f = figs["fig6-3_pointing.png"]
    check(f)
    a, b = [ax for ax in f.axes if ax.get_label() != "<inset>"]
    assert level_at(a, 140.0) and level_at(a, 127.0) and level_at(b, 33.0) and level_at(b, 12.7)
    assert a.get_ylim()[1] < 400 and insets(a)[0].get_ylim()[1] > 2000


def test_the_population_cdf_draws_each_budget(figs, tmp_path, monkeypatch):
    from ground import plots as gp
    from ground.adcs import population
    monkeypatch.setattr(gp, "save_png", lambda fig, path, dpi=110: figs.__setitem__(os.path.basename(path), fig))
    res = [{"figures": {"pointing_3sigma_arcsec": 50.0 + k, "stability_3sigma_arcsec_s": 5.0, "max_wheel_speed_rpm":
                        1000.0, "mtq_duty": 0.5, "apkf_nees_in_band_share": 0.95, "stkf_nees_in_band_share": 0.9},
            "wheel_speed_limit_rpm": 6000.0} for k in range(5)]
    s = {"requirements": {"body_pointing_3sigma_arcsec": 52.5, "body_stability_3sigma_arcsec_s": 20.0,
                          "wheel_speed_share": 0.8}, "spacecraft": {"name": "x"}, "orbits": 2}
    population.plot_cdf(str(tmp_path / "cdf.png"), res, s)
    f = figs["cdf.png"]
    check(f)
    p = f.axes[0]
    assert any(np.allclose(ln.get_xdata(), 52.5) for ln in p.lines) and p.get_title() == "3 of 5 within the budget"
    assert any(np.allclose(ln.get_xdata(), 4800.0) for ln in f.axes[2].lines)
