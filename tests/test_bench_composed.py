"""The bench's fused tick loops against the tick written one part per call (``Bench(fused=False)``): the same
samples, truth, records, counters and end state, bit for bit, on every timing path."""

import numpy as np
import pytest

from emulator.bench import Bench
from emulator.mirrors import INIT_WORDS, fsm_words
from emulator.sensing import Chain

BLOCK = 40


class Wobble:
    """Answers INIT_WORDS, then a command that moves every tick, beyond the MEMS range for a while, and
    misses some ticks: every path through a tick (new words, the same words, clipping, overruns)."""

    def __init__(self, cfg):
        self.cfg = cfg

    def on_tick(self, tick, t_us, vx, vy, vs):
        if tick == 0:
            return list(INIT_WORDS)
        if 30 <= tick < 36:
            return None
        if 60 <= tick < 64:
            return list(fsm_words(2.6, 0.0, self.cfg))
        if 80 <= tick < 90:
            return list(fsm_words(0.5, -0.5, self.cfg))          # the same words again
        return list(fsm_words(0.03 + 1e-3 * (vx % 17), -0.002 + 1e-3 * (vy % 5), self.cfg))


def _run(fused, timing, rate_hz, noise):
    b = Bench({"board": {"timing": timing}}, seed=11, rate_hz=rate_hz, noise=noise, fused=fused)
    c = Wobble(b.config)
    rows, q1, fsm = [], [], []
    rng = np.random.default_rng(3)
    for blk in range(4):
        counts = rng.integers(14, 18, BLOCK)
        x = (32768 + 3000 * np.sin(np.arange(counts.sum()) * 0.01 + blk)).astype(np.uint16)
        b.load_pfsm(x, x[::-1].copy(), counts)
        b.run_ticks(BLOCK, rows, c.on_tick, blk * BLOCK, 1e6 / rate_hz, q1, fsm)
    m = b.m
    return rows, q1, fsm, b.counters(), b.n_missed, (m.zmx1, m.zmx2, m.zmy1, m.zmy2, m.tpx, m.tpy, b.q2_next)


@pytest.mark.parametrize("timing, rate_hz", [("zero-latency", 637.8), ("arduino-zero", 637.8),
                                             ("arduino-zero", 200.0)])
@pytest.mark.parametrize("noise", [True, False])
def test_the_fused_loops_equal_the_composed_tick_bit_for_bit(timing, rate_hz, noise):
    fused, composed = _run(True, timing, rate_hz, noise), _run(False, timing, rate_hz, noise)
    assert fused == composed
    rows, _, _, counters, missed, _ = fused
    assert len(rows) > 100 and missed == 6 and counters["mems_clip_ticks"] > 0


def test_the_two_timed_landings_are_both_taken():
    """637.8 Hz on the arduino-zero board lands the words a tick later, 200 Hz within the tick."""
    assert Bench(rate_hz=637.8).tab.land_d == 1
    assert Bench(rate_hz=200.0).tab.land_d == 0


def test_a_chain_clips_to_its_adc_and_counts_it():
    b = Bench(noise=False)
    ch = b.chain1
    far = ch.sample(1.0, 1.0)                  # the spot far off the detector: no light
    assert far == (ch.adc.mid, ch.adc.mid, 0)
    n0 = ch.adc.n_clip
    assert ch.clip(-5, 5000, 7) == (0, ch.adc.top, 7)
    assert ch.adc.n_clip == n0 + 1
    assert isinstance(b.chain2, Chain) and b.chain2.consts[12:14] == (-0x800000, 0x7FFFFF)
