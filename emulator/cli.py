"""``fps emulator``: the bench emulator's command line.

- ``config``  print the default bench config ("thesis bench" preset) as JSON
- ``truth-h`` write the true H field over the Sec. 7.4 grid (calibration JSON shape)
- ``serve``   serve the bench (lockstep, the emulator owns time) or the reaction wheels and star tracker
  (``--devices wheels``, paced by the wall clock) on a link
"""

import math
import os
import sys

from emulator.runtime import check_seed
from protocol.fileio import output_file


def register(sub, name, help_):
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0])
    cmds = p.add_subparsers(dest="emulator_cmd", metavar="CMD")

    c = cmds.add_parser("config", help="print the default bench config (JSON)")
    c.add_argument("--config", help="validate and print this config file merged over the preset instead")
    c.set_defaults(func=_config)

    t = cmds.add_parser("truth-h", help="true H field over the P-FSM grid (Sec. 7.4) as calibration JSON")
    t.add_argument("--grid", type=int, default=11, help="grid points per axis over -5..+5 V (default 11)")
    t.add_argument("--dv", type=float, default=0.01, help="FSM perturbation in V (default 0.01)")
    t.add_argument("--config", help="bench config JSON (default: the thesis bench preset)")
    t.add_argument("-o", "--output", required=True, type=output_file, help="output JSON file")
    t.set_defaults(func=_truth_h)

    s = cmds.add_parser("serve", help="serve the bench or the wheels on a link; the flight software connects to it")
    s.add_argument("--devices", default="bench", choices=("bench", "wheels"),
                   help="bench: the optical bench in lockstep (default); wheels: RW0..RW3 and STARTRACKER of the "
                        "spacecraft emulator, paced by the wall clock")
    s.add_argument("--link", default="serial", choices=("serial", "can"),
                   help="serial (default): a pseudo-terminal pair (prints the slave path); can: slcan over a pty")
    s.add_argument("--seed", type=int, default=0, help="the emulator's seed, >= 0 (default 0)")
    s.add_argument("--duration", type=float,
                   help="the seconds collected: the run its summary covers (bench: virtual, default 10, at most what "
                        "80 %% of this machine's memory holds at ~400 B a tick; wheels: wall = virtual, default "
                        "until stopped)")
    s.add_argument("--wait", type=float, default=30.0,
                   help="wall seconds to wait for the peer's first packet (bench: HELLO; wheels: any; default 30)")
    s.add_argument("-o", "--output", type=output_file, help="write the run summary (JSON) here")
    b = s.add_argument_group("bench (--devices bench)")
    b.add_argument("--config", help="bench config JSON")
    b.add_argument("--rate", type=float, default=637.8, help="control tick rate in Hz (default 637.8)")
    b.add_argument("--pfsm-v", type=float, nargs=2, default=(0.0, 0.0), metavar=("VX", "VY"),
                   help="hold the P-FSM at these volts (when no --distfile; default 0 0)")
    b.add_argument("--distfile", help="play this distfile into the P-FSM (firmware player)")
    b.add_argument("--deadline", type=float, default=1.0, help="wall seconds to wait for each FSM command (default 1)")
    b.add_argument("--max-failed-ticks", type=int, default=MAX_FAILED_TICKS, metavar="N",
                   help="consecutive ticks without the controller's FSM command (each waits --deadline) that end "
                        "the run as a dead link, exit 1 (default %d)" % MAX_FAILED_TICKS)
    b.add_argument("--realtime", action="store_true", help="pace by the wall clock")
    w = s.add_argument_group("wheels (--devices wheels)")
    w.add_argument("--dt", type=float, default=0.1, help="physics step in s (default 0.1)")
    w.add_argument("--startracker-hz", type=float, default=1.0,
                   help="STARTRACKER packets to ADCS per s (default 1; at most one per --dt step)")
    s.set_defaults(func=_serve)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def _config(args):
    from emulator.config import default_config, dumps, load_config
    cfg = load_config(args.config) if args.config is not None else default_config()
    sys.stdout.write(dumps(cfg))
    return 0


