"""The flight app's estimation with the ground's filters, for analysis: the 41-state APKF (``apkf.APKF``, the
consistent form: the 23 parameters estimated on from the parameter file's prior and covariance, Sec. 4.6-4.7) and
the full STKF with its AFLS (``afls.Afls`` over ``stkf``: SatA's GNSS and the beacon in one update, Eq. 5.12-5.17,
SatB's relayed GNSS at its time tag). ``GroundEstimation`` takes the calls ``firmware.adcs.estimation.Estimation``
takes, so the app (``firmware.adcs.app.App(cfg, estimation=...)``) flies the same modes, command and allocation
on either; ``estimation(spacecraft, field)`` is the factory a run passes.

What the app reads of its estimator: ``apkf`` (None until it starts; ``apkf.x`` with q, w, tau_d in its first
ten entries, the lean APKF's layout), ``xs`` (the STKF's [rA, vA, rB, vB]), ``Patt`` (the attitude covariance the
beacon takes, 9 flat), ``model`` (the lean model of the parameter file, whose J, C Jrw and dipole the control law
takes, as it does with the lean filters), ``beacon_used``; the gate's resets go to ``Health`` (``n_resets``,
``reset_nis``, ``reset_arcsec``). Refusals (a measurement the STKF rejects, a fix the APKF cannot take) are counted in
``Health.n_refused`` as the lean filters' are.
"""

import math
from array import array

import numpy as np

from emulator.spacecraft.environment import TiltedDipoleField
from firmware.adcs import apkf_lean, estimation as lean
from ground.adcs import afls, apkf, quat, runs, stkf
from ground.adcs.params import check_params
from protocol.units import RAD_PER_ARCSEC

I6 = np.eye(6)


class EstimatedOrbit:
    """SatA's orbit as the flight software knows it, for the APKF's model (``apkf.Model.orbit``): the STKF's
    latest rA, vA (at ``t0``) carried along vA, ``position(t)`` = rA + (t - t0) vA. The APKF asks for the
    mid-step, half a second on, where the orbit's curvature leaves ~1 m (as the flight app's ``_env``)."""

    def __init__(self, t0, x):
        self.set(t0, x)

    def set(self, t0, x):
        self.t0, self.r, self.v = float(t0), np.array(x[0:3], dtype=float), np.array(x[3:6], dtype=float)

    def position(self, t):
        return self.r + (t - self.t0) * self.v


def estimation(spacecraft):
    """The factory ``App(cfg, estimation=...)`` calls: ``GroundEstimation`` for the checked spacecraft file
    ``spacecraft`` (the APKF's model: ``runs.apkf_model``)."""
    def make(cfg, rd, health, fo=None):
        return GroundEstimation(cfg, rd, health, fo, spacecraft=spacecraft)
    return make


