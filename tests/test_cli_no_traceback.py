"""No ``fps`` command ends in a traceback, whatever it is given.

Every sub-command (and sub-sub-command) runs in-process through ``ground.cli.main`` over bad inputs: missing,
empty, garbage and binary files, directories, NaN/inf/1e40 numbers, negative durations, unknown names and
empty strings; ``fps protocol encode`` and ``decode`` also over hypothesis-generated argument lists and
captures. Bad input must end with exit status 1 or 2 and a one-line ``error`` message; good input with 0.
An exception escaping ``main`` fails the test with its traceback (what a user would have seen).
"""

import json
import os
import string
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ground import cli
from protocol import core, distfile

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "mp"))
try:
    import firmware_plant as fp
finally:
    sys.path.pop(0)

BAD_NUMBERS = ("nan", "inf", "-inf", "1e40", "-1e40", "1e400", "", "x", "-1")


def run(capsys, argv):
    """(exit status, stdout, stderr) of ``fps argv``; argparse's SystemExit gives its code."""
    capsys.readouterr()
    try:
        rc = cli.main([str(a) for a in argv])
    except SystemExit as e:
        rc = e.code if isinstance(e.code, int) else 1
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err, (argv, out, err)
    return rc, out, err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    f = {"dir": str(d), "missing": str(d / "missing" / "nothing.bin"), "out": str(d / "out")}
    os.makedirs(f["out"])
    rnd = bytes((i * 167 + 13) & 0xFF for i in range(300))
    for name, data in (("garbage", rnd), ("empty", b""), ("text", b"hello {"), ("binjson", b"\xff\xfe\x00x"),
                       ("nanjson", b'{"grid_v": [NaN, 1e400], "points": []}'),
                       ("csv_nan", b"t_s,x_arcsec,y_arcsec\n0,nan,1\n0.1,inf,2\n0.2,1,1\n0.3,1,1\n"),
                       ("csv_big", b"t_s,x_arcsec,y_arcsec\n0,1e40,1\n0.1,2,2\n0.2,3,3\n0.3,1,1\n"),
                       ("csv_bad", b"garbage\n,,,\n"),
                       ("csv_ok", b"t_s,x_arcsec,y_arcsec\n0,1,1\n0.1,2,2\n0.2,3,3\n0.3,1,1\n0.4,1,1\n"),
                       ("dist", distfile.pack([0.0, 1.0, 2.0], [0.0, 1.0, 2.0])),
                       ("cal", json.dumps(fp.calibration(3)).encode())):
        f[name] = str(d / name)
        with open(f[name], "wb") as fh:
            fh.write(data)
    sing = fp.calibration(3)
    sing["points"][4]["H"] = [[1.0, 2.0], [2.0, 4.0]]
    f["cal_singular"] = str(d / "cal_singular.json")
    with open(f["cal_singular"], "w") as fh:
        json.dump(sing, fh)
    return f


def _bad_protocol_and_emulator_cases(f, o):
    """Unknown commands, bad ``fps protocol`` and ``fps emulator`` arguments and input files."""
    m, g, t, d = f["missing"], f["garbage"], f["text"], f["dir"]
    return [["nope"], [""], ["protocol"], ["protocol", "nope"], ["protocol", "encode"],
            ["protocol", "encode", ""], ["protocol", "encode", "NOPE"], ["protocol", "encode", "999"],
            ["protocol", "encode", "-1"], ["protocol", "encode", "RW_CMD", "torque"],
            ["protocol", "encode", "RW_CMD", "=1"], ["protocol", "encode", "RW_CMD", "bogus=1"],
            ["protocol", "encode", "TICK", "--seq", "-1"], ["protocol", "encode", "TICK", "--seq", "256"],
            ["protocol", "encode", "TICK", "--src", "NOPE"], ["protocol", "encode", "TICK", "--dst", "999"],
            ["protocol", "encode", "TICK", "--src", ""], ["protocol", "encode", "DIST_CHUNK", "data=zz"],
            ["protocol", "encode", "DIST_CHUNK", "data=" + "00" * 49], ["protocol", "decode"],
            ["protocol", "decode", "--serial", m], ["protocol", "decode", "--serial", d],
            ["protocol", "decode", "--serial", ""], ["protocol", "decode", "--can", m],
            ["protocol", "dbc"], ["protocol", "dbc", "-o", m], ["protocol", "dbc", "-o", ""],
            ["protocol", "dbc", "-o", d],
            ["emulator", "config", "--config", m], ["emulator", "config", "--config", g],
            ["emulator", "config", "--config", t], ["emulator", "config", "--config", f["nanjson"]],
            ["emulator", "config", "--config", f["binjson"]], ["emulator", "config", "--config", ""],
            ["emulator", "truth-h"], ["emulator", "truth-h", "-o", o, "--grid", "0"],
            ["emulator", "truth-h", "-o", o, "--grid", "-3"], ["emulator", "truth-h", "-o", o, "--grid", "100000000"],
            ["emulator", "truth-h", "-o", o, "--grid", "x"], ["emulator", "truth-h", "-o", "", "--grid", "2"],
            ["emulator", "truth-h", "-o", m, "--grid", "2"], ["emulator", "truth-h", "-o", o, "--config", g],
            ["emulator", "serve", "--devices", "nope"], ["emulator", "serve", "--link", ""],
            ["emulator", "serve", "--distfile", m, "--wait", "0"],
            ["emulator", "serve", "--distfile", g, "--wait", "0"],
            ["emulator", "serve", "--config", g, "--wait", "0"], ["emulator", "serve", "--wait", "0.05"],
            ["emulator", "serve", "--devices", "wheels", "--config", f["cal"], "--duration", "0.1", "--wait", "0"],
            ["emulator", "serve", "--devices", "wheels", "--wait", "0"]]


