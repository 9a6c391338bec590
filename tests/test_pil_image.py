"""The PIL images against the tree and their boards (tools/pil_build.py): an image carries the digest of the
sources it was frozen from, and every ``--runtime qemu`` command refuses one that is not the tree's, or a missing
QEMU, with exit 2 and a message naming ``make pil``; each image's flash and RAM are checked against its board at
build and stated in build/pil/summary.json; a board whose firmware stops at boot is reported at once, with its
traceback."""

import json
import os
import shutil

import pytest

from emulator import launcher
from tools import pil_build

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
needs_image = pytest.mark.skipif(not os.path.exists(pil_build.IMAGE) or shutil.which("qemu-system-arm") is None,
                                 reason="no PIL image (make pil; it needs %s)"
                                        % pil_build.install_hint(pil_build.PACKAGES))


def _copy_sources(mem, dest):
    for rel in pil_build.source_files(mem):
        os.makedirs(os.path.join(dest, os.path.dirname(rel)), exist_ok=True)
        shutil.copyfile(os.path.join(ROOT, rel), os.path.join(dest, rel))


def test_a_changed_source_makes_the_image_stale(tmp_path):
    """A copy of the tree's sources is the image's; the controller's default gain changed in the copy is not, and the
    message names the file and make pil."""
    mem = pil_build.TARGET_MEM
    if pil_build.stale(mem) is not None:
        pytest.skip("the PIL image is not the tree's: %s" % pil_build.stale(mem))
    _copy_sources(mem, str(tmp_path))
    assert pil_build.stale(mem, root=str(tmp_path)) is None
    path = tmp_path / "firmware" / "controller.py"
    text = path.read_text()
    assert "gain_q15=16384" in text
    path.write_text(text.replace("gain_q15=16384", "gain_q15=8192"))
    why = pil_build.stale(mem, root=str(tmp_path))
    assert why is not None and "make pil" in why and "firmware/controller.py" in why


def _stale_copy(tmp_path, mem):
    """A Memory like ``mem`` whose image is a copy of its image with another digest in it."""
    new = pil_build.Memory(mem.name, mem.ram_bytes, mem.heap_bytes, mem.stack_bytes, machine=mem.machine,
                           ram_start=mem.ram_start, frozen=mem.frozen, tests=mem.tests, c_sources=mem.c_sources,
                           flash_bytes=mem.flash_bytes, board=mem.board)
    new.dir = str(tmp_path / mem.name)
    new.image = os.path.join(new.dir, "firmware.elf")
    os.makedirs(new.dir)
    data = open(mem.image, "rb").read()
    digest = pil_build.image_digest(mem.image).encode()
    with open(new.image, "wb") as f:
        f.write(data.replace(digest, b"0" * len(digest)))
    return new


@needs_image
@pytest.mark.parametrize("argv", [["calibrate", "--runtime", "qemu", "--grid", "3"],
                                  ["hil", "--runtime", "qemu", "--duration", "1", "--distfile", "x.dist",
                                   "--calibration", "x.json"]])
