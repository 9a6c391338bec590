"""The STKF simulation of thesis Sec. 5.5: one run per seed, and the Monte Carlo aggregate.

A run: truth orbits (``emulator.orbits``, 1 s samples, 10th-order Lagrange interpolation as in Sec. 6.4.1
for SatB's off-tick measurement times), the sensors of ``emulator.navsensors``, and the STKF with the EAFLS
at 1 Hz. Case 1: SatA's GNSS and the beacon. Case 2: plus SatB's GNSS through the relay, delayed U(2, 3) s,
each solution time-tagged on SatB's own clock (a random phase per run, so the tags fall between nodes).

Attitude (stated; Sec. 5.5 gives no attitude profile and no APKF runs here): SatA's body frame is held on
J2000 (q = [0, 0, 0, 1]), and the attitude estimate carries a white error each second with the stated
covariance ``ATT_SIGMA_ARCSEC`` = the APKF's final 1 sigma of Sec. 4.8 Case 1 (9.81, 8.01, 19.70 arcsec).
That covariance is the P_att of Eq. 5.16 and 5.59.

With ``attitude="apkf"`` the APKF runs in the same simulation instead (the Sec. 4.8 Case 1 scenario,
same seed, for the same duration): the true attitude is the scenario's, the STKF uses the APKF's estimate
A(q_hat) and its attitude covariance 4 P[0:3, 0:3] (P of dq_vec, Eq. 4.77) as P_att; before the APKF starts,
the star-tracker quaternion with its 20/20/60 arcsec covariance.

The beacon camera's misalignment (``beacon_misalignment``; the spacecraft file's ``beacon.misalignment_deg``, its
1 sigma and its truth): the truth's camera measures in its own frame (``navsensors.Beacon``); "ignore" (the
default) holds the filter at the file's figure (zero in the presets: the thesis's aligned camera, its tables
unchanged), "estimate" adds the three angles to the STKF's state (``stkf.beacon_m``, P0 from the file's 1 sigma).

Figures: a "final 1 sigma" is sqrt(trace) of the 3x3 block (the thesis's "for the three axes in total");
the pointing figure is sqrt(Pz11 + Pz22) of Eq. 5.59 ("for the two axes in total").
"""

import json
import os
import time

import numpy as np

from emulator import orbits
from emulator.interp import lagrange
from emulator.navsensors import Beacon, Gnss, Relay
from emulator.spacecraft.dynamics import dcm
from emulator.spacecraft.scenario import LAG_S
from ground.adcs import stkf
from ground.adcs.afls import Afls
from ground.fileio import write_atomic, write_json
from protocol import spacecraft as sf
from protocol.units import RAD_PER_ARCSEC

ATT_SIGMA_ARCSEC = (9.81, 8.01, 19.70)
SENSORS = ("gnss_a", "beacon", "relay")
FIGURES = ("fig5-4_states.png", "fig5-5_pointing.png", "fig5-6_states.png", "fig5-7_pointing.png")  # as the thesis's
GAP_S = {"gnss_a": 2.0, "beacon": 2.0, "relay": 5.0}   # silence longer than this is logged as an outage
THESIS = {1: {"final_sigma_ra_m": 9.22, "final_sigma_va_m_s": 0.5252, "final_sigma_rb_m": 3264.2,
              "final_sigma_vb_m_s": 4.52, "final_sigma_pointing_arcsec": 23.0},
          2: {"final_sigma_ra_m": 9.21, "final_sigma_va_m_s": 0.5252, "final_sigma_rb_m": 9.21,
              "final_sigma_vb_m_s": 0.5252, "final_sigma_pointing_arcsec": 19.8}}
KEYS = tuple(THESIS[1])
NEES_FROM_S = 60    # the consistency figures skip the first minute (P0 of km against GNSS fixes of m)


def parse_outage(text):
    """'SENSOR:T0:T1' (seconds from the start) -> (sensor, t0, t1); SENSOR one of gnss_a, beacon, relay."""
    parts = str(text).split(":")
    if len(parts) != 3 or parts[0] not in SENSORS:
        raise ValueError("outage must be SENSOR:T0:T1 with SENSOR one of %s, got %r" % ("/".join(SENSORS), text))
    try:
        t0, t1 = float(parts[1]), float(parts[2])
    except ValueError:
        raise ValueError("outage times must be numbers (s), got %r" % (text,)) from None
    if not (np.isfinite(t0) and np.isfinite(t1) and 0 <= t0 < t1):
        raise ValueError("outage must have 0 <= T0 < T1 (s), got %r" % (text,))
    return parts[0], t0, t1


