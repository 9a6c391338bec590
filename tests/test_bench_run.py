"""``make bench``'s driver (bench/run.py): a name that is no benchmark is refused (exit 2, the names listed), not
a silent run of nothing that exits 0; a benchmark that raises is named as failed at the end and the exit is 1."""

import types

import pytest

from bench import run


def test_an_unknown_benchmark_name_is_refused(capsys):
    assert run.main(["protocl"]) == 2
    err = capsys.readouterr().err
    assert "protocl" in err and "protocol" in err and "adcs_can" in err


def test_a_failing_benchmark_is_named_at_the_end_and_exits_1(monkeypatch, capsys):
    def boom():
        print("| a | table |")
        raise RuntimeError("link down")

    def ok():
        print("| fine |")

    mods = {"bench.bench_protocol": types.SimpleNamespace(main=boom),
            "bench.bench_spacecraft": types.SimpleNamespace(main=ok)}
    monkeypatch.setattr(run.importlib, "import_module", lambda name: mods[name])
    assert run.main(["protocol", "spacecraft"]) == 1
    out = capsys.readouterr().out
    assert "link down" in out and "| fine |" in out
    assert out.rstrip().splitlines()[-1] == "benchmarks FAILED: protocol (1 of 2)"


def test_all_benchmarks_passing_exit_0(monkeypatch, capsys):
    monkeypatch.setattr(run.importlib, "import_module", lambda name: types.SimpleNamespace(main=lambda: None))
    assert run.main(["stkf"]) == 0
    assert "FAILED" not in capsys.readouterr().out


@pytest.mark.parametrize("exc", [SystemExit(3), SystemExit("bad")])
def test_a_benchmark_that_exits_is_a_failure_not_the_end_of_the_run(monkeypatch, capsys, exc):
    def bye():
        raise exc

    mods = {"bench.bench_protocol": types.SimpleNamespace(main=bye),
            "bench.bench_spacecraft": types.SimpleNamespace(main=lambda: print("| ran |"))}
    monkeypatch.setattr(run.importlib, "import_module", lambda name: mods[name])
    assert run.main(["protocol", "spacecraft"]) == 1
    out = capsys.readouterr().out
    assert "| ran |" in out and "benchmarks FAILED: protocol" in out
