"""``bench/apkf_first_set.py``: a row's figures from its runs, and one vehicle's run under each variant."""

import numpy as np

from bench import apkf_first_set


def _result(seed, level, n=30, end=10):
    nees = np.full(n, np.nan)
    nees[end:] = level
    z = np.full((n, 6), np.sqrt(level / 6.0))
    return {"seed": seed, "end": end, "nees": nees, "z": z, "params_nees_first_set": 20.0 + seed,
            "final_z_params": np.full(23, 0.5 if seed else 3.5)}


def test_a_row_counts_its_stopped_runs_and_takes_its_figures_from_the_others():
    res = [_result(0, 6.0), _result(1, 6.0), {"seed": 2, "error": "APKF diverged at t = 9 s"}]
    s = apkf_first_set.row_figures(res)
    assert s["vehicles"] == 3 and s["stopped"] == 1
    assert s["in_band"] == 1.0 and s["nees_mean"] == 6.0 and np.allclose(s["rms"], 1.0)
    assert s["params_nees"] == [20.0, 21.0] and s["params_3sigma"] == 0.5
    s = apkf_first_set.row_figures([_result(0, 12.0), _result(1, 12.0)])
    assert s["in_band"] == 0.0 and np.allclose(s["rms"], np.sqrt(2.0))


def test_the_variants_differ_only_in_the_first_sets_linearisation():
    runs = {v: apkf_first_set.run_first_set(0, name="generic-12u", variant=v) for v in apkf_first_set.VARIANTS}
    end = runs["once"]["end"]
    assert all("error" not in r for r in runs.values())
    assert np.array_equal(runs["once"]["nees"][:end], runs["filtered again"]["nees"][:end], equal_nan=True)
    assert not np.array_equal(runs["once"]["nees"][end:], runs["filtered again"]["nees"][end:])
    assert not np.array_equal(runs["once"]["nees"][:end], runs["at the truth"]["nees"][:end], equal_nan=True)
