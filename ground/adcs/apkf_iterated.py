"""The APKF's first maneuver set filtered again (the consistent form): an iterated extended Kalman smoother's
linearisation for the near-constant parameters.

An EKF linearises each step about its own estimate. In the first set the parameters are still far from the truth
(P near P0: a file's 30-42 % on the moments, 10 deg on the tilts), the fixes after each blind rotation fuse
information through Jacobians taken at those estimates, and the combinations they pin down come out overconfident.
The thesis holds the filter together there with fictitious noise (Sec. 4.7.4: Q and R x100, then Q x10). The
iterated smoother instead re-linearises the whole interval about its own better estimate and filters it again
(Bell, "The iterated Kalman smoother as a Gauss-Newton method", SIAM J. Optim., 1994). For states that are
constant but for a small walk, the smoothed estimate over the interval is the filtered one at its end, so a pass
here is: from the first set's start (x0, P0), every step of the set again with J5, m, d1, d2 and Jrw linearised
at the previous pass's end-of-set estimate (``Model.p_lin``; the attitude, rate and wheel speeds about the pass's
own, each blind stretch still iterated by ``apkf.update_window``), and without the fictitious noise, which was
there for the linearisation this replaces. The second set then keeps no fictitious noise either.

Measured (Case 1, 100 vehicles drawn within thesis-3u's uncertainty block; docs/ADCS.md "Drawn vehicles"): at
the first set's end the parameters' NEES (20 dof) had a mean of 78 (median 36) filtered once and 18.5 (median 14)
after ``PASSES`` passes; after the set the attitude + rate NEES mean went from 7.15 to 5.71 (6 dof).
"""

import copy

import numpy as np

PASSES = 2          # passes over the first set


def refilter(f, passes, check_covariance):
    """Filter the first set again, ``passes`` times (module docstring), for the APKF ``f`` at the set's end;
    ``f._first`` = [(x0, P0) as its first step found them, then each step's (t, w_plus, q_meas or None,
    m_ctrl) as ``f.step`` took it]. f's (x, P) become the last pass's that completes; a pass whose covariance
    fails ``check_covariance`` or that cannot be carried out (a singular matrix) ends the iteration with the
    previous one kept.
    ``f.iterations`` gains (t, passes completed). ``check_covariance``: ``apkf.check_covariance``."""
    (x0, P0), steps = f._first[0], f._first[1:]
    f._first = None
    m = f.model
    m_now, done = m.m_ctrl, 0
    x, P, stretch = f.x, f.P, f._stretch
    try:
        for _ in range(passes):
            g = copy.copy(f)
            g.x, g.P, g.set_ends, g._stretch = x0.copy(), P0.copy(), [], None
            g.fadings, g.reacquisitions, g.resets, g.iterations = [], [], [], []
            m.p_lin = x[10:30].copy()
            for t, w_plus, q_meas, m_ctrl in steps:
                m.m_ctrl = m_ctrl
                g._step(t, w_plus, q_meas)
                check_covariance(g.P, t + m.dt)
            if not np.all(np.isfinite(g.x)):
                raise FloatingPointError("the pass's estimate is not finite")
            x, P, stretch, done = g.x, g.P, g._stretch, done + 1
    except (FloatingPointError, np.linalg.LinAlgError, ZeroDivisionError):
        pass
    finally:
        m.p_lin, m.m_ctrl = None, m_now
    f.x, f.P, f._stretch = x, P, stretch       # a blind stretch open at the set's end goes on from the pass's
    f.iterations.append((steps[-1][0] + m.dt, done))
