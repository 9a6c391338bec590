"""Fixtures shared by the HIL tests, and the test tiers: ``make check`` (daily work, under 2 minutes) leaves out the
end-to-end modules below, whose tests start processes, boards or whole runs; ``make test`` (what CI runs) runs all;
``FPS_SLOW=1`` adds the longest runs (marked ``slow(reason=...)``: skipped with that reason without it)."""

import os

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


@pytest.fixture(scope="module")
def system_inputs(tmp_path_factory):
    """(params file, H calibration file, bps cache folder) for short fps system runs without calibrating."""
    from ground.adcs import body_pointing as bps, bps_cli
    d = tmp_path_factory.mktemp("system_inputs")
    cache = str(d / "cache")
    params = str(d / "params.json")
    bps.write_params(params, bps_cli.calibration(0, cache, progress=False))
    cal = str(d / "cal.json")
    write_json(cal, true_h_field(Bench(noise=False), None, 0.01))
    return params, cal, cache

E2E_MODULES = (                            # longest first (their durations in make test), so that they start first
    "test_pil", "test_can_faults", "test_system_failures", "test_no_orphans", "test_hil_faults", "test_system",
    "test_flight_firmware",
    "test_ground_calibrate", "test_firmware_lockstep", "test_cli_no_traceback", "test_ground_hil", "test_adcs_can",
    "test_adcs_runs", "test_protocol_fuzz", "test_adcs_consistency", "test_emulator_serve_wheels",
    "test_firmware_mp", "test_fine_pointing_edges", "test_flight_world", "test_adcs_lean", "test_adcs_lean_stkf",
    "test_adcs_cli_edges", "test_adcs_campaign", "test_protocol_mp", "test_launcher", "test_adcs_natmod",
    "test_emulator_lockstep", "test_emulator_serve_and_session_edges", "test_protocol_link_edges",
    "test_protocol_emulator_edges", "test_hil_keepalive",
)


def pytest_collection_modifyitems(config, items):
    """Mark the end-to-end modules, and run them first (each module's tests kept together, in order): the long
    tests start while the short ones are left to fill both workers of ``make test`` (pytest-xdist) to the end."""
    rank = dict((m, k) for k, m in enumerate(E2E_MODULES))
    slow = bool(os.environ.get("FPS_SLOW"))
    for item in items:
        if item.module.__name__.rsplit(".", 1)[-1] in rank:
            item.add_marker(pytest.mark.e2e)
        mark = item.get_closest_marker("slow")
        if mark is not None and not slow:
            item.add_marker(pytest.mark.skip(reason=mark.kwargs.get("reason", "a long run: FPS_SLOW=1 runs it")))
    items.sort(key=lambda item: rank.get(item.module.__name__.rsplit(".", 1)[-1], len(rank)))
