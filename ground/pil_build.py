"""``make pil``: the controller firmware frozen into MicroPython's own qemu port for a Cortex-M0 board, for
processor-in-the-loop runs under ``qemu-system-arm``.

``python -m ground.pil_build [--optional]`` writes ``build/pil/MICROBIT/firmware.elf``: MicroPython 1.25.0's
``ports/qemu`` for ``BOARD=MICROBIT`` (QEMU's ``microbit`` machine: an nRF51822, Cortex-M0 at 16 MHz, the closest
machine QEMU has to the thesis's SAMD21G18, a Cortex-M0+ at 48 MHz with 32 KB of RAM; both ARMv6-M, the M0+ has
a two-stage pipeline and a single-cycle I/O port the M0 lacks), with the fine-pointing controller's modules
frozen as armv6m bytecode and viper code (``FROZEN``). The source tarball is the one ``make natmod`` fetches
(``ground.natmod_build``: the machine's own apt archives, the pinned SHA-256), here extracted whole into
``build/``. The port as shipped needs three changes, made to a copy of its configuration:

- the native emitter is off for the nRF51 (``mpconfigport.h``): viper code would not link; it is turned on for
  ARMv6-M (``MICROPY_EMIT_THUMB``, without the ARMv7-M instructions);
- ``sys.stdin.buffer`` / ``sys.stdout.buffer`` are off: the packet protocol is binary; they are turned on;
- its default frozen manifest requires micropython-lib, which the tarball leaves empty: ours freezes the
  firmware only.

Needs ``arm-none-eabi-gcc`` with newlib (``gcc-arm-none-eabi``, ``libnewlib-arm-none-eabi``), host ``gcc`` and
``make`` for mpy-cross, and ``qemu-system-arm`` to run the image: Debian packages. ``--optional`` (what a
``make`` target that must not fail uses): a build that cannot be done says why in one line, with the command that
installs what is missing, and exits 0; the PIL tests are then skipped with that reason.
"""

import argparse
import os
import shutil
import subprocess
import sys

from emulator import launcher
from ground import natmod_build

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOARD = "MICROBIT"
FULL_DIR = os.path.join(ROOT, "build", "micropython-%s-full" % natmod_build.MP_VERSION)
OUT = os.path.join(ROOT, "build", "pil")
IMAGE = launcher.PIL_IMAGE                     # build/pil/MICROBIT/firmware.elf
PACKAGES = ("gcc-arm-none-eabi", "libnewlib-arm-none-eabi", "qemu-system-arm")
MARCH = "armv6m"
# the heap in the image: 224 KB of the machine's 256 KB. The port's own 140 KB runs out building the H table
# (MemoryError allocating 512 bytes in htable.grid_from_calibration, measured): the controller does not yet fit
# the thesis's 32 KB board, and this image does not pretend it does
HEAP_BYTES = 229376
# the controller and what it imports on the board (the packet table's pure core, the H table, the viper law)
FROZEN = ("firmware/__init__.py", "firmware/ad5664r.py", "firmware/hinv.py", "firmware/upload.py",
          "firmware/controller.py", "firmware/controller_viper.py",
          "firmware/hal/__init__.py", "firmware/hal/link.py", "firmware/hal/stdio.py", "firmware/pil_main.py",
          "protocol/__init__.py", "protocol/table.py", "protocol/core.py", "protocol/htable.py", "protocol/fast.py",
          "protocol/can.py", "protocol/isotp.py", "protocol/lawicel.py")
# mpconfigport.h: (what the port has, what the PIL image needs)
PATCHES = (
    ("#if !defined(QEMU_SOC_NRF51)\n#define MICROPY_EMIT_THUMB          (1)\n#define MICROPY_EMIT_INLINE_THUMB   (1)\n"
     "#endif\n",
     "#if !defined(QEMU_SOC_NRF51)\n#define MICROPY_EMIT_THUMB          (1)\n#define MICROPY_EMIT_INLINE_THUMB   (1)\n"
     "#else\n#define MICROPY_EMIT_THUMB          (1)\n#define MICROPY_EMIT_THUMB_ARMV7M   (0)\n#endif\n"),
    ("#define MICROPY_PY_SYS_STDIO_BUFFER (0)\n", "#define MICROPY_PY_SYS_STDIO_BUFFER (1)\n"),
)


class BuildError(Exception):
    pass


def missing_tools():
    """The Debian packages whose programs are not on PATH."""
    need = {"gcc-arm-none-eabi": "arm-none-eabi-gcc", "qemu-system-arm": "qemu-system-arm"}
    out = [p for p, exe in need.items() if shutil.which(exe) is None]
    if shutil.which("arm-none-eabi-gcc") is not None:          # newlib: its headers beside the compiler's
        p = subprocess.run(["arm-none-eabi-gcc", "-print-file-name=libc.a"], capture_output=True, text=True)
        if not os.path.isabs(p.stdout.strip()):
            out.append("libnewlib-arm-none-eabi")
    for exe in ("gcc", "make"):
        if shutil.which(exe) is None:
            out.append(exe)
    return out


def install_hint(pkgs):
    return "apt-get install --no-install-recommends %s" % " ".join(pkgs)


def fetch_full(dest=FULL_DIR):
    """MicroPython's whole source tree under ``dest`` (``natmod_build.fetch_source``: the machine's apt archives,
    the pinned SHA-256, extracted once)."""
    if os.path.exists(os.path.join(dest, "ports", "qemu", "Makefile")):
        return dest
    try:
        return natmod_build.fetch_source(dest, parts=None)
    except natmod_build.BuildError as exc:
        raise BuildError(str(exc)) from None


