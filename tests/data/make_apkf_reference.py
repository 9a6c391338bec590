"""Writes tests/data/apkf_reference.npz: a recorded APKF run (inputs and results) from the APKF as it was
before the APKF's structured steps (commit b2c87c3, dense-ish textbook steps), for tests/test_adcs_apkf_fast.py.

Inputs: the 930 s Case 3 scenario (seed 0) as the filter sees it (t, tachometers, star-tracker outputs, the
maneuver set ends, x0). Results: x and P after ``CHECKS`` steps of ``APKF.step``, and F, Phi, Q at one
state mid-run. Run from the repository root: ``python -m tests.data.make_apkf_reference``.
"""

import os

import numpy as np

from emulator.spacecraft import scenario
from ground.adcs import apkf, quat, runs

CASE, SEED = 3, 0
CHECKS = (150, 400, None)          # steps after the start (None: the end of the run)
F_STEP = 250                       # F, Phi, Q at the state before this step


def main(path=os.path.join(os.path.dirname(__file__), "apkf_reference.npz")):
    o = scenario.simulate(case=CASE, seed=SEED)
    k0 = runs._start(o)
    q0 = o["st_q"][k0]
    w0 = quat.rotvec(quat.quat_mul(q0, quat.conj(o["st_q"][k0 - 1])))
    x0 = apkf.initial_state(q0, w0, o["tach"][k0])
    f = apkf.APKF(x0, case=CASE, set_ends=o["set_ends"], form="thesis")
    n = len(o["t"]) - k0 - 1
    checks = [c if c is not None else n for c in CHECKS]
    xs, Ps = [], []
    out = {}
    for i in range(1, n + 1):
        k = k0 + i
        if i == F_STEP:
            x, P = apkf.shift_tach(f.x, f.P, o["tach"][k], f.model.R_rw)
            m = apkf.terms(x, f.model, o["t"][k - 1] + 0.5 * f.model.dt)
            F = apkf.jacobian(x, f.model, o["t"][k - 1], m)
            out.update(F_x=x, F_t=o["t"][k - 1], F=F, Phi=apkf.phi(F, f.model.dt),
                       Q=apkf.process_noise(F, apkf.noise_density(x, CASE, 10.0), f.model.dt))
        f.step(o["t"][k - 1], o["tach"][k], o["st_q"][k] if o["st_valid"][k] else None)
        if i in checks:
            xs.append(f.x.copy())
            Ps.append(f.P.copy())
    sl = slice(k0, None)
    np.savez_compressed(path, case=CASE, t=o["t"][sl], tach=o["tach"][sl], st_q=o["st_q"][sl],
                        st_valid=o["st_valid"][sl], set_ends=np.asarray(o["set_ends"], float), x0=x0,
                        checks=np.array(checks), x=np.array(xs), P=np.array(Ps), F_step=F_STEP, **out)
    print("wrote", path, os.path.getsize(path), "bytes")


if __name__ == "__main__":
    main()
