# Runs under micropython: the control tick allocates nothing. 10,000 ticks through Controller.tick() (which
# locks the heap, so any allocation would raise MemoryError) with a preallocated Q1 sample source and SPI sink
# (a fake HAL), every mode path exercised; gc.mem_alloc() must not grow either, also with Controller.step
# called unlocked. A deliberately allocating loop is measured the same way as a positive control, and an
# allocating HAL must fail under the lock.
import gc
import json

import firmware_plant as fp
from firmware.controller import SAFE, TRACK, Controller
from protocol import htable

N = 10000


class FakeHal:
    def __init__(self, samples):
        self.src = samples          # flat list vx, vy, vs, vx, ...
        self.i = 0
        self.n = len(samples)
        self.sink = bytearray(12)   # the SPI bytes of one tick, MSB first
        self.words_out = 0

    def read_q1(self, out):
        i = self.i
        out[0] = self.src[i]
        out[1] = self.src[i + 1]
        out[2] = self.src[i + 2]
        i += 3
        self.i = i if i < self.n else 0

    def spi_write(self, words, n):
        b = self.sink
        for k in range(n):
            w = words[k]
            b[3 * k] = (w >> 16) & 0xFF
            b[3 * k + 1] = (w >> 8) & 0xFF
            b[3 * k + 2] = w & 0xFF
        self.words_out += n


# Precompute samples from a closed-loop run (allocation allowed here), then blank the beam for a while.
grid = htable.grid_from_calibration(fp.calibration())
ctl = Controller(table=grid, safe_ticks=65535)
plant = fp.Plant(seed=9)
samples = []
for k in range(2000):
    s = plant.sample()
    if 1500 <= k < 1600:
        s = (s[0], s[1], 10)
    samples.extend(s)
    plant.apply(ctl.on_tick(k, 0, s[0], s[1], s[2]))

hal = FakeHal(samples)
ctl = Controller(hal, table=grid, safe_ticks=65535)
ctl.tick()
ctl.mode = TRACK
ticks = range(N)
half = N // 2
gc.collect()
m0 = gc.mem_alloc()
for k in ticks:
    ctl.tick()
    if k == half:
        ctl.mode = SAFE         # the ramp path too
m1 = gc.mem_alloc()

# Controller.step unlocked: large frames may borrow heap blocks, but nothing stays allocated.
def unlocked(ctl, src, n, ticks):
    i = 0
    for k in ticks:
        ctl.step(src[i], src[i + 1], src[i + 2])
        i = i + 3 if i + 3 < n else 0


unlocked(ctl, hal.src, hal.n, range(10))
gc.collect()
s0 = gc.mem_alloc()
unlocked(ctl, hal.src, hal.n, ticks)
s1 = gc.mem_alloc()

# An allocating HAL is caught by the lock.
class LeakyHal(FakeHal):
    def spi_write(self, words, n):
        self.last = list(words)


caught = False
try:
    Controller(LeakyHal(samples), table=grid).tick()
except MemoryError:
    caught = True

# Positive control: one small tuple per iteration is seen.
gc.collect()
c0 = gc.mem_alloc()
keep = None
for k in ticks:
    keep = (k, k + 1, k + 2)
c1 = gc.mem_alloc()

print(json.dumps({"ticks": N, "alloc_bytes": m1 - m0, "control_alloc_bytes": c1 - c0,
                  "step_alloc_bytes": s1 - s0, "leak_caught": caught,
                  "words_out": hal.words_out, "mode": ctl.mode, "n_lost": ctl.n_lost,
                  "last_code_xp": ctl.words[0] & 0xFFFF}))