def small_rotation(alpha):
    """A(dq) of the rotation vector alpha (dq = [alpha/2, 1] normalised, Eq. 4.77)."""
    q = np.array([0.5 * alpha[0], 0.5 * alpha[1], 0.5 * alpha[2], 1.0])
    return dcm(q / np.linalg.norm(q))


class _Gaps:
    """Logs the silence of each sensor: the filter keeps propagating and says so."""

    def __init__(self, log, sensors):
        self.log, self.last, self.open, self.done = log, {s: 0.0 for s in sensors}, {}, []

    def seen(self, sensor, t):
        if sensor in self.open:
            t0 = self.open.pop(sensor)
            self.done.append({"sensor": sensor, "from_s": t0, "to_s": t})
            self.log.append("t=%7.1f s  %s back after %.1f s; filter was propagating on the others"
                            % (t, sensor, t - t0))
        self.last[sensor] = t

    def tick(self, t):
        for s, tl in self.last.items():
            if s not in self.open and t - tl > GAP_S[s]:
                self.open[s] = tl
                self.log.append("t=%7.1f s  no %s since t=%.1f s: propagating without it" % (t, s, tl))

    def close(self, t):
        for s, t0 in sorted(self.open.items()):
            self.done.append({"sensor": s, "from_s": t0, "to_s": None})
            self.log.append("t=%7.1f s  %s still silent at the end (since t=%.1f s)" % (t, s, t0))
        return sorted(self.done, key=lambda d: (d["from_s"], d["sensor"]))


ATTITUDES = ("stated", "apkf")
MISALIGNMENT = ("ignore", "estimate")


def apkf_attitude(seed, K, spacecraft=None):
    """(A_true, A_hat, P_att) for k = 0..K from the APKF over the Sec. 4.8 Case 1 scenario, flown by
    the checked spacecraft file ``spacecraft`` (None: thesis-3u; ``scenario.simulate``, ``runs._start_apkf``)."""
    from emulator.spacecraft import scenario
    from ground.adcs.runs import _start_apkf
    d = spacecraft or scenario.thesis_3u()
    o = scenario.simulate(case=1, seed=seed, duration=max(K, 2), spacecraft=d)
    k0, flt = _start_apkf(o, 1, spacecraft=d)
    A_true = np.array([dcm(q) for q in o["q"][:K + 1]])
    A_hat = np.empty_like(A_true)
    P_att = np.empty_like(A_true)
    st = np.diag((np.array(d["star_tracker"]["sigma_arcsec"]) * RAD_PER_ARCSEC) ** 2)
    for k in range(K + 1):
        if k < k0:
            A_hat[k], P_att[k] = dcm(o["st_q"][k]), st
            continue
        if k > k0:
            flt.step(o["t"][k - 1], o["tach"][k], o["st_q"][k] if o["st_valid"][k] else None)
        A_hat[k], P_att[k] = dcm(flt.x[0:4]), 4.0 * flt.P[0:3, 0:3]
    return A_true, A_hat, P_att


