"""One Monte Carlo run of the Sec. 4.8 scenario through the APKF or the MEKF, and the campaign's aggregate.

``run_apkf(seed, run_dir, case, ...)`` and ``run_mekf(seed, run_dir, ...)`` are top-level (picklable for Dask):
each simulates the truth from its seed, runs the filter from its initialisation (the APKF at the first two
consecutive star-tracker outputs, Sec. 4.8; the MEKF at the first), checks P (finite, positive definite) at
every step, writes ``run_dir/series.npz`` (t, error, sigma, nees, z_att_rate) and ``run_dir/result.json``, and
returns the result dict.

Units in result.json and the summary are physical and named in each key: attitude errors are the full small
angles 2 dq (arcsec), rates arcsec/s, misalignments deg, the gyro bias deg/h, inertias kg m^2, the dipole A m^2
(the APKF's Jxx-relative parameters converted with the run's scale, ``physical_params``); series.npz holds the
error state as the filter has it (dq, half angles, rad; rad/s; parameters in the filter's relative units) and
``z_att_rate``, the attitude and rate errors over their 1 sigma.
NEES (attitude and rate, 6 dof; MEKF: attitude and gyro bias): e^T P^-1 e per step; over N runs the mean is
compared with the 95 % band chi2(6N) / N (Bar-Shalom), after the first maneuver set.
A run that diverged (``divergence``: an estimate not finite, or its NEES beyond ``NEES_DIVERGED_MEDIAN`` /
``NEES_DIVERGED_LAST``) finishes with ``ok`` false, ``diverged`` true, the reason in ``diverged_why`` and its
figures null; one whose P stops being finite or positive definite raises FloatingPointError (the campaign
records it as that run's error); ``aggregate`` counts both in ``runs_diverged`` and leaves them out of its figures.
"""

import json
import os
import re
import warnings

import numpy as np

from emulator.spacecraft import scenario
from ground.adcs import apkf, mekf, quat
from ground.fileio import read_json, write_atomic, write_json
from protocol.units import RAD_PER_ARCSEC

MIN_DURATION_S = 10.0     # below ~5 s no two consecutive star-tracker outputs exist to start the filters
# Divergence bounds on the 6-dof NEES (a consistent filter's mean is 6; P(chi2_6 > 100) ~ 2e-19). Measured, APKF
# Case 1-3 on the thesis's 3U (overconfident, docs/ADCS.md): over 930 s the median after the first set is 6-13 (12
# runs), and 39 at most over any shorter duration (66 over the first set alone); the largest at any step 300 (the
# first fix after a blind rotation; 24 runs). On the generic 6U's inertia (s = 0.089), 9 runs: 3 lost P's
# positive definiteness, the other 6 had medians of 128-4300 and ended 30-90 deg off.
NEES_DIVERGED_MEDIAN = 100.0   # median over the steps after the first maneuver set (all steps if shorter)
NEES_DIVERGED_LAST = 1000.0    # at the last step
PARAM_KEYS = {
    "inertia_kgm2": "6 numbers [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz], a rigid body's: positive definite, triangle "
                    "inequality (the true spacecraft)",
    "dipole_am2": "3 numbers within +-10 A m^2 (true residual dipole; the thesis's is 0.27 A m^2)",
    "duration_s": "scenario length, 10..930 s (default 930; the star tracker answers once the 1 deg/s "
                  "initial rate is damped below 0.1 deg/s, after ~4 s)",
    "dt_truth_s": "truth RK4 step dividing 1 s, (0, 1] (default 1)",
}


def load_params(path):
    """A scenario/parameter JSON file, checked: unknown keys, NaN and a non-PD inertia are ValueErrors."""
    d = read_json(path, "params")             # NaN and Infinity parse to floats, refused below
    if not isinstance(d, dict):
        raise ValueError("params %s: expected a JSON object with keys %s" % (path, ", ".join(sorted(PARAM_KEYS))))
    return check_params(d, "params %s" % path)


