"""``fps spacecraft``: list, show, check and write spacecraft files; print their schema.

    fps spacecraft list                          the presets, one a line
    fps spacecraft show NAME|FILE [--json]       a preset or a file as a table (key, value, unit), or as JSON
    fps spacecraft check FILE|NAME               exit 0 "ok: ..." or 2 with the checker's message
    fps spacecraft template NAME -o FILE         write a preset to FILE to edit (- for standard output)
    fps spacecraft schema [--markdown | --json]  every key with its unit, range and meaning (docs/SPACECRAFT.md)

The schema and the checker are ``protocol.spacecraft`` (pure Python: the firmware runs the same checker).
"""

import argparse
import json
import sys

from protocol import spacecraft as sc
from protocol.fileio import output_file, write_atomic
from protocol.spacecraft import plausible

UNITS_HELP = ("Units are in the key names: _kg kg, _kgm2 kg m^2, _kgm kg m, _am2 A m^2, _nm N m, _nms_rad N m s/rad, "
              "_rpm rev/min, _arcsec arcseconds, _deg degrees, _deg_s deg/s, _deg_rt_h deg/sqrt(h), _deg_h deg/h, "
              "_hz Hz, _m metres, _m2 m^2, _m_s m/s, _km km, _nt nT, _s seconds; sigma = 1 standard deviation. "
              "Bad input (a missing or unknown key, a value out of range, NaN or inf, a non-physical inertia, "
              "wheels that do not span three axes, a figure implausible for the vehicle's size and mass: a unit "
              "slip) exits 2 naming the key, the value and the allowed range.")


def register(sub, name, help_):
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0].replace("``", "") + " " + UNITS_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=_usage())
    s = p.add_subparsers(dest="spacecraft_cmd", metavar="ACTION")
    s.required = True

    a = s.add_parser("list", help="list the presets")
    a.set_defaults(func=cmd_list)

    a = s.add_parser("show", help="print a preset or a file: key, value, unit", description=UNITS_HELP)
    a.add_argument("what", metavar="NAME|FILE", help="a preset name (fps spacecraft list) or a JSON file")
    a.add_argument("--json", action="store_true", help="the checked, normalised file as JSON instead")
    a.set_defaults(func=cmd_show)

    a = s.add_parser("check", help="check a file: exit 0 'ok', or 2 naming the key, value and allowed range",
                     description=UNITS_HELP)
    a.add_argument("what", metavar="FILE|NAME", help="a JSON spacecraft file (or a preset name)")
    a.set_defaults(func=cmd_check)

    a = s.add_parser("template", help="write a preset to a file to start your own from",
                     description="Write preset NAME, as shipped (its sources included), to FILE atomically. "
                                 + UNITS_HELP)
    a.add_argument("name", metavar="NAME", help="a preset: %s" % ", ".join(sc.presets()))
    a.add_argument("-o", "--output", required=True, metavar="FILE", type=output_file,
                   help="file to write (- for standard output)")
    a.set_defaults(func=cmd_template)

    a = s.add_parser("schema", help="every key with its unit, allowed range and meaning (docs/SPACECRAFT.md)")
    g = a.add_mutually_exclusive_group()
    g.add_argument("--markdown", action="store_true", help="markdown, as docs/SPACECRAFT.md (the default)")
    g.add_argument("--json", action="store_true", help="machine-readable: one object per key")
    a.set_defaults(func=cmd_schema)


def _usage():
    return "\n".join(line.strip() for line in __doc__.split("\n\n")[1].splitlines())


# --- actions ------------------------------------------------------------------------------------------------
def cmd_list(args):
    for n in sc.presets():
        d = sc.load(n)
        print("%-14s %s" % (n, d["description"].split(":")[0].split(". ")[0]))
    return 0


def cmd_show(args):
    d = sc.load(args.what)
    if args.json:
        print(json.dumps(d, indent=1))
    else:
        print(show_table(d))
    return 0


def cmd_check(args):
    d = sc.load(args.what)
    print("ok: %s: %s, %d wheels, inertia %s kg m^2 (principal %s), %s" % (
        args.what, d["name"], d["wheels"]["count"], sc.value_text(d["inertia_kgm2"]),
        sc.value_text([float("%.4g" % x) for x in sc.principal_moments(d["inertia_kgm2"])]),
        "with a truth block" if d["truth"] else "no truth block"))
    return 0


