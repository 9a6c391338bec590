"""``write_atomic`` (emulator/fileio.py, re-exported by ground/fileio.py): whole files only, and the
permissions a plain ``open`` would give."""

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