def check_params(d, where="params"):
    out = {}
    for k, v in d.items():
        if k not in PARAM_KEYS:
            raise ValueError("%s: unknown key %r (allowed: %s)" % (where, k, ", ".join(sorted(PARAM_KEYS))))
        try:
            if any(isinstance(e, (str, bool)) for e in (v if isinstance(v, list) else [v])):
                raise TypeError("a string or boolean")                # JSON numbers only, not "10" or true
            a = np.array(v, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("%s: %s = %r is not numeric (%s)" % (where, k, v, PARAM_KEYS[k])) from None
        except OverflowError:                                          # an integer beyond any float
            from protocol.spacecraft import value_text
            raise ValueError("%s: %s = %s is out of range (%s)" % (where, k, value_text(v), PARAM_KEYS[k])) from None
        if not np.all(np.isfinite(a)):
            raise ValueError("%s: %s = %r is not finite (%s)" % (where, k, v, PARAM_KEYS[k]))
        out[k] = a
    if "inertia_kgm2" in out:
        a = out["inertia_kgm2"]
        if a.shape != (6,):
            raise ValueError("%s: inertia_kgm2 = %r must be %s" % (where, d["inertia_kgm2"], PARAM_KEYS["inertia_kgm2"]))
        from emulator.spacecraft.dynamics import inertia_matrix
        try:
            inertia_matrix(a)
        except ValueError as exc:
            why = "is not positive definite" if "positive definite" in str(exc) else \
                "is no rigid body's (a principal moment exceeds the sum of the other two)"
            raise ValueError("%s: inertia_kgm2 = %r %s (%s)" % (where, d["inertia_kgm2"], why,
                                                               PARAM_KEYS["inertia_kgm2"])) from None
        if not np.all((1e-4 <= a[:3]) & (a[:3] <= 1.0)):
            raise ValueError("%s: inertia_kgm2 = %r: Jxx, Jyy, Jzz must be from 1e-4 to 1 kg m^2 (a "
                             "CubeSat's; the thesis's 3U has 0.012-0.047)" % (where, d["inertia_kgm2"]))
    if "dipole_am2" in out and (out["dipole_am2"].shape != (3,) or np.abs(out["dipole_am2"]).max() > 10.0):
        raise ValueError("%s: dipole_am2 = %r must be %s" % (where, d["dipole_am2"], PARAM_KEYS["dipole_am2"]))
    for k, lo, hi in (("duration_s", MIN_DURATION_S, 930.0), ("dt_truth_s", 1e-6, 1.0)):
        if k in out and not (out[k].shape == () and lo <= out[k] <= hi):
            raise ValueError("%s: %s = %r out of range (%s)" % (where, k, d[k], PARAM_KEYS[k]))
    if "dt_truth_s" in out and abs(1.0 / out["dt_truth_s"] - round(1.0 / out["dt_truth_s"])) >= 1e-9:
        raise ValueError("%s: dt_truth_s = %r does not divide 1 s (%s; e.g. 1, 0.5, 0.1)"
                         % (where, d["dt_truth_s"], PARAM_KEYS["dt_truth_s"]))      # as scenario.simulate
    return {k: (v.tolist() if v.shape else float(v)) for k, v in out.items()}


def _simulate(case, seed, params, gyro, spacecraft=None):
    p = params or {}
    return scenario.simulate(case=case, seed=seed, dt=p.get("dt_truth_s", 1.0), gyro=gyro,
                             duration=p.get("duration_s"), inertia=p.get("inertia_kgm2"),
                             dipole=p.get("dipole_am2"), spacecraft=spacecraft)


def spacecraft_record(d, source):
    """What a run records of its spacecraft file: the name or path it was given, the file's name and the first 12
    hex digits of the SHA-256 of the checked dict (JSON, sorted keys)."""
    import hashlib
    h = hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]
    return {"source": source, "name": d["name"], "sha256": h}


def apkf_model(d):
    """The APKF's ``Model`` for a checked spacecraft file ``d``: Jxx reference = its Jxx (Sec. 4.6.2), the wheel
    axes its angles are measured from (``reference_axes``: the file's nominal tilts enter once, as the prior,
    ``apkf_prior``), star-tracker sigma, tachometer noise and ``uncertainty`` block (the initial P)."""
    from emulator.spacecraft.dispersion import scale_second_moment
    from protocol import spacecraft as sf
    return apkf.Model(jxx=d["inertia_kgm2"][0], sigma_st_arcsec=tuple(d["star_tracker"]["sigma_arcsec"]),
                      tach_rpm=d["wheels"]["tach_noise_rpm"],
                      c0=np.ascontiguousarray(np.array(sf.reference_axes(d)).T),
                      uncertainty=d["uncertainty"], scale_var=scale_second_moment(d))


def apkf_prior(d):
    """The APKF's parameter priors from a checked spacecraft file ``d``, in its relative units with the file's Jxx
    as the reference (s = 1 at the nominal, Sec. 4.6.2): J5 = [Jyy, Jzz, Jxy, Jxz, Jyz], m, d1, d2 (rad, about
    ``reference_axes``), Jrw divided by the norm of the unnormalised Eq. 4.60 column at the file's angles (the
    filter's C Jrw then equals the file's unit axes times its rotor inertia, as ``scenario.filter_truth``'s)."""
    w = d["wheels"]
    j = d["inertia_kgm2"]
    d1, d2 = np.radians(w["delta1_deg"]), np.radians(w["delta2_deg"])
    cn = np.sqrt(1 + d1 ** 2 + d2 ** 2)
    return {"j5": list(j[1:]), "m": list(d["residual_dipole_am2"]), "delta1": d1, "delta2": d2,
            "jrw": list(np.asarray(w["rotor_inertia_kgm2"], float) / cn)}


