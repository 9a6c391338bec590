"""The two steering mirrors: the P-FSM behind its AD660 DACs, the MEMS FSM behind its AD5664R driver.

Linear dynamics are cascades of second-order sections with unit DC gain, written in modal form: each
conjugate pole pair becomes one complex state z (z' = lam z + b u, output 2 Re(c z)). With the input held
over an interval dt (zero-order hold) the exact update is z <- exp(lam dt) z + (exp(lam dt) - 1)/lam b u,
which costs one complex multiply-add per mode in plain Python.
"""

import cmath
import math

import numpy as np

DEG = math.pi / 180.0

# AD5664R commands (DB21-19) and addresses (DB18-16), AD5664R datasheet Rev. C p. 21.
CMD_WRITE = 0
CMD_UPDATE = 1
CMD_WRITE_UPDATE_ALL = 2
CMD_WRITE_UPDATE = 3
CMD_POWER = 4
CMD_RESET = 5
CMD_LDAC = 6
CMD_REFERENCE = 7
ADDR_ALL = 7
CH_XP, CH_XN, CH_YN, CH_YP = 0, 1, 2, 3   # A = X+, B = X-, C = Y-, D = Y+ (NODE fsm.cpp mapping)
_ALL_UP = [True, True, True, True]


class Modal:
    """Cascade of second-order sections w^2/(s^2 + 2 zeta w s + w^2) in modal coordinates.

    ``sections`` is a list of (natural frequency in Hz, damping ratio). Attributes ``lam``, ``b``, ``c`` are
    lists over the kept modes (one per conjugate pair, weight 2 folded into c).
    """

    def __init__(self, sections):
        n = 2 * len(sections)
        a = np.zeros((n, n))
        bvec = np.zeros(n)
        for i, (f_hz, zeta) in enumerate(sections):
            w = 2.0 * math.pi * f_hz
            k = 2 * i
            a[k, k + 1] = 1.0
            a[k + 1, k] = -w * w
            a[k + 1, k + 1] = -2.0 * zeta * w
            if i == 0:
                bvec[k + 1] = w * w
            else:
                a[k + 1, k - 2] = w * w
        cvec = np.zeros(n)
        cvec[n - 2] = 1.0
        self.a, self.b_ss, self.c_ss = a, bvec, cvec
        lam, vec = np.linalg.eig(a)
        bm = np.linalg.solve(vec, bvec)
        cm = cvec @ vec
        self.lam, self.b, self.c = [], [], []
        for i in range(n):
            if lam[i].imag < -1e-9 * abs(lam[i]):
                continue
            weight = 2.0 if lam[i].imag > 1e-9 * abs(lam[i]) else 1.0
            self.lam.append(complex(lam[i]))
            self.b.append(complex(bm[i]))
            self.c.append(complex(cm[i] * weight))

    def step(self, dt):
        """Per-mode (phi, gamma) for a held input over dt: z <- phi z + gamma u."""
        out = []
        for lam, b in zip(self.lam, self.b):
            phi = cmath.exp(lam * dt)
            out.append((phi, (phi - 1.0) / lam * b))
        return out

    def output(self, z):
        return sum((c * zi).real for c, zi in zip(self.c, z))

    def steady(self, u):
        """Modal state at rest under a constant input u."""
        return [-b / lam * u for lam, b in zip(self.lam, self.b)]

    def response(self, f_hz):
        """Complex frequency response at f_hz (continuous time)."""
        s = 2j * math.pi * f_hz
        g = 1.0
        n = len(self.a) // 2
        for i in range(n):
            w2 = -self.a[2 * i + 1, 2 * i]
            g *= w2 / (s * s - self.a[2 * i + 1, 2 * i + 1] * s + w2)
        return g

    def bandwidth_hz(self):
        """-3 dB frequency (first crossing of |G| = 1/sqrt 2), found by bisection on a log scan."""
        f = 1.0
        while abs(self.response(f)) >= 0.5 ** 0.5:
            f *= 1.01
            if f > 1e7:
                return float("inf")
        lo, hi = f / 1.01, f
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if abs(self.response(mid)) >= 0.5 ** 0.5:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)


