"""The crosslink's line of sight against the Earth (ground/adcs/occultation.py): the segment's geometry, the
occulted stretches, the pointing figures leaving occulted samples out, the shipped partners' clearance, and a
partner on the far side of the Earth: the run says "no line of sight", never "budgets met", and exits 3."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from emulator import orbits
from emulator.adcs_session import AdcsSession
from emulator.spacecraft import scenario
from ground.adcs import body_pointing as bps, flight_world, occultation as oc
from ground.adcs.modes import MODE_CODE
from protocol import spacecraft as sf
from protocol.units import RAD_PER_ARCSEC

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
R, M = oc.R_EARTH_M, oc.ATMOSPHERE_MARGIN_M
KM = 1e3


def test_a_segment_through_the_earth_is_occulted():
    a, b = np.array([R + 500 * KM, 0, 0]), np.array([-(R + 500 * KM), 0, 0])
    assert oc.occulted(a, b) and oc.clearance(a, b) == pytest.approx(-R)


def test_a_grazing_segment_is_occulted_only_within_the_margin():
    def chord(h):                         # a chord whose lowest point is h above the sphere, at (R + h, 0, 0)
        return np.array([R + h, -3000 * KM, 0]), np.array([R + h, 3000 * KM, 0])
    assert not oc.occulted(*chord(M + 1 * KM)) and oc.occulted(*chord(M - 1 * KM))
    assert oc.clearance(*chord(M + 1 * KM)) == pytest.approx(M + 1 * KM)
    assert not oc.occulted(*chord(50 * KM), margin_m=0.0) and oc.occulted(*chord(-1 * KM), margin_m=0.0)
    with pytest.raises(ValueError, match="margin"):
        oc.occulted(*chord(0.0), margin_m=-1.0)


def test_a_segment_whose_line_crosses_the_earth_is_clear():
    radial = (np.array([R + 500 * KM, 0, 0]), np.array([R + 1500 * KM, 0, 0]))     # the line through the centre
    oblique = (np.array([10000 * KM, 3000 * KM, 0]), np.array([8000 * KM, 1000 * KM, 0]))  # the line 4950 km off
    for a, b in (radial, oblique):
        assert not oc.occulted(a, b) and not oc.occulted(b, a)
    assert oc.clearance(*oblique) == pytest.approx(np.hypot(8000, 1000) * KM - R)
    # per sample, any leading shape
    ra = np.stack([radial[0], oblique[0], np.array([R + 500 * KM, 0, 0])])
    rb = np.stack([radial[1], oblique[1], np.array([-(R + 500 * KM), 0, 0])])
    assert oc.occulted(ra, rb).tolist() == [False, False, True]


def test_intervals():
    t = np.arange(10) * 0.5
    m = np.array([0, 1, 1, 0, 0, 1, 0, 0, 1, 1], bool)
    assert oc.intervals(t, m) == [(0.5, 1.0), (2.5, 0.5), (4.0, 0.5)]
    assert oc.intervals(t, np.zeros(10, bool)) == []
    assert oc.intervals(t, np.ones(10, bool)) == [(0.0, 4.5)]
    assert oc.intervals(t[:1], np.ones(1, bool)) == [(0.0, 0.0)]
    with pytest.raises(ValueError, match="one length"):
        oc.intervals(t, m[:5])


def test_summary_names_the_window_and_the_verdict():
    t = np.arange(4.0)
    ra = np.tile([R + 500 * KM, 0, 0], (4, 1))
    rb = np.array([[R + 900 * KM, 0, 0]] * 2 + [[-(R + 500 * KM), 0, 0]] * 2)
    mask, s = oc.summary(t, ra, rb, window=np.array([0, 0, 1, 1], bool))
    assert mask.tolist() == [False, False, True, True] and s["share"] == 0.5 and s["window_share"] == 1.0
    assert s["line_of_sight"] is False and s["intervals"] == [[2.0, 1.0]] and s["margin_km"] == 100.0
    _, s = oc.summary(t, ra, rb, window=np.array([1, 1, 1, 0], bool))
    assert s["line_of_sight"] is True and s["window_share"] == pytest.approx(1 / 3)
    _, s = oc.summary(t, ra, rb)                       # no window: blocked only when the whole run is
    assert s["line_of_sight"] is True and s["window_share"] is None


def test_the_pointing_passes_leave_occulted_samples_out():
    T, n = 100.0, 2501                                  # 250 s at 10 Hz: orbit 1 is whole
    rng = np.random.default_rng(0)
    hist = {"t": np.arange(n) / 10.0, "w_rel": np.zeros((n, 4))}
    dth, dom = rng.standard_normal((n, 2)) * 1e-4, rng.standard_normal((n, 2)) * 1e-5
    occ = (hist["t"] >= 150) & (hist["t"] < 175)
    dth[occ] *= 100                                     # what the Earth's shadow would hide
    mode10 = np.full(n, MODE_CODE["POINT"])
    flog = {"m_cmd": np.zeros((26, 3)), "h_w": np.zeros((26, 3)), "mtq_sat": np.zeros(26),
            "beacon_used": np.ones(26)}
    st = flight_world.flight_statistics(hist, dth, dom, mode10, T, flog, 1.0, np.eye(3), occ)
    p1 = st["passes"][0]
    clear = (hist["t"] >= 100) & (hist["t"] < 200) & ~occ
    assert p1["samples"] == clear.sum() and p1["occulted_samples"] == 250
    assert p1["pointing_3sigma_arcsec"] == pytest.approx(3 * np.hypot(*(dth[clear] / RAD_PER_ARCSEC).std(axis=0)))
    kept = flight_world.flight_statistics(hist, dth, dom, mode10, T, flog, 1.0, np.eye(3))["passes"][0]
    assert kept["pointing_3sigma_arcsec"] > 10 * p1["pointing_3sigma_arcsec"]


@pytest.mark.parametrize("name", ["thesis-3u", "generic-6u", "generic-12u"])
def test_the_shipped_partners_are_in_sight(name):
    """Each preset's partner (generic-12u's as bps.with_partner puts it) clears the Earth and its 100 km of
    atmosphere over three orbits (two-body): thesis-3u by 308 km at the least, the others by 517 and 567 km."""
    d = sf.load(name)
    if d["partner"] is None:
        d = bps.with_partner(d)
    o = scenario.orbit_setup(d)
    _, x = orbits.truth_samples("two-body", 3 * bps.orbit_period(o["x0s"][0]), x0s=o["x0s"],
                                epoch_utc=o["epoch_utc"], spacecraft=o["surface"])
    low = oc.clearance(x[:, 0, 0:3], x[:, 1, 0:3]).min()
    assert low > M + 100 * KM and not oc.occulted(x[:, 0, 0:3], x[:, 1, 0:3]).any()


def _far_side(tmp_path):
    """thesis-3u with its partner on the far side of the Earth: SatA's state negated (the same orbit half a
    revolution on, the same radius), so the line of sight goes through the Earth's centre all along."""
    d = json.load(open(sf.preset_path("thesis-3u")))
    s = d["orbit"]["state"]
    d["partner"]["position_m"] = [-v for v in s["position_m"]]
    d["partner"]["velocity_m_s"] = [-v for v in s["velocity_m_s"]]
    d["name"] = "thesis-3u-far-side"
    path = tmp_path / "far.json"
    path.write_text(json.dumps(d))
    params = tmp_path / "params.json"
    params.write_text(json.dumps(AdcsSession(runtime="inproc", world="flight", duration_s=5).params))
    return path, params


