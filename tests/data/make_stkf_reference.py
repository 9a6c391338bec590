"""Writes tests/data/stkf_step_reference.npz, for tests/test_adcs_stkf_equivalence.py: the runs ``RUNS`` of that test
(``stkf_sim.simulate(..., truth="two-body")``), keeping for each the history (error, 1 sigma, pointing error and
its 1 sigma at every step) and the smoother's final nodes (times, X, joint P), under the keys ``<run>_<name>``.

The file in the repository was written by the code of commit b2c87c3, before the STKF's speed work, so that the
test proves the faster code computes the same; this script writes it from the code as it is (the same figures
within the test's tolerances: run it into another path and compare). Run from the repository root:
``python -m tests.data.make_stkf_reference [PATH]``.
"""

import os
import sys

import numpy as np

from ground.adcs import afls, stkf_sim
from tests.test_adcs_stkf_equivalence import RUNS


def main(path=os.path.join(os.path.dirname(__file__), "stkf_step_reference.npz")):
    out = {}
    for name, kw in sorted(RUNS.items()):
        got = []

        class Rec(afls.Afls):
            def __init__(self, *a, **k):
                super().__init__(*a, **k)
                got.append(self)

        real = stkf_sim.Afls
        stkf_sim.Afls = Rec
        try:
            _, h = stkf_sim.simulate(truth="two-body", **kw)
        finally:
            stkf_sim.Afls = real
        flt = got[0]
        for k in ("err", "sig", "perr", "psig"):
            out["%s_%s" % (name, k)] = np.asarray(h[k])
        out[name + "_X"] = np.asarray(flt.X)
        out[name + "_P"] = np.asarray(flt.P)
        out[name + "_t"] = np.asarray(flt.t)
    np.savez(path, **out)
    print("wrote %s" % path)


if __name__ == "__main__":
    main(*sys.argv[1:])
