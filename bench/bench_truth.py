"""The truth's speed: microseconds per RK4 step of ``Spacecraft.step`` in its Python form and its C kernel
(``emulator.spacecraft.kernel``) beside Basilisk's 13.5-19 us per step; where one campaign vehicle's CPU time goes
(3 orbits, the truth's kernel) with the ADCS app's kernels in their Python forms (``FPS_ADCS_KERNELS=python``, the
before) and in C (firmware.adcs._adcsk, the after), with the 100 vehicles that CPU makes over this machine's cores
beside the goal; and the wall time of a 3-orbit ``fps adcs campaign`` on the cores beside the goal of 100 vehicles
in 15 min, extrapolated from two measured campaigns of ``CAMPAIGN_RUNS`` and twice as many vehicles
(``BENCH_TRUTH_RUNS``) with each ADCS form, a fixed part and a part per vehicle: from their wall time, and from
their processes' CPU time over the cores (what an idle machine would take; a shared machine's wall time is read
against its load)."""

import contextlib
import functools
import io
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict

import numpy as np

from bench import verdict
from emulator.spacecraft import Spacecraft, WheelParams, Wheels, kernel, scenario
from emulator.spacecraft.wheels import RPM

BASILISK_US = (13.5, 19.0)          # the goal's figure: Basilisk's spacecraft with four wheels, per step
GOAL_RUNS, GOAL_MIN = 100, 15.0     # 100 vehicles x 3 orbits in 15 min on 2 cores
CAMPAIGN_RUNS = int(os.environ.get("BENCH_TRUTH_RUNS", "2"))
REPEATS = 5


def _thesis(form, **kw):
    return Spacecraft(wheels=Wheels(WheelParams(jitter=kw.pop("jitter", False)), rng=np.random.default_rng(0)),
                      omega=np.radians([1.0, 0.0, 0.0]), omega_rw=np.array([1000.0, -1500.0, 800.0, 2000.0]) * RPM,
                      kernel=form == "kernel", **kw)


def _flight(form):
    sc = scenario.pointing_world(600, 0, flight=True).sc
    sc.truth_form = form
    return sc


CASES = (("the flight world's truth (orbit grid, dipole at the epoch, drag + solar torques)", _flight),
         ("thesis-3u, circular orbit, gravity gradient + dipole", _thesis),
         ("the same with a Python disturbance callable (called back per stage)",
          lambda f: _thesis(f, disturbance=lambda t, q, w: 1e-8 * q[0:3])),
         ("jitter on, dt = 0.5 ms", lambda f: _thesis(f, jitter=True, dt=5e-4)))


def step_us(sc, n):
    """The best of ``REPEATS`` timings of n steps, us of CPU time per step (the process's own: a shared machine's
    other work does not count) with the wheels commanded as a controller would."""
    sc.wheels.command_all([2e-4, -1e-4, 3e-4, -2e-4])
    best = np.inf
    for _ in range(REPEATS):
        t0 = time.process_time()
        for _ in range(n):
            sc.step()
        best = min(best, (time.process_time() - t0) / n)
    return 1e6 * best


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def campaign_wall(runs, adcs):
    """Wall time and CPU time (s) of ``fps adcs campaign --runs runs --orbits 3`` on all cores with the ADCS kernels'
    form ``adcs`` ("python" or "c", ``FPS_ADCS_KERNELS``) and the truth's kernel where built, and the truth's form
    its first run recorded."""
    env = dict(os.environ, FPS_ADCS_KERNELS=adcs)
    with tempfile.TemporaryDirectory() as d:
        t0, c0 = time.perf_counter(), _children_cpu()
        p = subprocess.run([sys.executable, "-m", "ground.cli", "adcs", "campaign", "--runs", str(runs), "--orbits",
                            "3", "--quiet", "--no-plots", "-o", os.path.join(d, "c")], env=env, capture_output=True,
                           text=True)
        wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
        if p.returncode not in (0, 3):
            raise RuntimeError("fps adcs campaign exit %d: %s" % (p.returncode, p.stderr[-400:]))
        with open(os.path.join(d, "c", "run_0000", "result.json")) as f:
            form_ran = json.load(f).get("truth_form")
    return wall, cpu, form_ran


@contextlib.contextmanager
def _timers(parts):
    """CPU time (s) and calls of each (owner, attribute, label) in ``parts`` while the block runs, into a dict."""
    spent, saved = defaultdict(lambda: [0.0, 0]), []
    for owner, name, label in parts:
        f = getattr(owner, name)
        saved.append((owner, name, f))

        def timed(*a, f=f, label=label, **kw):
            t = time.process_time()
            try:
                return f(*a, **kw)
            finally:
                spent[label][0] += time.process_time() - t
                spent[label][1] += 1
        setattr(owner, name, functools.wraps(f)(timed))
    try:
        yield spent
    finally:
        for owner, name, f in saved:
            setattr(owner, name, f)


