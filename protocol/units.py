"""Units and physical constants, defined once for every part (pure Python: the firmware imports it under MicroPython
too). Names say the direction: ``RAD_PER_ARCSEC`` turns arcsec into radians (multiply), ``ARCSEC_PER_RAD`` radians
into arcsec."""

import math

RAD_PER_ARCSEC = math.pi / 180.0 / 3600.0     # 4.8481e-6 rad in one arcsec
ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0     # 206264.8 arcsec in one radian

# The Earth's gravitational parameter, m^3/s^2: EGM2008's (= JGM-3's) 398600.4415 km^3/s^2, the value of the
# thesis's orbit model (Eq. 5.7) and of brahe's GM_EARTH, so the two-body orbits, the STKF, the gravity-gradient
# torque and the high-precision truth agree
MU_EARTH = 398600.4415e9

# The Earth's second zonal harmonic (JGM-3's and EGM96's unnormalised J2) and the equatorial radius it goes with
# (WGS-84's, m): the flight STKF's J2 model (firmware/adcs/stkf_kernels.py)
J2_EARTH = 1.08262668e-3
R_EARTH_EQ = 6378137.0