def test_qemu_commands_refuse_a_stale_image_with_exit_2(tmp_path, monkeypatch, capsys, argv):
    from ground import cli
    monkeypatch.setattr(pil_build, "TARGET_MEM", _stale_copy(tmp_path, pil_build.TARGET_MEM))
    assert cli.main(argv + ["-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "stale" in err and "make pil" in err and "Traceback" not in err


@pytest.mark.skipif(not os.path.exists(pil_build.ADCS_IMAGE), reason="no ADCS PIL image (make pil)")
def test_fps_adcs_can_refuses_a_stale_image_or_no_qemu_with_exit_2(tmp_path, monkeypatch, capsys):
    from ground import cli
    monkeypatch.setattr(pil_build, "ADCS_MEM", _stale_copy(tmp_path, pil_build.ADCS_MEM))
    argv = ["adcs", "can", "--runtime", "qemu", "--session", "2", "--no-plots", "-o", str(tmp_path / "out")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "stale" in err and "make pil" in err
    monkeypatch.setattr(launcher.shutil, "which", lambda exe: None)           # no QEMU on this machine
    for a in (argv, ["system", "--runtime", "qemu", "--duration", "2", "-o", str(tmp_path / "s")]):
        assert cli.main(a) == 2
        err = capsys.readouterr().err
        assert "qemu-system-arm" in err and "make pil" in err and "Errno" not in err


def test_an_image_over_its_boards_flash_fails_the_build(tmp_path):
    mem = pil_build.Memory("X", 32 * 1024, 19 * 1024, 6 * 1024, flash_bytes=pil_build.SAMD21G18_FLASH)
    mem.image = str(tmp_path / "firmware.elf")
    open(mem.image, "wb").close()
    fig = pil_build.memory_figures(mem, (269196, 16, 20252))
    assert fig["flash_bytes"] == 269212 and not fig["flash_fits"] and fig["ram_fits"]
    with pytest.raises(pil_build.BuildError, match="flash .* 269212 bytes of the board's 262144"):
        pil_build.check_fits(mem, fig)
    assert not os.path.exists(mem.image)                  # no image left that a run would take
    assert pil_build.memory_figures(mem, (228084, 16, 20252))["flash_fits"]


@pytest.mark.skipif(not os.path.exists(os.path.join(pil_build.OUT, "summary.json")), reason="no PIL build (make pil)")
def test_the_build_states_each_images_flash_and_ram_against_its_board():
    s = json.load(open(os.path.join(pil_build.OUT, "summary.json")))
    t = s[pil_build.TARGET_MEM.name]
    assert t["flash_limit_bytes"] == 262144 and t["flash_bytes"] == t["text_bytes"] + t["data_bytes"] <= 262144
    assert t["ram_limit_bytes"] == 32768 and t["ram_bytes"] <= 32768
    assert s[pil_build.SMALL_MEM.name]["ram_bytes"] <= 24 * 1024
    assert "protocol/spacecraft/plausible.py" in pil_build.ADCS_MEM.frozen
    assert "firmware/player.py" not in t.get("source_files", pil_build.TARGET_MEM.frozen)


@needs_image
def test_a_board_whose_firmware_stops_at_boot_is_reported_with_its_traceback(tmp_path):
    """The controller's firmware started on the 24 KB board with a heap too small for its link: the traceback, at
    once, not after the HELLO retries."""
    import time
    from protocol.link import open_serial
    mem = pil_build.SMALL_MEM
    if not os.path.exists(mem.image):
        pytest.skip("no 24 KB image (make pil)")
    cmd = launcher.qemu_command(mem.image, serial="pty", icount=True, ram_bytes=mem.ram_bytes)
    t0 = time.monotonic()
    code = "import micropython\nx = bytearray(%d)\nimport firmware.pil_main" % (mem.heap_bytes // 4)
    with pytest.raises(OSError, match="stopped at boot: .*MemoryError"):
        proc, link = launcher.start_board(cmd, code, lambda path: open_serial(path, "BENCH", baudrate=115200),
                                          console_log=False, speaks_first_s=20.0)
        link.close()
        proc.stop()
    assert time.monotonic() - t0 < 10.0


@pytest.mark.skipif(not os.path.exists(pil_build.ADCS_IMAGE) or shutil.which("qemu-system-arm") is None,
                    reason="no ADCS PIL image (make pil)")
def test_a_boards_console_shows_its_traceback_within_2_s():
    """The ADCS board's UART is also logged (its CAN link reads the same pty): a firmware that stops is seen in
    the log, which the session's HELLO loop reads, without waiting out its HELLO retries."""
    import time
    cmd = launcher.qemu_command(pil_build.ADCS_IMAGE, serial="pty", icount=True, machine=launcher.ADCS_MACHINE)
    proc, _ = launcher.start_board(cmd, "raise ValueError('a bad configuration')", lambda path: None)
    try:
        t0 = time.monotonic()
        while not proc.crashed() and time.monotonic() - t0 < 2.0:
            time.sleep(0.05)
        assert "ValueError: a bad configuration" in proc.crashed()
    finally:
        proc.kill()
        proc.stop()
