"""The ADCS kernels in C for CPython (firmware/adcs/native/adcsk_cpython.c over adcsk.c, the extension
firmware.adcs._adcsk): they give the Python forms' results bit for bit, kernel by kernel on seeded inputs and over
every cycle of a recorded session with SatB's GNSS (tests/mp/adcsk_digests.py, the script the MicroPython module is
held to, run here by CPython with and without the extension); bad arguments raise; lists run the Python form."""

import json
import os
import subprocess
import sys
from array import array

import numpy as np
import pytest

from firmware.adcs import linalg
from tests.adcs_lean_common import record_session
from tests.test_firmware_mp import ROOT

try:
    from firmware.adcs import _adcsk
except ImportError:
    _adcsk = None

need_extension = pytest.mark.skipif(_adcsk is None, reason="firmware.adcs._adcsk is not built (no C compiler at "
                                                            "install)")
SCRIPT = os.path.join(ROOT, "tests", "mp", "adcsk_digests.py")


def digests(form, *args):
    """The script's digests under CPython with the ADCS kernels' ``form`` (FPS_ADCS_KERNELS)."""
    code = "import runpy, sys\nsys.argv = sys.argv[1:]\nrunpy.run_path(sys.argv[0], run_name='__main__')\n"
    p = subprocess.run([sys.executable, "-c", code, SCRIPT] + [str(a) for a in args], cwd=ROOT,
                       env=dict(os.environ, FPS_ADCS_KERNELS=form), capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


@need_extension
def test_the_c_kernels_equal_the_python_forms_bit_for_bit(tmp_path):
    assert linalg.kernels is _adcsk                          # selected on CPython
    cfg, rec = record_session(tmp_path)
    c = digests("c", cfg, rec)
    py = digests("python", cfg, rec)
    assert c.pop("kernels") is True and py.pop("kernels") is False
    assert c["session cycles"] == 60 and c["satb fused"] > 40     # the smoother's update ran
    assert len(c) > 25
    for key in sorted(py):
        assert c[key] == py[key], key


@need_extension
def test_the_c_kernels_refuse_bad_arguments():
    f = array("f", bytes(4 * 36))
    for call, error in (((f, array("i", bytes(4 * 36)), f, 6, 6, 6), TypeError),     # not a float buffer
                        ((f, array("f", bytes(4 * 35)), f, 6, 6, 6), ValueError),    # too short
                        ((f, f, f, 6.0, 6, 6), TypeError),                            # a size not an int
                        ((f, f, f, -1, 6, 6), ValueError),
                        ((f, f, f, 6, 6), TypeError)):                                # an argument missing
        with pytest.raises(error, match="adcsk"):
            _adcsk.matmul(*call)
    with pytest.raises(ValueError, match="rows out of range"):
        _adcsk.joseph_select(f, 6, 4, 3, f, f, f, f, f)
    with pytest.raises(TypeError, match="a float is needed"):
        _adcsk.joseph_select(f, 6, 0, 3, [np.float32(1.0)] * 9, f, f, f, f)
    assert _adcsk.cholesky(f, f, 6) is False                  # zeros: not positive definite


@need_extension
def test_lists_run_the_python_form_and_errors_pass_through():
    """A test's ``zeros`` giving lists (of numpy.float32: float32 arithmetic) runs the Python form; a buffer too
    short is the kernel's ValueError, not a fallback."""
    rng = np.random.default_rng(3)
    a, b = rng.standard_normal(18), rng.standard_normal(24)
    out = {}
    for cast in (float, np.float32):
        C, A, B = [cast(0.0)] * 12, [cast(v) for v in a], [cast(v) for v in b]
        linalg.matmul(C, A, B, 3, 6, 4)
        ref = [cast(0.0)] * 12
        linalg.matmul.python(ref, A, B, 3, 6, 4)
        assert [type(v) for v in C] == [type(v) for v in ref] and C == ref
        out[cast] = C
    Cb, Ab, Bb = array("d", bytes(8 * 12)), array("d", a), array("d", b)
    linalg.matmul(Cb, Ab, Bb, 3, 6, 4)
    assert list(Cb) == out[float]                                     # the C and the Python form (doubles) agree
    with pytest.raises(ValueError, match="too short"):
        linalg.matmul(Cb, Ab, array("d", bytes(8 * 23)), 3, 6, 4)
