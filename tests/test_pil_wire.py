"""The controller's link on the wire (tools/pil_wire.py): a common tick puts 23 + 30 bytes on the UART, 4.6 ms at
115,200 baud (2.9 ticks at 637.8 Hz); the loop closes at the baud that leaves the tick's computation room, a status
tick's CTRL_STATUS queued behind its FSM_SPI."""

import pytest

from tools import pil_wire


def test_a_common_tick_is_53_bytes_and_three_ticks_at_115200_baud():
    b = pil_wire.tick_bytes()
    assert b["common"] == 23 + 30 and b["status"] == 53 + 62
    f = pil_wire.figures(20000, 400000, common_max=30000)
    assert f["wire_s_common"] == pytest.approx(4.6e-3, abs=1e-4) and f["ticks_on_the_wire_common"] == \
        pytest.approx(2.93, abs=0.01)
    # 20,000 instructions at CPI 1.6 and 48 MHz: 0.667 ms of the 1.568 ms tick, 530 bits in the other 0.901 ms
    assert f["least_baud_common"] == pytest.approx(530 / (1 / 637.8 - 20000 * 1.6 / 48e6), rel=1e-9)
    assert f["least_standard_baud_common"] == 921600
    assert f["least_baud_worst"] is None and f["least_standard_baud_worst"] is None     # 13 ms of computation
    assert pil_wire.figures(None, None)["least_baud_common"] is None


T = 1 / 637.8


def test_the_schedule_lays_a_tick_as_bytes_in_computation_bytes_out():
    byte = 10 / 1e6                                        # 1 Mbaud
    worst, late = pil_wire.schedule([(0.5e-3, 0.0, False)], 1e6, T)
    assert worst == pytest.approx(23 * byte + 0.5e-3 + 30 * byte) and late == 0
    worst, late = pil_wire.schedule([(1.2e-3, 0.0, False)], 1e6, T)      # 0.23 + 1.2 + 0.3 ms > 1.568
    assert late == 1


def test_a_status_queued_behind_its_fsm_spi_delays_the_next_tick_only_while_it_is_on_the_wire():
    # at 1 Mbaud the status tick's CTRL_STATUS (62 bytes, 0.62 ms) leaves after its packing, 1.4 ms into the tick,
    # and holds the next FSM_SPI (ready 0.23 + 0.1 ms into its tick) until 2.02 ms, 0.45 ms into it
    ticks = [(0.3e-3, 1.1e-3, True), (0.1e-3, 0.0, False)]
    worst, late = pil_wire.schedule(ticks, 1e6, T)
    assert late == 0
    assert worst == pytest.approx(0.23e-3 + 1.4e-3 + 0.62e-3 - T + 0.30e-3)
    # at 100 kbaud the same ticks are late: the bytes alone take 5.3 ms
    assert pil_wire.schedule(ticks, 1e5, T)[1] == 2


def test_the_least_baud_of_the_worst_sequence_closes_it_and_a_lower_one_does_not():
    c, s = 30000 * 1.6 / 48e6, 40000 * 1.6 / 48e6
    b = pil_wire.least_baud_worst(c, s, T)
    ticks = pil_wire.worst_sequence(c, s)
    assert pil_wire.schedule(ticks, b, T)[1] == 0 and pil_wire.schedule(ticks, 0.99 * b, T)[1] > 0


def test_a_late_tick_on_the_wire_is_a_missed_row_in_fps_hils_verdict():
    from ground import hil_report
    board = {"baud": 2000000, "period_cycles": 75259, "worst_cycles": 70120, "late_ticks": 0, "ticks": 38474}
    s = {"complete": True, "requirement_met": True, "q2": {"max_radial_arcsec": 3.0}, "q2_samples": 10,
         "target": {"wire": {"board": board}}}
    assert [r[3] for r in hil_report.verdict_rows(s)] == [True, True]
    assert any(line.startswith("deadlines met on the wire") for line in hil_report.verdict_lines(s))
    s["target"]["wire"]["board"] = dict(board, worst_cycles=80000, late_ticks=3)
    rows = hil_report.verdict_rows(s)
    assert rows[1][1:] == (80000, 75259, False)
    assert any(line.startswith("DEADLINE MISSED on the wire") and "3 of 38474" in line
               for line in hil_report.verdict_lines(s))
    del s["target"]                          # the other runtimes: no board, no row
    assert len(hil_report.verdict_rows(s)) == 1 and hil_report.wire_deadline(s) is None