def cmd_template(args):
    path = sc.preset_path(args.name)
    with open(path) as f:
        text = f.read()
    sc.check(json.loads(text))                    # a preset is checked before it is handed out
    if args.output == "-":
        sys.stdout.write(text)
        return 0
    try:
        write_atomic(args.output, text, make_folder=False)
    except FileNotFoundError:
        raise ValueError("-o %s: its folder does not exist; make it first" % args.output) from None
    print("wrote %s (preset %s): replace its figures and sources with yours, then fps spacecraft check %s"
          % (args.output, args.name, args.output))
    return 0


def cmd_schema(args):
    if args.json:
        print(json.dumps(schema_rows(), indent=1))
    else:
        sys.stdout.write(schema_markdown())
    return 0


# --- show ---------------------------------------------------------------------------------------------------
def show_table(d):
    """The checked file ``d`` as a text table: key, value, unit (schema order), then what follows from it."""
    rows = [("key", "value", "unit")]
    for e in sc.SCHEMA:
        kind, path = e["kind"], e["path"]
        v = _get(d, path)
        if v is _ABSENT:
            continue
        if kind == "block":
            if v is None:
                rows.append((path, "null (none)", ""))
            continue
        if kind == "sources":
            continue
        if kind == "str" and path == "description":
            continue
        rows.append((path, sc.value_text(v, 200), "" if e["unit"] == "1" else e["unit"]))
    lam = sc.principal_moments(d["inertia_kgm2"])
    rows.append(("(principal moments)", sc.value_text([float("%.6g" % x) for x in lam]), "kg m^2"))
    for i, a in enumerate(sc.wheel_axes(d)):
        rows.append(("(wheel %d unit axis)" % i, sc.value_text([float("%.6f" % x) for x in a]), ""))
    if d["truth"]:
        t = sc.true_figures(d)
        rows.append(("(true inertia)", sc.value_text(t["inertia_kgm2"]), "kg m^2"))
        rows.append(("(true residual dipole)", sc.value_text(t["residual_dipole_am2"]), "A m^2"))
        rows.append(("(true rotor inertia)", sc.value_text(t["rotor_inertia_kgm2"]), "kg m^2"))
        for i, a in enumerate(sc.wheel_axes(d, True)):
            rows.append(("(true wheel %d unit axis)" % i, sc.value_text([float("%.6f" % x) for x in a]), ""))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    out = ["%s: %s" % (d["name"], d["description"]), ""]
    for i, (k, v, u) in enumerate(rows):
        out.append(("%-*s  %-*s  %s" % (w0, k, w1, v, u)).rstrip())
        if i == 0:
            out.append("%s  %s  %s" % ("-" * w0, "-" * w1, "-" * 6))
    if d["sources"]:
        out += ["", "sources:"] + ["  %s: %s" % (k, d["sources"][k]) for k in _schema_order(d["sources"])]
    return "\n".join(out)


_ABSENT = object()


def _get(d, path):
    for k in path.split("."):
        if not isinstance(d, dict) or k not in d:
            return _ABSENT
        d = d[k]
    return d


def _schema_order(keys):
    order = dict((e["path"], i) for i, e in enumerate(sc.SCHEMA))
    return sorted(keys, key=lambda k: order.get(k, len(order)))


# --- schema -------------------------------------------------------------------------------------------------
def _shape(e):
    n = e["n"]
    count = "wheels.count" if n == sc.WHEELS else str(n)
    return {"str": "string", "int": "whole number", "num": "number", "vec": "%s numbers" % count,
            "axes": "%s vectors [x, y, z]" % count, "epoch": "string (UTC)", "block": "object",
            "sources": "object: key path -> text"}[e["kind"]]


def schema_rows():
    """The schema as plain data: key, type, unit, allowed range, required, meaning."""
    rows = []
    for e in sc.SCHEMA:
        numeric = e["kind"] in ("int", "num", "vec", "axes")
        rows.append({"key": e["path"], "type": _shape(e) + (" or null" if e["nullable"] else ""),
                     "unit": e["unit"], "range": sc.range_text(e["range"]) if numeric else "",
                     "required": not e["optional"], "meaning": e["doc"]})
    return rows


