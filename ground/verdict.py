"""The summary every run-folder command ends with: report.md's verdict table (what, ours, budget, met) and the
terminal's closing lines (the run-folder line naming every file the folder holds, then the verdict lines).

A row's ``met`` is True, False (the run exits 3: a requirement missed; 1 where the row is the runs' own failure)
or None (no figure, or no requirement: a measurement beside a reference). A figure compared with the thesis
only is a reference, never a row here."""

import sys

from ground.fileio import folder_line

MARK = {True: "yes", False: "**NO**", None: "—"}


def _cell(v):
    if v is None:
        return "—"
    if isinstance(v, float):
        return "%.4g" % v
    return str(v)


def table(rows, extra=None):
    """report.md's "## Verdict" section as lines: one row per (what, ours, budget, met[, extra]); ``extra`` the
    name of a fifth column (e.g. the thesis's figure beside ours, for reference)."""
    head = "| requirement | ours | budget | met |" + (" %s |" % extra if extra else "")
    out = ["## Verdict", "", head, "|---" * (5 if extra else 4) + "|"]
    for r in rows:
        cells = [r[0], _cell(r[1]), _cell(r[2]), MARK[r[3]]] + ([_cell(r[4] if len(r) > 4 else None)] if extra else [])
        out.append("| " + " | ".join(cells) + " |")
    return out + [""]


def missed(rows):
    """True when a row's requirement is missed."""
    return any(r[3] is False for r in rows)


def runs_row(ok, n, what="runs completed (none failed nor diverged)"):
    """The verdict's row of a Monte Carlo: ``ok`` of ``n`` runs completed; a run short of it exits 1."""
    return (what, "%d of %d" % (ok, n), "all", ok == n)


def close(out, lines=(), err=()):
    """The terminal's closing lines: the run-folder line (``fileio.folder_line``), then ``lines``, those
    starting with one of ``err`` (e.g. "BUDGET", "INTERRUPTED") on stderr."""
    print(folder_line(out))
    for line in lines:
        print(line, file=sys.stderr if err and line.startswith(tuple(err)) else sys.stdout)
    sys.stdout.flush()
