"""Fine-pointing edge cases: late duplicate ACKs, TICKs beyond the ADC, H-table size, --dv and --rate checks."""

from collections import deque

from firmware.controller import CALIBRATE, HOLD, Controller
from ground.rig import P_ACK, InprocController, Rig
from protocol import core


class _LateAckEndpoint(InprocController):
    """An in-process controller behind a link that is slow once and lossy once: the first command's ACK arrives
    only after the rig resent it (so two ACKs for it come back), and the next command's first frame is lost."""

    def __init__(self, ctrl):
        InprocController.__init__(self, ctrl)
        self.n_sent = 0
        self.held = deque()

    def send_ground(self, pid, payload, seq, dst=None):
        self.n_sent += 1
        if self.n_sent == 3:          # the second command's first copy: lost on the link
            return seq
        before = len(self.inbox)
        InprocController.send_ground(self, pid, payload, seq)
        if self.n_sent == 1:          # the first copy's ACK is late: it arrives after the resend
            while len(self.inbox) > before:
                self.held.append(self.inbox.pop())
        elif self.held:
            self.inbox.extend(self.held)
            self.held.clear()
        return seq


def test_a_late_duplicate_ack_is_not_taken_for_the_next_command():
    """Rig.command matched replies by packet id only: the second ACK of a resent CTRL_SETTINGS(CALIBRATE) was taken
    for the next CTRL_SETTINGS(HOLD) whose frame was lost, so the ground went on with the controller not in HOLD."""
    ctrl = Controller()
    rig = Rig(_LateAckEndpoint(ctrl))
    rig.cmd_timeout_s = 0.001
    rig.settings("CALIBRATE")         # ACK late: resent, both copies ACKed
    assert ctrl.mode == CALIBRATE and rig.n_cmd_retries == 1
    rig.settings("HOLD")              # first copy lost
    assert ctrl.mode == HOLD
    assert rig.n_cmd_retries == 2
    assert not [p for p in rig.replies if p[0] == P_ACK and p[4][0] == core.PACKET_ID["CTRL_SETTINGS"]]


def test_calibrate_refuses_a_bad_dv_as_bad_input(tmp_path, capsys):
    """--dv nan/0/-1/10 was refused only once the rig (and, for micropython, its process) ran, as a failed run
    (exit 1, "calibration stopped"); the README and --help promise exit 2 for bad input."""
    from ground.cli import main as fps
    for v in ("nan", "0", "-1", "10"):
        rc = fps(["calibrate", "-o", str(tmp_path / "cal.json"), "--grid", "2", "--dv", v, "--no-plots"])
        err = capsys.readouterr().err
        assert rc == 2 and "--dv" in err and "calibration stopped" not in err, (v, rc, err)
    assert not list(tmp_path.iterdir())


def _served_controller():
    """A TRACK controller (true H, CTRL_STATUS every 2 ticks) served by serve_controller on a thread over an
    in-process link: (the bench's end, the controller, the thread), its HELLO taken."""
    import threading

    from emulator.bench import Bench
    from emulator.truth import true_h_field
    from firmware.controller import TRACK
    from firmware.hal.link import serve_controller
    from firmware.hal.ports import _Ms
    from protocol import htable
    from protocol.link import inproc_pair
    a, b = inproc_pair("BENCH", "CONTROLLER")
    ctl = Controller(table=htable.pack_calibration(true_h_field(Bench(noise=False), None, 0.01)), decim=2)
    ctl.mode = TRACK
    th = threading.Thread(target=serve_controller, args=(ctl, _Ms(b)), daemon=True)
    th.start()
    assert a.recv(timeout=5)[0][0] == core.PACKET_ID["HELLO"]
    return a, ctl, th


