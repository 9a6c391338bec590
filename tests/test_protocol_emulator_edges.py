"""Edges of protocol/ and emulator/ found in review: files, bad input, the packet table as the one contract."""

import json
import os
import stat

import pytest

from emulator.config import write_json_atomic
from ground.cli import main as fps


# --- files people keep: written atomically with the umask's permissions -----------------------------------
def test_dbc_and_emulator_json_get_the_umask_not_mkstemps_0600(tmp_path):
    old = os.umask(0o022)
    try:
        assert fps(["protocol", "dbc", "-o", str(tmp_path / "fps.dbc")]) == 0
        write_json_atomic(str(tmp_path / "summary.json"), {"complete": True})
    finally:
        os.umask(old)
    for name in ("fps.dbc", "summary.json"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644, name
    assert json.loads((tmp_path / "summary.json").read_text()) == {"complete": True}
    assert sorted(os.listdir(tmp_path)) == ["fps.dbc", "summary.json"]      # no temp files left


def test_emulator_json_writer_fsyncs_before_the_rename(tmp_path, monkeypatch):
    p = tmp_path / "truth.json"
    write_json_atomic(str(p), {"old": 1})

    def fsync(fd):
        raise KeyboardInterrupt       # the machine stops between write and rename
    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(KeyboardInterrupt):
        write_json_atomic(str(p), {"new": 2})
    assert json.loads(p.read_text()) == {"old": 1} and os.listdir(tmp_path) == ["truth.json"]
