"""Units, defined once for every part (pure Python: the firmware imports it under MicroPython too). Names say the
direction: ``RAD_PER_ARCSEC`` turns arcsec into radians (multiply), ``ARCSEC_PER_RAD`` radians into arcsec."""

import math

RAD_PER_ARCSEC = math.pi / 180.0 / 3600.0     # 4.8481e-6 rad in one arcsec
ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0     # 206264.8 arcsec in one radian