def _bad_numbers_for_emulator_distfile_calibrate_hil(f, o):
    """Each of ``BAD_NUMBERS`` as a number option of ``fps emulator``, ``distfile generate``, ``calibrate``, ``hil``."""
    cases = []
    for v in BAD_NUMBERS:
        cases += [["emulator", "truth-h", "-o", o, "--dv", v],
                  ["emulator", "serve", "--duration", v, "--wait", "0"],
                  ["emulator", "serve", "--wait", v], ["emulator", "serve", "--rate", v, "--wait", "0"],
                  ["emulator", "serve", "--deadline", v, "--wait", "0"],
                  ["emulator", "serve", "--pfsm-v", v, "0", "--wait", "0"],
                  ["emulator", "serve", "--devices", "wheels", "--dt", v, "--duration", "0.1", "--wait", "0"],
                  ["emulator", "serve", "--devices", "wheels", "--startracker-hz", v, "--duration", "0.1",
                   "--wait", "0"],
                  ["emulator", "serve", "--devices", "wheels", "--duration", v, "--wait", "0"],
                  ["distfile", "generate", "-o", o, "--duration", v],
                  ["distfile", "generate", "-o", o, "--source", "sine", "--duration", "1", "--amp-arcsec", v],
                  ["distfile", "generate", "-o", o, "--source", "sine", "--duration", "1", "--freq-hz", v + ",1"],
                  ["distfile", "generate", "-o", o, "--source", "sine", "--duration", "1", "--sine-rate-hz", v],
                  ["distfile", "generate", "-o", o, "--source", "stat", "--duration", "1", "--stat-rate-hz", v],
                  ["distfile", "generate", "-o", o, "--source", "stat", "--duration", "1", "--stat-scale", v],
                  ["calibrate", "-o", o, "--grid", "2", "--span", v], ["calibrate", "-o", o, "--grid", "2", "--dv", v],
                  ["calibrate", "-o", o, "--grid", v],
                  ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--duration", v],
                  ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--duration", "0.01",
                   "--q2-dv", v if v != "-1" else "-inf"]]
    return cases