def simulate(case, duration_s=1200.0, seed=0, truth="two-body", cache_dir=None, lag_s=LAG_S, outages=(),
             att_sigma_arcsec=ATT_SIGMA_ARCSEC, qa=stkf.QA_THESIS, attitude="stated", spacecraft=None,
             beacon_misalignment="ignore"):
    """One run; returns (result dict, history dict of arrays). ``attitude``: "stated" or "apkf".
    ``beacon_misalignment``: "ignore" or "estimate" (module docstring). ``spacecraft``:
    a checked spacecraft file (None: thesis-3u) giving SatA's and SatB's initial states, the epoch and surface of
    the orbit truth, the GNSS's and the beacon's noise, the relay's delay and the STKF's P0
    (``scenario.orbit_setup``), and with ``attitude="apkf"`` the vehicle the APKF flies (``apkf_attitude``)."""
    from emulator.spacecraft import scenario
    d = spacecraft or scenario.thesis_3u()
    o = scenario.orbit_setup(d)
    delay_s = o["relay_delay_s"]
    outages = _check(case, duration_s, lag_s, outages, attitude, delay_s)
    mis = misalignment_setup(d, beacon_misalignment)
    t_s, xs = scenario.orbit_truth(truth, duration_s, o, cache_dir)
    K = int(np.floor(duration_s + 1e-9))
    r_init, r_ga, r_gb, r_bc, r_att, r_rel = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(6)]
    P0 = np.diag(o["stkf_P0_diag"])               # thesis-3u: (4 km)^2, (0.1 km/s)^2 per satellite (Sec. 5.5.1)
    x_true0 = xs[0].ravel()
    x0 = x_true0 + np.sqrt(o["stkf_P0_diag"]) * r_init.standard_normal(12)
    flt = _filter(x0, P0, lag_s, qa, mis)
    gnss_a = Gnss(r_ga, **o["gnss"])
    beacon = Beacon(r_bc, **o["beacon"])           # the camera's true misalignment (scenario.orbit_setup)
    relay = Relay(r_rel, Gnss(r_gb, **o["gnss"]), delay_s)
    phase = r_rel.uniform(0.0, 1.0)               # SatB's receiver clock vs SatA's ticks
    tb = phase + np.arange(0, K)                  # SatB GNSS epochs
    tb = tb[tb <= K]
    xb_at = lagrange(t_s, xs[:, 1, :], tb, order=10) if case == 2 else None
    att_sd = np.asarray(att_sigma_arcsec, dtype=float) * RAD_PER_ARCSEC
    P_att = np.diag(att_sd ** 2)
    A_true = np.eye(3)                            # body frame held on J2000 (stated)
    att = apkf_attitude(seed, K, d) if attitude == "apkf" else None
    R_g, R_relay = gnss_a.R, relay.gnss.R

    def out(sensor, t):
        return any(s == sensor and t0 <= t < t1 for s, t0, t1 in outages)

    log = []
    gaps = _Gaps(log, ("gnss_a", "beacon") + (("relay",) if case == 2 else ()))
    hist = {k: np.zeros((K + 1,) + s) for k, s in
            (("err", (12,)), ("sig", (12,)), ("perr", (2,)), ("psig", (2,)), ("nees", ()), ("lerr", ()),
             ("merr", (3,)), ("msig", (3,)), ("aerr", (3,)), ("asig", (3,)), ("xB", (6,)), ("PB", (36,)))}
    hist["t"] = np.arange(K + 1, dtype=float)
    step_s = []
    jb = 0
    for k in range(K + 1):
        t = float(k)
        x_true = xs[k].ravel()
        if att is None:
            A_hat = small_rotation(att_sd * r_att.standard_normal(3)).T @ A_true
        else:
            A_true, A_hat, P_att = att[0][k], att[1][k], att[2][k]
        # sensors (truth side, not timed)
        have_g, have_b = not out("gnss_a", t), not out("beacon", t)
        zg = gnss_a.measure(x_true[:6]) if have_g else None
        y = beacon.measure_dcm(x_true[0:3], x_true[6:9], A_true) if have_b else None
        due = []
        if case == 2:
            while jb < tb.size and tb[jb] <= t:
                if not out("relay", tb[jb]):
                    relay.sample(tb[jb], xb_at[jb])
                jb += 1
            due = relay.due(t)
        t0 = time.perf_counter()                 # the filter step, timed
        _step(flt, k, t, zg, y, due, A_hat, P_att, R_g, R_relay, beacon.sigma, mis)
        step_s.append(time.perf_counter() - t0)
        if have_g:
            gaps.seen("gnss_a", t)
        if have_b:
            gaps.seen("beacon", t)
        if due:
            gaps.seen("relay", t)
        gaps.tick(t)
        _record(hist, k, t, flt, x_true, A_hat, A_true, P_att, mis)
    res = _result(seed, case, truth, attitude, K, d, flt, hist, step_s, gaps.close(float(K)), log)
    res.update(_misalignment_result(hist, mis))
    return res, hist