def vehicle_split(orbits=3.0):
    """One campaign vehicle (``population.run_vehicle``, seed 0, two-body truth) in process: its CPU time (s), the
    parts' [CPU s, calls] (nested parts are inside their parents) and its history.npz's CPU (s) and bytes with
    ``body_pointing.save_history`` (zlib level 1) and with np.savez_compressed (zlib's default level 6)."""
    from emulator import adcs_bus, adcs_session
    from emulator.spacecraft import dynamics, environment
    from ground.adcs import app_host, body_pointing, bps_cli, flight_world, population
    from ground.adcs.options import load_spacecraft
    parts = ((bps_cli, "calibration", "calibration (the nine sets through the APKF)"),
             (scenario, "truth_grid", "the orbits' truth grid (20 Hz)"),
             (environment.SurfaceTorques, "__init__", "drag and solar pressure table"),
             (app_host, "fly", "the flight: session, 1 Hz cycles, recorder"),
             (adcs_session.AdcsSession, "cycle", "- the 1 Hz cycles"),
             (dynamics.Spacecraft, "step", "- - the truth's RK4 steps (10 Hz)"),
             (adcs_session.AdcsSession, "_burst", "- - the flight app's cycle with the sensors' packets"),
             (adcs_bus.SpacecraftBus, "burst", "- - - the sensors' packets"),
             (adcs_bus.SpacecraftBus, "apply", "- - the commands to the devices"),
             (flight_world, "_result", "the result: statistics, budget, NEES"),
             (body_pointing, "save_history", "history.npz"))
    d, _ = load_spacecraft(None, partner=True, flight=True)
    with tempfile.TemporaryDirectory() as out:
        with _timers(parts) as spent:
            c0 = time.process_time()
            population.run_vehicle(0, os.path.join(out, "run_0000"), d, vehicle="drawn", orbits=orbits,
                                   truth="two-body", cache_dir=os.path.join(out, "cache"))
            total = time.process_time() - c0
        npz = _npz_levels(body_pointing, os.path.join(out, "run_0000", "history.npz"))
    return total, [(label, spent[label]) for _, _, label in parts], npz


def _npz_levels(body_pointing, path):
    """{"level 1": (CPU s, bytes), "level 6": ...}: the history at ``path`` written again both ways."""
    with np.load(path) as z:
        hist = {k: z[k] for k in z.files}
    out = {}
    with tempfile.TemporaryDirectory() as d:
        t = time.process_time()
        body_pointing.save_history(os.path.join(d, "h.npz"), hist)
        out["level 1"] = (time.process_time() - t, os.path.getsize(os.path.join(d, "h.npz")))
    buf = io.BytesIO()
    t = time.process_time()
    np.savez_compressed(buf, **hist)
    out["level 6"] = (time.process_time() - t, len(buf.getvalue()))
    return out


def vehicle_split_form(adcs):
    """``vehicle_split`` in a process of its own with the ADCS kernels' form ``adcs`` ("python" or "c")."""
    p = subprocess.run([sys.executable, "-c", "import json\nfrom bench.bench_truth import vehicle_split\n"
                        "print(json.dumps(vehicle_split()))"], env=dict(os.environ, FPS_ADCS_KERNELS=adcs),
                       cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))), capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError("vehicle_split (%s) exit %d: %s" % (adcs, p.returncode, p.stderr[-400:]))
    return json.loads(p.stdout.strip().splitlines()[-1])


