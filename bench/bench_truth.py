"""The truth's speed: microseconds per RK4 step of ``Spacecraft.step`` in its Python form and its C kernel
(``emulator.spacecraft.kernel``) beside Basilisk's 13.5-19 us per step; where one campaign vehicle's CPU time goes
(3 orbits, the kernel); and the wall time of a 3-orbit ``fps adcs campaign`` on this machine's cores beside the goal
of 100 vehicles in 15 min, extrapolated from a measured campaign of ``CAMPAIGN_RUNS`` vehicles
(``BENCH_TRUTH_RUNS``), with each form: from its wall time, and from its processes' CPU time over the cores (what
an idle machine would take; a shared machine's wall time is read against its load)."""

import contextlib
import functools
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


def campaign_wall(runs, form):
    """Wall time and CPU time (s) of ``fps adcs campaign --runs runs --orbits 3`` on all cores with the truth's
    ``form``, and the form its first run recorded."""
    env = dict(os.environ, FPS_TRUTH=form)
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
    """One campaign vehicle (``population.run_vehicle``, seed 0, two-body truth) in process: its CPU time (s) and
    the parts' [CPU s, calls] (nested parts are inside their parents)."""
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
    with tempfile.TemporaryDirectory() as out, _timers(parts) as spent:
        c0 = time.process_time()
        population.run_vehicle(0, os.path.join(out, "run_0000"), d, vehicle="drawn", orbits=orbits,
                               truth="two-body", cache_dir=os.path.join(out, "cache"))
        total = time.process_time() - c0
    return total, [(label, spent[label]) for _, _, label in parts]


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
    total, split = vehicle_split()
    print("\n| one campaign vehicle, 3 orbits, C kernel: part | CPU (s) | share | calls | per call (us) |")
    print("|---|---|---|---|---|")
    print("| all | %.2f | 100 %% | 1 | |" % total)
    for label, (cpu, n) in split:
        print("| %s | %.2f | %.0f %% | %d | %.0f |" % (label, cpu, 100 * cpu / total, n, 1e6 * cpu / max(n, 1)))
    cores = os.cpu_count() or 1
    truth = next(cpu for label, (cpu, _) in split if "RK4" in label)
    print("\nWith the truth at no cost at all, %d such vehicles would take %.1f min of CPU over %d cores (the goal: "
          "%g min)." % (GOAL_RUNS, (total - truth) * GOAL_RUNS / cores / 60.0, cores, GOAL_MIN))
    print("\n| %d-orbit campaign, %d cores | measured: %d vehicles, wall (s) | CPU (s) | %d vehicles from the wall "
          "(min) | %d vehicles from the CPU / %d cores (min) | goal (min) |"
          % (3, cores, CAMPAIGN_RUNS, GOAL_RUNS, GOAL_RUNS, cores))
    print("|---|---|---|---|---|---|")
    for f in forms:
        wall, cpu, ran = campaign_wall(CAMPAIGN_RUNS, f)
        est, est_cpu = wall * GOAL_RUNS / CAMPAIGN_RUNS / 60.0, cpu * GOAL_RUNS / CAMPAIGN_RUNS / cores / 60.0
        print("| truth: %s | %.0f | %.0f | %.1f | %.1f | %g%s |" % (ran or f, wall, cpu, est, est_cpu, GOAL_MIN,
                                                               verdict(min(est, est_cpu), GOAL_MIN)))
    print("\nExtrapolated (not measured): the measured campaign scaled by %d / %d vehicles (independent runs spread "
          "over the cores); the CPU column assumes the cores are the campaign's alone." % (GOAL_RUNS, CAMPAIGN_RUNS))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
