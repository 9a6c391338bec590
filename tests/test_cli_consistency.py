"""One CLI: the same option for the same thing across commands (SatB's GNSS, device faults), parsed the same way."""

import argparse
import json

import pytest

from ground.adcs.options import add_fault_options, add_satb_gnss_option, faults_from_args
from ground.cli import build_parser


def _actions(argv):
    """The parser's sub-command for ``argv`` (e.g. ["adcs", "bps"]) and its options by flag."""
    p = build_parser(only=argv[0])
    for name in argv:
        sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
        p = sub.choices[name]
    return {o: a for a in p._actions for o in a.option_strings}


@pytest.mark.parametrize("cmd", [["adcs", "bps"], ["adcs", "sweep"], ["adcs", "can"], ["system"],
                                 ["distfile", "generate"]])
def test_every_command_that_flies_the_body_loop_takes_both_satb_gnss_flags(cmd):
    acts = _actions(cmd)
    assert "--satb-gnss" in acts and "--no-satb-gnss" in acts
    assert acts["--satb-gnss"] is acts["--no-satb-gnss"]


@pytest.mark.parametrize("cmd", [["adcs", "can"], ["system"]])
def test_device_faults_are_options_on_both_commands_with_a_bulk_file(cmd):
    acts = _actions(cmd)
    for flag in ("--wheel-silent", "--startracker-blind", "--gnss-outage", "--beacon-lost", "--faults"):
        assert flag in acts, flag
    assert acts["--faults"].metavar == "FILE"


def _parse(argv):
    p = argparse.ArgumentParser()
    add_fault_options(p, "seconds")
    add_satb_gnss_option(p, True)
    return p.parse_args(argv)


def test_the_fault_file_and_the_options_merge_an_option_overriding_the_file(tmp_path):
    f = tmp_path / "faults.json"
    f.write_text(json.dumps({"startracker_blind": [170, 230], "beacon_lost": 300}))
    a = _parse(["--faults", str(f), "--beacon-lost", "250", "--wheel-silent", "2:100", "--no-satb-gnss"])
    assert faults_from_args(a) == {"startracker_blind": [170, 230], "beacon_lost": 250.0, "wheel_silent": [2, 100.0]}
    assert a.satb_gnss is False and _parse([]).satb_gnss is True and faults_from_args(_parse([])) is None
    assert faults_from_args(_parse(["--faults", '{"gnss_outage": [1, 2]}'])) == {"gnss_outage": [1, 2]}


@pytest.mark.parametrize("argv, needle", [
    (["--faults", "/no/such/faults.json"], "--faults /no/such/faults.json"),
    (["--faults", "{beacon"], "--faults must be a JSON object"),
    (["--faults", "[1, 2]"], "--faults /"),
    (["--wheel-silent", "two"], "--wheel-silent 'two': expected WHEEL:T0"),
    (["--gnss-outage", "50"], "--gnss-outage '50': expected T0:T1")])
def test_a_bad_fault_names_its_option(argv, needle, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError) as e:
        faults_from_args(_parse(argv))
    assert str(e.value).startswith(needle.rstrip("/")) or needle.rstrip("/") in str(e.value)
