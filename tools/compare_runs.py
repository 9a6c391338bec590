"""``python -m tools.compare_runs A B``: whether two run folders hold the same results, file by file.

For checking that a change kept behaviour: run ``make hil OUT=a`` (or any fps command) before and after it, then
compare the two folders. JSON files are compared key by key (nested keys joined by dots), .npz files array by
array (bit for bit), CSV files column by column, other files byte for byte (figures, .png, are left out: they carry
the renderer's details). What a real-time run cannot repeat is reported but not counted as a difference: wall
times and dates, real-time factors, and the link's own counters of resent or late frames (``VARYING``; add
patterns with ``--vary``). Paths to files outside the folders are compared by file name. Text reports (.md, .txt) are compared line by line, a line with a wall time, a date, a
real-time factor or the link's counters counted as one that may vary.

Exit 0 when every result is the same, 1 when one differs (each named with both values), 2 for a folder that is
not there."""

import argparse
import csv
import json
import os
import re
import sys

VARYING = (r"(^|\.)(created|started|finished)_utc$", r"(^|\.|_)wall_s$", r"real_time_factor", r"^link\.",
           r"^(n_dup|n_rx_drop)$")
# the same in a text report's lines (entry "line N: <the line>")
TEXT_VARYING = (r"real-time factor", r"\bwall\b", r"^line \d+: - link:", r"\d{4}-\d\d-\d\dT\d\d:\d\d")
TEXT = (".md", ".txt", ".log")
SKIP = (".png", ".pdf", ".svg")


def flatten(d, prefix=""):
    """{dotted key: value} of a JSON value (lists kept whole)."""
    if isinstance(d, dict):
        out = {}
        for k, v in d.items():
            out.update(flatten(v, "%s.%s" % (prefix, k) if prefix else str(k)))
        return out
    return {prefix: d}


def _same_value(a, b):
    if isinstance(a, str) and isinstance(b, str) and os.sep in a and os.sep in b:
        return os.path.basename(a) == os.path.basename(b)
    return a == b


def compare_json(a, b):
    """[(key, value in a, value in b)] of the keys whose values differ."""
    fa, fb = flatten(a), flatten(b)
    return [(k, fa.get(k), fb.get(k)) for k in sorted(set(fa) | set(fb))
            if k not in fa or k not in fb or not _same_value(fa[k], fb[k])]


def compare_npz(pa, pb):
    import numpy as np
    with np.load(pa) as x, np.load(pb) as y:
        out = []
        for k in sorted(set(x.files) | set(y.files)):
            if k not in x.files or k not in y.files:
                out.append((k, "present" if k in x.files else "missing", "present" if k in y.files else "missing"))
            elif x[k].shape != y[k].shape or not np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind in "fc"):
                n = int((x[k] != y[k]).sum()) if x[k].shape == y[k].shape else None
                out.append((k, "shape %s" % (x[k].shape,), "shape %s, %s elements differ" % (y[k].shape, n)))
        return out


def compare_csv(pa, pb):
    with open(pa, newline="") as f:
        ra = list(csv.reader(f))
    with open(pb, newline="") as f:
        rb = list(csv.reader(f))
    if not ra or not rb or ra[0] != rb[0]:
        return [("header", ra[0] if ra else None, rb[0] if rb else None)]
    if len(ra) != len(rb):
        return [("rows", len(ra) - 1, len(rb) - 1)]
    out = []
    for j, name in enumerate(ra[0]):
        rows = [i for i in range(1, len(ra)) if ra[i][j] != rb[i][j]]
        if rows:
            out.append((name, "row %d: %s" % (rows[0], ra[rows[0]][j]), "%s (%d rows differ)" % (rb[rows[0]][j],
                                                                                                 len(rows))))
    return out


