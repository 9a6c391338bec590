"""The two ADC chains behind the quadcells (Sec. 7.3, docs/INTERFACES.md "Q1 chain").

Q1: inverting amplifier (gain G) into the SAMD21's 12-bit ADC, 0-3.3 V. The differences are inverted around
mid-scale, the sum is positive: vx = 2048 - G Vx / 3.3 * 4096, vy likewise, vs = G Vs / 3.3 * 4096, rounded and
clipped to 0..4095, plus noise. So Rx = (2048 - vx) / vs = Vx / Vs (Eq. 7.4).
Q2: ADS1256 24-bit two's complement, +FS = 2 VREF / PGA -> 0x7FFFFF, -FS -> 0x800000, clipping beyond; not
inverted, so Rx = vx / vs.
"""


class SAMD21:
    """12-bit unipolar ADC (the config holds adc_q1.bits at 12) behind the inverting amplifier; counts clipped
    samples."""

    def __init__(self, cfg, amp_gain):
        a = cfg["adc_q1"]
        self.full = 1 << a["bits"]
        self.mid = self.full >> 1
        self.top = self.full - 1
        self.k = amp_gain / a["vref_v"] * self.full     # counts per quadcell volt
        self.noise_counts = a["noise_counts"]
        self.n_clip = 0

    def convert(self, vx, vy, vs, nx=0.0, ny=0.0, ns=0.0):
        """Counts (vx, vy, vs) for quadcell volts plus noise given in counts (the bench inlines this)."""
        k, top = self.k, self.top
        counts = (round(self.mid - k * vx + nx), round(self.mid - k * vy + ny), round(k * vs + ns))
        if min(counts) < 0 or max(counts) > top:
            self.n_clip += 1
            counts = tuple(min(top, max(0, c)) for c in counts)
        return counts


class ADS1256:
    """24-bit two's complement ADC with FS = 2 VREF / PGA, after an amplifier of gain G (not inverted)."""

    LO = -0x800000
    HI = 0x7FFFFF

    def __init__(self, cfg, amp_gain):
        a = cfg["adc_q2"]
        self.k = amp_gain * a["pga"] / (2.0 * a["vref_v"]) * 0x800000
        self.noise_counts = a["noise_counts"]
        self.rate_hz = a["rate_hz"]
        self.n_clip = 0

    def code(self, v, noise=0.0):
        """Counts for volts plus noise in counts (the bench inlines this)."""
        c = round(self.k * v + noise)
        if c < self.LO or c > self.HI:
            self.n_clip += 1
            c = self.LO if c < self.LO else self.HI
        return c
