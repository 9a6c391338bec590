"""The board's machine-code CTRL_STATUS (``firmware.hal.fast_status``): its restated numbers are their sources', and
it frames ``Controller.status_payload``'s bytes without allocating, under the unix port and on the PIL lab board
(frozen for ARMv6-M, as the controller's board runs it); a resent status tick gets the same status again."""

import json
import os
import re
import subprocess
import sys

import pytest

from firmware import controller
from firmware.hal import stdio
from protocol import consts, frame
from tools import pil_board, pil_build

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")


def _consts(path):
    with open(os.path.join(ROOT, path)) as f:
        return {m.group(1): int(m.group(2), 0) for m in re.finditer(r"^(_\w+) = const\((\w+)\)", f.read(), re.M)}


def test_the_status_modules_numbers_are_their_sources():
    c = _consts("firmware/hal/fast_status.py")
    assert c.pop("_VERSION") == consts.PROTOCOL_VERSION and c.pop("_P_CTRL_STATUS") == consts.P_CTRL_STATUS
    assert c.pop("_STATUS_BODY") == frame.HEADER_SIZE + consts.SIZES[consts.P_CTRL_STATUS] == 58
    for name in [n for n in c if n.startswith("_ST_")]:
        assert c.pop(name) == getattr(stdio, name), name
    slots = {n: v for n, v in c.items() if n.startswith("_S_")}
    assert len(slots) == 14 and all(getattr(controller, n) == v for n, v in slots.items()), slots
    assert max(slots.values()) < c["_TICK"]              # the field table's sources: a slot below the codes
    assert _consts("firmware/hal/fast_tick.py")["_ST_RX_GAPS"] == stdio._ST_RX_GAPS
    assert consts.FMT_CTRL_STATUS == "<IBBiihhHHHHHHIHBHHHIIH"        # the byte offsets status() writes


def _unix_port(script, arg):
    """The last stdout line (JSON) of tests/mp/``script`` run with ``arg`` under the unix port (skip without it)."""
    if not os.path.exists(MICROPYTHON):
        pytest.skip("micropython binary not installed in the venv")
    env = dict(os.environ, MICROPYPATH=ROOT + ":" + os.path.join(ROOT, "tests", "mp"))
    p = subprocess.run([MICROPYTHON, os.path.join(ROOT, "tests", "mp", script), arg], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stdout + p.stderr
    return json.loads(p.stdout.splitlines()[-1])


def test_the_machine_code_status_is_the_controllers_under_the_unix_port():
    res = _unix_port("firmware_fast_status.py", "600")
    assert res["n"] == 600 and res["mismatch"] == 0 and res["tx_frames"] == 600 and res["tx_seq"] == 600 % 256


def test_a_resent_status_tick_gets_the_same_status_from_the_machine_code_path():
    """A resent CTRL_STATUS tick is answered from the cache with the status the machine code sent (the link's
    ``status_sent``): the same bytes as the bytecode path's, the status twice."""
    res = _unix_port("firmware_fast_tick.py", "300")
    assert res["status_resend"] is True and res["same"]["bytes"] is True


@pytest.mark.skipif(not os.path.exists(pil_build.LAB_IMAGE) or bool(pil_build.missing_tools()),
                    reason="no PIL image (make pil; it needs %s)" % pil_build.install_hint(pil_build.PACKAGES))
def test_the_machine_code_status_is_the_controllers_on_the_cortex_m0():
    with pil_board.Board() as b:
        res = json.loads(b.run("import firmware_fast_status").strip().splitlines()[-1])
    assert res["n"] == 400 and res["mismatch"] == 0 and res["tx_frames"] == 400
