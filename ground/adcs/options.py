"""The options the ``fps adcs`` commands and ``fps system`` share, each defined once: the campaign options, the
spacecraft file (``--spacecraft``, ``load_spacecraft``), SatB's GNSS (``--satb-gnss``/``--no-satb-gnss``), the
flight STKF's form (``--stkf-accel``) and the emulated devices' faults (one option each, or ``--faults FILE``).
Below the commands that use them (``ground.adcs.cli`` registers those)."""

import argparse

from ground.adcs import runs
from ground.fileio import output_folder

def add_campaign_options(p, cases=True):
    """The options every campaign sub-command shares."""
    if cases:
        p.add_argument("--case", type=int, default=1, choices=(1, 2, 3),
                       help="disturbance: 1 none (default), 2 sinusoidal (Eq. 4.150), 3 attitude-dependent (Eq. 4.151)")
    p.add_argument("--runs", type=int, default=1, help="Monte Carlo runs (seeds), >= 1 (default 1; >= 20 for NEES)")
    p.add_argument("--seed", type=int, default=0, help="first seed, >= 0; run i uses seed + i (default 0)")
    add_workers_options(p)
    p.add_argument("--spacecraft", default=None, metavar="NAME|FILE",
                   help="the vehicle flown and filtered: a preset (%s) or a spacecraft file (fps spacecraft); "
                        "its truth block is the simulated vehicle's errors, its figures and uncertainty block the "
                        "filter's priors and initial P (default thesis-3u, the thesis's 3U)"
                        % ", ".join(_presets()))
    add_vehicle_option(p, "each run's vehicle from its own seed")
    p.add_argument("--params", default=None,
                   help="JSON of scenario overrides, not a spacecraft: %s. inertia_kgm2 and dipole_am2 replace "
                        "only the simulated (true) vehicle's, the filter keeps the spacecraft file's priors (a "
                        "diagnostic; refused with an explicit --spacecraft, whose truth block says the same)"
                        % "; ".join("%s: %s" % kv for kv in runs.PARAM_KEYS.items()))
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("-o", "--output", required=True, type=output_folder, help="campaign folder")


WINDOW_WORD = "collected"     # what every --duration's --help names: the window the statistics are collected over


def add_session_option(p, default, what):
    """``--session S`` on ``p`` (a parser or a group): the whole session in virtual seconds from power-on, where a
    command flies one; ``what``: its range, default and what it includes."""
    p.add_argument("--session", type=float, default=default, metavar="S",
                   help="the whole session from power-on in virtual seconds, %s" % what)


def check_session(session_s):
    """``--session`` (s) in [1, campaign.MAX_DURATION_S]; ValueError naming it otherwise (NaN included)."""
    from ground.adcs.campaign import MAX_DURATION_S
    if not 1 <= session_s <= MAX_DURATION_S:
        raise ValueError("--session must be in [1, %g] s, got %r" % (MAX_DURATION_S, session_s))
    return session_s