class PFSM:
    """OIM5001 voice-coil mirror behind two AD660 16-bit DACs: offset binary, 0x8000 = 0 V, +-range_v."""

    def __init__(self, cfg):
        p = cfg["pfsm"]
        self.range_v = p["range_v"]
        self.rad_per_v = [p["range_deg"] / p["range_v"] * (1.0 + g) * DEG for g in p["gain_error"]]
        self.modal = Modal([(p["natural_hz"], p["damping"])])

    def code_to_v(self, code):
        """AD660 offset binary to volts: (code - 0x8000) / 0x8000 * range_v."""
        return (code - 0x8000) * (self.range_v / 32768.0)

    def v_to_code(self, v):
        """Volts to the nearest AD660 code, clipped to 0..0xFFFF."""
        return min(0xFFFF, max(0, int(round(v / self.range_v * 32768.0)) + 0x8000))

    def angle(self, v, axis):
        """Static mechanical tilt (rad) for a drive voltage on one axis."""
        return v * self.rad_per_v[axis]


class AD5664R:
    """The AD5664R quad 16-bit DAC as the MEMS driver sees it: decodes 24-bit SPI words.

    Power-on state (datasheet): input and DAC registers zero, channels powered up, internal reference off,
    LDAC mask clear. With the reference off the outputs read 0 V (no external reference on the board).
    Words with bits above 24 set, or an address other than A-D or all, are counted in ``n_unknown`` and ignored.
    """

    def __init__(self):
        self.n_words = 0
        self.n_unknown = 0
        self.power_on()

    def power_on(self):
        self.input = [0, 0, 0, 0]
        self.dac = [0, 0, 0, 0]
        self.powered = [True, True, True, True]
        self.ref_on = False
        self.ldac_mask = 0

    def _channels(self, addr):
        return (0, 1, 2, 3) if addr == ADDR_ALL else (addr,)

    def write_many(self, words):
        """Clock in words in order, as ``write`` each; plain data writes (write input register with the LDAC
        mask bit clear, write and update all) to a channel A-D are decoded inline, the common case."""
        inp = self.input
        fast = 0
        for w in words:
            if 0 <= w <= 0xFFFFFF:
                t = (w >> 16) & 0x3F                # command DB21-19, address DB18-16
                if t < 4 and not self.ldac_mask >> t & 1:
                    inp[t] = w & 0xFFFF
                    fast += 1
                    continue
                if 16 <= t < 20:                    # CMD_WRITE_UPDATE_ALL to one channel
                    inp[t - 16] = w & 0xFFFF
                    self.dac[:] = inp
                    fast += 1
                    continue
            self.write(w)
            inp = self.input                        # a reset replaces the registers
        self.n_words += fast

    def write(self, word):
        """Clock in one 24-bit word (latched on the 24th falling SCLK edge)."""
        self.n_words += 1
        if not 0 <= word <= 0xFFFFFF:
            self.n_unknown += 1
            return
        cmd = (word >> 19) & 7
        addr = (word >> 16) & 7
        data = word & 0xFFFF
        if cmd <= CMD_WRITE_UPDATE:
            if addr > 3 and addr != ADDR_ALL:
                self.n_unknown += 1
                return
            chans = self._channels(addr)
            if cmd != CMD_UPDATE:
                for ch in chans:
                    self.input[ch] = data
            if cmd == CMD_WRITE_UPDATE_ALL:
                self.dac[:] = self.input
            elif cmd == CMD_UPDATE or cmd == CMD_WRITE_UPDATE:
                for ch in chans:
                    self.dac[ch] = self.input[ch]
            else:  # write input register: transparent where the LDAC mask bit is set
                for ch in chans:
                    if self.ldac_mask >> ch & 1:
                        self.dac[ch] = self.input[ch]
        elif cmd == CMD_POWER:       # DB5-4 mode (00 = normal), DB3-0 channel select
            up = (data >> 4) & 3 == 0
            for ch in range(4):
                if data >> ch & 1:
                    self.powered[ch] = up
        elif cmd == CMD_RESET:       # DB0 = 1: power-on reset, 0: DAC and input registers only
            if data & 1:
                self.power_on()
            else:
                self.input = [0, 0, 0, 0]
                self.dac = [0, 0, 0, 0]
        elif cmd == CMD_LDAC:
            self.ldac_mask = data & 0xF
        else:                        # CMD_REFERENCE: DB0 = 1 internal reference on
            self.ref_on = bool(data & 1)

    def outputs(self):
        """Channel codes as seen at the outputs (0 when the reference is off or the channel powered down)."""
        if not self.ref_on:
            return [0, 0, 0, 0]
        if self.powered == _ALL_UP:
            return self.dac[:]
        return [c if p else 0 for c, p in zip(self.dac, self.powered)]


