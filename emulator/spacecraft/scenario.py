"""The attitude-determination scenario of Yoon 2017, Sec. 4.7-4.8: truth, disturbance cases and sensor records.

- Maneuver (Sec. 4.7.1, Fig. 4-2): a 30 s hold, then 5 sets of stop-and-go 30 deg rotations about body X, Y and Z
  (each rotation 30 s on a smooth 1 - cos profile, then 30 s hold), 930 s in all. Every set adds the same three
  rotations to the command (the thesis does not say whether sets reverse; assumed).
- omega0 = [1, 0, 0] deg/s momentum bias (Sec. 4.7.3), wheels initially at rest relative to the body.
- Control (Sec. 4.7.2, 4.8): quaternion PD with feed-forward and gyroscopic compensation, from perfect knowledge of
  q and w but the nominal J0, C0, Jrw; minimum-norm wheel torques (Eq. 4.144) plus the null-space torque of
  Eq. 4.145 with a = 10 % of the largest minimum-norm wheel torque of that step; held over each 1 s control step.
- Truth: ``Spacecraft`` (RK4, gravity gradient + residual dipole, true J, C, Jrw of Sec. 4.8), step ``dt`` (1 s as
  in the thesis, finer selectable); sensors sampled at 1 Hz.
- Disturbance (``tau_d``): Case 1 none; Case 2 Eq. 4.150; Case 3 Eq. 4.151 read as tau_mag (1 - q_i) per axis
  (the OCR shows "1 - q3" and "- q2"; no square is visible; Fig. 4-7's 0.2-1.2e-6 N m range fits).
- Wheels: the thesis's true Jrw, misalignments (Eq. 4.149) and 10 rpm read-out, with the speed limit raised to
  20 000 rpm (``SCENARIO_WHEELS``): the thesis models no limit, and with the emulator's 10 000 rpm default the
  residual dipole's secular torque (~2e-6 N m, 0.27 A m^2 in ~25 uT) plus the maneuver momentum saturate two
  wheels within the 930 s (measured: up to 11 800 rpm without the null torque).
- Sensors: star tracker (``devices.StarTracker``, 20/20/60 arcsec, 1 Hz, none at |w| >= 0.1 deg/s); tachometers
  10 rpm 1 sigma on W - c_i.w; a MEMS gyro for the MEKF baseline (model in ``MemsGyro``).

Also here: ``pointing_world``, the world of the body-pointing scenario (Sec. 6.4) that ground/adcs/body_pointing.py's
``simulate`` and emulator/adcs_session.py's ``AdcsSession`` both run, built in one place so that the "same
scenario" they are compared on stays the same.
"""

from dataclasses import dataclass

import numpy as np

from emulator.navsensors import Beacon, Gnss, Relay
from emulator.spacecraft.devices import StarTracker
from emulator.spacecraft.dynamics import J0_THESIS, Spacecraft, dcm, inertia_matrix, quat_mul
from emulator.spacecraft.environment import GridOrbit, TiltedDipoleField  # noqa: F401  (scenario.GridOrbit)
from emulator.spacecraft.wheels import J_RW_NOMINAL, Wheels, WheelParams, pyramid_c0
from protocol import paramfile
from protocol.units import RAD_PER_ARCSEC