def _filter(x0, P0, lag_s, qa, mis):
    """The STKF with the EAFLS from (x0, P0) at t = 0; with the misalignment estimated, x0 and P0 augmented by
    its figure and 1 sigma (``stkf.f_m``, ``Phi_m``, ``Q_m``)."""
    if mis["estimate"]:
        return Afls(np.concatenate((x0, mis["figure"])), _blockdiag(P0, mis["P0"]), 0.0, lag_s, stkf.f_m,
                    stkf.Phi_m, lambda dt: stkf.Q_m(dt, qa), keep_generated=False, parts=stkf.PARTS)
    return Afls(x0, P0, 0.0, lag_s, stkf.f, stkf.Phi, lambda dt: stkf.Q(dt, qa), keep_generated=False,
                parts=stkf.PARTS)


def _blockdiag(a, b):
    out = np.zeros((a.shape[0] + b.shape[0],) * 2)
    out[:a.shape[0], :a.shape[0]] = a
    out[a.shape[0]:, a.shape[0]:] = b
    return out


def misalignment_setup(d, mode):
    """The beacon camera's misalignment of the checked file ``d`` for ``simulate`` (rad): ``figure`` (the
    filter's prior mean), ``truth``, ``P0`` (3 x 3), ``estimate`` (bool), and for "ignore" ``C`` (the figure's
    C(delta), None when zero: the thesis's aligned camera, its arithmetic unchanged). ValueError for an unknown
    ``mode`` or "estimate" without a 1 sigma in the file."""
    if mode not in MISALIGNMENT:
        raise ValueError("beacon misalignment must be one of %s, got %r" % ("/".join(MISALIGNMENT), mode))
    fig = np.radians(sf.beacon_misalignment_deg(d, False))
    sd = np.radians(sf.beacon_misalignment_sigma_deg(d))
    if mode == "estimate" and not sd > 0:
        raise ValueError("--beacon-misalignment estimate needs the camera's alignment uncertainty: the spacecraft "
                         "file's uncertainty.beacon_misalignment_sigma_deg is %s (give its 1 sigma, deg, > 0)"
                         % sf.num_text(sf.beacon_misalignment_sigma_deg(d)))
    return {"estimate": mode == "estimate", "figure": fig, "truth": np.radians(sf.beacon_misalignment_deg(d)),
            "P0": sd * sd * np.eye(3), "C": stkf.misalignment_dcm(fig) if np.any(fig != 0) else None}


def _check(case, duration_s, lag_s, outages, attitude, delay_s):
    """``simulate``'s arguments checked (ValueError naming the bad one); the outages parsed."""
    if attitude not in ATTITUDES:
        raise ValueError("attitude must be one of %s, got %r" % ("/".join(ATTITUDES), attitude))
    if case not in (1, 2):
        raise ValueError("case must be 1 or 2, got %r" % (case,))
    if not (np.isfinite(duration_s) and duration_s >= 1):
        raise ValueError("duration must be >= 1 s, got %r" % (duration_s,))
    if case == 2 and delay_s[1] > lag_s:
        raise ValueError("relay delay up to %.2f s (partner.relay_delay_s) is longer than the smoother's lag of "
                         "%.2f s" % (delay_s[1], lag_s))
    outages = [o if isinstance(o, tuple) else parse_outage(o) for o in outages]
    if case == 1 and any(o[0] == "relay" for o in outages):
        raise ValueError("a relay outage was given for Case 1, which has no relay (SatB's GNSS is Case 2)")
    return outages


