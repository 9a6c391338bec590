# A small deterministic closed-loop plant for the firmware tests, pure Python (runs under CPython and
# micropython). Not the emulator: a first-order-lag mirror, a smooth H field, a disturbance in FSM volts
# and a 12-bit Q1 with the inverted X/Y channels of docs/INTERFACES.md, plus integer pseudo-noise.
import math

RATE_HZ = 637.8
CODES_PER_VOLT = 13107.2


def true_h(vx, vy):
    """H (ratio per volt) at FSM voltages (vx, vy): the thesis's centre value, bent a few percent."""
    return (-8.5221 * (1.0 + 0.06 * vx + 0.02 * vx * vx), 0.0717 + 0.01 * vy,
            -0.0370, 7.6871 * (1.0 - 0.01 * vy))


def calibration(n=11, step_v=1.0):
    """A calibration dict as `fps calibrate` writes it, over an n x n P-FSM grid (FSM Y runs reversed)."""
    grid = [(k - (n - 1) / 2) * step_v for k in range(n)]
    points = []
    for q in range(n):
        for p in range(n):
            v0 = (0.25 * grid[p] + 0.01 * grid[q], -0.22 * grid[q] + 0.008 * grid[p])
            a, b, c, d = true_h(v0[0], v0[1])
            points.append({"pfsm_v": [grid[p], grid[q]], "v0": [v0[0], v0[1]],
                           "H": [[a, b], [c, d]], "residual": 1e-4})
    return {"grid_v": grid, "dv": 0.01, "points": points}


class Plant:
    """Mirror + quadcell. ``sample()`` -> (vx, vy, vs) counts; ``apply(words)`` takes AD5664R words."""

    def __init__(self, seed=1, lag=0.14, noise=2, amp_v=0.6, vs=2500):
        self.x = seed & 0x7FFFFFFF or 1
        self.lag = lag
        self.noise = noise
        self.amp_v = amp_v
        self.vs0 = vs
        self.ux = 0.0     # commanded tilt voltages
        self.uy = 0.0
        self.px = 0.0     # mirror position, volts
        self.py = 0.0
        self.k = 0
        self.beam = True

    def _rand(self):
        self.x = (1103515245 * self.x + 12345) & 0x7FFFFFFF
        return (self.x >> 16) % (2 * self.noise + 1) - self.noise

    def disturbance(self):
        t = self.k / RATE_HZ
        return (self.amp_v * math.sin(2 * math.pi * 0.7 * t) + 0.05 * math.sin(2 * math.pi * 9.0 * t),
                -0.8 * self.amp_v * math.cos(2 * math.pi * 0.5 * t) + 0.04 * math.sin(2 * math.pi * 13.0 * t))

    def sample(self):
        dx, dy = self.disturbance()
        a, b, c, d = true_h(self.px, self.py)
        ex = self.px - dx
        ey = self.py - dy
        rx = a * ex + b * ey
        ry = c * ex + d * ey
        rx = max(-1.0, min(1.0, rx))
        ry = max(-1.0, min(1.0, ry))
        vs = self.vs0 + self._rand() if self.beam else 20
        vx = int(2048 - rx * vs + 0.5) + self._rand()
        vy = int(2048 - ry * vs + 0.5) + self._rand()
        return (max(0, min(4095, vx)), max(0, min(4095, vy)), max(0, min(4095, vs)))

    def apply(self, words):
        for w in words:
            cmd = (w >> 19) & 7
            addr = (w >> 16) & 7
            data = w & 0xFFFF
            if cmd == 0 or cmd == 2:
                if addr == 0:
                    self.ux = (data - 0x8000) / CODES_PER_VOLT
                elif addr == 3:
                    self.uy = (data - 0x8000) / CODES_PER_VOLT
        self.px = self.lag * self.px + (1.0 - self.lag) * self.ux
        self.py = self.lag * self.py + (1.0 - self.lag) * self.uy
        self.k += 1

    def residual_v(self):
        dx, dy = self.disturbance()
        return self.px - dx, self.py - dy
