"""The controller's link on the wire (tools/pil_wire.py): a common tick puts 23 + 30 bytes on the UART, 4.6 ms at
115,200 baud (2.9 ticks at 637.8 Hz); the loop closes at the baud that leaves the tick's computation room."""

import pytest

from tools import pil_wire


def test_a_common_tick_is_53_bytes_and_three_ticks_at_115200_baud():
    b = pil_wire.tick_bytes()
    assert b["common"] == 23 + 30 and b["status"] == 53 + 62
    f = pil_wire.figures(20000, 400000)
    assert f["wire_s_common"] == pytest.approx(4.6e-3, abs=1e-4) and f["ticks_on_the_wire_common"] == \
        pytest.approx(2.93, abs=0.01)
    # 20,000 instructions at CPI 1.6 and 48 MHz: 0.667 ms of the 1.568 ms tick, 530 bits in the other 0.901 ms
    assert f["least_baud_common"] == pytest.approx(530 / (1 / 637.8 - 20000 * 1.6 / 48e6), rel=1e-9)
    assert f["least_standard_baud_common"] == 921600
    assert f["least_baud_status"] is None and f["least_standard_baud_status"] is None   # 13 ms of computation
    assert pil_wire.figures(None, None)["least_baud_common"] is None
