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


def _angle_arcsec(q, p):
    import math
    d = abs(sum(a * b for a, b in zip(q, p)))
    return 2.0 * math.degrees(math.acos(min(1.0, d))) * 3600.0


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_gap_in_the_ticks_propagates_the_apkf_over_the_whole_gap(runtime, cfg_file):
    """8 s without a tick: the APKF propagates 8 steps (it used to step 1 s whatever the tick's time, so its
    attitude lagged by 7 s of its motion, ~3500 arcsec here, while the STKF went to the
    tick's time). Against ticks every second (wheels heard, field and orbit from the STKF each step) the
    attitude agrees within 1 arcsec and the attitude variance has grown as much."""
    every, gap = run_case("tick_gap", runtime, cfg_file)
    assert every["t_stkf"] == gap["t_stkf"] == 12.0
    assert _angle_arcsec(every["x"][0:4], gap["x"][0:4]) < 1.0
    assert gap["x"][4:7] == pytest.approx(every["x"][4:7], abs=1e-8)
    assert gap["Ptr"] == pytest.approx(every["Ptr"], rel=0.05)


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_repeated_tick_time_leaves_the_filters_as_they_are(runtime, cfg_file):
    """A new tick number at the previous tick's time: the APKF used to step another second (while the STKF
    did not), so every later estimate differed from the run without that tick."""
    plain, repeat = run_case("tick_repeat", runtime, cfg_file)
    for k in ("x", "P", "xs", "u"):
        assert repeat[k] == plain[k], k


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_tick_going_back_in_time_is_not_fused_and_the_status_packs(runtime, cfg_file):
    """A tick 1 s earlier than the last: the status packed a negative GNSS age (struct.error out of the cycle
    under CPython), SatA's GNSS and the beacon were applied at the filter's later time, the APKF stepped."""
    r = run_case("tick_backwards", runtime, cfg_file)
    assert r["err"] is None
    assert r["age"] == 0 and r["x_same"] and r["xs_same"] and r["n_refused"] == 2
    assert r["t_apkf"] == r["t_stkf"] == 7.0


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_no_beacon_update_without_an_attitude_of_this_cycle(runtime, cfg_file):
    """Before the APKF starts the beacon goes with the star tracker's fix of the same cycle. A cycle without a
    star-tracker packet used the previous cycle's fix (st_valid is not reset between cycles): the beacon was
    fused with a stale attitude (and with a tracker that died after one fix, at every cycle)."""
    without_st, without_both = run_case("beacon_without_attitude", runtime, cfg_file)
    assert not without_st["apkf"] and without_st["xs"] == without_both["xs"]


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_measurement_the_stkf_refuses_is_stale_in_the_status(runtime, cfg_file):
    """ADCS_STALE: 'the sensor gave nothing usable this cycle'. A beacon the STKF refuses every cycle was
    reported fresh and the mode never went DEGRADED; now it is as stale as an invalid one."""
    nan_beacon, invalid = run_case("refused_measurements_are_stale", runtime, cfg_file)
    assert nan_beacon["n_refused"] == 14 and invalid["n_refused"] == 0
    assert nan_beacon["stale"] == invalid["stale"] and nan_beacon["stale"] & 1 << 3
    assert nan_beacon["mode"] == invalid["mode"] == 3              # DEGRADED


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_fix_the_apkf_refuses_is_stale_in_the_status(runtime, cfg_file):
    """A star-tracker fix the APKF refuses (S not positive definite) was counted only in LeanApkf.skipped: the
    status said the tracker was fresh and the mode stayed POINT/HOLD while no fix was fused. Now it is stale,
    and after stale_s (10 s) of it the mode is DEGRADED; n_st_invalid (the tracker's own flag) is untouched."""
    r = run_case("apkf_refused_fix_is_stale", runtime, cfg_file)
    assert r["skipped"] == 12
    assert r["stale"] & 1 and r["mode"] == 3 and r["n_st_invalid"] == 0, r


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_gnss_b_stale_bit_and_degraded_mode_agree(runtime, cfg_file):
    """SatB's GNSS silent for stale_s (10 s) makes the mode DEGRADED (t - last >= stale_s); its stale bit
    used '>' and came one cycle later, so at 10 s the status said DEGRADED with no stale sensor to say why."""
    res = run_case("gnss_b_silent", runtime, cfg_file)
    for k, mode, bit in res:
        assert (mode == 3) == (k >= 10) and bit == (k >= 10), (k, mode, bit)


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_singular_pointing_command_damps_the_rate_instead_of_raising(runtime, cfg_file):
    """The command of Eq. 6.3 has no unique minimum rotation when the line of sight is opposite the laser axis
    (control.min_rotation raises ValueError): that ValueError left the 1 Hz cycle and ended the firmware."""
    r = run_case("command_singular", runtime, cfg_file)
    assert r["err"] is None
    assert r["qc_is_q"] and r["wc"] == [0.0, 0.0, 0.0] and r["no_command"]
    assert any(abs(u) > 1e-7 for u in r["u"])                     # the rate (1e-3 rad/s) is damped


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_backlog_of_satb_fixes_keeps_the_newest(runtime, cfg_file):
    """The app holds 4 SatB fixes per cycle. It kept the first 4 of a backlog and dropped the newer ones into a
    counter no status carries: the two oldest were then refused (older than the lag), the two newest lost.
    Now the newest 4 are kept (all fused) and the dropped ones are counted as refused."""
    r = run_case("satb_backlog", runtime, cfg_file)
    assert r["n_gnss_b"] == 4 and r["n_refused"] == 2 and r["t_last"] == 9.5



def test_a_lost_wheel_leaves_the_allocation_and_the_pointing_keeps_its_budget(tmp_path):
    """Wheel 1 silent from 300 s of an 1800 s flight-world session: the three left carry the pointing within its
    150″ 3σ budget (exit 0), with no bias over 20″ in any 400 s window from 400 s on (the coasting rotor's
    friction fed forward, its speed the wheel filter's), and every wheel below 80 % of its limit."""
    import numpy as np
    from ground.cli import main as fps
    out = tmp_path / "lost"
    assert fps(["adcs", "can", "--runtime", "inproc", "--world", "flight", "--wheel-silent", "1:300",
                "--session", "1800", "--no-plots", "--quiet", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["wheels_failed"] == 2 and s["pointing"]["pointing_3sigma_arcsec"] < 150.0
    assert s["max_wheel_speed_rpm"] < 0.8 * s["wheel_speed_limit_rpm"]
    h = np.load(out / "history.npz")
    t, dth = h["t"], h["dtheta_arcsec"]
    for a in np.arange(400.0, 1400.0 + 1e-9, 100.0):
        win = (t >= a) & (t < a + 400.0)
        assert np.all(np.abs(dth[win].mean(axis=0)) < 20.0), (a, dth[win].mean(axis=0))