def mekf_options(d):
    """The MEKF's figures from a checked spacecraft file ``d``: gyro ARW sigma_v (rad/sqrt(s)), rate random walk
    sigma_u (rad/s/sqrt(s); the instability over one hour, Eq. 4.17-4.20), P0 (attitude, initial bias) and the
    star tracker's sigma."""
    g, u = d["gyro"], d["uncertainty"]
    return {"P0_att_rad": np.radians(u["attitude_sigma_deg"]), "P0_bias": np.radians(g["bias_deg_h"]) / 3600.0,
            "sigma_v": np.radians(g["arw_deg_rt_h"]) / 60.0,
            "sigma_u": np.radians(g["bias_instability_deg_h"]) / 3600.0 / 60.0,
            "sigma_st_rad": np.array(d["star_tracker"]["sigma_arcsec"]) * quat.RAD_PER_ARCSEC}


def _start_apkf(o, case, start_at_truth=False, model=None, spacecraft=None, form="consistent", disturbance="white"):
    """(first step, APKF) for a simulated run: attitude from the star tracker, rate differentiated from it
    (Sec. 4.8); ``start_at_truth`` puts the parameters at their true values (a diagnostic), same P0;
    ``model``: an ``apkf.Model`` other than the default (a diagnostic); ``spacecraft``: a checked spacecraft
    file giving the model (``apkf_model``) and the priors (``apkf_prior``) instead of the thesis's; ``form`` and
    ``disturbance``: the APKF's (``apkf.APKF``)."""
    k0 = _start(o)
    q0 = o["st_q"][k0]
    w0 = quat.rotvec(quat.quat_mul(q0, quat.conj(o["st_q"][k0 - 1])))
    if spacecraft is None:
        x0 = apkf.initial_state(q0, w0, o["tach"][k0])
    else:
        pr = apkf_prior(spacecraft)
        x0 = apkf.initial_state(q0, w0, o["tach"][k0], j5=pr["j5"], jrw=pr["jrw"])
        x0[15:18], x0[18:22], x0[22:26] = pr["m"], pr["delta1"], pr["delta2"]
        model = model or apkf_model(spacecraft)
    if start_at_truth:
        tr = o["truth"]
        x0[10:15], x0[15:18], x0[18:22], x0[22:26], x0[26:30] = (tr["J5"], tr["m"], tr["delta1"], tr["delta2"],
                                                                  tr["jrw"])
    return k0, apkf.APKF(x0, model=model, case=case, set_ends=o["set_ends"], form=form, disturbance=disturbance)


def _start(o):
    """Index of the first star-tracker output that follows another one (filter initialisation)."""
    v = o["st_valid"]
    ks = np.flatnonzero(v[1:] & v[:-1])
    if len(ks) == 0:
        raise ValueError("no two consecutive star-tracker outputs: the filter cannot start")
    return int(ks[0]) + 1


def apkf_error(o, k, x, case):
    """Truth minus estimate in the APKF's 41 error coordinates (truth in the filter's own terms, Sec. 4.6.2)."""
    tr = o["truth"]
    e = np.zeros(apkf.N)
    e[0:3] = quat.error_vec(o["q"][k], x[0:4])
    e[3:6] = o["w"][k] - x[4:7]
    e[6:9] = tr["scale"] * o["tau_d"][k] - x[7:10]
    e[9:14] = tr["J5"] - x[10:15]
    e[14:17] = tr["m"] - x[15:18]
    e[17:21] = tr["delta1"] - x[18:22]
    e[21:25] = tr["delta2"] - x[22:26]
    e[25:29] = tr["jrw"] - x[26:30]
    e[29:33] = o["w_rel"][k] - x[30:34]
    e[33:37] = o["w_rel"][k - 1] - x[34:38]
    e[37:41] = o["w_rel"][k] - x[38:42]
    return e


