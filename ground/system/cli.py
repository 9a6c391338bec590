"""``fps system``'s command line."""

import json
import os
import sys


from ground import hil, verdict
from ground.adcs.campaign import MAX_DURATION_S     # the ADCS's run is held in memory, as fps adcs bps's
from ground.adcs.options import add_fault_options, add_satb_gnss_option, faults_from_args
from ground.fileio import cache_folder
from ground.system.constants import ADCS_KINDS, LEAD_S, RUNTIMES, firmware_available
from ground.system.reporting import _x, exit_code, side_by_side, verdict_lines
from ground.system.run import run_system


def _read_summary(out_dir):
    """The run folder's summary.json, or {} when it cannot be read (the error line says what happened)."""
    try:
        with open(os.path.join(out_dir, "summary.json")) as f:
            s = json.load(f)
        return s if isinstance(s, dict) else {}
    except (OSError, ValueError):
        return {}


def _link_faults_arg(text):
    """--link-faults SPEC as a ``LinkFaults`` (ValueError naming the option when it is malformed)."""
    if text is None:
        return None
    from protocol.faults import LinkFaults
    return LinkFaults.parse(text)


def _cmd(a):
    cfg = None
    if a.config is not None:
        from emulator.config import load_config
        cfg = load_config(a.config)
    try:
        s = run_system(a.duration, a.output, a.runtime, a.adcs, a.satb_gnss, a.seed, a.ts, a.truth, a.calibration,
                       a.params, a.bps_cache, cfg, a.q2_dv, a.quiet, not a.no_plots, faults_from_args(a),
                       _link_faults_arg(a.link_faults), a.spacecraft, a.world, a.vehicle, a.stkf_accel)
    except hil.Interrupted:
        s = _read_summary(a.output)
        print("interrupted after %.1f s of virtual time: partial run in %s (summary complete=false)"
              % (s.get("duration_s") or 0.0, a.output), file=sys.stderr)
        return 130
    except hil.RunFailed as exc:
        for line in verdict_lines(_read_summary(a.output))[1:]:
            print(line, file=sys.stderr)
        print("fps system: error: %s" % exc, file=sys.stderr)
        return 1
    print(side_by_side(s))
    print()
    print("ADCS %s, controller %s over serial: %.1f s virtual in %.1f s wall, real-time factor %s (play %s)"
          % (a.adcs, a.runtime, s["duration_s"], s["wall_s"], _x(s["real_time_factor"]),
             _x(s["real_time_factor_play"])))
    verdict.close(a.output, verdict_lines(s))
    return exit_code(s)


EXIT_STATUS = """exit status: 0 complete, and both loops within their budgets (fine: every Q2 sample within 11.98
arcsec; body: 3 sigma pointing <= 150 arcsec and stability <= 35 arcsec/s; --runtime qemu: no tick of the
controller board late on the wire); 3 complete but a budget missed
(summary.json's verdict and report.md name the loop and by how much); 1 failed (the ADCS failed or stopped
answering, link down, controller exited: the folder holds the
partial run with complete=false, the error and stopped_in); 2 bad input; 130 interrupted (partial folder,
complete=false)."""


def register(sub, name, help_):
    import argparse
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0], epilog=EXIT_STATUS,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=600.0,
                   help="the seconds collected: the window played to the P-FSM, the one the verdict judges, virtual s, "
                        "at most %g (default 600); the ADCS runs its settling before it (thesis world 30 s + 4 t_s, "
                        "flight world the planned slew and 4 t_s) and %g s beyond" % (MAX_DURATION_S, LEAD_S))
    p.add_argument("--adcs", choices=ADCS_KINDS, default="firmware" if firmware_available() else "ground",
                   help="firmware: the ADCS flight software on CAN against the emulated spacecraft; ground: the "
                        "body pointing simulator of Sec. 6.4 (default: firmware when this build has it)")
    p.add_argument("--runtime", default="micropython", choices=RUNTIMES,
                   help="where the fine-pointing controller (and the ADCS firmware) run: micropython and cpython "
                        "on this machine, qemu on the PIL boards of make pil (the controller on a Cortex-M0, the "
                        "ADCS on a Cortex-M7; default micropython)")
    add_satb_gnss_option(p, False)
    p.add_argument("--ts", type=float, default=33.0, help="ADCS settling time t_s in s (default 33, Sec. 6.4.4)")
    p.add_argument("--truth", choices=("hpop", "two-body"), default="hpop", help="true orbits (default hpop)")
    p.add_argument("--params", default=None, help="ADCS parameter file (fps adcs bps format; default: the cached "
                   "nine calibration sets of --seed)")
    p.add_argument("--cache-dir", "--bps-cache", dest="bps_cache", default=None, type=cache_folder, metavar="DIR",
                   help="calibration and truth cache folder (default out/bps_cache; --bps-cache is the same "
                        "option)")
    p.add_argument("--calibration", default=None, help="H calibration JSON (fps calibrate; default: calibrate "
                   "in-process first, 121 points, written to the run folder)")
    add_fault_options(p, "seconds from the ADCS's start, the play beginning after its 30 s hold and 4 t_s; "
                         "either ADCS")
    p.add_argument("--link-faults", default=None, metavar="SPEC",
                   help="faults on the ADCS's CAN link (firmware ADCS), both directions of its slcan stream: "
                        "bytes=P (a bit flip per ASCII byte), frames=P (a CAN frame's line dropped), seed=N, "
                        "silence=START_S:LENGTH_S (the ADCS's seconds; LENGTH_S may be inf), first=N (the first N "
                        "frame lines each way dropped); the lockstep's "
                        "retries keep each 1 Hz cycle exactly once, e.g. bytes=0.001,frames=0.05,seed=1")
    p.add_argument("--world", choices=("thesis", "flight"), default="flight",
                   help="flight (default): datasheet wheel limits, drag and solar pressure, magnetorquer "
                        "unloading, a rate-limited slew and re-acquisition (fps adcs bps --world flight), the play "
                        "starting once the planned slew and 4 t_s of settling are over (277 s for thesis-3u at t_s = 33 s); "
                        "thesis: Sec. 6.4's world, the play after 30 s + 4 t_s")
    from ground.adcs.options import add_spacecraft_option, add_stkf_accel_option
    add_stkf_accel_option(p, "--world flight with --truth hpop, either --adcs: both fly the flight app")
    add_spacecraft_option(p, "the ADCS's vehicle, as fps adcs bps (--adcs ground) or fps adcs can (--adcs "
                          "firmware) take it; --params is checked against it")
    hil.add_run_arguments(p, "seed of the ADCS scenario and the bench emulator, >= 0 (default 0)")
    p.set_defaults(func=_cmd)
