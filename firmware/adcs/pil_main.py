"""The ADCS flight software on the ADCS PIL board (QEMU's mps2-an500, a Cortex-M7 with its FPU; tools/pil_build.py's
ADCS image): what ``firmware/adcs/main_can.py`` does on the unix port, with CAN through Lawicel on the console UART
(``firmware.hal.slcan.UartSlcan``; the host opens python-can's slcan interface on QEMU's pty) and the board's timer
as its clock (``firmware.hal.mps2``). Started by importing it through the raw REPL, with Ctrl-C (a byte like any
other) turned off; it reads its configuration (main_can's CONFIG.json) as the first line on the UART, then serves
until the host leaves. A bad configuration or an error prints its traceback on the UART, and the board halts (the
host quotes it: ``emulator.launcher.FirmwareProcess.exit_note``)."""

import json
import sys

import machine
import micropython

from firmware.adcs.app import App
from firmware.adcs.lockstep import serve
from firmware.hal import mps2
from firmware.hal.slcan import CanPort, UartSlcan


def main():
    micropython.kbd_intr(-1)
    mps2.start()
    try:
        cfg = json.loads(sys.stdin.readline())
        app = App(cfg)
        clock = (mps2.ticks_ms, mps2.ticks_diff)
        port = CanPort(UartSlcan(ready=mps2.rx_ready, clock=clock), "ADCS",
                       isotp_timeout_ms=cfg.get("isotp_timeout_ms", 1000), clock=clock)
        serve(app, port, mps2.ticks_us)
    except Exception as exc:            # MemoryError and a bad configuration included
        sys.print_exception(exc)
    while True:
        machine.idle()


main()
