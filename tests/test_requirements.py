"""The budgets come from the spacecraft file's requirements block (the thesis's where it has none), and the
verdicts read them."""

import json

import pytest

from ground.system.reporting import verdict
from protocol import spacecraft as sf


def _file(req):
    raw = json.load(open(sf.preset_path("generic-6u")))
    if req is not None:
        raw["requirements"] = req
    return sf.check(raw)


TIGHT = {"body_pointing_3sigma_arcsec": 20.0, "body_stability_3sigma_arcsec_s": 2.0, "fine_pointing_arcsec": 0.5,
         "wheel_speed_share": 0.5}


def test_the_thesis_budgets_without_a_block_and_the_files_with_one():
    r = sf.requirements(_file(None))
    assert r["source"] == "thesis" and r["body_pointing_3sigma_arcsec"] == 150.0 and r["fine_pointing_arcsec"] == 11.98
    r = sf.requirements(_file(TIGHT))
    assert r == dict(TIGHT, source="file")


@pytest.mark.parametrize("key,value", [("body_pointing_3sigma_arcsec", 0), ("wheel_speed_share", 1.5),
                                       ("fine_pointing_arcsec", "12")])
def test_a_bad_requirement_names_its_key(key, value):
    with pytest.raises(ValueError, match="requirements.%s" % key):
        _file(dict(TIGHT, **{key: value}))


def test_the_terminals_verdict_reads_the_files_budgets():
    s = {"q2_samples": 100, "q2_beam_lost_samples": 0, "q2": {"max_radial_arcsec": 0.7},
         "body_pointing": {"pointing_3sigma_arcsec": 25.0, "stability_3sigma_arcsec_s": 2.5, "samples": 10},
         "complete": True}
    v = verdict(s)
    assert v["fine"]["met"] and v["body"]["met"]                    # the thesis's 11.98, 150 and 35
    v = verdict(dict(s, requirements=sf.requirements(_file(TIGHT))))
    assert v["fine"]["met"] is False and v["fine"]["budget_arcsec"] == 0.5
    assert v["body"]["met"] is False and v["body"]["pointing_budget_arcsec"] == 20.0


def test_the_flight_wheel_plot_draws_the_files_wheel_band(tmp_path, monkeypatch):
    import numpy as np
    from ground import plots
    from ground.adcs import bps_report
    figs = []
    monkeypatch.setattr(plots, "save_png", lambda fig, path, dpi=None: figs.append(fig))
    n = 20
    hist = {"t": np.arange(n, dtype=float), "dtheta_arcsec": np.zeros((n, 2)), "domega_arcsec_s": np.zeros((n, 2)),
            "fsw_mode": np.zeros((n, 1)), "w_rel": np.zeros((n, 4)), "fsw_h_w": np.zeros((n, 3)),
            "fsw_m_cmd": np.zeros((n, 3))}
    s = {"orbit_period_s": 10.0, "wheel_speed_limit_rpm": 6000.0, "requirements": sf.requirements(_file(TIGHT))}
    bps_report.plot_flight(str(tmp_path), hist, s)
    dashed = sorted(ln.get_ydata()[0] for ln in figs[1].axes[0].lines if ln.get_linestyle() == "--")
    assert dashed == [-3000.0, 3000.0]
    assert any("50 % of the 6000 rpm limit" in t.get_text() for t in figs[1].axes[0].get_legend().get_texts())