def physical_params(x, scale, model):
    """(p, G): the APKF's parameters at x in physical units and their Jacobian on the error state (23 x 41).

    p = [tau_d (N m, 3), J5 (kg m^2, 5), m (A m^2, 3), delta1, delta2 (deg, 4 + 4), Jrw (kg m^2, 4)].
    The filter's parameters are relative (Sec. 4.6.2): Jxx is fixed at ``model.jxx`` and J, m, tau_d and Jrw are
    the spacecraft's times s = Jxx_ref / Jxx (J with the rotors' transverse share, Eq. 4.16), and each Jrw_i is
    divided by the norm of its unnormalised Eq. 4.60 column c_i = c0_i + c1_i d1_i + c2_i d2_i
    (``scenario.filter_truth``). Hence J = J_f / s, m = m_f / s, tau_d = tau_d_f / s, Jrw_i = Jrw_f,i |c_i| / s;
    the angles are the filter's, in deg. A 1 sigma is sqrt(diag(G P G^T)): sigma_f / s for J, m and tau_d, and
    for Jrw_i the linearisation through |c_i| too (d|c_i|/d d1_i = c_i . c1_i / |c_i|). ``scale`` is s; the
    filter cannot observe it (the campaigns take the run's true s; ``bps.torque_scale`` estimates it)."""
    s = float(scale)
    d1, d2, jrw = x[18:22], x[22:26], x[26:30]
    c = model.c0 + model.c1 * d1 + model.c2 * d2
    cn = np.linalg.norm(c, axis=0)
    p = np.concatenate([x[7:18] / s, np.degrees(x[18:26]), jrw * cn / s])
    G = np.zeros((23, apkf.N))
    G[0:11, 6:17] = np.eye(11) / s
    G[11:19, 17:25] = np.eye(8) * (180.0 / np.pi)
    G[19:23, apkf.IJR] = np.diag(cn / s)
    G[19:23, apkf.ID1] = np.diag(jrw * np.sum(c * model.c1, axis=0) / cn / s)
    G[19:23, apkf.ID2] = np.diag(jrw * np.sum(c * model.c2, axis=0) / cn / s)
    return p, G


def apkf_params_report(o, k, f, case):
    """The APKF's parameter figures at step k in physical units (``physical_params``, the run's true s): the
    result's 1 sigma keys, ``final_error_params`` (truth minus estimate) and the scale used."""
    s = float(o["truth"]["scale"])
    p, G = physical_params(f.x, s, f.model)
    x_true = f.x.copy()
    x_true[7:30] = f.x[7:30] + apkf_error(o, k, f.x, case)[apkf.PARAMS]      # the truth in the filter's terms
    e = physical_params(x_true, s, f.model)[0] - p
    sp = np.sqrt(np.diag(G @ f.P[:apkf.N, :apkf.N] @ G.T))
    return {"sigma_jyy_jzz_kgm2": sp[3:5].tolist(), "sigma_dipole_am2": float(sp[8:11].max()),
            "max_sigma_delta_rw_deg": float(sp[11:19].max()), "max_sigma_jrw_kgm2": float(sp[19:23].max()),
            "final_error_params": {"jyy_jzz_kgm2": e[3:5].tolist(), "dipole_am2": e[8:11].tolist(),
                                   "delta_rw_deg": e[11:19].tolist(), "jrw_kgm2": e[19:23].tolist()},
            "jxx_ref_kgm2": f.model.jxx, "jxx_kgm2": f.model.jxx / s, "param_scale": s}


def divergence(nees, err, sig, k0, set_ends, what="attitude + rate"):
    """Why the run from step k0 diverged, or None: an error or 1 sigma not finite, or its NEES (6 dof) with a
    median above NEES_DIVERGED_MEDIAN after the first maneuver set (over all steps if the run ends before it)
    or above NEES_DIVERGED_LAST at the last step. Index k is t = k s."""
    bad = ~(np.all(np.isfinite(err[k0:]), axis=1) & np.all(np.isfinite(sig[k0:]), axis=1)
            & np.isfinite(nees[k0:]))
    if bad.any():
        return "the estimate is not finite from t = %d s" % (k0 + int(np.argmax(bad)))
    t0 = int(set_ends[0]) if len(set_ends) and set_ends[0] < len(nees) else k0
    med = float(np.median(nees[max(t0, k0):]))
    if med > NEES_DIVERGED_MEDIAN:
        return "%s NEES median %.3g from t = %d s (bound %g)" % (what, med, max(t0, k0), NEES_DIVERGED_MEDIAN)
    if nees[-1] > NEES_DIVERGED_LAST:
        return "%s NEES %.3g at the last step, t = %d s (bound %g)" % (what, nees[-1], len(nees) - 1,
                                                                       NEES_DIVERGED_LAST)
    return None


def _nees(e, P):
    return float(e @ np.linalg.solve(P, e))


