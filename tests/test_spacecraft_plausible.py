"""protocol.spacecraft.plausible: every preset passes; a figure in the wrong unit (inertia in g m^2 or kg mm^2, a
mass in g, areas in cm^2, an offset or an arm in mm or cm, a rotor inertia in g m^2) is refused by the checker with
the key path, the value and the plausible range; fps spacecraft check exits 2 with the message; the module runs
under MicroPython."""

import copy
import json
import math
import os
import re
import subprocess
import sys

import pytest

from ground import cli
from protocol import spacecraft as sc
from protocol.spacecraft import plausible

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")
PRESETS = ("generic-12u", "generic-6u", "thesis-3u")


def raw(name="thesis-3u"):
    return copy.deepcopy(sc.read(sc.preset_path(name)))


def one_u():
    """A 1U of 1.3 kg (10 cm cube), from thesis-3u's file."""
    d = raw()
    del d["truth"]
    d.update(mass_kg=1.3, inertia_kgm2=[0.0022, 0.0022, 0.0022, 0.0, 0.0, 0.0])
    d["surface"].update(drag_area_m2=0.01, srp_area_m2=0.01, cp_offset_m=[0.01, 0.0, 0.0])
    d["wheels"].update(arm_m=0.03)
    return d


def refused(d):
    with pytest.raises(ValueError) as e:
        sc.check(d)
    return str(e.value)


def test_every_preset_passes_well_inside_the_envelopes():
    for name in PRESETS:
        d = sc.load(name)
        plausible.check_plausible(d, sc.principal_moments)
        size = plausible.size_m(d)
        k = [math.sqrt(j / d["mass_kg"]) / size for j in sc.principal_moments(d["inertia_kgm2"])]
        assert 0.2 < k[0] and k[2] < 0.7, (name, k)                      # 0.22 to 0.64 L
        assert 200 < d["mass_kg"] / size ** 3 < 800
        assert max(d["wheels"]["rotor_inertia_kgm2"]) < 1e-3 * sc.principal_moments(d["inertia_kgm2"])[0]
        assert max(abs(x) for x in d["surface"]["cp_offset_m"]) < 0.2 * size and d["wheels"]["arm_m"] < 0.3 * size


def test_an_inertia_in_g_m2_or_kg_mm2_is_refused_naming_the_key_the_value_and_the_range():
    for name in PRESETS:
        d = raw(name)
        j = [round(x * 1000, 9) for x in d["inertia_kgm2"]]                # g m^2
        d["inertia_kgm2"] = j
        msg = refused(d)
        assert msg.startswith("inertia_kgm2 = %s: the largest principal moment" % sc.value_text(j)), msg
        assert re.search(r"radius of gyration sqrt\(J / mass_kg\) = [\d.]+ m, implausible for a [\d.]+ kg vehicle "
                         r"of about [\d.]+ m \(L = sqrt\(max\(surface\.drag_area_m2, surface\.srp_area_m2\)\)\): "
                         r"must be from [\d.]+ to [\d.]+ m \(inertia in g m\^2 or kg mm\^2", msg), msg
    d = raw("generic-6u")                                                 # kg mm^2: beyond the schema's range
    d["inertia_kgm2"] = [x * 1e6 for x in d["inertia_kgm2"]]
    assert refused(d).startswith("inertia_kgm2[0] = 135000: must be from -10000 to 10000 kg m^2")
    d = one_u()                                                           # kg mm^2 of a 1U: within it
    d["inertia_kgm2"] = [2200.0, 2200.0, 2200.0, 0.0, 0.0, 0.0]
    assert refused(d).startswith("inertia_kgm2 = [2200, 2200, 2200, 0, 0, 0]: the largest principal moment J = "
                                 "2200 kg m^2 gives a radius of gyration sqrt(J / mass_kg) = 41.1 m, implausible for "
                                 "a 1.3 kg vehicle of about 0.1 m")
    d = raw()                                                              # the example's 3U, from 0.00866 to 0.52 m
    d["inertia_kgm2"] = [12.0, 47.0, 45.0, 0.0, 0.0, 0.0]
    assert refused(d) == (
        "inertia_kgm2 = [12, 47, 45, 0, 0, 0]: the largest principal moment J = 47 kg m^2 gives a radius of gyration "
        "sqrt(J / mass_kg) = 3.43 m, implausible for a 4 kg vehicle of about 0.173 m (L = sqrt(max("
        "surface.drag_area_m2, surface.srp_area_m2))): must be from 0.00866 to 0.52 m (inertia in g m^2 or kg mm^2 "
        "instead of kg m^2?)")


def test_the_true_inertia_and_rotors_are_checked_too():
    d = raw()
    d["truth"]["inertia_error_kgm2"] = [0.0, 3.6, 3.6, 0.0, 0.0, 0.0]     # g m^2, a rigid body's still
    assert refused(d).startswith("truth.inertia_error_kgm2 = [0, 3.6, 3.6, 0, 0, 0]: the true inertia "
                                 "inertia_kgm2 + truth.inertia_error_kgm2 = [0.012, 3.647, 3.645, 0.001, 0.002, "
                                 "0.003]: the largest principal moment")
    d = raw()
    d["truth"]["rotor_inertia_error_kgm2"] = [3e-3, 0.0, 0.0, 0.0]
    assert "truth.rotor_inertia_error_kgm2 = [0.003, 0, 0, 0]" in refused(d)


