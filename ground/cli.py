"""``fps``: one command line for the whole workbench.

Subcommands live in their own modules and are imported only when used, so ``fps protocol`` never
pays for numpy or matplotlib. A module registers itself with ``register(subparsers, name, help)``,
which adds its parser and sets ``func`` (called with the parsed args; its return value is the exit code).
Exit status: 0 success, 1 the run failed (OSError: link, process, disk; or an internal error), 2 bad input
(ValueError, or argparse's own), 3 a run that completed but missed its requirement (``fps hil``), 130
interrupted: by Ctrl-C, or by SIGTERM, which every command takes as a Ctrl-C (``sigterm_as_interrupt``: a
process manager's stop leaves the run's folder valid with what it did so far).
"""

import argparse
import importlib
import os
import sys

COMMANDS = (
    ("protocol", "protocol.cli", "packet table, DBC file, encode and decode frames"),
    ("emulator", "emulator.cli", "bench emulator: default config, true H field, serve devices on a link"),
    ("distfile", "ground.distfile_cli", "generate, inspect and export disturbance files (distfiles)"),
    ("calibrate", "ground.calibrate", "H-matrix calibration over the P-FSM grid (Sec. 7.4)"),
    ("hil", "ground.hil", "emulated hardware-in-the-loop run with the Q2 recorder (Sec. 7.5)"),
    ("response", "ground.response", "the loop's frequency response: stepped sines, measured |S| beside the model"),
    ("system", "ground.system", "the whole terminal in one run: ADCS and fine-pointing loops coupled live"),
    ("adcs", "ground.adcs.cli", "the ADCS: apkf, mekf (Ch. 4), stkf (Ch. 5), bps and sweep (body pointing, Ch. 6; "
     "--world thesis|flight), can (the flight firmware on CAN)"),
    ("spacecraft", "ground.spacecraft_cli", "spacecraft files: list, show, check and write one; the schema with units"),
)


def build_parser(only=None):
    p = argparse.ArgumentParser(
        prog="fps",
        description="Fine-pointing workbench: firmware, emulated bench and ground tools "
                    "(units: angles in arcsec on the sky unless a flag says otherwise, volts, seconds).")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod, help_ in COMMANDS:
        if name == only:
            importlib.import_module(mod).register(sub, name, help_)
        else:
            sub.add_parser(name, help=help_)
    return p


# options whose value may start with "-" (a range such as --ts -5:60:20): argparse takes such a value for an option
# and answers "expected one argument"; they are joined as --ts=-5:60:20, so the option's own check names the value
DASH_VALUE_OPTS = ("--ts",)


def _join_dash_values(argv):
    out = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in DASH_VALUE_OPTS and i + 1 < len(argv) and argv[i + 1].startswith("-") and len(argv[i + 1]) > 1 \
                and (argv[i + 1][1].isdigit() or argv[i + 1][1] == "."):
            out.append(a + "=" + argv[i + 1])
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def main(argv=None):
    argv = _join_dash_values(sys.argv[1:] if argv is None else list(argv))
    names = [c[0] for c in COMMANDS]
    only = argv[0] if argv and argv[0] in names else None
    parser = build_parser(only)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from emulator.runtime import sigterm_as_interrupt
    try:
        with sigterm_as_interrupt():
            rc = args.func(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except ValueError as exc:          # bad input: a file, a value, an option combination
        print("fps %s: error: %s" % (args.command, exc), file=sys.stderr)
        return 2
    except OSError as exc:             # the run failed: a link, a process, the disk
        print("fps %s: error: %s" % (args.command, exc), file=sys.stderr)
        return 1
    except Exception as exc:           # a bug: say so in one line, the traceback only on request
        if os.environ.get("FPS_DEBUG"):
            raise
        print("fps %s: internal error: %s: %s (please report it; FPS_DEBUG=1 shows the traceback)"
              % (args.command, type(exc).__name__, exc), file=sys.stderr)
        return 1
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
