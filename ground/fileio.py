"""Atomic file writes for the ground tools (the writer lives in ``protocol.fileio``, re-exported by
``emulator.fileio``: ground depends on the emulator, never the other way)."""

import os

from emulator.fileio import (cache_folder, check_not_input, load_npz, output_file, output_folder,  # noqa: F401
                             parse_json, read_input, read_json, write_atomic, write_json)


def remove_stale(folder, names):
    """Remove the files ``names`` in ``folder`` that an earlier run left (its figures): in a reused folder every
    figure is then this run's, or absent (``--no-plots``, an interrupted run), never an older run's beside a new
    summary. Returns the names removed."""
    gone = []
    for n in names:
        try:
            os.remove(os.path.join(str(folder), n))
        except FileNotFoundError:
            continue
        gone.append(n)
    return gone


def folder_line(path, first=("summary.json", "report.md")):
    """"run folder PATH: a, b, ..." naming every file the folder holds (``first`` ahead, the rest sorted; a
    sub-folder with a trailing /), so the line never names a file that was not written nor leaves one out."""
    try:
        names = os.listdir(str(path))
    except OSError:
        return "run folder %s: (not written)" % path
    shown = [n + "/" if os.path.isdir(os.path.join(str(path), n)) else n for n in names if not n.startswith(".")]
    order = {n: i for i, n in enumerate(first)}
    shown.sort(key=lambda n: (order.get(n, len(order)), n))
    return "run folder %s: %s" % (path, ", ".join(shown) or "(empty)")


def run_folder(path, figures=()):
    """Make the run folder ``path`` (or reuse it) without the ``figures`` an earlier run left there
    (``remove_stale``); returns ``path``."""
    os.makedirs(str(path), exist_ok=True)
    remove_stale(path, figures)
    return path