def _record(hist, k, t, flt, x_true, A_hat, A_true, P_att, mis):
    """Row k of the history: the estimate's error and 1 sigma, its NEES, the pointing error and its 1 sigma,
    the line of sight's direction error (arcsec, J2000: the orbits' alone, without the attitude's), the
    misalignment's error and 1 sigma (arcsec; "ignore": the figure's error, 1 sigma 0), the attitude knowledge's
    error d_alpha (A_true = A(d_alpha) A_hat, Eq. 4.77) and the 1 sigma the filter is given (arcsec), SatB's
    estimate [rB, vB] and its 6 x 6 covariance (m, m/s; the plots resolve rB's and vB's errors in its orbit's frame);
    FloatingPointError when the filter diverged (NaN, or an orbit under the Earth's surface)."""
    x, Pk = flt.x, flt.Pk
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(Pk))):
        raise FloatingPointError("filter diverged at t=%.0f s (NaN in x or P)" % t)
    if min(x[0:3] @ x[0:3], x[6:9] @ x[6:9]) < orbits.R_EARTH ** 2:
        raise FloatingPointError("filter diverged at t=%.0f s: an estimated orbit is under the Earth's "
                                 "surface" % t)
    hist["err"][k] = x[:stkf.N] - x_true
    sig = np.sqrt(np.diag(Pk))
    hist["sig"][k] = sig[:stkf.N]
    hist["xB"][k], hist["PB"][k] = x[6:12], Pk[6:12, 6:12].ravel()
    hist["nees"][k] = hist["err"][k] @ np.linalg.solve(Pk[:stkf.N, :stkf.N], hist["err"][k])
    if mis["estimate"]:
        hist["merr"][k] = (x[stkf.IM] - mis["truth"]) / RAD_PER_ARCSEC
        hist["msig"][k] = sig[stkf.IM] / RAD_PER_ARCSEC
    else:
        hist["merr"][k] = (mis["figure"] - mis["truth"]) / RAD_PER_ARCSEC
    hist["perr"][k] = stkf.pointing_error(x, A_hat, x_true, A_true) / RAD_PER_ARCSEC
    hist["lerr"][k] = np.linalg.norm(np.cross(stkf.los(x)[0], stkf.los(x_true)[0])) / RAD_PER_ARCSEC
    M = A_true.dot(A_hat.T)                       # A(d_alpha) ~ I - [d_alpha x]
    hist["aerr"][k] = 0.5 * np.array([M[1, 2] - M[2, 1], M[2, 0] - M[0, 2], M[0, 1] - M[1, 0]]) / RAD_PER_ARCSEC
    hist["asig"][k] = np.sqrt(np.diag(P_att)) / RAD_PER_ARCSEC
    hist["psig"][k] = np.sqrt(np.diag(stkf.pointing_covariance(x, Pk, A_hat, P_att))) / RAD_PER_ARCSEC


_I6 = np.eye(6)


def _h_sat(x):
    """GNSS of one satellite (Eq. 5.12): H = I on its part."""
    return x, _I6


def _step(flt, k, t, zg, y, due, A_hat, P_att, R_g, R_relay, sigma_b, mis):
    """One second of the filter: predict to t, SatA's GNSS and the beacon (one stacked update when both came:
    the two noises are independent; either alone otherwise; None: not received), SatB's relayed fixes ``due``.
    ``mis``: ``misalignment_setup``'s; with a nonzero figure the camera's attitude C A(q_hat) takes A(q_hat)'s place."""
    if k > 0:
        flt.predict(t)
    if mis["estimate"]:
        _update_m(flt, zg, y, A_hat, P_att, R_g, sigma_b)
    elif mis["C"] is not None:
        C = mis["C"]
        _update(flt, zg, y, C.dot(A_hat), C.dot(P_att).dot(C.T), R_g, sigma_b)
    else:
        _update(flt, zg, y, A_hat, P_att, R_g, sigma_b)
    for tm, z in due:
        flt.update(z, R_relay, _h_sat, t=tm, part=stkf.SAT_B)


def _update(flt, zg, y, A_hat, P_att, R_g, sigma_b):
    """SatA's GNSS and the beacon, the camera aligned with the body frame A(q_hat) (Eq. 5.12, 5.13-5.16)."""
    if zg is not None and y is not None:
        R_gb = stkf.R_gnss_beacon(R_g, stkf.h_beacon(flt.x, A_hat), sigma_b, P_att)
        flt.update(np.concatenate([zg, y]), R_gb, lambda x: stkf.gnss_beacon(x, A_hat))
    elif zg is not None:
        flt.update(zg, R_g, _h_sat, part=stkf.SAT_A)
    elif y is not None:
        Rb = stkf.R_beacon(stkf.h_beacon(flt.x, A_hat), sigma_b, P_att)
        flt.update(y, Rb, lambda x: stkf.h_beacon(x, A_hat), lambda x: stkf.H_beacon(x, A_hat))


