"""What the lean flight ADCS tests share: micropython with a heap large enough for the STKF's cycle, float32
buffers for CPython, and the positive-definiteness check."""

import json
import os
import subprocess

import numpy as np
import pytest

from tests.test_firmware_mp import MICROPYTHON, ROOT


def run_mp(script, *args):
    """tests/mp/<script> under micropython with a 64 MB heap: the heap measurement turns the collector off
    for a whole cycle, and the STKF's cycle allocates more than the unix port's default heap."""
    if not os.path.exists(MICROPYTHON):
        pytest.skip("micropython binary not installed in the venv")
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen")
    p = subprocess.run([MICROPYTHON, "-X", "heapsize=64M", os.path.join(ROOT, "tests", "mp", script)]
                       + [str(a) for a in args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, "micropython %s failed:\n%s\n%s" % (script, p.stdout, p.stderr)
    return json.loads([ln for ln in p.stdout.splitlines() if ln.startswith("{")][-1])


class F32(list):
    """A buffer of numpy.float32 scalars: every store rounds to float32, so the arithmetic runs in float32."""

    def __setitem__(self, i, v):
        list.__setitem__(self, i, np.float32(v))


def positive_definite(P):
    try:
        np.linalg.cholesky(P)
        return True
    except np.linalg.LinAlgError:
        return False


def record_session(tmp_path, seconds=60):
    """A CPython ADCS session of ``seconds`` cycles with SatB's relayed fixes, recorded: (its config.json, its
    recorded bursts' json), for the digest scripts that replay it."""
    from emulator.adcs_session import AdcsSession
    with AdcsSession(runtime="cpython", duration_s=seconds, hold_s=20.0, satb_gnss=True, record=True) as s:
        for _ in range(seconds):
            s.cycle()
        cfg, rec = s.config(), s.recorded
    (tmp_path / "cfg.json").write_text(json.dumps(cfg))
    (tmp_path / "rec.json").write_text(json.dumps(rec))
    return tmp_path / "cfg.json", tmp_path / "rec.json"
