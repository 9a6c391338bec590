"""The controller board's mailbox (firmware/pil_main.py writes it, tools/pil_mailbox.py reads it): each kind of
TICK exchange apart with its histogram, a resend answered from the cache kept out of the totals."""

import os
import re

from firmware import controller
from firmware.hal import stdio
from tools import pil_mailbox as pm

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_the_firmware_and_the_host_agree_on_the_layout():
    text = open(os.path.join(ROOT, "firmware", "pil_main.py")).read()
    const = dict((k, int(v, 0)) for k, v in re.findall(r"^(_?[A-Z_]+) = const\((\w+)\)", text, re.M))
    assert const["_KINDS"] == len(pm.KINDS) and const["_BUCKETS"] == pm.BUCKETS
    assert const["_KIND_WORDS"] == pm.KIND_WORDS and const["_BOX_WORDS"] == pm.WORDS and const["MAGIC"] == pm.MAGIC
    assert [stdio._K_COMMON, stdio._K_BIN, stdio._K_STATUS, stdio._K_RESEND, stdio._K_OTHER] == list(range(5))
    assert pm.KINDS.index("resend") == stdio._K_RESEND and pm.KINDS.index("status") == stdio._K_STATUS
    assert (stdio._S_BXQ, stdio._S_BYQ) == (controller.S_BXQ, controller.S_BYQ)


def _box(kinds):
    box = [pm.MAGIC, 3] + [0] * (pm.WORDS - 2)
    for name, durations in kinds.items():
        a = 2 + pm.KINDS.index(name) * pm.KIND_WORDS
        for d in durations:
            box[a] += 1
            box[a + 1] += d
            box[a + 2] = max(box[a + 2], d)
            box[a + 3 + d.bit_length()] += 1
    return box


def test_a_resend_is_counted_apart_and_each_kind_has_its_distribution():
    r = pm.decode(_box({"common": [300, 310, 700], "bin_change": [500], "status": [6000], "resend": [1900, 2000]}))
    assert r["n"] == 5 and r["max"] == 6000 * 62.5                  # the resends in no total
    assert r["mean"] == (300 + 310 + 700 + 500 + 6000) / 5 * 62.5
    k = r["kinds"]
    assert k["resend"]["n"] == 2 and k["common"]["max"] == 700 * 62.5
    assert k["common"]["histogram"] == [[256 * 62.5, 511 * 62.5, 2], [512 * 62.5, 1023 * 62.5, 1]]
    assert r["common"]["n"] == 4 and r["common"]["max"] == 700 * 62.5
    assert pm.decode([0] * pm.WORDS) is None