def _update_m(flt, zg, y, A_hat, P_att, R_g, sigma_b):
    """``_update`` with the misalignment in the state (``stkf.gnss_beacon_m``, ``stkf.beacon_m``)."""
    if y is None:
        if zg is not None:
            flt.update(zg, R_g, _h_sat, part=stkf.SAT_A)
        return
    Rb = stkf.R_beacon_m(flt.x, A_hat, sigma_b, P_att)
    if zg is None:
        flt.update(y, Rb, lambda x: stkf.beacon_m(x, A_hat))
    else:
        flt.update(np.concatenate([zg, y]), _blockdiag(R_g, Rb), lambda x: stkf.gnss_beacon_m(x, A_hat))


def _misalignment_result(hist, mis):
    """The result's misalignment figures (arcsec): the truth, the final error and 1 sigma per angle, and
    whether each final error is within 3 sigma ("estimate" only; "ignore": the figure's error, 1 sigma 0)."""
    e, sd = hist["merr"][-1], hist["msig"][-1]
    out = {"beacon_misalignment": "estimate" if mis["estimate"] else "ignore",
           "misalignment_truth_arcsec": (mis["truth"] / RAD_PER_ARCSEC).tolist(),
           "final_error_misalignment_arcsec": e.tolist(), "final_sigma_misalignment_arcsec": sd.tolist()}
    if mis["estimate"]:
        out["misalignment_within_3sigma"] = bool(np.all(np.abs(e) <= 3.0 * sd))
    return out


def _result(seed, case, truth, attitude, K, d, flt, hist, step_s, outage_list, log):
    """``simulate``'s result dict from the filter at the end and the run's history."""
    Pk = flt.Pk
    tot = lambda s: float(np.sqrt(np.trace(Pk[s, s])))  # noqa: E731
    res = {"seed": int(seed), "case": case, "truth": truth, "attitude": attitude, "duration_s": float(K),
           "spacecraft": d["name"],
           "final_sigma_ra_m": tot(stkf.IA), "final_sigma_va_m_s": tot(stkf.VA),
           "final_sigma_rb_m": tot(stkf.IB), "final_sigma_vb_m_s": tot(stkf.VB),
           "final_sigma_pointing_arcsec": float(np.hypot(*hist["psig"][-1])),
           "final_error_ra_m": float(np.linalg.norm(hist["err"][-1, 0:3])),
           "final_error_va_m_s": float(np.linalg.norm(hist["err"][-1, 3:6])),
           "final_error_rb_m": float(np.linalg.norm(hist["err"][-1, 6:9])),
           "final_error_vb_m_s": float(np.linalg.norm(hist["err"][-1, 9:12])),
           "final_error_pointing_arcsec": float(np.hypot(*hist["perr"][-1])),
           "oosm_nodes_generated": flt.generated, "step_us_mean": 1e6 * float(np.mean(step_s[1:] or step_s)),
           "step_us_median": 1e6 * float(np.median(step_s[1:] or step_s)),
           "outages": outage_list, "log": log,
           "nees": [round(float(v), 4) for v in hist["nees"]],
           "z2_sum": np.sum((hist["err"][NEES_FROM_S:] / hist["sig"][NEES_FROM_S:]) ** 2, axis=0).tolist(),
           "z2_steps": max(K + 1 - NEES_FROM_S, 0)}
    return res


def run_one(seed, run_dir, vehicle="file", **kw):
    """Campaign entry (top level, picklable): simulate, write run_dir/history.npz, result.json, run.log. The run
    flies the vehicle ``vehicle`` of the seed (``runs.fly_vehicle``): its beacon camera's misalignment, and with
    ``attitude="apkf"`` the vehicle the APKF flies."""
    from ground.adcs.runs import fly_vehicle
    t0 = time.perf_counter()
    kw["spacecraft"], vrec = fly_vehicle(kw.get("spacecraft"), seed, vehicle)
    res, hist = simulate(seed=seed, **kw)
    res["vehicle"] = vrec
    res["wall_s"] = time.perf_counter() - t0
    if run_dir:
        import io
        buf = io.BytesIO()
        np.savez(buf, **hist)
        write_atomic(os.path.join(run_dir, "history.npz"), buf.getvalue())
        write_atomic(os.path.join(run_dir, "run.log"), "\n".join(res["log"] + ["end of run"]) + "\n")
        write_json(os.path.join(run_dir, "result.json"), res)
    return res