def _write_run(run_dir, res, t, err, sig, nees, z):
    if run_dir is None:
        return
    os.makedirs(run_dir, exist_ok=True)
    import io
    buf = io.BytesIO()
    np.savez_compressed(buf, t=t, error=err, sigma=sig, nees=nees, z_att_rate=z)
    write_atomic(os.path.join(run_dir, "series.npz"), buf.getvalue())
    write_json(os.path.join(run_dir, "result.json"), res)


def _series(err, nees, z):
    """What ``aggregate`` needs of a run's history: attitude errors (full angles, arcsec), NEES and z."""
    return {"att_err": (2 * err[:, 0:3] / RAD_PER_ARCSEC).tolist(), "nees": nees.tolist(), "z_att_rate": z.tolist()}


def fly_vehicle(spacecraft, seed, vehicle="file"):
    """(the spacecraft file a run of ``seed`` flies, the record of its vehicle): ``emulator.spacecraft.dispersion
    .flown``. ``spacecraft`` None (the thesis's 3U, its built-in truth) stays None for ``vehicle`` "file"."""
    from emulator.spacecraft import dispersion
    if spacecraft is None and vehicle == "file":
        return None, {"vehicle": "file", "kind": "truth block", "truth": scenario.thesis_3u()["truth"]}
    return dispersion.flown(spacecraft or scenario.thesis_3u(), seed, vehicle)


def run_apkf(seed, run_dir=None, case=1, params=None, keep_series=True, start_at_truth=False, spacecraft=None,
             form="consistent", vehicle="file", disturbance="white"):
    """One APKF run; see the module docstring. Returns the final figures and (for the aggregate) the series.
    ``start_at_truth`` (a diagnostic, not in the CLI) starts the parameters at their true values, same P0.
    ``spacecraft``: a checked spacecraft file for the truth and the filter (None: the thesis's 3U); ``vehicle``:
    the vehicle flown (``fly_vehicle``: the file's truth block, or drawn from ``seed``); ``form``: the APKF's,
    "consistent" or "thesis", and ``disturbance``, tau_d's model, "white" or "markov" (``apkf.APKF``)."""
    spacecraft, vrec = fly_vehicle(spacecraft, seed, vehicle)
    o = _simulate(case, seed, params, gyro=False, spacecraft=spacecraft)
    k0, f = _start_apkf(o, case, start_at_truth, spacecraft=spacecraft, form=form, disturbance=disturbance)
    n = len(o["t"])
    err = np.full((n, apkf.N), np.nan)
    sig = np.full((n, apkf.N), np.nan)
    nees = np.full(n, np.nan)
    for k in range(k0, n):
        if k > k0:
            f.step(o["t"][k - 1], o["tach"][k], o["st_q"][k] if o["st_valid"][k] else None)
            apkf.check_covariance(f.P, o["t"][k])
        err[k] = apkf_error(o, k, f.x, case)
        sig[k] = np.sqrt(np.diag(f.P)[:apkf.N])           # a shaping filter's added states left out
        nees[k] = _nees(err[k, 0:6], f.P[0:6, 0:6])
    z = err[:, 0:6] / sig[:, 0:6]
    why = divergence(nees, err, sig, k0, o["set_ends"])
    res = _final(seed, "apkf", case, o, err, sig, nees, k0, why,
                 None if why else apkf_params_report(o, n - 1, f, case))
    passes = [r[2] for r in f.reacquisitions]
    res["vehicle"] = vrec
    res["filter_form"] = form
    res["disturbance_model"] = disturbance
    res["iterated_updates"] = {"count": len(passes), "max_passes": max(passes, default=0),
                               "mean_passes": float(np.mean(passes)) if passes else 0.0}
    res["fadings"] = {"count": len(f.fadings), "max_factor": max((lam for _, lam in f.fadings), default=1.0)}
    res["first_set_passes"] = [int(n) for _, n in f.iterations]    # passes over the first set (``apkf_iterated``)
    _write_run(run_dir, res, o["t"], err, sig, nees, z)
    if keep_series:
        res["series"] = _series(err, nees, z)
    return res


