"""The bench's two sensing chains, each defined once (Sec. 7.3, docs/INTERFACES.md "Q1 chain").

A chain takes the spot's beam-frame position, turns it into the quadcell's detector frame (its rotation and
offset), into quadrant volts (Eq. 7.3, the separable erfc model of ``Quadcell.outputs_fast``), and through its
amplifier and ADC into counts with noise (emulator.adc):
- Q1: inverted about mid-scale into the SAMD21, vx = mid - k Vx, vs = k Vs, clipped to 0..4095;
- Q2: the ADS1256, vx = k Vx, vs = k Vs, two's complement 24 bit.
The noise in counts is sd n, n standard normal, sd = sqrt((k (sigma0 + p r))^2 + sigma_adc^2) with r the
spot's distance from the detector centre.

``Chain.sample`` is the definition, one call per sample. The bench's fused tick loops
(``emulator.bench_loops``) inline the same arithmetic on ``Chain.consts`` and the same ``NoiseStream``; a test
holds them to ``sample`` bit for bit, and ``bench/bench_emulator.py`` measures what the inlining pays.
"""

from math import erfc, sqrt

from emulator.adc import ADS1256

NOISE_BLOCK = 3 * 4096          # normals drawn at a time: a multiple of 3, one sample's draws never straddle two


class NoiseStream:
    """Standard normals from a numpy Generator, drawn NOISE_BLOCK at a time into ``buf``; ``i`` the next one.
    Two streams sharing one Generator draw in the order they run out, so a run is the same for the same seed
    and call sequence."""

    __slots__ = ("rng", "buf", "i")

    def __init__(self, rng):
        self.rng = rng
        self.buf = []
        self.i = 0

    def refill(self):
        """A new block; returns it (``i`` back at 0)."""
        self.buf = self.rng.standard_normal(NOISE_BLOCK).tolist()
        self.i = 0
        return self.buf

    def take3(self):
        """The next three normals."""
        if self.i + 3 > len(self.buf):
            self.refill()
        i = self.i
        self.i = i + 3
        b = self.buf
        return b[i], b[i + 1], b[i + 2]


class Chain:
    """One quadcell, its amplifier and ADC, and its noise.

    ``geometry`` = (gp, gf): the beam-frame spot position per P-FSM and per MEMS mechanical tilt (m/rad);
    ``noise`` the chain's NoiseStream, or None for noiseless samples.
    """

    def __init__(self, quadcell, adc, geometry, noise):
        self.quadcell = quadcell
        self.adc = adc
        self.gp, self.gf = geometry
        self.noise = noise
        if isinstance(adc, ADS1256):
            mid, kxy, lo, hi = 0, adc.k, ADS1256.LO, ADS1256.HI
        else:
            mid, kxy, lo, hi = adc.mid, -adc.k, 0, adc.top
        q = quadcell
        fast = q.inline if q.inline is not None else (-1.0, 0.0, 0.0, 0.0, 0.0)
        # (cos, sin, off_x, off_y, r2 limit of the inline model, half gap, kx, ky, V/4,
        #  mid, k of X and Y, k of SUM, lo, hi, sigma0, position noise, ADC noise^2)
        self.consts = (q.cos, q.sin, q.off_x, q.off_y) + fast + (
            mid, kxy, adc.k, lo, hi, q.sigma0_v, q.pos_noise, adc.noise_counts * adc.noise_counts)

    def spot(self, xb, yb):
        """Detector-frame spot position for a beam-frame one (m)."""
        co, si, ox, oy = self.consts[:4]
        return co * xb + si * yb - ox, co * yb - si * xb - oy

    def volts(self, xd, yd):
        """(Vx, Vy, Vs) for a detector-frame spot (Eq. 7.3): the separable closed form, or the quadcell's own
        model where that does not hold."""
        lim, h, kx, ky, v = self.consts[4:9]
        if xd * xd + yd * yd > lim:
            return self.quadcell.outputs_fast(xd, yd)
        fxp = erfc(kx * (h - xd))
        fxn = erfc(kx * (h + xd))
        fyp = erfc(ky * (h - yd))
        fyn = erfc(ky * (h + yd))
        sx, sy = fxp + fxn, fyp + fyn
        return v * (fxn - fxp) * sy, v * (fyp - fyn) * sx, v * sx * sy

    def sd(self, r2):
        """1-sigma noise (counts) at a spot r2 (m^2) from the detector centre."""
        s0, pn, nc2 = self.consts[14:17]
        sv = self.consts[11] * (s0 + pn * sqrt(r2))
        return sqrt(sv * sv + nc2)

    def counts(self, vx, vy, vs, r2, nx=0.0, ny=0.0, ns=0.0):
        """Unclipped counts for quadrant volts, the spot at r2, and standard normals nx, ny, ns."""
        mid, kxy, k = self.consts[9:12]
        if self.noise is None:
            return round(mid + kxy * vx), round(mid + kxy * vy), round(k * vs)
        sd = self.sd(r2)
        return round(mid + kxy * vx + sd * nx), round(mid + kxy * vy + sd * ny), round(k * vs + sd * ns)

    def clip(self, cx, cy, cs):
        """Counts held to the ADC's range; a clipped sample is counted in ``adc.n_clip``."""
        lo, hi = self.consts[12:14]
        if cx < lo or cx > hi or cy < lo or cy > hi or cs < lo or cs > hi:
            self.adc.n_clip += 1
            return tuple(min(hi, max(lo, c)) for c in (cx, cy, cs))
        return cx, cy, cs

    def sample(self, xb, yb):
        """(vx, vy, vs) counts for the spot at beam-frame (xb, yb), noise drawn from the chain's stream."""
        xd, yd = self.spot(xb, yb)
        vx, vy, vs = self.volts(xd, yd)
        r2 = xd * xd + yd * yd
        if self.noise is None:
            return self.clip(*self.counts(vx, vy, vs, r2))
        return self.clip(*self.counts(vx, vy, vs, r2, *self.noise.take3()))

    def sample_channels(self, beams):
        """(vx, vy, vs) counts with each channel converted where the spot stood at its own instant: ``beams``
        the beam-frame positions at X's, Y's and SUM's. The three normals are drawn as ``sample`` draws them;
        X's and Y's enter with the opposite sign (the same distribution)."""
        nx, ny, ns = self.noise.take3() if self.noise is not None else (0.0, 0.0, 0.0)
        out = []
        for c, (xb, yb), n in zip(range(3), beams, (-nx, -ny, ns)):
            xd, yd = self.spot(xb, yb)
            out.append(self.counts(*self.volts(xd, yd), xd * xd + yd * yd, n, n, n)[c])
        return self.clip(*out)
