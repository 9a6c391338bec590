"""Fixtures shared by the HIL tests."""

import pytest

from emulator.bench import Bench
from emulator.truth import true_h_field
from ground.cli import main as fps
from ground.fileio import write_json


@pytest.fixture(scope="session")
def inputs(tmp_path_factory):
    """(distfile, calibration): 30 s of the stat source (seed 1) and the emulator's true H field."""
    d = tmp_path_factory.mktemp("hil_inputs")
    dist = str(d / "stat.dist")
    assert fps(["distfile", "generate", "--source", "stat", "--duration", "30", "--seed", "1", "-o", dist]) == 0
    cal = str(d / "cal.json")
    write_json(cal, true_h_field(Bench(noise=False), None, 0.01))
    return dist, cal
