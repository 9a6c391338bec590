"""Laser, beam resizer and beam splitter of the fine pointing bench (Sec. 7.2.1, Fig. 7-3, Fig. 7-5).

Geometry is paraxial and unfolded: a ray is (x, alpha) per axis, x in metres, alpha in radians. The laser
hits the P-FSM at its centre; the P-FSM's optical tilt (2x mechanical, Eq. 7.9) enters the L1/L2 resizer,
whose ABCD matrix (Eq. 7.1) gives the angle and position at the MEMS FSM; the FSM adds its own optical tilt;
the beam then travels to each quadcell. Gaussian beam radii follow the complex q parameter through the same
ABCD matrices.
"""

import math

import numpy as np


def prop(d):
    """Free-space ABCD matrix over distance d."""
    return np.array([[1.0, d], [0.0, 1.0]])


def lens(f):
    """Thin-lens ABCD matrix of focal length f."""
    return np.array([[1.0, 0.0], [-1.0 / f, 1.0]])


def exit_pupil_z2(f1, f2, z1):
    """Exit pupil distance after L2 (Eq. 7.2): z2 = (f2/f1)(f1 + f2 - (f2/f1) z1)."""
    return f2 / f1 * (f1 + f2 - f2 / f1 * z1)


def resizer_matrix(f1, f2, z1, z2):
    """ABCD matrix from the P-FSM (z1 before L1) to a plane z2 after L2, lenses f1 + f2 apart (Eq. 7.1).

    Closed form: [[-f2/f1, f1 + f2 - (f2/f1) z1 - (f1/f2) z2], [0, -f1/f2]]; B = 0 at the exit pupil.
    """
    return prop(z2) @ lens(f2) @ prop(f1 + f2) @ lens(f1) @ prop(z1)


def beam_radius(q, wavelength):
    """1/e^2 radius of a Gaussian beam with complex parameter q."""
    return math.sqrt(-wavelength / (math.pi * (1.0 / q).imag))


def propagate_q(q, m):
    a, b, c, d = m[0, 0], m[0, 1], m[1, 0], m[1, 1]
    return (a * q + b) / (c * q + d)


class Optics:
    """The bench's static optics from a validated config.

    Attributes: ``m_fsm`` (ABCD P-FSM -> MEMS FSM), ``ang_mag`` (signed angular magnification, -f1/f2),
    ``walk`` (metres of beam walk on the FSM per radian of P-FSM optical tilt, 0 at the exit pupil),
    ``spot`` per quadcell name: (major, minor) 1/e^2 radii at the detector, ``power`` per quadcell (W).
    """

    def __init__(self, cfg):
        r = cfg["resizer"]
        f1, f2, z1 = r["f1_m"], r["f2_m"], r["z1_m"]
        self.z2 = exit_pupil_z2(f1, f2, z1) + r["fsm_offset_m"]
        self.m_fsm = resizer_matrix(f1, f2, z1, self.z2)
        self.ang_mag = float(self.m_fsm[1, 1])
        self.walk = float(self.m_fsm[0, 1])
        las = cfg["laser"]
        lam = las["wavelength_m"]
        self.spot = {}
        self.power = {}
        frac = cfg["splitter"]["q1_fraction"]
        for name, share in (("q1", frac), ("q2", 1.0 - frac)):
            m = prop(cfg[name]["distance_m"]) @ self.m_fsm
            radii = []
            for w0 in (las["waist_radius_m"], las["waist_radius_m"] * las["ellipticity"]):
                q0 = 1j * math.pi * w0 * w0 / lam   # waist at the P-FSM
                radii.append(beam_radius(propagate_q(q0, m), lam))
            self.spot[name] = tuple(radii)
            self.power[name] = las["power_w"] * share
        # Sky-referred error (Eq. 7.5): the angle after the FSM over the flight magnification, sign so that a
        # pure P-FSM tilt theta_P = 13.33 theta_e (Eq. 7.7) reads back as theta_e.
        self.sky_per_rad = 1.0 / (math.copysign(1.0, self.ang_mag) * cfg["flight_magnification"])
        # theta_P per theta_e (Eq. 7.5-7.7): theta_e Mal_real = 2 theta_P |Mal_demo|.
        self.pfsm_per_sky = cfg["flight_magnification"] / (2.0 * abs(self.ang_mag))
