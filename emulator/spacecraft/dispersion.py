"""The simulated vehicle: a spacecraft file's figures, a fixed departure from them (its ``truth`` block), or a
vehicle drawn from its seed within the file's own ``uncertainty`` (a flight team's Monte Carlo dispersions).

``flown(d, seed, vehicle)`` returns (the checked file with the truth block the run flies, the record of it):

- ``"file"`` (the default): the file's ``truth`` block where it has one (thesis-3u keeps the thesis's Sec. 4.8
  errors, so its tables are unchanged); a file without one flies a vehicle drawn from ``seed``, never its own
  figures, for a filter that starts at the truth tests nothing;
- ``"drawn"``: drawn from ``seed`` whatever the file's truth block;
- ``"nominal"``: the figures themselves (a diagnostic: the filters start at the truth).

What is drawn (``draw_truth``), each error independent and Gaussian with the file's 1 sigma:

- the inertia's six entries (``uncertainty.inertia_sigma_kgm2``), redrawn until the true inertia is a rigid
  body's (positive definite, each principal moment at most the sum of the other two), so the moments and the
  products are dispersed together;
- the residual dipole per axis (``residual_dipole_sigma_am2``);
- each wheel's two misalignment angles (``misalignment_sigma_deg``) about ``reference_axes``, redrawn until the
  true angles are within +-45 deg and the axes span three axes;
- each rotor's inertia (``rotor_inertia_sigma_kgm2``), redrawn until positive;
- the beacon camera's three misalignment angles (``beacon_misalignment_sigma_deg``; absent: zero), redrawn
  until the true angles are within +-5 deg.

The star tracker's misalignment is not drawn: its frame is the body's.
The draws come from their own stream (``SeedSequence([seed, STREAM])``), so a drawn vehicle leaves the run's
noise draws as they are, and ``--seed N`` replays vehicle N exactly.
"""

import copy

import numpy as np

VEHICLES = ("file", "drawn", "nominal")
STREAM = 0x7E41C1E          # the vehicle's draws, apart from every other stream of the seed
MAX_TRIES = 1000            # redraws for one rigid body, one set of angles, one positive rotor inertia
VEHICLE_HELP = ("the simulated vehicle: file = the spacecraft file's truth block, or drawn from --seed within its "
                "uncertainty block when it has none (default); drawn = drawn from --seed always; nominal = the "
                "file's figures exactly (a diagnostic: the filters start at the truth)")


def check_vehicle(vehicle):
    """``vehicle`` if it is one of ``VEHICLES``; ValueError naming the choices otherwise."""
    if vehicle not in VEHICLES:
        raise ValueError("--vehicle %r: must be one of %s" % (vehicle, ", ".join(VEHICLES)))
    return vehicle


def _redraw(what, draw, ok):
    for _ in range(MAX_TRIES):
        v = draw()
        if ok(v):
            return v
    raise ValueError("the file's uncertainty.%s is too wide to draw a vehicle from: none of %d draws was "
                     "plausible" % (what, MAX_TRIES))


