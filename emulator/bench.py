"""The emulated fine pointing bench (Ch. 7, Fig. 7-2/7-3): P-FSM -> resizer -> MEMS FSM -> splitter -> Q1, Q2.

Physics in SI units and radians; the truth is reported in arcsec on the sky (Eq. 7.5). One control tick is
advanced at a time: the P-FSM takes its AD660 codes at equal sub-steps across the tick, the MEMS FSM holds the
input decoded from the last AD5664R words. Both mirrors' linear dynamics are updated exactly in modal form
(emulator.mirrors.Modal; their state in ``MirrorState``, the transitions in ``TickTables``); the P-FSM's
per-tick input sums are precomputed with numpy for a block of ticks (``load_pfsm``, kept in ``PfsmBlock``).
Q1 and Q2 are each one sensing chain (``emulator.sensing.Chain``: quadcell, amplifier, ADC, noise).
``run_ticks`` runs a block of ticks against a controller, in the fused loops of ``emulator.bench_loops`` (the
lockstep's fast path) or, with ``fused=False``, one part per call (``emulator.bench_composed``), with the same
numbers; ``static_q1``, ``null_q1`` and ``true_h`` are the noiseless static truth (``emulator.bench_static``).

The board's timing (``emulator.timing``): with ``zero-latency`` the Q1 sample is taken at the tick start and the
controller's words act at once; otherwise X, Y and SUM are sampled at their own instants (P-FSM and MEMS states
exact there) and the words act at their landing instant, in this tick or a later one. ``spi_write`` and
``spi_words`` called directly act at once (devices on a link, tests).

Randomness: one numpy Generator per bench (seeded), drawn in fixed-size blocks, so the same seed, config and
call sequence give bit-identical samples.
"""

import math
import numpy as np

from emulator.adc import ADS1256, SAMD21
from emulator.bench_composed import ComposedLoops
from emulator.bench_loops import FusedLoops
from emulator.bench_static import StaticTruth
from emulator.sensing import Chain, NoiseStream
from emulator.config import default_config, validate
from emulator.mirrors import AD5664R, MEMS, PFSM
from emulator.optics import Optics
from emulator.quadcell import Quadcell
from emulator.timing import board_timing
from protocol.units import ARCSEC_PER_RAD

RATE_HZ_MAX = 1e5                     # control tick rate limit (Hz)


class MirrorState:
    """Both mirrors now: the P-FSM's modal states and tilts (rad) at the tick boundary, the MEMS modal states,
    its input (rad, from the last words), those words' tilt volts, and whether that input was clipped."""

    __slots__ = ("zpx", "zpy", "tpx", "tpy", "zmx1", "zmx2", "zmy1", "zmy2", "umx", "umy", "fsm_v", "clipped")

    def __init__(self):
        self.zpx = self.zpy = 0j
        self.tpx = self.tpy = 0.0
        self.zmx1 = self.zmx2 = self.zmy1 = self.zmy2 = 0j
        self.umx = self.umy = 0.0
        self.fsm_v = (0.0, 0.0)
        self.clipped = False

    def mems_tilts(self, c1, c2):
        """The MEMS mechanical tilts (x, y) in rad, for the modal output weights c1, c2."""
        return (c1 * self.zmx1 + c2 * self.zmx2).real, (c1 * self.zmy1 + c2 * self.zmy2).real


class PfsmBlock:
    """The loaded block of ticks (``Bench.load_pfsm``): the P-FSM modal states and tilts at every tick boundary
    (zx, zy, tpx, tpy), the Q2 samples falling in it (the tick of each, -1 ending the list; their times, P-FSM
    tilts, rows of MEMS transitions, and gains on a landed command), the P-FSM at Q1's channel instants (timed
    board), and where the loops are: tick ``i`` of ``n``, Q2 sample ``q2_p`` after the first one, ``q2_m0``."""

    __slots__ = ("zx", "zy", "tpx", "tpy", "q2_ticks", "q2_t_us", "q2_tpx", "q2_tpy", "q2_mem", "q2_land",
                 "q1_tp", "q2_p", "q2_m0", "n", "i")

    def __init__(self):
        self.n = self.i = 0