def _bad_files_for_spacecraft_distfile_calibrate_hil(f, o):
    """Missing, garbage, empty and wrong input files, and bad options, of ``fps spacecraft``, ``distfile``,
    ``calibrate`` and ``hil``."""
    m, g, e, d = f["missing"], f["garbage"], f["empty"], f["dir"]
    cases = [["distfile", "info"], ["distfile", "nope"]]
    cases += [["spacecraft"], ["spacecraft", "nope"], ["spacecraft", "show", ""],
              ["spacecraft", "template", "nope", "-o", o], ["spacecraft", "template", "thesis-3u", "-o", d],
              ["spacecraft", "template", "thesis-3u", "-o", ""]]
    for p in (m, g, e, d, "", f["text"], f["cal"], f["nanjson"], f["binjson"]):
        cases += [["spacecraft", "check", p], ["spacecraft", "show", p]]
    for p in (m, g, e, d, "", f["text"], f["cal"]):
        cases += [["distfile", "info", p], ["distfile", "csv", p],
                  ["distfile", "generate", "-o", o, "--source", "csv", "--csv", p],
                  ["hil", "-o", o, "--distfile", p, "--calibration", f["cal"], "--duration", "0.01"],
                  ["hil", "-o", o, "--distfile", f["dist"], "--calibration", p if p != f["cal"] else f["dist"],
                   "--duration", "0.01"],
                  ["calibrate", "-o", o, "--grid", "2", "--config", p]]
    for p in (f["csv_nan"], f["csv_big"], f["csv_bad"], f["binjson"]):
        cases += [["distfile", "generate", "-o", o, "--source", "csv", "--csv", p]]
    cases += [["distfile", "generate", "-o", o, "--source", "csv"],
              ["distfile", "generate", "-o", o, "--source", "nope"],
              ["distfile", "generate", "-o", o, "--duration", "1", "--seed", "-1"],
              ["distfile", "generate", "-o", o, "--duration", "1", "--seed", str(2 ** 40)],
              ["distfile", "generate", "-o", o, "--duration", "1", "--stat-case", "nope"],
              ["distfile", "generate", "-o", "", "--source", "sine", "--duration", "1"],
              ["distfile", "generate", "-o", d, "--source", "sine", "--duration", "1"],
              ["distfile", "generate", "-o", o, "--source", "sine", "--duration", "1", "--offset-arcsec", ""],
              ["distfile", "generate", "-o", o, "--source", "sine", "--duration", "1", "--freq-hz", "600"],
              ["distfile", "csv", f["dist"], "-o", d], ["calibrate"], ["calibrate", "-o", o, "--grid", "100000"],
              ["calibrate", "-o", o, "--grid", "2", "--seed", "-5"],
              ["calibrate", "-o", o, "--grid", "2", "--port", ""],
              ["calibrate", "-o", o, "--grid", "2", "--port", m], ["calibrate", "-o", o, "--runtime", "nope"],
              ["calibrate", "-o", o, "--grid", "2", "--link", ""], ["hil"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["nanjson"], "--duration", "0.01"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["binjson"], "--duration", "0.01"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal_singular"], "--duration", "0.01"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--duration", "0.01",
               "--config", g],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--duration", "10"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--runtime", "nope"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--runtime", "micropython",
               "--link-faults", "bytes=2"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--link-faults", "frames=0.1"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--runtime", "board"],
              ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--tick-tries", "0",
               "--runtime", "cpython"]]
    return cases


def _bad_response_and_distfile_step_cases(f, o):
    """Bad numbers and options of ``fps response`` and of ``distfile generate``'s step, jitter and tones."""
    g = f["garbage"]
    cases = []
    for v in BAD_NUMBERS:
        cases += [["response", "-o", o, "--points", "2", "--from", v], ["response", "-o", o, "--points", "2",
                                                                        "--to", v],
                  ["response", "-o", o, "--points", "2", "--amp", v],
                  ["distfile", "generate", "-o", o, "--duration", "1", "--step-us", v],
                  ["distfile", "generate", "-o", o, "--source", "jitter", "--duration", "0.1", "--step-us", "1000",
                   "--jitter-scale", v],
                  ["distfile", "generate", "-o", o, "--source", "jitter", "--duration", "0.1", "--step-us", "1000",
                   "--jitter-step-us", v],
                  ["distfile", "generate", "-o", o, "--source", "jitter", "--duration", "0.1", "--step-us", "1000",
                   "--jitter-rpm", v]]
    cases += [["response"], ["response", "-o", o, "--points", "1"], ["response", "-o", o, "--config", g],
              ["response", "-o", o, "--points", "2", "--rate-hz", "2000"],
              ["response", "-o", o, "--points", "2", "--timing", "nope"],
              ["distfile", "generate", "-o", o, "--duration", "1", "--step-us", "94"],
              ["distfile", "generate", "-o", o, "--source", "jitter", "--duration", "0.1", "--step-us", "1000",
               "--jitter-base", "jitter"],
              ["distfile", "generate", "-o", o, "--source", "jitter", "--duration", "0.1", "--step-us", "1000",
               "--jitter-base", "nope"],
              ["distfile", "generate", "-o", o, "--duration", "1", "--step-us", "100.5"],
              ["distfile", "generate", "-o", o, "--source", "sine", "--duration", "1", "--freq-hz", "110"],
              ["distfile", "generate", "-o", o, "--source", "csv", "--csv", f["csv_ok"], "--seed", "3"]]
    return cases


