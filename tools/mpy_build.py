"""``make mpy``: compile every firmware file and the pure protocol core to .mpy with mpy-cross.

``python -m tools.mpy_build [--out build/mpy] [--march armv6m]`` writes ``<out>/<package>/<name>.mpy``
mirroring the source tree (load it with ``MICROPYPATH=<out>``) and prints a markdown table of sizes.
Bytecode .mpy files are architecture independent, but ``protocol/fast.py`` holds viper code, which mpy-cross
refuses to compile without ``-march`` ("invalid arch"). The default ``host`` is this machine's port (x64 here,
what the unix MicroPython loads); give the board's arch (e.g. ``armv6m``) when building for an MCU.
"""

import argparse
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The protocol modules that run on the MCU (the host side, pyserial/python-can links and CLIs, does not).
PROTOCOL_CORE = ("__init__", "compat", "table", "consts", "frame", "core", "fast", "distfile", "hblob", "htable",
                 "isotp", "stream")
DEFAULT_MARCH = "host"


def mpy_cross():
    exe = os.path.join(os.path.dirname(sys.executable), "mpy-cross")
    if not os.path.exists(exe):
        raise OSError("mpy-cross not found beside %s (install the test extras)" % sys.executable)
    return exe


def sources():
    """Relative paths of every file to compile: all of firmware/, and the protocol core that exists."""
    out = []
    for d, _, files in os.walk(os.path.join(ROOT, "firmware")):
        if "__pycache__" in d:
            continue
        for f in sorted(files):
            if f.endswith(".py"):
                out.append(os.path.relpath(os.path.join(d, f), ROOT))
    for name in PROTOCOL_CORE:
        rel = os.path.join("protocol", name + ".py")
        if os.path.exists(os.path.join(ROOT, rel)):
            out.append(rel)
    return sorted(out)


def build(out_dir, march=DEFAULT_MARCH):
    """Compile every source into out_dir for native code of ``march`` (mpy-cross -march; bytecode-only files
    come out the same for any arch); returns [(source, mpy path, source bytes, mpy bytes)].
    Raises RuntimeError naming the file and mpy-cross's message when one fails."""
    from emulator.runtime import child_options
    exe = mpy_cross()
    rows = []
    for rel in sources():
        dst = os.path.join(out_dir, rel[:-3] + ".mpy")
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        tmp = dst + ".tmp"
        cmd = [exe, "-o", tmp, "-s", rel]
        if march:
            cmd.append("-march=" + march)
        p = subprocess.run(cmd + [os.path.join(ROOT, rel)], capture_output=True, text=True, **child_options())
        if p.returncode != 0:
            raise RuntimeError("mpy-cross failed on %s: %s" % (rel, (p.stderr or p.stdout).strip()))
        os.replace(tmp, dst)
        rows.append((rel, dst, os.path.getsize(os.path.join(ROOT, rel)), os.path.getsize(dst)))
    return rows


def table(rows):
    lines = ["| file | source bytes | .mpy bytes |", "|---|---:|---:|"]
    for rel, _, src, mpy in rows:
        lines.append("| %s | %d | %d |" % (rel, src, mpy))
    lines.append("| **total** | %d | %d |" % (sum(r[2] for r in rows), sum(r[3] for r in rows)))
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m tools.mpy_build", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "build", "mpy"), help="output folder (default build/mpy)")
    ap.add_argument("--march", default=DEFAULT_MARCH,
                    help="mpy-cross -march for the viper code (default host: this machine's port, x64 here)")
    args = ap.parse_args(argv)
    try:
        rows = build(args.out, args.march)
    except (OSError, RuntimeError) as exc:
        print("mpy_build: error: %s" % exc, file=sys.stderr)
        return 1
    print(table(rows))
    print("\n%d files compiled into %s" % (len(rows), args.out))
    from tools.natmod_build import TARGET as kern       # the C kernels (make natmod): x64 code
    if args.march in ("host", "x64") and os.path.exists(kern):
        from protocol.fileio import write_atomic
        with open(kern, "rb") as fh:
            write_atomic(os.path.join(args.out, os.path.relpath(kern, ROOT)), fh.read())
        print("and the ADCS C kernels (native module, x64) copied beside them: %d bytes" % os.path.getsize(kern))
    return 0


if __name__ == "__main__":
    sys.exit(main())
