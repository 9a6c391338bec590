"""Thorlabs PDQ80A quadrant detector lit by a Gaussian spot (Sec. 7.2.3, Eq. 7.3-7.4).

Quadrants in the detector frame: Q1 (+x, +y), Q2 (-x, +y), Q3 (-x, -y), Q4 (+x, -y), separated by a gap of
width g along both axes, inside a disc of radius R. Outputs (Eq. 7.3): Vx = (Q2 + Q3) - (Q1 + Q4),
Vy = (Q1 + Q2) - (Q3 + Q4), Vs = Q1 + Q2 + Q3 + Q4, in volts (responsivity x transimpedance x power).

Two models:
- ``reference``: numerical integration over the disc with the gap, for an elliptical spot at any angle
  (composite Gauss-Legendre over x = R sin u, which keeps the disc edge smooth; the y integral in closed form
  by erf for the conditional Gaussian). Used for truth; a spot wholly off the disc reads zero.
- ``fast``: closed form with math.erfc for a spot whose ellipse axes lie along the detector axes on a gapped
  infinite detector: the quadrant powers factor into x and y edge fractions. For a round spot at the centre
  the ratio is Vx/Vs = -erf(sqrt 2 x / w). Exact (to ~1e-12) while the disc edge is > 3.3 w away; beyond that
  radius ``fast`` falls back to the reference. A tilted ellipse (not separable) gets a 2-D sextic correction
  fitted to the reference at init (ratios within ~1e-4 over the fast region, tested).
"""

import math

import numpy as np

SQRT2 = math.sqrt(2.0)
_ERFC = np.frompyfunc(math.erfc, 1, 1)

# Composite Gauss-Legendre nodes on [0, 1] for the reference integral.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
_GL_X = 0.5 * (_GL_X + 1.0)
_GL_W = 0.5 * _GL_W
_PANEL_SIGMAS = 1.0     # panel width in sigma_x (16 nodes each: ~1e-15 against finer panels)


def erfc_array(x):
    return _ERFC(np.asarray(x, dtype=float)).astype(float)


def ratio_closed_form(x, w):
    """Vx/Vs for a round spot of 1/e^2 radius w at x on a centred gap-free infinite detector: -erf(sqrt2 x/w)."""
    return -math.erf(SQRT2 * x / w)