def _bad_adcs_and_system_cases(f, o):
    """Bad options and input files of ``fps adcs`` and ``fps system``, and of the bps distfile source."""
    cases = []
    for sub in ("apkf", "mekf", "stkf"):
        cases += [["adcs", sub, "-o", o, "--runs", "0"], ["adcs", sub, "-o", o, "--runs", "x"],
                  ["adcs", sub, "-o", o, "--workers", "0"], ["adcs", sub, "-o", o, "--seed", "-1e40"],
                  ["adcs", sub, "-o", o, "--params", f["missing"]], ["adcs", sub, "-o", o, "--params", f["garbage"]],
                  ["adcs", sub, "-o", o, "--scheduler", "tcp://127.0.0.1:9", "--runs", "1"]]
    for sub, ts in (("bps", "0"), ("sweep", "10:5:5")):
        cases += [["adcs", sub, "-o", o, "--ts", ts], ["adcs", sub, "-o", o, "--ts", "nan"],
                  ["adcs", sub, "-o", o, "--ts", "-1"], ["adcs", sub, "-o", o, "--duration", "0"],
                  ["adcs", sub, "-o", o, "--duration", "1e40"], ["adcs", sub, "-o", o, "--seed", "-1"],
                  ["adcs", sub, "-o", o, "--params", f["missing"]], ["adcs", sub, "-o", o, "--params", f["garbage"]],
                  ["adcs", sub, "-o", o, "--params", f["nanjson"]]]
    for v in ("nan", "inf", "-inf", "", "x", "-1", "0"):
        cases += [["system", "--adcs", "ground", "-o", o, "--duration", v], ["system", "--adcs", "ground", "-o", o,
                                                                           "--ts", v],
                  ["system", "--adcs", "ground", "-o", o, "--seed", v if v != "0" else "-5"]]
    cases += [["system", "--adcs", "ground", "-o", o, "--calibration", f["missing"]],
              ["system", "--adcs", "ground", "-o", o, "--calibration", f["garbage"]],
              ["system", "--adcs", "ground", "-o", o, "--params", f["nanjson"]],
              ["system", "--adcs", "ground", "-o", o, "--params", f["missing"]],
              ["system", "--adcs", "ground", "-o", o, "--truth", "nope"],
              ["system", "--adcs", "ground", "-o", o, "--runtime", "inproc"],
              ["system", "--adcs", "ground", "-o", o, "--q2-dv", "0"],
              ["system", "--adcs", "nope", "-o", o], ["system"]]
    cases += [["adcs", "sweep", "-o", o, "--ts", "x"], ["adcs", "sweep", "-o", o, "--workers", "0"],
              ["distfile", "generate", "-o", o, "--source", "bps", "--ts", "0"],
              ["distfile", "generate", "-o", o, "--source", "bps", "--params", f["garbage"]],
              ["distfile", "generate", "-o", o, "--source", "bps", "--bps-truth", "nope"]]
    return cases


def _bad_cases(f):
    """Argument lists that must be refused (exit 1 or 2), in the order they run."""
    o = os.path.join(f["out"], "x")
    return (_bad_protocol_and_emulator_cases(f, o) + _bad_numbers_for_emulator_distfile_calibrate_hil(f, o)
            + _bad_files_for_spacecraft_distfile_calibrate_hil(f, o) + _bad_response_and_distfile_step_cases(f, o)
            + _bad_adcs_and_system_cases(f, o))


BIG = "1" + "0" * 400           # valid JSON, an integer no float holds


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    """For each kind of input JSON file (faults, spacecraft, campaign and calibrated parameters, calibration,
    bench config): a 400-digit integer and a string where a number is due (each with the key it is under), and
    one file nested 100000 deep for all of them."""
    from protocol import paramfile
    from protocol import spacecraft as sf
    d = tmp_path_factory.mktemp("hostile")
    sc = json.dumps(sf.load("thesis-3u"))
    cal = json.dumps(fp.calibration(3))
    pf = json.dumps({"format": paramfile.FORMAT, "wheels": 4, "jxx_ref_kgm2": "@", "x": {}, "P": []})
    texts = {"faults": ('{"beacon_lost": @}', "beacon_lost"), "spacecraft": (sc.replace('"mass_kg": 4.0',
                                                                                         '"mass_kg": @'), "mass_kg"),
             "campaign_params": ('{"duration_s": @}', "duration_s"), "params": (pf.replace('"@"', "@"), "jxx_ref_kgm2"),
             "calibration": (cal.replace('"grid_v": [-1.0', '"grid_v": [@'), "grid_v[0]"),
             "config": ('{"laser": {"power_w": @}}', "laser.power_w")}
    h = {"deep": (str(d / "deep.json"), None)}
    with open(h["deep"][0], "w") as fh:
        fh.write("[" * 100000 + "]" * 100000)
    for kind, (text, key) in texts.items():
        assert text.count("@") == 1, kind
        for variant, value in (("big", BIG), ("string", '"3"')):
            h[kind, variant] = (str(d / ("%s_%s.json" % (kind, variant))), key)
            with open(h[kind, variant][0], "w") as fh:
                fh.write(text.replace("@", value))
    return h


