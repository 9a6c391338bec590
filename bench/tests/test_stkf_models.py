"""``bench_stkf_gravity`` flies the flight world's STKF forms from the scenario's own dicts (one source)."""

from bench import bench_stkf_gravity
from emulator.spacecraft import scenario


def test_the_bench_flies_the_scenarios_forms():
    assert bench_stkf_gravity.MODELS["j2"] == scenario.FLIGHT_STKF
    assert bench_stkf_gravity.MODELS["j2-markov"] == scenario.FLIGHT_STKF_MARKOV