class TickTables:
    """The exact transitions over one tick of period T (s) and its parts, for the bench's loops.

    phi_p: the P-FSM's over T; mems_step (p1, g1, p2, g2): the MEMS modes' over T; cp, cm1, cm2 the modal
    output weights. With the board's timing (``timed``): the landing split (land_d ticks, land_f s), per Q1
    channel the MEMS transitions from the tick start and from the landing (q1_mem) and the tilt gains they
    make (q1_gains), and the MEMS input gains from the landing to the tick end (mem_tail).
    """

    def __init__(self, pfsm_modal, mems_modal, timing, T):
        self.pm, self.mm, self.T = pfsm_modal, mems_modal, T
        self.cp = pfsm_modal.c[0]
        self.cm1, self.cm2 = mems_modal.c
        (self.phi_p, _), = pfsm_modal.step(T)
        (pm1, gm1), (pm2, gm2) = mems_modal.step(T)
        self.mems_step = (pm1, gm1, pm2, gm2)
        self.sub = {}
        self.mems_rows = []
        self.timed = not timing.zero
        if self.timed:
            self.land_d, self.land_f = timing.split(T)
            f = self.land_f
            # per channel: MEMS (e1, g1, e2, g2) from the tick start, and g1, g2 from the landing (if after it)
            self.q1_mem = [(self._flat(t), self._flat(t - f)[1::2] if t >= f else (0j, 0j))
                           for t in timing.sample_s]
            c1, c2 = self.cm1, self.cm2
            # per channel: the MEMS tilt at its instant = Re(c1 e1 z1 + c2 e2 z2) + u_old Re(c1 g1 + c2 g2)
            # + (u_new - u_old) Re(c1 l1 + c2 l2) (the input is real)
            self.q1_gains = [(c1 * e1, c2 * e2, (c1 * h1 + c2 * h2).real, (c1 * l1 + c2 * l2).real)
                             for (e1, h1, e2, h2), (l1, l2) in self.q1_mem]
            self.mem_tail = self._flat(T - f)[1::2]

    def _flat(self, dt):
        """The MEMS (e1, g1, e2, g2) over dt."""
        return tuple(c for pair in self.mm.step(dt) for c in pair)

    def substeps(self, ns):
        """Tables for ticks of n equal P-FSM sub-steps, n in the tuple ``ns``, zero-padded to nmax = max(ns) and
        stacked along the first axis (cached per ns): w_end[u, i] weight of u_i in z_n; w_part[u, j, i] weight
        of u_i in z_j (i < j); powers[u, j] = phi^j; ``mems_rows[mems_row[u] + j]`` the MEMS (e1, g1, e2, g2)
        over j sub-steps."""
        tab = self.sub.get(ns)
        if tab is None:
            nmax = ns[-1]
            w_end = np.zeros((len(ns), nmax), complex)
            w_part = np.zeros((len(ns), nmax + 1, nmax), complex)
            powers = np.zeros((len(ns), nmax + 1), complex)
            mems_row = []
            for u, n in enumerate(ns):
                dt = self.T / n
                (phi, gam), = self.pm.step(dt)
                pw = phi ** np.arange(n + 1)
                powers[u, :n + 1] = pw
                w_end[u, :n] = gam * pw[n - 1::-1]
                for j in range(1, n + 1):
                    w_part[u, j, :j] = gam * pw[j - 1::-1]
                mems_row.append(len(self.mems_rows))
                self.mems_rows.extend(self._flat(j * dt) for j in range(n + 1))
            tab = self.sub[ns] = (w_end, w_part, powers, np.array(mems_row))
        return tab


