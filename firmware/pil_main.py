"""The controller on the PIL board (ground/pil_build.py's image; ``--runtime qemu``): what ``firmware.main
controller`` does on the unix port, on the console UART (``firmware.hal.stdio``). Started by importing it through
the raw REPL; Ctrl-C (0x03, a byte like any other in the frames) is turned off first."""

import micropython

from firmware.controller_viper import ViperController
from firmware.hal.link import serve_controller
from firmware.hal.stdio import StdioLink

micropython.kbd_intr(-1)
serve_controller(ViperController(), StdioLink("CONTROLLER"), rate_hz=637.8)