def schema_markdown():
    """docs/SPACECRAFT.md: the spacecraft file's schema, generated from ``protocol.spacecraft.SCHEMA``."""
    return "\n".join(_schema_intro() + _schema_plausible() + _schema_keys())


def _schema_intro():
    """docs/SPACECRAFT.md's head: the commands, which commands take the file, units and conventions."""
    L = ["# The spacecraft file", "",
         "Generated by `fps spacecraft schema` from `protocol/spacecraft/schema.py`: do not edit by hand "
         "(`fps spacecraft schema > docs/SPACECRAFT.md` rewrites it; a test checks it is fresh).", "",
         "One JSON file describes one vehicle as its team knows it before flight; one checker "
         "(`protocol.spacecraft.check`, pure Python) serves the ground tools and the MicroPython firmware. "
         "Format `%s`." % sc.FORMAT, "",
         "```",
         "fps spacecraft list                          the presets",
         "fps spacecraft show NAME|FILE [--json]       key, value, unit",
         "fps spacecraft check FILE                    exit 0 \"ok: ...\", or 2 naming the key, value and range",
         "fps spacecraft template NAME -o FILE         a preset to start from",
         "fps spacecraft schema [--markdown | --json]  this page",
         "```", "",
         "## Commands that take it", "",
         "`--spacecraft NAME|FILE` (a preset or a file; default `thesis-3u`, with which every command gives the "
         "thesis's results bit for bit, as without the option; the APKF's consistent form adds the file's Jxx "
         "spread to its initial P, which the thesis holds exact):", "",
         "- `fps adcs apkf|mekf`: the Sec. 4.8 scenario's true vehicle (the figures plus the `truth` block: "
         "inertia, dipole, wheels, star tracker, gyro), the filters' model, priors and initial P (`uncertainty`).",
         "- `fps adcs stkf`: SatA's `orbit.state` and the `partner`'s state, the epoch, `mass_kg` and `surface` "
         "(the hpop truth), the `gnss` and `beacon` noise, `partner.relay_delay_s`, the STKF's P0 "
         "(`uncertainty.orbit_*`); with `--attitude apkf` the vehicle the APKF flies (the stated attitude "
         "covariance stays the thesis's APKF's).",
         "- `fps adcs bps|sweep` and `fps distfile generate --source bps`: the true vehicle, the orbits and "
         "sensors as `stkf`, the calibration maneuvers (truth, and the controller on the nominal figures), the "
         "APKF's model and priors, the STKF's P0, the controller's wheel torque limit and friction, the "
         "`laser_axis`; `--params` (a calibration's parameter file, `protocol.paramfile`) is checked against the "
         "wheels.",
         "- `fps adcs can` and `fps system`: the emulated vehicle as `bps`, the default parameter file (a perfect "
         "calibration of that vehicle, its P the thesis's final share of the file's `uncertainty`) and the "
         "firmware's configuration (nominal wheel axes, the wheels block its parameter file is checked against, "
         "torque limit, friction, read-out, star tracker, GNSS and beacon noise, the APKF's initial 1 σ, the "
         "STKF's P0, the laser axis).", "",
         "Refused (exit 2 naming the key): `wheels.count` other than 4 (the APKF, the parameter file and the "
         "controllers fly four), and a null `partner` for `stkf`, `bps`, `sweep`, `can` and `system`. Not "
         "followed yet: the sensors' `rate_hz` (the flight software runs at 1 Hz and samples each sensor then), "
         "`orbit.circular` (the Sec. 4.8 scenario and the calibration maneuvers fly the thesis's circular "
         "orbit), the wheels' imbalance (no jitter in these runs); in the thesis world (`--world thesis`) also "
         "`wheels.speed_limit_rpm` (the thesis's wheels have no limit; `bps` reports the largest speed), "
         "`magnetorquers`, `magnetometer` and `surface.cp_offset_m`. The flight world (`--world flight` of `bps`, "
         "`can` and `system`) flies those four: the wheels at their speed and torque limits, the magnetorquers "
         "(three rods along body x, y, z in the lean firmware) and the magnetometer on the bus, drag and solar "
         "pressure torques about the centre of pressure.", "",
         "## Units and conventions", "",
         UNITS_HELP, "",
         "- `inertia_kgm2` = [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz] about the centre of mass, body frame. The products are "
         "the inertia matrix's off-diagonal entries, Jxy = -∫ x y dm (CAD tools often print the product of inertia "
         "+∫ x y dm: change its sign). The spacecraft with its wheels, less the rotors' own inertia about their "
         "spin axes (the emulator's J). It must be a rigid body's: positive definite, and no principal moment "
         "larger than the sum of the other two (1e-9 relative slack).",
         "- Wheel axes (Yoon 2017, Eq. 4.58-4.60, 4.148): c_i = normalise(n_i + d1_i e1_i + d2_i e2_i), n_i the "
         "unit nominal axis, d1_i = `delta1_deg`, d2_i = `delta2_deg` in radians, e1_i = normalise(n_i × n_j) "
         "with j the next wheel in the list (the last's next is the first; if n_i × n_j vanishes, the body axis "
         "least aligned with n_i replaces n_j), e2_i = normalise(n_i × e1_i). The angles enter linearly as in the "
         "thesis: the axis tilts by atan(√(d1² + d2²)) (11.8° for 12°; the same to 0.1 %% below 3°). The unit "
         "axes (with the misalignment) must span three axes: the least eigenvalue of C Cᵀ at least %s." %
         sc.num_text(sc.SPAN_MIN),
         "- `uncertainty`: 1 σ of the figures, the filters' priors and initial covariance (the figure is the "
         "prior mean). Absolute, in the figure's unit.",
         "- `truth` (optional, simulation only): the simulated vehicle's departures from the figures, true = "
         "figure + error (the thesis's Sec. 4.8 errors for `thesis-3u`). A flight team leaves it out.",
         "- The simulated vehicle (`--vehicle`, every command that flies the body loop): `file` (the default) flies "
         "the `truth` block where there is one, and otherwise a vehicle drawn from the run's `--seed` within the "
         "`uncertainty` block (each figure's error Gaussian with its 1 σ: the inertia's six entries redrawn until "
         "they make a rigid body, each wheel's two tilts, each rotor inertia redrawn until positive, the dipole, "
         "the beacon camera's three misalignment angles; not the star tracker's, whose frame is the body's); never the file's own figures, where the "
         "filters would start at the truth. `drawn` draws even with a truth block; `nominal` flies the figures "
         "(a diagnostic). A campaign's runs each fly their own seed's vehicle; `--seed N` replays vehicle N; each "
         "result records the vehicle (`vehicle`: kind, seed, the truth block flown) "
         "(`emulator/spacecraft/dispersion.py`).",
         "- Misalignment angles, the file's and the truth's, are measured about the untilted nominal axes: a "
         "nominal tilt is the filters' prior and counts once.",
         "- `partner`, `magnetorquers`, `magnetometer` may be null (none); `partner`, `truth`, `sources`, "
         "`surface.cp_offset_m` (no drag or solar pressure torque) and the beacon camera's misalignment keys "
         "(zero: an aligned camera) may be left out. Every other key is required, and an unknown key is refused.",
         "- NaN and ±inf are refused everywhere; integers are accepted where a number is asked.", ""]
    return L


