"""Distfiles that keep their bandwidth: the step, no silent aliasing, what the player plays."""

import os
from array import array

import numpy as np
import pytest

from firmware.player import Player
from ground import distfile_cli, resample, sources
from ground.cli import main
from ground.fileio import write_atomic

CODES_PER_ARCSEC = distfile_cli.V_PER_ARCSEC * 65536 / 20.0


def _play(path, n):
    p = Player()
    p.open_file(os.path.abspath(path))
    p.oneshot()
    xb, yb = array("H", bytes(2 * n)), array("H", bytes(2 * n))
    assert p.fill(xb, yb, n) == n
    return (np.array(xb, float) - 0x8000) / CODES_PER_ARCSEC, (np.array(yb, float) - 0x8000) / CODES_PER_ARCSEC


def _amp(y, f, rate):
    t = np.arange(len(y)) / rate
    a = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(a, y, rcond=None)
    return float(np.hypot(c[0], c[1]))


@pytest.mark.parametrize("step_us,f", [(1000, 150.0), (95, 1500.0), (8192, 35.0), (8192, 55.0)])
def test_player_plays_the_step_at_the_kernels_gain(tmp_path, step_us, f):
    """The played amplitude is the file's x the Keys 6-point kernel's gain (firmware/player.py), not sinc^2."""
    path = str(tmp_path / "s.dist")
    src = sources.Sine((40.0, 40.0), (f, f), (0.0, 90.0))
    write_atomic(path, distfile_cli.generate(src, 2.0, 1, "sine", period_us=step_us))
    x, _ = _play(path, 10600)
    got = _amp(x[1000:], f, 10600.0)
    want = 40.0 * resample.player_gain(f, step_us)
    assert got == pytest.approx(want, rel=0.01)
    lin = 40.0 * resample.player_gain(f, step_us, "linear")
    assert abs(got - lin) > 0.02 * 40.0 or f == 150.0            # distinguishable from linear interpolation
    if step_us == 8192:       # the figures for linear interpolation, and the kernel's
        assert resample.player_gain(f, 8192, "linear") == pytest.approx({35.0: 0.76, 55.0: 0.49}[f], abs=0.01)
        assert resample.player_gain(f, 8192) == pytest.approx({35.0: 0.94, 55.0: 0.63}[f], abs=0.01)


def test_sine_above_the_files_nyquist_is_refused_naming_both(tmp_path, capsys):
    o = str(tmp_path / "s.dist")
    rc = main(["distfile", "generate", "--source", "sine", "--freq-hz", "110", "--duration", "1", "-o", o])
    err = capsys.readouterr().err
    assert rc == 2 and "110 Hz" in err and "61.0352 Hz" in err and "np.float64" not in err
    assert not os.path.exists(o)
    assert main(["distfile", "generate", "--source", "sine", "--freq-hz", "110", "--duration", "1",
                 "--step-us", "1000", "-o", o]) == 0


def test_fast_csv_is_low_pass_filtered_not_aliased(tmp_path, capsys):
    """110 Hz at 1 kHz into an 8.192 ms file used to come out as a full 12 Hz tone; now it is filtered out,
    and 20 Hz content passes (x|H|^2 of the stated filter)."""
    t = np.arange(0, 4.0, 1e-3)
    x = 10 * np.sin(2 * np.pi * 110 * t) + 5 * np.sin(2 * np.pi * 20 * t)
    csv = tmp_path / "in.csv"
    csv.write_text("t_s,x_arcsec,y_arcsec\n" + "\n".join("%.6f,%.6f,0" % r for r in zip(t, x)) + "\n")
    o = str(tmp_path / "c.dist")
    assert main(["distfile", "generate", "--source", "csv", "--csv", str(csv), "--duration", "3", "-o", o]) == 0
    d, xd, _ = distfile_cli.load(o)
    fs = 1e6 / d.period_us
    assert _amp(xd[30:-30], 1e6 / 8192 - 110, fs) < 0.05                   # no 12 Hz alias
    assert _amp(xd[30:-30], 20.0, fs) == pytest.approx(5 * resample.antialias_gain(20.0, 8192), rel=0.02)
    assert d.source == "csv+aa"
    capsys.readouterr()
    assert main(["distfile", "info", o]) == 0
    out = capsys.readouterr().out
    assert "nyquist    61.035 Hz" in out and "Butterworth order 8" in out and "Keys" in out
    # non-uniform and faster than the file: refused
    tn = np.sort(np.concatenate([t, t[:-1] + 3e-4]))
    csv.write_text("t_s,x_arcsec,y_arcsec\n" + "\n".join("%.6f,0,0" % v for v in tn) + "\n")
    assert main(["distfile", "generate", "--source", "csv", "--csv", str(csv), "--duration", "3", "-o", o]) == 2
    assert "Nyquist 61.04 Hz" in capsys.readouterr().err


