"""The APKF's disturbance torque model (Yoon 2017, Eq. 4.76, 4.135; Sec. 8.3 asks for a better one than white noise).

``white`` (the thesis's): tau_d is a random walk, d tau_d / dt = w with E[w w^T] = q_d (per axis, Sec. 4.8 and
Eq. 4.152), so Phi_dd = I and Q_dd = q_d dt.

A shaping filter instead makes tau_d the output of a linear system driven by white noise, per axis, its states z
(tau_d first) appended to the filter's: dz/dt = Fd z + e_k w, E[w^2] = q_c (e_k: the last state). Over a step:

    z(t + dt) = Phi_dd z(t) + w_k,  Phi_dd = e^{Fd dt},  Q_dd = int_0^dt e^{Fd u} e_k q_c e_k^T e^{Fd^T u} du,

and for a stationary filter Q_dd = P_inf - Phi_dd P_inf Phi_dd^T (P_inf its stationary covariance). Three forms:

- ``markov``, first order (Gauss-Markov): d tau_d / dt = -tau_d / T + w, q_c = 2 sigma^2 / T, so Phi_dd =
  e^{-dt/T}, Q_dd = sigma^2 (1 - e^{-2 dt/T}); no state is added (tau_d is the thesis's state). The random walk
  is its limit T -> inf with 2 sigma^2 / T = q_d.
- ``harmonic``, second order (a damped oscillator): z = [tau_d, d tau_d / dt], Fd = [[0, 1], [-w0^2, -2 zeta w0]],
  q_c = 4 zeta w0^3 sigma^2, P_inf = diag(sigma^2, w0^2 sigma^2); three states are added (error state 41:44).
- ``gradient``, the torque as a function of the attitude (``AttitudeGradient``): d tau_d / dt = G w with the
  3 x 3 slope G = d tau_d / d theta as states (nine added, error state 41:50), Phi_dd from the rate at the step.

The torque moves within the step, z(s) = e^{Fd (s - dt)} z(t + dt), so its effect on the attitude and rate
(Phi_A,d of Eq. 4.114-4.127, ``apkf.phi``) is int_0^dt e^{A u} F_A,d e^{-Fd u} du on the step's end value; the
filter takes the first order in Fd dt, (G1 F_A,d - (dt G1 - G2) F_A,d Fd) (the next term is (|Fd| dt)^2 / 6 of
that block: < 1e-3 at T >= 14 s or periods >= 73 s), and holds the torque at mid-step, (e^{Fd dt/2} z(t))_tau,
in the RK4 of the mean. Q's cross terms with the rate keep the order of Eq. 4.135-4.136: Q_w,d = F_w,d Q_dd dt/2,
Q_ww = F_w,d Q_dd F_w,d^T dt^2/3 (the thesis's for the random walk, Q_dd = q_d dt). Sec. 4.7.4's fictitious
noise (Q x100 in the first maneuver set, x10 in the second) multiplies Q_dd as it does the rest of Q
(``fictitious``; without it the first-order model of Case 1 is no longer the random walk it equals at T = 50 h:
measured, docs/ADCS.md).

sigma, T, w0 and G's prior come from what is known of each case's disturbance (``shaping``); where nothing is
known of a density, it is the thesis's floor q_d0.
"""

from math import acos, exp, pi

import numpy as np
from scipy.linalg import expm

from emulator.spacecraft.scenario import CASE2_PERIODS, HOUR, TAU_MAG

