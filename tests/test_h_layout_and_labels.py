"""Small things: one layout of H with its name, the thesis label only for the thesis preset."""

import json

from emulator.config import default_config
from ground.cli import main


def test_h_is_printed_by_columns_everywhere_and_eq_7_18_only_for_the_preset(tmp_path, capsys):
    assert main(["calibrate", "--grid", "3", "--no-plots", "-o", str(tmp_path / "c.json")]) == 0
    out = capsys.readouterr().out
    assert "H by columns" in out and "thesis Eq. 7.18" in out
    cfg = default_config()
    cfg["laser"]["power_w"] = 6e-4
    (tmp_path / "user.json").write_text(json.dumps(cfg))
    assert main(["calibrate", "--grid", "3", "--no-plots", "--config", str(tmp_path / "user.json"), "-o",
                 str(tmp_path / "u.json")]) == 0
    out = capsys.readouterr().out
    assert "H by columns" in out and "7.18" not in out
    assert "png" not in out                                  # --no-plots names no plot file
    assert main(["emulator", "truth-h", "--grid", "3", "-o", str(tmp_path / "t.json")]) == 0
    out = capsys.readouterr().out
    h = json.load(open(tmp_path / "t.json"))["points"][4]["H"]
    assert "H by columns" in out and "h_x = (%.4f, %.4f)" % (h[0][0], h[1][0]) in out
