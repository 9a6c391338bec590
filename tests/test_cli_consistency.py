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


BIG = "1" + "0" * 400           # an integer no float holds


@pytest.mark.parametrize("text, msg", [
    ('{"beacon_lost": "3"}', '"beacon_lost": "3" is not a number (seconds)'),
    ('{"beacon_lost": %s}' % BIG, '"beacon_lost": 100000...000 (401 digits) is out of range (expected t0 s >= 0'),
    ('{"beacon_lost": -1}', '"beacon_lost": -1 is out of range (expected t0 s >= 0, finite)'),
    ('{"beacon_lost": true}', '"beacon_lost": true is not a number (seconds)'),
    ('{"beacon_lost": null}', '"beacon_lost": null is not a number (seconds)'),
    ('{"wheel_silent": ["1", 30]}', '"wheel_silent": ["1", 30]: "1" is not a number (the wheel, 0-3)'),
    ('{"wheel_silent": [%s, 30]}' % BIG, '"wheel_silent": [100000...000 (401 digits), 30]: the wheel must be 0 to 3'),
    ('{"wheel_silent": [1, "30"]}', '"wheel_silent": [1, "30"]: "30" is not a number (seconds)'),
    ('{"startracker_blind": [170, %s]}' % BIG, '"startracker_blind": [170, 100000...000 (401 digits)]: 100000...000 '
                                               '(401 digits) is out of range (expected [t0 s, t1 s], 0 <= t0 < t1'),
    ('{"gnss_outage": "12"}', '"gnss_outage": "12": expected [t0 s, t1 s], 0 <= t0 < t1'),
    ('{"gnss_outage": [20, 10]}', '"gnss_outage": [20, 10]: expected [t0 s, t1 s], 0 <= t0 < t1'),
    ('{"meteor": 3}', 'unknown fault "meteor" (known: wheel_silent, startracker_blind, gnss_outage, beacon_lost, magnetometer_silent'),
    ("[1, 2]", 'must be a JSON object such as {"startracker_blind": [170, 230]}, got [1, 2]'),
    ("[" * 100000 + "]" * 100000, "its arrays and objects nest too deeply to read"),
    ('{"beacon_lost": 1%s}' % ("0" * 5000), "an integer of more than 4300 digits, beyond any number's range"),
    ("{beacon", "not valid JSON (Expecting property name")])
def test_a_bad_faults_file_names_the_option_the_file_the_key_and_the_value(tmp_path, text, msg):
    f = tmp_path / "faults.json"
    f.write_text(text)
    with pytest.raises(ValueError) as e:
        faults_from_args(_parse(["--faults", str(f)]))
    assert str(e.value).startswith("--faults %s: %s" % (f, msg)), str(e.value)
    if text.startswith("{"):                                  # the object itself, given inline
        with pytest.raises(ValueError) as e:
            faults_from_args(_parse(["--faults", text]))
        assert str(e.value).startswith("--faults") and msg in str(e.value), str(e.value)


def test_a_fault_given_as_an_option_is_named_by_its_option_and_checked_the_same():
    for argv, msg in ((["--beacon-lost", "-5"], '--beacon-lost -5: "beacon_lost": -5 is out of range'),
                      (["--beacon-lost", "1e400"], '--beacon-lost inf: "beacon_lost": inf is out of range'),
                      (["--wheel-silent", "4:10"], '--wheel-silent 4:10: "wheel_silent": [4, 10]: the wheel must be 0'),
                      (["--gnss-outage", "50:40"], '--gnss-outage 50:40: "gnss_outage": [50, 40]: expected [t0 s')):
        with pytest.raises(ValueError) as e:
            faults_from_args(_parse(argv))
        assert str(e.value).startswith(msg), str(e.value)


def test_a_fault_past_the_runs_end_names_where_it_was_given(tmp_path):
    from emulator.adcs_bus import check_faults
    f = tmp_path / "faults.json"
    f.write_text('{"startracker_blind": [170, 230], "beacon_lost": 700}')
    faults = faults_from_args(_parse(["--faults", str(f), "--gnss-outage", "900:950"]))
    assert faults == {"startracker_blind": [170, 230], "beacon_lost": 700, "gnss_outage": [900.0, 950.0]}
    assert check_faults(faults, 1000) == {"startracker_blind": [170.0, 230.0], "beacon_lost": 700.0,
                                          "gnss_outage": [900.0, 950.0]}
    with pytest.raises(ValueError) as e:
        check_faults(faults, 800)
    assert str(e.value) == ('--gnss-outage 900:950: "gnss_outage" starts at 900 s, not before the run\'s end (800 s): '
                            'it would never happen')
    with pytest.raises(ValueError) as e:
        check_faults(faults, 600)
    assert str(e.value).startswith('--faults %s: "beacon_lost" starts at 700 s' % f)