def run_mekf(seed, run_dir=None, case=1, params=None, keep_series=True, spacecraft=None, vehicle="file"):
    """One MEKF run with the MEMS gyro (Sec. 4.4.1). Its rate is the gyro's, w_hat = w_meas - b_hat (the bias
    before the step's update); the rate error against the truth's mean rate over the step, w_true - w_hat =
    -(b - b_hat) - n, has 1 sigma sqrt(P_bb + sigma_v^2 / dt) (Eq. 4.17, ``scenario.MemsGyro``).
    ``spacecraft``: a checked spacecraft file for the truth and the filter's figures (``mekf_options``);
    ``vehicle``: as ``run_apkf``'s."""
    spacecraft, vrec = fly_vehicle(spacecraft, seed, vehicle)
    o = _simulate(case, seed, params, gyro=True, spacecraft=spacecraft)
    k0 = np.flatnonzero(o["st_valid"])
    if len(k0) == 0:
        raise ValueError("no star-tracker output: the filter cannot start")
    k0 = int(k0[0])
    f = mekf.MEKF(o["st_q"][k0], **({} if spacecraft is None else mekf_options(spacecraft)))
    n = len(o["t"])
    err = np.full((n, 6), np.nan)
    sig = np.full((n, 6), np.nan)
    nees = np.full(n, np.nan)
    z = np.full((n, 6), np.nan)
    for k in range(k0, n):
        if k > k0:
            b_hat, var_b = f.x[4:7].copy(), np.diag(f.P)[3:6].copy()
            f.step(o["gyro"][k], o["st_q"][k] if o["st_valid"][k] else None)
            apkf.check_covariance(f.P, o["t"][k], "MEKF")
            w_true = quat.rotvec(quat.quat_mul(o["q"][k], quat.conj(o["q"][k - 1]))) / f.dt
            z[k, 3:6] = (w_true - (o["gyro"][k] - b_hat)) / np.sqrt(var_b + f.sigma_v ** 2 / f.dt)
        err[k, 0:3] = quat.error_vec(o["q"][k], f.x[0:4])
        err[k, 3:6] = o["gyro_bias"][max(k, 1)] - f.x[4:7]
        sig[k] = np.sqrt(np.diag(f.P))
        nees[k] = _nees(err[k], f.P)
        z[k, 0:3] = err[k, 0:3] / sig[k, 0:3]
    why = divergence(nees, err, sig, k0, o["set_ends"], "attitude + gyro bias")
    res = _final(seed, "mekf", case, o, err, sig, nees, k0, why)
    res["vehicle"] = vrec
    _write_run(run_dir, res, o["t"], err, sig, nees, z)
    if keep_series:
        res["series"] = _series(err, nees, z)
    return res


# the APKF's 23 parameters, in the error state's order (``apkf.PARAMS``)
PARAM_NAMES = (["tau_d_%s" % a for a in "xyz"] + ["Jyy", "Jzz", "Jxy", "Jxz", "Jyz"] + ["m_%s" % a for a in "xyz"]
               + ["delta1_%d" % i for i in range(4)] + ["delta2_%d" % i for i in range(4)]
               + ["Jrw_%d" % i for i in range(4)])
FIGURE_KEYS = {"apkf": ["final_sigma_attitude_arcsec", "final_error_attitude_arcsec", "final_sigma_rate_arcsec_s",
                        "final_error_rate_arcsec_s", "sigma_jyy_jzz_kgm2", "sigma_dipole_am2",
                        "max_sigma_delta_rw_deg", "max_sigma_jrw_kgm2", "final_error_params",
                        "final_normalised_error"],
               "mekf": ["final_sigma_attitude_arcsec", "final_error_attitude_arcsec", "final_sigma_bias_deg_h"]}


def _final(seed, name, case, o, err, sig, nees, k0, why=None, params=None):
    """result.json: the final figures (physical units; ``params`` from ``apkf_params_report``), ``ok`` and, for
    a run that diverged (``why``, from ``divergence``), ``diverged`` true and every figure null."""
    s, e = sig[-1], err[-1]
    res = {"seed": int(seed), "filter": name, "case": case, "ok": why is None, "diverged": why is not None,
           "diverged_why": why, "start_s": float(o["t"][k0]), "duration_s": float(o["t"][-1]),
           "set_ends_s": list(o["set_ends"])}
    if why is not None:
        res.update({k: None for k in FIGURE_KEYS[name]})
        res["wheel_speed_clips"] = o["clips"]
        return res
    res.update({"final_sigma_attitude_arcsec": (2 * s[0:3] / RAD_PER_ARCSEC).tolist(),
                "final_error_attitude_arcsec": (2 * e[0:3] / RAD_PER_ARCSEC).tolist()})
    if name == "apkf":
        res.update({
            "final_sigma_rate_arcsec_s": (s[3:6] / RAD_PER_ARCSEC).tolist(),
            "final_error_rate_arcsec_s": (e[3:6] / RAD_PER_ARCSEC).tolist(),
            "final_normalised_error": (e / s).tolist(),
        })
        res.update(params)
    else:
        res["final_sigma_bias_deg_h"] = (np.degrees(s[3:6]) * 3600).tolist()
    res["wheel_speed_clips"] = o["clips"]
    return res


def run_record(r):
    """A result or error record for ``summary.json``'s ``per_run``: without its series, with ``ok`` (false for an
    error record) and ``diverged`` (an error record whose P stopped being finite or positive definite too)."""
    out = {k: v for k, v in r.items() if k != "series"}
    if "error" in r:
        out["ok"], out["diverged"] = False, _raised_divergence(r)
    return out


