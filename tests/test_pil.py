"""Processor in the loop, first part: the controller firmware frozen into MicroPython's qemu port for a Cortex-M0
(``make pil``, ground/pil_build.py) runs on QEMU's microbit machine, and its viper law, compiled for ARMv6-M,
clocks out the same AD5664R words as the bytecode controller on the host, bit for bit; its instructions per
control step are counted under ``-icount``. Skipped, saying why, where the image is not built."""

import json
import os
import sys

import pytest

from firmware.controller import TRACK, Controller
from ground import pil_build
from protocol import htable

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
import firmware_plant as fp  # noqa: E402

pytestmark = pytest.mark.skipif(
    not os.path.exists(pil_build.IMAGE) or pil_build.missing_tools(),
    reason="no PIL image (make pil; it needs %s)" % pil_build.install_hint(pil_build.PACKAGES))


def _table():
    return htable.grid_from_calibration(fp.calibration())


def _samples(n):
    """Q1 samples of a closed loop on the host (the plant in double precision), as ints."""
    c = Controller(table=_table(), safe_ticks=65535)
    p = fp.Plant(seed=5)
    src = []
    c.step(2048, 2048, 0)
    c.mode = TRACK
    for k in range(n):
        s = p.sample()
        src.extend(int(v) for v in s)
        p.apply(c.on_tick(k, 0, s[0], s[1], s[2]))
    return src


def _host(blob, src):
    """The bytecode controller on the host over the same replay: the board's ``pil_probe.replay`` figures."""
    from binascii import crc32
    c = Controller(table=htable.parse(blob), safe_ticks=65535)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    t = c.table
    tab = crc32(bytes(str([t.nx, t.ny] + list(t.ax) + list(t.ay) + list(t.rdx) + list(t.rdy) + list(t.h)),
                      "ascii"))
    crc = 0
    for k in range(len(src) // 3):
        c.step(src[3 * k], src[3 * k + 1], src[3 * k + 2])
        for w in c.words:
            crc = crc32(bytes([w >> 16, (w >> 8) & 0xFF, w & 0xFF]), crc)
    return {"crc": crc & 0xFFFFFFFF, "words": list(c.words), "table_crc": tab & 0xFFFFFFFF, "mode": c.mode}


@pytest.fixture(scope="module")
def board():
    with pil_build.Board() as b:
        yield b


def test_the_image_boots_on_the_cortex_m0_machine(board):
    assert b"microbit with nRF51" in board.banner
    assert board.run("import sys\nprint(sys.implementation._mpy & 0xff, sys.platform)").split() == ["6", "qemu"]


def test_viper_and_bytecode_on_the_board_clock_out_the_hosts_words(board):
    blob = htable.pack(_table())
    src = _samples(600)
    host = _host(blob, src)
    from array import array
    board.run("import gc, json, pil_probe\nfrom array import array\nb = bytes.fromhex(%r)\n"
              "s = array('H', bytes.fromhex(%r))\ngc.collect()" % (blob.hex(), array("H", src).tobytes().hex()))
    viper, byte = (json.loads(board.run("print(json.dumps(pil_probe.replay(b, s, %s)))\ngc.collect()" % v)
                              .strip().splitlines()[-1]) for v in ("True", "False"))
    for r in (viper, byte):
        assert r["table_crc"] == host["table_crc"]              # H^-1 per grid point: the same integers
        assert (r["crc"], r["words"], r["mode"]) == (host["crc"], host["words"], host["mode"])
    # instructions per step, counted by the nRF51's TIMER0 under -icount (one instruction a virtual ns)
    assert 1000 < viper["insn_per_step_with_crc"] < byte["insn_per_step_with_crc"]
