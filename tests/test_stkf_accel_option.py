"""``--stkf-accel {white,markov}``: the flight STKF's form reaches the firmware's configuration
(``AdcsSession.config``) from every command that flies the flight world over the hpop truth, white leaves the
configurations as they are, a run records the form it flew, and the option is refused where it cannot apply."""

import json

import pytest

from emulator import adcs_session
from emulator.adcs_session import AdcsSession
from emulator.spacecraft import scenario
from ground import cli
from ground.adcs import app_host, bps_cli

STKF_KEYS = ("stkf_gravity", "stkf_qa", "stkf_accel", "stkf_sigma_a", "stkf_tau")


def _stkf(cfg):
    return {k: cfg[k] for k in STKF_KEYS if k in cfg}


def _flown(configs):
    """The distinct STKF configurations among ``configs``."""
    out = []
    for c in map(_stkf, configs):
        if c not in out:
            out.append(c)
    return out


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return str(tmp_path_factory.mktemp("stkf_accel_cache"))


@pytest.fixture(scope="module")
def params(tmp_path_factory):
    p = tmp_path_factory.mktemp("stkf_accel_params") / "params.json"
    p.write_text(json.dumps(AdcsSession(runtime="inproc", world="flight", duration_s=2).params))
    return str(p)


@pytest.fixture
def configs(monkeypatch):
    """Every ``AdcsSession.config`` the test's runs build, in order."""
    seen, real = [], AdcsSession.config

    def config(self):
        cfg = real(self)
        seen.append(cfg)
        return cfg
    monkeypatch.setattr(AdcsSession, "config", config)
    return seen


def test_one_source_for_the_forms():
    assert scenario.flight_stkf() is scenario.FLIGHT_STKF and scenario.flight_stkf("white") is scenario.FLIGHT_STKF
    assert scenario.FLIGHT_STKF_MARKOV == {"stkf_gravity": "j2", "stkf_accel": "markov", "stkf_sigma_a": 1e-4,
                                           "stkf_tau": 300.0}
    with pytest.raises(ValueError, match="stkf_accel must be one of white, markov"):
        scenario.flight_stkf("pink")


def test_the_session_configures_the_form_and_white_is_unchanged(cache):
    kw = dict(runtime="inproc", world="flight", truth="hpop", cache_dir=cache, duration_s=2)
    white, default = AdcsSession(stkf_accel="white", **kw).config(), AdcsSession(**kw).config()
    assert white == default and _stkf(default) == {"stkf_gravity": "j2", "stkf_qa": 5e-6}
    markov = AdcsSession(stkf_accel="markov", **kw).config()
    assert _stkf(markov) == scenario.FLIGHT_STKF_MARKOV
    assert {k: v for k, v in markov.items() if k not in STKF_KEYS} == \
        {k: v for k, v in default.items() if k not in STKF_KEYS}
    for world, truth in (("thesis", "two-body"), ("flight", "two-body"), ("thesis", "hpop")):
        assert _stkf(AdcsSession(runtime="inproc", world=world, truth=truth, cache_dir=cache,
                                 duration_s=2).config()) == {}
        with pytest.raises(ValueError, match="stkf_accel markov is the flight STKF's form over the hpop truth"):
            adcs_session._check_args("inproc", 2, 33.0, truth, "filtered", world, None, None, None, "markov")
    with pytest.raises(ValueError, match="stkf_accel must be one of"):
        AdcsSession(stkf_accel="pink", **kw)
    with pytest.raises(ValueError, match="stkf_accel markov: the ADCS PIL image"):
        adcs_session._check_args("qemu", 2, 33.0, "hpop", "filtered", "flight", None, None, None, "markov")


def test_bps_flight_flies_and_records_markov(tmp_path, params, cache, configs, capsys):
    out = tmp_path / "bps"
    rc = cli.main(["adcs", "bps", "--world", "flight", "--stkf-accel", "markov", "--session", "1", "--params",
                   params, "--truth", "hpop", "--quiet", "--no-plots", "--cache-dir", cache, "-o", str(out)])
    assert rc == 3                                        # one second: no pointing pass to judge
    assert _flown(configs) == [scenario.FLIGHT_STKF_MARKOV]
    s = json.load(open(out / "summary.json"))
    assert s["complete"] and s["stkf"] == {"accel": "markov", "gravity": "j2", "sigma_a": 1e-4, "tau": 300.0}
    assert "`--stkf-accel markov`" in (out / "report.md").read_text()
    assert "Traceback" not in capsys.readouterr().err
    configs.clear()
    rc = cli.main(["adcs", "bps", "--world", "flight", "--session", "1", "--params", params, "--truth", "hpop",
                   "--quiet", "--no-plots", "--cache-dir", cache, "-o", str(tmp_path / "white")])
    assert _flown(configs) == [scenario.FLIGHT_STKF]
    assert json.load(open(tmp_path / "white" / "summary.json"))["stkf"] == {"accel": "white", "gravity": "j2",
                                                                            "qa": 5e-6}


def test_can_flies_markov_over_hpop(tmp_path, cache, configs):
    out = tmp_path / "can"
    rc = cli.main(["adcs", "can", "--world", "flight", "--truth", "hpop", "--stkf-accel", "markov", "--session",
                   "3", "--runtime", "inproc", "--quiet", "--no-plots", "--cache-dir", cache, "-o", str(out)])
    assert rc == 0 and _flown(configs) == [scenario.FLIGHT_STKF_MARKOV]
    s = json.load(open(out / "summary.json"))
    assert s["truth"] == "hpop" and s["stkf"]["accel"] == "markov" and s["cycles"] == 3
    assert "`--stkf-accel markov`" in (out / "report.md").read_text()


