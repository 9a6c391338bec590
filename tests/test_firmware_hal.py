"""HAL backends with small fakes (no board exists here), the in-process Bench HAL, and firmware.main's options."""

import pytest

from firmware import ad5664r
from firmware.controller import TRACK, Controller
from firmware.hal import backend
from firmware.hal.board import MachineHal, run
from firmware.main import parse
from protocol import core, htable
from tests.mp import firmware_plant as fp


class FakeADC:
    def __init__(self, value):
        self.value = value

    def read_u16(self):
        return self.value << 4 | 0xA           # the low nibble is below the 12-bit resolution


class FakeSPI:
    def __init__(self, sync):
        self.sync = sync
        self.frames = []

    def write(self, buf):
        assert self.sync.level == 0, "SYNC must be low while a word is clocked"
        self.frames.append(bytes(buf))


class FakePin:
    def __init__(self):
        self.level = None

    def value(self, v):
        self.level = v


class FakeUART:
    def __init__(self):
        self.rx = bytearray()
        self.tx = bytearray()

    def any(self):
        return len(self.rx)

    def read(self, n):
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out

    def write(self, b):
        self.tx.extend(b)


def _board(vx=2048, vy=2048, vs=2500):
    sync, en = FakePin(), FakePin()
    spi = FakeSPI(sync)
    uart = FakeUART()
    hal = MachineHal(FakeADC(vx), FakeADC(vy), FakeADC(vs), spi, sync, en, uart)
    return hal, spi, uart, en


def test_machine_hal_reads_12_bit_counts_and_clocks_24_bit_words_msb_first():
    hal, spi, uart, en = _board(1000, 3000, 2500)
    q = [0, 0, 0]
    hal.read_q1(q)
    assert q == [1000, 3000, 2500]
    hal.spi_write([0x123456, 0xABCDEF], 2)
    assert spi.frames == [b"\x12\x34\x56", b"\xab\xcd\xef"] and hal.sync.level == 1


def test_board_loop_ticks_handles_uart_packets_and_sends_status():
    grid = htable.grid_from_calibration(fp.calibration())
    hal, spi, uart, en = _board(2048 - 50, 2048 + 30, 2500)
    ctl = Controller(hal, table=grid, decim=5)
    uart.rx.extend(core.encode_packet("CTRL_SETTINGS", core.NODE["GROUND"], core.NODE["CONTROLLER"], 9,
                                      mode=TRACK, decim=5))
    assert run(ctl, hal, rate_hz=5000, ticks=20) == 20
    assert en.level == 1 and ctl.mode == TRACK
    assert len(spi.frames) == 4 * 20
    words = [int.from_bytes(f, "big") for f in spi.frames]
    assert words[:4] == list(ad5664r.INIT_WORDS)
    assert [ad5664r.decode(w)[:2] for w in words[-4:]] == [(0, 0), (0, 1), (0, 3), (2, 2)]
    # the spot sits at +X (vx below mid-scale): the law drives X, the pair stays centred on the bias
    xp, xn = words[-4] & 0xFFFF, words[-3] & 0xFFFF
    assert xp + xn == 2 * ad5664r.BIAS_CODE and xp != ad5664r.BIAS_CODE
    pkts = core.Decoder().feed(bytes(uart.tx))
    kinds = [p[0] for p in pkts]
    assert kinds[0] == core.PACKET_ID["ACK"] and kinds.count(core.PACKET_ID["CTRL_STATUS"]) >= 3


def test_inproc_hal_drives_the_emulator_bench():
    from emulator import bench as bench_mod
    bench = bench_mod.Bench(seed=2)
    hal = backend("inproc").BenchHal(bench)
    ctl = Controller(hal)
    for _ in range(5):
        ctl.tick()
    assert bench.counters()["spi_words"] == 20


def test_backend_names_and_main_options():
    assert backend("board").MachineHal is MachineHal
    with pytest.raises(ValueError, match="unknown HAL backend"):
        backend("usb")
    role, o = parse(["controller", "--link", "serial:/dev/pts/3", "--table", "t.json", "--track", "--gain",
                     "8192", "--decim", "0"])
    assert role == "controller" and o["link"] == "serial:/dev/pts/3" and o["track"]
    assert o["ctl"] == {"gain_q15": 8192, "decim": 0}
    for argv, match in ((["controller"], "--link"), (["robot", "--link", "x"], "controller or player"),
                        (["controller", "--link", "x", "--gain", "high"], "--gain"),
                        (["controller", "--link", "x", "--track"], "--table"),
                        (["controller", "--link", "x", "--bogus", "1"], "unknown option")):
        with pytest.raises(ValueError, match=match):
            parse(argv)


def test_firmware_main_reports_a_link_failure_while_serving_on_stderr_with_exit_1(monkeypatch, capsys):
    """A link that fails while serving (a port error, a peer that stopped reading) is not a usage error: exit 1
    with the reason on stderr, which ground.runtime keeps and fps hil reports (stdout goes to /dev/null). A bad
    option or link spec (before serving) is still exit 2 with the usage."""
    from firmware.hal import link as hal_link
    from firmware.hal import ports
    from firmware.main import main

    def port_failed(*a, **k):
        raise OSError("the link failed: the peer read nothing for 5 s")
    monkeypatch.setattr(ports, "open_link", lambda spec, node, **kw: object())
    monkeypatch.setattr(hal_link, "serve_controller", port_failed)
    monkeypatch.setattr(hal_link, "serve_player", port_failed)
    for role in ("controller", "player"):
        assert main([role, "--link", "slcan:/dev/pts/99"]) == 1
        out, err = capsys.readouterr()
        assert out == "" and "firmware.main: error: the link failed" in err and "usage" not in err
    assert main(["controller", "--link", "slcan:/dev/pts/99", "--isotp-timeout-ms", "0"]) == 2
    assert "--isotp-timeout-ms" in capsys.readouterr()[1]
    assert main(["controller", "--link", "slcan:/dev/pts/99", "--gain", "x"]) == 2
    out, err = capsys.readouterr()        # on stderr, which ground.runtime keeps (it drops stdout)
    assert out == "" and "usage: firmware.main" in err and "--gain" in err


def test_serve_controller_raises_when_its_link_failed_and_not_when_the_peer_left():
    """The link's ``closed_why`` (set when it closed for more than the peer leaving) becomes the OSError that
    firmware.main turns into exit 1; a peer that left in order ends the serve quietly (exit 0)."""
    from firmware.controller import Controller
    from firmware.hal import link as hal_link

    class Closed:
        node = 0x10
        closed = True

        def __init__(self, why):
            self.closed_why = why

        def send_raw(self, *a):
            pass

        def close(self):
            pass

    hal_link.serve_controller(Controller(), Closed(None))
    with pytest.raises(OSError, match="the link failed: port gone"):
        hal_link.serve_controller(Controller(), Closed("port gone"))