def print_split(cores):
    """The per-part table, before (the ADCS kernels' Python forms) and after (C), and the 100 vehicles that CPU
    makes over ``cores`` beside the goal."""
    from firmware.adcs import linalg
    forms = ("python", "c") if linalg.kernels is not None else ("python",)
    runs = {f: vehicle_split_form(f) for f in forms}
    after = forms[-1]
    print("\n| one campaign vehicle, 3 orbits, the truth's kernel: part | CPU (s), ADCS kernels in Python | CPU (s), "
          "in C | calls | per call in Python (us) | in C (us) |")
    print("|---|---|---|---|---|---|")
    print("| all | %.2f | %s | 1 | | |" % (runs["python"][0], "%.2f" % runs["c"][0] if "c" in runs else "not built"))
    for i, (label, (cpu, n)) in enumerate(runs["python"][1]):
        ca = runs[after][1][i][1][0]
        print("| %s | %.2f | %.2f | %d | %.0f | %.0f |" % (label, cpu, ca, n, 1e6 * cpu / max(n, 1),
                                                           1e6 * ca / max(n, 1)))
    npz = runs[after][2]
    print("\nhistory.npz written again: zlib level 1 (save_history) %.2f s, %d bytes; level 6 (np.savez_compressed) "
          "%.2f s, %d bytes." % (npz["level 1"][0], npz["level 1"][1], npz["level 6"][0], npz["level 6"][1]))
    print("\n| %d vehicles from one vehicle's CPU / %d cores | CPU a vehicle (s) | min | goal (min) |"
          % (GOAL_RUNS, cores))
    print("|---|---|---|---|")
    for f in forms:
        est = runs[f][0] * GOAL_RUNS / cores / 60.0
        print("| ADCS kernels in %s | %.1f | %.1f | %g%s |" % ("C" if f == "c" else "Python", runs[f][0], est,
                                                             GOAL_MIN, verdict(est, GOAL_MIN)))
    truth = next(cpu for label, (cpu, _) in runs[after][1] if "RK4" in label)
    print("\nWith the truth at no cost at all, %d such vehicles would take %.1f min of CPU over %d cores (the goal: "
          "%g min)." % (GOAL_RUNS, (runs[after][0] - truth) * GOAL_RUNS / cores / 60.0, cores, GOAL_MIN))
    return forms


def main():
    forms = ("python", "kernel") if kernel.available() else ("python",)
    print("| truth: CPU time of one RK4 step (dt 0.1 s unless said; best of %d) | Python form (us) | C kernel (us) "
          "| speed-up | Basilisk (us) |" % REPEATS)
    print("|---|---|---|---|---|")
    for name, make in CASES:
        us = {f: step_us(make(f), 400 if f == "python" else 4000) for f in forms}
        k = us.get("kernel")
        print("| %s | %.1f | %s | %s | %g-%g%s |" % (
            name, us["python"], "%.1f" % k if k else "not built",
            "%.0fx" % (us["python"] / k) if k else "-", BASILISK_US[0], BASILISK_US[1],
            verdict(k, BASILISK_US[0]) if k else " (missed: no kernel)"))
    cores = os.cpu_count() or 1
    adcs_forms = print_split(cores)
    print("\n| %d-orbit campaign, %d cores, the truth's kernel | vehicles | wall (s) | CPU (s) |" % (3, cores))
    print("|---|---|---|---|")
    fits = {}
    for f in adcs_forms:
        m = {}
        for runs in (CAMPAIGN_RUNS, 2 * CAMPAIGN_RUNS):
            wall, cpu, ran = m[runs] = campaign_wall(runs, f)
            print("| ADCS kernels in %s (truth: %s) | %d | %.0f | %.0f |" % ("C" if f == "c" else "Python", ran, runs,
                                                                        wall, cpu))
        fits[f] = campaign_fit(m[CAMPAIGN_RUNS], m[2 * CAMPAIGN_RUNS], CAMPAIGN_RUNS)
    print("\n| %d vehicles, %d orbits, %d cores: a line through the two campaigns | CPU a vehicle (s) | fixed CPU (s) "
          "| from the CPU / %d cores (min) | from the wall (min) | goal (min) |" % (GOAL_RUNS, 3, cores, cores))
    print("|---|---|---|---|---|---|")
    for f, (per, fixed, wall_min) in fits.items():
        est = (fixed + GOAL_RUNS * per) / cores / 60.0
        print("| ADCS kernels in %s | %.1f | %.0f | %.1f | %s | %g%s |" % (
            "C" if f == "c" else "Python", per, fixed, est, "%.1f" % wall_min if wall_min > 0 else "- (the load's)",
            GOAL_MIN, verdict(est, GOAL_MIN)))
    print("\nExtrapolated (not measured): each campaign's CPU and wall as a fixed part (the workers' start, their "
          "imports, the truth's orbits) plus a part per vehicle, fitted through the two campaigns measured (%d and %d "
          "vehicles), at %d vehicles; the CPU column assumes the cores are the campaign's alone (the verdict's), the "
          "wall column carries the machine's load." % (CAMPAIGN_RUNS, 2 * CAMPAIGN_RUNS, GOAL_RUNS))


def campaign_fit(small, large, n):
    """(CPU s a vehicle, fixed CPU s, wall min at ``GOAL_RUNS``) from campaigns of n and 2n vehicles, each
    (wall s, CPU s, truth form): the difference is n vehicles' worth, the rest of the small one is fixed."""
    per = (large[1] - small[1]) / n
    wall_per = (large[0] - small[0]) / n
    return per, small[1] - n * per, (small[0] - n * wall_per + GOAL_RUNS * wall_per) / 60.0

if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
