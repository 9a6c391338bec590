"""One summary style for every run-folder command: report.md opens its findings with the verdict table, the last
lines name the run folder with every file it holds (no more, no fewer), and a verdict row marked missed goes with
exit 3 (1 when the row is the runs' own failure). Each command's shortest run, a few seconds in all."""

import os

import pytest

from ground import cli, verdict

HEAD = "| requirement | ours | budget | met |"


def _runs(tmp_path):
    dist, cal = str(tmp_path / "s.dist"), str(tmp_path / "cal.json")
    assert cli.main(["distfile", "generate", "--source", "sine", "--freq-hz", "10", "--duration", "2", "-o",
                     dist]) == 0
    assert cli.main(["calibrate", "--grid", "3", "--no-plots", "-o", cal]) == 0
    return {
        "hil": ["hil", "--distfile", dist, "--calibration", cal, "--duration", "1", "--quiet"],
        "response": ["response", "--points", "3", "--from", "2", "--to", "100", "--quiet"],
        "mekf": ["adcs", "mekf", "--case", "1", "--runs", "1", "--workers", "1", "--quiet"],
        "stkf": ["adcs", "stkf", "--case", "1", "--truth", "two-body", "--duration", "20", "--quiet"],
        "bps": ["adcs", "bps", "--ts", "20", "--duration", "30", "--seed", "2", "--truth", "two-body", "--quiet",
                "--cache-dir", str(tmp_path / "cache")],
        "can": ["adcs", "can", "--session", "40", "--runtime", "inproc", "--quiet"],
    }


def test_every_command_ends_in_one_summary_style(tmp_path, capsys):
    for name, argv in _runs(tmp_path).items():
        out = str(tmp_path / name)
        rc = cli.main(argv + ["-o", out])
        text = capsys.readouterr().out
        with open(os.path.join(out, "report.md")) as f:
            md = f.read()
        assert "## Verdict" in md and HEAD in md, name
        line = [ln for ln in text.splitlines() if ln.startswith("run folder ")]
        assert line == [verdict.folder_line(out)], name
        named = set(n.rstrip("/") for n in line[0].split(": ", 1)[1].split(", "))
        assert named == set(n for n in os.listdir(out) if not n.startswith(".")), name
        missed = "| **NO** |" in md
        assert rc == (3 if missed else 0) or (rc == 1 and "runs completed" in md), (name, rc)
        assert "| MISS |" not in md and "| MISS |" not in text, name          # thesis figures: a reference


def test_a_missed_row_makes_the_table_and_the_exit_say_so():
    rows = [("3σ pointing (arcsec)", 160.0, 150, False), ("3σ stability (arcsec/s)", None, 35, None)]
    md = "\n".join(verdict.table(rows, extra="thesis"))
    assert "| 3σ pointing (arcsec) | 160 | 150 | **NO** |" in md and "| — | 35 | — |" in md
    assert verdict.missed(rows) and not verdict.missed(rows[1:])
    assert verdict.runs_row(2, 3)[3] is False and verdict.runs_row(3, 3)[1:] == ("3 of 3", "all", True)


@pytest.mark.parametrize("gone", [True, False])
def test_the_folder_line_names_what_is_there(tmp_path, gone):
    d = tmp_path / "run"
    if not gone:
        d.mkdir()
        (d / "b.png").write_text("x")
        (d / "summary.json").write_text("{}")
        (d / "run_0000").mkdir()
    line = verdict.folder_line(str(d))
    assert line.endswith("(not written)" if gone else "summary.json, b.png, run_0000/")


def test_a_sweep_with_a_failed_t_s_says_so_in_its_verdict():
    from ground.adcs.bps_cli import sweep_lines, sweep_summary
    s = sweep_summary([20.0, 30.0], [{"J_rad2": 1e-7, "complete": True}, {"error": "diverged"}], True, False)
    md = "\n".join(sweep_lines(s, {"name": "thesis-3u"}, 20.0, False, True))
    assert "| t_s points computed (none failed) | 1 of 2 | all | **NO** |" in md and md.index("## Verdict") < \
        md.index("| t_s (s) |")
    s = sweep_summary([20.0], [{"J_rad2": 1e-7, "complete": True}], True, False)
    assert "| 1 of 1 | all | yes |" in "\n".join(sweep_lines(s, {"name": "thesis-3u"}, 20.0, False, True))