def test_campaign_hands_the_form_to_each_vehicle(tmp_path, monkeypatch, configs):
    def calibration(seed, cache_dir, progress=True, spacecraft=None):      # a perfect one: no maneuvers
        return AdcsSession(runtime="inproc", world="flight", duration_s=2, spacecraft=spacecraft, seed=seed).params
    monkeypatch.setattr(bps_cli, "calibration", calibration)
    out = tmp_path / "campaign"
    rc = cli.main(["adcs", "campaign", "--runs", "1", "--workers", "1", "--orbits", "0.0004", "--truth", "hpop",
                   "--stkf-accel", "markov", "--quiet", "--no-plots", "-o", str(out)])
    assert rc == 3
    assert _stkf(configs[-1]) == scenario.FLIGHT_STKF_MARKOV
    s = json.load(open(out / "summary.json"))
    assert s["stkf_accel"] == "markov" and json.load(open(out / "campaign.json"))["stkf_accel"] == "markov"
    assert json.load(open(out / "run_0000" / "result.json"))["stkf"]["accel"] == "markov"
    md = (out / "report.md").read_text()
    assert "J2 model with its acceleration markov" in md and "--truth hpop --ts 33 --stkf-accel markov`" in md


def test_a_campaign_folder_without_the_key_resumes_as_white(tmp_path):
    from ground.adcs import population
    identity = {"format": "fps-adcs-campaign/1", "truth": "two-body"}
    population._open_folder(str(tmp_path / "c"), identity)
    population._open_folder(str(tmp_path / "c"), dict(identity, stkf_accel="white"))
    with pytest.raises(ValueError, match="differs in stkf_accel"):
        population._open_folder(str(tmp_path / "c"), dict(identity, stkf_accel="markov"))


def test_system_spec_reaches_both_adcs(tmp_path, params, cache, monkeypatch, configs):
    from ground.system import adcs as system_adcs, run
    d = scenario.thesis_3u()
    spec = run._spec("firmware", "inproc", False, 0, 33.0, "hpop", 1.0, json.load(open(params)), cache, None, d,
                     None, "flight", 0.0, "markov")
    assert run.spec_config(spec)["stkf_accel"] == "markov"
    assert "stkf_accel" not in run.spec_config(dict(spec, truth="two-body"))

    class Stop(Exception):
        pass

    class Session(AdcsSession):
        def start(self):
            self.config()
            raise Stop
    monkeypatch.setattr(adcs_session, "AdcsSession", Session)
    with pytest.raises(Stop):                             # --adcs firmware: the session over CAN
        system_adcs._send_firmware(dict(spec, adcs_duration_s=2.0), spec["params"], _Q(), None)
    monkeypatch.setattr(app_host, "AdcsSession", Session)
    with pytest.raises(Stop):                             # --adcs ground: the flight app in process
        system_adcs._ground_run(dict(spec, adcs="ground", adcs_duration_s=2.0), spec["params"])
    assert _flown(configs) == [scenario.FLIGHT_STKF_MARKOV] and len(configs) == 2


class _Q:
    def put(self, item):
        pass


@pytest.mark.parametrize("argv, why", [
    (["adcs", "bps", "--stkf-accel", "markov"], "the thesis world"),
    (["adcs", "bps", "--world", "flight", "--truth", "two-body", "--stkf-accel", "markov"], "two-body truth"),
    (["adcs", "bps", "--world", "flight", "--estimator", "ground", "--stkf-accel", "markov"], "--estimator ground"),
    (["adcs", "can", "--world", "flight", "--stkf-accel", "markov"], "two-body truth"),
    (["adcs", "can", "--truth", "hpop", "--stkf-accel", "white"], "the thesis world"),
    (["adcs", "campaign", "--stkf-accel", "markov"], "two-body truth"),
    (["system", "--truth", "two-body", "--stkf-accel", "markov"], "two-body truth"),
    (["system", "--world", "thesis", "--adcs", "ground", "--stkf-accel", "markov"], "the thesis world"),
    (["adcs", "can", "--world", "flight", "--truth", "hpop", "--runtime", "qemu", "--stkf-accel", "markov"],
     "the ADCS PIL image"),
    (["system", "--adcs", "firmware", "--runtime", "qemu", "--stkf-accel", "markov"], "the ADCS PIL image"),
])
def test_refused_where_it_cannot_apply(tmp_path, capsys, argv, why):
    out = tmp_path / "refused"
    rc = cli.main(argv + ["-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "--stkf-accel" in err and why in err and "Traceback" not in err, err
    assert not out.exists()


def test_an_unknown_form_is_argparse_s_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["adcs", "bps", "--world", "flight", "--stkf-accel", "pink", "-o", str(tmp_path / "x")])
    assert exc.value.code == 2 and "invalid choice: 'pink'" in capsys.readouterr().err


def test_the_commands_that_fly_the_flight_stkf_take_it_and_say_the_forms():
    from tests.test_cli_defaults import _options
    helps = _options("--stkf-accel")
    assert set(helps) == {"adcs bps", "adcs can", "adcs campaign", "system"}
    for c, a in helps.items():
        assert a.default is None and tuple(a.choices) == scenario.STKF_ACCELS, c
        assert all(w in a.help for w in ("white (default)", "m^2/s^3", "Gauss-Markov", "m/s^2", "300 s",
                                          "--truth hpop")), (c, a.help)