DISTURBANCES = ("white", "markov", "harmonic", "gradient")
LAG_1_OVER_E = acos(exp(-1.0))     # a sine's autocorrelation cos(w L) is 1/e at w L = 1.1941
QD_FLOOR = (2.0e-7) ** 2 / HOUR    # the thesis's q_d0 "preventing the filter from closing" (Sec. 4.8), (N m)^2/s
N_BASE = 41                        # the thesis's error state (Eq. 4.78); a second-order filter's rates follow
# Eq. 4.152: q_d1 per rad/s. The OCR reads "2.0 10^-? Nm/sqrt(h)"; we take 2.0e-5, which makes q_d1 |w| during a
# 1.4 deg/s rotation comparable with Case 2's q_d (the thesis's stated intent); q_d2 = 0.1 q_d1.
QD1 = (2.0e-5) ** 2 / HOUR
QD2 = 0.1 * QD1


class ShapingFilter:
    """A per-axis linear shaping filter of the module docstring: ``F1`` (k x k, per axis: a 3 x k x k array or one
    for all), ``qc`` (3, the driving density on the last state) and ``P_inf`` (3 x k x k, the stationary
    covariance; None: none). The states are ordered [tau_x, tau_y, tau_z(, rate_x, rate_y, rate_z)]; ``ix`` are
    their places in the error state, ``ix + 1`` in x."""

    fictitious = True       # Q_dd takes Sec. 4.7.4's fictitious-noise scale, as the thesis's Q (False: not)

    def __init__(self, F1, qc, P_inf=None):
        self.F1 = np.broadcast_to(np.asarray(F1, dtype=float), (3,) + np.shape(F1)[-2:]).copy()
        self.k = self.F1.shape[-1]
        self.qc = np.broadcast_to(np.asarray(qc, dtype=float), (3,)).copy()
        self.P_inf = None if P_inf is None else np.broadcast_to(np.asarray(P_inf, float), self.F1.shape).copy()
        self.Fd = self._blocks(self.F1)
        self.ix = np.r_[6:9, N_BASE:N_BASE + 3 * (self.k - 1)]
        self.n = N_BASE + 3 * (self.k - 1)
        self._steps = {}

    def _blocks(self, per_axis):
        """The 3k x 3k matrix of per-axis k x k blocks, in the state order [tau (3), rate (3)]."""
        out = np.zeros((3 * self.k, 3 * self.k))
        for a in range(3):
            i = a + 3 * np.arange(self.k)
            out[np.ix_(i, i)] = per_axis[a]
        return out

    def step(self, dt, x=None):
        """(ix, Phi_dd, e^{Fd dt/2}, Q_dd, Fd) over dt (Q_dd by Van Loan's method, ``discrete_noise``), kept per
        dt; the state x does not enter."""
        if dt not in self._steps:
            self._steps[dt] = (self.ix, expm(self.Fd * dt), expm(self.Fd * (0.5 * dt)), self.discrete_noise(dt),
                               self.Fd)
        return self._steps[dt]

    def discrete_noise(self, dt):
        """Q_dd = int_0^dt e^{Fd u} G q_c G^T e^{Fd^T u} du (Van Loan, 1978: the upper-right block of
        e^{[[-Fd, G q_c G^T], [0, Fd^T]] dt} is Phi^-1 Q_dd)."""
        m = 3 * self.k
        Gq = np.zeros((m, m))
        Gq[m - 3:, m - 3:] = np.diag(self.qc)
        V = expm(np.block([[-self.Fd, Gq], [np.zeros((m, m)), self.Fd.T]]) * dt)
        Q = V[m:, m:].T @ V[:m, m:]
        return 0.5 * (Q + Q.T)

    def prior(self):
        """P0 of the filter's states (3k x 3k, tau_d's first): the stationary covariance, the prior of a stationary
        process seen at an unknown time."""
        return self._blocks(self.P_inf)


