"""``fps distfile generate | info | csv``: disturbance files for the P-FSM player (Sec. 7.3.1).

A source (``ground.sources``) produces body pointing error angles theta_e (X, Y, arcsec) at its own rate;
they are resampled to the 8.192 ms step by 3rd-order Lagrange interpolation and written in the distfile
format of ``protocol.distfile``. Samples the P-FSM cannot play are refused: the P-FSM tilts
13.33 theta_e (Eq. 7.7) within +-3 deg mechanical (+-10 V, Eq. 7.8), so |theta_e| <= 810.2 arcsec.
"""

import argparse
import math
import os
import sys

import numpy as np

from emulator.runtime import check_seed
from ground import resample, sources
from ground.fileio import check_not_input, output_file, read_input, write_atomic
from protocol import distfile

MAG_PFSM = 13.33                   # theta_P-FSM / theta_e, Eq. 7.7
PFSM_MAX_DEG = 3.0                 # P-FSM mechanical range, +-3 deg <-> +-10 V
MAX_THETA_E_ARCSEC = PFSM_MAX_DEG * 3600.0 / MAG_PFSM   # 810.2 arcsec
V_PER_ARCSEC = 10.0 / PFSM_MAX_DEG * MAG_PFSM / 3600.0  # 0.012343 V/arcsec, Eq. 7.8