def test_a_tick_with_counts_beyond_the_adc_is_dropped_not_stepped():
    """serve_controller stepped any TICK: vx = 65535 (damage the CRC-16 let through) made (2048 - vx) << 15
    about -2^31, outside the +-2^30 the step's docstring promises: on a 32-bit board a heap allocation under
    heap_lock (MemoryError, and the heap left locked) or, in viper, a wrapped ratio. It is now dropped and
    counted; the bench's resend of the same tick is answered."""
    import struct
    a, ctl, th = _served_controller()
    tick, spi, status = core.PACKET_ID["TICK"], core.PACKET_ID["FSM_SPI"], core.PACKET_ID["CTRL_STATUS"]
    fmt = core.PACKET[tick].fmt

    def answer(payload, wait_s=10.0):  # every reply: the FSM_SPI and a due CTRL_STATUS after it, or none in wait_s
        a.send_raw(tick, a.node, core.NODE["CONTROLLER"], payload)
        want = {spi, status} if ctl.status_due_at(struct.unpack(fmt, payload)[0]) else {spi}
        got = []
        while not want <= {p[0] for p in got}:
            more = a.recv(timeout=wait_s)
            if not more:
                break
            got += more
        return got

    assert [p[0] for p in answer(struct.pack(fmt, 0, 0, 2048, 2048, 3000))] == [spi, status]   # init tick
    # damaged: no answer, no step (a reply arriving after the short wait would show in the next answer and
    # in ctl.ticks / n_dup below, which the thread's order makes exact)
    assert answer(struct.pack(fmt, 1, 1568, 65535, 2048, 3000), 0.3) == []
    assert answer(struct.pack(fmt, 1, 1568, 2048, 4096, 3000), 0.3) == []
    assert ctl.ticks == 0
    got = answer(struct.pack(fmt, 1, 1568, 1900, 2100, 3000))               # the resend, undamaged
    assert [p[0] for p in got] == [spi] and ctl.ticks == 1 and ctl.n_dup == 0
    got = answer(struct.pack(fmt, 2, 3136, 1900, 2100, 3000))
    st = core.payload_dict(status, [p for p in got if p[0] == status][0][4])
    assert st["n_rx_drop"] == 2
    a.close()
    th.join(5)


def test_the_controllers_rx_drop_counts_what_a_serial_or_a_can_link_dropped():
    """CTRL_STATUS.n_rx_drop summed only the serial decoder's reasons: on a CAN link (python-can's, with
    can-isotp) frames that were not extended, had the reserved bit, or broke an ISO-TP transfer were not
    counted. Frames for other nodes, sent frames, the link's own send timeouts and sequence gaps are not drops."""
    from protocol import can
    _DROPS = can.LINK_DROPS                     # what firmware.hal.link's serve_controller counts
    serial = {k: 1 for k in core.DROP_REASONS}
    serial.update(frames=100, seq_gaps=3, seq_dups=2)
    assert can.rx_drops(serial, _DROPS) == len(core.DROP_REASONS)
    bus = {k: 1 for k in can.DROP_REASONS}
    bus.update(other_dst=5, tx_frames=9, isotp_ConsecutiveFrameTimeoutError=2, isotp_unexpected_frame=1,
               tx_isotp_timeouts=4, tx_isotp_TimeoutError=6, tx_isotp_UnexpectedFlowControlError=6)
    assert can.rx_drops(bus, _DROPS) == len(set(can.DROP_REASONS)) + 3


