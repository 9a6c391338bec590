"""``fps adcs ...`` and ``fps system`` on edge cases: Ctrl-C in a sweep, a reused run folder, a run that misses
its budget, sizes too large to hold in memory, negative seeds. Each runs in-process through ``ground.cli.main``
with short runs (two-body truth, a perfect parameter file)."""

import json
import os

import pytest

from emulator.spacecraft import scenario
from emulator.spacecraft.dynamics import Spacecraft
from ground import cli
from ground.adcs import body_pointing as bps, runs


@pytest.fixture(scope="module")
def params_file(tmp_path_factory):
    """The parameter file a perfect calibration would write (no nine calibration sets: fast)."""
    p = tmp_path_factory.mktemp("edges") / "params.json"
    bps.write_params(str(p), scenario.truth_params(scenario.pointing_world(10, 0).sc))
    return str(p)


def _fps(capsys, argv):
    capsys.readouterr()
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


def _summary(d):
    with open(os.path.join(d, "summary.json")) as f:
        return json.load(f)


def test_ctrl_c_stops_an_in_process_sweep_and_leaves_it_incomplete(params_file, tmp_path, monkeypatch, capsys):
    """bps.simulate turns Ctrl-C into a partial result; the sweep must stop there, not run the next t_s and
    call the whole sweep complete (exit 0)."""
    real, calls = Spacecraft.step, {"n": 0}

    def step(self):
        calls["n"] += 1
        if calls["n"] == 1500:          # t_s = 15: 1100 steps of 0.1 s; this is inside t_s = 25
            raise KeyboardInterrupt
        return real(self)
    monkeypatch.setattr(Spacecraft, "step", step)
    out = tmp_path / "sweep"
    rc, _, err = _fps(capsys, ["adcs", "sweep", "--ts", "15:35:10", "--duration", "20", "--workers", "1", "--params",
                               params_file, "--truth", "two-body", "--quiet", "--no-plots", "--cache-dir",
                               tmp_path / "c", "-o", out])
    s = _summary(out)
    assert rc == 130 and "interrupted" in err
    assert s["complete"] is False and s["J"][0] is not None and s["J"][1:] == [None, None]
    assert not (out / "run_0002").exists()                           # t_s = 35 never started
    with open(out / "run_0001" / "result.json") as f:
        assert json.load(f)["complete"] is False                     # what was done is kept, marked partial


def test_interrupted_campaign_counts_only_its_own_runs_in_a_reused_folder(tmp_path, monkeypatch, capsys):
    out = tmp_path / "apkf"
    pf = tmp_path / "short.json"
    pf.write_text('{"duration_s": 60}')
    base = ["adcs", "apkf", "--runs", "2", "--workers", "1", "--params", pf, "--quiet", "--no-plots", "-o", out]
    assert _fps(capsys, base + ["--case", "3"])[0] == 0
    assert _summary(out)["runs"] == 2                                # an earlier case-3 campaign in the folder

    def interrupted(**kw):
        raise KeyboardInterrupt
    monkeypatch.setattr(runs, "run_apkf", interrupted)
    rc, _, err = _fps(capsys, base + ["--case", "1"])
    s = _summary(out)
    assert rc == 130 and s["complete"] is False and s["case"] == 1
    assert s["runs"] == 0 and s["per_run"] == []                     # not the case-3 runs left in run_000N/


def test_a_reused_campaign_folder_keeps_no_earlier_campaigns_runs(tmp_path, capsys):
    """Three runs, then one in the same folder: run_0001/ and run_0002/ would sit beside a one-run summary as if
    they were its. The user's own files stay."""
    out = tmp_path / "apkf"
    pf = tmp_path / "short.json"
    pf.write_text('{"duration_s": 30}')
    base = ["adcs", "apkf", "--workers", "1", "--params", pf, "--quiet", "--no-plots", "-o", out]
    assert _fps(capsys, base + ["--runs", "3"])[0] == 0 and (out / "run_0002" / "result.json").exists()
    (out / "notes.txt").write_text("mine")
    (out / "run_notes").mkdir()
    assert _fps(capsys, base + ["--runs", "1", "--seed", "7"])[0] == 0
    assert sorted(os.listdir(out)) == ["config.json", "notes.txt", "report.md", "run_0000", "run_notes",
                                       "summary.json"]
    with open(out / "run_0000" / "result.json") as f:
        assert json.load(f)["seed"] == 7


def test_interrupted_while_clearing_an_earlier_campaign_the_folder_says_incomplete(tmp_path, monkeypatch):
    """Ctrl-C while the earlier campaign's runs are being removed: its summary (complete) is already replaced
    by this campaign's (complete false), so the folder never claims a campaign it no longer holds."""
    import shutil

    from ground.adcs import campaign
    out = tmp_path / "c"
    (out / "run_0000").mkdir(parents=True)
    (out / "summary.json").write_text('{"complete": true, "runs": 20}')

    def interrupted(path):
        raise KeyboardInterrupt
    monkeypatch.setattr(shutil, "rmtree", interrupted)
    with pytest.raises(KeyboardInterrupt):
        campaign.campaign_folder(str(out), (), {"complete": False, "runs": 0})
    assert _summary(out) == {"complete": False, "runs": 0}


