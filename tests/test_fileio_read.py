"""``read_json`` and ``parse_json`` (protocol/fileio.py, re-exported by emulator/fileio.py and ground/fileio.py):
an input file that cannot be read, is not JSON or nests too deeply is a ValueError naming what it is and the
path; a good file reads as ``json.loads`` reads it."""

import json

import pytest

from ground.fileio import parse_json, read_json


def test_a_good_file_reads_as_json_loads_reads_it(tmp_path):
    text = '{"a": [1, 2.5, -0.0, 1e-300, "x", null, true], "b": {"c": 12345678901234567890}}'
    p = tmp_path / "good.json"
    p.write_text(text)
    got = read_json(str(p), "config")
    assert got == json.loads(text) and repr(got) == repr(json.loads(text))
    pairs = read_json(str(p), "config", object_pairs_hook=list)
    assert pairs == json.loads(text, object_pairs_hook=list)


@pytest.mark.parametrize("text", ["[" * 100000 + "]" * 100000, '{"a": ' * 100000 + "1" + "}" * 100000,
                                  '{"k": ' + "[" * 50000 + "]" * 50000 + "}"])
def test_nesting_too_deep_is_bad_input_naming_the_file(tmp_path, text):
    p = tmp_path / "deep.json"
    p.write_text(text)
    with pytest.raises(ValueError) as e:
        read_json(str(p), "spacecraft file")
    assert str(e.value) == "spacecraft file %s: its arrays and objects nest too deeply to read" % p
    with pytest.raises(ValueError, match="^--faults: its arrays and objects nest too deeply"):
        parse_json(text, "--faults")


def test_text_that_is_not_json_names_where_it_came_from(tmp_path):
    with pytest.raises(ValueError, match=r"^--faults x\.json: not valid JSON \(Expecting"):
        parse_json("{beacon", "--faults x.json")
    p = tmp_path / "missing.json"
    with pytest.raises(ValueError, match="^calibration %s: cannot read it" % p):
        read_json(str(p), "calibration")


def test_an_integer_of_thousands_of_digits_names_the_file(tmp_path):
    p = tmp_path / "big.json"
    p.write_text('{"beacon_lost": 1%s}' % ("0" * 5000))
    with pytest.raises(ValueError) as e:
        read_json(str(p), "--faults")
    assert str(e.value).startswith("--faults %s: an integer of more than " % p), str(e.value)
    assert "beyond any number's range" in str(e.value) and "set_int_max_str_digits" not in str(e.value)


def test_a_hooks_refusal_begins_with_the_file(tmp_path):
    def no_b(pairs):
        if any(k == "b" for k, _ in pairs):
            raise ValueError('key "b" is not allowed')
        return dict(pairs)
    with pytest.raises(ValueError, match='^spacecraft file f.json: key "b" is not allowed$'):
        parse_json('{"a": {"b": 1}}', "spacecraft file f.json", object_pairs_hook=no_b)