class AttitudeGradient:
    """tau_d a function of the attitude (Sec. 4.8.3: "the variation of the aerodynamic torque depends on the body
    rates"), to first order d tau_d / dt = G w with G = d tau_d / d theta (N m/rad, 3 x 3) the torque's
    sensitivity to a small rotation; G's nine entries are states, z = [tau_d, G row by row] (nine added, error
    state 41:50):

        d tau_d / dt = G w + w_tau,   d vec(G) / dt = w_G,   E[w_tau^2] = q_tau, E[w_G^2] = q_G (each entry),

    q_G = q_g + q_g_angle |w|: G changes as the attitude does (a random walk in the angle turned).

    This is Eq. 4.152's adaptive q_d made a model: its q_d1 |w_i| (own axis) and q_d2 sum_{j != i} |w_j| (the
    other axes) are the random-walk stand-ins for G's diagonal and off-diagonal terms. Over a step at the rate
    w (held; the filter's estimate), with W (3 x 9) the map vec(G) -> G w (W[i, 3 i + j] = w_j), Phi_dd =
    [[I, W dt], [0, I]] exactly, and

        Q_tau,tau = q_tau dt I + q_G W W^T dt^3/3,  Q_tau,G = q_G W dt^2/2,  Q_G,G = q_G dt I.

    The Jacobian of G w on the rate error, G d(w), is left out: |G| <= 1e-6 N m/rad against the rate's 1 sigma
    < 1e-3 rad/s, < 1e-9 N m/s. P0: tau_d ``sigma_tau`` (Sec. 4.8's), each entry of G ``sigma_g``."""

    k, n = 4, N_BASE + 9
    fictitious = True
    ix = np.r_[6:9, N_BASE:N_BASE + 9]

    def __init__(self, sigma_tau, sigma_g, q_tau, q_g, q_g_angle=0.0):
        self.sigma_tau, self.sigma_g, self.q_tau, self.q_g = (float(v) for v in (sigma_tau, sigma_g, q_tau, q_g))
        self.q_g_angle = float(q_g_angle)

    def step(self, dt, x):
        """(ix, Phi_dd, Phi over dt/2, Q_dd, Fd) at the rate x[4:7] (the class docstring)."""
        w = np.asarray(x[4:7], dtype=float)
        W = np.kron(np.eye(3), w[None, :])                                          # 3 x 9, W vec(G) = G w
        q_g = self.q_g + self.q_g_angle * np.sqrt(w @ w)
        Fd = np.zeros((12, 12))
        Fd[0:3, 3:12] = W
        Q = np.zeros((12, 12))
        Q[0:3, 0:3] = np.eye(3) * (self.q_tau * dt) + W @ W.T * (q_g * dt ** 3 / 3)
        Q[0:3, 3:12] = W * (q_g * dt * dt / 2)
        Q[3:12, 0:3] = Q[0:3, 3:12].T
        Q[3:12, 3:12] = np.eye(9) * (q_g * dt)
        return self.ix, np.eye(12) + Fd * dt, np.eye(12) + Fd * (0.5 * dt), Q, Fd

    def prior(self):
        """P0 of [tau_d, vec(G)] (12 x 12)."""
        return np.diag([self.sigma_tau ** 2] * 3 + [self.sigma_g ** 2] * 9)


def gauss_markov(T, sigma):
    """The first-order Gauss-Markov filter: T (s) and sigma (N m), per axis or one for all."""
    T = np.broadcast_to(np.asarray(T, dtype=float), (3,))
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (3,))
    if not (np.all(T > 0) and np.all(np.isfinite(T)) and np.all(sigma >= 0)):
        raise ValueError("Gauss-Markov T must be positive and finite, sigma non-negative: T %r, sigma %r"
                         % (T.tolist(), sigma.tolist()))
    return ShapingFilter((-1.0 / T)[:, None, None], 2 * sigma ** 2 / T, (sigma ** 2)[:, None, None])


