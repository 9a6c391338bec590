"""``make pil``: the controller firmware frozen into MicroPython's own qemu port for a Cortex-M0 board, for
processor-in-the-loop runs under ``qemu-system-arm``.

``python -m tools.pil_build [--optional]`` writes two images of MicroPython 1.25.0's ``ports/qemu`` for
``BOARD=MICROBIT`` (QEMU's ``microbit`` machine: an nRF51822, Cortex-M0 at 16 MHz, the closest machine QEMU has to
the thesis's SAMD21G18, a Cortex-M0+ at 48 MHz with 32 KB of RAM; both ARMv6-M, the M0+ has a two-stage pipeline
and a single-cycle I/O port the M0 lacks), with the fine-pointing controller's modules frozen as armv6m bytecode
and viper code (``FROZEN``):

- ``build/pil/MICROBIT/firmware.elf``, the thesis's board (``TARGET_MEM``): linked for 32 KB of SRAM, run with as
  much, what ``--runtime qemu`` starts (``firmware.pil_main``);
- ``build/pil/MICROBIT-LAB/firmware.elf``, the instruments' board (``LAB_MEM``): the same code with 256 KB, where
  the tests and ``make bench`` replay recorded samples and count instructions;

and a third for the ADCS computer (``ADCS_MEM``): ``build/pil/MPS2-AN500-ADCS/firmware.elf``, QEMU's mps2-an500 (a
Cortex-M7 with a double-precision FPU), the lean ADCS frozen (``ADCS_FROZEN``) and its C kernels built in as the
module ``adcsk`` (``build_adcs``), where ``replay_adcs`` runs a recorded session cycle by cycle.

The source tarball is the one ``make natmod`` fetches (``tools.natmod_build``: the machine's own apt archives,
the pinned SHA-256), here extracted whole into ``build/``. The port as shipped needs these changes, made to a copy
of its files:

- the native emitter is off for the nRF51 (``mpconfigport.h``): viper code would not link; it is turned on for
  ARMv6-M (``MICROPY_EMIT_THUMB``, without the ARMv7-M instructions);
- ``sys.stdin.buffer`` / ``sys.stdout.buffer`` are off: the packet protocol is binary; they are turned on;
- its linker script fixes 256 KB of RAM and ``main.c`` a 10 KB stack check: ours (``linker_script``) sets the
  SRAM, puts the stack region on top and fails the link if the heap runs into it, and the check follows it;
- its default frozen manifest requires micropython-lib, which the tarball leaves empty: ours freezes the
  firmware only;
- a Cortex-M's FPU is off at reset: for the hard-float ADCS image the startup code turns it on (``CPACR``).

Needs ``arm-none-eabi-gcc`` with newlib (``gcc-arm-none-eabi``, ``libnewlib-arm-none-eabi``), host ``gcc`` and
``make`` for mpy-cross, and ``qemu-system-arm`` to run the image: Debian packages, which the build installs itself
as root with apt-get at hand (a CI machine). ``--optional`` (what a ``make`` target that must not fail uses): a
build that cannot be done says why in one line, with the command that installs what is missing, and exits 0; the
PIL tests are then skipped with that reason.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys

from emulator import launcher
from emulator.runtime import child_options
from tools import natmod_build

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOARD = "MICROBIT"
FULL_DIR = os.path.join(ROOT, "build", "micropython-%s-full" % natmod_build.MP_VERSION)
OUT = os.path.join(ROOT, "build", "pil")
PACKAGES = ("gcc-arm-none-eabi", "libnewlib-arm-none-eabi", "qemu-system-arm")
MARCH = "armv6m"
RAM_START = 0x20000000
STACK_PAINT = 0x15A5C33C         # written over the free stack at start (firmware.pil_main): the high-water mark; a small int


class Memory:
    """One image's memory map: ``ram_bytes`` of SRAM (the linker script's, and QEMU's nRF51 given as much, so an
    access beyond faults), MicroPython's own variables (about 0.8 KB), the GC heap (a static array of
    ``heap_bytes``), and the stack, the top ``stack_bytes`` (MicroPython's stack check set 512 bytes inside it);
    what is left between them is unused. The image is ``build/pil/<name>/firmware.elf``; ``frozen`` (paths from
    the repository's root) and ``tests`` (tests/mp scripts) what it freezes, ``c_sources`` C files built in;
    ``flash_bytes`` the flash of the board it stands for (None: no limit checked)."""

    def __init__(self, name, ram_bytes, heap_bytes, stack_bytes, machine="microbit", ram_start=RAM_START,
                 frozen=(), tests=(), c_sources=(), flash_bytes=None, board=True):
        self.name, self.ram_bytes, self.heap_bytes, self.stack_bytes = name, ram_bytes, heap_bytes, stack_bytes
        self.machine = machine
        self.dir = os.path.join(OUT, name)
        self.image = os.path.join(self.dir, "firmware.elf")
        self.ram_start = ram_start
        self.stack_top = ram_start + ram_bytes
        self.stack_bottom = self.stack_top - stack_bytes
        self.frozen, self.tests, self.c_sources = tuple(frozen), tuple(tests), tuple(c_sources)
        self.flash_bytes = flash_bytes
        self.board = board             # a generated pil_board module (the memory map) frozen in


# the controller and what it imports on the board (the packet table's numbers, the H table, the viper law): what
# the thesis's board runs (``TARGET_MEM``)
CONTROLLER_FROZEN = ("firmware/__init__.py", "firmware/ad5664r.py", "firmware/hinv.py", "firmware/upload.py",
                     "firmware/controller.py", "firmware/controller_viper.py",
                     "firmware/hal/__init__.py", "firmware/hal/link.py", "firmware/hal/stdio.py",
                     "firmware/hal/nrf51.py", "firmware/hal/fast_tick.py", "firmware/hal/fast_status.py",
                     "firmware/pil_main.py",
                     "protocol/__init__.py", "protocol/compat.py", "protocol/consts.py",
                     "protocol/hblob.py", "protocol/htable.py", "protocol/fast.py")
# the lab board's besides: the disturbance player, measured there (tests/mp/pil_player_probe.py), and the framing's
# module (the tests' scripts frame with it; the controller's link frames with protocol.fast)
FROZEN = CONTROLLER_FROZEN + ("firmware/player.py", "firmware/player_viper.py", "firmware/ad660.py",
                              "protocol/distfile.py", "protocol/core.py", "protocol/table.py", "protocol/frame.py")
# the known-answer scripts the PIL tests run on the lab board (tests/mp: the same ones the unix port runs)
FROZEN_TESTS = ("firmware_plant.py", "pil_probe.py", "pil_player_probe.py", "firmware_fast_status.py")
SAMD21G18_FLASH = 256 * 1024      # the thesis's CtrlArduino: 256 KB of flash, 32 KB of SRAM

# The thesis's board (a SAMD21G18: 32 KB of SRAM, 256 KB of flash), what --runtime qemu runs: the controller's
# modules only; a heap of 20 KB (the 11x11 run needs between 17,281 and 17,408 bytes, measured on the 24 KB image:
# docs/PIL.md), a stack region of 6 KB (its high-water mark is about 4.7 KB, measured in every qemu run's
# summary.json)
TARGET_MEM = Memory("MICROBIT", launcher.PIL_RAM_BYTES, 20 * 1024, 6 * 1024, frozen=CONTROLLER_FROZEN,
                    flash_bytes=SAMD21G18_FLASH)
# the same firmware on 24 KB of SRAM (a smaller part of the family): the tests run the 11x11 table on it. A stack
# region of 5.5 KB: the high-water mark of its 5 s fps hil (4,664 bytes; 4,832 on an image with a 17,408-byte heap),
# the mailbox below it (452 bytes, firmware.pil_main) and 348 bytes to spare; the heap the rest, 18,240 bytes (the
# 11x11 run needs between 17,281 and 17,408: measured, docs/PIL.md)
SMALL_MEM = Memory("MICROBIT-24K", 24 * 1024, 18240, 5 * 1024 + 512, frozen=CONTROLLER_FROZEN,
                   flash_bytes=SAMD21G18_FLASH)
# the instruments' image (tests and make bench count instructions on it): the same code, room for their recorded
# samples and the float plant; 256 KB of SRAM, as the microbit machine of the port has
LAB_MEM = Memory("MICROBIT-LAB", 256 * 1024, 200 * 1024, 8 * 1024, frozen=FROZEN, tests=FROZEN_TESTS)
IMAGE = TARGET_MEM.image
LAB_IMAGE = LAB_MEM.image
SMALL_IMAGE = SMALL_MEM.image

# The ADCS computer: QEMU's mps2-an500 machine, a Cortex-M7 with a double-precision FPU (FPv5-D16), the closest
# QEMU has to a CubeSat ADCS board's Cortex-M7 (an STM32F7 at 216 MHz; QEMU models no caches, TCM or pipeline);
# MicroPython's floats single precision (the lean ADCS's float32), the C kernels (firmware/adcs/native/adcsk.c)
# built in as the module ``adcsk`` with hard-float doubles; 4 MB of SSRAM at 0, the port's own memory map
ADCS_BOARD = "MPS2-AN500"
ADCS_MACHINE = "mps2-an500"
ADCS_MARCH = "armv7emdp"
ADCS_FROZEN = ("firmware/__init__.py", "firmware/adcs/__init__.py", "firmware/adcs/app.py", "firmware/adcs/pil_main.py",
               "firmware/hal/__init__.py", "firmware/hal/slcan.py", "firmware/hal/mps2.py",
               "firmware/adcs/apkf_lean.py", "firmware/adcs/apkf_lean_model.py", "firmware/adcs/stkf_lean.py",
               "firmware/adcs/stkf_kernels.py", "firmware/adcs/control.py",
               "firmware/adcs/flight.py", "firmware/adcs/linalg.py", "firmware/adcs/intake.py",
               "firmware/adcs/health.py", "firmware/adcs/estimation.py", "firmware/adcs/modes.py",
               "firmware/adcs/allocation.py", "firmware/adcs/telemetry.py", "firmware/adcs/lockstep.py",
               "protocol/__init__.py", "protocol/compat.py", "protocol/consts.py", "protocol/frame.py",
               "protocol/fast.py", "protocol/core.py", "protocol/table.py", "protocol/can.py", "protocol/isotp.py",
               "protocol/lawicel.py", "protocol/paramfile.py", "protocol/spacecraft/__init__.py",
               "protocol/spacecraft/schema.py", "protocol/spacecraft/plausible.py", "protocol/units.py")
ADCS_FROZEN_TESTS = ("pil_adcs_probe.py",)
ADCS_MEM = Memory(ADCS_BOARD + "-ADCS", 4 * 1024 * 1024, 1024 * 1024, 64 * 1024, machine=ADCS_MACHINE, ram_start=0,
                  frozen=ADCS_FROZEN, tests=ADCS_FROZEN_TESTS, c_sources=("firmware/adcs/native/adcsk.c",),
                  board=False)
ADCS_DIR = ADCS_MEM.dir
ADCS_IMAGE = ADCS_MEM.image
ADCS_BOARD_MK = """# The ADCS computer's board (generated by tools/pil_build.py): mps2-an500, a Cortex-M7 with its FPU
QEMU_ARCH = arm
QEMU_MACHINE = %s
CFLAGS += -mthumb -mcpu=cortex-m7 -mfpu=fpv5-d16 -mfloat-abi=hard
CFLAGS += -DQEMU_SOC_MPS2
CFLAGS += -DMICROPY_HW_MCU_NAME='"Cortex-M7"'
LDSCRIPT = mcu/arm/mps2.ld
SRC_BOARD_O = shared/runtime/gchelper_native.o shared/runtime/gchelper_thumb2.o
MPY_CROSS_FLAGS += -march=%s
""" % (ADCS_MACHINE, ADCS_MARCH)
# the C kernels as a user C module: adcsk.c compiled in (ADCSK_BUILTIN), without fused multiply-add as the native
# module, sqrt as the FPU's instruction; the port's float warnings (-Werror) are about MicroPython's single floats,
# the kernels compute in double on purpose
ADCSK_MK = """ADCSK_DIR := $(USERMOD_DIR)
SRC_USERMOD_C += $(ADCSK_DIR)/adcsk_builtin.c
CFLAGS_USERMOD += -ffp-contract=off -fno-math-errno -Wno-double-promotion -Wno-float-conversion
"""
# mpconfigport.h: (what the port has, what the PIL image needs); on the controller's board no map lookup cache: its
# guesses are left by every lookup before, the bytecode path's included, so the same machine code took a few more or
# fewer instructions after a host's resends (measured: the same input's tick sums apart by more than the timer's
# resolution between two runs)
PATCHES = (
    ("#if !defined(QEMU_SOC_NRF51)\n#define MICROPY_EMIT_THUMB          (1)\n#define MICROPY_EMIT_INLINE_THUMB   (1)\n"
     "#endif\n",
     "#if !defined(QEMU_SOC_NRF51)\n#define MICROPY_EMIT_THUMB          (1)\n#define MICROPY_EMIT_INLINE_THUMB   (1)\n"
     "#else\n#define MICROPY_EMIT_THUMB          (1)\n#define MICROPY_EMIT_THUMB_ARMV7M   (0)\n#endif\n"),
    ("#define MICROPY_PY_SYS_STDIO_BUFFER (0)\n", "#define MICROPY_PY_SYS_STDIO_BUFFER (1)\n"
     "#if defined(QEMU_SOC_NRF51)\n#define MICROPY_OPT_MAP_LOOKUP_CACHE (0)\n#endif\n"),
)
# tools/mpy-tool.py (what freezes the modules): ARMv6-M native code aligned to 4 bytes, not 2. The armv6m emitter
# loads a constant it cannot build from 8-bit immediates (0x3FFFFFFF; a boxed 0xFFFF argument) PC-relative, its
# word's alignment reckoned from the code's start: at a start 2 bytes off a word, the word read is off by 2 bytes
# (measured on the Cortex-M0: a frozen firmware.hal.fast_tick.answer took the CRC-16's 0xFFFF as 0xF000)
MPY_TOOL_PATCHES = (("            MP_NATIVE_ARCH_ARMV6,\n            MP_NATIVE_ARCH_XTENSA,\n",
                     "            MP_NATIVE_ARCH_ARMV6,\n            MP_NATIVE_ARCH_ARMV6M,\n"
                     "            MP_NATIVE_ARCH_XTENSA,\n"),)
# main.c: (what the port has, what the PIL image needs): the stack check inside the linker script's stack
MAIN_PATCHES = (("    mp_stack_set_limit(10240);\n", "    mp_stack_set_limit(MICROPY_PIL_STACK_LIMIT);\n"),)
# mcu/arm/startup.c: a Cortex-M's FPU is off at reset; a hard-float image turns it on before any C code runs
STARTUP_PATCHES = (("    // jump to board initialisation\n",
                    "    #if defined(__ARM_FP)\n    *(volatile uint32_t *)0xE000ED88 |= 0xFu << 20; // CPACR: CP10, CP11 "
                    "(tools/pil_build.py)\n    __asm volatile (\"dsb\\n isb\");\n    #endif\n"
                    "    // jump to board initialisation\n"),)


def linker_script(mem=TARGET_MEM):
    """The board's memory: ports/qemu's nrf51.ld with ``mem.ram_bytes`` of SRAM and a stack region of
    ``mem.stack_bytes`` at its top (``_sstack`` .. ``_estack``); the link fails if the variables and the heap run
    into it."""
    return """/* The PIL board (tools/pil_build.py): an nRF51 memory map with %(ram)d KB of SRAM, the stack on top */
MEMORY
{
    ROM : ORIGIN = 0x00000000, LENGTH = 1M
    RAM : ORIGIN = 0x%(org)08X, LENGTH = %(ram)dK
}

_estack = ORIGIN(RAM) + LENGTH(RAM);
_sstack = _estack - %(stack)d;

SECTIONS
{
    .text : {
        . = ALIGN(4);
        KEEP(*(.isr_vector))
        *(.text*)
        *(.rodata*)
        . = ALIGN(4);
        _etext = .;
        _sidata = _etext;
    } > ROM

    .data : AT ( _sidata )
    {
        . = ALIGN(4);
        _sdata = .;
        *(.data*)
        . = ALIGN(4);
        _edata = .;
    } >RAM

    .bss :
    {
        . = ALIGN(4);
        _sbss = .;
        *(.bss*)
        *(COMMON)
        . = ALIGN(4);
        _ebss = .;
    } >RAM
}
ASSERT(_ebss <= _sstack, "the variables and the GC heap run into the stack: a smaller heap or stack")
""" % {"org": RAM_START, "ram": mem.ram_bytes // 1024, "stack": mem.stack_bytes}


def board_module(mem=TARGET_MEM):
    """``pil_board``, frozen into the image: the memory map the firmware paints and the host reads back."""
    return ('"""The PIL board\'s memory map (generated by tools/pil_build.py)."""\n'
            "RAM_START = 0x%08X\nRAM_BYTES = %d\nHEAP_BYTES = %d\nSTACK_BYTES = %d\nSTACK_BOTTOM = 0x%08X\n"
            "STACK_TOP = 0x%08X\nSTACK_PAINT = 0x%08X\n"
            % (RAM_START, mem.ram_bytes, mem.heap_bytes, mem.stack_bytes, mem.stack_bottom, mem.stack_top,
               STACK_PAINT))


class BuildError(Exception):
    pass


def missing_tools():
    """The Debian packages whose programs (or, for newlib, whose C library) are not there."""
    need = {"gcc-arm-none-eabi": "arm-none-eabi-gcc", "qemu-system-arm": "qemu-system-arm"}
    out = [p for p, exe in need.items() if shutil.which(exe) is None]
    if shutil.which("arm-none-eabi-gcc") is None:              # newlib comes with the compiler, not with it
        out.append("libnewlib-arm-none-eabi")
    else:                                                      # newlib: its libc beside the compiler's
        p = subprocess.run(["arm-none-eabi-gcc", "-print-file-name=libc.a"], capture_output=True, text=True,
                           **child_options())
        if not os.path.isabs(p.stdout.strip()):
            out.append("libnewlib-arm-none-eabi")
    for exe in ("gcc", "make"):
        if shutil.which(exe) is None:
            out.append(exe)
    return out


def install_hint(pkgs):
    return "apt-get install --no-install-recommends %s" % " ".join(pkgs)


def install_tools(missing):
    """As root with apt-get at hand (a CI machine): install the ``missing`` Debian packages from the machine's own apt
    sources, as ``make natmod`` fetches its source; returns what is still missing (all of it when this is not such
    a machine). BuildError if apt-get fails."""
    if not missing or os.geteuid() != 0 or shutil.which("apt-get") is None:
        return missing
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    # apt-get alone does not die with this process: a package install killed halfway leaves dpkg to be repaired
    install = ["apt-get", "install", "-y", "-q", "--no-install-recommends"] + list(missing)
    print("pil: installing %s (apt-get, as root)" % " ".join(missing), file=sys.stderr, flush=True)
    p = subprocess.run(install, capture_output=True, text=True, env=env)
    if p.returncode != 0:                 # the package lists may be stale or absent: once more after an update
        for cmd in (["apt-get", "update", "-q"], install):
            p = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if p.returncode != 0:
                raise BuildError("%s failed: %s" % (" ".join(cmd[:3]), (p.stderr or p.stdout).strip()[-1500:]))
    return missing_tools()


def fetch_full(dest=FULL_DIR):
    """MicroPython's whole source tree under ``dest`` (``natmod_build.fetch_source``: the machine's apt archives,
    the pinned SHA-256, extracted once)."""
    if os.path.exists(os.path.join(dest, "ports", "qemu", "Makefile")):
        return dest
    try:
        return natmod_build.fetch_source(dest, parts=None)
    except natmod_build.BuildError as exc:
        raise BuildError(str(exc)) from None


def manifest_text(mem, root=ROOT):
    """``mem``'s frozen manifest: its modules, by path from the repository's root (module names follow), its tests'
    scripts as top-level modules, and the generated ``pil_source`` (and ``pil_board``, for a board that has one) in
    its build directory."""
    text = "freeze(%r, (%s,))\n" % (root, ", ".join(repr(f) for f in mem.frozen))
    if mem.tests:
        text += "freeze(%r, (%s,))\n" % (os.path.join(root, "tests", "mp"), ", ".join(repr(f) for f in mem.tests))
    return text + "freeze(%r, (%s))\n" % (mem.dir, "'pil_board.py', 'pil_source.py'" if mem.board
                                          else "'pil_source.py',")


# the image carries the digest of what it was built from (a string in the frozen ``pil_source``, kept verbatim in
# the ELF's read-only data); a run refuses an image whose digest is not the tree's (``stale``)
SOURCE_TAG = "fps-pil-sources:"


def source_files(mem):
    """The repository's files ``mem``'s image is built from, by path from its root: the frozen modules, the tests'
    scripts, the C sources built in."""
    return list(mem.frozen) + ["tests/mp/" + t for t in mem.tests] + list(mem.c_sources)


def source_digests(mem, root=ROOT):
    """({path: SHA-256 of the file}, the digest of them all and of the generated memory map): what ``mem``'s image
    is built from. OSError if a file is missing."""
    import hashlib
    files, total = {}, hashlib.sha256()
    for rel in source_files(mem):
        with open(os.path.join(root, rel), "rb") as f:
            files[rel] = hashlib.sha256(f.read()).hexdigest()
        total.update(("%s %s\n" % (rel, files[rel])).encode())
    total.update(("%s %d %d %d\n" % (mem.name, mem.ram_bytes, mem.heap_bytes, mem.stack_bytes)).encode())
    if mem.board:
        total.update(board_module(mem).encode())
    return files, total.hexdigest()


def source_module(digest):
    """``pil_source``, frozen into an image: the digest of its sources (``source_digests``)."""
    return '"""The digest of the sources this image is built from (generated by tools/pil_build.py)."""\n' \
           'SOURCES = "%s%s"\n' % (SOURCE_TAG, digest)


def image_digest(path):
    """The source digest an image carries (None: none found)."""
    import re
    with open(path, "rb") as f:
        m = re.search(re.escape(SOURCE_TAG.encode()) + rb"([0-9a-f]{64})", f.read())
    return m.group(1).decode() if m else None


def stale(mem, root=ROOT):
    """Why ``mem``'s image cannot run the tree's code, in words naming ``make pil`` (None: it can): missing, or
    built from other sources than the tree's (the files that differ named, from the build's summary.json)."""
    rel = os.path.relpath(mem.image, root)
    if not os.path.exists(mem.image):
        return "no PIL image %s: build it with make pil" % rel
    files, digest = source_digests(mem, root)
    if image_digest(mem.image) == digest:
        return None
    try:
        with open(os.path.join(mem.dir, "summary.json")) as f:
            built = json.load(f)["source_files"]
        changed = sorted(k for k in set(files) | set(built) if files.get(k) != built.get(k))
    except (OSError, ValueError, KeyError, TypeError):
        changed = []
    return "the PIL image %s is stale: built from other sources than the tree's%s; rebuild it with make pil" % (
        rel, " (%s)" % ", ".join(changed[:6] + (["..."] if len(changed) > 6 else [])) if changed else "")


def section_sizes(image):
    """(.text, .data, .bss) of an ELF image in bytes (``arm-none-eabi-size``)."""
    p = subprocess.run(["arm-none-eabi-size", image], capture_output=True, text=True, **child_options())
    if p.returncode != 0:
        raise BuildError("arm-none-eabi-size %s failed: %s" % (image, p.stderr.strip()))
    text, data, bss = (int(v) for v in p.stdout.splitlines()[1].split()[:3])
    return text, data, bss


def memory_figures(mem, sizes):
    """An image's flash and RAM against its board's, from its section ``sizes`` (.text, .data, .bss): flash is
    .text + .data (the data's initial values), RAM .data + .bss (the GC heap among them) + the stack region
    (reserved; its high-water mark is measured at run time, ``tools.pil_board.read_target``)."""
    text, data, bss = sizes
    return {"text_bytes": text, "data_bytes": data, "bss_bytes": bss, "heap_bytes": mem.heap_bytes,
            "stack_bytes": mem.stack_bytes, "flash_bytes": text + data, "flash_limit_bytes": mem.flash_bytes,
            "ram_bytes": data + bss + mem.stack_bytes, "ram_limit_bytes": mem.ram_bytes,
            "flash_fits": mem.flash_bytes is None or text + data <= mem.flash_bytes,
            "ram_fits": data + bss + mem.stack_bytes <= mem.ram_bytes}


def check_fits(mem, figures):
    """BuildError, the image removed, when an image does not fit its board's flash or RAM."""
    over = []
    if not figures["flash_fits"]:
        over.append("flash (.text + .data) %d bytes of the board's %d" % (figures["flash_bytes"], mem.flash_bytes))
    if not figures["ram_fits"]:
        over.append("RAM (.data + .bss + stack) %d bytes of the board's %d" % (figures["ram_bytes"], mem.ram_bytes))
    if over:
        os.remove(mem.image)
        raise BuildError("%s does not fit its board: %s (fewer frozen modules, a smaller heap or stack)"
                         % (os.path.relpath(mem.image, ROOT), "; ".join(over)))


def finish_image(mem, digests):
    """After ``mem``'s image is linked: its sizes checked against the board (``check_fits``) and, with the digests
    of its sources, written to its build directory's summary.json (atomically)."""
    if not os.path.exists(mem.image):
        raise BuildError("the build left no %s" % mem.image)
    fig = memory_figures(mem, section_sizes(mem.image))
    files, digest = digests
    fig.update(image=os.path.relpath(mem.image, ROOT), machine=mem.machine, sources=digest)
    tmp = os.path.join(mem.dir, "summary.json.tmp")
    with open(tmp, "w") as f:
        json.dump(dict(fig, source_files=files), f, indent=1, sort_keys=True)
    os.replace(tmp, os.path.join(mem.dir, "summary.json"))
    check_fits(mem, fig)
    return fig


def patch_port(src):
    """ports/qemu's configuration and main.c with ``PATCHES`` and ``MAIN_PATCHES`` made, and mpy-tool.py with
    ``MPY_TOOL_PATCHES`` (the tree's own files kept as .orig); the frozen modules are generated again when
    mpy-tool.py changes."""
    q = os.path.join("ports", "qemu")
    for name, patches in ((os.path.join(q, "mpconfigport.h"), PATCHES), (os.path.join(q, "main.c"), MAIN_PATCHES),
                          (os.path.join(q, "mcu", "arm", "startup.c"), STARTUP_PATCHES),
                          (os.path.join("tools", "mpy-tool.py"), MPY_TOOL_PATCHES)):
        path = os.path.join(src, name)
        orig = path + ".orig"
        if not os.path.exists(orig):
            shutil.copyfile(path, orig)
        with open(orig) as f:
            text = f.read()
        for old, new in patches:
            if old not in text:
                raise BuildError("%s is not the 1.25.0 one this build patches (%r missing)"
                                 % (name, old.strip().splitlines()[0]))
            text = text.replace(old, new)
        if _write_if_changed(path, text) and patches is MPY_TOOL_PATCHES:
            for mem in (TARGET_MEM, SMALL_MEM, LAB_MEM):
                for f in ("frozen_content.c", "frozen_content.o", "firmware.elf"):
                    if os.path.exists(os.path.join(mem.dir, f)):
                        os.remove(os.path.join(mem.dir, f))


def _write_if_changed(path, text):
    """Write ``text`` unless the file holds it already (make rebuilds what depends on a newer file); True if
    written."""
    try:
        with open(path) as f:
            if f.read() == text:
                return False
    except OSError:
        pass
    with open(path, "w") as f:
        f.write(text)
    return True


def build(src=None, mems=(TARGET_MEM, SMALL_MEM, LAB_MEM)):
    """mpy-cross, then a MICROBIT image with the firmware frozen for each memory map, then the ADCS's; each checked
    against its board's flash and RAM, the figures in build/pil/summary.json; returns the target's path."""
    missing = install_tools(missing_tools())
    if missing:
        raise BuildError("missing %s (install: %s; as root with apt-get this build installs them itself)"
                         % (", ".join(missing), install_hint(missing)))
    src = src or fetch_full()
    patch_port(src)
    nolib = os.path.join(OUT, "no-micropython-lib")        # the build insists on micropython-lib's README only
    os.makedirs(nolib, exist_ok=True)
    with open(os.path.join(nolib, "README.md"), "w") as f:
        f.write("Empty: the PIL image freezes the firmware only (tools/pil_build.py).\n")
    _make(["make", "-s", "-C", os.path.join(src, "mpy-cross"), "-j2"])
    figures = {}
    for k, mem in enumerate(mems):
        if k and not os.path.isdir(mem.dir):
            _seed_objects(mems[0].dir, mem.dir)
        os.makedirs(mem.dir, exist_ok=True)
        man = os.path.join(mem.dir, "manifest.py")
        ld = os.path.join(mem.dir, "board.ld")
        digests = source_digests(mem)
        for path, text in ((man, manifest_text(mem)), (ld, linker_script(mem)),
                           (os.path.join(mem.dir, "pil_board.py"), board_module(mem)),
                           (os.path.join(mem.dir, "pil_source.py"), source_module(digests[1]))):
            _write_if_changed(path, text)
        config = ["MICROPY_HEAP_SIZE=%d" % mem.heap_bytes, "LDSCRIPT=" + ld,
                  "CFLAGS_EXTRA=-DMICROPY_PIL_STACK_LIMIT=%d" % (mem.stack_bytes - 512)]
        stamp = os.path.join(mem.dir, "config.stamp")     # make does not see a changed -D: every object built again
        try:
            with open(stamp) as f:
                same = f.read() == "\n".join(config)
        except OSError:
            same = False
        if not same:
            for root, _, files in os.walk(mem.dir):
                for f in files:
                    if f.endswith(".o") or f == "firmware.elf":
                        os.remove(os.path.join(root, f))
        _make(["make", "-s", "-C", os.path.join(src, "ports", "qemu"), "-j2", "BOARD=" + BOARD, "BUILD=" + mem.dir,
               "FROZEN_MANIFEST=" + man, "MPY_LIB_DIR=" + nolib, "MPY_CROSS_FLAGS=-march=" + MARCH] + config)
        with open(stamp, "w") as f:
            f.write("\n".join(config))
        figures[mem.name] = finish_image(mem, digests)
    figures[ADCS_MEM.name] = build_adcs(src, nolib)
    tmp = os.path.join(OUT, "summary.json.tmp")
    with open(tmp, "w") as f:
        json.dump(figures, f, indent=1, sort_keys=True)
    os.replace(tmp, os.path.join(OUT, "summary.json"))
    return IMAGE


# what differs between two MICROBIT images (main.c takes the heap size and the stack limit; the rest of the objects
# are the same): left out when a build directory is seeded from another
_PER_IMAGE = ("main.o", "main.P", "firmware.elf", "firmware.map", "firmware.bin", "frozen_content.c",
              "frozen_content.o", "frozen_content.P", "manifest.py", "board.ld", "pil_board.py", "config.stamp",
              "pil_source.py", "summary.json")


def _seed_objects(done, new):
    """A new image's build directory started from a built one's objects, times kept, so that make compiles only
    main.c and the frozen modules again (the lab image came out byte for byte as a build from nothing when this was
    written; the PIL tests run on it either way)."""
    import shutil
    shutil.copytree(done, new, ignore=lambda d, names: [n for n in names if d == done and n in _PER_IMAGE])


def build_adcs(src, nolib):
    """The ADCS computer's image (``ADCS_IMAGE``): the lean ADCS frozen for the Cortex-M7 (``ADCS_FROZEN``), its C
    kernels built in; the board's definition and the user C module generated under ``ADCS_DIR``. Returns its
    memory figures (``finish_image``)."""
    board = os.path.join(ADCS_DIR, "board")
    cmod = os.path.join(ADCS_DIR, "cmod", "adcsk")
    os.makedirs(board, exist_ok=True)
    os.makedirs(cmod, exist_ok=True)
    man = os.path.join(ADCS_DIR, "manifest.py")
    digests = source_digests(ADCS_MEM)
    for path, text in ((os.path.join(board, "mpconfigboard.mk"), ADCS_BOARD_MK),
                       (os.path.join(cmod, "micropython.mk"), ADCSK_MK),
                       (os.path.join(cmod, "adcsk_builtin.c"),
                        "// generated by tools/pil_build.py: the ADCS kernels built into the image\n"
                        "// adcsk.c's SHA-256 %s (a new adcsk.c rewrites this file: the port's qstr\n"
                        "// scan reads the changed sources only)\n"
                        "#define ADCSK_BUILTIN 1\n#include \"py/runtime.h\"\n#include \"%s\"\n"
                        % (digests[0]["firmware/adcs/native/adcsk.c"],
                           os.path.join(ROOT, "firmware", "adcs", "native", "adcsk.c"))),
                       (os.path.join(ADCS_DIR, "pil_source.py"), source_module(digests[1])),
                       (man, manifest_text(ADCS_MEM))):
        _write_if_changed(path, text)
    _make(["make", "-s", "-C", os.path.join(src, "ports", "qemu"), "-j2", "BOARD=" + ADCS_BOARD, "BOARD_DIR=" + board,
           "BUILD=" + ADCS_DIR, "FROZEN_MANIFEST=" + man, "MPY_LIB_DIR=" + nolib,
           "USER_C_MODULES=" + os.path.dirname(cmod), "MICROPY_HEAP_SIZE=%d" % ADCS_MEM.heap_bytes,
           "CFLAGS_EXTRA=-DMICROPY_PIL_STACK_LIMIT=%d" % (ADCS_MEM.stack_bytes - 1024)])
    return finish_image(ADCS_MEM, digests)


def _make(cmd):
    p = subprocess.run(cmd, capture_output=True, text=True, **child_options())
    if p.returncode != 0:
        raise BuildError("%s failed:\n%s" % (" ".join(cmd[:4]), (p.stderr or p.stdout).strip()[-3000:]))


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m tools.pil_build", description=__doc__.split("\n\n")[0])
    ap.add_argument("--optional", action="store_true",
                    help="a build that cannot be done says why (and what installs the tools) and exits 0")
    a = ap.parse_args(argv)
    try:
        path = build()
    except BuildError as exc:
        print("pil: %s" % exc, file=sys.stderr)
        return 0 if a.optional else 1
    with open(os.path.join(OUT, "summary.json")) as f:
        figures = json.load(f)
    for name, fig in figures.items():
        print("pil: %s: flash %d bytes%s, RAM %d of %d bytes (.data + .bss with a %d-byte heap + a %d-byte stack)"
              % (fig["image"], fig["flash_bytes"], " of %d" % fig["flash_limit_bytes"] if fig["flash_limit_bytes"]
                 else "", fig["ram_bytes"], fig["ram_limit_bytes"], fig["heap_bytes"], fig["stack_bytes"]))
    print("pil: %s" % os.path.relpath(path, ROOT))
    return 0


if __name__ == "__main__":
    sys.exit(main())