def refuse_option(p, option, why):
    """``option`` on ``p``, hidden from --help: given, the command exits 2 (argparse's error) with ``why``."""
    class Refused(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            parser.error("%s: %s" % (option_string, why))
    p.add_argument(option, action=Refused, default=argparse.SUPPRESS, help=argparse.SUPPRESS)


def add_stkf_accel_option(p, where):
    """``--stkf-accel {white,markov}``: the flight STKF's form (``scenario.flight_stkf``), given only where the
    flight world's STKF flies over the hpop truth (``where``: the command's words for it); None when not given."""
    from emulator.spacecraft.scenario import FLIGHT_STKF, FLIGHT_STKF_MARKOV, STKF_ACCELS
    p.add_argument("--stkf-accel", choices=STKF_ACCELS, default=None,
                   help="the flight STKF's acceleration beyond its J2 gravity model (%s): white (default) = white "
                        "noise of qa %g m^2/s^3 per axis; markov = a first-order Gauss-Markov state per satellite "
                        "and axis of 1 sigma %g m/s^2 and correlation time %g s (dynamic model compensation, about "
                        "1.1x white's CPU)" % (where, FLIGHT_STKF["stkf_qa"], FLIGHT_STKF_MARKOV["stkf_sigma_a"],
                                                FLIGHT_STKF_MARKOV["stkf_tau"]))


def check_stkf_accel(given, world, truth, estimator=None, runtime=None):
    """The form ``--stkf-accel`` flies ("white" when not given); ValueError naming the option when it is given where
    the flight STKF does not fly: outside the flight world, over a two-body truth (no J2: the thesis's two-body
    STKF flies), or with the ground's estimators (``estimator`` "ground": the full STKF, two-body); and markov on
    the ADCS PIL board (``runtime`` "qemu", ``AdcsSession``'s check)."""
    if given is None:
        return "white"
    if given != "white" and runtime == "qemu":
        from emulator.adcs_session import BOARD_STKF
        raise ValueError("--stkf-accel %s with --runtime qemu: %s" % (given, BOARD_STKF))
    why = ("the thesis world flies the thesis's two-body STKF (--world flight)" if world != "flight" else
           "a two-body truth has no J2, and the STKF keeps the thesis's two-body model (--truth hpop)"
           if truth != "hpop" else
           "--estimator ground flies the ground's full STKF, two-body" if estimator == "ground" else None)
    if why is not None:
        raise ValueError("--stkf-accel %s: the option chooses the flight STKF's form over its J2 model, which flies "
                         "in the flight world over the hpop truth; %s" % (given, why))
    return given


def add_workers_options(p):
    """``--workers N`` or ``--scheduler ADDR``: where a campaign's runs go (``ground.adcs.campaign``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: all cores; 1 = in-process)")
    g.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="Dask scheduler address (tcp://host:port): run on that cluster instead of locally")


def _presets():
    from protocol import spacecraft as sf
    return sf.presets()


def load_spacecraft(name_or_path, params=None, wheels=True, partner=False, flight=False):
    """(checked spacecraft file, what was given) for ``--spacecraft`` (None: thesis-3u). ValueError (exit 2)
    naming the option and the file, with the reader's or the checker's message, for a bad one, one whose
    wheels.count is not 4 (``wheels``: the APKF and the controllers fly four), one without a partner
    (``partner``: the STKF and the body pointing track one, ``scenario.orbit_setup``), one without magnetorquers
    (``flight``: the flight world's, ``flight_world.require_magnetorquers``), or when ``params`` also sets the
    true inertia or dipole."""
    from emulator.spacecraft import scenario
    from protocol import spacecraft as sf
    if name_or_path is not None and params and ({"inertia_kgm2", "dipole_am2"} & set(params)):
        raise ValueError("--params sets %s and --spacecraft %s says the vehicle too: give the true vehicle in the "
                         "spacecraft file's truth block, or drop --spacecraft"
                         % (" and ".join(sorted({"inertia_kgm2", "dipole_am2"} & set(params))), name_or_path))
    source = "thesis-3u" if name_or_path is None else name_or_path
    try:
        d = sf.load(source)
        if wheels and d["wheels"]["count"] != 4:
            raise ValueError("wheels.count = %d: the Sec. 4.8 scenario, the APKF and the controllers fly four "
                             "wheels" % d["wheels"]["count"])
        if partner:
            scenario.orbit_setup(d)
        if flight:
            from ground.adcs.flight_world import require_magnetorquers
            require_magnetorquers(d)
    except ValueError as exc:
        msg, head = str(exc), "spacecraft file %s: " % source
        raise ValueError("--spacecraft %s: %s" % (source, msg[len(head):] if msg.startswith(head) else msg)) from None
    return d, source


def add_satb_gnss_option(p, default):
    """``--satb-gnss`` / ``--no-satb-gnss`` (SatB's GNSS fixes relayed to SatA 2-3 s late), the same pair on every
    command that flies the body loop; ``default`` is the command's (the thesis's choice for what it reproduces)."""
    p.add_argument("--satb-gnss", action=argparse.BooleanOptionalAction, default=default,
                   help="SatB's GNSS fixes relayed to SatA 2-3 s late (Sec. 5.5), or not (default %s)"
                        % ("with them" if default else "without"))


def add_fault_options(p, clock):
    """The emulated spacecraft's device faults, one option each, and ``--faults FILE`` (a JSON object of the same
    keys: wheel_silent [wheel, t0], startracker_blind [t0, t1], gnss_outage [t0, t1], beacon_lost t0,
    magnetometer_silent t0, magnetorquer_dead [rod, t0]) for many at once; an option given overrides the file's
    entry. ``clock``: what the times count (said in --help's group title)."""
    g = p.add_argument_group("device faults (times: %s)" % clock)
    g.add_argument("--wheel-silent", default=None, metavar="I:T0", help="wheel I (0-3) stops answering at T0 s")
    g.add_argument("--startracker-blind", default=None, metavar="T0:T1", help="star tracker blind from T0 to T1 s")
    g.add_argument("--gnss-outage", default=None, metavar="T0:T1", help="no GNSS fix from T0 to T1 s")
    g.add_argument("--beacon-lost", type=float, default=None, metavar="T0", help="beacon out of view from T0 s")
    g.add_argument("--magnetometer-silent", type=float, default=None, metavar="T0",
                   help="the magnetometer stops answering at T0 s (flight world)")
    g.add_argument("--magnetorquer-dead", default=None, metavar="I:T0",
                   help="rod I's driver (0-2) dies at T0 s: no dipole, MTQ_TLM names it silent (flight world)")
    g.add_argument("--faults", default=None, metavar="FILE",
                   help="a JSON file of faults (the keys wheel_silent, startracker_blind, gnss_outage, beacon_lost, "
                        "magnetometer_silent, magnetorquer_dead as above, e.g. {\"startracker_blind\": [170, 230]}; "
                        "the object itself is taken too)")


def _window(text, name):
    try:
        a, b = text.split(":")
        return [float(a), float(b)]
    except ValueError:
        raise ValueError("--%s %r: expected T0:T1 in seconds" % (name, text)) from None


def _unit(text, name, unit, last):
    try:
        i, t0 = text.split(":")
        return [int(i), float(t0)]
    except ValueError:
        raise ValueError("--%s %r: expected %s:T0 (%s 0-%d, seconds)" % (name, text, unit.upper(), unit, last)) \
            from None


FAULTS_EXAMPLE = '{"startracker_blind": [170, 230]}'


def _faults_file(text):
    """(the faults of ``--faults``, where they were given): a JSON file (read by ``ground.fileio.read_json``:
    size-limited, not nested too deeply), or the JSON object itself. ValueError beginning with the option and
    the file."""
    from ground.fileio import parse_json, read_json
    from protocol.spacecraft import value_text
    if text.strip().startswith("{"):
        where = "--faults"
        try:
            f = parse_json(text, "--faults %s" % value_text(text.strip(), 60))
        except ValueError as exc:
            raise ValueError("%s; --faults must be a JSON object such as %s, or a file" % (exc, FAULTS_EXAMPLE)) \
                from None
    else:
        where = "--faults %s" % text
        f = read_json(text, "--faults")
    if not isinstance(f, dict):
        raise ValueError("%s: must be a JSON object such as %s, got %s" % (where, FAULTS_EXAMPLE, value_text(f, 40)))
    return f, where


def faults_from_args(a):
    """The faults ``add_fault_options`` took, as the session's dict (an ``emulator.adcs_bus.Faults``, which
    knows where each entry was given; None: none), each entry checked (``check_faults``). ValueError naming the
    option (and the file), the key and the value."""
    from emulator.adcs_bus import Faults, check_faults
    f, sources = {}, {}
    if a.faults is not None:
        f, where = _faults_file(a.faults)
        sources = dict.fromkeys(f, where)
    if a.wheel_silent:
        f["wheel_silent"] = _unit(a.wheel_silent, "wheel-silent", "wheel", 3)
        sources["wheel_silent"] = "--wheel-silent %s" % a.wheel_silent
    if a.magnetorquer_dead:
        f["magnetorquer_dead"] = _unit(a.magnetorquer_dead, "magnetorquer-dead", "rod", 2)
        sources["magnetorquer_dead"] = "--magnetorquer-dead %s" % a.magnetorquer_dead
    if a.startracker_blind:
        f["startracker_blind"] = _window(a.startracker_blind, "startracker-blind")
        sources["startracker_blind"] = "--startracker-blind %s" % a.startracker_blind
    if a.gnss_outage:
        f["gnss_outage"] = _window(a.gnss_outage, "gnss-outage")
        sources["gnss_outage"] = "--gnss-outage %s" % a.gnss_outage
    if a.beacon_lost is not None:
        f["beacon_lost"] = a.beacon_lost
        sources["beacon_lost"] = "--beacon-lost %g" % a.beacon_lost
    if a.magnetometer_silent is not None:
        f["magnetometer_silent"] = a.magnetometer_silent
        sources["magnetometer_silent"] = "--magnetometer-silent %g" % a.magnetometer_silent
    if not f:
        return None
    f = Faults(f, sources)
    check_faults(f, float("inf"))              # the run's span is checked by the run
    world = getattr(a, "world", "flight")
    for k in ("magnetometer_silent", "magnetorquer_dead"):
        if k in f and world != "flight":
            raise ValueError("%s: the %s world has no magnetic devices on the bus (--world flight)"
                             % (sources[k], world))
    return f


def add_spacecraft_option(p, what):
    """``--spacecraft NAME|FILE`` and ``--vehicle`` on ``p``; ``what``: what the command takes from the file."""
    p.add_argument("--spacecraft", default=None, metavar="NAME|FILE",
                   help="the vehicle: a preset (%s) or a spacecraft file (fps spacecraft); %s (default thesis-3u, "
                        "the thesis's 3U)" % (", ".join(_presets()), what))
    add_vehicle_option(p, "the vehicle from --seed")


def add_vehicle_option(p, drawn):
    """``--vehicle {file,drawn,nominal}`` (``emulator.spacecraft.dispersion``); ``drawn``: what a draw takes."""
    from emulator.spacecraft.dispersion import VEHICLES
    p.add_argument("--vehicle", default="file", choices=VEHICLES,
                   help="the simulated vehicle: file (default) = the spacecraft file's truth block (thesis-3u's: the "
                        "thesis's Sec. 4.8 errors), or, for a file without one, %s drawn within its uncertainty "
                        "block (inertia as a rigid body, wheel tilts, rotor inertias, dipole; never the file's own "
                        "figures, where the filters would start at the truth); drawn = drawn always; nominal = the "
                        "file's figures exactly (a diagnostic)" % drawn)


def fly(d, source, seed, vehicle):
    """(the spacecraft file a single run flies, its record for the summary: the file's ``spacecraft_record`` and
    the vehicle flown, ``emulator.spacecraft.dispersion.flown`` from ``seed``)."""
    from emulator.spacecraft import dispersion
    flown, rec = dispersion.flown(d, seed, vehicle)
    return flown, dict(runs.spacecraft_record(d, source), vehicle=rec)
