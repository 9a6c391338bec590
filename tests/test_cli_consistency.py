"""CLI cases of the "one consistent CLI" issue fixed so far: bad input exits 2 naming the option; the help lists every
sub-command."""

import subprocess
import sys

ROOT = __import__("os").path.dirname(__import__("os").path.dirname(__import__("os").path.abspath(__file__)))


def _fps(*args):
    return subprocess.run([sys.executable, "-m", "ground.cli"] + list(args), cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_fps_help_names_every_adcs_command():
    top = _fps("--help").stdout
    adcs = _fps("adcs", "--help").stdout
    for name in ("apkf", "mekf", "stkf", "bps", "sweep", "can"):
        assert name in top.split("adcs", 1)[1] and name in adcs
    assert "MEKF baseline" not in adcs and "FILTER" not in adcs


def test_a_missing_capture_is_bad_input_named_by_its_option(tmp_path):
    for opt in ("--serial", "--can"):
        p = _fps("protocol", "decode", opt, str(tmp_path / "none.bin"))
        assert p.returncode == 2 and ("%s %s: cannot read it" % (opt, tmp_path / "none.bin")) in p.stderr
        assert "Traceback" not in p.stderr and "[Errno" not in p.stderr


def test_custom_board_timing_without_its_numbers_is_refused(tmp_path):
    p = _fps("response", "--timing", "custom", "-o", str(tmp_path / "r"))
    assert p.returncode == 2 and "--timing custom" in p.stderr and "--config" in p.stderr
    assert not (tmp_path / "r").exists()


def test_a_bad_loop_rate_is_named_before_the_tones_it_would_limit(tmp_path):
    p = _fps("response", "--rate-hz", "0", "-o", str(tmp_path / "r"))
    assert p.returncode == 2 and "--rate-hz" in p.stderr and "--to" not in p.stderr


def test_an_stkf_run_too_short_for_the_apkf_to_start_is_bad_input(tmp_path):
    """--attitude apkf with a run shorter than the scenario's first two star-tracker outputs: exit 2 naming
    --duration and the shortest that works, no folder left (it ran and failed before, exit 1)."""
    p = _fps("adcs", "stkf", "--case", "1", "--attitude", "apkf", "--duration", "1", "--quiet", "-o", str(tmp_path / "s"))
    assert p.returncode == 2 and "--duration 1 s is too short for --attitude apkf" in p.stderr
    assert not (tmp_path / "s").exists()
    need = int(p.stderr.split("give --duration ")[1].split()[0])
    p = _fps("adcs", "stkf", "--case", "1", "--attitude", "apkf", "--duration", str(need), "--quiet", "--no-plots",
             "-o", str(tmp_path / "t"))
    assert p.returncode == 0, p.stderr


def test_a_negative_settling_time_is_named_by_its_option(tmp_path):
    """--ts -5:60:20 reached argparse as an option ("expected one argument"); it is now the value --ts refuses."""
    for cmd in (("adcs", "sweep", "--ts", "-5:60:20"), ("adcs", "bps", "--ts", "-5")):
        p = _fps(*cmd, "-o", str(tmp_path / "x"))
        assert p.returncode == 2 and "--ts (settling time t_s) must be in (0" in p.stderr, p.stderr
        assert "expected one argument" not in p.stderr