def check_playable(x, y, period_us=resample.DIST_PERIOD_US):
    """Refuse (ValueError) the first sample beyond the P-FSM's range, naming it."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    bad = np.flatnonzero((np.abs(x) > MAX_THETA_E_ARCSEC) | (np.abs(y) > MAX_THETA_E_ARCSEC)
                         | ~np.isfinite(x) | ~np.isfinite(y))
    if bad.size:
        i = int(bad[0])
        with np.errstate(invalid="ignore"):
            peak = float(np.nanmax(np.abs(np.concatenate([x, y]))))
        excess = peak - MAX_THETA_E_ARCSEC
        raise ValueError("sample %d (t = %.3f s) = (%s, %s) arcsec is beyond the P-FSM's range: "
                         "|theta_e| <= %.1f arcsec (+-%g deg mechanical / %.2f, Eq. 7.7); %d samples out of "
                         "range, the largest |theta_e| %s arcsec passes the limit by %s arcsec (the P-FSM "
                         "would need %s deg, %s deg beyond its +-%g deg); not clipped"
                         % (i, i * period_us * 1e-6, _fx(x[i], 2), _fx(y[i], 2), MAX_THETA_E_ARCSEC, PFSM_MAX_DEG,
                            MAG_PFSM, bad.size, _fx(peak, 1), _fx(excess, 1), _fx(peak * MAG_PFSM / 3600.0, 3),
                            _fx(excess * MAG_PFSM / 3600.0, 3), PFSM_MAX_DEG))


def check_step(step_us):
    """The distfile step: a whole number of us (the format's period_us), not below the P-FSM period."""
    if not (math.isfinite(step_us) and step_us == int(step_us) and resample.MIN_STEP_US <= step_us <= 10_000_000):
        raise ValueError("--step-us %s: need a whole number of us from %d (the first at or above the P-FSM's "
                         "%.2f us period, 10.6 kHz) to 10000000" % (_num(step_us), resample.MIN_STEP_US,
                                                                   resample.PFSM_PERIOD_US))
    return int(step_us)


def _fx(v, decimals):
    """``v`` with ``decimals`` decimals, or in %g form when it is huge or not finite (a message stays short)."""
    v = float(v)
    return "%.*f" % (decimals, v) if abs(v) < 1e9 else "%.4g" % v


def _num(v):
    """A number for a message: 110, 110.5, inf or nan, never np.float64(110.0)."""
    v = float(v)
    return "%d" % v if math.isfinite(v) and v == int(v) and abs(v) < 1e15 else "%g" % v


def generate(source, duration_s, seed, source_name=None, period_us=resample.DIST_PERIOD_US):
    """Run ``source``, keep it from aliasing (``resample.antialias``), resample to the step ``period_us`` by
    3rd-order Lagrange interpolation: returns the distfile bytes."""
    period_us = check_step(period_us)
    if not 0 < duration_s < math.inf:
        raise ValueError("duration must be > 0 s and finite, got %s" % _num(duration_s))
    longest = (distfile.MAX_COUNT - 2) * period_us * 1e-6
    if duration_s > longest:
        raise ValueError("duration %s s is longer than a distfile holds (%d samples of %d us: %.0f s)"
                         % (_num(duration_s), distfile.MAX_COUNT, period_us, longest))
    check_seed(seed)
    if hasattr(source, "check_rate"):
        source.check_rate(period_us)
    name = source_name or getattr(source, "name", "user")
    t, x, y = source.generate(duration_s, seed)
    x, y, filtered = resample.antialias(t, x, y, period_us, "source %s" % name)
    xr, yr = resample.to_dist_step(t, x, y, duration_s, period_us)
    check_playable(xr, yr, period_us)
    if hasattr(source, "header_source"):      # a source that names its own parameters (bps)
        name = source.header_source()
    if filtered:
        name = name[:16 - len(resample.AA_TAG)] + resample.AA_TAG
    return distfile.pack(xr, yr, period_us=period_us, kind=distfile.KIND_FLOAT32, source=name, seed=int(seed))


def load(path):
    """Read and validate a distfile: (Distfile, x, y) with x, y numpy arrays in arcsec."""
    data = read_input(path, "distfile", distfile.HEADER_SIZE + distfile.SAMPLE_SIZE * distfile.MAX_COUNT
                      + distfile.CRC_SIZE, text=False)
    try:
        d = distfile.parse(data)
    except distfile.DistfileError as exc:
        raise ValueError("%s: %s" % (path, exc)) from None
    raw = np.frombuffer(data, dtype="<f4" if d.kind == distfile.KIND_FLOAT32 else "<i4",
                        count=2 * d.count, offset=distfile.HEADER_SIZE).reshape(-1, 2).astype(float)
    if d.kind == distfile.KIND_INT32:
        raw *= d.scale
    return d, raw[:, 0].copy(), raw[:, 1].copy()


def stats(x, y):
    r = np.hypot(x, y)
    return {"mean_arcsec": [float(x.mean()), float(y.mean())], "std_arcsec": [float(x.std()), float(y.std())],
            "min_arcsec": [float(x.min()), float(y.min())], "max_arcsec": [float(x.max()), float(y.max())],
            "max_radial_arcsec": float(r.max()),
            "pfsm_peak_v": [float(np.abs(x).max() * V_PER_ARCSEC), float(np.abs(y).max() * V_PER_ARCSEC)]}


def _cmd_generate(a):
    check_source_options(a)
    inputs = [("--csv", getattr(a, "csv_path", None)), ("--params", getattr(a, "params", None))]
    for path in (a.output, inputs_sidecar(a.output), a.output + ".jitter.json"):     # the file and its sidecars
        check_not_input(path, inputs)
        if os.path.isdir(path):
            raise ValueError("-o %s: %s is a folder, where the distfile or its sidecar goes" % (a.output, path))
    src = sources.get_source(a.source).from_args(a)
    if a.source == "csv" and a.seed_given:
        raise ValueError("--seed: the csv source takes no seed (its samples are the file's); leave --seed out")
    data = generate(src, a.duration, a.seed if a.seed_given or a.source != "csv" else 0, a.source,
                    period_us=check_step(a.step_us))
    write_atomic(a.output, data)
    if getattr(src, "inputs", None) is not None:          # the source's parameters in full, beside the file
        from ground.fileio import write_json
        write_json(inputs_sidecar(a.output), dict(src.inputs, from_cache=bool(getattr(src, "from_cache", False))))
        print("source parameters in %s%s" % (inputs_sidecar(a.output), " (run taken from the cache)"
                                             if getattr(src, "from_cache", False) else ""))
    d, x, y = load(a.output)
    s = stats(x, y)
    side = a.output + ".jitter.json"
    if a.source == "jitter":
        write_jitter_sidecar(side, src, d, x, y)
    elif os.path.exists(side):
        os.unlink(side)             # a stale sidecar would describe another file
    print("wrote %s: %d samples at %d us (%s s), source %s%s; 1-sigma (%.2f, %.2f) arcsec, "
          "peak P-FSM (%.2f, %.2f) V" % (a.output, d.count, d.period_us, "%.4g" % (d.duration_us() * 1e-6),
                                          d.source, "" if a.source == "csv" else ", seed %d" % d.seed,
                                          s["std_arcsec"][0], s["std_arcsec"][1], *s["pfsm_peak_v"]))
    return 0


def write_jitter_sidecar(path, src, d, x, y):
    """The wheel harmonics of a jitter distfile (``path`` = F.jitter.json): frequencies, amplitudes in the file
    and the player's gain on each (``resample.player_gain``, Keys's 6-point kernel); printed too."""
    import json
    t = np.arange(d.count) * d.period_us * 1e-6
    amp = src.harmonics(t, x, y)
    side = {"wheel_rpm": src.rpm.tolist(), "wheel_hz": src.wheel_hz.tolist(), "file_amp_arcsec": amp.tolist(),
            "player_gain": resample.player_gain(src.wheel_hz, d.period_us).tolist(), "period_us": d.period_us,
            "jitter_scale": src.scale}
    write_atomic(path, (json.dumps(side, indent=2) + "\n").encode())
    print("wheel harmonics (arcsec in the file, X / Y; the player plays them x its kernel's gain):")
    for f, (ax, ay), g in zip(side["wheel_hz"], amp, side["player_gain"]):
        print("  %8.3f Hz  %.4f / %.4f  x%.4f" % (f, ax, ay, g))
    print("wrote %s" % path)


def _cmd_info(a):
    d, x, y = load(a.file)
    s = stats(x, y)
    kind = "float32" if d.kind == distfile.KIND_FLOAT32 else "int32 x %g arcsec" % d.scale
    print("file       %s (%d bytes)" % (a.file, os.path.getsize(a.file)))
    print("version    %d" % d.version)
    print("source     %s, seed %d" % (d.source, d.seed))
    for line in source_input_lines(a.file, d):
        print(line)
    print("samples    %d x (x, y) %s, theta_e in arcsec" % (d.count, kind))
    print("period     %d us (%.3f Hz), duration %.3f s" % (d.period_us, 1e6 / d.period_us, d.duration_us() * 1e-6))
    print("           %12s %12s" % ("X", "Y"))
    for key in ("mean_arcsec", "std_arcsec", "min_arcsec", "max_arcsec", "pfsm_peak_v"):
        print("%-10s %12.4f %12.4f" % (key, s[key][0], s[key][1]))
    print("max radial %.4f arcsec (P-FSM limit %.1f arcsec per axis)" % (s["max_radial_arcsec"],
                                                                         MAX_THETA_E_ARCSEC))
    for line in bandwidth_lines(d):
        print(line)
    return 0


def inputs_sidecar(path):
    """Where ``generate`` writes the inputs in full of a source that names them (``inputs``) beside distfile
    ``path``."""
    return path + ".json"


def source_input_lines(path, d):
    """The source's inputs in full from the sidecar (``inputs_sidecar``) of a distfile whose registered source
    can tell its own (``describes(header_source, seed, inputs)``: bps, whose 16-byte header holds
    ``bps<ts><g|n>`` and the inputs' hash), when the sidecar is this file's; a line saying so when it is
    missing, unreadable or another file's."""
    owner = next((c for n, c in sources.SOURCES.items() if hasattr(c, "describes") and d.source.startswith(n)),
                 None)
    if owner is None:
        return []
    import json
    from ground.fileio import read_json
    side = inputs_sidecar(path)
    if not os.path.lexists(side):
        return ["inputs     %s is missing: the header's hash names the inputs, not shown here" % side]
    try:
        inputs = read_json(side, "sidecar")          # size-limited: a sidecar is a few hundred bytes
    except ValueError as exc:
        return ["inputs     unreadable, not shown: %s" % exc]
    if not owner.describes(d.source, d.seed, inputs):
        return ["inputs     %s is another file's (its hash is not this header's): not shown" % side]
    unhashed = getattr(owner, "UNHASHED", ())       # the sidecar's notes the header's hash does not cover
    lines = ["inputs     " + ", ".join("%s %s" % (k, json.dumps(v)) for k, v in inputs.items()
                                      if k != "source" and k not in unhashed)]
    notes = [(k, inputs[k]) for k in unhashed if k in inputs]
    if notes:
        lines.append("notes      " + ", ".join("%s %s" % (k, json.dumps(v)) for k, v in notes)
                     + " (not covered by the header's hash: as the sidecar says)")
    return lines


def bandwidth_lines(d):
    """What the file can hold and what the player makes of it (``fps distfile info``)."""
    ts = d.period_us
    nyq = resample.nyquist_hz(ts)
    fs = 1e6 / ts
    out = ["nyquist    %.3f Hz (half the file's rate): content above it cannot be in the file" % nyq]
    if d.source.endswith(resample.AA_TAG):
        out.append("anti-alias Butterworth order %d at %.3f Hz (%.1f x Nyquist), forward and backward (zero phase), "
                   "applied before resampling: x%.4f at 0.5 Nyquist, x%.4f at %.3f Hz, x%.4f at Nyquist"
                   % (resample.AA_ORDER, resample.AA_FRACTION * nyq, resample.AA_FRACTION,
                      resample.antialias_gain(0.5 * nyq, ts), resample.antialias_gain(resample.AA_FRACTION * nyq, ts),
                      resample.AA_FRACTION * nyq, resample.antialias_gain(nyq, ts)))
    else:
        out.append("anti-alias none needed: the source was no faster than the file (or a sine checked against "
                   "its Nyquist)")
    out.append("player     Keys 6-point cubic interpolation (firmware/player.py) plays a tone f at G(f x %d us) and "
               "adds images" % ts)
    out.append("           at %.3f Hz -+ f (then the AD660 holds each code for 1/10.6 kHz; the thesis's linear "
               "interpolation played sinc^2):" % fs)
    out.append("           %10s %10s %12s %10s %12s %10s" % ("f (Hz)", "gain", "image (Hz)", "gain", "image (Hz)",
                                                             "gain"))
    for k in (0.05, 0.25, 0.5, 0.75, 0.9):
        f = k * nyq
        out.append("           %10.3f %10.4f %12.3f %10.4f %12.3f %10.4f"
                   % (f, resample.player_gain(f, ts), fs - f, resample.player_gain(fs - f, ts), fs + f,
                      resample.player_gain(fs + f, ts)))
    return out


def _cmd_csv(a):
    check_not_input(a.output, [("the distfile", a.file)])
    d, x, y = load(a.file)
    t = np.arange(d.count) * (d.period_us * 1e-6)
    lines = ["t_s,x_arcsec,y_arcsec"] + ["%.6f,%.6f,%.6f" % r for r in zip(t, x, y)]
    if a.output in (None, "-"):
        sys.stdout.write("\n".join(lines) + "\n")
    else:
        write_atomic(a.output, ("\n".join(lines) + "\n").encode())
        print("wrote %s (%d samples)" % (a.output, d.count))
    return 0


class _Group:
    """An argument group that keeps the options a source adds to it, each without a parsed default, so that
    ``check_source_options`` sees which were given (it then puts the defaults in)."""

    def __init__(self, group):
        self.group, self.actions = group, []

    def add_argument(self, *args, **kw):
        default = kw.get("default", {"store_true": False, "store_false": True}.get(kw.get("action")))
        kw["default"] = argparse.SUPPRESS
        act = self.group.add_argument(*args, **kw)
        self.actions.append((act, default))
        return act


def source_options(parser):
    """Add each source's options to ``parser``, one --help group per source; returns {source: [(flag, dest,
    default)]} for ``check_source_options``."""
    out = {}
    for name, cls in sources.SOURCES.items():
        grp = _Group(parser.add_argument_group("--source %s" % name))
        cls.add_arguments(grp)
        out[name] = [([o for o in act.option_strings if o.startswith("--")][0], act.dest, default)
                     for act, default in grp.actions]
    return out


def check_source_options(a):
    """Put in the defaults of the sources' options not given, and refuse (ValueError naming it) one given with
    another source (``--ts 33`` without ``--source bps``: a stat file would be written, as if --ts had been
    taken). A source's ``bases(a)`` names the other sources whose options it uses (the jitter's
    --jitter-base)."""
    given = set(vars(a))
    for opts in a.source_options.values():
        for flag, dest, default in opts:
            if dest not in given:
                setattr(a, dest, default)
    cls = sources.get_source(a.source)
    used = {a.source} | set(cls.bases(a) if hasattr(cls, "bases") else ())
    for name, opts in a.source_options.items():
        for flag, dest, default in opts:
            if name not in used and dest in given:
                raise ValueError("%s is an option of --source %s, which this run does not use (its sources: %s): "
                                 "leave it out, or give --source %s" % (flag, name, ", ".join(sorted(used)), name))


def _seeded(fn):
    def run(a):
        a.seed_given = a.seed is not None
        if a.seed is None:
            a.seed = 1
        return fn(a)
    return run


def register(sub, name, help_):
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0])
    s = p.add_subparsers(dest="distfile_cmd", metavar="ACTION")
    g = s.add_parser("generate", help="generate a distfile from a source")
    g.add_argument("--source", default="stat", choices=sorted(sources.SOURCES), help="disturbance source (default stat)")
    g.add_argument("--duration", type=float, default=600.0, help="the seconds collected into the file, "
                   "the window of its statistics (fps hil plays up to them; default 600)")
    g.add_argument("--seed", type=int, default=None,
                   help="random seed (default 1; not for --source csv, which has no randomness)")
    g.add_argument("--step-us", type=float, default=resample.DIST_PERIOD_US,
                   help="distfile step in whole us, from 95 (the P-FSM's 94.3 us period) up (default %d, the "
                        "thesis's 8.192 ms: Nyquist 61 Hz)" % resample.DIST_PERIOD_US)
    g.add_argument("-o", "--output", required=True, type=output_file, help="distfile to write")
    g.set_defaults(func=_seeded(_cmd_generate), source_options=source_options(g))
    i = s.add_parser("info", help="print the header and statistics")
    i.add_argument("file")
    i.set_defaults(func=_cmd_info)
    c = s.add_parser("csv", help="export to CSV (t_s, x_arcsec, y_arcsec)")
    c.add_argument("file")
    c.add_argument("-o", "--output", type=output_file, help="CSV to write (default stdout)")
    c.set_defaults(func=_cmd_csv)
    p.set_defaults(func=lambda a: p.print_help() or 2)
