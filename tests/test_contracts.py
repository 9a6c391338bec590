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
