"""One parameter-file checker (protocol.paramfile) for the ground and the flight firmware: the same verdicts under
CPython and under MicroPython on good and bad files, each refusal naming the key, the value and the allowed range;
ground/adcs/body_pointing.py and firmware/adcs/apkf_lean.py both refuse through it."""

import json
import os
import subprocess
import sys

import pytest

from emulator.spacecraft import scenario
from firmware.adcs import apkf_lean
from ground.adcs import body_pointing as bps
from protocol import paramfile as pf
from protocol import spacecraft as sf

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")
SCRIPT = os.path.join(ROOT, "tests", "mp", "paramfile_check.py")


def _lines(exe, path):
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    r = subprocess.run([exe, SCRIPT, str(path)], capture_output=True, text=True, timeout=60, env=env, cwd="/")
    assert r.returncode == 0, r.stderr
    return r.stdout.splitlines()


@pytest.fixture
def perfect(tmp_path):
    p = tmp_path / "params.json"
    p.write_text(json.dumps(scenario.truth_params(scenario.pointing_world(2, 0).sc)))
    return p


def test_the_same_verdicts_under_micropython_and_cpython(perfect):
    if not os.path.exists(MICROPYTHON):
        pytest.skip("micropython binary not installed in the venv")
    cp, mp = _lines(sys.executable, perfect), _lines(MICROPYTHON, perfect)
    assert mp == cp
    refused = [line for line in cp if line.startswith("refused ")]
    accepted = [line.split(" ")[1] for line in cp if line.startswith("accepted ")]
    assert len(refused) == 36 and accepted == ["good", "no", "integers", "6U", "file"]
    for line in refused:                    # the key (or the whole file), the value and what is allowed
        assert any(w in line for w in (" = ", ": missing", ": unknown key", "P: must be", "a JSON object")), line
    for want in ("x.jrw_kgm2[0] = 0.0003: must be from 3e-07 to 3e-05 kg m^2",
                 "x.J5_kgm2[1] = nan: must be a finite number, from -10000 to 10000 kg m^2",
                 "torque_scale = inf: must be a finite number, > 0.2 and < 5", "x.jrw_kgm2: missing",
                 "colour: unknown key", "P[2][2] = nan: must be a finite number", "not positive definite",
                 "x.jrw_kgm2[0] = 3.4e-06: must be from 4.8e-06 to 0.00048 kg m^2",     # on generic-6u
                 "x.tau_d_nm[0] = 0.0015: must be from -0.001 to 0.001 N m"):
        assert any(want in line for line in refused), want


def test_ground_and_firmware_refuse_through_the_one_checker(perfect):
    d = json.loads(perfect.read_text())
    assert not hasattr(apkf_lean, "check_params") and bps.FORMAT == pf.FORMAT
    d["x"]["jrw_kgm2"][2] = float("nan")
    msg = "x.jrw_kgm2[2] = nan: must be a finite number, from 3e-07 to 3e-05 kg m^2"
    with pytest.raises(ValueError) as g:
        bps.check_params(d, "p.json")
    with pytest.raises(ValueError) as f:
        apkf_lean.Model(d)
    assert str(g.value) == "p.json: " + msg and str(f.value) == msg
    six = sf.load("generic-6u")
    d = json.loads(perfect.read_text())
    with pytest.raises(ValueError, match="4.8e-06 to 0.00048"):
        bps.check_params(d, spacecraft=six)
    xp, P, jxx, s = bps.check_params(d)
    assert xp.tolist() == [v for k, _ in pf.X_PARTS for v in d["x"][k]] and P.tolist() == d["P"] and s == 1.0


@pytest.mark.parametrize("where, msg", [
    (("jxx_ref_kgm2",), "jxx_ref_kgm2 = 100000...000 (401 digits): must be a finite number, > 0"),
    (("x", "tau_d_nm", 1), "x.tau_d_nm[1] = 100000...000 (401 digits): must be a finite number"),
    (("P", 2, 2), "P[2][2] = 100000...000 (401 digits): must be a finite number")])
def test_an_integer_beyond_any_float_is_refused_by_the_range_check(perfect, where, msg):
    d = json.loads(perfect.read_text())
    at = d
    for k in where[:-1]:
        at = at[k]
    at[where[-1]] = 10 ** 400
    with pytest.raises(ValueError) as e:
        bps.check_params(d, "p.json")
    assert str(e.value).startswith("p.json: " + msg), str(e.value)