def test_a_mass_in_g_is_refused():
    d = raw()
    d["mass_kg"] = 1500                                                   # a 1.5 kg 3U in g (the schema takes it)
    msg = refused(d)
    assert msg.startswith("mass_kg = 1500: mass_kg / L^3 = 289000 kg/m^3 is implausible for a vehicle of about "
                          "0.173 m"), msg
    assert msg.endswith("must be from 0.01 to 10000 kg/m^3 (mass in g instead of kg?)")
    d = raw()                                                             # a light vehicle: density passes, k does not
    d["mass_kg"], d["surface"]["srp_area_m2"] = 1500, 1.0
    msg = refused(d)
    assert msg.startswith("inertia_kgm2 = [0.012, 0.047, 0.045, 0.001, 0.002, 0.003]: the smallest principal "
                          "moment") and "(mass_kg in g instead of kg" in msg, msg


def test_areas_in_cm2_are_refused():
    d = one_u()
    sc.check(d)
    d["surface"]["srp_area_m2"] = 100                                     # its 0.01 m^2 in cm^2
    assert refused(d).startswith("surface.srp_area_m2 = 100: mass_kg / L^3 = 0.0013 kg/m^3 is implausible for a "
                                 "1.3 kg vehicle of about 10 m")


def test_an_offset_or_an_arm_in_mm_or_cm_is_refused():
    d = raw()
    d["surface"]["cp_offset_m"] = [2.0, 0.5, 0.0]                         # cm
    assert refused(d) == (
        "surface.cp_offset_m = [2, 0.5, 0]: |offset| = 2.06 m is implausible for a vehicle of about 0.173 m (L = "
        "sqrt(max(surface.drag_area_m2, surface.srp_area_m2))): must be at most 0.346 m (2 L; offset in mm or cm "
        "instead of m?)")
    d["surface"]["cp_offset_m"] = [5.0, 2.0, 0.0]                         # mm (the schema's 10 m takes it)
    assert refused(d).startswith("surface.cp_offset_m = [5, 2, 0]: |offset| = 5.39 m")
    d = raw()
    d["wheels"]["arm_m"] = 4                                              # cm
    assert refused(d).startswith("wheels.arm_m = 4: 4 m is implausible for a vehicle of about 0.173 m")
    d["wheels"]["arm_m"] = 0.34                                           # a long 3U's end: plausible
    sc.check(d)


def test_a_rotor_inertia_in_g_m2_is_refused():
    for name in PRESETS:
        d = raw(name)
        w = d["wheels"]
        w["rotor_inertia_kgm2"] = [round(x * 1000, 12) for x in w["rotor_inertia_kgm2"]]
        msg = refused(d)
        assert msg.startswith("wheels.rotor_inertia_kgm2 = %s: rotor 0's inertia" % sc.value_text(
            w["rotor_inertia_kgm2"])), msg
        assert re.search(r"must be at most 5 % of it, [\d.e-]+ kg m\^2 \(rotor inertia in g m\^2", msg), msg


def test_plausible_vehicles_beyond_the_presets_pass():
    d = raw()                                                             # a 4 kg 3U with two 3 m wings (2 m^2)
    d["surface"]["srp_area_m2"] = 2.04
    d["inertia_kgm2"] = [0.041, 1.9, 1.93, 0.0, 0.0, 0.0]
    sc.check(d)
    d = raw("generic-6u")                                                 # a 6U whose areas leave out its panels
    d["inertia_kgm2"] = [0.6, 0.5, 0.9, 0.0, 0.0, 0.0]
    sc.check(d)


def test_fps_spacecraft_check_exits_2_with_the_message_and_no_traceback(tmp_path, capsys):
    bad = tmp_path / "grams.json"
    d = raw()
    d["inertia_kgm2"] = [x * 1000 for x in d["inertia_kgm2"]]
    bad.write_text(json.dumps(d))
    capsys.readouterr()
    assert cli.main(["spacecraft", "check", str(bad)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "Traceback" not in err
    assert err.strip() == "fps spacecraft: error: spacecraft file %s: %s" % (bad, refused(d))
    r = subprocess.run([sys.executable, "-m", "ground.cli", "spacecraft", "check", str(bad)], capture_output=True,
                       text=True, timeout=60, cwd=ROOT)
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    assert "inertia_kgm2 = [12, 47, 45, 1, 2, 3]: the largest principal moment" in r.stderr
    assert "must be from 0.00866 to 0.52 m" in r.stderr


MP_CODE = """
import json
from protocol import spacecraft as sc
from protocol.spacecraft import plausible
def put(d, path, v):
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[k]
    d[keys[-1]] = v
raw = sc.read(sc.preset_path("thesis-3u"))
for n in sc.presets():
    plausible.check_plausible(sc.load(n), sc.principal_moments)
    print("ok", n)
for path, v in (("inertia_kgm2", [12.0, 47.0, 45.0, 1.0, 2.0, 3.0]), ("mass_kg", 1500.0),
                ("surface.cp_offset_m", [2.0, 0.5, 0.0]), ("wheels.arm_m", 4.0),
                ("wheels.rotor_inertia_kgm2", [0.003, 0.003, 0.003, 0.003])):
    d = json.loads(json.dumps(raw))
    put(d, path, v)
    try:
        sc.check(d)
        print("accepted", path)
    except ValueError as exc:
        print("refused", exc)
"""


def _run(exe):
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    r = subprocess.run([exe, "-c", MP_CODE], capture_output=True, text=True, timeout=60, env=env, cwd="/")
    assert r.returncode == 0, r.stderr
    return r.stdout.splitlines()


@pytest.mark.skipif(not os.path.exists(MICROPYTHON), reason="no micropython in the environment (make install)")
def test_the_checks_run_under_micropython_with_the_same_messages():
    mp, cp = _run(MICROPYTHON), _run(sys.executable)
    assert mp == cp and len(cp) == 8
    assert [line.split()[0] for line in cp] == ["ok"] * 3 + ["refused"] * 5