def _hostile_file_cases(f, h, o):
    """(argument list, the file, the key it must name or None) for each hostile file of ``hostile`` given to
    every command that takes that kind of file."""
    takes = {"faults": [["system", "--adcs", "ground", "-o", o], ["adcs", "can", "--session", "2", "-o", o]],
             "spacecraft": [["adcs", "apkf", "-o", o], ["adcs", "mekf", "-o", o], ["adcs", "stkf", "--case", "1",
                                                                                    "-o", o],
                            ["adcs", "bps", "-o", o], ["adcs", "sweep", "-o", o], ["adcs", "can", "-o", o],
                            ["system", "--adcs", "ground", "-o", o],
                            ["distfile", "generate", "--source", "bps", "--duration", "5", "-o", o + ".dist"]],
             "campaign_params": [["adcs", "apkf", "-o", o], ["adcs", "mekf", "-o", o]],
             "params": [["adcs", "bps", "-o", o], ["adcs", "sweep", "-o", o], ["adcs", "can", "-o", o],
                        ["system", "--adcs", "ground", "-o", o],
                        ["distfile", "generate", "--source", "bps", "--duration", "5", "-o", o + ".dist"]],
             "calibration": [["hil", "-o", o, "--distfile", f["dist"], "--duration", "0.01"],
                             ["system", "--adcs", "ground", "-o", o]],
             "config": [["emulator", "config"], ["emulator", "truth-h", "--grid", "2", "-o", o],
                        ["emulator", "serve", "--wait", "0"], ["calibrate", "--grid", "2", "-o", o],
                        ["hil", "-o", o, "--distfile", f["dist"], "--calibration", f["cal"], "--duration", "0.01"],
                        ["response", "--points", "2", "-o", o]]}
    option = {"faults": "--faults", "spacecraft": "--spacecraft", "campaign_params": "--params",
              "params": "--params", "calibration": "--calibration", "config": "--config"}
    cases = []
    for kind, argvs in takes.items():
        for argv in argvs:
            for path, key in (h["deep"], h[kind, "big"], h[kind, "string"]):
                cases.append((argv + [option[kind], path], path, key))
    for sub in ("check", "show"):
        cases += [(["spacecraft", sub, path], path, key) for path, key in (h["deep"], h["spacecraft", "big"],
                                                                          h["spacecraft", "string"])]
    return cases


def test_hostile_json_files_exit_2_naming_the_file_and_the_key(capsys, files, hostile):
    """A 400-digit integer, a string number and a file nested 100000 deep, in every JSON file every command
    reads: exit 2, one error line naming the file (and the key), no internal error, nothing written."""
    o = os.path.join(files["out"], "hostile")
    cases = _hostile_file_cases(files, hostile, o)
    assert len(cases) == 81
    for argv, path, key in cases:
        rc, out, err = run(capsys, argv)
        last = err.strip().splitlines()[-1] if err.strip() else ""
        assert rc == 2 and last.startswith("fps") and "error: " in last, (argv, rc, err)
        assert path in last and (key is None or key in last) and "internal error" not in err, (argv, err)
        assert not os.path.exists(o) and not os.path.exists(o + ".dist"), argv


def test_every_command_is_covered(files):
    """The bad cases reach every command and sub-command ``fps --help`` and their own help list."""
    reached = {tuple(a[:2]) if a[0] in ("protocol", "emulator", "distfile", "adcs") else (a[0],)
               for a in _bad_cases(files) if a and a[0]}
    want = {("protocol", "encode"), ("protocol", "decode"), ("protocol", "dbc"), ("emulator", "config"),
            ("emulator", "truth-h"), ("emulator", "serve"), ("distfile", "generate"), ("distfile", "info"),
            ("distfile", "csv"), ("calibrate",), ("hil",), ("adcs", "apkf"), ("adcs", "mekf"), ("adcs", "stkf"),
            ("adcs", "bps"), ("adcs", "sweep"), ("response",), ("system",), ("spacecraft",)}
    assert want <= reached
    assert {c[0] for c in cli.COMMANDS} == {w[0] for w in want}