def _fly_far_side(tmp_path, world, duration_s):
    """``fps adcs bps`` with the far-side partner: (the finished process, its run folder); asserts it exits 3
    saying NO LINE OF SIGHT, without a traceback."""
    sc, params = _far_side(tmp_path)
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, "-m", "ground.cli", "adcs", "bps", "--world", world,
                        "--session" if world == "flight" else "--duration", str(duration_s), "--spacecraft", str(sc),
                        "--params", str(params), "--truth", "two-body",
                        "--quiet", "--no-plots", "--cache-dir", str(tmp_path / "cache"), "-o", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert p.returncode == 3, p.stderr
    assert "Traceback" not in p.stderr and "NO LINE OF SIGHT" in p.stderr
    return p, out


def test_a_partner_behind_the_earth_has_no_line_of_sight_and_exits_3(tmp_path):
    p, out = _fly_far_side(tmp_path, "flight", 200)
    assert "requirements met" not in p.stdout and "budgets met" not in p.stdout
    s = json.load(open(out / "summary.json"))
    assert s["budgets_met"] is False and s["line_of_sight"] is False and s["verdict"] == "no line of sight"
    o = s["occultation"]
    assert o["share"] == 1.0 and o["intervals"] == [[0.0, 200.0]] and o["margin_km"] == 100.0
    assert o["min_clearance_km"] < 0
    assert "Verdict: no line of sight" in (out / "report.md").read_text()
    h = np.load(out / "history.npz")
    assert h["occulted"].all() and len(h["occulted"]) == len(h["t"])


def test_the_thesis_world_marks_it_too(tmp_path):
    p, out = _fly_far_side(tmp_path, "thesis", 20)
    s = json.load(open(out / "summary.json"))
    assert s["budgets_met"] is False and s["line_of_sight"] is False and s["pointing_3sigma_arcsec"] is None


def test_the_beacon_camera_cannot_see_a_partner_behind_the_earth(tmp_path):
    """The emulated beacon answers "not in view" on every cycle the Earth hides the partner, and the flight
    software counts each as an invalid beacon; the shipped partner is never hidden."""
    sc, _ = _far_side(tmp_path)
    counts = []
    for d in (sf.load(str(sc)), sf.load("thesis-3u")):
        s = AdcsSession(runtime="inproc", world="flight", duration_s=20, spacecraft=d)
        s.start()
        try:
            for _ in range(s.K):
                s.cycle()
            out = s.summary()
        finally:
            s.close()
        counts.append((out["beacon_occulted_cycles"], out["firmware_missed"]["beacon_invalid"], out["cycles"]))
    (hid, invalid, n), (hid_ok, invalid_ok, _) = counts
    assert hid == n == 20 and invalid >= n - 2          # the first cycle or two come before the app reads it
    assert hid_ok == 0 and invalid_ok == 0


def test_a_preset_given_a_partner_is_a_spacecraft_file_again(tmp_path):
    """bps.with_partner's copy written out loads as a file (its name is still a valid one), partner and all."""
    d = bps.with_partner(sf.load("generic-12u"))
    path = tmp_path / "p.json"
    path.write_text(json.dumps(d))
    e = sf.load(str(path))
    assert e["name"] == "generic-12u-partner" and e["partner"]["position_m"] == d["partner"]["position_m"]