def aggregate(results, runs_requested, complete):
    """summary.json content: the means over the good runs of the final 1 sigma (the keys)."""
    good = [r for r in results if r and "error" not in r]
    s = {k: (float(np.mean([r[k] for r in good])) if good else None) for k in KEYS}
    s["runs"] = len(good)
    s["complete"] = bool(complete and len(good) == runs_requested)
    s["runs_requested"] = runs_requested
    s["failed_runs"] = [r for r in results if r and "error" in r]
    for k in ("final_error_ra_m", "final_error_va_m_s", "final_error_rb_m", "final_error_vb_m_s",
              "final_error_pointing_arcsec"):
        s["rms_" + k] = float(np.sqrt(np.mean([r[k] ** 2 for r in good]))) if good else None
    s["step_us_mean"] = float(np.mean([r["step_us_mean"] for r in good])) if good else None
    med = [r["step_us_median"] for r in good if "step_us_median" in r]
    s["step_us_median"] = float(np.mean(med)) if med and len(med) == len(good) else None   # mean of run medians
    s["outages"] = {str(r["seed"]): r["outages"] for r in good if r["outages"]}
    s.update(consistency(good))
    s.update(misalignment_summary(good))
    return s


def misalignment_summary(good):
    """The beacon camera's misalignment over the runs ``good`` that estimated it: the share of runs whose three
    final errors are each within 3 sigma (``misalignment_within_3sigma_share``), and per angle the RMS over the
    runs of the final error and the mean final 1 sigma (arcsec). Empty without such runs."""
    est = [r for r in good if "misalignment_within_3sigma" in r]
    if not est:
        return {}
    e = np.array([r["final_error_misalignment_arcsec"] for r in est])
    sd = np.array([r["final_sigma_misalignment_arcsec"] for r in est])
    return {"misalignment_within_3sigma_share": float(np.mean([r["misalignment_within_3sigma"] for r in est])),
            "rms_final_error_misalignment_arcsec": np.sqrt(np.mean(e ** 2, axis=0)).tolist(),
            "final_sigma_misalignment_arcsec": sd.mean(axis=0).tolist()}


def consistency(good):
    """The STKF's consistency over the runs ``good`` from ``NEES_FROM_S``: ``nees_in_band_share``, the share of
    steps whose mean NEES over the runs (12 dof, all four vectors) lies in its 95 % band, and per vector (SatA,
    SatB position, velocity) the RMS over runs, steps and axes of the error over its 1 sigma
    (``rms_over_sigma_*``, 1 if P is right). None without runs."""
    from ground.adcs.runs import nees_band
    out = {"nees_in_band_share": None, "nees_mean": None, "rms_over_sigma_ra": None,
           "rms_over_sigma_va": None, "rms_over_sigma_rb": None, "rms_over_sigma_vb": None}
    good = [r for r in good if r.get("nees") and r.get("z2_steps")]
    if not good:
        return out
    n = min(len(r["nees"]) for r in good)
    mean = np.mean([r["nees"][NEES_FROM_S:n] for r in good], axis=0)
    lo, hi = nees_band(len(good), dof=12)
    z2 = np.sum([r["z2_sum"] for r in good], axis=0) / sum(r["z2_steps"] for r in good)
    out.update(nees_in_band_share=float(np.mean((mean >= lo) & (mean <= hi))), nees_mean=float(mean.mean()),
               nees_band=[lo, hi])
    for i, k in enumerate(("ra", "va", "rb", "vb")):
        out["rms_over_sigma_" + k] = float(np.sqrt(np.mean(z2[3 * i:3 * i + 3])))
    return out


