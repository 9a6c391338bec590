"""True orbits of SatA and SatB for the STKF study (thesis Sec. 5.5.1), sampled at 1 s.

Initial states: the J2000 (EME2000) states of Eq. 5.53 at 2016-12-19 03:24:57.4339 UTC (ISS-like, 400 km,
51.65 deg, 2300 km apart). Two truths:

* ``hpop`` (default): brahe's ``NumericalOrbitPropagator`` (Rust core), the open stand-in for STK's HPOP.
  Force model: EGM2008 gravity 30x30 (the packaged EGM2008_120 truncated), NRLMSISE-00 drag with the packaged
  space weather, solar radiation pressure with a conical Earth shadow, Sun and Moon as point masses from
  brahe's low-precision analytical ephemerides (~km level; DE440s is a download this tool does not make).
  Left out: solid-Earth and ocean tides (FES2004 is a download), relativity, planets other than Sun/Moon,
  Earth albedo/IR, and attitude-dependent areas (the 3U is a cannonball of fixed area). The thesis's STK
  run used JGM-2 gravity, so the two truths differ at the metre level over 20 min.
  brahe integrates in GCRF; the initial state is rotated from EME2000 by the frame bias and the samples
  are returned in EME2000, the frame of Eq. 5.53.
* ``two-body``: Kepler's problem solved in closed form (universal variables), no dependency; for tests.

The 3U CubeSat (stated; the thesis gives none): mass 4.0 kg, drag and SRP area 0.03 m^2 (a long face,
10 cm x 30 cm), Cd 2.2, Cr 1.3.

Samples are cached under ``<out>/truth_cache/<key>.npz``, the key a hash of every input (states, epoch,
duration, step, truth kind, spacecraft, force model, brahe version); the file is written atomically, so
a cache is complete or absent; a damaged one is computed again and replaced.
"""

import hashlib
import io
import json
import os

import numpy as np

from emulator.fileio import load_npz, write_atomic
from protocol.units import MU_EARTH as MU  # noqa: F401  (orbits.MU: Eq. 5.7)

R_EARTH = 6378136.3         # m (EGM2008)
EPOCH_UTC = (2016, 12, 19, 3, 24, 57.4339)
# Eq. 5.53, J2000, SI units: [rA, vA], [rB, vB]
X0_A = np.array([5885.025e3, 1083.325e3, 3203.013e3, 1.547068e3, 5.774748e3, -4.791070e3])
X0_B = np.array([6005.858e3, 2721.229e3, 1610.554e3, -0.749660e3, 5.039841e3, -5.723465e3])
CUBESAT_3U = {"mass_kg": 4.0, "drag_area_m2": 0.03, "cd": 2.2, "srp_area_m2": 0.03, "cr": 1.3}
GRAVITY_DEGREE = 30
TRUTHS = ("hpop", "two-body")


def check_state(x, name="state"):
    """Refuse a non-finite orbit state or one under the Earth's surface (ValueError naming the state)."""
    x = np.asarray(x, dtype=float)
    if x.shape != (6,):
        raise ValueError("%s must be 6 numbers [r (m), v (m/s)], got shape %s" % (name, x.shape))
    if not np.all(np.isfinite(x)):
        raise ValueError("%s has a NaN or infinite value: %s" % (name, x.tolist()))
    r = float(np.linalg.norm(x[:3]))
    if r < R_EARTH:
        raise ValueError("%s is under the Earth's surface: |r| = %.1f km < %.1f km"
                         % (name, r / 1e3, R_EARTH / 1e3))
    return x


def kepler(x0, t, mu=MU):
    """Two-body state(s) at times ``t`` (s, array) from ``x0``, closed form (universal variables, f and g).

    Returns (len(t), 6). Elliptic or hyperbolic; Newton on the universal anomaly chi.
    """
    x0 = np.asarray(x0, dtype=float)
    t = np.atleast_1d(np.asarray(t, dtype=float))
    r0v, v0v = x0[:3], x0[3:]
    r0 = np.linalg.norm(r0v)
    vr0 = r0v @ v0v / r0
    alpha = 2.0 / r0 - v0v @ v0v / mu  # 1/a
    sq = np.sqrt(mu)
    chi = sq * abs(alpha) * t
    for _ in range(50):
        z = alpha * chi ** 2
        c, s = _stumpff(z)
        f = r0 * vr0 / sq * chi ** 2 * c + (1 - alpha * r0) * chi ** 3 * s + r0 * chi - sq * t
        df = r0 * vr0 / sq * chi * (1 - alpha * chi ** 2 * s) + (1 - alpha * r0) * chi ** 2 * c + r0
        step = f / df
        chi = chi - step
        if np.all(np.abs(step) < 1e-12 * (1.0 + np.abs(chi))):
            break
    z = alpha * chi ** 2
    c, s = _stumpff(z)
    f = 1 - chi ** 2 / r0 * c
    g = t - chi ** 3 / sq * s
    r = f[:, None] * r0v + g[:, None] * v0v
    rn = np.linalg.norm(r, axis=1)
    fd = sq / (rn * r0) * (alpha * chi ** 3 * s - chi)
    gd = 1 - chi ** 2 / rn * c
    v = fd[:, None] * r0v + gd[:, None] * v0v
    return np.hstack([r, v])


