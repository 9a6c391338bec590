"""``--source bps`` for ``fps distfile generate``: the body pointing simulator's (dtheta1, dtheta2) at 10 Hz.

The run (``ground.adcs.body_pointing.simulate``, flown by ``--spacecraft``) starts after the calibration (from ``--params
FILE`` or the cached nine sets of ``--seed``); the history given to the distfile is the collection window (after
the 30 s hold and 4 t_s), its time origin at the window's start. Runs are cached in ``--cache-dir`` (default out/bps_cache) under
a hash of every input (t_s, SatB GNSS, parameter file content, duration, seed, truth, simulator version, the
spacecraft file's hash unless it is thesis-3u); an
entry is written atomically and only for a complete run, so the cache never holds a partial run. A sidecar
``<distfile>.json`` written by the distfile command records the inputs in full; the 16-byte header source field
carries ``bps<ts><g|n> <key>`` (g: with SatB's GNSS).
"""

import io
import json
import os
import sys

import numpy as np

from emulator.fileio import cache_folder, load_npz, write_atomic
from ground.adcs.options import add_satb_gnss_option

TRUTHS = ("hpop", "two-body")
UNHASHED = ("params_file", "from_cache")    # sidecar notes outside the cache key: the path (its content is hashed)


def _key(inputs):
    """The cache key of a run's inputs (``BpsSource.key``): their hash without the parameter file's path (its
    content is in ``params_sha256``) and the sidecar's ``from_cache``."""
    from ground.adcs import bps_cli
    return bps_cli._key({x: v for x, v in inputs.items() if x not in UNHASHED})


class BpsSource:
    name = "bps"
    UNHASHED = UNHASHED

    def __init__(self, ts=33.0, satb_gnss=False, params_path=None, truth="hpop", cache_dir=None, quiet=False,
                 spacecraft=None):
        from ground.adcs import body_pointing as bps, bps_cli
        from ground.adcs.options import load_spacecraft
        self.ts = bps.check_ts(ts)
        if truth not in TRUTHS:
            raise ValueError("--truth must be one of %s, got %r" % ("/".join(TRUTHS), truth))
        self.satb_gnss, self.truth, self.quiet = bool(satb_gnss), truth, quiet
        self.cache_dir = cache_dir if cache_dir is not None else bps_cli.CACHE_DEFAULT
        self.params_path = params_path
        self.spacecraft = load_spacecraft(spacecraft, partner=True)[0]
        self.params = bps.load_params(params_path, self.spacecraft)[-1] if params_path else None
        self.inputs = None
        self.from_cache = False

    @staticmethod
    def add_arguments(p):
        p.add_argument("--ts", type=float, default=33.0, help="bps: settling time t_s in s (default 33)")
        add_satb_gnss_option(p, False)
        p.add_argument("--params", default=None, help="bps: parameter file (default: the cached calibration "
                       "of --seed)")
        p.add_argument("--truth", "--bps-truth", dest="bps_truth", choices=TRUTHS, default="hpop",
                       help="bps: true orbits (default hpop; --bps-truth is the same option)")
        p.add_argument("--cache-dir", "--bps-cache", dest="bps_cache", default=None, type=cache_folder, metavar="DIR",
                       help="bps: calibration and truth cache folder (default out/bps_cache; --bps-cache is the "
                            "same option)")
        p.add_argument("--spacecraft", default=None, metavar="NAME|FILE",
                       help="bps: the vehicle, a preset or a spacecraft file (default thesis-3u), as fps adcs bps: "
                            "its truth block, or, for a file without one, a vehicle drawn from --seed within its "
                            "uncertainty block")

    @classmethod
    def from_args(cls, a):
        return cls(a.ts, a.satb_gnss, a.params, a.bps_truth, a.bps_cache, getattr(a, "quiet", False), a.spacecraft)

    def key(self, duration_s, seed, params, simulated_s=None):
        """The cache key of a run: the hash of ``inputs``, which hold the file's ``duration_s`` and the
        ``simulated_s`` behind it (one step and the interpolation stencil more)."""
        from ground.adcs import bps_cli
        self.inputs = {"source": "bps", "ts_s": self.ts, "satb_gnss": self.satb_gnss, "duration_s": float(duration_s),
                       "simulated_s": float(duration_s if simulated_s is None else simulated_s),
                       "seed": int(seed), "truth": self.truth, "version": bps_cli.VERSION,
                       "params_sha256": bps_cli._key(params), "params_file": self.params_path,
                       "calibration_seed": params.get("calibration", {}).get("seed")}
        self.inputs.update(bps_cli.spacecraft_key(self.spacecraft))
        return _key(self.inputs)

    @staticmethod
    def describes(header_source, header_seed, inputs):
        """Whether ``inputs`` (a distfile's sidecar) are the inputs of the file whose header carries
        ``header_source`` and ``header_seed``: their hash is the header's key and the seeds agree."""
        if not isinstance(inputs, dict) or inputs.get("source") != "bps" or " " not in header_source:
            return False
        tag = header_source.split(" ", 1)[1]
        return bool(tag) and _key(inputs).startswith(tag) and inputs.get("seed") == header_seed

    def header_source(self):
        return ("bps%g%s %s" % (self.ts, "g" if self.satb_gnss else "n", self.cache_key))[:16]

    def generate(self, duration_s, seed):
        from emulator.spacecraft.dispersion import flown
        from ground.adcs import body_pointing as bps, bps_cli
        d = flown(self.spacecraft, seed)[0]          # its truth block, or a vehicle drawn from the seed
        params = self.params or bps_cli.calibration(seed, self.cache_dir, not self.quiet, d)
        span = float(duration_s) + 1.0                    # the distfile needs one step and a stencil beyond
        self.cache_key = self.key(duration_s, seed, params, simulated_s=span)
        path = os.path.join(self.cache_dir, "run_%s.npz" % self.cache_key)
        if os.path.exists(path):
            try:
                t, x, y = load_npz(path, ("t", "x", "y"))
                if not (t.ndim == 1 and x.shape == y.shape == t.shape and len(t) >= 2
                        and np.all(np.isfinite(np.concatenate([t, x, y])))):
                    raise ValueError("arrays of the wrong shape or not finite")
                self.from_cache = True
                return t, x, y
            except ValueError as exc:
                print("bps: cached run %s is damaged (%s): simulating it again" % (path, exc), file=sys.stderr)
        if not self.quiet:
            print("bps: simulating t_s = %g s, %s SatB's GNSS, %g s (+%g s settling) ..."
                  % (self.ts, "with" if self.satb_gnss else "without", span, 30 + 4 * self.ts), file=sys.stderr)
        res, hist = bps.simulate(ts=self.ts, satb_gnss=self.satb_gnss, duration_s=span, seed=seed, params=params,
                                 truth=self.truth, cache_dir=os.path.abspath(self.cache_dir),
                                 progress=not self.quiet, spacecraft=d)
        if not res["complete"]:
            raise KeyboardInterrupt            # nothing cached, nothing written
        sel = hist["t"] >= res["settle_s"] - 1e-9
        t = hist["t"][sel] - hist["t"][sel][0]
        x, y = hist["dtheta_arcsec"][sel, 0], hist["dtheta_arcsec"][sel, 1]
        buf = io.BytesIO()
        np.savez(buf, t=t, x=x, y=y, inputs=json.dumps(self.inputs),
                 stats=json.dumps({k: res.get(k) for k in bps.SUMMARY_KEYS}))
        os.makedirs(self.cache_dir, exist_ok=True)
        write_atomic(path, buf.getvalue())
        return t, x, y
