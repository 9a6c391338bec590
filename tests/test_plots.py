"""Every plot the tools write, opened as a figure object (``ground.plots.save_png`` caught): each axes with data has
a y label with its unit, the figure an x label, and a legend wherever an axes draws more than one trace (in it, or one its panels share); the
requirement or budget is drawn and named where a plot has one; a start-up transient does not set the scale."""

import os
import sys

import numpy as np
import pytest

from ground import plots

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
    """The house rules on every axes of ``fig`` that draws data (colorbars and switched-off axes left out)."""
    data = [ax for ax in fig.axes if ax.axison and ax.get_label() != "<colorbar>" and
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


def test_the_adcs_can_plot(figs, tmp_path):
    n = 400
    h = {"t": np.arange(n) / 10, "dtheta_arcsec": np.column_stack([np.linspace(5000, 20, n), np.zeros(n)]),
         "status_adcs_mode": np.array([0] * 5 + [1] * 20 + [2] * 15)}
    plots.adcs_can_pointing(h, str(tmp_path / "pointing.png"), {"gnss_outage": [10, 20]})
    f = figs["pointing.png"]
    check(f)
    assert f.axes[0].get_title() and f.axes[1].get_ylabel().startswith("ADCS mode")


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
