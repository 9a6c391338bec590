"""tools/compare_runs.py: two run folders compared file by file, what a real-time run cannot repeat set apart."""

import json

import numpy as np

from tools import compare_runs


def _folder(root, name, resent, rtf, q2, vs, report_src):
    d = root / name
    (d / "hil").mkdir(parents=True)
    (d / "hil" / "summary.json").write_text(json.dumps({
        "real_time_factor": rtf, "finished_utc": "2026-12-05T16:0%dZ" % resent, "play_wall_s": rtf / 3,
        "link": {"bench": {"controller_resent": resent}}, "error_arcsec": {"q2_max": 0.7},
        "calibration": "/somewhere/%s/calibration.json" % name}))
    np.savez(d / "hil" / "samples.npz", q2=np.array(q2, dtype=np.float32), t=np.arange(3))
    (d / "hil" / "telemetry.csv").write_text("tick,vs,n_dup\n64,%d,%d\n128,1578,0\n" % (vs, resent))
    (d / "hil" / "report.md").write_text("# run\nsource %s\n- link: %d TICKs resent\n" % (report_src, resent))
    (d / "in.dist").write_bytes(b"FPSD\x01\x02")
    (d / "fig.png").write_bytes(name.encode())                   # figures are left out
    return str(d)


def test_the_same_results_with_other_timings_are_the_same(tmp_path, capsys):
    a = _folder(tmp_path, "a", 3, 16.1, [0.1, 0.2, 0.3], 1578, "bps33n 1")
    b = _folder(tmp_path, "b", 7, 14.2, [0.1, 0.2, 0.3], 1578, "bps33n 1")
    rows = compare_runs.compare(a, b)
    assert rows and all(r[4] for r in rows)                      # only what may vary differs
    assert {r[1] for r in rows} >= {"real_time_factor", "finished_utc", "play_wall_s", "link.bench.controller_resent",
                                     "n_dup", "line 3: - link: 3 TICKs resent"}
    assert compare_runs.main([a, b]) == 0
    assert "the same results" in capsys.readouterr().out


def test_a_changed_result_is_named_with_both_values(tmp_path, capsys):
    a = _folder(tmp_path, "a", 3, 16.1, [0.1, 0.2, 0.3], 1578, "bps33n 1")
    b = _folder(tmp_path, "b", 3, 16.1, [0.1, 0.2000001, 0.3], 1579, "bps33n 2")
    (tmp_path / "b" / "in.dist").write_bytes(b"FPSD\x01\x03")
    (tmp_path / "b" / "extra.json").write_text("{}")
    real = {(r[0], r[1]): r for r in compare_runs.compare(a, b) if not r[4]}
    assert set(real) == {("hil/samples.npz", "q2"), ("hil/telemetry.csv", "vs"), ("hil/report.md", "line 2: source bps33n 1"),
                         ("in.dist", "bytes"), ("extra.json", "file")}
    assert "1 elements differ" in real[("hil/samples.npz", "q2")][3]
    assert real[("hil/telemetry.csv", "vs")][2:4] == ("row 1: 1578", "1579 (1 rows differ)")
    assert "first difference at byte 5" in real[("in.dist", "bytes")][3]
    assert compare_runs.main([a, b]) == 1
    assert "5 results differ" in capsys.readouterr().out
    # a key the team knows to vary can be set apart
    assert compare_runs.main([a, b, "--vary", "^vs$", "--vary", "^q2$", "--vary", "source", "--vary", "bytes",
                              "--vary", "file"]) == 0


def test_a_missing_folder_exits_2(tmp_path, capsys):
    assert compare_runs.main([str(tmp_path), str(tmp_path / "nothing")]) == 2
    assert "is not a folder" in capsys.readouterr().err
