"""The ADCS application's fault paths (firmware/adcs/app.py and what it calls), each under CPython and under
micropython (tests/mp/firmware_adcs_faults.py holds the cases; the same code runs in both)."""

import json
import os
import sys

import pytest

from emulator.adcs_session import AdcsSession
from tests.test_firmware_mp import MICROPYTHON, ROOT, run_mp

sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
import firmware_adcs_faults as cases  # noqa: E402

sys.path.pop(0)

RUNTIMES = ["cpython"] + (["micropython"] if os.path.exists(MICROPYTHON) else [])


@pytest.fixture(scope="module")
def cfg_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("adcs") / "cfg.json"
    p.write_text(json.dumps(AdcsSession(runtime="cpython", duration_s=30.0).config()))
    return p


def run_case(name, runtime, cfg_file):
    if runtime == "micropython":
        return run_mp("firmware_adcs_faults.py", cfg_file, name)[name]
    with open(cfg_file) as fh:
        return json.loads(json.dumps(cases.CASES[name](json.load(fh))))


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_wheels_left_that_do_not_span_get_no_torque_and_the_cycle_goes_on(runtime, cfg_file):
    """Two wheels failed leave a rank-2 C C^T: its determinant is ~1e-17 by rounding (or exactly 0). The
    allocation must not divide by it (torques at the limit in a meaningless direction) nor raise out of the
    cycle; the wheels left keep their speed (friction compensation), the failed ones get nothing."""
    res = run_case("wheels_left_do_not_span", runtime, cfg_file)
    for mask, r in res.items():
        mask = int(mask)
        assert r["failed"] == mask
        for u in r["u"]:
            assert isinstance(u, list), "mask %s: %s" % (bin(mask), u)
            for i in range(4):
                want = 0.0 if mask >> i & 1 else r["friction"][i]
                assert u[i] == pytest.approx(want, abs=1e-12), (bin(mask), u)


STATUS_COUNTERS = ("adcs_mode", "stale", "wheels_failed", "miss_rw0", "miss_rw1", "miss_rw2", "miss_rw3",
                   "miss_st", "miss_gnss", "miss_beacon", "n_st_invalid", "n_beacon_invalid", "n_gnss_b",
                   "n_refused", "n_rx_drop", "gnss_age_s")


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_out_of_range_payloads_are_not_fused(runtime, cfg_file):
    """A star-tracker fix marked valid that is not a finite unit quaternion (NaN, all zeros) or whose valid
    byte is out of range (2) counts as invalid, and so does a beacon vector that is not a unit vector; a NaN
    wheel speed counts as no reply; a GNSS fix of a satellite other than 0 or 1 is refused. The filters end
    exactly where the packet they stand for leaves them (before: NaN in the APKF for good, or the bad vector
    fused)."""
    res = run_case("bad_payloads", runtime, cfg_file)
    for name, (bad, ref) in res.items():
        for k in ("x", "P", "xs", "u"):
            assert bad[k] == ref[k], (name, k)
        sb, sr = dict(zip(STATUS_COUNTERS, bad["status"])), dict(zip(STATUS_COUNTERS, ref["status"]))
        if name.startswith("st_"):
            assert sb == sr and sb["n_st_invalid"] == 1, name
        elif name == "rw_nan":
            assert sb == sr and sb["miss_rw1"] == 1, name
        elif name == "bc_zero":
            assert sb == sr and sb["n_beacon_invalid"] == 1, name
        else:
            assert sb["n_refused"] == sr["n_refused"] + 1 and sb["n_gnss_b"] == sr["n_gnss_b"] == 0, name
