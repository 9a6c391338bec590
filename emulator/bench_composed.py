"""The bench's tick written one part per call (``Bench(fused=False)``): the sensing chains through
``emulator.sensing.Chain``, the mirrors through their state and tables. The reference the fused loops
(``emulator.bench_loops``) are held to bit for bit, and what ``bench/bench_emulator.py`` measures their gain
against. A mixin of ``emulator.bench.Bench``, whose state it runs on."""


class ComposedLoops:
    """``run_ticks`` for ``Bench``, one part per call."""

    def _run_ticks_composed(self, n, rows, on_tick, k0, us_per_tick, q1_rows, fsm_rows):
        """``run_ticks``, both timings."""
        blk = self.blk
        if blk.i + n > blk.n:
            raise RuntimeError("no P-FSM codes queued for tick %d: call load_pfsm or advance_tick" % self.tick)
        for k in range(k0, k0 + n):
            du = self._land_pending()
            if on_tick is not None:
                c = self._q1_now(du)
                words = on_tick(k, int(k * us_per_tick + 0.5), *c)
                if not words:
                    self.n_missed += 1
                elif self.tab.timed and self.tab.land_d:
                    self._pending.append((self.tick + self.tab.land_d, tuple(words)))
                else:
                    du = self._apply(tuple(words))
                if q1_rows is not None:
                    q1_rows.append(c)
                    fsm_rows.append(self.m.fsm_v)
            self._q2_in_tick(rows, du)
            self._advance(du)

    def _apply(self, words):
        """Words reaching the MEMS driver: the change of its input (x, y) in rad, None when unchanged."""
        m = self.m
        ux0, uy0 = m.umx, m.umy
        self.spi_words(words)
        if not self.tab.timed or (m.umx == ux0 and m.umy == uy0):
            return None
        return m.umx - ux0, m.umy - uy0

    def _land_pending(self):
        """The words of an earlier tick due in this one (timed board, landing a tick or more later)."""
        p = self._pending
        if self.tab.timed and self.tab.land_d and p and p[0][0] <= self.tick:
            return self._apply(p.pop(0)[1])
        return None

    def _q1_now(self, du):
        """Q1's counts this tick: at the tick start, or (timed board) X, Y and SUM at their own instants."""
        ch, m, tab, blk = self.chain1, self.m, self.tab, self.blk
        if not tab.timed:
            tfx, tfy = m.mems_tilts(tab.cm1, tab.cm2)
            return ch.sample(ch.gp * m.tpx + ch.gf * tfx, ch.gp * m.tpy + ch.gf * tfy)
        dux, duy = du or (0.0, 0.0)
        ux0, uy0 = m.umx - dux, m.umy - duy
        beams = []
        for (tpx, tpy), (e1, e2, h0, l0) in zip(blk.q1_tp, tab.q1_gains):
            tfx = (e1 * m.zmx1 + e2 * m.zmx2).real + h0 * ux0 + l0 * dux
            tfy = (e1 * m.zmy1 + e2 * m.zmy2).real + h0 * uy0 + l0 * duy
            beams.append((tpx[blk.i] + ch.gf * tfx, tpy[blk.i] + ch.gf * tfy))
        return ch.sample_channels(beams)

    def _q2_in_tick(self, rows, du):
        """Q2's samples falling in this tick, with the true sky error then (Eq. 7.5), appended to rows."""
        ch, m, tab, blk = self.chain2, self.m, self.tab, self.blk
        c1, c2 = tab.cm1, tab.cm2
        dux, duy = du or (0.0, 0.0)
        ux0, uy0 = m.umx - dux, m.umy - duy
        while blk.q2_ticks[blk.q2_p] == blk.i:
            p = blk.q2_p
            e1, h1, e2, h2 = tab.mems_rows[blk.q2_mem[p]]
            qx, qy = blk.q2_tpx[p], blk.q2_tpy[p]
            tfx = (c1 * (e1 * m.zmx1 + h1 * ux0) + c2 * (e2 * m.zmx2 + h2 * ux0)).real
            tfy = (c1 * (e1 * m.zmy1 + h1 * uy0) + c2 * (e2 * m.zmy2 + h2 * uy0)).real
            if du is not None:
                tfx += blk.q2_land[p] * dux
                tfy += blk.q2_land[p] * duy
            cx, cy, cs = ch.sample(ch.gp * qx + ch.gf * tfx, ch.gp * qy + ch.gf * tfy)
            ex = (self._ang_mag2 * qx - 2.0 * tfx - self.bore[0]) * self._sky
            ey = (self._ang_mag2 * qy - 2.0 * tfy - self.bore[1]) * self._sky
            rows.append((blk.q2_m0 + p, blk.q2_t_us[p], cx, cy, cs, ex, ey))
            blk.q2_p = p + 1
            self.q2_next = blk.q2_m0 + p + 1

    def _advance(self, du):
        """To the next tick boundary: the P-FSM from the block's states, the MEMS exactly (its input changed
        at the landing when ``du``)."""
        m, tab, blk = self.m, self.tab, self.blk
        p1, g1, p2, g2 = tab.mems_step
        blk.i += 1
        m.tpx, m.tpy = blk.tpx[blk.i], blk.tpy[blk.i]
        if du is None:
            m.zmx1, m.zmx2 = p1 * m.zmx1 + g1 * m.umx, p2 * m.zmx2 + g2 * m.umx
            m.zmy1, m.zmy2 = p1 * m.zmy1 + g1 * m.umy, p2 * m.zmy2 + g2 * m.umy
        else:
            (dux, duy), (t1, t2) = du, tab.mem_tail
            ux0, uy0 = m.umx - dux, m.umy - duy
            m.zmx1 = p1 * m.zmx1 + g1 * ux0 + t1 * dux
            m.zmx2 = p2 * m.zmx2 + g2 * ux0 + t2 * dux
            m.zmy1 = p1 * m.zmy1 + g1 * uy0 + t1 * duy
            m.zmy2 = p2 * m.zmy2 + g2 * uy0 + t2 * duy
        if m.clipped:
            self.n_mems_clip_ticks += 1
        self.tick += 1
