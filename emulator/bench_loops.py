"""The bench's fused tick loops (``Bench.run_ticks``): a block of ticks against a controller with the per-tick
work (the P-FSM's sub-steps, the sensing chains of ``emulator.sensing``, the controller's words, the MEMS
advance) inlined and the state in locals, the lockstep's fast path; with the board's timing
(``emulator.timing``), ``_run_ticks_timed`` samples X, Y and SUM at their own instants and applies the words at
their landing instant. ``emulator.bench_composed`` is the same tick one part per call: a test holds the two
equal bit for bit, and ``bench/bench_emulator.py`` measures what fusing pays. A mixin of
``emulator.bench.Bench``, whose state it runs on."""

from math import erfc, sqrt


class FusedLoops:
    """``run_ticks`` and ``_run_ticks_timed`` for ``Bench``."""

    def run_ticks(self, n, rows, on_tick=None, k0=0, us_per_tick=0.0, q1_rows=None, fsm_rows=None):
        """Advance n queued ticks in one call (the lockstep's loop, state kept in locals meanwhile).

        With ``on_tick``, each tick k = k0, k0 + 1, ... starts with ``on_tick(k, t_us, vx, vy, vs)``, t_us =
        round(k us_per_tick), given the Q1 sample (as ``q1_sample``); its words, if any, go to ``spi_words``.
        Then the tick advances (``step``); its Q2 samples are appended to the list ``rows``. Ticks whose answer
        was empty or None (overruns) are counted in ``n_missed``. ``q1_rows``, ``fsm_rows``: lists that record
        each tick's Q1 sample and the MEMS tilt volts after its words (with ``on_tick``).
        """
        if not self.fused:
            return self._run_ticks_composed(n, rows, on_tick, k0, us_per_tick, q1_rows, fsm_rows)
        if self.tab.timed:
            return self._run_ticks_timed(n, rows, on_tick, k0, us_per_tick, q1_rows, fsm_rows)
        blk, m, tab = self.blk, self.m, self.tab
        i = blk.i
        if i + n > blk.n:
            raise RuntimeError("no P-FSM codes queued for tick %d: call load_pfsm or advance_tick" % self.tick)
        umx, umy, clipped = m.umx, m.umy, m.clipped
        zmx1, zmx2, zmy1, zmy2 = m.zmx1, m.zmx2, m.zmy1, m.zmy2
        tpx, tpy = m.tpx, m.tpy
        tpxs, tpys = blk.tpx, blk.tpy
        p1, g1, p2, g2 = tab.mems_step
        c1, c2 = tab.cm1, tab.cm2
        p = blk.q2_p
        q2_ticks, q2_m0, q2_t_us = blk.q2_ticks, blk.q2_m0, blk.q2_t_us
        q2_tpx, q2_tpy, q2_mem, mems_rows = blk.q2_tpx, blk.q2_tpy, blk.q2_mem, tab.mems_rows
        ch1, ch2 = self.chain1, self.chain2
        noise, ns1, ns2 = self.noise, ch1.noise, ch2.noise
        n1, n1_i, n2, n2_i = (ns1.buf, ns1.i, ns2.buf, ns2.i) if noise else ((), 0, (), 0)
        gp1, gf1, gp2, gf2 = ch1.gp, ch1.gf, ch2.gp, ch2.gf
        co1, si1, ox1, oy1, lim1, hq1, kx1, ky1, v1, mid, _, k1, _, top, s01, pn1, nc21 = ch1.consts
        co2, si2, ox2, oy2, lim2, hq2, kx2, ky2, v2, _, _, k2, lo, hi, s02, pn2, nc22 = ch2.consts
        adc1, adc2 = ch1.adc, ch2.adc
        fast1, fast2 = ch1.quadcell.outputs_fast, ch2.quadcell.outputs_fast
        ksky, ang = self._sky, self._ang_mag2
        borex, borey = self.bore
        missed = done = 0
        erfc_, sqrt_, round_ = erfc, sqrt, round        # locals: the loop calls them ~10 times a tick
        dac = self.dac
        last_words, last_unknown = self._memo
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
                        vx, vy, vs = fast1(xd, yd)
                    if noise:
                        if n1_i + 3 > len(n1):
                            n1 = ns1.refill()
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
                        adc1.n_clip += 1
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
                            last_words, last_unknown = self._memo
                            umx, umy, clipped = m.umx, m.umy, m.clipped
                    else:
                        missed += 1
                    if q1_rows is not None:
                        q1_rows.append((cx, cy, cs))
                        fsm_rows.append(m.fsm_v)
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
                        vx, vy, vs = fast2(xd, yd)
                    ex = (ang * qx - 2.0 * tfx - borex) * ksky       # true sky error (Eq. 7.5)
                    ey = (ang * qy - 2.0 * tfy - borey) * ksky
                    if noise:
                        if n2_i + 3 > len(n2):
                            n2 = ns2.refill()
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
                        adc2.n_clip += 1
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
            m.zmx1, m.zmx2, m.zmy1, m.zmy2 = zmx1, zmx2, zmy1, zmy2
            m.tpx, m.tpy = tpx, tpy
            blk.i = i
            self.tick += done
            blk.q2_p = p
            self.q2_next = q2_m0 + p
            if noise:
                ns1.i, ns2.i = n1_i, n2_i
            self.n_missed += missed

    def _run_ticks_timed(self, n, rows, on_tick, k0, us_per_tick, q1_rows, fsm_rows):
        """``run_ticks`` with the board's timing (emulator.timing): Q1's X, Y and SUM channels are sampled at
        their own instants in the tick (P-FSM and MEMS states exact there), and the controller's words act
        ``land`` after the tick start: in this tick (d = 0) or d ticks later, at offset f. A tick without an
        answer is an overrun; the words in flight still land."""
        blk, m, tab = self.blk, self.m, self.tab
        i = blk.i
        if i + n > blk.n:
            raise RuntimeError("no P-FSM codes queued for tick %d: call load_pfsm or advance_tick" % self.tick)
        umx, umy, clipped = m.umx, m.umy, m.clipped
        zmx1, zmx2, zmy1, zmy2 = m.zmx1, m.zmx2, m.zmy1, m.zmy2
        tpxs, tpys = blk.tpx, blk.tpy
        p1, g1, p2, g2 = tab.mems_step
        t1, t2 = tab.mem_tail
        c1, c2 = tab.cm1, tab.cm2
        d = tab.land_d
        pending = self._pending
        (tpx0, tpy0), (tpx1, tpy1), (tpx2, tpy2) = blk.q1_tp
        (ae1, ae2, ah0, al0), (be1, be2, bh0, bl0), (ce1, ce2, ch0, cl0) = tab.q1_gains
        p = blk.q2_p
        q2_ticks, q2_m0, q2_t_us, q2_land = blk.q2_ticks, blk.q2_m0, blk.q2_t_us, blk.q2_land
        q2_tpx, q2_tpy, q2_mem, mems_rows = blk.q2_tpx, blk.q2_tpy, blk.q2_mem, tab.mems_rows
        ch1, ch2 = self.chain1, self.chain2
        noise, ns1, ns2 = self.noise, ch1.noise, ch2.noise
        n1, n1_i, n2, n2_i = (ns1.buf, ns1.i, ns2.buf, ns2.i) if noise else ((), 0, (), 0)
        gp1, gf1, gp2, gf2 = ch1.gp, ch1.gf, ch2.gp, ch2.gf
        co1, si1, ox1, oy1, lim1, hq1, kx1, ky1, v1, mid, _, k1, _, top, s01, pn1, nc21 = ch1.consts
        co2, si2, ox2, oy2, lim2, hq2, kx2, ky2, v2, _, _, k2, lo, hi, s02, pn2, nc22 = ch2.consts
        adc1, adc2 = ch1.adc, ch2.adc
        fast1, fast2 = ch1.quadcell.outputs_fast, ch2.quadcell.outputs_fast
        ksky, ang = self._sky, self._ang_mag2
        borex, borey = self.bore
        missed = done = 0
        bt = self.tick
        erfc_, sqrt_, round_ = erfc, sqrt, round        # locals: the loop calls them ~20 times a tick
        dac = self.dac
        last_words, last_unknown = self._memo
        same_words = same_unknown = 0                   # repeated words, counted as spi_words counts them
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
                        last_words, last_unknown = self._memo
                        umx, umy, clipped = m.umx, m.umy, m.clipped
                        dux, duy = umx - ux0, umy - uy0
                        land = dux != 0.0 or duy != 0.0         # a change of input (none: the same sums)
                if on_tick is not None:
                    if noise and n1_i + 3 > len(n1):
                        n1 = ns1.refill()
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
                        adc1.n_clip += 1
                        cx, cy, cs = (min(top, max(0, c)) for c in (cx, cy, cs))
                    words = on_tick(k, int(k * us_per_tick + 0.5), cx, cy, cs)
                    if words:
                        if d:
                            pending.append((bt + d, tuple(words)))
                        else:                                   # lands in this tick, after the samples
                            ux0, uy0 = umx, umy
                            self.spi_words(words)
                            last_words, last_unknown = self._memo
                            umx, umy, clipped = m.umx, m.umy, m.clipped
                            dux, duy = umx - ux0, umy - uy0
                            land = dux != 0.0 or duy != 0.0
                    else:
                        missed += 1
                    if q1_rows is not None:
                        q1_rows.append((cx, cy, cs))
                        fsm_rows.append(m.fsm_v)
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
                            n2 = ns2.refill()
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
                        adc2.n_clip += 1
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
            m.zmx1, m.zmx2, m.zmy1, m.zmy2 = zmx1, zmx2, zmy1, zmy2
            m.tpx, m.tpy = tpxs[i], tpys[i]
            blk.i = i
            self.tick += done
            blk.q2_p = p
            self.q2_next = q2_m0 + p
            if noise:
                ns1.i, ns2.i = n1_i, n2_i
            self.n_missed += missed
