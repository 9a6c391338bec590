"""The APKF's fading at a re-acquisition (``ground/adcs/apkf_fading.py``)."""

import numpy as np

from ground.adcs import apkf, quat
from ground.adcs.apkf_fading import BOUND, faded, fading_factor, nis


def _spd(rng, n, scale):
    A = rng.standard_normal((n, n))
    return A @ A.T * scale + np.eye(n) * scale * 0.1


def test_a_fix_within_the_bound_is_left_alone_and_one_beyond_it_is_brought_to_the_mean():
    rng = np.random.default_rng(2)
    B, A = _spd(rng, 3, 1e-6), _spd(rng, 3, 1e-8)
    z = np.linalg.cholesky(A + B) @ np.array([1.0, -0.5, 0.8])            # NIS 1.89
    assert fading_factor(z, A + B, B) == 1.0
    z = z * 6.0                                                             # NIS 68
    assert nis(z, A + B) > BOUND
    lam = fading_factor(z, A + B, B)
    assert 1.0 < lam <= nis(z, A + B)
    assert abs(nis(z, A + lam * B) - 3.0) < 1e-9


def test_the_stretchs_added_noise_is_kept_and_only_the_start_is_scaled():
    rng = np.random.default_rng(4)
    n = 8
    Pa, Qs = _spd(rng, n, 1e-6), _spd(rng, n, 1e-9)
    M = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    Pb = M @ Pa @ M.T + Qs
    R = np.eye(3) * 1e-10
    z = 20.0 * np.sqrt(np.diag(Pb[0:3, 0:3]))
    Pa2, Pb2, lam = faded(Pa, Pb, M, z, R)
    assert lam > 1.0 and np.allclose(Pa2, lam * Pa)
    assert np.allclose(Pb2 - M @ Pa2 @ M.T, Qs, atol=1e-12 * np.abs(Pb2).max())
    assert abs(nis(z, Pb2[0:3, 0:3] + R) - 3.0) < 1e-6


def _run(form, offset_deg, fading=True):
    """30 steps of the APKF on seeded read-outs with a 10-step blind stretch, whose ending fix is ``offset_deg``
    away from where the filter's prediction puts it."""
    rng = np.random.default_rng(7)
    q0 = np.array([0.1, -0.2, 0.05, 1.0]) / np.linalg.norm([0.1, -0.2, 0.05, 1.0])
    f = apkf.APKF(apkf.initial_state(q0, np.array([0.002, -0.001, 0.0005]), np.full(4, 300.0)), case=1,
                  set_ends=(1.0,), form=form)
    f.fading = f.fading and fading
    for k in range(30):
        w_plus = np.full(4, 300.0) + rng.normal(0, 1.0, 4)
        blind = 10 <= k < 20
        q = None if blind else quat.from_small(rng.normal(0, 1e-4, 3), f.x[0:4])
        if k == 20:
            q = quat.from_small(np.radians([offset_deg, 0.0, 0.0]) / 2, f.x[0:4])
        f.step(float(k), w_plus, q)
        if k == 20:
            return f


def test_the_consistent_form_fades_a_fix_its_prior_cannot_hold_and_the_thesis_form_never_does():
    f = _run("consistent", 0.0)
    assert f.fadings == [] and len(f.reacquisitions) == 1
    f = _run("consistent", 20.0)
    assert len(f.fadings) == 1 and f.fadings[0][0] == 21.0 and f.fadings[0][1] > 1.0
    g = _run("consistent", 20.0, fading=False)
    assert g.fadings == []
    sf, sg = np.sqrt(np.diag(f.P)), np.sqrt(np.diag(g.P))
    assert np.all(sf[apkf.PARAMS] >= sg[apkf.PARAMS]) and np.any(sf[apkf.PARAMS] > 1.01 * sg[apkf.PARAMS])
    assert _run("thesis", 20.0).fadings == []


def test_a_run_records_its_fadings():
    """A generic-6u vehicle whose second first-set fix fails its test is faded; thesis-3u's fixed vehicle never is."""
    from ground.adcs import runs
    from protocol import spacecraft as sf
    r = runs.run_apkf(0, None, case=1, spacecraft=sf.load("generic-6u"), vehicle="drawn", keep_series=False)
    assert r["fadings"]["count"] >= 1 and r["fadings"]["max_factor"] > 1.0
    r = runs.run_apkf(0, None, case=1, keep_series=False)
    assert r["fadings"] == {"count": 0, "max_factor": 1.0}
