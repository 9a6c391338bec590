"""Atomic file writes for the emulator (the writer lives in ``protocol.fileio``: emulator depends on protocol,
not the other way round)."""

from protocol.fileio import check_not_input, read_input, write_atomic, write_json  # noqa: F401