DEG = np.pi / 180.0
HOUR = 3600.0
TAU_MAG = 1e-6                                   # N m (Eq. 4.150-4.151)
CASE2_PERIODS = (80.0, 72.7, 82.47)              # s
CASE2_PHASES_DEG = (90.0, 0.0, 135.0)
CASES = (1, 2, 3)
SCENARIO_WHEELS = dict(speed_max_rpm=20000.0)
STKF_P0_DIAG = [4e3 ** 2] * 3 + [100.0 ** 2] * 3 + [4e3 ** 2] * 3 + [100.0 ** 2] * 3   # Sec. 5.5.1 (m^2, (m/s)^2)
WORLD_RATE_HZ = 20                               # the orbit grid of pointing_world (RK4 mid-steps at 0.05 s)
# The body-pointing world's wheel speed limit: one no run reaches. The thesis's wheels (Eq. 4.56) have none and
# Sec. 6.4.2 keeps Sec. 4.8's conditions. Measured (bps, seed 0, t_s 33 s): the first slew to SatB peaks at
# ~23,000 rpm (wheel 3, t = 37 s; the flight loop over CAN the same), and after settling the residual dipole's
# secular torque (field at Eq. 5.53's epoch) takes a wheel past the datasheet's 10,000 rpm at ~430 s and past
# SCENARIO_WHEELS' 20,000 rpm at ~920 s (~24,500 rpm by 4000 s). bps reports the largest speed and the clips,
# bench_bps the runs with those limits: a real design must limit the slew's rate and unload the wheels
# (magnetorquers), neither of which the thesis models.
POINTING_WHEEL_RPM = 1e5
HOLD_S = 30.0      # rate damping while the APKF converges on the star tracker (as the 30 s hold of Sec. 4.7.1)
LAG_S = 4.0        # the STKF smoother's lag: relay delay U(2, 3) s (Sec. 5.5.1) + up to 1 s to the next cycle
# The flight world's STKF dynamics under the hpop truth (the app's configuration keys; the thesis world and a
# two-body truth, whose Earth has no J2, keep the thesis's two-body model and qa): the J2 model with the white acceleration noise of the hpop truth's acceleration beyond it,
# q = 2 sigma_a^2 tau per axis, the largest over the presets' orbits rounded up (docs/ADCS.md, "The flight
# STKF's gravity model"; bench/bench_stkf_gravity.py measures it)
FLIGHT_STKF = {"stkf_gravity": "j2", "stkf_qa": 5e-6}
# Its other form (``stkf_accel``, ``firmware/adcs/stkf_dmc.py``): the acceleration beyond J2 as a first-order
# Gauss-Markov state per satellite and axis, sigma_a (m/s^2) the presets' largest rounded up and tau (s) their mean
# rounded (docs/ADCS.md, "The flight STKF's gravity model")
FLIGHT_STKF_MARKOV = {"stkf_gravity": FLIGHT_STKF["stkf_gravity"], "stkf_accel": "markov", "stkf_sigma_a": 1e-4,
                      "stkf_tau": 300.0}
STKF_ACCELS = ("white", "markov")                # the flight STKF's forms, the first the default


def flight_stkf(accel="white"):
    """The flight world's STKF configuration keys (hpop truth) for the form ``accel`` of ``STKF_ACCELS``."""
    if accel not in STKF_ACCELS:
        raise ValueError("stkf_accel must be one of %s, got %r" % (", ".join(STKF_ACCELS), accel))
    return FLIGHT_STKF if accel == "white" else FLIGHT_STKF_MARKOV


def tau_d_case(case, t, q):
    """Unmodelled disturbance torque (N m, body) of Case 1-3 at time t and attitude q."""
    if case == 1:
        return np.zeros(3)
    if case == 2:                                                   # Eq. 4.150
        return TAU_MAG * np.sin(2 * np.pi * t / np.array(CASE2_PERIODS) + np.radians(CASE2_PHASES_DEG))
    if case == 3:                                                   # Eq. 4.151 (as read)
        return TAU_MAG * (1.0 - np.asarray(q[:3]))
    raise ValueError("case must be 1, 2 or 3, got %r" % (case,))


def axis_angle_quat(axis, angle):
    s = np.sin(0.5 * angle)
    return np.array([axis[0] * s, axis[1] * s, axis[2] * s, np.cos(0.5 * angle)])


