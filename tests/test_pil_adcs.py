"""The ADCS board's figures under QEMU: the cycle that starts the filters (the first out of INIT: the APKF's start,
11 M instructions on the Cortex-M7) is stated apart from the cycles' mean and largest; the host's ISO-TP timeouts
on a PIL board's CAN are ISO 15765-2's, not the 20 ms of the unix port's pty."""

from emulator import launcher
from emulator.adcs_replies import StatusWatch
from protocol import table


def _status(tick, mode, cycle_us):
    s = {"tick": tick, "adcs_mode": dict(table.ADCS_MODES)[mode], "stale": 0, "cycle_us": cycle_us,
         "magnetic_failed": 0, "wheels_failed": 0, "att_sigma": 0.0}
    s.update((n, 0.0) for n in ("q0", "q1", "q2", "q3", "wx", "wy", "wz", "rax", "ray", "raz", "rbx", "rby", "rbz"))
    return s


def test_the_filters_start_is_apart_from_the_cycles_largest():
    w = StatusWatch(lambda m: None, [])
    for k, (mode, us) in enumerate((("INIT", 642), ("HOLD", 11501), ("HOLD", 1907), ("HOLD", 1924))):
        w.take(_status(k, mode, us), float(k), 0.0)
    assert w.filters_start_us == 11501
    assert w.cycle_us == [3, 642 + 1907 + 1924, 1924]


def test_a_pil_boards_isotp_timeout_covers_its_longest_computation():
    # the filters' start, 11.6 M instructions, at QEMU's -icount speed on a loaded machine (tens of MIPS)
    assert launcher.PIL_ISOTP_TIMEOUT_MS >= 1000.0
