"""``make figures``: the documentation's figures, each made by the ``fps`` command named beside it in
``docs/FIGURES.md``, into ``docs/figures/``. Short runs (a minute or two in all): the figures show what each plot
looks like and how to read it; the full runs' figures come from the same commands with the docs' durations.

    python -m ground.figures [OUT_DIR]      (default docs/figures)
"""

import os
import shutil
import sys
import tempfile

from ground.cli import main as fps

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# (the figure's file in the run folder, its name in docs/figures, the command (after "fps"), the thesis figure)
FIGURES = (
    ("calibration.json", "calibration_fig7-16.png", "calibration_fig7-16.png",
     ["calibrate", "--runtime", "inproc", "--link", "inproc", "-o", "{d}/calibration.json"], "Fig. 7-16"),
    ("calibration.json", "calibration_fig7-17.png", "calibration_fig7-17.png", None, "Fig. 7-17"),
    ("hil", "fig7-18_scatter.png", "fig7-18_scatter.png",
     ["hil", "--distfile", "{d}/d.dist", "--calibration", "{d}/calibration.json", "--duration", "60", "--runtime", "inproc",
      "--link", "inproc", "--quiet", "-o", "{d}/hil"], "Fig. 7-18"),
    ("hil", "fig7-19_time.png", "fig7-19_time.png", None, "Fig. 7-19"),
    ("apkf", "fig4-5_errors.png", "apkf_fig4-5_errors.png",
     ["adcs", "apkf", "--case", "1", "--runs", "3", "--workers", "1", "--quiet", "-o", "{d}/apkf"], "Fig. 4-5"),
    ("apkf", "monte_carlo.png", "apkf_monte_carlo.png", None, None),
    ("stkf", "fig5-4_states.png", "stkf_fig5-4_states.png",
     ["adcs", "stkf", "--case", "1", "--runs", "2", "--workers", "1", "--quiet", "-o", "{d}/stkf"], "Fig. 5-4"),
    ("stkf", "fig5-5_pointing.png", "stkf_fig5-5_pointing.png", None, "Fig. 5-5"),
    ("bps", "fig6-3_pointing.png", "bps_fig6-3_pointing.png",
     ["adcs", "bps", "--duration", "400", "--truth", "two-body", "--quiet", "-o", "{d}/bps"], "Fig. 6-3"),
    ("flight", "flight_pointing.png", "flight_pointing.png",
     ["adcs", "bps", "--world", "flight", "--orbits", "2", "--cache-dir", "{d}/cache", "--quiet", "-o", "{d}/flight"],
     None),
    ("flight", "flight_wheels.png", "flight_wheels.png", None, None),
    ("response", "bode_sensitivity.png", "bode_sensitivity.png",
     ["response", "--runtime", "inproc", "--link", "inproc", "--points", "6", "--quiet", "-o", "{d}/response"],
     None),
    ("response", "bode_loop.png", "bode_loop.png", None, None),
)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    out = argv[0] if argv else os.path.join(ROOT, "docs", "figures")
    os.makedirs(out, exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        code = fps(["distfile", "generate", "--source", "stat", "--duration", "60", "--seed", "1", "-o",
                    os.path.join(d, "d.dist")])
        if code != 0:
            return code
        for folder, name, dest, cmd, _ in FIGURES:
            if cmd is not None:
                print("fps %s" % " ".join(cmd).replace("{d}/", ""), flush=True)
                code = fps([c.format(d=d) for c in cmd])
                if code not in (0, 3):                  # 3: a run that missed a budget still draws its figures
                    print("figures: fps %s exited %d" % (cmd[0], code), file=sys.stderr)
                    return 1
            src = os.path.join(d, name) if folder.endswith(".json") else os.path.join(d, folder, name)
            if not os.path.exists(src):
                print("figures: %s was not written" % name, file=sys.stderr)
                return 1
            shutil.copyfile(src, os.path.join(out, dest))
    print("figures: %d in %s" % (len(FIGURES), os.path.relpath(out, ROOT)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