class Bench(FusedLoops, ComposedLoops, StaticTruth):
    """The optical bench. ``config`` is a (partial) config dict or None for the "thesis bench" preset.

    ``rate_hz`` is the control tick rate (the Lockstep sets it); ``noise=False`` gives noiseless samples;
    ``fused=False`` runs the tick one part per call (``emulator.bench_composed``; the same numbers, slower).
    Counters: ``counters()``.
    """

    def __init__(self, config=None, seed=0, rate_hz=637.8, noise=True, fused=True):
        self.config = validate(config) if config is not None else default_config()
        cfg = self.config
        self.seed = seed
        self.optics = Optics(cfg)
        self.pfsm = PFSM(cfg)
        self.mems = MEMS(cfg)
        self.dac = AD5664R()
        self.q2_hz = cfg["adc_q2"]["rate_hz"]
        self.noise = noise
        self.fused = fused
        self.rng = np.random.default_rng(seed)
        las = cfg["laser"]
        chains = []
        for name, adc in (("q1", SAMD21), ("q2", ADS1256)):
            q = Quadcell(cfg[name], self.optics.spot[name], las["ellipse_angle_deg"], self.optics.power[name])
            chains.append(Chain(q, adc(cfg, cfg[name]["amp_gain"]), self._geometry(name),
                                NoiseStream(self.rng) if noise else None))
        self.chain1, self.chain2 = chains
        assert len(self.pfsm.modal.lam) == 1 and len(self.mems.modal.lam) == 2
        self.tick = 0
        self.q2_next = 0
        self.m = MirrorState()
        self.n_mems_clip_ticks = 0
        self.n_missed = 0                 # ticks without words in run_ticks
        self.n_pfsm_clip = 0
        self._memo = (None, 0)            # the last words spi_words decoded, and the unknown ones among them
        # Boresight: the beam angle after the FSM that centres the spot on Q1 (R = 0, the loop's goal).
        q, d = self.q1, cfg["q1"]["distance_m"]
        self.bore = ((q.cos * q.off_x - q.sin * q.off_y) / d, (q.sin * q.off_x + q.cos * q.off_y) / d)
        self._sky = self.optics.sky_per_rad * ARCSEC_PER_RAD
        self._ang_mag2 = 2.0 * self.optics.ang_mag
        self.timing = board_timing(cfg)
        self._pending = []                # (tick, words) the controller answered, landing later (timed board)
        self.blk = PfsmBlock()
        self.tab = None
        self.set_rate(rate_hz)

    # --- parts -------------------------------------------------------------------------------------
    q1 = property(lambda self: self.chain1.quadcell, doc="Quadcell Q1 (the controller's sensor).")
    q2 = property(lambda self: self.chain2.quadcell, doc="Quadcell Q2 (the truth sensor, Sec. 7.3).")
    adc1 = property(lambda self: self.chain1.adc, doc="Q1's SAMD21 ADC.")
    adc2 = property(lambda self: self.chain2.adc, doc="Q2's ADS1256 ADC.")
    fsm_v = property(lambda self: self.m.fsm_v, doc="MEMS tilt volts (x, y) decoded from the last words.")

    # --- timing ------------------------------------------------------------------------------------
    def set_rate(self, rate_hz):
        """Set the control tick rate; precompute the exact per-tick and per-sub-step transitions."""
        if not 1.0 <= rate_hz <= RATE_HZ_MAX:
            raise ValueError("rate_hz = %r is out of range [1, %g]" % (rate_hz, RATE_HZ_MAX))
        self._sync_pfsm()
        self.rate_hz = float(rate_hz)
        self.T = 1.0 / self.rate_hz
        self.tab = TickTables(self.pfsm.modal, self.mems.modal, self.timing, self.T)

    # --- P-FSM input ---------------------------------------------------------------------------------
    def _sync_pfsm(self):
        """Bring the P-FSM modal state to the current tick from the loaded block's boundary states."""
        blk = self.blk
        if blk.n:
            self.m.zpx, self.m.zpy = blk.zx[blk.i], blk.zy[blk.i]
            blk.n = blk.i = 0

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
        tab = self.tab
        w_end, w_part, powers, mems_row = tab.substeps(ns)
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
        phi, cp, blk = tab.phi_p, tab.cp, self.blk
        zx, zy = self.m.zpx, self.m.zpy
        zxs = [zx] + [zx := phi * zx + a for a in sx.tolist()]
        zys = [zy] + [zy := phi * zy + b for b in sy.tolist()]
        zxa, zya = np.array(zxs), np.array(zys)
        blk.zx, blk.zy = zxs, zys
        blk.tpx = (cp * zxa).real.tolist()
        blk.tpy = (cp * zya).real.tolist()
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
        blk.q2_ticks = ks.tolist() + [-1]
        blk.q2_t_us = np.round(t_m * 1e6).astype(np.int64).tolist()
        blk.q2_tpx = tqx.tolist()
        blk.q2_tpy = tqy.tolist()
        blk.q2_mem = (mems_row[uq] + js).tolist()       # MEMS (e1, g1, e2, g2) from the tick start
        if tab.timed:
            tau = js / ns_q * self.T                         # Q2 instants from their tick's start (s)
            dt = np.maximum(tau - tab.land_f, 0.0)
            mm = self.mems.modal
            lg = sum(c * (np.exp(lam * dt) - 1.0) / lam * bb for c, lam, bb in zip(mm.c, mm.lam, mm.b))
            # the MEMS tilt's real gain on (u_new - u_old) at each Q2 instant of a tick whose words landed
            blk.q2_land = np.where(tau >= tab.land_f, lg.real, 0.0).tolist()
            blk.q1_tp = self._pfsm_at(self.timing.sample_s, inv, offs, ux, uy, zxa, zya, w_part, powers, ns)
        blk.q2_p = 0
        blk.q2_m0 = m0
        blk.n = n_ticks
        blk.i = 0

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
        cp, nmax = self.tab.cp, w_part.shape[2]
        gp = self.chain1.gp
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
        self._memo = (None, 0)
        self.dac.write(word)
        self._update_mems()

    def spi_words(self, words):
        """A sequence of AD5664R words, in the order clocked out (a repeated sequence is not re-decoded:
        applying the same words twice leaves the DAC as applying them once)."""
        t = tuple(words)
        dac = self.dac
        last, unknown = self._memo
        if t == last:
            dac.n_words += len(t)
            dac.n_unknown += unknown
            return
        before = dac.n_unknown
        dac.write_many(t)
        self._memo = (t, dac.n_unknown - before)
        self._update_mems()

    def _update_mems(self):
        m = self.m
        vx, vy = self.mems.tilt_v(self.dac.outputs())
        m.fsm_v = (vx, vy)
        m.umx, m.umy, m.clipped = self.mems.static_angle(vx, vy)

    # --- sensing -------------------------------------------------------------------------------------
    def _angles(self):
        """Current mechanical tilts (P-FSM x, y; MEMS x, y) in rad."""
        m = self.m
        return (m.tpx, m.tpy) + m.mems_tilts(self.tab.cm1, self.tab.cm2)

    def _geometry(self, name):
        """Linear map from tilts to the beam-frame spot on quadcell ``name``: (gp, gf) with x = gp theta_P +
        gf theta_F (walk 2 theta_P + distance (2 M theta_P - 2 theta_F))."""
        o, d = self.optics, self.config[name]["distance_m"]
        return 2.0 * o.walk + 2.0 * d * o.ang_mag, -2.0 * d

    def q1_sample(self):
        """Q1 through the inverting amplifier into the SAMD21: (vx, vy, vs) counts now (INTERFACES Q1 chain)."""
        ch, m = self.chain1, self.m
        tfx, tfy = m.mems_tilts(self.tab.cm1, self.tab.cm2)
        return ch.sample(ch.gp * m.tpx + ch.gf * tfx, ch.gp * m.tpy + ch.gf * tfy)

    def _spot(self, q, tpx, tpy, tfx, tfy):
        """Detector-frame spot position on quadcell q for the given tilts."""
        ch = self.chain1 if q is self.q1 else self.chain2
        return ch.spot(ch.gp * tpx + ch.gf * tfx, ch.gp * tpy + ch.gf * tfy)

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
        m = self.m
        (m.zpx,), (m.zpy,) = self.pfsm.modal.steady(ax), self.pfsm.modal.steady(ay)
        m.tpx, m.tpy = ax, ay
        m.zmx1, m.zmx2 = self.mems.modal.steady(m.umx)
        m.zmy1, m.zmy2 = self.mems.modal.steady(m.umy)

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