# the known-answer scripts the PIL tests run on the board (tests/mp: the same ones the unix port runs)
FROZEN_TESTS = ("firmware_plant.py", "firmware_viper.py", "pil_probe.py")


def manifest_text(root=ROOT, files=FROZEN, tests=FROZEN_TESTS):
    """The frozen manifest: our modules, by path from the repository's root (module names follow), and the
    tests' scripts as top-level modules."""
    return "freeze(%r, (%s,))\nfreeze(%r, (%s,))\n" % (
        root, ", ".join(repr(f) for f in files), os.path.join(root, "tests", "mp"), ", ".join(repr(f) for f in tests))


def patch_port(src):
    """A copy of ports/qemu's configuration with ``PATCHES`` made (the tree's own file kept as .orig)."""
    path = os.path.join(src, "ports", "qemu", "mpconfigport.h")
    orig = path + ".orig"
    if not os.path.exists(orig):
        shutil.copyfile(path, orig)
    with open(orig) as f:
        text = f.read()
    for old, new in PATCHES:
        if old not in text:
            raise BuildError("ports/qemu/mpconfigport.h is not the 1.25.0 one this build patches (%r missing)"
                             % old.splitlines()[0])
        text = text.replace(old, new)
    with open(path, "w") as f:
        f.write(text)


def build(src=None):
    """mpy-cross, then the MICROBIT image with the firmware frozen; returns the image's path."""
    missing = missing_tools()
    if missing:
        raise BuildError("missing %s (install: %s)" % (", ".join(missing), install_hint(missing)))
    src = src or fetch_full()
    patch_port(src)
    os.makedirs(OUT, exist_ok=True)
    man = os.path.join(OUT, "manifest.py")
    with open(man, "w") as f:
        f.write(manifest_text())
    nolib = os.path.join(OUT, "no-micropython-lib")        # the build insists on micropython-lib's README only
    os.makedirs(nolib, exist_ok=True)
    with open(os.path.join(nolib, "README.md"), "w") as f:
        f.write("Empty: the PIL image freezes the firmware only (ground/pil_build.py).\n")
    for cmd in (["make", "-s", "-C", os.path.join(src, "mpy-cross"), "-j2"],
                ["make", "-s", "-C", os.path.join(src, "ports", "qemu"), "-j2", "BOARD=" + BOARD,
                 "BUILD=" + os.path.join(OUT, BOARD), "FROZEN_MANIFEST=" + man, "MPY_LIB_DIR=" + nolib,
                 "MPY_CROSS_FLAGS=-march=" + MARCH, "MICROPY_HEAP_SIZE=%d" % HEAP_BYTES]):
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            raise BuildError("%s failed:\n%s" % (" ".join(cmd[:4]), (p.stderr or p.stdout).strip()[-3000:]))
    if not os.path.exists(IMAGE):
        raise BuildError("the build left no %s" % IMAGE)
    return IMAGE


def qemu_command(image=IMAGE, serial="stdio", icount=True):
    """``emulator.launcher.qemu_command``; here the UART on stdio and ``-icount`` by default (the tests' board)."""
    return launcher.qemu_command(image, serial, icount)


class Board:
    """The PIL image running under QEMU with its UART on this process's pipes, driven through MicroPython's raw
    REPL: ``run(code)`` executes ``code`` on the board and returns its output (a board-side exception raises
    ``BoardError`` with its traceback). A context manager; ``close()`` ends QEMU."""

    def __init__(self, image=IMAGE, icount=True, boot_s=30.0):
        import select  # noqa: F401  (POSIX pipes: what _read polls)
        if not os.path.exists(image):
            raise BuildError("no PIL image at %s (make pil)" % image)
        self.proc = subprocess.Popen(qemu_command(image, "stdio", icount), stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.banner = self._read(b">>> ", boot_s)
        self._write(b"\r\x01")                        # raw REPL
        self._read(b"raw REPL; CTRL-B to exit\r\n>", 10.0)

    def _write(self, data):
        self.proc.stdin.write(data)
        self.proc.stdin.flush()

    def _read(self, token, timeout):
        import select
        import time
        buf = b""
        end = time.monotonic() + timeout
        while token not in buf:
            left = end - time.monotonic()
            if left <= 0:
                raise BoardError("the board gave no %r within %g s (got %r)" % (token, timeout, buf[-300:]))
            r, _, _ = select.select([self.proc.stdout], [], [], min(left, 0.5))
            if r:
                b = os.read(self.proc.stdout.fileno(), 65536)
                if not b:
                    raise BoardError("QEMU exited (%s): %s" % (self.proc.poll(), self.proc.stderr.read()[-500:]))
                buf += b
        return buf

    def run(self, code, timeout=300.0):
        """Run ``code`` (text) on the board; its standard output as text."""
        self._write(code.encode() + b"\x04")
        out = self._read(b"\x04>", timeout)
        if not out.startswith(b"OK"):
            raise BoardError("the board refused the code: %r" % out[:300])
        body = out[2:-2]
        res, _, err = body.partition(b"\x04")
        if err.strip():
            raise BoardError(err.decode(errors="replace").strip())
        return res.decode(errors="replace")

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class BoardError(Exception):
    pass


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m ground.pil_build", description=__doc__.split("\n\n")[0])
    ap.add_argument("--optional", action="store_true",
                    help="a build that cannot be done says why (and what installs the tools) and exits 0")
    a = ap.parse_args(argv)
    try:
        path = build()
    except BuildError as exc:
        print("pil: %s" % exc, file=sys.stderr)
        return 0 if a.optional else 1
    print("pil: %s (%d bytes)" % (os.path.relpath(path, ROOT), os.path.getsize(path)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