def test_help_of_every_command(capsys):
    for argv in ([], ["--help"], ["protocol"], ["protocol", "--help"], ["emulator"], ["distfile"]):
        rc, out, err = run(capsys, argv)
        assert rc in (0, 2) and (out or err)
    subs = {"protocol": ("table", "dbc", "encode", "decode"), "emulator": ("config", "truth-h", "serve"),
            "distfile": ("generate", "info", "csv")}
    for cmd, names in subs.items():
        for name in names:
            rc, out, _ = run(capsys, [cmd, name, "--help"])
            assert rc == 0 and "usage: fps %s %s" % (cmd, name) in out
    for cmd in ("calibrate", "hil", "system"):
        rc, out, _ = run(capsys, [cmd, "--help"])
        assert rc == 0 and "usage: fps %s" % cmd in out


def test_bad_inputs_give_a_clear_error_never_a_traceback(capsys, files):
    for argv in _bad_cases(files):
        rc, out, err = run(capsys, argv)
        assert rc in (1, 2), (" ".join(argv), rc, out, err)
        last = err.strip().splitlines()[-1] if err.strip() else ""
        assert last.startswith("fps") and "error: " in last, (argv, err)     # argparse's usage may precede it
        assert "np.float" not in err and "np.int" not in err, (argv, err)   # numbers as people write them


def test_audited_inputs_are_refused_up_front_by_name(capsys, files, tmp_path):
    """Inputs a bad-input audit found ending in an internal error, a mid-run failure with a partial folder, a
    message naming nothing, or a destroyed input: each now exits 2 before anything is written, naming it."""
    o = str(tmp_path / "run")
    hil = ["hil", "-o", o, "--distfile", files["dist"], "--calibration", files["cal"], "--duration", "0.01"]
    gen = ["distfile", "generate", "-o", str(tmp_path / "x.dist")]
    for argv, msg in ((hil + ["--seed", "-1"], "--seed must be a whole number from 0 to 2^32 - 1"),
                      (hil + ["--q2-dv", "1e-4"], "--q2-dv must be in [0.0012, 2] V"),
                      (hil[:-1] + ["1e-9"], "--duration must be >= 0.01 s"),
                      (hil + ["--rate-hz", "150000"], "--rate-hz = 150000.0: must be a number from 100 to 100000"),
                      (hil + ["--runtime", "qemu", "--baud", "0"], "--baud 0: must be a whole number of bit/s"),
                      (hil + ["--runtime", "micropython", "--baud", "9600"], "--baud 9600 goes with --runtime board"),
                      (["calibrate", "-o", o + ".json", "--grid", "2", "--runtime", "qemu", "--port", "/dev/null"],
                       "--port /dev/null with --runtime qemu"),
                      (["response", "-o", o, "--from", "1e-9"], "need 0.1 <= from < to"),
                      (["response", "-o", o, "--points", "1001"], "--points 1001: need 2 to 200"),
                      (["response", "-o", o, "--amp", "1e-3"], "need 0.1 <= amp <= 10 arcsec"),
                      (["response", "-o", o, "--seed", "-1"], "--seed must be"),
                      (["calibrate", "-o", o + ".json", "--grid", "2", "--seed", "4294967296"], "--seed must be"),
                      (["emulator", "serve", "--seed", "-1", "--wait", "0"], "--seed must be"),
                      (gen + ["--source", "sine", "--duration", "inf"], "duration must be > 0 s and finite, got inf"),
                      (gen + ["--source", "sine", "--duration", "nan"], "got nan"),
                      (gen + ["--source", "sine", "--step-us", "inf"], "--step-us inf: need a whole number"),
                      (gen + ["--source", "sine", "--step-us", "nan"], "--step-us nan"),
                      (gen + ["--source", "sine", "--freq-hz", "6000,1"], "the finest step, 95 us, plays tones below"),
                      (gen + ["--source", "stat", "--stat-scale", "0"], "stat scale must be finite and >= 1e-6"),
                      (["distfile", "csv", files["dist"], "-o", files["dist"]], "is the input file of the distfile"),
                      (["emulator", "truth-h", "--grid", "2", "--config", files["cal"], "-o", files["cal"]],
                       "is the input file of --config")):
        before = {p: open(p, "rb").read() for p in (files["dist"], files["cal"])}
        rc, out, err = run(capsys, argv)
        assert rc == 2 and msg in err, (argv, rc, err)
        assert not os.path.exists(o) and not os.path.exists(o + ".json"), argv
        assert {p: open(p, "rb").read() for p in before} == before, argv
    (tmp_path / "j.dist.jitter.json").mkdir()                         # the distfile was written, then exit 1
    rc, out, err = run(capsys, ["distfile", "generate", "--source", "jitter", "--duration", "0.2", "--step-us", "1000",
                                "-o", str(tmp_path / "j.dist")])
    assert rc == 2 and "is a folder" in err and not (tmp_path / "j.dist").exists(), err
    slow = tmp_path / "slow.json"
    slow.write_text('{"board": {"adc_read_us": 5000}}')                # failed at the first tick, folder left
    gap = tmp_path / "gap.csv"
    gap.write_text("0,1,2\n1,1,2\n2,3,4\n3,1,1\n50,1,1\n")         # cubic interpolation overshot to 860 arcsec
    for argv, msg in ((["distfile", "info", "/dev/zero"], "larger than"),
                      (hil[:4] + [files["missing"]] + hil[5:], "distfile %s: cannot read it" % files["missing"]),
                      (hil[:6] + [files["dir"]] + hil[7:], "calibration %s: cannot read it" % files["dir"]),
                      (gen + ["--source", "csv", "--csv", str(gap), "--duration", "40"], "a gap of 47 s after sample 3"),
                      (hil + ["--config", str(slow)], "use a faster board (board.adc_read_us)"),
                      (["calibrate", "-o", o, "--grid", "2", "--config", str(slow)], "use a faster board")):
        rc, out, err = run(capsys, argv)
        assert rc == 2 and msg in err and not os.path.exists(o), (argv, rc, err)
    rc, out, err = run(capsys, gen + ["--source", "sine", "--offset-arcsec", "1e300,1"])
    assert rc == 2 and "1e+300 arcsec passes the limit" in err and len(err) < 600, err