# --- aggregate --------------------------------------------------------------------------------------------
def nees_band(runs, dof=6, p=0.95):
    """(lo, hi) of the mean NEES over `runs` runs (chi-square with dof * runs degrees of freedom, / runs)."""
    from scipy.stats import chi2
    n = dof * runs
    return chi2.ppf((1 - p) / 2, n) / runs, chi2.ppf(1 - (1 - p) / 2, n) / runs


_RAISED_DIVERGENCE = re.compile(r"FloatingPointError: (APKF|MEKF) diverged")


def _raised_divergence(r):
    """An error record of a run whose filter's P stopped being finite or positive definite (``check_covariance``;
    not the truth's own FloatingPointError)."""
    return bool(_RAISED_DIVERGENCE.match(str(r.get("error", ""))))


def aggregate(results, name, case, dof=6):
    """The summary dict over the runs that finished and did not diverge (``ok``); None figures
    when there is none. ``runs_diverged`` counts the runs that diverged, whether they finished (``divergence``)
    or raised (P not finite or not positive definite; these are also in ``runs_failed``), listed in ``diverged``.
    Over the steps after the first maneuver set (index k is t = k s; all steps if the runs end before it):
    ``nees_in_band_share`` (``nees_in_band_fraction``, the same figure under its older name), the share of steps
    whose mean NEES over the runs (attitude + rate; MEKF: attitude + gyro bias) lies in its 95 % band, and
    ``rms_over_sigma_attitude`` / ``rms_over_sigma_rate``, per axis the RMS over runs and steps of the error over
    its 1 sigma (1 for a consistent filter; the MEKF's rate is its gyro's, ``run_mekf``). APKF:
    ``params_within_3sigma_share``, over the parameters the smallest share of runs whose final error is within
    3 sigma (``params_within_3sigma_by_parameter``, each)."""
    ok = [r for r in results if r and "error" not in r and not r.get("diverged")]
    errors = [r for r in results if r and "error" in r]
    div = [r for r in results if r and (r.get("diverged") or _raised_divergence(r))]
    s = {"filter": name, "case": case, "runs": len(ok), "runs_failed": len(errors),
         "failures": [{"seed": r["seed"], "error": r["error"]} for r in errors],
         "runs_diverged": len(div),
         "diverged": [{"seed": r["seed"], "why": r.get("diverged_why") or r.get("error")} for r in div]}
    keys = ["final_sigma_attitude_arcsec", "final_sigma_rate_arcsec_s", "final_error_attitude_arcsec",
            "sigma_jyy_jzz_kgm2", "sigma_dipole_am2", "max_sigma_delta_rw_deg", "max_sigma_jrw_kgm2"]
    for k in keys + ["nees_in_band_share", "nees_in_band_fraction", "rms_over_sigma_attitude",
                     "rms_over_sigma_rate", "params_within_3sigma_share"]:
        s[k] = None
    if not ok:
        return s
    for k in keys:
        if k == "final_error_attitude_arcsec":
            a = np.array([r[k] for r in ok])
            s[k] = np.sqrt(np.mean(a ** 2, axis=0)).tolist()          # RMS over runs
        elif k in ok[0]:
            a = np.array([r[k] for r in ok], dtype=float)
            s[k] = np.mean(a, axis=0).tolist()
    with_series = [r for r in ok if "series" in r]
    nees = np.array([r["series"]["nees"] for r in with_series], dtype=float)
    t0 = ok[0]["set_ends_s"][0] if ok[0]["set_ends_s"] else 0.0
    if len(nees):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)        # steps before the filter started: all NaN
            mean = np.nanmean(nees, axis=0)
        lo, hi = nees_band(len(nees), dof)
        sel = np.arange(nees.shape[1]) >= t0
        sel &= np.all(np.isfinite(nees), axis=0)
        inside = (mean >= lo) & (mean <= hi)
        s["nees_in_band_share"] = s["nees_in_band_fraction"] = float(inside[sel].mean()) if sel.any() else None
        s["nees"] = {"band": [lo, hi], "from_s": t0, "dof": dof, "mean_after": float(np.mean(mean[sel]))
                     if sel.any() else None, "runs": len(nees),
                     # the runs' NEES variance per step over chi-square's 2 dof: the band assumes 1
                     "variance_ratio_after": float(np.mean(np.var(nees[:, sel], axis=0)) / (2 * dof))
                     if sel.any() and len(nees) > 1 else None,
                     "note": "mean over runs of e^T P^-1 e (attitude + %s); band: 95 %% chi-square"
                             % ("rate" if name == "apkf" else "gyro bias")}
    zf = [r["final_normalised_error"] for r in ok if r.get("final_normalised_error") is not None]
    if zf:
        inside = np.abs(np.array(zf, dtype=float)[:, apkf.PARAMS]) <= 3.0           # runs x 23
        s["params_within_3sigma_share"] = float(inside.mean(axis=0).min())
        s["params_within_3sigma_by_parameter"] = dict(zip(PARAM_NAMES, inside.mean(axis=0).round(4).tolist()))
    z = [np.array(r["series"]["z_att_rate"], dtype=float) for r in with_series
         if r["series"].get("z_att_rate") is not None]
    if z:
        z = np.array(z)[:, int(np.ceil(t0)):]                     # runs x steps x 6
        fin = np.isfinite(z)
        n = fin.sum(axis=(0, 1))
        if np.all(n > 0):
            rms = np.sqrt(np.sum(np.where(fin, z * z, 0.0), axis=(0, 1)) / n)
            s["rms_over_sigma_attitude"], s["rms_over_sigma_rate"] = rms[0:3].tolist(), rms[3:6].tolist()
    return s