def test_a_damaged_tick_number_does_not_make_every_later_tick_stale():
    """A TICK whose tick number the CRC-16 let through damaged (here 10^6 for 2) became serve_controller's
    last: every real TICK after it was older, ignored unanswered, and the run ended as a dead link. Now a
    stale TICK is dropped and counted, and the bench's resend of it (a second stale TICK, not older) is
    stepped and answered; a lone stale TICK among good ones is only dropped."""
    import struct

    from firmware.controller import SAFE, TRACK, WHY_LINK
    a, ctl, th = _served_controller()
    tick, spi, status = core.PACKET_ID["TICK"], core.PACKET_ID["FSM_SPI"], core.PACKET_ID["CTRL_STATUS"]
    fmt = core.PACKET[tick].fmt

    def answer(k, wait=10.0):          # the SPI answer's tick number (None: no answer in ``wait`` s), status
        a.send_raw(tick, a.node, core.NODE["CONTROLLER"], struct.pack(fmt, k, 1568 * k, 1900, 2100, 3000))
        want = {spi, status} if ctl.status_due_at(k) else {spi}     # the status after the FSM_SPI
        got = []
        while not want <= {p[0] for p in got}:
            more = a.recv(timeout=wait)
            if not more:
                return None, None
            got += more
        st = [core.payload_dict(status, p[4]) for p in got if p[0] == status]
        return core.payload_dict(spi, [p for p in got if p[0] == spi][0][4])["tick"], (st[0] if st else None)

    assert [answer(k)[0] for k in (0, 1, 10 ** 6)] == [0, 1, 10 ** 6]     # 10^6: tick 2, damaged
    assert answer(2, 0.3)[0] is None                 # stale: dropped unanswered
    assert answer(2)[0] == 2                         # the bench's resend: the ticks go on from it
    k3, st = answer(3)[0], answer(4)[1]
    assert k3 == 3 and st["n_rx_drop"] == 1 and ctl.n_dup == 0
    assert answer(2, 0.3) == (None, None)            # a lone stale TICK is only dropped ...
    assert answer(5)[0] == 5 and ctl.n_gap == 0      # ... and the good ones go on
    assert answer(9)[0] == 9 and ctl.n_gap == 0      # a real gap counts once the next tick confirms it
    assert answer(10)[0] == 10 and ctl.n_gap == 3
    big = 10 + ctl.safe_ticks + 1
    assert answer(big)[0] == big and ctl.mode == TRACK
    assert answer(big + 1)[0] == big + 1 and ctl.mode == SAFE and ctl.why == WHY_LINK
    a.close()
    th.join(5)


def test_a_calibration_grid_the_controller_cannot_hold_is_refused_up_front(tmp_path, capsys):
    """--grid accepted up to 32 ("the controller's H table holds 32 per axis"), but the controller takes an
    H-table blob of 8192 bytes: 23x23 (8660 B) to 32x32 (16652 B) passed check_calibration, and fps hil then
    failed at the upload (HTABLE_BEGIN refused: TOO_LARGE, exit 1)."""
    import pytest

    from emulator.bench import Bench
    from emulator.truth import true_h_field
    from ground.calibrate import check_calibration
    from ground.cli import main as fps
    from protocol import htable
    grid = [-5.0 + 10.0 * k / 22 for k in range(23)]
    cal = true_h_field(Bench(noise=False), grid, 0.01)
    assert len(htable.pack_calibration(cal)) > Controller()._upload.max_bytes
    with pytest.raises(htable.HTableError, match="bytes"):
        check_calibration(cal)
    check_calibration(true_h_field(Bench(noise=False), grid[::2][:11] + [5.0], 0.01))   # 12x12: fine
    rc = fps(["calibrate", "-o", str(tmp_path / "cal.json"), "--grid", "23"])
    assert rc == 2 and "--grid" in capsys.readouterr().err and not list(tmp_path.iterdir())


def test_firmware_main_refuses_a_bad_rate():
    """firmware.main took any float for --rate: inf raised OverflowError (a traceback, exit 1) once the link
    was open, and a negative rate made each silent poll count negative ticks, so link silence never reached
    SAFE. The module promises exit 2 with the option named."""
    import pytest

    from firmware.main import main, parse
    for v in ("inf", "nan", "-5", "0", "x"):
        with pytest.raises(ValueError, match="--rate"):
            parse(["controller", "--link", "serial:/nonexistent", "--rate", v])
        assert main(["controller", "--link", "serial:/nonexistent", "--rate", v]) == 2
    assert parse(["controller", "--link", "serial:/x", "--rate", "637.8"])[1]["rate"] == 637.8
