"""The parameter file (``protocol.paramfile``, the one checker the flight firmware uses too) on the ground: its
``x`` parts where they sit in the 41-state APKF's state, made from the APKF after a calibration, checked against a
spacecraft and read and written (``body_pointing``'s calibration writes it; its runs and the estimators read it)."""

import numpy as np

from emulator.spacecraft.wheels import N_WHEELS
from ground.adcs import apkf
from ground.fileio import write_json
from protocol import paramfile as pf

FORMAT = pf.FORMAT


# The parameter file's "x" (protocol.paramfile): its parts, in order, and where each sits in the APKF's state x (in
# P, one row lower)
def _x_slices(start=7):
    out = []
    for k, n in pf.X_PARTS:
        out.append((k, slice(start, start + n)))
        start += n
    return tuple(out)


X_PARTS = _x_slices()


def params_from_apkf(x, P, jxx, meta, scale=1.0):
    return {"format": FORMAT, "wheels": N_WHEELS, "jxx_ref_kgm2": float(jxx), "torque_scale": float(scale),
            "x": {k: x[s].tolist() for k, s in X_PARTS},
            "P": P[apkf.PARAMS, apkf.PARAMS].tolist(), "calibration": meta}


def check_params(d, where="parameter file", spacecraft=None):
    """Validate a parameter file dict against the spacecraft (``protocol.paramfile.check``; ``spacecraft`` a
    checked spacecraft file, None: the thesis's 3U); returns (x_params (23), P (23 x 23), jxx, torque_scale)."""
    try:
        c = pf.check(d, spacecraft)
    except ValueError as exc:
        raise ValueError("%s: %s" % (where, exc)) from None
    xp = np.array([v for k, _ in X_PARTS for v in c["x"][k]])
    return xp, np.array(c["P"]), c["jxx_ref_kgm2"], c["torque_scale"]


def load_params(path, spacecraft=None):
    """``check_params`` of the parameter file at ``path`` (read by ``ground.fileio.read_json``), and the dict as
    read; ValueError beginning with the file."""
    from ground.fileio import read_json
    d = read_json(path, "parameter file")
    return check_params(d, "parameter file %s" % path, spacecraft) + (d,)


def write_params(path, d, spacecraft=None):
    check_params(d, path, spacecraft)
    write_json(path, d)
