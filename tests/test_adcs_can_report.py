"""``fps adcs can`` reports as the other commands do: report.md with the verdict table against the budgets the
verdict reads, the run-folder line naming exactly the files written, the miss on stderr with exit 3."""

import json
import os

from ground.cli import main as fps
from protocol import spacecraft as sf


def _run(tmp_path, capsys, requirements=None):
    argv = ["adcs", "can", "--world", "flight", "--session", "400", "--runtime", "inproc", "--seed", "3",
            "--quiet", "--no-plots", "-o", str(tmp_path / "run")]
    if requirements is not None:
        d = json.load(open(sf.preset_path("thesis-3u")))
        d["requirements"] = requirements
        path = tmp_path / "sc.json"
        path.write_text(json.dumps(d))
        argv += ["--spacecraft", str(path)]
    rc = fps(argv)
    out, err = capsys.readouterr()
    return rc, out, err, json.load(open(tmp_path / "run" / "summary.json")), (tmp_path / "run" / "report.md")


def test_a_met_run_reports_its_table_and_every_file(tmp_path, capsys):
    rc, out, err, s, report = _run(tmp_path, capsys)
    assert rc == 0 and s["budgets_met"] is True
    p = s["pointing"]
    text = report.read_text()
    assert "| body pointing 3σ (arcsec) | %.1f | 150 | yes |" % p["pointing_3sigma_arcsec"] in text
    assert "| body stability 3σ (arcsec/s) | %.1f | 35 | yes |" % p["stability_3sigma_arcsec_s"] in text
    assert "| 1 | INIT | HOLD | the APKF started |" in text and "exactly once" in text
    line = [ln for ln in out.splitlines() if ln.startswith("run folder ")][0]
    named = line.split(": ", 1)[1].split(", ")
    assert sorted(named) == sorted(os.listdir(tmp_path / "run")) and named[:2] == ["summary.json", "report.md"]
    assert "requirements met (the thesis's budgets)" in out and "{" not in out     # no Python dict printed


def test_a_missed_budget_is_named_on_stderr_with_exit_3(tmp_path, capsys):
    tight = {"body_pointing_3sigma_arcsec": 1.0, "body_stability_3sigma_arcsec_s": 35.0, "fine_pointing_arcsec": 11.98,
             "wheel_speed_share": 0.8}
    rc, out, err, s, report = _run(tmp_path, capsys, tight)
    assert rc == 3 and s["budgets_met"] is False
    assert "BUDGET MISSED (the spacecraft file's budgets): body pointing 3σ (arcsec)" in err
    assert "| 1 | **NO** |" in report.read_text()


def test_the_report_of_a_run_stopped_before_its_first_cycle():
    """SIGTERM while the board boots: no cycle, no wall time, no status from the firmware; the report and the
    verdict still say so, without an error."""
    import argparse
    from ground.adcs import can_cli
    s = {"complete": False, "interrupted": True, "cycles": 0, "last_mode": None, "late_cycles": 0, "wall_s": 0.0,
         "speed_x_realtime": None, "firmware_missed": {"rw": [None] * 4, "startracker": None},
         "retries": {"cycles_retried": 0, "tick_resent": 0, "packets_resent": 0}, "mode_changes": [],
         "requirements": sf.requirements(None), "settle_s": 162.0, "budgets_met": None, "spacecraft": {}}
    a = argparse.Namespace(world="thesis", runtime="qemu", ts=33.0, seed=0, satb_gnss=False)
    text = can_cli.report_md(s, a)
    assert "0 cycles of 1 s, last mode None, 0 late cycles; 0.0 s wall (—× real time)" in text
    assert "missed by the firmware: none" in text
    assert can_cli.verdict_lines(s) == ["INTERRUPTED after 0 cycles: partial run, complete=false"]