def load_run(run_dir):
    """A finished run back from its folder (result.json + series.npz), or None if it did not finish."""
    try:
        with open(os.path.join(run_dir, "result.json")) as f:
            res = json.load(f)
        d = np.load(os.path.join(run_dir, "series.npz"))
        z = d["z_att_rate"].tolist() if "z_att_rate" in d.files else None
    except (OSError, ValueError):
        return None
    k = 2 / RAD_PER_ARCSEC
    res["series"] = {"att_err": (d["error"][:, 0:3] * k).tolist(), "nees": d["nees"].tolist(), "z_att_rate": z}
    return res


def hold_consistency(seed, case=1, start_at_truth=False, t_from=630.0, settle=10):
    """Diagnostic of the APKF's attitude accuracy: over the attitude holds after ``t_from`` (steps
    with a star-tracker output in each of the last ``settle`` + 1 seconds), the star-tracker innovations'
    NIS (z^T S^-1 z, 3 dof, before the update), the attitude and rate NEES (3 dof each), and the errors and
    1 sigma (attitude as full angles, arcsec; rate arcsec/s). Returns a dict of arrays."""
    o = _simulate(case, seed, None, gyro=False)
    k0, f = _start_apkf(o, case, start_at_truth)
    v = o["st_valid"]
    nis, err, sig, nees = [], [], [], []
    for k in range(k0 + 1, len(o["t"])):
        t = o["t"][k - 1]
        f.x, f.P = apkf.predict(f.x, f.P, o["tach"][k], f.model, t, f.case, apkf.fictitious_scale(t, f.set_ends))
        hold = t >= t_from and k > settle and bool(v[k - settle:k + 1].all())
        if v[k]:
            R = f.model.R_st * apkf.fictitious_scale(t + f.model.dt, f.set_ends)
            if hold:
                z = quat.error_vec(o["st_q"][k], f.x[0:4])
                nis.append(float(z @ np.linalg.solve(f.P[0:3, 0:3] + R, z)))
            f.x, f.P = apkf.update(f.x, f.P, o["st_q"][k], R)
        if hold:
            e = apkf_error(o, k, f.x, case)[0:6]
            err.append(e)
            sig.append(np.sqrt(np.diag(f.P)[0:6]))
            nees.append([_nees(e[0:3], f.P[0:3, 0:3]), _nees(e[3:6], f.P[3:6, 3:6])])
    err, sig = np.array(err), np.array(sig)
    k = np.array([2 / RAD_PER_ARCSEC] * 3 + [1 / RAD_PER_ARCSEC] * 3)
    return {"nis": np.array(nis), "nees_att_rate": np.array(nees), "error": err * k, "sigma": sig * k}


def random_walk_bound(rate_sigma, st_sigma=(20.0, 20.0, 60.0), dt=1.0):
    """Per axis, the steady-state 1 sigma after a star-tracker update (sigma ``st_sigma``, every dt) of an
    attitude that walks by ``rate_sigma`` dt per step (white rate errors integrated): P+ of the scalar Kalman
    filter, P- = (q + sqrt(q^2 + 4 q r)) / 2, P+ = P- r / (P- + r). Units of the inputs (arcsec, arcsec/s)."""
    q = (np.asarray(rate_sigma, dtype=float) * dt) ** 2
    r = np.asarray(st_sigma, dtype=float) ** 2
    p = (q + np.sqrt(q * q + 4 * q * r)) / 2
    return np.sqrt(p * r / (p + r))
