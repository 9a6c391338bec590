"""The APKF's fading at a re-acquisition (the consistent form): a star-tracker fix after a blind stretch whose
innovation is beyond a chi-square bound for the filter's own prior says that prior is too narrow, and the stretch's
start P is scaled up until the innovation is what the filter expects of it.

The fading-memory filter scales P by a factor above 1 to keep old information from holding the estimate (Simon,
Optimal State Estimation, 2006, Sec. 7.4); here the factor is set from the innovation itself, at the fix only, and
only when the test fails. With z the attitude innovation at the fix (Eq. 4.139), the prior at the fix of a stretch
from (xa, Pa) is Pb = M Pa M^T + Q_s (``apkf.update_window``: M = d xb / d xa, Q_s what the stretch added), and

    NIS = z^T (Pb_qq + R)^-1 z.

Beyond ``BOUND`` (chi-square, 3 dof, 0.999) the start's P becomes lambda Pa, lambda > 1 the root of
z^T ((Q_s + lambda M Pa M^T)_qq + R)^-1 z = 3 (the NIS's mean; found by bisection on log lambda), so the prior at the
fix is Pb + (lambda - 1) M Pa M^T with Q_s kept. Why (measured, docs/ADCS.md "Drawn vehicles"): vehicles drawn 2σ
out in inertia lie where the stretch's linear prediction no longer holds, and the fix found them 10-20° off against
a 1σ of tenths of a degree; fused at face value, their parameters' NEES went to thousands.
"""

import numpy as np

BOUND = 16.266             # scipy.stats.chi2.ppf(0.999, 3)
_PASSES = 60               # bisection on log lambda: lambda to ~1e-12 of itself


def nis(z, S):
    """z^T S^-1 z."""
    return float(z @ np.linalg.solve(S, z))


def fading_factor(z, S, MPM_qq, bound=BOUND, n0=None):
    """lambda >= 1 for a fix with attitude innovation ``z``, prior innovation covariance ``S`` = Pb_qq + R and
    ``MPM_qq`` = (M Pa M^T)_qq: 1 while the NIS (``n0``, if already known) is within ``bound``, else the root of
    NIS(lambda) = 3."""
    n0 = nis(z, S) if n0 is None else n0
    if not n0 > bound:
        return 1.0
    A = S - MPM_qq
    lo, hi = 0.0, np.log(n0)              # lambda at most the NIS: where the stretch's added noise and R alone
    #                                       hold the innovation beyond 3, scaling the start cannot bring it there
    for _ in range(_PASSES):
        mid = 0.5 * (lo + hi)
        if nis(z, A + np.exp(mid) * MPM_qq) > 3.0:
            lo = mid
        else:
            hi = mid
    return float(np.exp(hi))


def faded(Pa, Pb, M, z, R, bound=BOUND):
    """(Pa, Pb, lambda): the stretch's start and the fix's prior covariances after ``fading_factor``. A fix within
    the bound costs one 3 x 3 solve; M Pa M^T is formed only for one beyond it."""
    S = Pb[0:3, 0:3] + R
    n0 = nis(z, S)
    if not n0 > bound:
        return Pa, Pb, 1.0
    MPM = M @ Pa @ M.T
    lam = fading_factor(z, S, MPM[0:3, 0:3], bound, n0)
    return Pa * lam, Pb + (lam - 1.0) * MPM, lam
