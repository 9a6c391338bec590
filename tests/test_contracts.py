"""One home for each contract: the units defined once (``protocol.units``, names that say their direction), and
the copies that must exist (MicroPython's ``const()`` needs its numbers in the module that uses them) checked
against their source."""

import os
import re
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _sources():
    out = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    return [(f, open(os.path.join(ROOT, f)).read()) for f in out if os.path.exists(os.path.join(ROOT, f))]


def test_the_angle_units_are_defined_once_with_their_direction_in_the_name():
    from protocol import units
    assert units.RAD_PER_ARCSEC * units.ARCSEC_PER_RAD == 1.0
    assert abs(units.RAD_PER_ARCSEC - 4.84813681109536e-06) < 1e-20
    for f, text in _sources():
        if f == "tests/test_contracts.py":
            continue
        assert not re.search(r"\bARCSEC\b", text), "%s uses the ambiguous name ARCSEC" % f
        if f != "protocol/units.py":
            assert not re.search(r"^\s*(RAD_PER_ARCSEC|ARCSEC_PER_RAD)\s*=", text, re.M), \
                "%s defines a unit protocol.units holds" % f


def test_the_controllers_modes_are_the_packet_tables():
    from firmware import controller
    from protocol import table
    for name, value in table.MODES:
        assert getattr(controller, name) == value, name


def test_the_calibration_maths_is_one_module_for_the_truth_and_fps_calibrate():
    from emulator import bench, hcal, truth
    from ground import calibrate, hil
    assert calibrate.fit_h is hcal.fit_h and hil.fit_h is hcal.fit_h and calibrate.STEPS is hcal.STEPS
    assert truth.sec74_grid(11) == calibrate.sec74_grid(11) == hcal.grid(11) == [float(v) for v in range(-5, 6)]
    for mod in (bench, calibrate, truth):          # no second least-squares H or grid formula beside hcal's
        src = open(mod.__file__).read()
        assert "lstsq" not in src and "linspace" not in src, mod.__name__


def test_one_gravitational_parameter_for_the_orbits_the_filters_and_the_torques():
    import brahe
    from emulator import orbits
    from emulator.spacecraft import environment
    from firmware.adcs import estimation, stkf_lean
    from ground.adcs import stkf
    from protocol import units
    assert units.MU_EARTH == brahe.GM_EARTH == 398600.4415e9
    assert orbits.MU == stkf.MU == stkf_lean.MU == environment.MU_EARTH == estimation.MU_EARTH == units.MU_EARTH
    for f, text in _sources():
        if f not in ("protocol/units.py", "tests/test_contracts.py", "tests/test_adcs_apkf_fast.py"):
            assert not re.search(r"3\.98600\d*e14|398600\.44\d*e9", text), "%s writes mu again" % f


def test_the_repository_stands_alone():
    """No tracked file needs or cites a document outside the repository."""
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    outside = ("DESIGN" + ".md", "../" + "shared", "THESIS_" + "NUMBERS", "HARDWARE_" + "FACTS")
    for f in out:
        p = os.path.join(ROOT, f)
        if not os.path.isfile(p) or f.endswith((".png", ".npz", ".elf")):
            continue
        try:
            text = open(p, encoding="utf-8").read()
        except UnicodeDecodeError:
            continue
        for word in outside:
            assert word not in text, "%s cites %s" % (f, word)
