"""Ground distfile tools: sources, 3rd-order Lagrange resampler (Sec. 7.3.1), generate/info/csv round trips."""

import numpy as np
import pytest

from ground import distfile_cli, resample, sources
from ground.cli import main as fps
from protocol import distfile


def test_lagrange3_exact_for_cubic_on_nonuniform_grid():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.05, 0.2, 60))
    f = lambda s: 0.3 * s ** 3 - 2.0 * s ** 2 + 5.0 * s - 7.0
    tq = np.linspace(t[0], t[-1], 777)
    np.testing.assert_allclose(resample.lagrange3(t, f(t), tq), f(tq), rtol=1e-10, atol=1e-8)


def test_lagrange3_not_exact_for_quartic():
    t = np.arange(20) * 0.1
    tq = t[:-1] + 0.05
    err = np.abs(resample.lagrange3(t, t ** 4, tq) - tq ** 4).max()
    assert err > 1e-6  # a 4-point stencil cannot be exact beyond cubics


def test_lagrange3_sine_error_matches_fourth_order():
    f = 0.5  # Hz, sampled at 10 Hz like the body pointing simulator
    errs = []
    for rate in (10.0, 20.0):
        t = np.arange(int(30 * rate) + 1) / rate
        tq = np.arange(0, 29.9, 0.008192)
        errs.append(np.abs(resample.lagrange3(t, np.sin(2 * np.pi * f * t), tq) - np.sin(2 * np.pi * f * tq)).max())
    assert errs[0] < 2e-3
    assert 10 < errs[0] / errs[1] < 22  # halving the step divides the error by ~2^4


def test_lagrange3_rejects_bad_input():
    with pytest.raises(ValueError, match="strictly increasing"):
        resample.lagrange3([0, 1, 1, 2], [0, 1, 2, 3], [0.5])
    with pytest.raises(ValueError, match="outside"):
        resample.lagrange3([0, 1, 2, 3], [0, 1, 2, 3], [3.5])
    with pytest.raises(ValueError, match="at least 4"):
        resample.lagrange3([0, 1, 2], [0, 1, 2], [0.5])


def test_stat_source_matches_body_pointing_table():
    src = sources.GaussMarkov2("gnss")
    t, x, y = src.generate(15000.0, seed=5)
    tab = sources.BODY_POINTING["gnss"]
    for ax, v in enumerate((x, y)):
        mean, sig = tab["theta"][ax]
        assert abs(v.mean() - mean) < 0.15 * sig
        assert abs(v.std() / sig - 1) < 0.1
        rate_sig = np.std(np.diff(v) * src.rate_hz)
        assert abs(rate_sig / tab["omega"][ax][1] - 1) < 0.1
    assert np.allclose(np.diff(t), 0.1)


def test_stat_source_reproducible_by_seed():
    a = sources.GaussMarkov2().generate(20.0, 7)[1]
    b = sources.GaussMarkov2().generate(20.0, 7)[1]
    c = sources.GaussMarkov2().generate(20.0, 8)[1]
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_generate_round_trip_and_period(tmp_path):
    out = tmp_path / "s.dist"
    assert fps(["distfile", "generate", "--source", "stat", "--duration", "30", "--seed", "1", "-o", str(out)]) == 0
    d, x, y = distfile_cli.load(str(out))
    assert d.period_us == 8192 and d.seed == 1 and d.source == "stat"
    assert d.count == int(np.ceil(30 / 0.008192)) + 1
    assert x.std() > 1 and y.std() > 1
    data = out.read_bytes()
    assert distfile.parse(data).sample(5) == pytest.approx((x[5], y[5]))


def test_sine_source_resampled_to_dist_step(tmp_path):
    out = tmp_path / "sine.dist"
    assert fps(["distfile", "generate", "--source", "sine", "--duration", "10", "--amp-arcsec", "50,20",
                "--freq-hz", "0.5,1", "--phase-deg", "0,90", "--sine-rate-hz", "50", "-o", str(out)]) == 0
    d, x, y = distfile_cli.load(str(out))
    t = np.arange(d.count) * 0.008192
    np.testing.assert_allclose(x, 50 * np.sin(2 * np.pi * 0.5 * t), atol=0.02)
    np.testing.assert_allclose(y, 20 * np.cos(2 * np.pi * 1.0 * t), atol=0.02)