def _truth_h(args):
    from emulator.bench import Bench
    from emulator.config import load_config
    from emulator.fileio import check_not_input, write_json
    from emulator.truth import sec74_grid, true_h_field
    check_not_input(args.output, [("--config", args.config)])
    bench = Bench(load_config(args.config), noise=False)
    out = true_h_field(bench, sec74_grid(args.grid), args.dv)
    write_json(args.output, out, make_folder=False)
    c = next(p for p in out["points"] if p["pfsm_v"] == [0.0, 0.0]) if args.grid % 2 else out["points"][0]
    from emulator.truth import format_h
    print("wrote %s: %d points; at P-FSM %s V: V0 = (%.4f, %.4f) V, %s"
          % (args.output, len(out["points"]), c["pfsm_v"], c["v0"][0], c["v0"][1], format_h(c["H"])))
    return 0


MAX_SECONDS = 1e6        # ~11.6 days: longer --duration or --wait is a typo (and overflows select's timeout)
MAX_FAILED_TICKS = 10    # consecutive overruns that end a bench serve run (10 s at the default --deadline)
BYTES_PER_TICK = 400     # a bench run's samples held in memory until its summary (measured, tracemalloc peak)


def _memory_bytes():
    """This machine's physical memory in bytes (None where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _check_serve_args(args):
    """Refuse serve options that are not finite or out of range before anything opens (ValueError)."""
    def finite(name, v, lo, lo_open=False, hi=math.inf):
        if not (math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi):
            raise ValueError("%s must be a finite number %s %g%s, got %r"
                             % (name, ">" if lo_open else ">=", lo, "" if hi == math.inf else " and <= %g" % hi, v))
    check_seed(args.seed)
    if args.duration is not None:
        finite("--duration (s)", args.duration, 0.0, lo_open=True, hi=MAX_SECONDS)
    finite("--wait (s)", args.wait, 0.0, hi=MAX_SECONDS)
    if args.devices == "bench":
        finite("--deadline (s)", args.deadline, 0.0, lo_open=True, hi=MAX_SECONDS)
        if args.max_failed_ticks < 1:
            raise ValueError("--max-failed-ticks must be at least 1, got %d" % args.max_failed_ticks)
        finite("--rate (Hz)", args.rate, 0.0, lo_open=True)
        from emulator.serve import BENCH_DURATION_S
        duration = BENCH_DURATION_S if args.duration is None else args.duration
        need, have = duration * args.rate * BYTES_PER_TICK, _memory_bytes()
        if have and need > 0.8 * have:        # the run would end in MemoryError (or swap) hours in
            raise ValueError("--duration %g s at %g Hz keeps ~%.1f GB of samples in memory; this machine has "
                             "%.1f GB: at most %.0f s" % (duration, args.rate, need / 1e9, have / 1e9,
                                                          0.8 * have / (args.rate * BYTES_PER_TICK)))
        for v in args.pfsm_v:
            finite("--pfsm-v (V)", v, -10.0, hi=10.0)
    else:
        finite("--dt (s)", args.dt, 0.0, lo_open=True, hi=MAX_SECONDS)
        finite("--startracker-hz", args.startracker_hz, 0.0, lo_open=True, hi=1000.0)
        if args.startracker_hz * args.dt > 1.0 + 1e-9:    # the attitude changes once a step: more would repeat it
            raise ValueError("--startracker-hz %g is more than one packet per physics step of --dt %g s: at most %g"
                             % (args.startracker_hz, args.dt, 1.0 / args.dt))


def _serve(args):
    from emulator import serve
    _check_serve_args(args)
    if args.devices == "bench":
        return serve.serve(args)
    if args.config or args.distfile:
        raise ValueError("--config and --distfile are bench options, not for --devices wheels")
    return serve.serve_wheels(args)
