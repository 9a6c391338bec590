"""The emulated fine pointing bench (Ch. 7, Fig. 7-2/7-3): P-FSM -> resizer -> MEMS FSM -> splitter -> Q1, Q2.

Physics in SI units and radians; the truth is reported in arcsec on the sky (Eq. 7.5). One control tick is
advanced at a time: the P-FSM takes its AD660 codes at equal sub-steps across the tick, the MEMS FSM holds the
input decoded from the last AD5664R words. Both mirrors' linear dynamics are updated exactly in modal form
(emulator.mirrors.Modal); the P-FSM's per-tick input sums are precomputed with numpy for a block of ticks
(``load_pfsm``), the per-tick work (``q1_sample``, ``spi_words``, ``step``) is plain Python floats;
``run_ticks`` runs a block of ticks against a controller with that work inlined (the lockstep's fast path).

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
from emulator import hcal
from emulator.config import default_config, validate
from emulator.mirrors import AD5664R, MEMS, PFSM
from emulator.optics import Optics
from emulator.quadcell import Quadcell
from emulator.timing import board_timing
from protocol.units import ARCSEC_PER_RAD

_NOISE_BLOCK = 3 * 4096
RATE_HZ_MAX = 1e5                     # control tick rate limit (Hz)


class Bench:
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

    def run_ticks(self, n, rows, on_tick=None, k0=0, us_per_tick=0.0, q1_rows=None, fsm_rows=None):
        """Advance n queued ticks in one call (the lockstep's loop, state kept in locals meanwhile).

        With ``on_tick``, each tick k = k0, k0 + 1, ... starts with ``on_tick(k, t_us, vx, vy, vs)``, t_us =
        round(k us_per_tick), given the Q1 sample (as ``q1_sample``); its words, if any, go to ``spi_words``.
        Then the tick advances (``step``); its Q2 samples are appended to the list ``rows``. Ticks whose answer
        was empty or None (overruns) are counted in ``n_missed``. ``q1_rows``, ``fsm_rows``: lists that record
        each tick's Q1 sample and the MEMS tilt volts after its words (with ``on_tick``).
        """
        if self._timed:
            return self._run_ticks_timed(n, rows, on_tick, k0, us_per_tick, q1_rows, fsm_rows)
        i = self._blk_i
        if i + n > self._blk_n:
            raise RuntimeError("no P-FSM codes queued for tick %d: call load_pfsm or advance_tick" % self.tick)
        umx, umy, clipped = self.u_mx, self.u_my, self.mems_clipped
        zmx1, zmx2, zmy1, zmy2 = self.zmx1, self.zmx2, self.zmy1, self.zmy2
        tpx, tpy = self.tpx, self.tpy
        tpxs, tpys = self._tpx, self._tpy
        p1, g1, p2, g2 = self._mems_step
        c1, c2 = self._cm1, self._cm2
        p = self._q2_p
        q2_ticks, q2_m0, q2_t_us = self._q2_ticks, self._q2_m0, self._q2_t_us
        q2_tpx, q2_tpy, q2_mem, mems_rows = self._q2_tpx, self._q2_tpy, self._q2_mem, self._mems_rows
        noise = self.noise
        n1, n1_i, n2, n2_i = self._n1, self._n1_i, self._n2, self._n2_i
        gp1, gf1, co1, si1, ox1, oy1 = self._g1
        gp2, gf2, co2, si2, ox2, oy2 = self._g2
        f1, f2 = self.q1.inline, self.q2.inline
        mid, k1, top, s01, pn1, nc21 = self._adc1
        k2, s02, pn2, nc22 = self._adc2
        lo, hi = ADS1256.LO, ADS1256.HI
        ksky, ang = self._sky, self._ang_mag2
        borex, borey = self.bore
        missed = done = 0
        erfc_, sqrt_, round_ = erfc, sqrt, round        # locals: the loop calls them ~10 times a tick
        lim1, hq1, kx1, ky1, v1 = f1 if f1 is not None else (-1.0, 0.0, 0.0, 0.0, 0.0)
        lim2, hq2, kx2, ky2, v2 = f2 if f2 is not None else (-1.0, 0.0, 0.0, 0.0, 0.0)
        dac = self.dac
        last_words, last_unknown = self._last_words, self._last_unknown
        same_words = same_unknown = 0                   # repeated words, counted as spi_words counts them
        try:
            for k in range(k0, k0 + n):
                if on_tick is not None:
                    # --- Q1 sample: as q1_sample ---
                    xb = gp1 * tpx + gf1 * (c1 * zmx1 + c2 * zmx2).real
                    yb = gp1 * tpy + gf1 * (c1 * zmy1 + c2 * zmy2).real
                    xd = co1 * xb + si1 * yb - ox1
                    yd = co1 * yb - si1 * xb - oy1
                    r2 = xd * xd + yd * yd
                    if r2 <= lim1:
                        fxp = erfc_(kx1 * (hq1 - xd))
                        fxn = erfc_(kx1 * (hq1 + xd))
                        fyp = erfc_(ky1 * (hq1 - yd))
                        fyn = erfc_(ky1 * (hq1 + yd))
                        sx, sy = fxp + fxn, fyp + fyn
                        vx, vy, vs = v1 * (fxn - fxp) * sy, v1 * (fyp - fyn) * sx, v1 * sx * sy
                    else:
                        vx, vy, vs = self._fast1(xd, yd)
                    if noise:
                        if n1_i + 3 > len(n1):
                            n1 = self._n1 = self._refill()
                            n1_i = 0
                        sv = k1 * (s01 + pn1 * sqrt_(r2))
                        sd = sqrt_(sv * sv + nc21)
                        cx = round_(mid - k1 * vx + sd * n1[n1_i])
                        cy = round_(mid - k1 * vy + sd * n1[n1_i + 1])
                        cs = round_(k1 * vs + sd * n1[n1_i + 2])
                        n1_i += 3
                    else:
                        cx, cy, cs = round_(mid - k1 * vx), round_(mid - k1 * vy), round_(k1 * vs)
                    if cx < 0 or cx > top or cy < 0 or cy > top or cs < 0 or cs > top:
                        self.adc1.n_clip += 1
                        cx, cy, cs = (min(top, max(0, c)) for c in (cx, cy, cs))
                    # --- the controller's answer ---
                    words = on_tick(k, int(k * us_per_tick + 0.5), cx, cy, cs)
                    if words:
                        words = tuple(words)
                        if words == last_words:                 # as spi_words: the MEMS input is unchanged
                            same_words += len(words)
                            same_unknown += last_unknown
                        else:
                            self.spi_words(words)
                            last_words, last_unknown = self._last_words, self._last_unknown
                            umx, umy, clipped = self.u_mx, self.u_my, self.mems_clipped
                    else:
                        missed += 1
                    if q1_rows is not None:
                        q1_rows.append((cx, cy, cs))
                        fsm_rows.append(self.fsm_v)
                # --- Q2 samples in this tick: MEMS from the tick start, P-FSM precomputed (load_pfsm) ---
                while q2_ticks[p] == i:
                    e1, h1, e2, h2 = mems_rows[q2_mem[p]]
                    qx, qy = q2_tpx[p], q2_tpy[p]
                    tfx = (c1 * (e1 * zmx1 + h1 * umx) + c2 * (e2 * zmx2 + h2 * umx)).real
                    tfy = (c1 * (e1 * zmy1 + h1 * umy) + c2 * (e2 * zmy2 + h2 * umy)).real
                    xb = gp2 * qx + gf2 * tfx
                    yb = gp2 * qy + gf2 * tfy
                    xd = co2 * xb + si2 * yb - ox2
                    yd = co2 * yb - si2 * xb - oy2
                    r2 = xd * xd + yd * yd
                    if r2 <= lim2:
                        fxp = erfc_(kx2 * (hq2 - xd))
                        fxn = erfc_(kx2 * (hq2 + xd))
                        fyp = erfc_(ky2 * (hq2 - yd))
                        fyn = erfc_(ky2 * (hq2 + yd))
                        sx, sy = fxp + fxn, fyp + fyn
                        vx, vy, vs = v2 * (fxn - fxp) * sy, v2 * (fyp - fyn) * sx, v2 * sx * sy
                    else:
                        vx, vy, vs = self._fast2(xd, yd)
                    ex = (ang * qx - 2.0 * tfx - borex) * ksky       # true sky error (Eq. 7.5)
                    ey = (ang * qy - 2.0 * tfy - borey) * ksky
                    if noise:
                        if n2_i + 3 > len(n2):
                            n2 = self._n2 = self._refill()
                            n2_i = 0
                        sv = k2 * (s02 + pn2 * sqrt_(r2))
                        sd = sqrt_(sv * sv + nc22)
                        cx = round_(k2 * vx + sd * n2[n2_i])
                        cy = round_(k2 * vy + sd * n2[n2_i + 1])
                        cs = round_(k2 * vs + sd * n2[n2_i + 2])
                        n2_i += 3
                    else:
                        cx, cy, cs = round_(k2 * vx), round_(k2 * vy), round_(k2 * vs)
                    if cx < lo or cx > hi or cy < lo or cy > hi or cs < lo or cs > hi:
                        self.adc2.n_clip += 1
                        cx, cy, cs = (min(hi, max(lo, c)) for c in (cx, cy, cs))
                    rows.append((q2_m0 + p, q2_t_us[p], cx, cy, cs, ex, ey))
                    p += 1
                # --- advance: P-FSM from the block's boundary states, MEMS exactly (modal form) ---
                i += 1
                tpx = tpxs[i]
                tpy = tpys[i]
                zmx1, zmx2 = p1 * zmx1 + g1 * umx, p2 * zmx2 + g2 * umx
                zmy1, zmy2 = p1 * zmy1 + g1 * umy, p2 * zmy2 + g2 * umy
                if clipped:
                    self.n_mems_clip_ticks += 1
                done += 1
        finally:
            dac.n_words += same_words
            dac.n_unknown += same_unknown
            self.zmx1, self.zmx2, self.zmy1, self.zmy2 = zmx1, zmx2, zmy1, zmy2
            self.tpx, self.tpy = tpx, tpy
            self._blk_i = i
            self.tick += done
            self._q2_p = p
            self.q2_next = q2_m0 + p
            self._n1_i, self._n2_i = n1_i, n2_i
            self.n_missed += missed

    def _run_ticks_timed(self, n, rows, on_tick, k0, us_per_tick, q1_rows, fsm_rows):
        """``run_ticks`` with the board's timing (emulator.timing): Q1's X, Y and SUM channels are sampled at
        their own instants in the tick (P-FSM and MEMS states exact there), and the controller's words act
        ``land`` after the tick start: in this tick (d = 0) or d ticks later, at offset f. A tick without an
        answer is an overrun; the words in flight still land."""
        i = self._blk_i
        if i + n > self._blk_n:
            raise RuntimeError("no P-FSM codes queued for tick %d: call load_pfsm or advance_tick" % self.tick)
        umx, umy, clipped = self.u_mx, self.u_my, self.mems_clipped
        zmx1, zmx2, zmy1, zmy2 = self.zmx1, self.zmx2, self.zmy1, self.zmy2
        tpxs, tpys = self._tpx, self._tpy
        p1, g1, p2, g2 = self._mems_step
        t1, t2 = self._mem_tail
        c1, c2 = self._cm1, self._cm2
        d = self._land_d
        pending = self._pending
        (tpx0, tpy0), (tpx1, tpy1), (tpx2, tpy2) = self._q1_tp
        (ae1, ae2, ah0, al0), (be1, be2, bh0, bl0), (ce1, ce2, ch0, cl0) = self._q1_gains
        p = self._q2_p
        q2_ticks, q2_m0, q2_t_us, q2_land = self._q2_ticks, self._q2_m0, self._q2_t_us, self._q2_land
        q2_tpx, q2_tpy, q2_mem, mems_rows = self._q2_tpx, self._q2_tpy, self._q2_mem, self._mems_rows
        noise = self.noise
        n1, n1_i, n2, n2_i = self._n1, self._n1_i, self._n2, self._n2_i
        gp1, gf1, co1, si1, ox1, oy1 = self._g1
        gp2, gf2, co2, si2, ox2, oy2 = self._g2
        f1, f2 = self.q1.inline, self.q2.inline
        fast1, fast2 = self._fast1, self._fast2
        lim1, hq1, kx1, ky1, v1 = f1 if f1 is not None else (-1.0, 0.0, 0.0, 0.0, 0.0)
        mid, k1, top, s01, pn1, nc21 = self._adc1
        k2, s02, pn2, nc22 = self._adc2
        lo, hi = ADS1256.LO, ADS1256.HI
        ksky, ang = self._sky, self._ang_mag2
        borex, borey = self.bore
        missed = done = 0
        bt = self.tick
        erfc_, sqrt_, round_ = erfc, sqrt, round        # locals: the loop calls them ~20 times a tick
        dac = self.dac
        last_words, last_unknown = self._last_words, self._last_unknown
        same_words = same_unknown = 0                   # repeated words, counted as spi_words counts them
        lim2, hq2, kx2, ky2, v2 = f2 if f2 is not None else (-1.0, 0.0, 0.0, 0.0, 0.0)
        try:
            for k in range(k0, k0 + n):
                dux = duy = 0.0
                land = False
                if d and pending and pending[0][0] <= bt:        # words of tick bt - d land at fl
                    words = pending.pop(0)[1]
                    if words == last_words:                     # as spi_words: the MEMS input is unchanged
                        same_words += len(words)
                        same_unknown += last_unknown
                    else:
                        ux0, uy0 = umx, umy
                        self.spi_words(words)
                        last_words, last_unknown = self._last_words, self._last_unknown
                        umx, umy, clipped = self.u_mx, self.u_my, self.mems_clipped
                        dux, duy = umx - ux0, umy - uy0
                        land = dux != 0.0 or duy != 0.0         # a change of input (none: the same sums)
                if on_tick is not None:
                    if noise and n1_i + 3 > len(n1):
                        n1 = self._n1 = self._refill()
                        n1_i = 0
                    ux0, uy0 = umx - dux, umy - duy
                    # X at its instant (MEMS: modal part + the held inputs' real gains, see set_rate)
                    xb = tpx0[i] + gf1 * ((ae1 * zmx1 + ae2 * zmx2).real + ah0 * ux0 + al0 * dux)
                    yb = tpy0[i] + gf1 * ((ae1 * zmy1 + ae2 * zmy2).real + ah0 * uy0 + al0 * duy)
                    xd = co1 * xb + si1 * yb - ox1
                    yd = co1 * yb - si1 * xb - oy1
                    r2 = xd * xd + yd * yd
                    if r2 <= lim1:
                        val = (v1 * (erfc_(kx1 * (hq1 + xd)) - erfc_(kx1 * (hq1 - xd))) *
                               (erfc_(ky1 * (hq1 - yd)) + erfc_(ky1 * (hq1 + yd))))
                    else:
                        val = fast1(xd, yd)[0]
                    if noise:
                        sv = k1 * (s01 + pn1 * sqrt_(r2))
                        cx = round_(mid - k1 * val - sqrt_(sv * sv + nc21) * n1[n1_i])
                    else:
                        cx = round_(mid - k1 * val)
                    # Y
                    xb = tpx1[i] + gf1 * ((be1 * zmx1 + be2 * zmx2).real + bh0 * ux0 + bl0 * dux)
                    yb = tpy1[i] + gf1 * ((be1 * zmy1 + be2 * zmy2).real + bh0 * uy0 + bl0 * duy)
                    xd = co1 * xb + si1 * yb - ox1
                    yd = co1 * yb - si1 * xb - oy1
                    r2 = xd * xd + yd * yd
                    if r2 <= lim1:
                        val = (v1 * (erfc_(ky1 * (hq1 - yd)) - erfc_(ky1 * (hq1 + yd))) *
                               (erfc_(kx1 * (hq1 - xd)) + erfc_(kx1 * (hq1 + xd))))
                    else:
                        val = fast1(xd, yd)[1]
                    if noise:
                        sv = k1 * (s01 + pn1 * sqrt_(r2))
                        cy = round_(mid - k1 * val - sqrt_(sv * sv + nc21) * n1[n1_i + 1])
                    else:
                        cy = round_(mid - k1 * val)
                    # SUM
                    xb = tpx2[i] + gf1 * ((ce1 * zmx1 + ce2 * zmx2).real + ch0 * ux0 + cl0 * dux)
                    yb = tpy2[i] + gf1 * ((ce1 * zmy1 + ce2 * zmy2).real + ch0 * uy0 + cl0 * duy)
                    xd = co1 * xb + si1 * yb - ox1
                    yd = co1 * yb - si1 * xb - oy1
                    r2 = xd * xd + yd * yd
                    if r2 <= lim1:
                        val = (v1 * (erfc_(kx1 * (hq1 - xd)) + erfc_(kx1 * (hq1 + xd))) *
                               (erfc_(ky1 * (hq1 - yd)) + erfc_(ky1 * (hq1 + yd))))
                    else:
                        val = fast1(xd, yd)[2]
                    if noise:
                        sv = k1 * (s01 + pn1 * sqrt_(r2))
                        cs = round_(k1 * val + sqrt_(sv * sv + nc21) * n1[n1_i + 2])
                        n1_i += 3
                    else:
                        cs = round_(k1 * val)
                    if cx < 0 or cx > top or cy < 0 or cy > top or cs < 0 or cs > top:
                        self.adc1.n_clip += 1
                        cx, cy, cs = (min(top, max(0, c)) for c in (cx, cy, cs))
                    words = on_tick(k, int(k * us_per_tick + 0.5), cx, cy, cs)
                    if words:
                        if d:
                            pending.append((bt + d, tuple(words)))
                        else:                                   # lands in this tick, after the samples
                            ux0, uy0 = umx, umy
                            self.spi_words(words)
                            last_words, last_unknown = self._last_words, self._last_unknown
                            umx, umy, clipped = self.u_mx, self.u_my, self.mems_clipped
                            dux, duy = umx - ux0, umy - uy0
                            land = dux != 0.0 or duy != 0.0
                    else:
                        missed += 1
                    if q1_rows is not None:
                        q1_rows.append((cx, cy, cs))
                        fsm_rows.append(self.fsm_v)
                ux0, uy0 = umx - dux, umy - duy
                while q2_ticks[p] == i:
                    e1, h1, e2, h2 = mems_rows[q2_mem[p]]
                    qx, qy = q2_tpx[p], q2_tpy[p]
                    tfx = (c1 * (e1 * zmx1 + h1 * ux0) + c2 * (e2 * zmx2 + h2 * ux0)).real
                    tfy = (c1 * (e1 * zmy1 + h1 * uy0) + c2 * (e2 * zmy2 + h2 * uy0)).real
                    if land:                                  # the new command acts since fl
                        lq = q2_land[p]
                        tfx += lq * dux
                        tfy += lq * duy
                    xb = gp2 * qx + gf2 * tfx
                    yb = gp2 * qy + gf2 * tfy
                    xd = co2 * xb + si2 * yb - ox2
                    yd = co2 * yb - si2 * xb - oy2
                    r2 = xd * xd + yd * yd
                    if r2 <= lim2:
                        fxp = erfc_(kx2 * (hq2 - xd))
                        fxn = erfc_(kx2 * (hq2 + xd))
                        fyp = erfc_(ky2 * (hq2 - yd))
                        fyn = erfc_(ky2 * (hq2 + yd))
                        sx, sy = fxp + fxn, fyp + fyn
                        vx, vy, vs = v2 * (fxn - fxp) * sy, v2 * (fyp - fyn) * sx, v2 * sx * sy
                    else:
                        vx, vy, vs = fast2(xd, yd)
                    ex = (ang * qx - 2.0 * tfx - borex) * ksky       # true sky error (Eq. 7.5)
                    ey = (ang * qy - 2.0 * tfy - borey) * ksky
                    if noise:
                        if n2_i + 3 > len(n2):
                            n2 = self._n2 = self._refill()
                            n2_i = 0
                        sv = k2 * (s02 + pn2 * sqrt_(r2))
                        sd = sqrt_(sv * sv + nc22)
                        cx = round_(k2 * vx + sd * n2[n2_i])
                        cy = round_(k2 * vy + sd * n2[n2_i + 1])
                        cs = round_(k2 * vs + sd * n2[n2_i + 2])
                        n2_i += 3
                    else:
                        cx, cy, cs = round_(k2 * vx), round_(k2 * vy), round_(k2 * vs)
                    if cx < lo or cx > hi or cy < lo or cy > hi or cs < lo or cs > hi:
                        self.adc2.n_clip += 1
                        cx, cy, cs = (min(hi, max(lo, c)) for c in (cx, cy, cs))
                    rows.append((q2_m0 + p, q2_t_us[p], cx, cy, cs, ex, ey))
                    p += 1
                # --- advance: the old input up to the landing (_land_f), the new one after it (exact, modal form) ---
                i += 1
                if land:
                    zmx1 = p1 * zmx1 + g1 * ux0 + t1 * dux
                    zmx2 = p2 * zmx2 + g2 * ux0 + t2 * dux
                    zmy1 = p1 * zmy1 + g1 * uy0 + t1 * duy
                    zmy2 = p2 * zmy2 + g2 * uy0 + t2 * duy
                else:
                    zmx1, zmx2 = p1 * zmx1 + g1 * umx, p2 * zmx2 + g2 * umx
                    zmy1, zmy2 = p1 * zmy1 + g1 * umy, p2 * zmy2 + g2 * umy
                if clipped:
                    self.n_mems_clip_ticks += 1
                done += 1
                bt += 1
        finally:
            dac.n_words += same_words
            dac.n_unknown += same_unknown
            self.zmx1, self.zmx2, self.zmy1, self.zmy2 = zmx1, zmx2, zmy1, zmy2
            self.tpx, self.tpy = tpxs[i], tpys[i]
            self._blk_i = i
            self.tick += done
            self._q2_p = p
            self.q2_next = q2_m0 + p
            self._n1_i, self._n2_i = n1_i, n2_i
            self.n_missed += missed

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

    def pfsm_v_for_error(self, err_arcsec):
        """P-FSM volts that give a sky error (Eq. 7.7-7.8: V = 10 V / 3 deg x 13.33 theta_e)."""
        return err_arcsec / ARCSEC_PER_RAD * self.optics.pfsm_per_sky / self.pfsm.rad_per_v[0]

    def static_q1(self, pfsm_v, fsm_v, model="reference"):
        """Noiseless steady-state Q1 ratios (Rx, Ry) and Vs (V) for P-FSM and FSM tilt volts (Eq. 7.4)."""
        tpx, tpy = self.pfsm.angle(pfsm_v[0], 0), self.pfsm.angle(pfsm_v[1], 1)
        tfx, tfy, _ = self.mems.static_angle(fsm_v[0], fsm_v[1])
        xd, yd = self._spot(self.q1, tpx, tpy, tfx, tfy)
        f = self.q1.outputs_reference if model == "reference" else self.q1.outputs_fast
        vx, vy, vs = f(xd, yd)
        return vx / vs, vy / vs, vs

    def null_q1(self, pfsm_v, v_start=None, tol=1e-12, model="reference"):
        """FSM tilt volts V0 that null Q1, (Rx, Ry) = (0, 0), by Newton's method (Sec. 7.4)."""
        v = list(self._null_guess(pfsm_v) if v_start is None else v_start)
        h = 1e-5
        for _ in range(30):
            rx, ry, _ = self.static_q1(pfsm_v, v, model)
            if abs(rx) < tol and abs(ry) < tol:
                return v
            jac = np.empty((2, 2))
            for c in range(2):
                vp = list(v)
                vm = list(v)
                vp[c] += h
                vm[c] -= h
                rp = self.static_q1(pfsm_v, vp, model)
                rm = self.static_q1(pfsm_v, vm, model)
                jac[0, c] = (rp[0] - rm[0]) / (2 * h)
                jac[1, c] = (rp[1] - rm[1]) / (2 * h)
            if abs(np.linalg.det(jac)) < 1e-12:
                break                       # the spot is off the detector: no gradient to follow
            dv = np.linalg.solve(jac, [rx, ry])
            lim = 0.05          # trust region (V) while the spot is far from the centre
            scale = min(1.0, lim / max(abs(dv[0]), abs(dv[1]), 1e-300))
            v = [v[0] - scale * dv[0], v[1] - scale * dv[1]]
        raise ValueError("null_q1: no null found at P-FSM %r V (last FSM %r V, R = %r)" % (pfsm_v, v, (rx, ry)))

    def _null_guess(self, pfsm_v):
        """Linear guess: FSM optical tilt that cancels the P-FSM's and centres the spot on Q1's offset."""
        o = self.optics
        tpx, tpy = self.pfsm.angle(pfsm_v[0], 0), self.pfsm.angle(pfsm_v[1], 1)
        d = self.config["q1"]["distance_m"]
        fx = (o.walk * 2 * tpx / d + o.ang_mag * 2 * tpx - self.bore[0]) / 2
        fy = (o.walk * 2 * tpy / d + o.ang_mag * 2 * tpy - self.bore[1]) / 2
        k = self.mems.k
        return fx / k[0], fy / k[1]

    def true_h(self, pfsm_v, dv=0.01, v_start=None):
        """True H at a P-FSM point (Sec. 7.4): null Q1, then least squares over the 8 points +-dv along X,
        Y and both (Eq. 7.14-7.16), on the noiseless reference model.

        Returns {"pfsm_v", "v0", "H", "residual"} (residual: RMS of the 16 fit residuals, ratio units).
        """
        v0 = self.null_q1(pfsm_v, v_start)
        steps = [(sx * dv, sy * dv) for sx, sy in hcal.STEPS]
        r = [self.static_q1(pfsm_v, (v0[0] + dx, v0[1] + dy))[:2] for dx, dy in steps]
        h, _, resid = hcal.fit_h(steps, r, offset=False)
        return {"pfsm_v": [float(pfsm_v[0]), float(pfsm_v[1])], "v0": [float(v0[0]), float(v0[1])],
                "H": [[float(h[0, 0]), float(h[0, 1])], [float(h[1, 0]), float(h[1, 1])]], "residual": resid}

    def counters(self):
        return {"ticks": self.tick, "spi_words": self.dac.n_words, "spi_unknown": self.dac.n_unknown,
                "mems_clip_ticks": self.n_mems_clip_ticks, "pfsm_code_clips": self.n_pfsm_clip,
                "q1_adc_clips": self.adc1.n_clip, "q2_adc_clips": self.adc2.n_clip,
                "q1_reference_evals": self.q1.n_reference, "q2_reference_evals": self.q2.n_reference}