def report_md(summary, case, args_text):
    th = THESIS[case]
    names = {"final_sigma_ra_m": ("rA", "m"), "final_sigma_va_m_s": ("vA", "m/s"),
             "final_sigma_rb_m": ("rB", "m"), "final_sigma_vb_m_s": ("vB", "m/s"),
             "final_sigma_pointing_arcsec": ("pointing vector", "arcsec")}
    lines = ["# STKF Case %d (%s)" % (case, "without SatB GNSS" if case == 1 else "with SatB GNSS, delayed (EAFLS)"),
             "", "`%s`" % args_text, "",
             "Runs: %d of %d, complete: %s. Spacecraft: %s." % (summary["runs"], summary["runs_requested"],
                                                                 summary["complete"],
                                                                 (summary.get("spacecraft") or {}).get("name",
                                                                                                       "thesis-3u")), "",
             "Attitude: %s." % ("from the APKF run in the same simulation (Sec. 4.8 Case 1 scenario)"
                                if summary.get("attitude") == "apkf" else "stated covariance (below)"), "",
             "| final 1 sigma | thesis | ours | ours/thesis | within 25 % | MC RMS of the final error |",
             "|---|---|---|---|---|---|"]
    for k, (n, u) in names.items():
        v = summary.get(k)
        e = summary.get("rms_" + k.replace("sigma", "error"))
        if v is None:
            lines.append("| %s (%s) | %g | — | — | — | — |" % (n, u, th[k]))
            continue
        lines.append("| %s (%s) | %g | %.4g | %.2f | %s | %s |" % (n, u, th[k], v, v / th[k],
                     "yes" if abs(v / th[k] - 1) <= 0.25 else "**no**", "—" if e is None else "%.4g" % e))
    lines += ["", "Definitions: 1 sigma totals are sqrt(trace) of each 3x3 block; the pointing figure is",
              "sqrt(Pz11 + Pz22) of Eq. 5.59. Stated attitude: body held on J2000, attitude knowledge error white",
              "with the APKF's Sec. 4.8 Case 1 final 1 sigma (9.81, 8.01, 19.70 arcsec) as P_att.",
              "Truth: %s. The thesis's truth was STK HPOP (JGM-2); ours is brahe (EGM2008 30x30, NRLMSISE-00,"
              % summary.get("truth", "?"),
              "conical SRP, low-precision Sun/Moon; no tides, no DE440s) or two-body: a figure that misses is",
              "reported as is, not tuned.", ""]
    if summary.get("nees_in_band_share") is not None:
        lines += ["Consistency after %d s: the runs' mean NEES (12 dof) %.2f, in its 95 %% band [%.2f, %.2f] %.2f of "
                  "the steps; RMS error / 1 sigma: rA %.2f, vA %.2f, rB %.2f, vB %.2f (1 if P is right; below 1 the "
                  "filter is cautious, above 1 overconfident)." % (
                      NEES_FROM_S, summary["nees_mean"], summary["nees_band"][0], summary["nees_band"][1],
                      summary["nees_in_band_share"], summary["rms_over_sigma_ra"], summary["rms_over_sigma_va"],
                      summary["rms_over_sigma_rb"], summary["rms_over_sigma_vb"]), ""]
    if summary.get("misalignment_within_3sigma_share") is not None:
        lines += ["The beacon camera's misalignment, estimated: each final error within 3 sigma in %.0f %% of the "
                  "runs; RMS final error %s arcsec, mean final 1 sigma %s arcsec (about body x, y, z)." % (
                      100 * summary["misalignment_within_3sigma_share"],
                      ", ".join("%.1f" % v for v in summary["rms_final_error_misalignment_arcsec"]),
                      ", ".join("%.1f" % v for v in summary["final_sigma_misalignment_arcsec"])), ""]
    if summary["outages"]:
        lines += ["## Sensor outages (the filter propagated through them)", ""]
        for seed, ol in summary["outages"].items():
            for o in ol:
                lines.append("- seed %s: %s silent from %.1f s to %s" % (
                    seed, o["sensor"], o["from_s"], "the end" if o["to_s"] is None else "%.1f s" % o["to_s"]))
        lines.append("")
    if summary["failed_runs"]:
        lines += ["## Failed runs", ""] + ["- seed %s: %s" % (r["seed"], r["error"]) for r in summary["failed_runs"]]
    return "\n".join(lines) + "\n"


def plots(out_dir, run_dirs, case):
    """Fig. 5-4/5-6 (state errors with ±3σ) and Fig. 5-5/5-7 (pointing vector): ``stkf_plots``."""
    from ground.adcs import stkf_plots
    return stkf_plots.plots(out_dir, run_dirs, case, FIGURES)


def dumps(obj):
    return json.dumps(obj, indent=1)