class MEMS:
    """Mirrorcle 13L2.2 behind the AD5664R driver: differential drive to tilt volts to angle.

    Tilt volts per axis = full_scale_tilt_v * (code X+ - code X-) / (2 full_scale_codes) (Y: D - C), so
    X+ = bias + x, X- = bias - x gives x * full_scale_tilt_v / full_scale_codes whatever the bias.
    Static angle (rad) = deg_per_v (1 + gain error) (V + q V^2 + c V^3), then axis cross-coupling, clipped to
    +-range_deg (the bench counts clipped ticks). Dynamics: the driver's low-pass (2nd-order Butterworth) then
    the mirror's resonance.
    """

    def __init__(self, cfg):
        m = cfg["mems"]
        self.v_per_diff = m["full_scale_tilt_v"] / (2.0 * m["full_scale_codes"])
        self.k = [m["deg_per_v"] * (1.0 + g) * DEG for g in m["gain_error"]]
        self.q = list(m["quadratic_per_v"])
        self.c3 = list(m["cubic_per_v2"])
        self.cross = list(m["cross_coupling"])
        self.limit = m["range_deg"] * DEG
        self.modal = Modal([(m["driver_cutoff_hz"], 0.5 ** 0.5),
                            (m["resonance_hz"], 0.5 / m["resonance_q"])])

    def tilt_v(self, codes):
        """Tilt volts (X, Y) from the four channel output codes [A, B, C, D]."""
        return ((codes[CH_XP] - codes[CH_XN]) * self.v_per_diff,
                (codes[CH_YP] - codes[CH_YN]) * self.v_per_diff)

    def static_angle(self, vx, vy):
        """Mechanical tilt (rad) for tilt volts, with the angle-voltage curve, cross-coupling and clip.

        Returns (theta_x, theta_y, clipped).
        """
        ax = self.k[0] * (vx + self.q[0] * vx * vx + self.c3[0] * vx * vx * vx)
        ay = self.k[1] * (vy + self.q[1] * vy * vy + self.c3[1] * vy * vy * vy)
        ax, ay = ax + self.cross[0] * ay, ay + self.cross[1] * ax
        lim = self.limit
        if ax > lim or ax < -lim or ay > lim or ay < -lim:
            return min(lim, max(-lim, ax)), min(lim, max(-lim, ay)), True
        return ax, ay, False


INIT_WORDS = (0x280001, 0x380001, 0x20000F, 0x300000)   # reset, reference on, power up A-D, LDAC setup
BIAS_CODE = 32767                                        # 80 V of a 160 V full scale (Mirrorcle driver)


def fsm_words(vx, vy, cfg, bias=BIAS_CODE):
    """AD5664R words for tilt volts (vx, vy): X+ = bias + x, X- = bias - x (command 000), Y+ = bias + y
    (000), Y- = bias - y with command 010 (write and update all), as the NODE driver does."""
    m = cfg["mems"]
    per = m["full_scale_codes"] / m["full_scale_tilt_v"]
    x = int(round(vx * per))
    y = int(round(vy * per))
    return ((CMD_WRITE << 19) | (CH_XP << 16) | _code16(bias + x),
            (CMD_WRITE << 19) | (CH_XN << 16) | _code16(bias - x),
            (CMD_WRITE << 19) | (CH_YP << 16) | _code16(bias + y),
            (CMD_WRITE_UPDATE_ALL << 19) | (CH_YN << 16) | _code16(bias - y))


def _code16(c):
    return min(0xFFFF, max(0, c))
