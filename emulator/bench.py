"""The emulated fine pointing bench (Ch. 7, Fig. 7-2/7-3): P-FSM -> resizer -> MEMS FSM -> splitter -> Q1, Q2.

Physics in SI units and radians; the truth is reported in arcsec on the sky (Eq. 7.5). One control tick is
advanced at a time: the P-FSM takes its AD660 codes at equal sub-steps across the tick, the MEMS FSM holds the
input decoded from the last AD5664R words. Both mirrors' linear dynamics are updated exactly in modal form
(emulator.mirrors.Modal); the P-FSM's per-tick input sums are precomputed with numpy for a block of ticks
(``load_pfsm``), the per-tick work (``q1_sample``, ``spi_words``, ``step``) is plain Python floats;
``run_ticks`` runs a block of ticks against a controller with that work inlined (the lockstep's fast path,
``emulator.bench_loops``); ``static_q1``, ``null_q1`` and ``true_h`` are the noiseless static truth
(``emulator.bench_static``).

The board's timing (``emulator.timing``): with ``zero-latency`` the Q1 sample is taken at the tick start and the
controller's words act at once (``run_ticks``' original loop); otherwise ``_run_ticks_timed`` samples X, Y and SUM
at their own instants (P-FSM and MEMS states exact there) and applies the words at their landing instant, in this
tick or a later one. ``spi_write``/``spi_words`` called directly still act at once (devices on a link, tests).

Randomness: one numpy Generator per bench (seeded), drawn in fixed-size blocks, so the same seed, config and
call sequence give bit-identical samples.
"""

import math
from math import erfc, sqrt

import numpy as np

from emulator.adc import ADS1256, SAMD21
from emulator.bench_loops import FusedLoops
from emulator.bench_static import StaticTruth
from emulator.config import default_config, validate
from emulator.mirrors import AD5664R, MEMS, PFSM
from emulator.optics import Optics
from emulator.quadcell import Quadcell
from emulator.timing import board_timing
from protocol.units import ARCSEC_PER_RAD

_NOISE_BLOCK = 3 * 4096
RATE_HZ_MAX = 1e5                     # control tick rate limit (Hz)