class Quadcell:
    """One quadcell with its mounting (rotation about the optical axis, offset) and its spot.

    ``spot`` = (major, minor) 1/e^2 radii in the beam frame, ``ellipse_deg`` the major axis angle in the
    beam frame, ``power_w`` the optical power reaching the detector.
    """

    def __init__(self, qcfg, spot, ellipse_deg, power_w):
        self.radius = qcfg["radius_m"]
        self.half_gap = 0.5 * qcfg["gap_m"]
        phi = (qcfg["rotation_deg"] + qcfg["misalignment_deg"]) * math.pi / 180.0
        self.cos, self.sin = math.cos(phi), math.sin(phi)
        self.off_x, self.off_y = qcfg["offset_m"]
        self.v_per_w = qcfg["responsivity_a_per_w"] * qcfg["transimpedance_v_per_a"]
        self.volts = power_w * self.v_per_w            # Vs with the whole spot on the detector
        self.pos_noise = qcfg["position_noise_v_per_m"]
        amp = power_w * qcfg["responsivity_a_per_w"]
        # shot and thermal noise over the detector bandwidth, in output volts (1 sigma)
        shot = math.sqrt(2 * 1.602176634e-19 * amp * qcfg["bandwidth_hz"])
        thermal = math.sqrt(4 * 1.380649e-23 * 300.0 * qcfg["bandwidth_hz"] / qcfg["transimpedance_v_per_a"])
        self.sigma0_v = math.sqrt(qcfg["noise_v"] ** 2 + ((shot ** 2 + thermal ** 2) ** 0.5
                                                          * qcfg["transimpedance_v_per_a"]) ** 2)
        a, b = spot
        psi = ellipse_deg * math.pi / 180.0 - phi      # ellipse angle in the detector frame
        c, s = math.cos(psi), math.sin(psi)
        self.sxx = (a * a * c * c + b * b * s * s) / 4.0      # Gaussian covariance (sigma = w/2)
        self.syy = (a * a * s * s + b * b * c * c) / 4.0
        self.sxy = (a * a - b * b) * c * s / 4.0
        self.wx = 2.0 * math.sqrt(self.sxx)
        self.wy = 2.0 * math.sqrt(self.syy)
        self.kx = SQRT2 / self.wx
        self.ky = SQRT2 / self.wy
        self.fast_r2 = max(0.0, self.radius - 3.3 * max(a, b)) ** 2
        self.dark_r = self.radius + 5.0 * max(a, b)
        self.n_reference = 0
        self.corr = None
        if abs(self.sxy) > 1e-9 * (self.sxx + self.syy) and self.fast_r2 > 0.0:
            self._fit_correction()
        # constants of the separable fast path for callers that inline it (None: call outputs_fast)
        self.inline = (self.fast_r2, self.half_gap, self.kx, self.ky, 0.25 * self.volts) if self.corr is None \
            else None

    # --- geometry --------------------------------------------------------------------------------
    def to_detector(self, x, y):
        """Beam-frame spot position (m) to the detector frame: rotate by -phi, subtract the offset."""
        return (self.cos * x + self.sin * y - self.off_x, -self.sin * x + self.cos * y - self.off_y)

    # --- reference model -------------------------------------------------------------------------
    def quadrants_reference(self, x, y):
        """Quadrant powers as fractions of the spot power (Q1..Q4), by numerical integration."""
        self.n_reference += 1
        h, rad = self.half_gap, self.radius
        sx = math.sqrt(self.sxx)
        s_cond = math.sqrt(max(self.syy - self.sxy * self.sxy / self.sxx, 1e-30))
        # x = R sin(u) over [h, sqrt(R^2 - h^2)] keeps the disc edge y = R cos(u) smooth; panels of ~sigma_x
        u0, u1 = math.asin(h / rad), math.acos(h / rad)
        n_pan = int(min(400, max(8, math.ceil((u1 - u0) * rad / (_PANEL_SIGMAS * sx)))))
        edges = np.linspace(u0, u1, n_pan + 1)
        u = (edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * _GL_X[None, :]).ravel()
        t = rad * np.sin(u)
        wts = ((edges[1:] - edges[:-1])[:, None] * _GL_W[None, :]).ravel() * rad * np.cos(u)
        out = []
        for side in (1.0, -1.0):
            xs = side * t
            px = np.exp(-0.5 * ((xs - x) / sx) ** 2) / (sx * math.sqrt(2 * math.pi))
            m = y + self.sxy / self.sxx * (xs - x)
            ymax = np.maximum(rad * np.cos(u), h)
            k = 1.0 / (SQRT2 * s_cond)
            e_top = erfc_array((ymax - m) * k)
            e_hp = erfc_array((h - m) * k)
            e_hn = erfc_array((-h - m) * k)
            e_bot = erfc_array((-ymax - m) * k)
            up = 0.5 * (e_hp - e_top)       # P(h < y < ymax | x)
            down = 0.5 * (e_bot - e_hn)     # P(-ymax < y < -h | x)
            out.append((float(np.dot(wts, px * up)), float(np.dot(wts, px * down))))
        (q1, q4), (q2, q3) = out
        return q1, q2, q3, q4

    def outputs_reference(self, x, y):
        """(Vx, Vy, Vs) in volts for a detector-frame spot position, reference model (Eq. 7.3)."""
        if math.hypot(x, y) > self.dark_r:
            return 0.0, 0.0, 0.0           # the whole spot is off the detector (< 1e-20 of its power on it)
        q1, q2, q3, q4 = self.quadrants_reference(x, y)
        v = self.volts
        return v * ((q2 + q3) - (q1 + q4)), v * ((q1 + q2) - (q3 + q4)), v * (q1 + q2 + q3 + q4)

    # --- fast model ------------------------------------------------------------------------------
    def outputs_fast(self, x, y):
        """(Vx, Vy, Vs) in volts, closed form by erfc (see the module doc), plain floats."""
        if x * x + y * y > self.fast_r2:
            return self.outputs_reference(x, y)
        h = self.half_gap
        fxp = math.erfc(self.kx * (h - x))    # 2 P(x > h)
        fxn = math.erfc(self.kx * (h + x))    # 2 P(x < -h)
        fyp = math.erfc(self.ky * (h - y))
        fyn = math.erfc(self.ky * (h + y))
        v = 0.25 * self.volts
        sx, sy = fxp + fxn, fyp + fyn
        vx, vy, vs = v * (fxn - fxp) * sy, v * (fyp - fyn) * sx, v * sx * sy
        if self.corr is not None:
            dx, dy, ds = self._correction(x, y)
            vx += dx * self.volts
            vy += dy * self.volts
            vs += ds * self.volts
        return vx, vy, vs

    def _terms(self, u, v):
        return [u ** i * v ** j for i in range(7) for j in range(7 - i)]

    def _correction(self, x, y):
        u, v = x * self.kx, y * self.ky
        t = self._terms(u, v)
        cx, cy, cs = self.corr
        return (sum(a * b for a, b in zip(cx, t)), sum(a * b for a, b in zip(cy, t)),
                sum(a * b for a, b in zip(cs, t)))

    def _fit_correction(self):
        """Fit the reference-minus-separable difference (in units of the spot's volts) by a 2-D sextic."""
        lim = math.sqrt(self.fast_r2)
        g = np.linspace(-1.0, 1.0, 19)
        pts = [(gx * lim, gy * lim) for gx in g for gy in g if gx * gx + gy * gy <= 1.0]
        rows, dx, dy, ds = [], [], [], []
        for x, y in pts:
            ref = self.outputs_reference(x, y)
            fast = self.outputs_fast(x, y)
            rows.append(self._terms(x * self.kx, y * self.ky))
            dx.append((ref[0] - fast[0]) / self.volts)
            dy.append((ref[1] - fast[1]) / self.volts)
            ds.append((ref[2] - fast[2]) / self.volts)
        a = np.array(rows)
        self.corr = tuple(np.linalg.lstsq(a, np.array(d), rcond=None)[0].tolist() for d in (dx, dy, ds))
        self.n_reference = 0

    def noise_sigma_v(self, x, y):
        """1 sigma output noise (V): shot + thermal + electronics, plus a term growing with the offset."""
        return self.sigma0_v + self.pos_noise * math.sqrt(x * x + y * y)