def compare_text(pa, pb):
    with open(pa, errors="replace") as f:
        la = f.read().splitlines()
    with open(pb, errors="replace") as f:
        lb = f.read().splitlines()
    out = [("line %d: %s" % (i + 1, x[:40]), x, y) for i, (x, y) in enumerate(zip(la, lb)) if x != y]
    if len(la) != len(lb):
        out.append(("lines", len(la), len(lb)))
    return out


def compare_file(pa, pb):
    """[(entry, a, b)] of what differs between two files of the same name."""
    if pa.endswith(".json"):
        with open(pa) as fa, open(pb) as fb:
            return compare_json(json.load(fa), json.load(fb))
    if pa.endswith(".npz"):
        return compare_npz(pa, pb)
    if pa.endswith(".csv"):
        return compare_csv(pa, pb)
    if pa.endswith(TEXT):
        return compare_text(pa, pb)
    with open(pa, "rb") as fa, open(pb, "rb") as fb:
        x, y = fa.read(), fb.read()
    if x == y:
        return []
    at = next((i for i in range(min(len(x), len(y))) if x[i] != y[i]), min(len(x), len(y)))
    return [("bytes", "%d bytes" % len(x), "%d bytes, first difference at byte %d" % (len(y), at))]


def files(folder):
    out = set()
    for d, _, names in os.walk(folder):
        for n in names:
            if not n.endswith(SKIP):
                out.add(os.path.relpath(os.path.join(d, n), folder))
    return out


def compare(a, b, vary=(), listing=None):
    """[(file, entry, a, b, varying)] for every difference between folders ``a`` and ``b``; ``varying`` is True
    for an entry matching ``VARYING`` or ``vary``. ``listing``: their ``files()``, if already walked."""
    mine = [re.compile(p) for p in vary]
    pats = [re.compile(p) for p in VARYING + TEXT_VARYING] + mine
    fa, fb = listing or (files(a), files(b))
    rows = []
    for f in sorted(fa | fb):
        if f not in fa or f not in fb:
            rows.append((f, "file", "present" if f in fa else "missing", "present" if f in fb else "missing",
                         any(p.search("file") for p in mine)))          # a missing file only if told
            continue
        try:
            diffs = compare_file(os.path.join(a, f), os.path.join(b, f))
        except (ValueError, OSError) as exc:
            diffs = [("unreadable", str(exc)[:80], "")]
        rows += [(f, k, x, y, any(p.search(k) for p in pats)) for k, x, y in diffs]
    return rows


def _short(v):
    s = json.dumps(v) if not isinstance(v, str) else v
    return s if len(s) <= 60 else s[:57] + "..."


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m tools.compare_runs", description=__doc__.split("\n\n")[0])
    ap.add_argument("a", help="a run folder (e.g. make hil's OUT before a change)")
    ap.add_argument("b", help="the other run folder")
    ap.add_argument("--vary", action="append", default=[], metavar="REGEX",
                    help="another entry that may vary between runs (a regular expression on JSON keys, CSV "
                         "columns and npz names), besides the wall times, dates, real-time factors and link "
                         "counters")
    a = ap.parse_args(argv)
    for d in (a.a, a.b):
        if not os.path.isdir(d):
            print("compare_runs: error: %s is not a folder" % d, file=sys.stderr)
            return 2
    fa, fb = files(a.a), files(a.b)
    rows = compare(a.a, a.b, a.vary, (fa, fb))
    real = [r for r in rows if not r[4]]
    n = len(fa | fb)
    print("| file | entry | %s | %s | may vary |\n|---|---|---|---|---|" % (a.a, a.b))
    for f, k, x, y, v in rows:
        print("| %s | %s | %s | %s | %s |" % (f, k, _short(x), _short(y), "yes" if v else "no"))
    print("\n%d files compared: %s" % (n, "the same results (%d entries that may vary differ)" % len(rows)
                                       if not real else "%d result%s differ%s" % (
                                           len(real), "" if len(real) == 1 else "s", "s" if len(real) == 1 else "")))
    return 1 if real else 0


if __name__ == "__main__":
    sys.exit(main())
