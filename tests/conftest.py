"""Fixtures shared by the HIL tests, and the test tiers: ``make check`` (daily work, under 2 minutes) leaves out the
end-to-end modules below, whose tests start processes, boards or whole runs; ``make test`` (what CI runs) runs all;
``FPS_SLOW=1`` adds the longest runs (marked ``slow``)."""

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


E2E_MODULES = {
    "test_pil", "test_can_faults", "test_hil_faults", "test_system", "test_system_failures", "test_flight_firmware",
    "test_firmware_lockstep", "test_ground_hil", "test_ground_calibrate", "test_adcs_can", "test_emulator_serve_wheels",
    "test_adcs_cli_edges", "test_protocol_fuzz", "test_cli_no_traceback", "test_firmware_mp", "test_adcs_natmod",
    "test_fine_pointing_edges", "test_flight_world", "test_adcs_consistency", "test_adcs_campaign", "test_adcs_runs",
    "test_launcher", "test_protocol_mp", "test_emulator_lockstep", "test_adcs_lean", "test_protocol_emulator_edges",
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.module.__name__.rsplit(".", 1)[-1] in E2E_MODULES:
            item.add_marker(pytest.mark.e2e)
