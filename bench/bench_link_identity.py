"""Benchmark: the whole terminal's verdict under link faults never depends on the faults or the host's speed.
``fps system`` (the firmware ADCS over CAN, the fine loop over serial, both MicroPython), 120 s, clean and then
with ``--link-faults bytes=0.001,frames=0.05`` on the ADCS's slcan stream under ``RUNS`` fault seeds (each run
a different pattern of damaged bytes and lost frames): every run's fine samples (samples.npz) and body history
(body.npz) bit-identical to the clean run's, whatever its wall time and retries.
"""

import os
import shutil
import tempfile

from bench.bench_faults import _fps_timed, _same_npz
from emulator.bench import Bench
from emulator.truth import true_h_field
from ground.fileio import write_json

DURATION_S = 120.0
RUNS = 10
SPEC = "bytes=0.001,frames=0.05,seed=%d"


def main(runs=RUNS, duration_s=DURATION_S):
    tmp = tempfile.mkdtemp(prefix="bench_link_identity_")
    try:
        _main(tmp, runs, duration_s)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _main(tmp, runs, duration_s):
    from ground.adcs import body_pointing as bps, bps_cli
    cal = os.path.join(tmp, "cal.json")
    write_json(cal, true_h_field(Bench(noise=False), None, 0.01))
    params, cache = os.path.join(tmp, "params.json"), os.path.join(tmp, "bps_cache")
    bps.write_params(params, bps_cli.calibration(0, cache, progress=False))
    print("### fps system, %g s, faults on the ADCS's slcan stream: %d fault seeds against the clean run\n"
          % (duration_s, runs))
    print("| run | exit | complete | wall (s) | ADCS cycles retried | faults injected (bits flipped, frames dropped) | both loops "
          "bit-identical to clean (goal: every run) |")
    print("|---|---|---|---|---|---|---|")
    ref, same, failed = None, 0, []
    for k in range(runs + 1):
        spec = None if k == 0 else SPEC % k
        out = os.path.join(tmp, "system_%d" % k)
        rc, wall, s = _fps_timed(["system", "--adcs", "firmware", "--duration", "%g" % duration_s, "--truth",
                                  "two-body", "--params", params, "--calibration", cal, "--bps-cache", cache,
                                  "--quiet", "--no-plots", "-o", out], spec)
        r = (s.get("adcs_summary") or {}).get("retries") or {}
        link = (s.get("adcs_summary") or {}).get("link") or {}
        faults = sum(v for k, v in link.items() if k.startswith("fault_")) if spec else 0
        if k == 0:
            ref, ident = out, "(the reference)"
            if rc not in (0, 3):
                failed.append("the clean run (exit %d): %s" % (rc, s.get("error")))
        else:
            ident = all(_same_npz(os.path.join(ref, f), os.path.join(out, f)) for f in ("samples.npz", "body.npz"))
            same += bool(ident)
        print("| %s | %d | %s | %.1f | %s | %s | %s |" % ("clean" if spec is None else "`%s`" % spec, rc,
                                                       s.get("complete"), wall, r.get("cycles_retried", "—"),
                                                       faults, ident), flush=True)
    print("\n%d of %d faulted runs identical to the clean run (goal: %d of %d)" % (same, runs, runs, runs))
    if failed:
        raise RuntimeError("; ".join(failed))


if __name__ == "__main__":
    main()
