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


def test_a_bps_distfile_sidecar_says_its_own_duration_and_keeps_unhashed_notes_apart(tmp_path):
    """The sidecar's duration_s is the file's (simulated_s the run behind it, one step and the stencil more), and
    `fps distfile info` shows the notes its header's hash does not cover (params_file, from_cache) apart."""
    import json
    out = tmp_path / "b.dist"
    p = _fps("distfile", "generate", "--source", "bps", "--duration", "5", "--seed", "1", "--bps-truth", "two-body",
             "--bps-cache", str(tmp_path / "cache"), "-o", str(out))
    assert p.returncode == 0, p.stderr
    side = json.loads((tmp_path / "b.dist.json").read_text())
    assert side["duration_s"] == 5.0 and side["simulated_s"] == 6.0
    info = _fps("distfile", "info", str(out)).stdout
    inputs = [ln for ln in info.splitlines() if ln.startswith("inputs ")][0]
    notes = [ln for ln in info.splitlines() if ln.startswith("notes ")][0]
    assert "duration_s 5.0" in inputs and "from_cache" not in inputs and "params_file" not in inputs
    assert "from_cache false" in notes and "not covered by the header's hash" in notes


def test_distfile_generate_says_a_short_files_duration_and_no_seed_for_a_csv(tmp_path):
    p = _fps("distfile", "generate", "--source", "stat", "--duration", "0.05", "-o", str(tmp_path / "s.dist"))
    assert p.returncode == 0 and "(0.05734 s)" in p.stdout and "(0.0 s)" not in p.stdout
    csv = tmp_path / "d.csv"
    csv.write_text("t_s,x_arcsec,y_arcsec\n" + "".join("%g,%g,%g\n" % (k * 0.01, k % 3, -k % 5) for k in range(200)))
    p = _fps("distfile", "generate", "--source", "csv", "--csv", str(csv), "--duration", "1", "-o", str(tmp_path / "c.dist"))
    assert p.returncode == 0, p.stderr
    assert ", source csv" in p.stdout and "seed" not in p.stdout.split("wrote", 1)[1].split(";")[0]
