"""Physical plausibility of a checked spacecraft file (pure Python, only ``math``: runs under MicroPython too).

``check(d)`` checks each key against its range; a figure in the wrong unit often stays within it (an inertia in
g m^2 is 1000 times too large, yet far below the schema's 1e4 kg m^2) and a flight then diverges without a word.
``check_plausible(out, principal_moments)`` compares the figures with each other and refuses, with a ValueError
naming the key path, the value, the plausible range with units and the likely slip, a file no vehicle could have.

Size. The file gives no dimensions; its areas do: L = sqrt(max(surface.drag_area_m2, surface.srp_area_m2)), the
side of the larger area's square, is the vehicle's characteristic length (0.17 m for the 3U's 10 x 30 cm face).
For a box a >= b >= c whose largest face a b is that area, L^3 = (a b)^1.5 >= a b c, the box's volume.

The checks, in this order (the first failing one is reported):

1. Mass against size: mass_kg / L^3 from 0.01 to 10000 kg/m^3. A CubeSat carries at most about 2 kg per 1U
   (10 cm cube), 2000 kg/m^3 of its volume, and L^3 is at least the volume; 10000 leaves a factor 5 for areas
   stated as a smaller face. The floor admits area-dominated vehicles (a 4 kg 3U whose wings make 0.68 m^2,
   7.1 kg/m^3; a solar sail, LightSail 2's 5 kg and 32 m^2, 0.03). A mass in g (x 1000) is refused here whenever
   the true figure is above 10 kg/m^3 (the presets: 250 to 770), below it by check 2; areas in cm^2 (x 1e4, so
   L^3 x 1e6) always.
2. Inertia against mass and size: each principal moment J's radius of gyration k = sqrt(J / mass_kg) from
   max(0.05 L, 5 mm) to min(3 L, 10 m). A homogeneous box has J = m (b^2 + c^2) / 12: about its largest face's
   normal k >= L / sqrt(6) = 0.41 L; about its long axis k = 0.22 L for a 3U, 0.17 L for a 1 x 1 x 6 box,
   0.12 L for a 6 : 1 plate. Deployed panels that the areas include make L large and the smallest k small: a
   4 kg 3U with two 1 x 0.34 m wings has k from 0.12 to 0.31 L, with two 3 m wings (2 m^2) 0.07 L; the floor
   0.05 L admits them. Panels the areas leave out make k large: a 3U with four 10 x 34 cm panels deployed
   radially at one end reaches 0.71 L of its body's L; the ceiling 3 L leaves a factor 4 beyond and admits
   homogeneous shapes up to about 100 : 1. A slip by 1000 multiplies every k by 31.6: the largest k of a real
   vehicle, above 0.15 L even when light panels make most of the area (0.18 L for a 12 kg 6U with 1 m^2 of
   wings; 0.29 to 0.64 L for the presets), then lands above 3 L: an inertia in g m^2 or kg mm^2 is refused; a
   mass in g (k / 31.6) lands below 0.05 L. The true inertia (the truth block) likewise.
3. Rotor against vehicle: each rotor inertia at most 5 % of the vehicle's smallest principal moment. A reaction
   wheel's rotor is a small part of it (the presets: 2.5e-4 to 8.6e-4); 5 %, 50 times the presets' largest,
   would be a dual-spin vehicle's rotor rather than a wheel's, and the smallest moment is the conservative one;
   a rotor inertia in g m^2 (x 1000) is refused whenever the true share is above 5e-5. The true rotor inertias
   likewise.
4. Lengths against size: |surface.cp_offset_m| and wheels.arm_m at most 2 L. Both are distances between points
   of the vehicle (the centre of pressure lies within its outline, the wheels within its body): a 3U's corner is
   1.0 L from its centre, a 6U's 0.77 L, a 1 x 1 x 6 box's 1.26 L (the presets' offsets and arms: 0.11 to 0.28 L).
   A length in mm or cm (x 1000, x 100) is refused whenever the true one is above 0.002 L or 0.02 L (the
   schema's 10 m refuses most mm already).

A vehicle outside these envelopes (a gravity-gradient boom with a tip mass, a dual-spin rotor) is outside what
this workbench flies.
"""

import math

DENSITY_MIN = 0.01        # kg/m^3, mass_kg / L^3
DENSITY_MAX = 1e4
K_MIN_L = 0.05            # radius of gyration, in L
K_MAX_L = 3.0
K_MIN_M = 0.005           # radius of gyration, absolute (m)
K_MAX_M = 10.0
ROTOR_SHARE_MAX = 0.05    # rotor inertia / smallest principal moment
LENGTH_MAX_L = 2.0        # |cp_offset_m| and arm_m, in L

SIZE = "L = sqrt(max(surface.drag_area_m2, surface.srp_area_m2))"


def _num(x, digits=3):
    """x to ``digits`` significant digits as people write it: 12000 (not 1.2e+04), 0.0118, 3e-06."""
    s = ("%." + str(digits) + "g") % x
    v = float(s)
    if v == int(v) and abs(v) < 1e15:
        return str(int(v))
    return s


def _vec(v):
    """A list of numbers as given (6 significant digits)."""
    return "[" + ", ".join(_num(x, 6) for x in v) + "]"


def size_m(out):
    """The characteristic length L (m) of a checked file: the side of the larger of its two areas."""
    s = out["surface"]
    return math.sqrt(max(s["drag_area_m2"], s["srp_area_m2"]))


def k_range_m(size):
    """(lowest, highest) plausible radius of gyration (m) for a vehicle of characteristic length ``size`` (m)."""
    return max(K_MIN_L * size, K_MIN_M), min(K_MAX_L * size, K_MAX_M)