def _schema_plausible():
    """docs/SPACECRAFT.md's plausibility checks (``protocol.spacecraft.plausible``), with the presets' figures."""
    p, g = plausible, sc.num_text
    ratios = {"k": [], "rho": [], "rotor": [], "length": []}
    for n in sc.presets():
        d = sc.load(n)
        size = p.size_m(d)
        lam = sc.principal_moments(d["inertia_kgm2"])
        ratios["k"] += [(j / d["mass_kg"]) ** 0.5 / size for j in lam]
        ratios["rho"].append(d["mass_kg"] / size ** 3)
        ratios["rotor"].append(max(d["wheels"]["rotor_inertia_kgm2"]) / lam[0])
        ratios["length"] += [sum(x * x for x in d["surface"]["cp_offset_m"] or [0.0]) ** 0.5 / size,
                             d["wheels"]["arm_m"] / size]

    def span(k, digits):
        return "%s to %s" % tuple(g(float("%.*g" % (digits, f(ratios[k])))) for f in (min, max))
    return ["## Plausibility", "",
            "Within its range a figure may still be in the wrong unit (an inertia in g m^2 is 1000 times too large "
            "yet far below the schema's 1e4 kg m^2), and a flight then diverges without a word. After the ranges "
            "and the checks above, `check` compares the figures with each other and with the vehicle's size, and "
            "refuses a file no vehicle could have, naming the key, the value, the plausible range and the likely slip "
            "(`protocol/spacecraft/plausible.py`; its docstring gives the reasoning, from homogeneous boxes, "
            "J = m (b² + c²) / 12, and vehicles with deployed panels). The size is "
            "L = √max(`surface.drag_area_m2`, `surface.srp_area_m2`), the side of the larger area's square "
            "(%s m for `thesis-3u`). In order, the first failing check reported:" % g(float("%.3g" % (
                p.size_m(sc.load("thesis-3u"))))), "",
            "| check | plausible | catches | the presets |", "|---|---|---|---|",
            "| `mass_kg` / L³ | from %s to %s kg/m³ | a mass in g; areas in cm² | %s kg/m³ |"
            % (g(p.DENSITY_MIN), g(p.DENSITY_MAX), span("rho", 2)),
            "| each principal moment's radius of gyration k = √(J / `mass_kg`), of the inertia and of the true "
            "inertia (`truth`) | from max(%s L, %s m) to min(%s L, %s m) | an inertia in g m² or kg mm² (k × 31.6 or "
            "× 1000); a mass in g (k / 31.6) | %s L |" % (g(p.K_MIN_L), g(p.K_MIN_M), g(p.K_MAX_L), g(p.K_MAX_M),
                                                         span("k", 2)),
            "| each `wheels.rotor_inertia_kgm2`, and each true one | at most %s %% of the smallest principal moment "
            "| a rotor inertia in g m² | %s of it |" % (g(100 * p.ROTOR_SHARE_MAX), span("rotor", 2)),
            "| \\|`surface.cp_offset_m`\\| and `wheels.arm_m` | at most %s L | a length in mm or cm | %s L |"
            % (g(p.LENGTH_MAX_L), span("length", 2)), "",
            "The envelopes admit real CubeSats and small satellites with deployed panels (a homogeneous 3U's "
            "smallest k is 0.22 L, a 3U with 2 m² of wings 0.07 L; panels the areas leave out can raise the "
            "largest k to about 0.7 L) and still catch a factor 1000: the largest k of a real vehicle is above "
            "0.15 L, so × 31.6 lands above 3 L. A vehicle outside them (a gravity-gradient boom with a tip mass, "
            "a dual-spin rotor) is outside what this workbench flies.", ""]


def _schema_keys():
    """docs/SPACECRAFT.md's keys (``schema_rows``) and presets."""
    L = ["## Keys", "", "| key | type | unit | allowed range | meaning |", "|---|---|---|---|---|"]
    for r in schema_rows():
        depth = r["key"].count(".")
        key = "`%s`" % r["key"]
        opt = "" if r["required"] else " (optional)"
        L.append("| %s%s | %s | %s | %s | %s |" % ("&nbsp;&nbsp;" * depth, key, r["type"] + opt, r["unit"],
                                                 r["range"], r["meaning"].replace("|", "\\|")))
    L += ["", "## Presets", "", "| name | description |", "|---|---|"]
    for n in sc.presets():
        d = sc.load(n)
        L.append("| `%s` | %s |" % (n, d["description"]))
    L += ["", "Each preset names the source of every figure in its `sources` block (`fps spacecraft show NAME`)."
          " `thesis-3u` takes every figure from the thesis's constants in this repository's code (a test compares "
          "them), so the thesis's tables reproduce; `generic-6u` and `generic-12u` are representative vehicles "
          "with datasheet-class figures, not specific ones.", ""]
    return L