def test_csv_round_trip_any_rate(tmp_path, capsys):
    src = tmp_path / "in.csv"
    t = np.sort(np.random.default_rng(0).uniform(0, 5, 200))
    t[0] = 0.0
    rows = ["t_s,x_arcsec,y_arcsec"] + ["%.12g,%.12g,%.12g" % (a, 2 * a + 1, -a * a) for a in t]
    src.write_text("\n".join(rows) + "\n")
    dist = tmp_path / "c.dist"
    assert fps(["distfile", "generate", "--source", "csv", "--csv", str(src), "--duration", "4",
                "-o", str(dist)]) == 0
    out = tmp_path / "out.csv"
    assert fps(["distfile", "csv", str(dist), "-o", str(out)]) == 0
    back = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(back[:, 1], 2 * back[:, 0] + 1, atol=1e-4)
    np.testing.assert_allclose(back[:, 2], -back[:, 0] ** 2, atol=1e-4)
    capsys.readouterr()
    assert fps(["distfile", "info", str(dist)]) == 0
    info = capsys.readouterr().out
    assert "source     csv" in info and "8192 us" in info


def test_refuses_samples_beyond_pfsm_range(tmp_path, capsys):
    limit = 3 * 3600 / 13.33
    assert distfile_cli.MAX_THETA_E_ARCSEC == pytest.approx(limit)
    out = tmp_path / "big.dist"
    rc = fps(["distfile", "generate", "--source", "sine", "--duration", "5", "--amp-arcsec", "%g,1" % (limit + 5),
              "--freq-hz", "1,1", "-o", str(out)])
    assert rc == 2 and not out.exists()            # bad input
    err = capsys.readouterr().err
    assert "beyond the P-FSM" in err and "810.2" in err
    distfile_cli.check_playable([limit - 0.01], [-limit + 0.01])  # inside: accepted


def test_refuses_malformed_distfiles(tmp_path, capsys):
    good = distfile.pack([0.0, 1.0, 2.0], [0.0, -1.0, -2.0])
    cases = {"crc": good[:-1] + bytes([good[-1] ^ 1]), "magic": b"XXXX" + good[4:], "short": good[:50]}
    for name, data in cases.items():
        p = tmp_path / (name + ".dist")
        p.write_bytes(data)
        assert fps(["distfile", "info", str(p)]) == 2
        assert str(p) in capsys.readouterr().err


@pytest.mark.parametrize("args, flag, owner", [
    (["--ts", "40"], "--ts", "bps"),                              # --source bps forgotten: a stat file was written
    (["--source", "stat", "--ts", "33"], "--ts", "bps"),          # given, though at bps's default
    (["--satb-gnss"], "--satb-gnss", "bps"),
    (["--source", "sine", "--stat-scale", "2"], "--stat-scale", "stat"),
    (["--source", "jitter", "--stat-scale", "2"], "--stat-scale", "stat"),   # without --jitter-base stat
    (["--source", "csv", "--amp-arcsec", "3,3"], "--amp-arcsec", "sine"),
    (["--jitter-rpm", "1,2,3,4"], "--jitter-rpm", "jitter")])
def test_an_option_of_another_source_is_refused_not_ignored(tmp_path, capsys, args, flag, owner):
    out = tmp_path / "x.dist"
    assert fps(["distfile", "generate", "--duration", "1", "-o", str(out)] + args) == 2 and not out.exists()
    err = capsys.readouterr().err
    assert "%s is an option of --source %s" % (flag, owner) in err and "Traceback" not in err


def test_the_jitter_takes_its_base_sources_options(tmp_path):
    out = tmp_path / "j.dist"
    assert fps(["distfile", "generate", "--source", "jitter", "--jitter-base", "sine", "--amp-arcsec", "7,7",
                "--freq-hz", "0.5,0.5", "--duration", "0.5", "--step-us", "1000", "-o", str(out)]) == 0
    d, x, _ = distfile_cli.load(str(out))
    assert 5 < np.abs(x).max() < 9                                 # the 7 arcsec sine under the jitter


def test_csv_source_errors_name_the_line(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("t_s,x,y\n0,1,2\n1,1,2\n0.5,1,2\n2,1,2\n3,1,2\n")
    with pytest.raises(ValueError, match="strictly increasing"):
        sources.CsvSource(str(p))
    p.write_text("0,1,2\n1,x,2\n")
    with pytest.raises(ValueError, match="line 2"):
        sources.CsvSource(str(p))


def test_source_registry_plugs_in_new_source(tmp_path):
    class Ramp:
        name = "ramp"

        @staticmethod
        def add_arguments(p):
            p.add_argument("--ramp-rate", type=float, default=1.0)

        @classmethod
        def from_args(cls, a):
            obj = cls()
            obj.rate = a.ramp_rate
            return obj

        def generate(self, duration_s, seed):
            t = np.arange(0, duration_s + 1, 0.1)
            return t, self.rate * t, -self.rate * t

    sources.register_source("ramp", Ramp)
    try:
        out = tmp_path / "r.dist"
        assert fps(["distfile", "generate", "--source", "ramp", "--ramp-rate", "2", "--duration", "3",
                    "-o", str(out)]) == 0
        d, x, y = distfile_cli.load(str(out))
        assert d.source == "ramp"
        np.testing.assert_allclose(x, 2 * np.arange(d.count) * 0.008192, atol=1e-4)
    finally:
        del sources.SOURCES["ramp"]
