"""``write_atomic`` (emulator/fileio.py, re-exported by ground/fileio.py): whole files only, and the
permissions a plain ``open`` would give; ``remove_stale``: a reused run folder holds no earlier run's figures."""

import os
import stat

import pytest

from ground.fileio import write_atomic, write_json


def test_new_files_get_the_umask_not_mkstemps_0600(tmp_path):
    old = os.umask(0o022)
    try:
        write_json(str(tmp_path / "run" / "summary.json"), {"complete": False})
        write_atomic(str(tmp_path / "run" / "report.md"), "# report\n")
    finally:
        os.umask(old)
    for name in ("summary.json", "report.md"):
        assert stat.S_IMODE(os.stat(tmp_path / "run" / name).st_mode) == 0o644
    assert sorted(os.listdir(tmp_path / "run")) == ["report.md", "summary.json"]     # no temp files left


def test_a_rewrite_keeps_the_files_own_mode(tmp_path):
    p = tmp_path / "summary.json"
    p.write_text("{}")
    os.chmod(p, 0o640)
    write_json(str(p), {"complete": True})
    assert stat.S_IMODE(os.stat(p).st_mode) == 0o640 and '"complete": true' in p.read_text()


def test_an_interrupted_write_leaves_the_old_file_whole(tmp_path, monkeypatch):
    p = tmp_path / "summary.json"
    write_json(str(p), {"complete": False})

    def fsync(fd):
        raise KeyboardInterrupt
    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(KeyboardInterrupt):
        write_json(str(p), {"complete": True})
    assert '"complete": false' in p.read_text() and os.listdir(tmp_path) == ["summary.json"]


def _stale(folder, names):
    os.makedirs(folder, exist_ok=True)
    for n in names + ["notes.txt"]:
        (folder / n).write_bytes(b"an earlier run's")


@pytest.mark.parametrize("argv, names", [
    (["adcs", "apkf", "--runs", "1", "--quiet", "--no-plots"], ["fig4-5_errors.png", "monte_carlo.png"]),
    (["adcs", "stkf", "--case", "1", "--duration", "20", "--truth", "two-body", "--quiet", "--no-plots"],
     ["fig5-4_states.png", "fig5-5_pointing.png", "fig5-6_states.png", "fig5-7_pointing.png"])])
def test_a_reused_run_folder_keeps_no_earlier_runs_figures(tmp_path, argv, names):
    """--no-plots in a folder an earlier run plotted into: the old figures go (they would sit beside a new
    summary as if they were its); the user's own files stay."""
    from ground.cli import main
    out = tmp_path / "run"
    _stale(out, names)
    assert main(argv + ["-o", str(out)]) == 0
    assert not [n for n in names if (out / n).exists()] and (out / "notes.txt").exists()


def test_a_new_calibration_removes_the_earlier_ones_figures_and_failure_details(tmp_path):
    from ground.cli import main
    _stale(tmp_path, ["cal_fig7-16.png", "cal_fig7-17.png", "cal.failed.json", "other_fig7-16.png"])
    assert main(["calibrate", "-o", str(tmp_path / "cal.json"), "--grid", "2", "--span", "1", "--no-plots",
                 "--no-truth"]) == 0
    assert sorted(os.listdir(tmp_path)) == ["cal.json", "notes.txt", "other_fig7-16.png"]
