"""Atomic file writes: a temp file in the same folder, fsync, then ``os.replace``. Here, the lowest layer, so
that protocol's own tools use it too; ``emulator.fileio`` and ``ground.fileio`` re-export it (host only: not
for MicroPython)."""

import errno
import json
import os
import sys
import tempfile


def _mode(path):
    """The permissions ``path`` gets: an existing file's own, else what ``open`` would give (0o666 less the
    umask). ``mkstemp`` makes its file 0o600, which would leave every run folder unreadable to the group."""
    try:
        return os.stat(path).st_mode & 0o777
    except OSError:
        return 0o666 & ~_umask()


def _umask():
    """The process's umask, read without setting it where Linux tells it (os.umask is the fallback: it must set
    one to read it, for an instant, which another thread could see)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_atomic(path, data, make_folder=True):
    """Write ``data`` (bytes or str) to ``path`` atomically; creates the parent folder (a run folder's file),
    or with ``make_folder=False`` refuses a missing one (FileNotFoundError: an output file's typo)."""
    if isinstance(data, str):
        data = data.encode()
    folder = os.path.dirname(os.path.abspath(path))
    if make_folder:
        os.makedirs(folder, exist_ok=True)
    elif not os.path.isdir(folder):
        raise FileNotFoundError(errno.ENOENT, "no such folder", folder)
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), _mode(path))
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


JSON_MAX_BYTES = 64 << 20


def read_input(path, what, max_bytes=JSON_MAX_BYTES, text=True):
    """An input file's content (str, or bytes with ``text=False``). A file that cannot be read (missing, a
    folder, no permission), is larger than ``max_bytes`` (``/dev/zero`` included) or, as text, is not UTF-8 is
    a ValueError naming ``what`` and the path: bad input, not a failed run."""
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as exc:
        raise ValueError("%s %s: cannot read it (%s)" % (what, path, exc.strerror or exc)) from None
    if len(data) > max_bytes:
        raise ValueError("%s %s: larger than %d bytes, not such a file" % (what, path, max_bytes))
    if not text:
        return data
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError("%s %s: not a text file (%s)" % (what, path, exc)) from None


def parse_json(text, where, **kw):
    """The JSON value of ``text`` (``kw`` go to ``json.loads``). Text that is not JSON, whose arrays and objects
    nest deeper than the parser can follow or that holds an integer of more digits than Python converts, and a
    ValueError of a ``kw`` hook, are a ValueError that begins with ``where`` (e.g. the option and the file)."""
    try:
        return json.loads(text, **kw)
    except json.JSONDecodeError as exc:
        raise ValueError("%s: not valid JSON (%s)" % (where, exc)) from None
    except RecursionError:
        raise ValueError("%s: its arrays and objects nest too deeply to read" % where) from None
    except ValueError as exc:                   # an integer of more digits than int() takes, or a hook's refusal
        msg = str(exc)
        if "integer string conversion" in msg:
            msg = "an integer of more than %d digits, beyond any number's range" % sys.get_int_max_str_digits()
        raise ValueError("%s: %s" % (where, msg)) from None


def read_json(path, what, **kw):
    """An input JSON file, through ``read_input`` and ``parse_json`` (``kw`` go to ``json.loads``): a file that
    cannot be read, is not JSON or nests too deeply is a ValueError naming ``what`` and the path."""
    return parse_json(read_input(path, what), "%s %s" % (what, path), **kw)


def check_not_input(output, inputs, option="-o"):
    """ValueError if the output path names one of the input files (given as (option, path) pairs; None skipped):
    the atomic write would replace the input the command is reading."""
    if output in (None, "-"):
        return
    for opt, path in inputs:
        if path in (None, "-"):
            continue
        try:
            same = os.path.samefile(output, path)
        except OSError:                                    # one of them does not exist (yet)
            same = os.path.realpath(output) == os.path.realpath(path)
        if same:
            raise ValueError("%s %s is the input file of %s: writing it would destroy the input; choose another "
                             "output" % (option, output, opt))


def _output_path(path, folder, what="run folder"):
    """``path`` if a command can write its output there (a folder when ``folder``, else a file); an
    argparse.ArgumentTypeError saying why not, so a bad ``-o`` is refused (exit 2) before any work is done: the
    path, or the nearest part of it that exists, is a file where a folder must be (or a folder where the file
    goes), or the folder that would be written is not writable (an atomic write makes its temp file there)."""
    import argparse
    if not path.strip():
        raise argparse.ArgumentTypeError("an empty path; name the %s" % (what if folder else "output file"))
    p = os.path.abspath(path)
    if os.path.isdir(p) and not folder:
        raise argparse.ArgumentTypeError("%s is a folder; the output file goes there" % path)
    if os.path.exists(p) and folder and not os.path.isdir(p):
        raise argparse.ArgumentTypeError("%s is a file; the %s goes there" % (path, what))
    a = p if folder else os.path.dirname(p)
    while not os.path.exists(a):
        a = os.path.dirname(a)
    if not os.path.isdir(a):
        raise argparse.ArgumentTypeError("%s: %s is a file, so no folder can be made under it" % (path, a))
    if not os.access(a, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError("%s: %s is not writable" % (path, a))
    return path


def output_folder(path):
    """argparse ``type`` of a run folder option (``-o DIR``); see ``_output_path``."""
    return _output_path(path, True)


def cache_folder(path):
    """argparse ``type`` of a cache folder option (``--cache-dir``, ``--bps-cache``); see ``_output_path``."""
    return _output_path(path, True, "cache folder")


def output_file(path):
    """argparse ``type`` of an output file option (``-o FILE``; ``-``, standard output, passes); see
    ``_output_path``."""
    return path if path == "-" else _output_path(path, False)


def write_json(path, obj, make_folder=True):
    """``obj`` as indented JSON at ``path``, through ``write_atomic`` (``make_folder`` as there)."""
    write_atomic(path, json.dumps(obj, indent=1, sort_keys=False) + "\n", make_folder=make_folder)
