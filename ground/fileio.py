"""Atomic file writes for the ground tools (the writer lives in ``emulator.fileio``: ground depends on the
emulator, never the other way)."""

from emulator.fileio import (check_not_input, load_npz, output_file, output_folder, read_input,  # noqa: F401
                             read_json, write_atomic, write_json)