def harmonic(period, sigma, zeta):
    """The damped oscillator: natural period (s), stationary sigma (N m) and damping ratio, per axis or one for
    all."""
    w0 = 2 * pi / np.broadcast_to(np.asarray(period, dtype=float), (3,))
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (3,))
    zeta = np.broadcast_to(np.asarray(zeta, dtype=float), (3,))
    if not (np.all(w0 > 0) and np.all(np.isfinite(w0)) and np.all(zeta > 0) and np.all(sigma >= 0)):
        raise ValueError("harmonic period and zeta must be positive, sigma non-negative")
    F1 = np.zeros((3, 2, 2))
    F1[:, 0, 1] = 1.0
    F1[:, 1, 0], F1[:, 1, 1] = -w0 ** 2, -2 * zeta * w0
    P_inf = np.zeros((3, 2, 2))
    P_inf[:, 0, 0], P_inf[:, 1, 1] = sigma ** 2, (w0 * sigma) ** 2
    return ShapingFilter(F1, 4 * zeta * w0 ** 3 * sigma ** 2, P_inf)


def shaping(case, form):
    """The shaping filter of ``form`` ("markov", "harmonic" or "gradient") for Sec. 4.8's Case 1-3 (the module
    docstring; none is fitted to a figure of the runs):
    - Case 2 (Eq. 4.150), sines of amplitude A = 1e-6 N m and periods P_i: their mean square A^2 / 2 and
      autocorrelation cos(2 pi L / P_i). markov: sigma = A / sqrt(2) and T_i the lag where the autocorrelation
      falls to 1/e, 1.1941 P_i / (2 pi) = (15.2, 13.8, 15.7) s (the first-order fit of an autocorrelation, Brown
      and Hwang, Introduction to Random Signals and Applied Kalman Filtering, Ch. 2). harmonic: w0 = 2 pi / P_i,
      sigma = A / sqrt(2), and zeta from the floor: the oscillator's amplitude (its in-phase and quadrature parts)
      walks with density q_c / (2 w0^2), set to the thesis's q_d0, zeta = q_d0 / (2 w0 sigma^2) ~ 1.4e-4.
    - Case 1 (none) and Case 3 (Eq. 4.151, tau_mag (1 - q_i), mean tau_mag: its autocorrelation stays near 1 and
      gives no finite T): the thesis's bound, sigma = A (its P0), and T = 2 sigma^2 / q_d0, the random walk's
      density at short lags (50 h); harmonic has no period to take there and is refused.
    - gradient, Case 3 only (an attitude-dependent torque; ValueError otherwise): bounded by A = 1e-6 N m, so its
      slope by A per rad: G's prior 1 sigma A/rad per entry (Eq. 4.151's is -(A/2)(q4 I + [e x]): |G| <= A/2),
      and G itself may change by that bound over each radian turned, a random walk in the angle of density
      A^2 (N m/rad)^2 per rad, q_G = q_d0 + A^2 |w|; tau_d's own noise the floor q_d0 (Eq. 4.152's rate terms are
      G's now)."""
    if form not in DISTURBANCES[1:]:
        raise ValueError("a shaping filter is one of %s, got %r" % (", ".join(DISTURBANCES[1:]), form))
    if case not in (1, 2, 3):
        raise ValueError("case must be 1, 2 or 3, got %r" % (case,))
    sigma2 = TAU_MAG / np.sqrt(2.0)
    periods = np.array(CASE2_PERIODS)
    if form == "harmonic":
        if case != 2:
            raise ValueError("--disturbance harmonic needs a period: Case 2's sines have one, Case %d's "
                             "disturbance none" % case)
        return harmonic(periods, sigma2, QD_FLOOR * periods / (4 * pi * sigma2 ** 2))
    if form == "gradient":
        if case != 3:
            raise ValueError("--disturbance gradient is an attitude-dependent torque's model: Case 3's, not "
                             "Case %d's" % case)
        return AttitudeGradient(TAU_MAG, TAU_MAG, QD_FLOOR, QD_FLOOR, TAU_MAG ** 2)
    if case == 2:
        return gauss_markov(LAG_1_OVER_E * periods / (2 * pi), sigma2)
    return gauss_markov(2 * TAU_MAG ** 2 / QD_FLOOR, TAU_MAG)