def _stumpff(z):
    z = np.asarray(z, dtype=float)
    c = np.empty_like(z)
    s = np.empty_like(z)
    pos, neg, zero = z > 1e-8, z < -1e-8, np.abs(z) <= 1e-8
    sz = np.sqrt(z[pos])
    c[pos] = (1 - np.cos(sz)) / z[pos]
    s[pos] = (sz - np.sin(sz)) / sz ** 3
    sz = np.sqrt(-z[neg])
    c[neg] = (np.cosh(sz) - 1) / -z[neg]
    s[neg] = (np.sinh(sz) - sz) / sz ** 3
    zz = z[zero]
    c[zero] = 0.5 - zz / 24.0
    s[zero] = 1.0 / 6.0 - zz / 120.0
    return c, s


def _brahe():
    import brahe as bh
    if not getattr(_brahe, "ready", False):
        bh.initialize_eop()
        bh.initialize_sw()
        _brahe.ready = True
    return bh


def epoch_gmst_rad(epoch_utc=EPOCH_UTC):
    """Greenwich mean sidereal time (rad, in [0, 2 pi)) at ``epoch_utc``: the Earth's angle at t = 0 for the
    tilted-dipole field of a run that starts at that epoch (``TiltedDipoleField(gmst0_rad=...)``). brahe's
    ``Epoch.gmst`` with its packaged EOP (UT1 - UTC); 139.40 deg at Eq. 5.53's epoch. Precession and nutation
    since J2000 (~0.2 deg in 2016) are left out, as the field is a dipole."""
    bh = _brahe()
    y, mo, d, h, mi, s = epoch_utc
    return float(bh.Epoch(y, mo, d, h, mi, s, time_system=bh.UTC).gmst(bh.AngleFormat.RADIANS)) % (2 * np.pi)


def force_model(bh, spacecraft=CUBESAT_3U):
    """brahe force model of the module docstring; parameters [mass, drag area, Cd, SRP area, Cr]."""
    ps = bh.ParameterSource
    fm = bh.ForceModelConfig(
        gravity=bh.GravityConfiguration.spherical_harmonic(degree=GRAVITY_DEGREE, order=GRAVITY_DEGREE),
        drag=bh.DragConfiguration(model=bh.AtmosphericModel.NRLMSISE00, area=ps.parameter_index(1),
                                  cd=ps.parameter_index(2)),
        srp=bh.SolarRadiationPressureConfiguration(area=ps.parameter_index(3), cr=ps.parameter_index(4),
                                                   eclipse_model=bh.EclipseModel.CONICAL),
        third_body=[bh.ThirdBodyConfiguration(bh.ThirdBody.SUN, ephemeris_source=bh.EphemerisSource.LowPrecision),
                    bh.ThirdBodyConfiguration(bh.ThirdBody.MOON, ephemeris_source=bh.EphemerisSource.LowPrecision)],
        mass=ps.parameter_index(0))
    params = np.array([spacecraft["mass_kg"], spacecraft["drag_area_m2"], spacecraft["cd"],
                       spacecraft["srp_area_m2"], spacecraft["cr"]], dtype=float)
    return fm, params


HPOP_MIN_SPAN_S = 64.0