def check_plausible(out, principal_moments):
    """ValueError (key path, value, plausible range with units, the likely slip) unless the checked file ``out``
    is physically plausible (the module docstring's checks); ``principal_moments`` is
    ``protocol.spacecraft.principal_moments`` (passed in: this module imports nothing of the package)."""
    size = size_m(out)
    s = out["surface"]
    mass = out["mass_kg"]
    vehicle = "a vehicle of about %s m (%s)" % (_num(size), SIZE)
    rho = mass / size ** 3
    if rho > DENSITY_MAX:
        raise ValueError("mass_kg = %s: mass_kg / L^3 = %s kg/m^3 is implausible for %s: must be from %s to %s "
                         "kg/m^3 (mass in g instead of kg?)" % (_num(mass, 6), _num(rho), vehicle,
                                                                 _num(DENSITY_MIN), _num(DENSITY_MAX)))
    if rho < DENSITY_MIN:
        key = "surface.drag_area_m2" if s["drag_area_m2"] >= s["srp_area_m2"] else "surface.srp_area_m2"
        raise ValueError("%s = %s: mass_kg / L^3 = %s kg/m^3 is implausible for a %s kg vehicle of about %s m (%s): "
                         "must be from %s to %s kg/m^3 (areas in cm^2 instead of m^2?)"
                         % (key, _num(max(s["drag_area_m2"], s["srp_area_m2"]), 6), _num(rho), _num(mass, 6),
                            _num(size), SIZE, _num(DENSITY_MIN), _num(DENSITY_MAX)))
    w = out["wheels"]
    lam = principal_moments(out["inertia_kgm2"])
    _check_moments("inertia_kgm2 = %s" % _vec(out["inertia_kgm2"]), lam, mass, size)
    _check_rotors("wheels.rotor_inertia_kgm2 = %s" % _vec(w["rotor_inertia_kgm2"]), w["rotor_inertia_kgm2"], lam)
    t = out.get("truth")
    if t:
        j = [a + b for a, b in zip(out["inertia_kgm2"], t["inertia_error_kgm2"])]
        lam = principal_moments(j)
        _check_moments("truth.inertia_error_kgm2 = %s: the true inertia inertia_kgm2 + truth.inertia_error_kgm2 = %s"
                       % (_vec(t["inertia_error_kgm2"]), _vec(j)), lam, mass, size)
        jr = [a + b for a, b in zip(w["rotor_inertia_kgm2"], t["rotor_inertia_error_kgm2"])]
        _check_rotors("truth.rotor_inertia_error_kgm2 = %s: the true rotor inertias wheels.rotor_inertia_kgm2 + "
                      "truth.rotor_inertia_error_kgm2 = %s" % (_vec(t["rotor_inertia_error_kgm2"]), _vec(jr)), jr, lam)
    hi = LENGTH_MAX_L * size
    cp = s.get("cp_offset_m")
    if cp is not None:
        n = math.sqrt(sum(x * x for x in cp))
        if n > hi:
            raise ValueError("surface.cp_offset_m = %s: |offset| = %s m is implausible for %s: must be at most %s m "
                             "(%s L; offset in mm or cm instead of m?)" % (_vec(cp), _num(n), vehicle, _num(hi),
                                                                          _num(LENGTH_MAX_L)))
    if w["arm_m"] > hi:
        raise ValueError("wheels.arm_m = %s: %s m is implausible for %s: must be at most %s m (%s L; arm in mm or "
                         "cm instead of m?)" % (_num(w["arm_m"], 6), _num(w["arm_m"]), vehicle, _num(hi),
                                                _num(LENGTH_MAX_L)))


def _check_moments(head, lam, mass, size):
    """ValueError starting with ``head`` unless the radius of gyration of each principal moment (``lam``,
    ascending, kg m^2) is within ``k_range_m(size)``: the largest is checked against the ceiling, the smallest
    against the floor."""
    lo, hi = k_range_m(size)
    k_big, k_small = math.sqrt(lam[2] / mass), math.sqrt(lam[0] / mass)
    if k_big > hi:
        which, j, k, hint = "largest", lam[2], k_big, "inertia in g m^2 or kg mm^2 instead of kg m^2?"
    elif k_small < lo:
        which, j, k, hint = "smallest", lam[0], k_small, "mass_kg in g instead of kg, areas too large, or the " \
                                                         "inertia too small?"
    else:
        return
    raise ValueError("%s: the %s principal moment J = %s kg m^2 gives a radius of gyration sqrt(J / mass_kg) = %s m, "
                     "implausible for a %s kg vehicle of about %s m (%s): must be from %s to %s m (%s)"
                     % (head, which, _num(j), _num(k), _num(mass, 6), _num(size), SIZE, _num(lo), _num(hi), hint))


def _check_rotors(head, rotors, lam):
    """ValueError starting with ``head`` unless each rotor inertia is at most ROTOR_SHARE_MAX of the smallest
    principal moment ``lam[0]`` (kg m^2)."""
    cap = ROTOR_SHARE_MAX * lam[0]
    for i, r in enumerate(rotors):
        if r > cap:
            raise ValueError("%s: rotor %d's inertia %s kg m^2 is %s %% of the vehicle's smallest principal moment "
                             "%s kg m^2: must be at most %s %% of it, %s kg m^2 (rotor inertia in g m^2 instead of "
                             "kg m^2?)" % (head, i, _num(r), _num(100.0 * r / lam[0]), _num(lam[0]),
                                           _num(100.0 * ROTOR_SHARE_MAX), _num(cap)))
