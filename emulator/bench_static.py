"""The bench's static truth (``Bench.static_q1``, ``null_q1``, ``true_h``): the noiseless steady state Q1 sees for
P-FSM and FSM volts, the FSM volts that null it, and the true H there by the calibration's own fit
(``emulator.hcal``). A mixin of ``emulator.bench.Bench``, whose models it reads."""

import numpy as np

from emulator import hcal
from protocol.units import ARCSEC_PER_RAD


class StaticTruth:
    """The noiseless steady-state views of ``Bench``."""

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
