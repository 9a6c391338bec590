"""The spacecraft file's schema (pure Python, MicroPython-compatible): every key in order with its kind (str,
int, num, vec of n numbers, axes of n 3-vectors, epoch, block, sources), unit, allowed range and meaning; the
checker (``protocol.spacecraft.check``) walks it, and ``fps spacecraft schema`` prints it."""

FORMAT = "fps-spacecraft/1"
MAX_WHEELS = 8

WHEELS = "wheels.count"   # a vector's length given by the wheel count


def _rng(lo=None, hi=None, lo_open=False, hi_open=False):
    return (lo, lo_open, hi, hi_open)


ANY = _rng()
POS = _rng(0, None, True)          # > 0
NONNEG = _rng(0)                   # >= 0


def _e(path, kind, unit="", rng=ANY, doc="", n=None, optional=False, nullable=False):
    return {"path": path, "kind": kind, "unit": unit, "range": rng, "doc": doc, "n": n, "optional": optional,
            "nullable": nullable}


# Every key, in order. kind: str, int, num, vec (n numbers), axes (n 3-vectors), epoch (ISO UTC), block, sources.
SCHEMA = [
    _e("format", "str", doc="the file's format, \"%s\"" % FORMAT),
    _e("name", "str", doc="a short name (letters, digits, - _ .)"),
    _e("description", "str", doc="what the vehicle is and what the figures are"),
    _e("mass_kg", "num", "kg", _rng(0, 2000, True), "mass (the orbit truth's drag and SRP)"),
    _e("inertia_kgm2", "vec", "kg m^2", _rng(-1e4, 1e4), "[Jxx, Jyy, Jzz, Jxy, Jxz, Jyz] about the centre of mass; "
       "products are the matrix entries (-integral x y dm); without the rotors' spin-axis inertia; must be "
       "positive definite with each principal moment <= the sum of the other two", n=6),
    _e("residual_dipole_am2", "vec", "A m^2", _rng(-100, 100), "residual magnetic dipole, body frame "
       "(the filters' prior mean)", n=3),
    _e("laser_axis", "vec", "1", _rng(-1, 1), "the laser terminal's boresight in the body frame (normalised; "
       "not zero)", n=3),
    _e("surface", "block", doc="areas and coefficients of the orbit truth's drag and solar radiation pressure"),
    _e("surface.drag_area_m2", "num", "m^2", _rng(0, 100, True), "drag area"),
    _e("surface.cd", "num", "1", _rng(0, 10, True), "drag coefficient"),
    _e("surface.srp_area_m2", "num", "m^2", _rng(0, 100, True), "solar radiation pressure area"),
    _e("surface.cr", "num", "1", _rng(0, 2), "radiation pressure coefficient"),
    _e("surface.cp_offset_m", "vec", "m", _rng(-10, 10), "centre of pressure minus centre of mass, body frame: "
       "the flight world's drag and solar pressure torques (absent: none)", n=3, optional=True),
    _e("wheels", "block", doc="the reaction wheel assembly"),
    _e("wheels.count", "int", "1", _rng(3, MAX_WHEELS), "number of wheels"),
    _e("wheels.nominal_axes", "axes", "1", _rng(-1e3, 1e3), "each wheel's nominal spin axis, body frame "
       "(any non-zero length: normalised); with the misalignment they must span three axes", n=WHEELS),
    _e("wheels.delta1_deg", "vec", "deg", _rng(-45, 45), "misalignment angle 1 per wheel, about e1 "
       "(module docstring; Eq. 4.58-4.60)", n=WHEELS),
    _e("wheels.delta2_deg", "vec", "deg", _rng(-45, 45), "misalignment angle 2 per wheel, about e2", n=WHEELS),
    _e("wheels.rotor_inertia_kgm2", "vec", "kg m^2", _rng(0, 1, True), "each rotor's inertia about its spin axis",
       n=WHEELS),
    _e("wheels.speed_limit_rpm", "num", "rpm", _rng(0, 1e5, True), "speed limit (the driver cuts the torque "
       "that would pass it)"),
    _e("wheels.torque_limit_nm", "num", "N m", _rng(0, 10, True), "motor torque limit"),
    _e("wheels.friction_coulomb_nm", "num", "N m", _rng(0, 1), "Coulomb friction torque"),
    _e("wheels.friction_viscous_nms_rad", "num", "N m s/rad", _rng(0, 1e-3), "viscous friction coefficient"),
    _e("wheels.friction_smooth_rpm", "num", "rpm", _rng(0, 1e3, True), "Coulomb term = c tanh(W / this): "
       "smooth through zero speed"),
    _e("wheels.tach_noise_rpm", "num", "rpm", _rng(0, 1e3, True), "speed read-out noise, 1 sigma"),
    _e("wheels.imbalance_static_kgm", "num", "kg m", _rng(0, 1e-3), "static imbalance U_s (jitter)"),
    _e("wheels.imbalance_dynamic_kgm2", "num", "kg m^2", _rng(0, 1e-3), "dynamic imbalance U_d (jitter)"),
    _e("wheels.arm_m", "num", "m", _rng(0, 10), "each wheel sits at arm_m times its unit nominal axis from the "
       "centre of mass (jitter)"),
    _e("star_tracker", "block", doc="star tracker; sensor frame = body frame"),
    _e("star_tracker.sigma_arcsec", "vec", "arcsec", _rng(0, 3600, True), "noise about body x, y, z, 1 sigma",
       n=3),
    _e("star_tracker.rate_limit_deg_s", "num", "deg/s", _rng(0, 30, True), "no output at or above this body rate"),
    _e("star_tracker.rate_hz", "num", "Hz", _rng(0, 1000, True), "output rate"),
    _e("gyro", "block", doc="rate gyro of the MEKF baseline (Eq. 4.17-4.20)"),
    _e("gyro.arw_deg_rt_h", "num", "deg/sqrt(h)", _rng(0, 100, True), "angle random walk sigma_v"),
    _e("gyro.bias_deg_h", "num", "deg/h", _rng(0, 1e5), "initial bias per axis, 1 sigma (the MEKF's P0)"),
    _e("gyro.bias_instability_deg_h", "num", "deg/h", _rng(0, 1e4), "bias drift over one hour, 1 sigma: "
       "sigma_u = this / sqrt(1 h)"),
    _e("gyro.rate_hz", "num", "Hz", _rng(0, 1e4, True), "output rate"),
    _e("gnss", "block", doc="GNSS navigation solution (Eq. 5.10-5.11)"),
    _e("gnss.sigma_position_m", "num", "m", _rng(0, 1e5, True), "position noise per axis, 1 sigma"),
    _e("gnss.sigma_velocity_m_s", "num", "m/s", _rng(0, 1e3, True), "velocity noise per axis, 1 sigma"),
    _e("gnss.rate_hz", "num", "Hz", _rng(0, 100, True), "solution rate"),
    _e("beacon", "block", doc="beacon camera: unit vector to the partner, body frame (Eq. 5.13-5.15)"),
    _e("beacon.sigma_arcsec", "num", "arcsec", _rng(0, 36000, True), "noise per axis, 1 sigma"),
    _e("beacon.rate_hz", "num", "Hz", _rng(0, 1000, True), "output rate"),
    _e("beacon.misalignment_deg", "vec", "deg", _rng(-5, 5), "the camera's frame from the body frame: a small "
       "rotation vector [x, y, z] about body axes, y = C A(q) u with C = A(dq), dq = [angles/2, 1] normalised "
       "(Eq. 4.77) (absent: 0, an aligned camera)", n=3, optional=True),
    _e("orbit", "block", doc="the vehicle's orbit"),
    _e("orbit.circular", "block", doc="circular orbit of the attitude scenarios (analytic)"),
    _e("orbit.circular.altitude_km", "num", "km", _rng(100, 50000), "altitude above 6371.2 km (the IGRF "
       "reference radius the emulator's circular orbit uses)"),
    _e("orbit.circular.inclination_deg", "num", "deg", _rng(0, 180), "inclination"),
    _e("orbit.circular.raan_deg", "num", "deg", _rng(0, 360, False, True), "right ascension of the ascending "
       "node"),
    _e("orbit.circular.arg_lat_deg", "num", "deg", _rng(0, 360, False, True), "argument of latitude at t = 0"),
    _e("orbit.state", "block", doc="initial state the orbit truth propagates (EME2000)"),
    _e("orbit.state.epoch_utc", "epoch", "UTC", doc="epoch, \"YYYY-MM-DDThh:mm:ss[.s]\" (t = 0 of a run)"),
    _e("orbit.state.position_m", "vec", "m", _rng(-1e8, 1e8), "position at the epoch, EME2000; |r| from "
       "6478 km to 1e8 m", n=3),
    _e("orbit.state.velocity_m_s", "vec", "m/s", _rng(-2e4, 2e4), "velocity at the epoch, EME2000; |v| > 0 and "
       "< 12 km/s", n=3),
    _e("partner", "block", doc="the other terminal (SatB): null or absent for none", optional=True, nullable=True),
    _e("partner.position_m", "vec", "m", _rng(-1e8, 1e8), "position at orbit.state.epoch_utc, EME2000", n=3),
    _e("partner.velocity_m_s", "vec", "m/s", _rng(-2e4, 2e4), "velocity at orbit.state.epoch_utc, EME2000", n=3),
    _e("partner.relay_delay_s", "vec", "s", _rng(0, 3600), "[min, max] delay of the partner's GNSS relayed "
       "through the ground (uniform)", n=2),
    _e("magnetorquers", "block", doc="three magnetorquer rods; null for none", nullable=True),
    _e("magnetorquers.axes", "axes", "1", _rng(-1e3, 1e3), "each rod's axis, body frame (normalised; must span "
       "three axes)", n=3),
    _e("magnetorquers.dipole_limit_am2", "num", "A m^2", _rng(0, 1000, True), "each rod's dipole limit"),
    _e("magnetometer", "block", doc="three-axis magnetometer; null for none", nullable=True),
    _e("magnetometer.noise_nt", "num", "nT", _rng(0, 1e5, True), "noise per axis, 1 sigma"),
    _e("magnetometer.bias_nt", "num", "nT", _rng(0, 1e5), "constant bias per axis after calibration, 1 sigma"),
    _e("magnetometer.rate_hz", "num", "Hz", _rng(0, 1000, True), "output rate"),
    _e("uncertainty", "block", doc="1 sigma of the figures above: the filters' initial covariance"),
    _e("uncertainty.inertia_sigma_kgm2", "vec", "kg m^2", _rng(0, 1e4), "of [Jxx, Jyy, Jzz, Jxy, Jxz, Jyz]", n=6),
    _e("uncertainty.residual_dipole_sigma_am2", "num", "A m^2", _rng(0, 100), "of each dipole component"),
    _e("uncertainty.misalignment_sigma_deg", "num", "deg", _rng(0, 45), "of each misalignment angle"),
    _e("uncertainty.rotor_inertia_sigma_kgm2", "num", "kg m^2", _rng(0, 1), "of each rotor inertia"),
    _e("uncertainty.disturbance_torque_sigma_nm", "num", "N m", _rng(0, 1), "of the unmodelled disturbance "
       "torque per axis"),
    _e("uncertainty.attitude_sigma_deg", "num", "deg", _rng(0, 180, True), "of the initial attitude per axis"),
    _e("uncertainty.rate_sigma_deg_s", "num", "deg/s", _rng(0, 180, True), "of the initial body rate per axis"),
    _e("uncertainty.orbit_position_sigma_m", "num", "m", _rng(0, 1e7, True), "of the initial orbit position "
       "per axis (the STKF's P0)"),
    _e("uncertainty.orbit_velocity_sigma_m_s", "num", "m/s", _rng(0, 1e4, True), "of the initial orbit velocity "
       "per axis"),
    _e("uncertainty.beacon_misalignment_sigma_deg", "num", "deg", _rng(0, 5), "of each angle of "
       "beacon.misalignment_deg (the STKF's P0 when it estimates them; absent: 0)", optional=True),
    _e("truth", "block", doc="simulation only: the simulated vehicle's departures from the figures "
       "(true = figure + error); absent or null for none", optional=True, nullable=True),
    _e("truth.inertia_error_kgm2", "vec", "kg m^2", _rng(-1e4, 1e4), "error of inertia_kgm2 (the true inertia "
       "must be a rigid body's too)", n=6),
    _e("truth.residual_dipole_error_am2", "vec", "A m^2", _rng(-100, 100), "error of residual_dipole_am2", n=3),
    _e("truth.rotor_inertia_error_kgm2", "vec", "kg m^2", _rng(-1, 1), "error of wheels.rotor_inertia_kgm2 (the "
       "true inertias must be > 0)", n=WHEELS),
    _e("truth.delta1_error_deg", "vec", "deg", _rng(-45, 45), "error of wheels.delta1_deg (the true angles must be "
       "from -45 to 45 deg)", n=WHEELS),
    _e("truth.delta2_error_deg", "vec", "deg", _rng(-45, 45), "error of wheels.delta2_deg", n=WHEELS),
    _e("truth.beacon_misalignment_error_deg", "vec", "deg", _rng(-5, 5), "error of beacon.misalignment_deg (the "
       "true angles must be from -5 to 5 deg; absent: 0)", n=3, optional=True),
    _e("requirements", "block", doc="the budgets every verdict reads (absent: the thesis's, Yoon 2017 Ch. 2 and "
       "Sec. 6.4: 150 arcsec, 35 arcsec/s, 11.98 arcsec, 80 %)", optional=True, nullable=True),
    _e("requirements.body_pointing_3sigma_arcsec", "num", "arcsec", _rng(0, 36000, True), "the body loop's "
       "pointing error, 3 sigma"),
    _e("requirements.body_stability_3sigma_arcsec_s", "num", "arcsec/s", _rng(0, 36000, True), "the body "
       "loop's pointing stability, 3 sigma"),
    _e("requirements.fine_pointing_arcsec", "num", "arcsec", _rng(0, 3600, True), "the fine loop's pointing "
       "requirement: the beam within this of its partner (half the beam's FWHM in the thesis)"),
    _e("requirements.wheel_speed_share", "num", "1", _rng(0, 1, True, False), "the wheels' speed after the first "
       "orbit at most this share of wheels.speed_limit_rpm (the flight world)"),
    _e("sources", "sources", doc="where each figure comes from: key path (a block or a key) -> text",
       optional=True),
]
BY_PATH = dict((e["path"], e) for e in SCHEMA)


def _children(block):
    """The schema entries directly inside ``block`` ("" for the top level), in order."""
    depth = 0 if block == "" else block.count(".") + 1
    pre = "" if block == "" else block + "."
    return [e for e in SCHEMA if e["path"].startswith(pre) and e["path"].count(".") == depth]
