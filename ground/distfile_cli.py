"""``fps distfile generate | info | csv``: disturbance files for the P-FSM player (Sec. 7.3.1).

A source (``ground.sources``) produces body pointing error angles theta_e (X, Y, arcsec) at its own rate;
they are resampled to the 8.192 ms step by 3rd-order Lagrange interpolation and written in the distfile
format of ``protocol.distfile``. Samples the P-FSM cannot play are refused: the P-FSM tilts
13.33 theta_e (Eq. 7.7) within +-3 deg mechanical (+-10 V, Eq. 7.8), so |theta_e| <= 810.2 arcsec.
"""

import math
import os
import sys

import numpy as np

from ground import resample, sources
from ground.fileio import write_atomic
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
        raise ValueError("sample %d (t = %.3f s) = (%.2f, %.2f) arcsec is beyond the P-FSM's range: "
                         "|theta_e| <= %.1f arcsec (+-%g deg mechanical / %.2f, Eq. 7.7); %d samples out of "
                         "range, the largest |theta_e| %.1f arcsec passes the limit by %.1f arcsec (the P-FSM "
                         "would need %.3f deg, %.3f deg beyond its +-%g deg); not clipped"
                         % (i, i * period_us * 1e-6, x[i], y[i], MAX_THETA_E_ARCSEC, PFSM_MAX_DEG, MAG_PFSM,
                            bad.size, peak, excess, peak * MAG_PFSM / 3600.0, excess * MAG_PFSM / 3600.0,
                            PFSM_MAX_DEG))


def generate(source, duration_s, seed, source_name=None):
    """Run ``source`` and resample to the distfile step: returns the distfile bytes."""
    if not 0 < duration_s < math.inf:
        raise ValueError("duration must be > 0 s and finite, got %r" % duration_s)
    longest = (distfile.MAX_COUNT - 2) * resample.DIST_PERIOD_US * 1e-6
    if duration_s > longest:
        raise ValueError("duration %g s is longer than a distfile holds (%d samples of %d us: %.0f s)"
                         % (duration_s, distfile.MAX_COUNT, resample.DIST_PERIOD_US, longest))
    if not 0 <= seed <= 0xFFFFFFFF:
        raise ValueError("seed %r out of range [0, 2**32-1]" % seed)
    t, x, y = source.generate(duration_s, seed)
    xr, yr = resample.to_dist_step(t, x, y, duration_s)
    check_playable(xr, yr)
    if hasattr(source, "header_source"):      # a source that names its own parameters (bps)
        source_name = source.header_source()
    return distfile.pack(xr, yr, period_us=resample.DIST_PERIOD_US, kind=distfile.KIND_FLOAT32,
                         source=source_name or getattr(source, "name", "user"), seed=int(seed))


def load(path):
    """Read and validate a distfile: (Distfile, x, y) with x, y numpy arrays in arcsec."""
    with open(path, "rb") as f:
        data = f.read()
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
    src = sources.get_source(a.source).from_args(a)
    data = generate(src, a.duration, a.seed, a.source)
    write_atomic(a.output, data)
    if getattr(src, "inputs", None) is not None:          # the source's parameters in full, beside the file
        from ground.fileio import write_json
        write_json(a.output + ".json", dict(src.inputs, from_cache=bool(getattr(src, "from_cache", False))))
        print("source parameters in %s.json%s" % (a.output, " (run taken from the cache)"
                                                    if getattr(src, "from_cache", False) else ""))
    d, x, y = load(a.output)
    s = stats(x, y)
    print("wrote %s: %d samples at %d us (%.1f s), source %s, seed %d; 1-sigma (%.2f, %.2f) arcsec, "
          "peak P-FSM (%.2f, %.2f) V" % (a.output, d.count, d.period_us, d.duration_us() * 1e-6, d.source,
                                          d.seed, s["std_arcsec"][0], s["std_arcsec"][1], *s["pfsm_peak_v"]))
    return 0


def _cmd_info(a):
    d, x, y = load(a.file)
    s = stats(x, y)
    kind = "float32" if d.kind == distfile.KIND_FLOAT32 else "int32 x %g arcsec" % d.scale
    print("file       %s (%d bytes)" % (a.file, os.path.getsize(a.file)))
    print("version    %d" % d.version)
    print("source     %s, seed %d" % (d.source, d.seed))
    print("samples    %d x (x, y) %s, theta_e in arcsec" % (d.count, kind))
    print("period     %d us (%.3f Hz), duration %.3f s" % (d.period_us, 1e6 / d.period_us, d.duration_us() * 1e-6))
    print("           %12s %12s" % ("X", "Y"))
    for key in ("mean_arcsec", "std_arcsec", "min_arcsec", "max_arcsec", "pfsm_peak_v"):
        print("%-10s %12.4f %12.4f" % (key, s[key][0], s[key][1]))
    print("max radial %.4f arcsec (P-FSM limit %.1f arcsec per axis)" % (s["max_radial_arcsec"],
                                                                         MAX_THETA_E_ARCSEC))
    return 0


def _cmd_csv(a):
    d, x, y = load(a.file)
    t = np.arange(d.count) * (d.period_us * 1e-6)
    lines = ["t_s,x_arcsec,y_arcsec"] + ["%.6f,%.6f,%.6f" % r for r in zip(t, x, y)]
    if a.output in (None, "-"):
        sys.stdout.write("\n".join(lines) + "\n")
    else:
        write_atomic(a.output, ("\n".join(lines) + "\n").encode())
        print("wrote %s (%d samples)" % (a.output, d.count))
    return 0


def register(sub, name, help_):
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0])
    s = p.add_subparsers(dest="distfile_cmd", metavar="ACTION")
    g = s.add_parser("generate", help="generate a distfile from a source")
    g.add_argument("--source", default="stat", choices=sorted(sources.SOURCES), help="disturbance source")
    g.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    g.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    g.add_argument("-o", "--output", required=True, help="distfile to write")
    for cls in sources.SOURCES.values():
        cls.add_arguments(g)
    g.set_defaults(func=_cmd_generate)
    i = s.add_parser("info", help="print the header and statistics")
    i.add_argument("file")
    i.set_defaults(func=_cmd_info)
    c = s.add_parser("csv", help="export to CSV (t_s, x_arcsec, y_arcsec)")
    c.add_argument("file")
    c.add_argument("-o", "--output", help="CSV to write (default stdout)")
    c.set_defaults(func=_cmd_csv)
    p.set_defaults(func=lambda a: p.print_help() or 2)
