"""Firmware entry point, the same under MicroPython and CPython::

    micropython -m firmware.main controller --link serial:/dev/pts/N [--table cal.json] [--track] ...
    python -m firmware.main controller --link slcan:/dev/pts/N ...        (CAN: CPython only)
    micropython -m firmware.main player --link serial:/dev/pts/N [--distfile d.bin] [--store d.bin]

Controller options: --table PATH (calibration JSON or H-table blob), --track (start in TRACK; needs a table),
--gain Q15, --decim TICKS, --safe-ticks TICKS, --beam-threshold COUNTS, --rate HZ (for link-silence
accounting), --isotp-timeout-ms MS (CAN: ISO-TP's N_Bs, the wait for flow control before a packet is sent
again; default 1000). Exit status 0 when the peer leaves, 2 on bad arguments (the message, naming the option, and the
usage, on stderr), 1 when the link fails while serving (its error on stderr, which the HIL reports when a
controller exits).
"""

import sys

_CTRL_INT = {"--gain": "gain_q15", "--decim": "decim", "--safe-ticks": "safe_ticks",
             "--beam-threshold": "beam_threshold"}


def _failed(exc):
    """The error on stderr, which ground.runtime keeps (it sends the controller's stdout to /dev/null); exit 1:
    the link failed while serving (e.g. an ISO-TP send without flow control)."""
    print("firmware.main: error: %s" % exc, file=sys.stderr)
    return 1


def _usage(msg):
    """Bad arguments: the error and the usage on stderr; exit 2."""
    _failed(msg)
    print("usage: firmware.main controller|player --link SPEC [options] (see the module docstring)", file=sys.stderr)
    return 2


def parse(argv):
    """(role, options dict) from argv; ValueError naming a bad or missing option."""
    if not argv or argv[0] not in ("controller", "player"):
        raise ValueError("first argument must be controller or player, got %r" % (argv[0] if argv else None))
    role = argv[0]
    opts = {"link": None, "table": None, "track": False, "rate": 637.8, "ctl": {}, "distfile": None,
            "store": None, "isotp_ms": None}
    i = 1
    while i < len(argv):
        a = argv[i]
        if a == "--track":
            opts["track"] = True
            i += 1
            continue
        if i + 1 >= len(argv):
            raise ValueError("option %s needs a value" % a)
        v = argv[i + 1]
        if a == "--link":
            opts["link"] = v
        elif a == "--table":
            opts["table"] = v
        elif a == "--distfile":
            opts["distfile"] = v
        elif a == "--store":
            opts["store"] = v
        elif a == "--rate":
            try:
                r = float(v)
            except ValueError:
                r = -1.0
            if not 1.0 <= r <= 100000.0:      # NaN and inf fail too
                raise ValueError("option --rate = %r: need a tick rate in Hz from 1 to 100000" % v)
            opts["rate"] = r
        elif a == "--isotp-timeout-ms":
            try:
                r = float(v)
            except ValueError:
                r = -1.0
            if not 0.1 <= r <= 60000.0:
                raise ValueError("option --isotp-timeout-ms = %r: need a wait in ms from 0.1 to 60000" % v)
            opts["isotp_ms"] = r
        elif a in _CTRL_INT:
            try:
                opts["ctl"][_CTRL_INT[a]] = int(v)
            except ValueError:
                raise ValueError("option %s = %r is not an integer" % (a, v))
        else:
            raise ValueError("unknown option %r" % a)
        i += 2
    if not opts["link"]:
        raise ValueError("--link SPEC is required (serial:/dev/pts/N, or slcan:PATH under CPython)")
    if opts["track"] and not opts["table"]:
        raise ValueError("--track needs --table")
    return role, opts


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    try:
        role, opts = parse(argv)
        from firmware.hal import link as hal_link
        from firmware.hal.ports import open_link
        if role == "controller":
            from firmware.controller import TRACK, Controller
            try:  # MicroPython with a native emitter: the viper step, identical codes (tests/mp/firmware_viper.py)
                from firmware.controller_viper import ViperController as Controller
            except ImportError:
                pass
            node = Controller(table=opts["table"], **opts["ctl"])
            if opts["track"]:
                node.mode = TRACK
            lk = open_link(opts["link"], "CONTROLLER", isotp_ms=opts["isotp_ms"])
        else:
            from firmware.player import Player
            node = Player(store_path=opts["store"])
            if opts["distfile"]:
                node.open_file(opts["distfile"])
            lk = open_link(opts["link"], "PLAYER", isotp_ms=opts["isotp_ms"])
    except (ValueError, OSError) as exc:          # an option, a file or the link spec: bad input
        return _usage(exc)
    try:
        if role == "controller":
            hal_link.serve_controller(node, lk, rate_hz=opts["rate"])
        else:
            hal_link.serve_player(node, lk)
    except ValueError as exc:
        return _usage(exc)
    except OSError as exc:
        return _failed(exc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
