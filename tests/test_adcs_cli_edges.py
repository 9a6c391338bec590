"""``fps adcs ...`` and ``fps system`` on edge cases: Ctrl-C in a sweep, a reused run folder, a run that misses
its budget, sizes too large to hold in memory, negative seeds. Each runs in-process through ``ground.cli.main``
with short runs (two-body truth, a perfect parameter file)."""

import json
import os

import pytest

from emulator.spacecraft import scenario
from emulator.spacecraft.dynamics import Spacecraft
from ground import cli
from ground.adcs import bps


@pytest.fixture(scope="module")
def params_file(tmp_path_factory):
    """The parameter file a perfect calibration would write (no nine calibration sets: fast)."""
    p = tmp_path_factory.mktemp("edges") / "params.json"
    bps.write_params(str(p), scenario.truth_params(scenario.pointing_world(10, 0).sc))
    return str(p)


def _fps(capsys, argv):
    capsys.readouterr()
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


def _summary(d):
    with open(os.path.join(d, "summary.json")) as f:
        return json.load(f)


def test_ctrl_c_stops_an_in_process_sweep_and_leaves_it_incomplete(params_file, tmp_path, monkeypatch, capsys):
    """bps.simulate turns Ctrl-C into a partial result; the sweep must stop there, not run the next t_s and
    call the whole sweep complete (exit 0)."""
    real, calls = Spacecraft.step, {"n": 0}

    def step(self):
        calls["n"] += 1
        if calls["n"] == 1500:          # t_s = 15: 1100 steps of 0.1 s; this is inside t_s = 25
            raise KeyboardInterrupt
        return real(self)
    monkeypatch.setattr(Spacecraft, "step", step)
    out = tmp_path / "sweep"
    rc, _, err = _fps(capsys, ["adcs", "sweep", "--ts", "15:35:10", "--duration", "20", "--workers", "1", "--params",
                               params_file, "--truth", "two-body", "--quiet", "--no-plots", "--cache-dir",
                               tmp_path / "c", "-o", out])
    s = _summary(out)
    assert rc == 130 and "interrupted" in err
    assert s["complete"] is False and s["J"][0] is not None and s["J"][1:] == [None, None]
    assert not (out / "run_0002").exists()                           # t_s = 35 never started
    with open(out / "run_0001" / "result.json") as f:
        assert json.load(f)["complete"] is False                     # what was done is kept, marked partial