class Bench(FusedLoops, StaticTruth):
    """The optical bench. ``config`` is a (partial) config dict or None for the "thesis bench" preset.

    ``rate_hz`` is the control tick rate (the Lockstep sets it); ``noise=False`` gives noiseless samples.
    Counters: ``counters()``.
    """

    def __init__(self, config=None, seed=0, rate_hz=637.8, noise=True):
        self.config = validate(config) if config is not None else default_config()
        cfg = self.config
        self.seed = seed
        self.optics = Optics(cfg)
        self.pfsm = PFSM(cfg)
        self.mems = MEMS(cfg)
        self.dac = AD5664R()
        las = cfg["laser"]
        self.q1 = Quadcell(cfg["q1"], self.optics.spot["q1"], las["ellipse_angle_deg"], self.optics.power["q1"])
        self.q2 = Quadcell(cfg["q2"], self.optics.spot["q2"], las["ellipse_angle_deg"], self.optics.power["q2"])
        self.adc1 = SAMD21(cfg, cfg["q1"]["amp_gain"])
        self.adc2 = ADS1256(cfg, cfg["q2"]["amp_gain"])
        self.q2_hz = cfg["adc_q2"]["rate_hz"]
        self.noise = noise
        self.rng = np.random.default_rng(seed)
        self._n1 = []
        self._n1_i = 0
        self._n2 = []
        self._n2_i = 0
        pm = self.pfsm.modal
        assert len(pm.lam) == 1 and len(self.mems.modal.lam) == 2
        self._cp = pm.c[0]
        self._cm1, self._cm2 = self.mems.modal.c
        self.tick = 0
        self.q2_next = 0
        self.zpx = self.zpy = 0j          # P-FSM modal states at the current tick boundary
        self.tpx = self.tpy = 0.0         # P-FSM mechanical tilts now (rad)
        self.zmx1 = self.zmx2 = self.zmy1 = self.zmy2 = 0j
        self.u_mx = self.u_my = 0.0
        self.fsm_v = (0.0, 0.0)
        self.mems_clipped = False
        self.n_mems_clip_ticks = 0
        self.n_missed = 0                 # ticks without words in run_ticks
        self.n_pfsm_clip = 0
        self._last_words = None
        self._last_unknown = 0
        self._blk_n = 0
        self._blk_i = 0
        # Boresight: the beam angle after the FSM that centres the spot on Q1 (R = 0, the loop's goal).
        q, d = self.q1, cfg["q1"]["distance_m"]
        self.bore = ((q.cos * q.off_x - q.sin * q.off_y) / d, (q.sin * q.off_x + q.cos * q.off_y) / d)
        self._sky = self.optics.sky_per_rad * ARCSEC_PER_RAD
        self._ang_mag2 = 2.0 * self.optics.ang_mag
        self._g1 = self._geometry("q1")
        self._g2 = self._geometry("q2")
        self._fast1 = self.q1.outputs_fast
        self._fast2 = self.q2.outputs_fast
        a1, a2 = self.adc1, self.adc2        # constants of the sensing chains, for the per-tick code
        self._adc1 = (a1.mid, a1.k, a1.top, self.q1.sigma0_v, self.q1.pos_noise, a1.noise_counts * a1.noise_counts)
        self._adc2 = (a2.k, self.q2.sigma0_v, self.q2.pos_noise, a2.noise_counts * a2.noise_counts)
        self.timing = board_timing(cfg)
        self._pending = []                # (tick, words) the controller answered, landing later (timed board)
        self.set_rate(rate_hz)

    # --- timing ------------------------------------------------------------------------------------
    def set_rate(self, rate_hz):
        """Set the control tick rate; precompute the exact per-tick and per-sub-step transitions."""
        if not 1.0 <= rate_hz <= RATE_HZ_MAX:
            raise ValueError("rate_hz = %r is out of range [1, %g]" % (rate_hz, RATE_HZ_MAX))
        self._sync_pfsm()
        self.rate_hz = float(rate_hz)
        self.T = 1.0 / self.rate_hz
        (self._phi_p, _), = self.pfsm.modal.step(self.T)
        (pm1, gm1), (pm2, gm2) = self.mems.modal.step(self.T)
        self._mems_step = (pm1, gm1, pm2, gm2)
        self._sub = {}
        self._mems_rows = []
        tm = self.timing
        self._timed = not tm.zero
        if self._timed:
            self._land_d, self._land_f = tm.split(self.T)
            mm = self.mems.modal
            flat = lambda dt: tuple(c for pair in mm.step(dt) for c in pair)      # (e1, g1, e2, g2) over dt
            f = self._land_f
            # per channel: MEMS (e1, g1, e2, g2) from the tick start, and g1, g2 from the landing (if after it)
            self._q1_mem = [(flat(t), flat(t - f)[1::2] if t >= f else (0j, 0j)) for t in tm.sample_s]
            c1, c2 = self._cm1, self._cm2
            # per channel: the MEMS tilt at its instant = Re(c1 e1 z1 + c2 e2 z2) + u_old Re(c1 g1 + c2 g2)
            # + (u_new - u_old) Re(c1 l1 + c2 l2) (the input is real)
            self._q1_gains = [(c1 * e1, c2 * e2, (c1 * h1 + c2 * h2).real, (c1 * l1 + c2 * l2).real)
                              for (e1, h1, e2, h2), (l1, l2) in self._q1_mem]
            self._mem_tail = flat(self.T - f)[1::2]

    def _substeps(self, ns):
        """Tables for ticks of n equal P-FSM sub-steps, n in the tuple ``ns``, zero-padded to nmax = max(ns) and
        stacked along the first axis (cached per ns): w_end[u, i] weight of u_i in z_n; w_part[u, j, i] weight
        of u_i in z_j (i < j); powers[u, j] = phi^j; ``_mems_rows[mems_row[u] + j]`` the MEMS (e1, g1, e2, g2)
        over j sub-steps."""
        tab = self._sub.get(ns)
        if tab is None:
            nmax = ns[-1]
            w_end = np.zeros((len(ns), nmax), complex)
            w_part = np.zeros((len(ns), nmax + 1, nmax), complex)
            powers = np.zeros((len(ns), nmax + 1), complex)
            mems_row = []
            for u, n in enumerate(ns):
                dt = self.T / n
                (phi, gam), = self.pfsm.modal.step(dt)
                pw = phi ** np.arange(n + 1)
                powers[u, :n + 1] = pw
                w_end[u, :n] = gam * pw[n - 1::-1]
                for j in range(1, n + 1):
                    w_part[u, j, :j] = gam * pw[j - 1::-1]
                mems_row.append(len(self._mems_rows))
                self._mems_rows.extend(tuple(c for pair in self.mems.modal.step(j * dt) for c in pair)
                                       for j in range(n + 1))
            tab = self._sub[ns] = (w_end, w_part, powers, np.array(mems_row))
        return tab

    # --- noise ---------------------------------------------------------------------------------------
    def _refill(self):
        return self.rng.standard_normal(_NOISE_BLOCK).tolist()

    # --- P-FSM input ---------------------------------------------------------------------------------
    def _sync_pfsm(self):
        """Bring the P-FSM modal state to the current tick from the loaded block's boundary states."""
        if self._blk_n:
            i = self._blk_i
            self.zpx, self.zpy = self._zx[i], self._zy[i]
            self._blk_n = self._blk_i = 0

    def load_pfsm(self, xcodes, ycodes, counts):
        """Queue AD660 codes for the next len(counts) ticks: tick k takes counts[k] codes at equal sub-steps.

        Precomputes the P-FSM's exact modal input sums per tick and the states at the Q2 sample instants.
        """
        counts, x, y = self._codes(xcodes, ycodes, counts)
        kv = self.pfsm.range_v / 32768.0
        lo, hi = int(counts.min()), int(counts.max())
        if hi - lo < 8:                             # the lockstep's counts: floor(r) and floor(r) + 1
            ns, inv = tuple(range(lo, hi + 1)), counts - lo
        else:
            ns, inv = np.unique(counts, return_inverse=True)
            ns = tuple(ns.tolist())
        w_end, w_part, powers, mems_row = self._substeps(ns)
        nmax = w_end.shape[1]
        pad = np.zeros(nmax)
        ux = np.concatenate(((x - 32768.0) * (kv * self.pfsm.rad_per_v[0]), pad))   # padded for the gathers
        uy = np.concatenate(((y - 32768.0) * (kv * self.pfsm.rad_per_v[1]), pad))
        offs = np.concatenate(([0], np.cumsum(counts)))
        n_ticks = len(counts)
        # per-tick input sums, each row over its tick's codes (weights beyond n are zero)
        idx = offs[:-1, None] + np.arange(nmax)
        w = w_end[inv]
        sx = (ux[idx] * w).sum(axis=1)              # elementwise, not BLAS: no thread pool per block
        sy = (uy[idx] * w).sum(axis=1)
        # P-FSM states at every tick boundary of the block: z[k+1] = Phi z[k] + s[k] (exact, Phi = exp(lam T))
        self._sync_pfsm()
        phi, cp = self._phi_p, self._cp
        zx, zy = self.zpx, self.zpy
        zxs = [zx] + [zx := phi * zx + a for a in sx.tolist()]
        zys = [zy] + [zy := phi * zy + b for b in sy.tolist()]
        zxa, zya = np.array(zxs), np.array(zys)
        self._zx, self._zy = zxs, zys
        self._tpx = (cp * zxa).real.tolist()
        self._tpy = (cp * zya).real.tolist()
        # Q2 samples: instant m / q2_hz, taken at the first sub-step boundary at or after it.
        m0 = self.q2_next
        m_end = max(m0, int(math.ceil((self.tick + n_ticks) * self.T * self.q2_hz - 1e-9)))
        ms = np.arange(m0, m_end)
        t_m = ms / self.q2_hz
        ks = np.clip(np.floor(t_m * self.rate_hz).astype(np.int64) - self.tick, 0, n_ticks - 1)
        ns_q = counts[ks]
        js = np.clip(np.ceil((t_m * self.rate_hz - (self.tick + ks)) * ns_q - 1e-9).astype(np.int64), 0, ns_q)
        uq = inv[ks]
        rows = w_part[uq, js]
        f = powers[uq, js]
        idx = offs[ks][:, None] + np.arange(nmax)
        tqx = (cp * (f * zxa[ks] + (ux[idx] * rows).sum(axis=1))).real     # P-FSM tilts at the sample
        tqy = (cp * (f * zya[ks] + (uy[idx] * rows).sum(axis=1))).real
        self._q2_ticks = ks.tolist() + [-1]
        self._q2_t_us = np.round(t_m * 1e6).astype(np.int64).tolist()
        self._q2_tpx = tqx.tolist()
        self._q2_tpy = tqy.tolist()
        self._q2_mem = (mems_row[uq] + js).tolist()     # MEMS (e1, g1, e2, g2) from the tick start
        if self._timed:
            tau = js / ns_q * self.T                         # Q2 instants from their tick's start (s)
            dt = np.maximum(tau - self._land_f, 0.0)
            mm = self.mems.modal
            lg = sum(c * (np.exp(lam * dt) - 1.0) / lam * bb for c, lam, bb in zip(mm.c, mm.lam, mm.b))
            # the MEMS tilt's real gain on (u_new - u_old) at each Q2 instant of a tick whose words landed
            self._q2_land = np.where(tau >= self._land_f, lg.real, 0.0).tolist()
            self._q1_tp = self._pfsm_at(self.timing.sample_s, inv, offs, ux, uy, zxa, zya,
                                        w_part, powers, ns)
        self._q2_p = 0
        self._q2_m0 = m0
        self._blk_n = n_ticks
        self._blk_i = 0

    def _codes(self, xcodes, ycodes, counts):
        """(counts, x, y) of ``load_pfsm``: the block's codes as floats, those outside 0..0xFFFF clipped and
        counted (``n_pfsm_clip``); ValueError for a tick without codes or too few codes."""
        counts = np.asarray(counts, dtype=np.int64)
        x = np.asarray(xcodes)
        y = np.asarray(ycodes)
        total = int(counts.sum())
        if len(counts) == 0 or counts.min() < 1 or len(x) < total or len(y) < total:
            raise ValueError("load_pfsm: need >= 1 code per tick and %d codes per axis" % total)
        codes16 = x.dtype == np.uint16 and y.dtype == np.uint16      # in range by type
        x = x[:total].astype(float)
        y = y[:total].astype(float)
        if not codes16:
            bad = int(((x < 0) | (x > 0xFFFF)).sum() + ((y < 0) | (y > 0xFFFF)).sum())
            if bad:
                self.n_pfsm_clip += bad
                x = np.clip(x, 0, 0xFFFF)
                y = np.clip(y, 0, 0xFFFF)
        return counts, x, y

    def _pfsm_at(self, taus, inv, offs, ux, uy, zxa, zya, w_part, powers, ns):
        """P-FSM tilts times Q1's geometry gain gp (x list, y list per tick of the block; the loop adds them as
        they are) at each offset tau (s) after the tick starts: the modal state at the last code change before
        tau, then exactly over the rest with that code held. The sub-step, its offset and the hold's
        propagation depend only on the tick's code count: computed once per count in ``ns`` (inv: each
        tick's), the same numbers as tick by tick."""
        (lam,), (b,) = self.pfsm.modal.lam, self.pfsm.modal.b
        cp, nmax = self._cp, w_part.shape[2]
        gp = self._g1[0]
        nsa = np.asarray(ns, np.int64)
        dt = self.T / nsa
        idx = offs[:-1, None] + np.arange(nmax)
        uxi, uyi = ux[idx], uy[idx]
        zx0, zy0 = zxa[:-1], zya[:-1]
        out = []
        for tau in taus:
            jsu = np.minimum((tau / dt + 1e-9).astype(np.int64), nsa - 1)
            phu = np.exp(lam * (tau - jsu * dt))
            gau = (phu - 1.0) / lam * b
            js, ph, ga = jsu[inv], phu[inv], gau[inv]
            rows = w_part[inv, js]
            f = powers[inv, js]
            ucur = offs[:-1] + js
            zx = f * zx0 + (uxi * rows).sum(axis=1)
            zy = f * zy0 + (uyi * rows).sum(axis=1)
            out.append(((gp * (cp * (ph * zx + ga * ux[ucur])).real).tolist(),
                        (gp * (cp * (ph * zy + ga * uy[ucur])).real).tolist()))
        return out

    # --- MEMS FSM input ------------------------------------------------------------------------------
    def spi_write(self, word):
        """One AD5664R 24-bit word to the MEMS driver."""
        self._last_words = None
        self.dac.write(word)
        self._update_mems()

    def spi_words(self, words):
        """A sequence of AD5664R words, in the order clocked out (a repeated sequence is not re-decoded:
        applying the same words twice leaves the DAC as applying them once)."""
        t = tuple(words)
        dac = self.dac
        if t == self._last_words:
            dac.n_words += len(t)
            dac.n_unknown += self._last_unknown
            return
        before = dac.n_unknown
        dac.write_many(t)
        self._last_unknown = dac.n_unknown - before
        self._last_words = t
        self._update_mems()

    def _update_mems(self):
        vx, vy = self.mems.tilt_v(self.dac.outputs())
        self.fsm_v = (vx, vy)
        self.u_mx, self.u_my, self.mems_clipped = self.mems.static_angle(vx, vy)

    # --- sensing -------------------------------------------------------------------------------------
    def _angles(self):
        """Current mechanical tilts (P-FSM x, y; MEMS x, y) in rad."""
        return (self.tpx, self.tpy,
                (self._cm1 * self.zmx1 + self._cm2 * self.zmx2).real,
                (self._cm1 * self.zmy1 + self._cm2 * self.zmy2).real)

    def _geometry(self, name):
        """Linear map from tilts to the detector-frame spot: (gp, gf, cos, sin, off_x, off_y) with the
        beam-frame position x = gp theta_P + gf theta_F (walk 2 theta_P + distance (2 M theta_P - 2 theta_F))."""
        o, q = self.optics, getattr(self, name)
        d = self.config[name]["distance_m"]
        return (2.0 * o.walk + 2.0 * d * o.ang_mag, -2.0 * d, q.cos, q.sin, q.off_x, q.off_y)

    def q1_sample(self):
        """Q1 through the inverting amplifier into the SAMD21: (vx, vy, vs) counts now (INTERFACES Q1 chain)."""
        c1, c2 = self._cm1, self._cm2
        gp, gf, co, si, ox, oy = self._g1
        xb = gp * self.tpx + gf * (c1 * self.zmx1 + c2 * self.zmx2).real
        yb = gp * self.tpy + gf * (c1 * self.zmy1 + c2 * self.zmy2).real
        xd = co * xb + si * yb - ox
        yd = co * yb - si * xb - oy
        r2 = xd * xd + yd * yd
        f = self.q1.inline
        if f is not None and r2 <= f[0]:        # Quadcell.outputs_fast, inlined
            _, h, kx, ky, v = f
            fxp = erfc(kx * (h - xd))
            fxn = erfc(kx * (h + xd))
            fyp = erfc(ky * (h - yd))
            fyn = erfc(ky * (h + yd))
            sx, sy = fxp + fxn, fyp + fyn
            vx, vy, vs = v * (fxn - fxp) * sy, v * (fyp - fyn) * sx, v * sx * sy
        else:
            vx, vy, vs = self._fast1(xd, yd)
        mid, k, top, s0, pn, nc2 = self._adc1
        if self.noise:
            i = self._n1_i
            n = self._n1
            if i + 3 > len(n):
                n = self._n1 = self._refill()
                i = 0
            self._n1_i = i + 3
            sv = k * (s0 + pn * sqrt(r2))
            sd = sqrt(sv * sv + nc2)
            cx = round(mid - k * vx + sd * n[i])
            cy = round(mid - k * vy + sd * n[i + 1])
            cs = round(k * vs + sd * n[i + 2])
        else:
            cx, cy, cs = round(mid - k * vx), round(mid - k * vy), round(k * vs)
        if cx < 0 or cx > top or cy < 0 or cy > top or cs < 0 or cs > top:
            self.adc1.n_clip += 1
            cx, cy, cs = (min(top, max(0, c)) for c in (cx, cy, cs))
        return cx, cy, cs

    def _spot(self, q, tpx, tpy, tfx, tfy):
        """Detector-frame spot position on quadcell q for the given tilts."""
        gp, gf, co, si, ox, oy = self._g1 if q is self.q1 else self._g2
        xb = gp * tpx + gf * tfx
        yb = gp * tpy + gf * tfy
        return co * xb + si * yb - ox, co * yb - si * xb - oy

    # --- time ----------------------------------------------------------------------------------------
    def step(self):
        """Advance one control tick with the queued P-FSM codes (``load_pfsm``).

        Returns the Q2 samples that fell in the tick: tuples (sample, t_us, vx, vy, vs, err_x_arcsec,
        err_y_arcsec), the first five as in the Q2_SAMPLE packet, the last two the true sky error then.
        """
        out = []
        self.run_ticks(1, out)
        return out

    def advance_tick(self, pfsm_x_codes, pfsm_y_codes):
        """Advance one control tick, the P-FSM taking the given AD660 codes at equal sub-steps across it.
        Returns the Q2 samples that fell in the tick (see ``step``)."""
        self.load_pfsm(pfsm_x_codes, pfsm_y_codes, [len(pfsm_x_codes)])
        return self.step()

    def settle(self, pfsm_v=(0.0, 0.0)):
        """Put both mirrors at rest: the P-FSM at the given volts, the MEMS at its current input."""
        ax, ay = self.pfsm.angle(pfsm_v[0], 0), self.pfsm.angle(pfsm_v[1], 1)
        self._sync_pfsm()
        (self.zpx,), (self.zpy,) = self.pfsm.modal.steady(ax), self.pfsm.modal.steady(ay)
        self.tpx, self.tpy = ax, ay
        self.zmx1, self.zmx2 = self.mems.modal.steady(self.u_mx)
        self.zmy1, self.zmy2 = self.mems.modal.steady(self.u_my)

    # --- truth ---------------------------------------------------------------------------------------
    def true_beam_angle(self):
        """Beam angle after the MEMS FSM (x, y) in rad, optical, bench frame."""
        tpx, tpy, tfx, tfy = self._angles()
        o = self.optics
        return o.ang_mag * 2.0 * tpx - 2.0 * tfx, o.ang_mag * 2.0 * tpy - 2.0 * tfy

    def true_error_arcsec(self):
        """Residual pointing error referred to the sky, theta_e + 2 theta_FSM / 13.33 (Eq. 7.5), arcsec,
        measured from the boresight (the beam direction that centres the spot on Q1)."""
        ax, ay = self.true_beam_angle()
        return (ax - self.bore[0]) * self._sky, (ay - self.bore[1]) * self._sky

    def counters(self):
        return {"ticks": self.tick, "spi_words": self.dac.n_words, "spi_unknown": self.dac.n_unknown,
                "mems_clip_ticks": self.n_mems_clip_ticks, "pfsm_code_clips": self.n_pfsm_clip,
                "q1_adc_clips": self.adc1.n_clip, "q2_adc_clips": self.adc2.n_clip,
                "q1_reference_evals": self.q1.n_reference, "q2_reference_evals": self.q2.n_reference}