def test_step_limits_and_csv_seed(tmp_path, capsys):
    o = str(tmp_path / "s.dist")
    assert main(["distfile", "generate", "--duration", "1", "--step-us", "94", "-o", o]) == 2
    assert "94.34 us" in capsys.readouterr().err
    assert main(["distfile", "generate", "--duration", "1", "--step-us", "95", "-o", o]) == 0
    csv = tmp_path / "in.csv"
    csv.write_text("0,1,1\n0.1,1,1\n0.2,1,1\n0.3,1,1\n0.4,1,1\n")
    assert main(["distfile", "generate", "--source", "csv", "--csv", str(csv), "--duration", "0.3", "--seed", "4",
                 "-o", o]) == 2
    assert "takes no seed" in capsys.readouterr().err


@pytest.mark.parametrize("step_us", [1000, 95])
def test_hil_plays_fine_steps(tmp_path, step_us):
    """The HIL (in-process) plays a 1 ms and a 95 us distfile (the first whole us above the P-FSM period)."""
    import json
    d = str(tmp_path / "s.dist")
    src = sources.Sine((3.0, 3.0), (40.0, 40.0), (0.0, 90.0))
    write_atomic(d, distfile_cli.generate(src, 1.5, 1, "sine", period_us=step_us))
    cal = str(tmp_path / "cal.json")
    from emulator.config import default_config
    from ground.response import truth_calibration
    c = truth_calibration(default_config())
    c["bench_config"] = default_config()
    with open(cal, "w") as f:
        json.dump(c, f)
    rc = main(["hil", "--distfile", d, "--calibration", cal, "--duration", "1", "--quiet", "--no-plots",
               "-o", str(tmp_path / "run")])
    s = json.load(open(tmp_path / "run" / "summary.json"))
    assert rc == 0 and s["complete"] and s["overruns"] == 0
    assert s["truth"]["max_radial_arcsec"] < 3.0        # a 3" tone at 40 Hz through the loop (|S| ~ 0.6)


def test_jitter_source_harmonics_in_the_file_and_as_played(tmp_path, capsys):
    """Wheel harmonics at rpm/60 Hz reach the file (sidecar written) and the player plays each at its kernel's
    gain, within 2 % of the file's below 200 Hz at a 1 ms step."""
    import json
    o = str(tmp_path / "j.dist")
    assert main(["distfile", "generate", "--source", "jitter", "--jitter-scale", "100", "--jitter-rpm",
                 "3000,4200,6000,9000", "--duration", "1.2", "--step-us", "1000", "-o", o]) == 0
    side = json.load(open(o + ".jitter.json"))
    assert side["wheel_hz"] == [50.0, 70.0, 100.0, 150.0]
    d, x, y = distfile_cli.load(o)
    assert d.source == "jitter+aa" and d.period_us == 1000
    amp = np.array(side["file_amp_arcsec"])
    assert np.all(amp[:, 0] > 0.5)                       # each wheel's harmonic is in the file
    from ground.jitter import harmonic_amplitudes
    xp, yp = _play(o, 10600)
    t = np.arange(10600) / 10600.0
    keep = (t > 0.05) & (t < 1.15)
    played = harmonic_amplitudes(t[keep], np.column_stack([xp[keep], yp[keep]]), side["wheel_hz"])
    gain = resample.player_gain(np.array(side["wheel_hz"]), 1000)
    assert np.allclose(played[:, 0] / amp[:, 0], gain, rtol=0.01)
    assert np.all(np.abs(played[:, 0] / amp[:, 0] - 1) < 0.02)
    # the file's step must hold the harmonics: a 9000 rpm wheel at an 8.192 ms step is refused
    assert main(["distfile", "generate", "--source", "jitter", "--jitter-rpm", "3000,4200,6000,9000",
                 "--duration", "0.2", "-o", str(tmp_path / "k.dist")]) == 2
    assert "Nyquist" in capsys.readouterr().err
    assert main(["distfile", "generate", "--source", "jitter", "--jitter-step-us", "700", "--duration", "0.2",
                 "--step-us", "1000", "-o", str(tmp_path / "k.dist")]) == 2