@pytest.mark.parametrize("command", ["apkf", "mekf", "stkf", "sweep"])
def test_workers_and_scheduler_together_are_refused(tmp_path, capsys, command):
    """--workers W | --scheduler ADDR: one of them, not both (--workers was ignored)."""
    with pytest.raises(SystemExit) as e:
        cli.main(["adcs", command, "--workers", "2", "--scheduler", "tcp://127.0.0.1:9", "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "not allowed with argument --workers" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_stkf_interrupted_in_a_reused_folder_counts_only_its_own_runs(tmp_path, monkeypatch, capsys):
    from ground.adcs import stkf_sim
    out = tmp_path / "stkf"
    base = ["adcs", "stkf", "--case", "1", "--duration", "5", "--truth", "two-body", "--workers", "1", "--quiet",
            "--no-plots", "-o", out]
    assert _fps(capsys, base)[0] == 0 and _summary(out)["runs"] == 1

    def interrupted(**kw):
        raise KeyboardInterrupt
    monkeypatch.setattr(stkf_sim, "run_one", interrupted)
    rc, _, _ = _fps(capsys, base)
    s = _summary(out)
    assert rc == 130 and s["complete"] is False and s["runs"] == 0


def test_adcs_can_run_that_misses_its_budget_does_not_exit_0(tmp_path, capsys):
    """t_s = 5 s is far too stiff for the 1 Hz loop: the pointing diverges; the summary and the exit agree."""
    out = tmp_path / "can"
    rc, _, err = _fps(capsys, ["adcs", "can", "--runtime", "cpython", "--session", "80", "--ts", "5", "--quiet",
                               "--no-plots", "-o", out])
    s = _summary(out)
    assert s["complete"] and s["pointing"]["pointing_3sigma_arcsec"] > bps.BUDGET_POINTING_3SIGMA
    assert s["budgets_met"] is False and rc == 3 and "BUDGET MISSED" in err


@pytest.mark.parametrize("argv, flag", [
    (["adcs", "bps", "--ts", "1e9", "--duration", "5"], "--ts"),
    (["adcs", "sweep", "--ts", "1e9", "--duration", "5", "--workers", "1"], "--ts"),
    (["adcs", "sweep", "--ts", "10:100:1e-9", "--duration", "5", "--workers", "1"], "--ts"),
    (["distfile", "generate", "--source", "bps", "--ts", "1e9", "--duration", "5", "--bps-truth", "two-body"],
     "--ts"),
    (["system", "--adcs", "ground", "--runtime", "cpython", "--truth", "two-body", "--ts", "1e9"], "--ts"),
    (["system", "--adcs", "ground", "--runtime", "cpython", "--truth", "two-body", "--duration", "1e12"],
     "--duration"),
    (["adcs", "can", "--runtime", "cpython", "--ts", "1e9"], "--ts"),
    (["adcs", "can", "--runtime", "cpython", "--session", "1e12"], "--session"),
    (["adcs", "stkf", "--case", "1", "--truth", "two-body", "--duration", "1e9"], "--duration"),
    (["adcs", "stkf", "--case", "1", "--truth", "two-body", "--duration", "inf"], "--duration"),
    (["adcs", "stkf", "--case", "2", "--truth", "two-body", "--lag", "inf"], "--lag"),
    (["adcs", "apkf", "--seed", "-1", "--workers", "1"], "--seed"),
    (["adcs", "mekf", "--seed", "-1", "--workers", "1"], "--seed"),
    (["adcs", "stkf", "--case", "1", "--truth", "two-body", "--seed", "-1", "--workers", "1"], "--seed"),
    (["adcs", "can", "--runtime", "cpython", "--seed", "-1"], "--seed"),
])
def test_too_large_or_negative_inputs_are_refused_up_front(argv, flag, params_file, tmp_path, capsys):
    """Refused as bad input (exit 2) with the flag named, before any run: not a MemoryError, an OOM kill or
    a run that fails later with exit 1."""
    o = tmp_path / ("x.dist" if argv[0] == "distfile" else "x")
    extra = ["--params", params_file] if argv[:2] in (["adcs", "bps"], ["adcs", "sweep"]) or "--source" in argv \
        or argv[0] == "system" else []
    rc, _, err = _fps(capsys, argv + extra + ["-o", o])
    assert rc == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("fps ") and "error: " in last and flag in last, err
    assert not (tmp_path / "x" / "run_0000").exists()


@pytest.mark.parametrize("argv", [["adcs", "apkf", "--workers", "1"], ["adcs", "bps", "--truth", "two-body"],
                                  ["adcs", "can", "--runtime", "cpython", "--session", "2"]])
def test_a_binary_parameter_file_is_named_in_the_error(argv, tmp_path, capsys):
    p = tmp_path / "params.json"
    p.write_bytes(b"\xff\xfe\x00{")
    rc, _, err = _fps(capsys, argv + ["--params", p, "-o", tmp_path / "x"])
    assert rc == 2 and str(p) in err.strip().splitlines()[-1] and "not a text file" in err, err


def test_stkf_plots_are_written_atomically(tmp_path, monkeypatch, capsys):
    """A Ctrl-C while a figure is being written leaves no truncated PNG in the run folder."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    out = tmp_path / "stkf"

    def savefig(self, fname, **kw):
        (fname.write if hasattr(fname, "write") else open(fname, "wb").write)(b"\x89PNG\r\n")   # half a file
        raise KeyboardInterrupt
    monkeypatch.setattr(Figure, "savefig", savefig)
    rc, _, _ = _fps(capsys, ["adcs", "stkf", "--case", "1", "--duration", "5", "--truth", "two-body", "--workers",
                             "1", "--quiet", "-o", out])
    assert rc == 130
    assert not [f for f in os.listdir(out) if f.endswith(".png") or ".tmp" in f]
    assert _summary(out)["complete"] is False


def test_a_truth_step_that_does_not_divide_1_s_is_refused_up_front(tmp_path, capsys):
    """dt_truth_s = 0.3 is in the checked range (0, 1] but the scenario needs 1/dt steps per second: refused as
    bad input (exit 2, the key named), not run and failed seed by seed (exit 1)."""
    p = tmp_path / "p.json"
    p.write_text('{"dt_truth_s": 0.3, "duration_s": 20}')
    rc, _, err = _fps(capsys, ["adcs", "mekf", "--workers", "1", "--params", p, "--quiet", "--no-plots", "-o",
                               tmp_path / "x"])
    assert rc == 2 and "dt_truth_s = 0.3" in err.strip().splitlines()[-1], err
    assert not (tmp_path / "x").exists()
    p.write_text('{"dt_truth_s": 0.5, "duration_s": 20}')
    assert runs.load_params(str(p)) == {"dt_truth_s": 0.5, "duration_s": 20.0}


def test_bps_and_sweep_plots_leave_no_partial_file(params_file, tmp_path, monkeypatch, capsys):
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    def savefig(self, fname, **kw):
        (fname.write if hasattr(fname, "write") else open(fname, "wb").write)(b"\x89PNG\r\n")   # half a file
        raise KeyboardInterrupt
    monkeypatch.setattr(Figure, "savefig", savefig)
    for cmd, ts in (("bps", "20"), ("sweep", "20")):
        out = tmp_path / cmd
        rc, _, _ = _fps(capsys, ["adcs", cmd, "--ts", ts, "--duration", "5", "--params", params_file, "--truth",
                                 "two-body", "--quiet", "--cache-dir", tmp_path / "c", "-o", out]
                        + (["--workers", "1"] if cmd == "sweep" else []))
        assert rc == 130 and _summary(out)["complete"] is False
        assert not [f for f in os.listdir(out) if f.endswith(".png") or ".tmp" in f], os.listdir(out)


def _sigint_default():
    """In the child: SIGINT's default action back, as an interactive terminal gives its jobs (a shell running the
    tests in the background hands them SIGINT ignored, and a Python started so takes no Ctrl-C)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_terminal_ctrl_c_on_a_local_campaign_prints_no_worker_tracebacks(tmp_path):
    """A terminal's Ctrl-C goes to the whole process group, the local worker processes included: the campaign
    ends with its one-line message, complete=false, and no KeyboardInterrupt traceback from any worker."""
    import signal
    import subprocess
    import sys
    import time
    out = tmp_path / "apkf"
    p = subprocess.Popen([sys.executable, "-m", "ground.cli", "adcs", "apkf", "--runs", "40", "--workers", "2",
                          "--quiet", "--no-plots", "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, start_new_session=True, preexec_fn=_sigint_default)
    try:
        t0 = time.monotonic()
        while not (out / "run_0000" / "result.json").exists() and time.monotonic() - t0 < 120 and p.poll() is None:
            time.sleep(0.05)
        assert p.poll() is None, p.communicate()
        os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 130 and "Traceback" not in err and "KeyboardInterrupt" not in err, err
    s = _summary(out)
    assert s["complete"] is False and 1 <= s["runs"] < 40


@pytest.mark.parametrize("edit, words", [(lambda d: d["x"]["J5_kgm2"].__setitem__(0, -1.0), "positive definite"),
                                         (lambda d: d["P"][0].__setitem__(0, -1.0), "P: must be the symmetric "
                                          "positive definite 23 x 23 covariance of x; not positive definite"),
                                         (lambda d: d.pop("P"), "P: missing")])
def test_adcs_can_refuses_the_parameter_files_fps_adcs_bps_refuses(edit, words, params_file, tmp_path, capsys):
    """--params is 'fps adcs bps format': a non-positive-definite inertia or P, or no P, is refused before the
    flight software is started with it (ground and flight check it with the one protocol.paramfile)."""
    with open(params_file) as f:
        d = json.load(f)
    edit(d)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    rc, _, err = _fps(capsys, ["adcs", "can", "--runtime", "cpython", "--session", "2", "--quiet", "--no-plots",
                               "--params", p, "-o", tmp_path / "x"])
    last = err.strip().splitlines()[-1] if err.strip() else ""
    assert rc == 2 and str(p) in last and words in last, err
    assert not (tmp_path / "x").exists()
