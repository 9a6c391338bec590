"""The truth's RK4 step in C: ``emulator.spacecraft._truth``, a CPython extension that ``pip install -e .`` builds
(pyproject.toml's ext-modules; optional, so an install without a C compiler still succeeds and the Python form
steps). Its ``Kernel`` holds the spacecraft's constants and environment; ``Kernel.step`` is one step of
``Spacecraft._step_python`` (Eq. 4.10, 4.16, 4.55-4.56, 4.69-4.75, the wheels' limits and jitter) and
``Kernel.torque`` is ``Spacecraft.external_torque``, with the same operations in the same order, compiled without floating-point contraction, so the two agree to rounding
(tests/test_truth_kernel.py).

The kernel evaluates in C the circular orbit, the orbit grid of ``environment.GridOrbit``, the tilted dipole, the
flight world's ``SurfaceTorques`` and the wheels' jitter; any other orbit, field or disturbance it calls back in
Python, once per RK4 stage as the Python form does. ``FPS_TRUTH=python`` in the environment makes every
spacecraft step the Python form.
"""

import os

import numpy as np

from emulator.spacecraft import environment as env
from emulator.spacecraft.wheels import RPM

try:
    from emulator.spacecraft import _truth
except ImportError:             # not built (no C compiler at install): the Python form steps
    _truth = None

API = 1                         # the C source's API: a stale build of another is not used
ORB_NONE, ORB_CIRCULAR, ORB_GRID, ORB_PY = range(4)
FLD_NONE, FLD_DIPOLE, FLD_PY = range(3)
DST_NONE, DST_SURFACE, DST_PY = range(3)


def available():
    """True when the C kernel is built, of this API, and ``FPS_TRUTH`` does not ask for the Python form."""
    return (_truth is not None and getattr(_truth, "API", None) == API
            and os.environ.get("FPS_TRUTH", "").lower() != "python")


def form(kernel, wheels_ok=True):
    """The form a spacecraft steps with, "kernel" or "python": ``kernel`` None = the kernel where ``available``
    (and the wheels are ``Wheels`` themselves, ``wheels_ok``), False = Python, True = the kernel or ValueError."""
    if kernel is None:
        return "kernel" if available() and wheels_ok else "python"
    if not kernel:
        return "python"
    if not available():
        raise ValueError("the truth's C kernel is not built (pip install -e . with a C compiler) or FPS_TRUTH=python")
    if not wheels_ok:
        raise ValueError("the truth's C kernel steps emulator.spacecraft.wheels.Wheels only")
    return "kernel"


def _table(a):
    """``a`` as an (n, >= 3) float64 array the kernel can read in place, or None."""
    return a if isinstance(a, np.ndarray) and a.dtype == np.float64 and a.ndim == 2 and a.shape[1] >= 3 else None


def _orbit(orbit):
    """(kind, keyword arguments) of the orbit."""
    if orbit is None:
        return ORB_NONE, {}
    if type(orbit) is env.CircularOrbit:
        return ORB_CIRCULAR, {"circular": [orbit.a, orbit.n, orbit.u0] + list(orbit.p) + list(orbit.w)}
    if type(orbit) is env.GridOrbit and _table(orbit.r) is not None:
        return ORB_GRID, {"grid": orbit.r, "grid_t0_rate": (orbit.t0, orbit.rate)}
    return ORB_PY, {"orbit_fn": orbit.position}


def _field(field):
    if field is None:
        return FLD_NONE, {}
    if type(field) is env.TiltedDipoleField:
        return FLD_DIPOLE, {"dipole_field": [field.gmst0] + list(field._m) + [env.R_EARTH, env.OMEGA_EARTH]}
    return FLD_PY, {"field_fn": field.field_floats}


def _disturbance(d):
    if d is None:
        return DST_NONE, {}
    if type(d) is env.SurfaceTorques and _table(d.force_i) is not None:
        return DST_SURFACE, {"force": d.force_i, "surface": (d.t0,) + tuple(d.cp)}

    def call(t, q, w):              # the Python form's call: q and w as arrays
        v = np.asarray(d(t, np.array(q), np.array(w)), dtype=float)
        return float(v[0]), float(v[1]), float(v[2])
    return DST_PY, {"dist_fn": call}


def build(sc):
    """The ``_truth.Kernel`` of spacecraft ``sc`` (``dynamics.Spacecraft``) for its orbit, field, disturbance and
    gravity gradient as they are (its ``step`` builds another when one of them changes)."""
    w, p = sc.wheels, sc.wheels.p
    ko, kw = _orbit(sc.orbit)
    kf, kwf = _field(sc.field)
    kd, kwd = _disturbance(sc.disturbance)
    kw.update(kwf)
    kw.update(kwd)
    zero12 = [0.0] * 12
    kw.setdefault("circular", [0.0] * 9)
    kw.setdefault("grid_t0_rate", (0.0, 0.0))
    kw.setdefault("dipole_field", [0.0] * 6)
    kw.setdefault("surface", [0.0] * 4)
    return _truth.Kernel(
        J=sc.j.ravel(), Jinv=sc.j_inv.ravel(), C=w.c.ravel(), CJ=w.cj.ravel(), jrw=w.j,
        wheel=(p.friction_viscous, p.friction_coulomb, 1.0 / (p.friction_smooth_rpm * RPM),
               p.torque_max, w.speed_max, env.MU_EARTH),
        kinds=(1 if sc.gravity_gradient else 0, ko, kf, kd, 1 if p.jitter else 0),
        g1=w.g1.ravel() if p.jitter else zero12, g2=w.g2.ravel() if p.jitter else zero12,
        r=w.r.ravel() if p.jitter else zero12, imbalance=(p.imbalance_static, p.imbalance_dynamic), **kw)