def test_an_output_path_that_cannot_be_written_is_refused_before_any_work(capsys, files, tmp_path):
    """-o under a file, a folder where a file goes, or a file where the run folder goes: exit 2 naming the
    path, from argparse, before the command runs (a bps distfile used to run its simulation, then exit 1)."""
    f = tmp_path / "a_file"
    f.write_text("keep")
    under = str(f / "x")
    cases = [(["adcs", cmd, "-o", under] + extra, "is a file, so no folder can be made under it")
             for cmd, extra in (("apkf", []), ("mekf", []), ("stkf", ["--case", "1"]), ("bps", []), ("sweep", []),
                                ("can", ["--session", "2"]))]
    cases += [([cmd, "-o", under] + extra, "is a file, so no folder can be made under it")
              for cmd, extra in (("hil", ["--distfile", files["dist"], "--calibration", files["cal"]]),
                                 ("response", []), ("system", []), ("calibrate", []))]
    cases += [(["distfile", "generate", "--source", "bps", "--duration", "600", "-o", str(tmp_path)],
               "is a folder; the output file goes there"),
              (["distfile", "csv", files["dist"], "-o", str(tmp_path)], "is a folder; the output file goes there"),
              (["emulator", "truth-h", "-o", str(tmp_path)], "is a folder"),
              (["emulator", "serve", "--wait", "0", "-o", str(tmp_path)], "is a folder"),
              (["protocol", "dbc", "-o", str(tmp_path)], "is a folder"),
              (["adcs", "apkf", "-o", str(f)], "is a file; the run folder goes there"),
              (["adcs", "apkf", "-o", ""], "an empty path; name the run folder"),
              (["distfile", "generate", "--source", "stat", "-o", " "], "an empty path; name the output file"),
              (["hil", "--distfile", files["dist"], "--calibration", files["cal"], "-o", str(f)], "is a file")]
    for argv, msg in cases:
        rc, out, err = run(capsys, argv)
        last = err.strip().splitlines()[-1] if err.strip() else ""
        assert rc == 2 and "argument -o/--output" in last and msg in last, (argv, rc, err)
    assert f.read_text() == "keep" and sorted(os.listdir(tmp_path)) == ["a_file"]


