# Runs on the PIL board (QEMU's microbit machine, tools/pil_build.py) under -icount shift=0, where one instruction
# takes one virtual ns: the nRF51's TIMER0 at 16 MHz then counts one tick per 62.5 instructions. ``counts(n)``
# measures the controller's instructions per control step over n recorded Q1 samples, for the viper controller
# (armv6m machine code) and the bytecode one, each less the same loop without the step, and the heap they hold.
import gc

import firmware_plant as fp
from firmware.controller import TRACK, Controller
from firmware.hal import nrf51
from protocol import htable

INSN_PER_TICK = nrf51.INSN_PER_TICK


def timer_start():
    nrf51.start(32)


def timer_now():
    return nrf51.now() & 0xFFFFFFFF


def _run(c, src, n):
    m = len(src)
    i = 0
    t0 = timer_now()
    for k in range(n):
        c.step(src[i], src[i + 1], src[i + 2])
        i += 3
        if i >= m:
            i = 0
    return timer_now() - t0


def recorded_loop(C, ticks):
    """A controller of class ``C`` on the plant's calibration table closes the loop on ``firmware_plant.Plant(seed=5)``
    in TRACK for ``ticks`` ticks: (a fresh ``C`` in TRACK, the Q1 samples the first one read: vx, vy, vs, ...), to
    replay them from their start."""
    grid = htable.grid_from_calibration(fp.calibration())
    c = C(table=grid, safe_ticks=65535)
    p = fp.Plant(seed=5)
    src = []
    c.step(2048, 2048, 0)
    c.mode = TRACK
    for k in range(ticks):
        s = p.sample()
        src.extend(s)
        p.apply(c.on_tick(k, 0, s[0], s[1], s[2]))
    c = C(table=grid, safe_ticks=65535)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    return c, src


class _Nothing:
    def step(self, vx, vy, vs):
        return 0


def counts(n=2000, viper=True):
    """Instructions per control step (mean over n steps, the loop's own cost taken off), for the viper controller
    when ``viper`` (else the bytecode one); the heap in use after the controller is built with its table."""
    gc.collect()
    heap0 = gc.mem_alloc()
    if viper:
        from firmware.controller_viper import ViperController as C
    else:
        C = Controller
    c, src = recorded_loop(C, 300)
    gc.collect()
    heap = gc.mem_alloc() - heap0
    timer_start()
    loop = _run(_Nothing(), src, n)
    step = _run(c, src, n)
    return {"n": n, "viper": viper, "insn_per_step": (step - loop) * INSN_PER_TICK / n,
            "insn_loop_per_step": loop * INSN_PER_TICK / n, "heap_bytes": heap, "heap_free": gc.mem_free(),
            "words": list(c.words)}


def replay(blob, src, viper=True, gain_q15=16384):
    """The controller built from the H-table ``blob`` (``protocol.htable.pack``) in TRACK, stepped over the Q1
    samples ``src`` (vx, vy, vs, ...): the CRC-32 of every word it clocks out, its last words, the CRC of its gain
    table (H^-1 per grid point) and the instructions per step (less the loop's own), for the host to compare."""
    from binascii import crc32
    if viper:
        from firmware.controller_viper import ViperController as C
    else:
        C = Controller
    c = C(table=htable.parse(blob), safe_ticks=65535, gain_q15=gain_q15)
    c.step(2048, 2048, 0)
    c.mode = TRACK
    t = c.table
    tab = crc32(bytes(str([t.nx, t.ny] + list(t.ax) + list(t.ay) + list(t.rdx) + list(t.rdy) + list(t.h)), "ascii"))
    buf = bytearray(3)
    crc = 0
    n = len(src) // 3
    timer_start()
    loop = _run(_Nothing(), src, n)
    t0 = timer_now()
    for k in range(n):
        c.step(src[3 * k], src[3 * k + 1], src[3 * k + 2])
        for w in c.words:
            buf[0] = w >> 16
            buf[1] = (w >> 8) & 0xFF
            buf[2] = w & 0xFF
            crc = crc32(buf, crc)
    steps = timer_now() - t0
    return {"crc": crc & 0xFFFFFFFF, "words": list(c.words), "table_crc": tab & 0xFFFFFFFF, "n": n,
            "mode": c.mode, "insn_per_step_with_crc": (steps - loop) * INSN_PER_TICK / n}