def hpop(x0, duration_s, step_s=1.0, epoch_utc=EPOCH_UTC, spacecraft=CUBESAT_3U):
    """brahe numerical propagation of one EME2000 state; samples (n, 6) in EME2000 every ``step_s``.

    The integrator (DP54, abs 1e-8, rel 1e-10, step <= span/16) runs over the whole span once; the samples come from its
    trajectory with brahe's 8th-order Lagrange interpolation (within 0.3 mm of stopping the integrator
    at each sample, checked when this was written).
    """
    bh = _brahe()
    y, mo, d, h, mi, s = epoch_utc
    ep = bh.Epoch.from_datetime(y, mo, d, h, mi, s, 0.0, bh.TimeSystem.UTC)
    fm, params = force_model(bh, spacecraft)
    x_gcrf = np.array(bh.state_eme2000_to_gcrf(np.asarray(x0, dtype=float)))
    n = int(round(duration_s / step_s)) + 1
    # at least 16 integrator steps over at least HPOP_MIN_SPAN_S, so the 9-point interpolation has its stencil
    # (brahe refuses samples of a span under ~40 s, measured)
    span = max((n - 1) * step_s, HPOP_MIN_SPAN_S)
    cfg = bh.NumericalPropagationConfig.default().with_max_step(min(60.0, span / 16.0))
    prop = bh.NumericalOrbitPropagator(ep, x_gcrf, cfg, fm, params)
    prop.set_interpolation_method(bh.InterpolationMethod.lagrange(8))
    prop.propagate_to(ep + float(span))
    out = np.array(prop.states_eme2000([ep + float(k * step_s) for k in range(n)]))
    out[0] = x0
    return out


def cache_key(kind, x0s, duration_s, step_s, epoch_utc=EPOCH_UTC, spacecraft=CUBESAT_3U):
    inputs = {"kind": kind, "x0": [np.asarray(x, dtype=float).tolist() for x in x0s],
              "duration_s": float(duration_s), "step_s": float(step_s), "epoch_utc": list(epoch_utc)}
    if kind == "hpop":
        import brahe
        inputs.update(spacecraft=dict(spacecraft), gravity=["EGM2008", GRAVITY_DEGREE, GRAVITY_DEGREE],
                      drag="NRLMSISE00", srp="conical", third_body="sun,moon lowprecision",
                      brahe=getattr(brahe, "__version__", "?"))
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()[:20], inputs


def truth_samples(kind="hpop", duration_s=1200.0, x0s=(X0_A, X0_B), step_s=1.0, cache_dir=None,
                  epoch_utc=EPOCH_UTC, spacecraft=CUBESAT_3U):
    """(t (n,), x (n, n_sat, 6)) at ``step_s``: the truth of every satellite, from the cache when present.

    ``kind`` is "hpop" or "two-body". The samples cover [0, duration_s] plus 10 s, so 10th-order Lagrange
    interpolation keeps a centred stencil to the end. ``epoch_utc`` (t = 0) and ``spacecraft`` (mass, areas and
    coefficients, ``CUBESAT_3U``'s keys) are hpop's (every satellite flies the same surface).
    """
    if kind not in TRUTHS:
        raise ValueError("truth must be one of %s, got %r" % ("/".join(TRUTHS), kind))
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ValueError("duration must be > 0 s, got %r" % (duration_s,))
    if not (np.isfinite(step_s) and step_s > 0):
        raise ValueError("truth step must be > 0 s, got %r" % (step_s,))
    for i, x in enumerate(x0s):
        check_state(x, "initial state of satellite %d" % i)
    span = float(np.ceil(duration_s / step_s) * step_s + 10 * step_s)
    key, inputs = cache_key(kind, x0s, span, step_s, epoch_utc, spacecraft)
    path = os.path.join(cache_dir, "truth_cache", key + ".npz") if cache_dir else None
    n = int(round(span / step_s)) + 1
    if path and os.path.exists(path):
        try:
            t, x = load_npz(path, ("t", "x"))
            if t.shape == (n,) and x.shape == (n, len(x0s), 6) and np.all(np.isfinite(x)):
                return t, x
        except ValueError:
            pass
        # a damaged cache file (not ours, truncated, the wrong shape) is computed again and replaced
    t = np.arange(n) * step_s
    if kind == "two-body":
        x = np.stack([kepler(x0, t) for x0 in x0s], axis=1)
    else:
        x = np.stack([hpop(x0, span, step_s, epoch_utc, spacecraft) for x0 in x0s], axis=1)
    r = np.linalg.norm(x[:, :, :3], axis=2)
    if not np.all(np.isfinite(x)) or r.min() < R_EARTH:
        raise ValueError("the %s truth left the valid range (min |r| %.1f km)" % (kind, np.nanmin(r) / 1e3))
    if path:
        buf = io.BytesIO()
        np.savez(buf, t=t, x=x, inputs=json.dumps(inputs))
        write_atomic(path, buf.getvalue())
    return t, x
