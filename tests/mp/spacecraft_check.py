"""protocol.spacecraft under MicroPython and CPython alike: each preset's checked copy, inertia, principal moments
and wheel axes, and the checker's message on each bad input, one line each (tests/test_spacecraft_file.py runs
this script under both and compares the lines)."""

import json

from protocol import spacecraft as sc
from tests.mp.mutate import DELETE, copy, put


def canon(v):
    """A JSON value as text with sorted keys and repr floats (MicroPython's dicts keep no order)."""
    if isinstance(v, dict):
        return "{" + ", ".join("%s: %s" % (json.dumps(k), canon(v[k])) for k in sorted(v)) + "}"
    if isinstance(v, list):
        return "[" + ", ".join(canon(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(v)
    return json.dumps(v)


NAN = float("nan")
INF = float("inf")
BAD = (   # (label, [(key path, new value or DELETE), ...]) applied to thesis-3u
    ("not positive definite", [("inertia_kgm2", [0.012, 0.047, 0.045, 0.03, 0.0, 0.0])]),
    ("negative moment", [("inertia_kgm2", [-0.012, 0.047, 0.045, 0.0, 0.0, 0.0])]),
    ("triangle inequality", [("inertia_kgm2", [0.012, 0.047, 0.1, 0.0, 0.0, 0.0])]),
    ("wheels in a plane", [("wheels.nominal_axes", [[1, 0, 0], [0, 1, 0], [1, 1, 0], [1, -1, 0]])]),
    ("wheels on one axis", [("wheels.nominal_axes", [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1]])]),
    ("a zero wheel axis", [("wheels.nominal_axes.2", [0, 0, 0])]),
    ("rate limit 0", [("star_tracker.rate_limit_deg_s", 0)]),
    ("rate limit < 0", [("star_tracker.rate_limit_deg_s", -0.1)]),
    ("speed limit < 0", [("wheels.speed_limit_rpm", -5)]),
    ("missing key", [("wheels.tach_noise_rpm", DELETE)]),
    ("missing block", [("gyro", DELETE)]),
    ("unknown key", [("wheels.tach_noise", 10.0)]),
    ("unknown top-level key", [("colour", "red")]),
    ("NaN", [("inertia_kgm2.1", NAN)]),
    ("inf", [("wheels.torque_limit_nm", INF)]),
    ("-inf", [("star_tracker.sigma_arcsec.2", -INF)]),
    ("count a string", [("wheels.count", "4")]),
    ("count a fraction", [("wheels.count", 4.5)]),
    ("count beside 4 axes", [("wheels.count", 5)]),
    ("a bool for a number", [("mass_kg", True)]),
    ("an object for a vector", [("inertia_kgm2", {"Jxx": 0.012})]),
    ("a short vector", [("wheels.rotor_inertia_kgm2", [3e-06, 3e-06, 3e-06])]),
    ("format", [("format", "fps-spacecraft/2")]),
    ("name", [("name", "my craft")]),
    ("month 13", [("orbit.state.epoch_utc", "2016-13-19T03:24:57.4339")]),
    ("29 Feb 2017", [("orbit.state.epoch_utc", "2017-02-29T00:00:00")]),
    ("inside the Earth", [("orbit.state.position_m", [1000.0, 0.0, 0.0])]),
    ("true inertia", [("truth.inertia_error_kgm2", [-0.02, 0.0, 0.0, 0.0, 0.0, 0.0])]),
    ("true rotor inertia", [("truth.rotor_inertia_error_kgm2", [-4e-06, 0.0, 0.0, 0.0])]),
    ("true angle", [("wheels.delta1_deg", [10.0, 0.0, 0.0, 0.0]), ("truth.delta1_error_deg", [40.0, 0.0, 0.0, 0.0])]),
    ("relay delay", [("partner.relay_delay_s", [3.0, 2.0])]),
    ("unknown source", [("sources.wheels.colour", "a wheel's colour")]),
    ("magnetorquers in a plane", [("magnetorquers", {"axes": [[1, 0, 0], [0, 1, 0], [1, 1, 0]],
                                                     "dipole_limit_am2": 0.2})]),
    ("zero laser axis", [("laser_axis", [0, 0, 0])]),
    ("null block", [("surface", None)]),
    ("null partner", [("partner", None)]),
    ("no truth", [("truth", DELETE)]),
    ("no sources", [("sources", DELETE)]),
    ("integers", [("mass_kg", 4), ("wheels.speed_limit_rpm", 10000)]),
)


def main():
    print("presets", sc.presets())
    for name in sc.presets():
        d = sc.load(name)
        print(name, "checked", canon(d))
        print(name, "again", canon(sc.check(d)) == canon(d))
        print(name, "J", canon(sc.inertia_matrix(d)), canon(sc.inertia_matrix(d, True)))
        print(name, "principal", canon(sc.principal_moments(d["inertia_kgm2"])))
        print(name, "axes", canon(sc.wheel_axes(d)), canon(sc.wheel_axes(d, True)))
        print(name, "true", canon(sc.true_figures(d)))
        print(name, "epoch", canon(list(sc.epoch_tuple(d))))
    raw = sc.read(sc.preset_path("thesis-3u"))
    for label, changes in BAD:
        d = copy(raw)
        for path, value in changes:
            if path.startswith("sources."):
                d["sources"][path[8:]] = value          # a source's key is a key path: no splitting
            else:
                put(d, path, value)
        try:
            print("accepted", label, canon(sc.check(d)) == canon(sc.check(raw)))
        except ValueError as exc:
            print("refused", label, "|", str(exc))
    for bad in ([], "x", None, 3):
        try:
            sc.check(bad)
            print("accepted", canon(bad))
        except ValueError as exc:
            print("refused", str(exc))
    for name in ("no-such-preset", "/no/such/file.json"):
        try:
            sc.load(name)
            print("loaded", name)
        except ValueError as exc:
            print("refused", name, str(exc).split(" (")[0])


main()
