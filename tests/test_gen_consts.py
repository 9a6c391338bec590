"""The constants the firmware restates (viper needs them in its own modules) are written by
``python -m tools.gen_consts`` from their one source: every block is current, a stale one is named and rewritten."""

import struct
import subprocess
import sys

import pytest

from protocol import consts, table
from tools import gen_consts

ROOT = gen_consts.ROOT


def test_every_generated_block_is_current():
    p = subprocess.run([sys.executable, "-m", "tools.gen_consts", "--check"], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 0, p.stderr


def test_a_block_that_differs_from_its_source_is_rewritten_from_it():
    path, source, entries = gen_consts.blocks()[0]
    assert path == "firmware/controller.py" and [n for n, _, _ in entries] == [n for n, _ in table.MODES]
    text = open(gen_consts.os.path.join(ROOT, path)).read()
    stale = text.replace("SATURATED = const(5)", "SATURATED = const(6)")
    assert stale != text and gen_consts.apply(stale, source, entries, path) == text
    with pytest.raises(ValueError, match="no block generated from"):
        gen_consts.apply("x = 1\n", source, entries, path)


def test_the_fast_ticks_numbers_are_the_tables():
    entries = dict((n, v) for p, _, e in gen_consts.blocks() if p.endswith("fast_tick.py") for n, v, _ in e)
    assert entries["_P_TICK"] == consts.P_TICK and entries["_BROADCAST"] == consts.NODE_BROADCAST
    assert entries["_TICK_RAW"] == 5 + struct.calcsize(consts.FMT_TICK) + 2 == 21
    assert consts.FMT_TICK == "<IIHHH" and consts.FMT_FSM_SPI == "<IBIIII"    # the byte offsets answer() uses
