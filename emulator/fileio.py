"""Atomic file writes and checked reads for the emulator (the writer and the input readers live in
``protocol.fileio``: emulator depends on protocol, not the other way round), and the cache reader of .npz files."""

import zipfile

import numpy as np

from protocol.fileio import (cache_folder, check_not_input, output_file, output_folder, parse_json,  # noqa: F401
                             read_input, read_json, write_atomic, write_json)


def load_npz(path, names):
    """The arrays ``names`` of an .npz cache file (no pickles), in order. A damaged or foreign file (truncated,
    not a zip, a pickle, a name missing) is a ValueError saying why: the caller computes the entry again."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return [z[n] for n in names]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError("%s: %s" % (type(exc).__name__, exc)) from None