def draw_truth(d, seed):
    """A ``truth`` block for the checked spacecraft file ``d``, drawn from ``seed`` (module docstring)."""
    from protocol import spacecraft as sf
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), STREAM]))
    u, w = d["uncertainty"], d["wheels"]
    n = w["count"]
    j = np.asarray(d["inertia_kgm2"], float)
    sj = np.asarray(u["inertia_sigma_kgm2"], float)

    def rigid(e):
        lam = sf.principal_moments(list(j + e))
        return lam[0] > 0 and lam[2] <= lam[0] + lam[1]
    dj = _redraw("inertia_sigma_kgm2", lambda: sj * rng.standard_normal(6), rigid)
    dm = u["residual_dipole_sigma_am2"] * rng.standard_normal(3)
    s = u["misalignment_sigma_deg"]
    d1, d2 = np.asarray(w["delta1_deg"], float), np.asarray(w["delta2_deg"], float)

    def spans(e):
        t = copy.deepcopy(d)
        t["truth"] = {"inertia_error_kgm2": [0.0] * 6, "residual_dipole_error_am2": [0.0] * 3,
                      "rotor_inertia_error_kgm2": [0.0] * n, "delta1_error_deg": list(e[:n]),
                      "delta2_error_deg": list(e[n:])}
        if not np.all(np.abs(np.concatenate([d1, d2]) + e) <= 45.0):
            return False
        c = np.array(sf.wheel_axes(t, True))
        return np.linalg.eigvalsh(c.T @ c)[0] >= sf.SPAN_MIN
    da = _redraw("misalignment_sigma_deg", lambda: s * rng.standard_normal(2 * n), spans)
    jr = np.asarray(w["rotor_inertia_kgm2"], float)
    djr = np.array([_redraw("rotor_inertia_sigma_kgm2",
                            lambda: u["rotor_inertia_sigma_kgm2"] * rng.standard_normal(), lambda e, i=i: jr[i] + e > 0)
                    for i in range(n)])
    b0, sb = np.array(sf.beacon_misalignment_deg(d, False)), sf.beacon_misalignment_sigma_deg(d)
    db = _redraw("beacon_misalignment_sigma_deg", lambda: sb * rng.standard_normal(3),
                 lambda e: np.all(np.abs(b0 + e) <= 5.0))
    return {"inertia_error_kgm2": dj.tolist(), "residual_dipole_error_am2": dm.tolist(),
            "rotor_inertia_error_kgm2": djr.tolist(), "delta1_error_deg": da[:n].tolist(),
            "delta2_error_deg": da[n:].tolist(), "beacon_misalignment_error_deg": db.tolist()}


def scale_second_moment(d, n=4000):
    """E[(s - 1)^2] for s = Jxx / Jxx_true over the inertias ``draw_truth`` draws from the checked file ``d``
    (Gaussian entries kept where they make a rigid body), estimated from ``n`` draws of a fixed stream: the
    spread of the APKF's Jxx-relative scale (Sec. 4.6.2) that its initial P must hold. The rigid-body bound
    truncates the draws, and s = 1 / (1 + e) is skewed, so this is taken from the draws, not from sigma_Jxx
    alone (first order: (sigma_Jxx / Jxx)^2, which a 30 % sigma understates by half)."""
    rng = np.random.default_rng(np.random.SeedSequence([0, STREAM]))
    j = np.asarray(d["inertia_kgm2"], float)
    e = np.asarray(d["uncertainty"]["inertia_sigma_kgm2"], float) * rng.standard_normal((n, 6))
    t = j + e
    J = np.empty((n, 3, 3))
    J[:, 0, 0], J[:, 1, 1], J[:, 2, 2] = t[:, 0], t[:, 1], t[:, 2]
    J[:, 0, 1] = J[:, 1, 0] = t[:, 3]
    J[:, 0, 2] = J[:, 2, 0] = t[:, 4]
    J[:, 1, 2] = J[:, 2, 1] = t[:, 5]
    lam = np.linalg.eigvalsh(J)
    ok = (lam[:, 0] > 0) & (lam[:, 2] <= lam[:, 0] + lam[:, 1])
    if not np.any(ok):
        raise ValueError("the file's uncertainty.inertia_sigma_kgm2 is too wide to draw a vehicle from: none of "
                         "%d draws was a rigid body" % n)
    return float(np.mean((j[0] / t[ok, 0] - 1.0) ** 2))


def flown(d, seed, vehicle="file"):
    """(the checked file ``d`` with the truth block the run flies, its record): module docstring. The record:
    ``vehicle`` (what was asked), ``kind`` ("truth block", "drawn" or "nominal"), ``seed`` (drawn only) and the
    ``truth`` block flown (null: the figures)."""
    check_vehicle(vehicle)
    out = copy.deepcopy(d)
    if vehicle == "nominal":
        out["truth"], kind = None, "nominal"
    elif vehicle == "file" and d.get("truth"):
        kind = "truth block"
    else:
        out["truth"], kind = draw_truth(d, seed), "drawn"      # plausible by construction (its redraws)
    rec = {"vehicle": vehicle, "kind": kind, "truth": out["truth"]}
    if kind == "drawn":
        rec["seed"] = int(seed)
    return out, rec
