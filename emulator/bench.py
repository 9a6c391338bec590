"""The emulated fine pointing bench (Ch. 7, Fig. 7-2/7-3): P-FSM -> resizer -> MEMS FSM -> splitter -> Q1, Q2.

Physics in SI units and radians; the truth is reported in arcsec on the sky (Eq. 7.5). One control tick is
advanced at a time: the P-FSM takes its AD660 codes at equal sub-steps across the tick, the MEMS FSM holds the
input decoded from the last AD5664R words. Both mirrors' linear dynamics are updated exactly in modal form
(emulator.mirrors.Modal); the P-FSM's per-tick input sums are precomputed with numpy for a block of ticks
(``load_pfsm``), the per-tick work (``q1_sample``, ``spi_words``, ``step``) is plain Python floats.

Randomness: one numpy Generator per bench (seeded), drawn in fixed-size blocks, so the same seed, config and
call sequence give bit-identical samples.
"""

import math

import numpy as np

from emulator.adc import ADS1256, SAMD21
from emulator.config import default_config, validate
from emulator.mirrors import AD5664R, MEMS, PFSM
from emulator.optics import Optics
from emulator.quadcell import Quadcell

ARCSEC = 180.0 / math.pi * 3600.0     # arcsec per radian
_NOISE_BLOCK = 3 * 4096


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
        self.n_pfsm_clip = 0
        self._last_words = None
        self._last_unknown = 0
        self._blk_n = 0
        self._blk_i = 0
        # Boresight: the beam angle after the FSM that centres the spot on Q1 (R = 0, the loop's goal).
        q, d = self.q1, cfg["q1"]["distance_m"]
        self.bore = ((q.cos * q.off_x - q.sin * q.off_y) / d, (q.sin * q.off_x + q.cos * q.off_y) / d)
        self._sky = self.optics.sky_per_rad * ARCSEC
        self._ang_mag2 = 2.0 * self.optics.ang_mag
        self._g1 = self._geometry("q1")
        self._g2 = self._geometry("q2")
        self._fast1 = self.q1.outputs_fast
        self._fast2 = self.q2.outputs_fast
        self.set_rate(rate_hz)

    # --- timing ------------------------------------------------------------------------------------
    def set_rate(self, rate_hz):
        """Set the control tick rate; precompute the exact per-tick and per-sub-step transitions."""
        if not 1.0 <= rate_hz <= 1e5:
            raise ValueError("rate_hz = %r is out of range [1, 1e5]" % rate_hz)
        self._sync_pfsm()
        self.rate_hz = float(rate_hz)
        self.T = 1.0 / self.rate_hz
        (self._phi_p, _), = self.pfsm.modal.step(self.T)
        (self._pm1, self._gm1), (self._pm2, self._gm2) = self.mems.modal.step(self.T)
        self._sub = {}

    def _substeps(self, n):
        """Tables for a tick of n equal P-FSM sub-steps (cached per n)."""
        tab = self._sub.get(n)
        if tab is None:
            dt = self.T / n
            (phi, gam), = self.pfsm.modal.step(dt)
            powers = phi ** np.arange(n + 1)
            w_end = gam * powers[n - 1::-1]                 # weight of u_i in z_n
            w_part = np.zeros((n + 1, n), complex)          # weight of u_i in z_j (i < j)
            for j in range(1, n + 1):
                w_part[j, :j] = gam * powers[j - 1::-1]
            mems = np.array([[c for pair in self.mems.modal.step(j * dt) for c in pair] for j in range(n + 1)])
            tab = self._sub[n] = (w_end, w_part, powers, mems)
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
        x = np.asarray(xcodes, dtype=float)
        y = np.asarray(ycodes, dtype=float)
        total = int(counts.sum())
        if len(counts) == 0 or counts.min() < 1 or len(x) < total or len(y) < total:
            raise ValueError("load_pfsm: need >= 1 code per tick and %d codes per axis" % total)
        x, y = x[:total], y[:total]
        bad = int(((x < 0) | (x > 0xFFFF)).sum() + ((y < 0) | (y > 0xFFFF)).sum())
        if bad:
            self.n_pfsm_clip += bad
            x = np.clip(x, 0, 0xFFFF)
            y = np.clip(y, 0, 0xFFFF)
        kv = self.pfsm.range_v / 32768.0
        ux = (x - 32768.0) * (kv * self.pfsm.rad_per_v[0])
        uy = (y - 32768.0) * (kv * self.pfsm.rad_per_v[1])
        offs = np.concatenate(([0], np.cumsum(counts)))
        n_ticks = len(counts)
        sx = np.empty(n_ticks, complex)
        sy = np.empty(n_ticks, complex)
        for n in np.unique(counts).tolist():
            ks = np.nonzero(counts == n)[0]
            idx = offs[ks][:, None] + np.arange(n)[None, :]
            w_end = self._substeps(n)[0]
            sx[ks] = (ux[idx] * w_end).sum(axis=1)   # elementwise, not BLAS: no thread pool per block
            sy[ks] = (uy[idx] * w_end).sum(axis=1)
        # P-FSM states at every tick boundary of the block: z[k+1] = Phi z[k] + s[k] (exact, Phi = exp(lam T))
        self._sync_pfsm()
        phi, cp = self._phi_p, self._cp
        zx, zy = self.zpx, self.zpy
        zxs, zys = [zx], [zy]
        for a, b in zip(sx.tolist(), sy.tolist()):
            zx = phi * zx + a
            zy = phi * zy + b
            zxs.append(zx)
            zys.append(zy)
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
        ns = counts[ks]
        js = np.clip(np.ceil((t_m * self.rate_hz - (self.tick + ks)) * ns - 1e-9).astype(np.int64), 0, ns)
        tq = np.empty((2, len(ms)))                 # P-FSM tilts x, y at the sample
        mem = np.empty((len(ms), 4), complex)       # MEMS e1, g1, e2, g2 from the tick start
        for n in np.unique(ns).tolist():
            sel = np.nonzero(ns == n)[0]
            _, w_part, powers, mems = self._substeps(n)
            idx = offs[ks[sel]][:, None] + np.arange(n)[None, :]
            rows = w_part[js[sel]]
            f = powers[js[sel]]
            tq[0, sel] = (cp * (f * zxa[ks[sel]] + (ux[idx] * rows).sum(axis=1))).real
            tq[1, sel] = (cp * (f * zya[ks[sel]] + (uy[idx] * rows).sum(axis=1))).real
            mem[sel] = mems[js[sel]]
        self._q2_ticks = ks.tolist() + [-1]
        self._q2_t_us = np.round(t_m * 1e6).astype(np.int64).tolist()
        self._q2_tp = tq.T.tolist()
        self._q2_mem = mem.tolist()
        self._q2_p = 0
        self._q2_m0 = m0
        self._blk_n = n_ticks
        self._blk_i = 0

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
        for w in t:
            dac.write(w)
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
        vx, vy, vs = self._fast1(xd, yd)
        adc = self.adc1
        k = adc.k
        if self.noise:
            i = self._n1_i
            n = self._n1
            if i + 3 > len(n):
                n = self._n1 = self._refill()
                i = 0
            self._n1_i = i + 3
            q = self.q1
            sv = k * (q.sigma0_v + q.pos_noise * math.sqrt(xd * xd + yd * yd))
            sd = math.sqrt(sv * sv + adc.noise_counts * adc.noise_counts)
            cx = round(adc.mid - k * vx + sd * n[i])
            cy = round(adc.mid - k * vy + sd * n[i + 1])
            cs = round(k * vs + sd * n[i + 2])
        else:
            cx, cy, cs = round(adc.mid - k * vx), round(adc.mid - k * vy), round(k * vs)
        top = adc.top
        if cx < 0 or cx > top or cy < 0 or cy > top or cs < 0 or cs > top:
            adc.n_clip += 1
            cx, cy, cs = (min(top, max(0, c)) for c in (cx, cy, cs))
        return cx, cy, cs

    def _q2_sample(self, tpx, tpy, tfx, tfy):
        gp, gf, co, si, ox, oy = self._g2
        xb = gp * tpx + gf * tfx
        yb = gp * tpy + gf * tfy
        xd = co * xb + si * yb - ox
        yd = co * yb - si * xb - oy
        vx, vy, vs = self._fast2(xd, yd)
        k = self._sky
        ang = self._ang_mag2
        ex = (ang * tpx - 2.0 * tfx - self.bore[0]) * k
        ey = (ang * tpy - 2.0 * tfy - self.bore[1]) * k
        adc = self.adc2
        g = adc.k
        if self.noise:
            i = self._n2_i
            n = self._n2
            if i + 3 > len(n):
                n = self._n2 = self._refill()
                i = 0
            self._n2_i = i + 3
            q = self.q2
            sv = g * (q.sigma0_v + q.pos_noise * math.sqrt(xd * xd + yd * yd))
            sd = math.sqrt(sv * sv + adc.noise_counts * adc.noise_counts)
            cx, cy, cs = round(g * vx + sd * n[i]), round(g * vy + sd * n[i + 1]), round(g * vs + sd * n[i + 2])
        else:
            cx, cy, cs = round(g * vx), round(g * vy), round(g * vs)
        lo, hi = adc.LO, adc.HI
        if cx < lo or cx > hi or cy < lo or cy > hi or cs < lo or cs > hi:
            adc.n_clip += 1
            cx, cy, cs = (min(hi, max(lo, c)) for c in (cx, cy, cs))
        return cx, cy, cs, ex, ey

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
        i = self._blk_i
        if i >= self._blk_n:
            raise RuntimeError("no P-FSM codes queued for tick %d: call load_pfsm or advance_tick" % self.tick)
        out = []
        umx, umy = self.u_mx, self.u_my
        zmx1, zmx2, zmy1, zmy2 = self.zmx1, self.zmx2, self.zmy1, self.zmy2
        p = self._q2_p
        ticks = self._q2_ticks
        while ticks[p] == i:
            tpx, tpy = self._q2_tp[p]
            e1, g1, e2, g2 = self._q2_mem[p]
            c1, c2 = self._cm1, self._cm2
            s = self._q2_sample(tpx, tpy,
                                (c1 * (e1 * zmx1 + g1 * umx) + c2 * (e2 * zmx2 + g2 * umx)).real,
                                (c1 * (e1 * zmy1 + g1 * umy) + c2 * (e2 * zmy2 + g2 * umy)).real)
            out.append((self._q2_m0 + p, self._q2_t_us[p]) + s)
            p += 1
        if p != self._q2_p:
            self._q2_p = p
            self.q2_next = self._q2_m0 + p
        self.tpx = self._tpx[i + 1]
        self.tpy = self._tpy[i + 1]
        p1, g1, p2, g2 = self._pm1, self._gm1, self._pm2, self._gm2
        self.zmx1 = p1 * zmx1 + g1 * umx
        self.zmx2 = p2 * zmx2 + g2 * umx
        self.zmy1 = p1 * zmy1 + g1 * umy
        self.zmy2 = p2 * zmy2 + g2 * umy
        if self.mems_clipped:
            self.n_mems_clip_ticks += 1
        self._blk_i = i + 1
        self.tick += 1
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

    def pfsm_v_for_error(self, err_arcsec):
        """P-FSM volts that give a sky error (Eq. 7.7-7.8: V = 10 V / 3 deg x 13.33 theta_e)."""
        return err_arcsec / ARCSEC * self.optics.pfsm_per_sky / self.pfsm.rad_per_v[0]

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
        steps = [(dv, 0), (-dv, 0), (0, dv), (0, -dv), (dv, dv), (-dv, -dv), (dv, -dv), (-dv, dv)]
        a = np.zeros((16, 4))
        r = np.zeros(16)
        for i, (dx, dy) in enumerate(steps):
            rx, ry, _ = self.static_q1(pfsm_v, (v0[0] + dx, v0[1] + dy))
            a[2 * i, 0:2] = (dx, dy)
            a[2 * i + 1, 2:4] = (dx, dy)
            r[2 * i], r[2 * i + 1] = rx, ry
        sol, *_ = np.linalg.lstsq(a, r, rcond=None)
        resid = float(np.sqrt(np.mean((a @ sol - r) ** 2)))
        return {"pfsm_v": [float(pfsm_v[0]), float(pfsm_v[1])], "v0": [float(v0[0]), float(v0[1])],
                "H": [[float(sol[0]), float(sol[1])], [float(sol[2]), float(sol[3])]], "residual": resid}

    def counters(self):
        return {"ticks": self.tick, "spi_words": self.dac.n_words, "spi_unknown": self.dac.n_unknown,
                "mems_clip_ticks": self.n_mems_clip_ticks, "pfsm_code_clips": self.n_pfsm_clip,
                "q1_adc_clips": self.adc1.n_clip, "q2_adc_clips": self.adc2.n_clip,
                "q1_reference_evals": self.q1.n_reference, "q2_reference_evals": self.q2.n_reference}