class GroundEstimation:
    """See the module docstring."""

    def __init__(self, cfg, rd, health, fo=None, spacecraft=None):
        self.rd, self.health = rd, health
        self.params = cfg["params"]
        self.xp, self.Pp, jxx, self.scale = check_params(self.params, spacecraft=spacecraft)
        veh = lean.vehicle(cfg)
        self.model = apkf_lean.Model(self.params, **veh)    # the control law's (fixed) model
        self.orb = EstimatedOrbit(0.0, cfg["stkf_x0"])
        self.amodel = runs.apkf_model(spacecraft)
        # the field: the lean filter's model, the tilted dipole turned from the configuration's GMST at t = 0
        self.amodel.jxx, self.amodel.orbit = jxx, self.orb
        self.amodel.field = TiltedDipoleField(gmst0_rad=float(cfg["gmst0_rad"]))
        sg = cfg.get("gnss_sigma", (30.0, 1.0))
        self.Rg = np.diag([sg[0] ** 2] * 3 + [sg[1] ** 2] * 3)
        self.sigma_b = float(cfg.get("beacon_sigma_arcsec", 60.0)) * RAD_PER_ARCSEC
        lag = float(cfg.get("lag_s", 4.0))
        self.stkf = afls.Afls(np.asarray(cfg["stkf_x0"], float), np.diag(cfg["stkf_P0"]), 0.0, lag, stkf.f,
                              stkf.Phi, lambda dt: stkf.Q(dt), keep_generated=False, parts=stkf.PARTS)
        self.xs = array("d", self.stkf.x.tolist())     # as the lean filter's (the command copies it so)
        self.sig = np.sqrt(np.diag(self.stkf.Pk))
        self.Patt = np.zeros(9)
        self.apkf = None
        self.t_apkf = 0.0
        self.q_prev = None                      # the last valid fix before the APKF starts (one step back)
        self.t_prev = -2.0
        self.beacon_used = False
        self.sigma_st = np.asarray(veh["sigma_st_arcsec"], float) * RAD_PER_ARCSEC
        self.fly = fo is not None
        self.gate_b = float(fo["beacon_gate_arcsec"]) * RAD_PER_ARCSEC if self.fly else math.inf
        self.gate = float(fo["innovation_gate"]) if self.fly else None

    def _start(self, q, w0, t):
        x0 = apkf.initial_state(q, w0, np.asarray(self.rd.wp, float))
        x0[7:30] = self.xp
        self.apkf = apkf.APKF(x0, model=self.amodel, case=1)
        self.apkf.P[apkf.PARAMS, apkf.PARAMS] = self.Pp
        self.apkf.gate = self.gate
        self.t_apkf = t

    def run_apkf(self, t, u, m_cmd=None):
        """Start the APKF from two valid fixes one step apart, or step it to t (each second of a gap without a
        fix, the read-out held); the magnetorquers' dipole ``m_cmd`` (A m^2) a known input in the flight world."""
        rd = self.rd
        st_ok = rd.st_ok()
        q = np.asarray(rd.qst, float)
        if self.apkf is None:
            if st_ok and self.q_prev is not None and lean.steps(t, self.t_prev) == 1:
                self._start(q, quat.rotvec(quat.quat_mul(q, quat.conj(self.q_prev))), t)
            if st_ok:
                self.q_prev, self.t_prev = q, t
            return
        n = lean.steps(t, self.t_apkf)
        if n < 1:
            return
        a = self.apkf
        if self.fly and m_cmd is not None:
            self.amodel.m_ctrl = np.asarray(m_cmd, float) * self.scale
        wp = np.asarray(rd.wp, float)
        n_resets = len(a.resets)
        try:
            for j in range(n):
                t0 = self.t_apkf + j
                self.orb.set(t0, self.xs)         # the STKF's rA, vA (at the last cycle) carried along vA
                a.step(t0, wp if j == n - 1 else a.x[38:42], q if (st_ok and j == n - 1) else None)
        except np.linalg.LinAlgError:
            self.health.n_refused += 1
            rd.st_valid = False
        if not np.all(np.isfinite(a.x)):
            raise FloatingPointError("APKF diverged at t = %.0f s" % t)
        if len(a.resets) != n_resets:
            hl = self.health
            _, hl.reset_nis, hl.reset_arcsec = a.resets[-1]
            hl.n_resets = len(a.resets)
        self.t_apkf += n

    def fill_unheard(self):
        """The speeds of the wheels not heard this cycle (``rd.wp``, rad/s): the 41-state APKF's wheel-speed states
        (Eq. 4.78) instead of the last read-out, for the control and the unloading (and its own next step)."""
        if self.apkf is None:
            return
        rd = self.rd
        for i in range(4):
            if not rd.rw_got[i]:
                rd.wp[i] = float(self.apkf.x[38 + i])

    def attitude(self):
        """(q, the attitude covariance 4 P_qq in ``Patt``): the APKF's, or the star tracker's before it starts."""
        if self.apkf is not None:
            self.Patt[:] = (4.0 * self.apkf.P[0:3, 0:3]).ravel()
            return self.apkf.x
        self.Patt[:] = np.diag(self.sigma_st ** 2).ravel()
        return self.rd.qst

    def run_stkf(self, t, q):
        """Predict to t, then SatA's GNSS with the beacon (one update; the GNSS alone when the beacon is not
        usable or, in the flight world, the attitude's 1 sigma is beyond the beacon gate), SatB's GNSS at its
        time tags. A measurement the filter refuses is counted and its sensor is stale."""
        f, rd, hl = self.stkf, self.rd, self.health
        if t > f.now + 1e-9:
            try:
                f.predict(t)
            except ValueError:
                hl.n_refused += 1
        P_att = self.Patt.reshape(3, 3)
        beacon = (rd.bc_got and rd.bc_valid and math.sqrt(np.trace(P_att)) <= self.gate_b
                  and (self.apkf is not None or rd.st_ok()))
        self.beacon_used = False
        A = quat.dcm(np.asarray(q[0:4], float))
        try:
            if rd.gnss_got and beacon:
                R = stkf.R_gnss_beacon(self.Rg, stkf.h_beacon(f.x, A), self.sigma_b, P_att)
                z = np.concatenate([np.asarray(rd.zg, float), np.asarray(rd.yb, float)])
                f.update(z, R, lambda x: stkf.gnss_beacon(x, A))
            elif rd.gnss_got:
                f.update(np.asarray(rd.zg, float), self.Rg, lambda x: (x, I6), part=stkf.SAT_A)
            elif beacon:
                R = stkf.R_beacon(stkf.h_beacon(f.x, A), self.sigma_b, P_att)
                f.update(np.asarray(rd.yb, float), R, lambda x: (stkf.h_beacon(x, A), stkf.H_beacon(x, A)))
            self.beacon_used = beacon
        except (ValueError, np.linalg.LinAlgError):         # refused: the filter is left as it was
            hl.n_refused += 1
            rd.gnss_got = False
            if beacon:
                rd.bc_valid = False
        if rd.satb:
            for j in range(rd.nb):
                try:
                    f.update(np.asarray(rd.zb[j], float), self.Rg, lambda x: (x, I6), t=rd.tb[j], part=stkf.SAT_B)
                    hl.n_gnss_b += 1
                    hl.last_ok["gnss_b"] = t
                except (ValueError, np.linalg.LinAlgError):
                    hl.n_refused += 1
        rd.nb = 0
        x = f.x
        if not np.all(np.isfinite(x)):
            raise FloatingPointError("STKF diverged at t = %.0f s" % t)
        self.xs[:] = array("d", x.tolist())
        self.sig[:] = np.sqrt(np.maximum(np.diag(f.Pk), 0.0))

    def position_cov(self, PA, PB):
        """PA[0:9], PB[0:9] = the STKF's 3 x 3 covariances of rA and rB now (m^2)."""
        Pk = self.stkf.Pk
        PA[0:9] = Pk[0:3, 0:3].ravel().tolist()
        PB[0:9] = Pk[6:9, 6:9].ravel().tolist()

    def sigma_att(self):
        """The attitude's 1 sigma (rad, root of the trace of 4 P_qq), 0 before the APKF starts."""
        if self.apkf is None:
            return 0.0
        return math.sqrt(max(0.0, 4.0 * float(np.trace(self.apkf.P[0:3, 0:3]))))
