"""Entry point of the ADCS flight software on CAN (MicroPython unix port or CPython):

    micropython firmware/adcs/main_can.py DEVICE CONFIG.json [HEAP_OUT.json]

DEVICE: the slcan adapter's side, a file descriptor number (a non-blocking pty master inherited from the
emulator) or a path. CONFIG: the parameter file and settings (emulator/adcs_session.py writes it;
``isotp_timeout_ms``, ISO-TP's N_Bs for this side's sends, defaults to ISO's 1000).
HEAP_OUT: when given, the heap bytes allocated per cycle (gc.mem_alloc deltas) are written there at exit
(MicroPython only: under CPython the list is empty). Exit status 0 when the host leaves (its end of the pty
closes), 1 when the link fails otherwise (the reason on stderr), 2 on a bad configuration.
"""

import json
import sys

from firmware.adcs.app import App
from firmware.adcs.lockstep import serve
from firmware.hal.slcan import CanPort, SlcanAdapter
from protocol.stream import ticks_us


def main(argv):
    if len(argv) < 3:
        sys.stderr.write("usage: main_can.py DEVICE CONFIG.json [HEAP_OUT.json]\n")
        return 2
    dev = argv[1]
    dev = int(dev) if dev.isdigit() else dev
    try:
        with open(argv[2]) as fh:
            cfg = json.load(fh)
        app = App(cfg)
    except KeyError as exc:                 # a setting the configuration lacks
        sys.stderr.write("main_can: %s: missing key %s\n" % (argv[2], exc))
        return 2
    except (ValueError, TypeError, OSError) as exc:
        sys.stderr.write("main_can: %s: %s\n" % (argv[2], exc))
        return 2
    port = CanPort(SlcanAdapter(dev), "ADCS", isotp_timeout_ms=cfg.get("isotp_timeout_ms", 1000))
    heap = None
    samples = []
    if len(argv) > 3 and sys.implementation.name == "micropython":
        def heap(tick, n):
            samples.append(n)
    try:
        serve(app, port, ticks_us, heap=heap)
    except KeyboardInterrupt:
        pass
    if len(argv) > 3:
        with open(argv[3], "w") as fh:
            json.dump({"heap_bytes": samples}, fh)
    why = getattr(port.ad, "fail_why", None)
    if why:                                 # the link failed (not the host leaving): say so, exit 1
        sys.stderr.write("main_can: error: the link failed: %s\n" % why)
        return 1
    return 0


sys.exit(main(sys.argv))