@dataclass
class Maneuver:
    """Commanded attitude (inertial to body), rate and acceleration (body command frame) at time t."""

    hold_s: float = 30.0
    sets: int = 5
    angle_deg: float = 30.0
    rot_s: float = 30.0
    pause_s: float = 30.0
    q0: tuple = (0.0, 0.0, 0.0, 1.0)

    @property
    def duration(self):
        return self.hold_s + self.sets * 3 * (self.rot_s + self.pause_s)

    @property
    def set_s(self):
        return 3 * (self.rot_s + self.pause_s)

    def command(self, t):
        q = np.array(self.q0, dtype=float)
        w, wd = np.zeros(3), np.zeros(3)
        if t <= self.hold_s:
            return q, w, wd
        tt = min(t, self.duration) - self.hold_s
        th = self.angle_deg * DEG
        n_seg = int(tt // (self.rot_s + self.pause_s))
        q = self._turned(min(n_seg, 3 * self.sets))
        r = tt - n_seg * (self.rot_s + self.pause_s)
        if n_seg >= 3 * self.sets:
            return q.copy(), w, wd
        ax = np.eye(3)[n_seg % 3]
        if r >= self.rot_s:
            return quat_mul(axis_angle_quat(ax, th), q), w, wd
        x = np.pi * r / self.rot_s
        ang = 0.5 * th * (1 - np.cos(x))
        q = quat_mul(axis_angle_quat(ax, ang), q)
        w = ax * 0.5 * th * np.sin(x) * np.pi / self.rot_s
        wd = ax * 0.5 * th * np.cos(x) * (np.pi / self.rot_s) ** 2
        return q, w, wd

    def _turned(self, n):
        """q0 after the first n rotations, by the same products in the same order each time (cached)."""
        cache = self.__dict__.setdefault("_turned_cache", {0: np.array(self.q0, dtype=float)})
        if n not in cache:
            cache[n] = quat_mul(axis_angle_quat(np.eye(3)[(n - 1) % 3], self.angle_deg * DEG), self._turned(n - 1))
        return cache[n]

    def set_end_times(self):
        return [self.hold_s + (i + 1) * self.set_s for i in range(self.sets)]


def null_vector(c):
    """Unit null vector of a 3 x 4 C (Eq. 4.145), sign fixed so its first nonzero entry is positive."""
    n = np.linalg.svd(c)[2][-1]
    return n if n[np.flatnonzero(np.abs(n) > 1e-12)[0]] > 0 else -n


def wheel_torques(tau_c, c0, null_fraction=0.1, w_rel=None, n=None):
    """Motor torques giving body torque tau_c: min-norm (Eq. 4.144) + null torque a N (Eq. 4.145).

    The body feels -C u (reaction), so u = -C^T (C C^T)^-1 tau_c + a N with |a| = null_fraction max|u_mn|.
    The sign of a opposes the wheels' null-space speed N.W_rel (assumed: a fixed sign drove the wheels into
    their 10 000 rpm limit within the 930 s run; the thesis only asks a to be small enough to avoid that).
    """
    u = -c0.T @ np.linalg.solve(c0 @ c0.T, tau_c)
    n = null_vector(c0) if n is None else n
    sign = -1.0 if (w_rel is not None and n @ w_rel > 0) else 1.0
    return u + sign * null_fraction * np.max(np.abs(u)) * n


class PD:
    """Quaternion PD with feed-forward and gyroscopic compensation on nominal J0, C0, Jrw (perfect q, w)."""

    def __init__(self, bandwidth=0.2, zeta=0.9, j0=J0_THESIS, c0=None, jrw=J_RW_NOMINAL):
        """``j0`` [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz], ``c0`` (3 x 4 nominal axes, default Eq. 4.147's pyramid) and
        ``jrw`` (kg m^2, one or per wheel): the nominal vehicle the controller is designed on."""
        self.j = inertia_matrix(j0)
        d = np.diag(self.j)
        self.kp = d * bandwidth ** 2
        self.kd = d * 2 * zeta * bandwidth
        self.c0 = pyramid_c0() if c0 is None else np.array(c0, dtype=float)
        self.cj0 = self.c0 * (jrw if np.ndim(jrw) == 0 else np.asarray(jrw, dtype=float))

    def torque(self, q, w, w_rel, qc, wc, wdc):
        dq = quat_mul(q, np.array([-qc[0], -qc[1], -qc[2], qc[3]]))        # body error, A(dq) = A(q) A(qc)^T
        e = dq[:3] if dq[3] >= 0 else -dq[:3]
        wc_b = dcm(dq) @ wc
        h = self.j @ w + self.cj0 @ w_rel
        return self.j @ (dcm(dq) @ wdc) + np.cross(w, h) - 2 * self.kp * e - self.kd * (w - wc_b)


class MemsGyro:
    """Rate-integrating MEMS gyro at 1 Hz (Sec. 4.4.1; model stated here, the thesis gives only the figures).

    w_meas,k = dtheta_k / dt + b_k + sigma_v / sqrt(dt) n_k   (Eq. 4.17: ARW sigma_v = 3 deg/sqrt(h))
    b_0 ~ N(0, (1 deg/h)^2) per axis (bias repeatability), b_{k+1} = b_k + sigma_u sqrt(dt) m_k (Eq. 4.20) with
    sigma_u = 0.05 deg/h / sqrt(1 h) (the bias-instability figure taken as the drift over one hour).
    dtheta_k is the true rotation vector over the step.
    """

    def __init__(self, rng, arw_deg_rt_h=3.0, bias_deg_h=1.0, instability_deg_h=0.05):
        self.rng = rng
        self.sigma_v = arw_deg_rt_h * DEG / np.sqrt(HOUR)           # rad/sqrt(s)
        self.sigma_b0 = bias_deg_h * DEG / HOUR                     # rad/s
        self.sigma_u = instability_deg_h * DEG / HOUR / np.sqrt(HOUR)   # rad/s/sqrt(s)
        self.b = self.sigma_b0 * rng.standard_normal(3)

    def measure(self, q_prev, q, dt):
        dq = quat_mul(q, np.array([-q_prev[0], -q_prev[1], -q_prev[2], q_prev[3]]))
        if dq[3] < 0:
            dq = -dq
        s = np.linalg.norm(dq[:3])
        rot = dq[:3] * (2 * np.arctan2(s, dq[3]) / s) if s > 0 else np.zeros(3)
        w = rot / dt + self.b + self.sigma_v / np.sqrt(dt) * self.rng.standard_normal(3)
        self.b = self.b + self.sigma_u * np.sqrt(dt) * self.rng.standard_normal(3)
        return w


def filter_truth(sc, jxx_ref=J0_THESIS[0]):
    """The parameters in the APKF's own terms (Sec. 4.6.2): J incl. the rotors' transverse share C Jrw C^T,
    everything scaled by s = Jxx_ref / Jxx_true (J, Jrw, dipole, tau_d; Jxx_ref the filter's, the nominal Jxx),
    and Jrw_i divided by the norm of the unnormalised Eq. 4.60 column the filter uses."""
    w = sc.wheels
    j_eq = sc.j + w.c @ np.diag(w.j) @ w.c.T
    s = jxx_ref / j_eq[0, 0]
    c1n = np.sqrt(1 + np.radians(w.p.delta1_deg) ** 2 + np.radians(w.p.delta2_deg) ** 2)
    js = s * j_eq
    return {"scale": s, "J5": np.array([js[1, 1], js[2, 2], js[0, 1], js[0, 2], js[1, 2]]),
            "m": s * sc.dipole, "delta1": np.radians(w.p.delta1_deg), "delta2": np.radians(w.p.delta2_deg),
            "jrw": s * w.j / c1n, "J": js}


def truth_setup(d):
    """What ``simulate`` flies for a checked spacecraft file ``d`` (``protocol.spacecraft``): the true inertia
    and dipole (figure + the truth block's error), the wheels (true rotor inertia and axes, ``wheel_axes(d,
    true=True)``, their angles about ``reference_axes(d)``; the file's torque limit, friction and read-out noise;
    the speed limit ``SCENARIO_WHEELS``'), the star tracker's noise and rate limit, the gyro's figures, and the PD
    on the file's nominal inertia, axes (``wheel_axes(d)``: its nominal tilts applied) and rotor inertia. ValueError for a file the scenario cannot fly (not four wheels)."""
    from protocol import spacecraft as sf
    w = d["wheels"]
    if w["count"] != 4:
        raise ValueError("wheels.count = %d: the Sec. 4.8 scenario and the APKF fly four wheels" % w["count"])
    tf = sf.true_figures(d)
    st, g = d["star_tracker"], d["gyro"]
    wp = WheelParams(**dict(SCENARIO_WHEELS, j_rw=tuple(tf["rotor_inertia_kgm2"]), delta1_deg=tuple(tf["delta1_deg"]),
                            delta2_deg=tuple(tf["delta2_deg"]), torque_max=w["torque_limit_nm"],
                            friction_coulomb=w["friction_coulomb_nm"],
                            friction_viscous=w["friction_viscous_nms_rad"],
                            friction_smooth_rpm=w["friction_smooth_rpm"], noise_rpm=w["tach_noise_rpm"]))
    # C order: the same BLAS sums as pyramid_c0(). The wheels' c0 is the angles' reference (the unit nominal axes),
    # so that their angles, truth_params' and the filters' all count a nominal tilt once; the PD allocates on
    # the axes the file believes (the nominal tilts applied).
    c0 = np.ascontiguousarray(np.array(sf.reference_axes(d)).T)
    c_pd = np.ascontiguousarray(np.array(sf.wheel_axes(d)).T)
    return {"inertia": list(tf["inertia_kgm2"]), "dipole": np.array(tf["residual_dipole_am2"]), "wheel_params": wp,
            "c0": c0, "c": np.ascontiguousarray(np.array(sf.wheel_axes(d, True)).T),
            "star_tracker": {"sigma_arcsec": tuple(st["sigma_arcsec"]), "rate_max_dps": st["rate_limit_deg_s"]},
            "gyro": {"arw_deg_rt_h": g["arw_deg_rt_h"], "bias_deg_h": g["bias_deg_h"],
                     "instability_deg_h": g["bias_instability_deg_h"]},
            "pd": {"j0": tuple(d["inertia_kgm2"]), "c0": c_pd, "jrw": w["rotor_inertia_kgm2"]},
            "filter_truth": {"jxx_ref": d["inertia_kgm2"][0]}}


def simulate(case=1, seed=0, dt=1.0, maneuver=None, gyro=False, null_fraction=0.1, duration=None,
             wheel_params=None, inertia=None, dipole=None, st_rate_max_dps=0.1, spacecraft=None):
    """Run the scenario; returns a dict of 1 Hz arrays (index k is t = k s) and the truth parameters.

    Keys: t, q, w, w_rel (true), tach (measured W - c.w, rad/s), st_q, st_valid, gyro (index k: over k-1..k),
    gyro_bias (true bias in gyro[k]), tau_d (true, N m), truth (``filter_truth``), set_ends (s), pd_c0 (the axes
    the PD allocated on, 3 x 4).
    ``inertia`` [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz] and ``dipole`` (A m^2) replace the thesis's true values.
    ``st_rate_max_dps``: the star tracker's rate limit (Sec. 4.8's 0.1 deg/s; raised only as a diagnostic: the
    noise draws are the same at any limit).
    ``spacecraft``: a checked spacecraft file (``protocol.spacecraft.load``) to fly instead of the thesis's 3U
    (``truth_setup``); ``inertia``, ``dipole`` and ``wheel_params`` still replace its true values.
    """
    if case not in CASES:
        raise ValueError("case must be 1, 2 or 3, got %r" % (case,))
    if not (np.isfinite(dt) and 0 < dt <= 1.0 and abs(1.0 / dt - round(1.0 / dt)) < 1e-9):
        raise ValueError("dt must divide 1 s (e.g. 1, 0.5, 0.1), got %r" % (dt,))
    man = maneuver or Maneuver()
    T = man.duration if duration is None else float(duration)
    if not (np.isfinite(T) and T >= 2):
        raise ValueError("duration must be >= 2 s, got %r" % (duration,))
    rng = np.random.default_rng(seed)
    r_st, r_rw, r_g = (np.random.default_rng(s) for s in rng.integers(0, 2 ** 63, 3))
    v = truth_setup(spacecraft) if spacecraft is not None else {}
    wheels = Wheels(wheel_params or v.get("wheel_params") or WheelParams(**SCENARIO_WHEELS), rng=r_rw,
                    c0=v.get("c0"), c=v.get("c"))
    q0, _, _ = man.command(0.0)
    dipole = v.get("dipole") if dipole is None else dipole
    kw = {} if dipole is None else {"dipole": dipole}
    sc = Spacecraft(wheels=wheels, dt=dt, q=q0, omega=np.radians([1.0, 0.0, 0.0]),
                    inertia=v.get("inertia") if inertia is None else inertia,
                    disturbance=lambda t, q, w: tau_d_case(case, t, q), **kw)
    st = StarTracker(r_st, **v.get("star_tracker", {"rate_max_dps": st_rate_max_dps}))
    gy = MemsGyro(r_g, **v.get("gyro", {})) if gyro else None
    pd = PD(**v.get("pd", {}))
    n_pd = null_vector(pd.c0)
    n = int(round(T))
    sub = int(round(1.0 / dt))
    out = {k: np.zeros((n + 1, m)) for k, m in (("q", 4), ("w", 3), ("w_rel", 4), ("tach", 4), ("st_q", 4),
                                                 ("gyro", 3), ("gyro_bias", 3), ("tau_d", 3),
                                                 ("tau_c", 3))}
    out["st_valid"] = np.zeros(n + 1, dtype=bool)

    def sample(k):
        out["q"][k], out["w"][k], out["w_rel"][k] = sc.q, sc.omega, sc.omega_rw_rel
        out["tach"][k] = wheels.read_speed_rpm(sc.omega_rw_rel) * (2 * np.pi / 60)
        out["st_q"][k], out["st_valid"][k] = st.measure(sc.q, sc.omega)
        out["tau_d"][k] = tau_d_case(case, sc.t, sc.q)

    sample(0)
    for k in range(1, n + 1):
        qc, wc, wdc = man.command(sc.t)
        tau_c = pd.torque(sc.q, sc.omega, sc.omega_rw_rel, qc, wc, wdc)
        out["tau_c"][k] = tau_c
        wheels.command_all(wheel_torques(tau_c, pd.c0, null_fraction, sc.omega_rw_rel, n_pd))
        q_prev = sc.q.copy()
        for _ in range(sub):
            sc.step()
        if not np.all(np.isfinite(sc.x)):
            raise FloatingPointError("truth diverged at t = %.0f s" % sc.t)
        sample(k)
        if gy is not None:
            out["gyro_bias"][k] = gy.b
            out["gyro"][k] = gy.measure(q_prev, sc.q, 1.0)
    out["t"] = np.arange(n + 1, dtype=float)
    out["truth"] = filter_truth(sc, **v.get("filter_truth", {}))
    out["set_ends"] = [x for x in man.set_end_times() if x <= n]
    out["pd_c0"] = pd.c0
    out["clips"] = wheels.counters()
    out["spacecraft"] = sc
    out["case"] = case
    return out



# truth_params' 1σ, in the file's order: tau_d (3), J5 (5), m (3), delta1, delta2 (4 + 4), Jrw (4)
TRUTH_PARAMS_SIGMA = [1e-8] * 3 + [0.078e-3] * 5 + [0.002] * 3 + [0.061 * DEG] * 8 + [0.61e-8] * 4


def _prior_sigma(d):
    """The spacecraft file ``d``'s 1σ priors (uncertainty block) in ``TRUTH_PARAMS_SIGMA``'s order."""
    u = d["uncertainty"]
    return ([u["disturbance_torque_sigma_nm"]] * 3 + list(u["inertia_sigma_kgm2"][1:])
            + [u["residual_dipole_sigma_am2"]] * 3 + [u["misalignment_sigma_deg"]] * 8
            + [u["rotor_inertia_sigma_kgm2"]] * 4)


def truth_params(sc, spacecraft=None):
    """The parameter file a perfect calibration would write for spacecraft ``sc`` (``protocol.paramfile``): its
    own J, wheel misalignment (its wheels' angles about their nominal axes) and dipole; Jrw scaled so that the
    filter's unnormalised C Jrw (Eq. 4.60) equals the true normalised axes times the true Jrw. P: the 1σ of a
    calibration as good as the thesis's (Sec. 4.8, Case 1 final): J 0.078e-3 kg m^2 (all five), m 0.002 A m^2,
    delta 0.061 deg, Jrw 0.61e-8 kg m^2, and tau_d 1e-8 N m (1 % of its Case 2 size; the thesis gives none);
    for a checked spacecraft file ``spacecraft`` (the vehicle ``sc`` was built from) each scaled by its prior 1σ
    over thesis-3u's (the same share of the prior left)."""
    from emulator.spacecraft.wheels import misalignment_axes
    j = sc.j
    w = sc.wheels
    d1, d2 = np.radians(w.p.delta1_deg), np.radians(w.p.delta2_deg)
    c1, c2 = misalignment_axes(w.c0)
    cn = np.linalg.norm(w.c0 + c1 * d1 + c2 * d2, axis=0)
    jrw = np.asarray(w.p.j_rw, float) / cn
    sigma = np.array(TRUTH_PARAMS_SIGMA)
    if spacecraft is not None:
        sigma = sigma * (np.array(_prior_sigma(spacecraft)) / np.array(_prior_sigma(thesis_3u())))
    return {"format": paramfile.FORMAT, "wheels": 4, "jxx_ref_kgm2": float(j[0, 0]), "torque_scale": 1.0,
            "x": {"tau_d_nm": [0.0, 0.0, 0.0], "J5_kgm2": [float(v) for v in (j[1, 1], j[2, 2], j[0, 1], j[0, 2], j[1, 2])],
                  "dipole_am2": [float(v) for v in sc.dipole], "delta1_rad": d1.tolist(), "delta2_rad": d2.tolist(),
                  "jrw_kgm2": jrw.tolist()},
            "P": np.diag(sigma ** 2).tolist(),
            "calibration": {"seed": -1, "sets": 0, "duration_s": 0}}


def thesis_3u():
    """The thesis's 3U (the preset thesis-3u, checked): the vehicle when no spacecraft file is given."""
    from protocol import spacecraft as sf
    return sf.load("thesis-3u")


def laser_axis(d):
    """The laser terminal's unit boresight l_b (body frame) of a checked spacecraft file ``d``."""
    lb = np.asarray(d["laser_axis"], float)
    return lb / np.linalg.norm(lb)


def orbit_setup(d):
    """What the orbit scenarios (the STKF study of Sec. 5.5, the body-pointing world of Sec. 6.4) take from a
    checked spacecraft file ``d``: ``x0s`` (SatA's orbit.state and the partner SatB's, EME2000 [r, v]),
    ``epoch_utc`` (t = 0), ``surface`` (the orbit truth's mass, areas and coefficients,
    ``emulator.orbits.CUBESAT_3U``'s keys), ``gnss`` and ``beacon`` (``emulator.navsensors``' keywords; the
    beacon camera's true misalignment),
    ``relay_delay_s`` and ``stkf_P0_diag`` (the STKF's P0 from the uncertainty block, m^2 and (m/s)^2 per
    satellite). ValueError naming ``partner`` when the file has none."""
    from protocol import spacecraft as sf
    p = d["partner"]
    if p is None:
        raise ValueError("partner = null: the scenario tracks a partner satellite (SatB); give the spacecraft "
                         "file a partner block")
    s, u, g = d["orbit"]["state"], d["uncertainty"], d["gnss"]
    return {"x0s": (np.array(s["position_m"] + s["velocity_m_s"]), np.array(p["position_m"] + p["velocity_m_s"])),
            "epoch_utc": sf.epoch_tuple(d),
            "surface": dict({k: v for k, v in d["surface"].items() if k != "cp_offset_m"}, mass_kg=d["mass_kg"]),
            "gnss": {"sigma_r_m": g["sigma_position_m"], "sigma_v_m_s": g["sigma_velocity_m_s"]},
            "beacon": {"sigma_arcsec": d["beacon"]["sigma_arcsec"],
                       "misalignment_deg": sf.beacon_misalignment_deg(d)}, "relay_delay_s": tuple(p["relay_delay_s"]),
            "stkf_P0_diag": ([u["orbit_position_sigma_m"] ** 2] * 3 + [u["orbit_velocity_sigma_m_s"] ** 2] * 3) * 2}


# --- the body-pointing scenario's world (Sec. 6.4) ----------------------------------------------------------
def truth_span(seconds, margin_s):
    """The orbit truth's span for a run of ``seconds`` (+ ``margin_s`` for the interpolation's stencil), rounded
    up to 1000 s so that runs of similar length share one (cached) truth."""
    return float(np.ceil((seconds + margin_s) / 1000.0) * 1000.0)


def orbit_truth(kind, duration_s, orbit=None, cache_dir=None):
    """``emulator.orbits.truth_samples`` of SatA and SatB from ``orbit`` (an ``orbit_setup``; None: thesis-3u's,
    the thesis's Eq. 5.53): their initial states, epoch and surface."""
    from emulator import orbits
    o = orbit or orbit_setup(thesis_3u())
    return orbits.truth_samples(kind, duration_s, x0s=o["x0s"], cache_dir=cache_dir, epoch_utc=o["epoch_utc"],
                                spacecraft=o["surface"])


_GRID = {}      # the last grid made in this process (a campaign's vehicles fly the same orbits): key -> its arrays


def _grid_key(K, truth, cache_dir, span_margin_s, orbit):
    """What ``truth_grid``'s arrays depend on: ``orbit_truth``'s inputs (x0s, epoch, surface) and the span."""
    o = None if orbit is None else (b"".join(np.asarray(x, float).tobytes() for x in orbit["x0s"]),
                                    repr(orbit["epoch_utc"]), repr(sorted(orbit["surface"].items())))
    return K, truth, cache_dir, float(span_margin_s), o


def truth_grid(K, truth="two-body", cache_dir=None, span_margin_s=2.0, orbit=None):
    """SatA's and SatB's orbits for a run of K s: the 1 s truth samples (``emulator.orbits.truth_samples``, from
    ``orbit``, an ``orbit_setup``; None: the thesis's Eq. 5.53) and their 10th-order Lagrange interpolation
    (Sec. 6.4.1) on the ``WORLD_RATE_HZ`` grid over [0, K + 1] s.

    Returns (t_s, xs, tg, xg): t_s (n,) s, xs (n, 2, 6) and xg (len(tg), 2, 6) [r (m), v (m/s)] of SatA, SatB,
    read-only: the last grid is kept and handed to the next run of the same orbits in this process."""
    from emulator.interp import lagrange        # the interpolation of Sec. 6.4.1 (numpy)
    key = _grid_key(K, truth, cache_dir, span_margin_s, orbit)
    if key in _GRID:
        return _GRID[key]
    t_s, xs = orbit_truth(truth, truth_span(K, span_margin_s), orbit, cache_dir)
    tg = np.arange(0, (K + 1) * WORLD_RATE_HZ + 1) / WORLD_RATE_HZ
    xg = lagrange(t_s, xs.reshape(len(t_s), -1), tg, order=10).reshape(len(tg), 2, 6)
    out = (t_s, xs, tg, xg)
    for a in out:
        a.flags.writeable = False
    _GRID.clear()
    _GRID[key] = out
    return out


class PointingWorld:
    """The world of one body-pointing run (see ``pointing_world``). Members:

    - ``K`` (s, the run's length), ``rate`` (Hz, of the grid), ``t_s``, ``xs`` (1 s truth samples), ``tg``,
      ``xg`` (the grid, ``truth_grid``), ``orbit`` (``GridOrbit`` of SatA's position on it);
    - ``field`` (the tilted dipole turned to Eq. 5.53's epoch: ``gmst0`` = GMST then, ``orbits.epoch_gmst_rad``);
    - ``wheels``, ``sc`` (the ``Spacecraft``: RK4 at 0.1 s from q = [0, 0, 0, 1] at rest), ``st`` (star
      tracker), ``gnss_a`` (SatA's GNSS), ``beacon``, ``relay`` (SatB's GNSS relayed, or None);
    - ``tb`` (SatB's GNSS epochs on its own clock; empty without the relay), ``xb_tb`` (SatB's truth at ``tb``,
      or None);
    - ``stkf_P0_diag`` (12,): the STKF's initial variances (``STKF_P0_DIAG`` for the thesis's 3U), ``stkf_x0``
      (12,): its initial estimate, the truth at t = 0 off by N(0, ``stkf_P0_diag``).
    """

    def __init__(self, **members):
        self.__dict__.update(members)


def pointing_world(K, seed, satb_gnss=False, truth="two-body", cache_dir=None, span_margin_s=2.0, n_tags=None,
                   wheel_speed_limit_rpm=POINTING_WHEEL_RPM, tach_noise_rpm=None, spacecraft=None, flight=False):
    """The world of a body-pointing run of K s (Sec. 6.4.1-6.4.2), as a ``PointingWorld``. ``flight``: the flight
    world's truth instead (``--world flight``): the wheels at the file's speed limit (``wheel_speed_limit_rpm``
    ignored) and the drag and solar pressure torques about ``surface.cp_offset_m`` (``SurfaceTorques``).

    Truth: ``truth_grid(K, truth, cache_dir, span_margin_s)`` at ``WORLD_RATE_HZ``. Random streams: the seven
    children of ``SeedSequence(seed)``, in order: wheels, star tracker, STKF start, SatA's GNSS, SatB's GNSS,
    beacon, relay (SatB's clock phase, then each fix's delay). ``n_tags``: SatB's GNSS epochs (default K), at
    U(0, 1) + 0, 1, ... s. The caller's own margin and tag count keep its results (and its truth cache) as
    they were: ground/adcs/body_pointing.py passes 2 s and K, emulator/adcs_session.py 8 s and K + 1.
    ``spacecraft``: a checked spacecraft file (None: thesis-3u, the thesis's 3U), giving the true vehicle
    (``truth_setup``: inertia, dipole, wheels, star tracker), the orbits, epoch and sensors (``orbit_setup``);
    ValueError for a file the world cannot fly (not four wheels, no partner). The wheels' speed limit is
    ``wheel_speed_limit_rpm`` (``POINTING_WHEEL_RPM``: none in effect) and, if ``tach_noise_rpm`` is given, the
    read-out noise that (1 sigma, rpm) instead of the file's (a diagnostic; the noise draws are the same, scaled).
    """
    from dataclasses import replace
    from emulator.interp import lagrange
    from emulator.orbits import epoch_gmst_rad
    d = spacecraft or thesis_3u()
    if flight:
        wheel_speed_limit_rpm = d["wheels"]["speed_limit_rpm"]
    v, o = truth_setup(d), orbit_setup(d)
    t_s, xs, tg, xg = truth_grid(K, truth, cache_dir, span_margin_s, o)
    orbit = GridOrbit(0.0, WORLD_RATE_HZ, xg[:, 0, 0:3])
    ss = np.random.SeedSequence(seed)
    r_rw, r_st, r_init, r_ga, r_gb, r_bc, r_rel = [np.random.default_rng(s) for s in ss.spawn(7)]
    wp = replace(v["wheel_params"], speed_max_rpm=wheel_speed_limit_rpm)
    if tach_noise_rpm is not None:
        wp = replace(wp, noise_rpm=float(tach_noise_rpm))
    wheels = Wheels(wp, rng=r_rw, c0=v["c0"], c=v["c"])
    field = TiltedDipoleField(gmst0_rad=epoch_gmst_rad(o["epoch_utc"]))     # the orbits' epoch (t = 0)
    sc = Spacecraft(wheels=wheels, dt=0.1, q=(0.0, 0.0, 0.0, 1.0), omega=(0.0, 0.0, 0.0), orbit=orbit, field=field,
                    inertia=v["inertia"], dipole=v["dipole"])
    cp = d["surface"].get("cp_offset_m")
    if flight and cp is not None and any(cp):
        from emulator.spacecraft.environment import SurfaceTorques
        sc.disturbance = SurfaceTorques(t_s, xs[:, 0, :], o["epoch_utc"], d["surface"], cp)
    relay = Relay(r_rel, Gnss(r_gb, **o["gnss"]), o["relay_delay_s"]) if satb_gnss else None
    tb = (r_rel.uniform(0.0, 1.0) + np.arange(K if n_tags is None else n_tags)) if satb_gnss else np.zeros(0)
    return PointingWorld(
        K=K, rate=WORLD_RATE_HZ, t_s=t_s, xs=xs, tg=tg, xg=xg, orbit=orbit, field=field, wheels=wheels, sc=sc,
        st=StarTracker(r_st, **v["star_tracker"]), gnss_a=Gnss(r_ga, **o["gnss"]),
        beacon=Beacon(r_bc, **o["beacon"]), relay=relay, tb=tb,
        xb_tb=lagrange(t_s, xs[:, 1, :], tb, order=10) if satb_gnss else None,
        stkf_P0_diag=o["stkf_P0_diag"],
        stkf_x0=xg[0].ravel() + np.sqrt(o["stkf_P0_diag"]) * r_init.standard_normal(12))