def test_a_cache_folder_that_cannot_be_one_is_refused_first(capsys, tmp_path):
    """``--cache-dir`` / ``--bps-cache`` on a file, under a file or empty: exit 2 naming the option, before the
    calibration runs (it once ran for seconds and then failed on the cache)."""
    f = tmp_path / "a_file"
    f.write_text("keep")
    out = str(tmp_path / "o")
    for bad, msg in ((str(f), "is a file; the cache folder goes there"), (str(f / "x"), "is a file, so no folder"),
                     ("", "an empty path; name the cache folder")):
        for argv, opt in ((["adcs", "bps", "--cache-dir", bad, "--duration", "10", "-o", out], "--cache-dir"),
                          (["adcs", "sweep", "--cache-dir", bad, "--duration", "10", "-o", out], "--cache-dir"),
                          (["distfile", "generate", "--source", "bps", "--bps-cache", bad, "--duration", "10",
                            "-o", out + ".dist"], "--cache-dir/--bps-cache"),
                          (["system", "--cache-dir", bad, "-o", out], "--cache-dir/--bps-cache")):
            rc, _, err = run(capsys, argv)
            last = err.strip().splitlines()[-1]
            assert rc == 2 and "argument %s" % opt in last and msg in last, (argv, rc, err)
    assert f.read_text() == "keep" and sorted(os.listdir(tmp_path)) == ["a_file"]


def test_fine_inputs_exit_0(capsys, files):
    o = os.path.join(files["out"], "fine")
    for argv in (["protocol", "table"], ["protocol", "table", "--json"], ["protocol", "encode", "RW_CMD", "torque=0.5"],
                 ["protocol", "encode", "RW_CMD", "torque=3.4028234663852886e38", "--can"],
                 ["protocol", "decode", "--serial", files["garbage"]], ["protocol", "decode", "--can", files["empty"]],
                 ["emulator", "config"], ["distfile", "info", files["dist"]], ["distfile", "csv", files["dist"]],
                 ["distfile", "generate", "-o", o + ".dist", "--source", "sine", "--duration", "0.5"]):
        rc, out, err = run(capsys, argv)
        assert rc == 0, (argv, err)


# --- hypothesis: fps protocol encode / decode ----------------------------------------------------------
_NAMES = sorted(core.PACKET_ID)
_FIELDS = sorted({f[0] for p in core.PACKET.values() for f in p.fields})
_text = st.text(alphabet=string.printable, max_size=12)
_number = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                    st.integers(min_value=-2 ** 70, max_value=2 ** 70).map(str),
                    st.integers(min_value=-2 ** 40, max_value=2 ** 40).map(hex),
                    st.sampled_from(BAD_NUMBERS + ("0x", "1_0", "0b12", "١", "5e-324", "True")),
                    st.binary(max_size=60).map(bytes.hex), _text)
_item = st.one_of(st.builds(lambda k, v: "%s=%s" % (k, v), st.sampled_from(_FIELDS) | _text, _number), _text)
_flag = st.one_of(st.tuples(st.sampled_from(["--seq", "--src", "--dst"]),
                            st.one_of(_number, st.sampled_from(sorted(core.NODE)))).map(list),
                  st.just(["--can"]))


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(st.sampled_from(_NAMES), st.integers(-5, 300).map(str), _text),
       st.lists(_item, max_size=6), st.lists(_flag, max_size=3))
def test_hypothesis_protocol_encode(capsys, name, items, flags):
    argv = ["protocol", "encode", name] + items + [a for f in flags for a in f]
    rc, out, err = run(capsys, argv)
    assert rc in (0, 1, 2), (argv, rc)
    if rc:
        assert "error" in err and not out, (argv, out, err)
    else:
        assert out.strip() and not err, (argv, err)
        text = out.strip().splitlines()
        if "--can" not in argv:
            assert all(c in string.hexdigits for c in text[0])


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(["--serial", "--can"]), st.binary(max_size=400),
       st.lists(st.sampled_from(["--serial", "--can", "-h", "", "x", "--bogus"]), max_size=2))
def test_hypothesis_protocol_decode(capsys, tmp_path_factory, how, data, extra):
    path = os.path.join(str(tmp_path_factory.getbasetemp()), "capture.bin")
    with open(path, "wb") as f:
        f.write(data)
    argv = ["protocol", "decode", how, path] + extra
    rc, out, err = run(capsys, argv)
    assert rc in (0, 1, 2), (argv, rc)
    if rc == 0 and "-h" not in extra:
        summary = json.loads(out.strip().splitlines()[-1])["summary"]
        assert summary["dropped"] == sum(summary["drops"].values()) and summary["frames"] <= len(data)
    elif rc:
        assert "error" in err
