"""The flight STKF's gravity model (firmware/adcs/stkf_kernels.py) and its acceleration model (firmware/adcs/
stkf_dmc.py; docs/ADCS.md, "The flight STKF's gravity model"), per shipped spacecraft (generic-12u with a partner
10 deg behind it, ``bps.with_partner``, as bench_flight flies it), brahe truth (EGM2008 30 x 30, drag, solar
pressure, sun and moon).

1. The process noise that goes with each model, from the physics: over 2 orbits of the truth, the acceleration
   the model leaves out, a(k) = (v(k + 1) - f(x(k), 1 s)_v) / 1 s (the filter's own one-second prediction from
   the true state: its integration and its frame are in it); sigma_a its RMS per axis, tau the lag where its
   autocorrelation (both satellites, three axes) falls to 1/e, and q = 2 sigma_a^2 tau, the low-frequency
   density per axis of a first-order Gauss-Markov acceleration of that variance and correlation time. The
   white model's qa (``scenario.FLIGHT_STKF``): the largest q of the J2 model over the presets, rounded up to
   one significant figure. The markov model's (``scenario.FLIGHT_STKF_MARKOV``, ``stkf_accel`` = markov, the
   acceleration as a Gauss-Markov state): sigma_a the J2 model's largest over the presets rounded up to one
   significant figure, tau the presets' mean rounded to one significant figure.
2. The flight world's STKF consistency over the second of 2 orbits (``fps adcs bps --world flight --truth hpop
   --orbits 2``'s ``stkf_consistency``), seeds 0-3: two-body with the thesis's qa, J2 with the derived qa, J2
   with the Gauss-Markov acceleration. Goal: the 12-state NEES within its 95 % band in >= 90 % of the seconds
   (a consistent filter: ~95 %); beside it the shares below and above the band and each satellite's 6-state
   NEES in its band, and the run's CPU seconds (CPython, the whole flight world).
3. The STKF cycle's cost under MicroPython (unix port, the C kernels where built): x86-64 instructions per 1 Hz
   cycle (callgrind, cycles 20-50 of tests/mp/stkf_dmc.py differenced) of the J2 filter, white and markov,
   without SatB's GNSS (the flight world's) and with it relayed (lag 4 s: nodes generated); the rest of the app
   cycle is the same with either (docs/BENCHMARKS.md: <= 10 M per cycle).
"""

import contextlib
import json
import math
import os
import tempfile
import time
from array import array

import numpy as np

from bench import mp
from emulator.spacecraft import scenario
from firmware.adcs import stkf_kernels as K
from ground.adcs import body_pointing as bps
from ground.adcs import bps_cli, flight_world
from ground.adcs.pointing import nees, nees_band
from protocol import spacecraft as sf

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CACHE = os.path.join(ROOT, "out", "orbit_cache")
SPACECRAFT = ("thesis-3u", "generic-6u", "generic-12u")
ORBITS = 2
SEEDS = (0, 1, 2, 3)
GOAL = 0.90
GOAL_INSTR = 10e6          # the app's 1 Hz cycle (docs/BENCHMARKS.md)
CG = (20, 50)
MODELS = {"two-body": {"stkf_gravity": "two-body", "stkf_qa": K.QA_THESIS},
          "j2": dict(scenario.flight_stkf("white")), "j2-markov": dict(scenario.flight_stkf("markov"))}
ACCEL = {"j2": "white", "j2-markov": "markov"}     # the flight world's forms, flown by ``stkf_accel``


def vehicle(name):
    d = sf.load(name)
    return bps.with_partner(d) if d["partner"] is None else d


def truth(d, orbits=ORBITS, cache_dir=CACHE):
    """The hpop truth's 1 s samples (t, x (n, 2, 6)) over ``orbits`` of the vehicle ``d``: the span and cache the
    flight world's run of that length uses."""
    o = scenario.orbit_setup(d)
    k = int(math.ceil(orbits * bps.orbit_period(o["x0s"][0])))
    return scenario.orbit_truth("hpop", scenario.truth_span(k, 8.0), o, cache_dir)


def residual(x, j2):
    """The acceleration the model (``j2``: f's J2 coefficient, 0.0 two-body) leaves out of the truth's samples
    x (n, 6) 1 s apart: (v(k + 1) - f(x(k), 1 s)_v) / 1 s, (n - 1, 3) m/s^2."""
    b = array("d", bytes(48))
    out = np.zeros((len(x) - 1, 3))
    for k in range(len(x) - 1):
        b[0:6] = array("d", x[k])
        K.f(b, 0, 1.0, j2)
        out[k] = x[k + 1, 3:6] - np.asarray(b[3:6])
    return out


def noise_density(a):
    """(sigma_a, tau, q) of the residual accelerations a (n, m columns): the RMS per column (m/s^2), the first
    lag (s) where the pooled autocorrelation falls below 1/e, q = 2 sigma_a^2 tau (m^2/s^3)."""
    n = len(a)
    c0 = float(np.sum(a * a))
    tau = n
    for lag in range(1, n // 2):
        if np.sum(a[:-lag] * a[lag:]) / c0 * n / (n - lag) < math.exp(-1.0):
            tau = lag
            break
    s2 = c0 / a.size
    return math.sqrt(s2), float(tau), 2.0 * s2 * tau


def low_frequency_density(a, spans=(600, 1200)):
    """2 sigma_a^2 times the pooled autocorrelation's integral to each span (s) of the residual a (n, m): the
    low-frequency density per axis (m^2/s^3) the residual itself has, beside a Gauss-Markov fit's 2 sigma_a^2 tau."""
    n = len(a)
    c0 = float(np.sum(a * a))
    rho = [1.0] + [float(np.sum(a[:-lag] * a[lag:])) / c0 * n / (n - lag) for lag in range(1, max(spans))]
    s2 = c0 / a.size
    return [2.0 * s2 * (0.5 + sum(rho[1:span])) for span in spans]


def round_up(q):
    """q rounded up to one significant figure."""
    e = 10.0 ** math.floor(math.log10(q))
    return math.ceil(q / e - 1e-9) * e


@contextlib.contextmanager
def stkf_model(model):
    """The flight world's white STKF configuration (``scenario.FLIGHT_STKF``) set to ``MODELS[model]`` meanwhile,
    for a model no ``stkf_accel`` flies (the two-body one); nothing for the flight forms (``ACCEL``)."""
    if model in ACCEL:
        yield
        return
    saved = dict(scenario.FLIGHT_STKF)
    scenario.FLIGHT_STKF.clear()
    scenario.FLIGHT_STKF.update(MODELS[model])
    try:
        yield
    finally:
        scenario.FLIGHT_STKF.clear()
        scenario.FLIGHT_STKF.update(saved)


def round_1(x):
    """x rounded to one significant figure."""
    e = 10.0 ** math.floor(math.log10(x))
    return round(x / e) * e


def consistency(d, model, seed=0):
    """The flight world's ``stkf_consistency`` of a 2-orbit hpop run of ``d`` with the STKF ``model``, with
    ``below``, ``above`` (the 12-state NEES's shares of seconds under and over its band), ``a6``, ``b6`` (each
    satellite's 6-state NEES's share in its band, its 6 x 6 block) and ``cpu_s`` (the run's CPU seconds)."""
    params = bps_cli.calibration(seed, os.path.join(ROOT, "out", "bps_cache"), progress=False, spacecraft=d)
    period = bps.orbit_period(scenario.orbit_setup(d)["x0s"][0])
    t0 = time.process_time()
    with stkf_model(model):
        res, hist = flight_world.simulate(params=params, duration_s=ORBITS * period, seed=seed, truth="hpop",
                                          cache_dir=CACHE, spacecraft=d, stkf_accel=ACCEL.get(model, "white"))
    c = dict(res["stkf_consistency"], cpu_s=time.process_time() - t0)
    k0 = int(np.ceil(period))
    e, P = hist["fsw_stkf_x_err"][k0:], hist["fsw_stkf_P"][k0:].reshape(-1, 12, 12)
    n12 = hist["fsw_stkf_nees12_full_cov"][k0:, 0]
    n12 = n12[np.isfinite(n12)]
    lo, hi = nees_band(12, 0.95)
    c["below"], c["above"] = float(np.mean(n12 < lo)), float(np.mean(n12 > hi))
    lo, hi = nees_band(6, 0.95)
    for key, sl in (("a6", slice(0, 6)), ("b6", slice(6, 12))):
        n6 = nees(e[:, sl], P[:, sl, sl])
        n6 = n6[np.isfinite(n6)]
        c[key] = float(np.mean((n6 >= lo) & (n6 <= hi)))
    return c


def _label(model):
    m = MODELS[model]
    if m.get("stkf_accel") == "markov":
        return "%s (sigma_a %.0e, tau %.0f s)" % (model, m["stkf_sigma_a"], m["stkf_tau"])
    return "%s (%.0e)" % (model, m["stkf_qa"])


def _noise_table(vehicles):
    print("Residual acceleration beyond each model (hpop truth, %d orbits, both satellites): sigma_a per axis, "
          "autocorrelation time tau (1/e), q = 2 sigma_a^2 tau\n" % ORBITS)
    print("| spacecraft | model | sigma_a (m/s^2) | tau (s) | q (m^2/s^3) | the white filter's qa |")
    print("|---|---|---|---|---|---|")
    qs, sas, taus = [], [], []
    for name, d in vehicles:
        x = truth(d)[1]
        for model, j2 in (("two-body", 0.0), ("j2", K.J2_TERM)):
            a = np.hstack([residual(x[:, i, :], j2) for i in range(x.shape[1])])
            s, tau, q = noise_density(a)
            if model == "j2":
                qs.append(q)
                sas.append(s)
                taus.append(tau)
            print("| %s | %s | %.2e | %.0f | %.2e | %.0e |" % (name, model, s, tau, q, MODELS[model]["stkf_qa"]))
    print("\nThe J2 residual's own low-frequency density per axis, each satellite: 2 sigma_a^2 times its "
          "autocorrelation's integral to 600 s / 1200 s, beside 2 sigma_a^2 tau (m^2/s^3)\n")
    print("| spacecraft | satellite | to 600 s | to 1200 s | 2 sigma_a^2 tau |")
    print("|---|---|---|---|---|")
    for name, d in vehicles:
        x = truth(d)[1]
        for i in range(x.shape[1]):
            a = residual(x[:, i, :], K.J2_TERM)
            print("| %s | %s | %.2e | %.2e | %.2e |" % ((name, "AB"[i]) + tuple(low_frequency_density(a))
                                                        + (noise_density(a)[2],)))
    mk = MODELS["j2-markov"]
    for what, rule, flown in (("white qa (the largest q rounded up)", round_up(max(qs)), MODELS["j2"]["stkf_qa"]),
                              ("markov sigma_a (the largest rounded up)", round_up(max(sas)), mk["stkf_sigma_a"]),
                              ("markov tau (the mean rounded)", round_1(float(np.mean(taus))), mk["stkf_tau"])):
        same = "the rule's" if math.isclose(rule, flown, rel_tol=1e-9) else "**not the rule's**"
        print("\nThe J2 model's %s = %.3g; the bench flies %.3g (%s)" % (what, rule, flown, same))
    print("\nscenario.FLIGHT_STKF: %s; scenario.FLIGHT_STKF_MARKOV: %s\n" % (scenario.FLIGHT_STKF,
                                                                             scenario.FLIGHT_STKF_MARKOV))


def _consistency_table(vehicles):
    print("Flight world, %d orbits, hpop truth: the STKF's consistency over the second orbit (goal: the 12-state "
          "NEES in its 95 %% band >= %.2f; RMS error / RMS 1 sigma per part, 1 when consistent)\n" % (ORBITS, GOAL))
    print("| spacecraft | seed | model | NEES in band (goal >= %.2f) | below / above | SatA 6 / SatB 6 in band | rA | vA "
          "| rB | vB | rB error, RMS norm (m) | run CPU (s) |" % GOAL)
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    met = {m: 0 for m in MODELS}
    for name, d in vehicles:
        for seed in SEEDS:
            for model in MODELS:
                c = consistency(d, model, seed)
                share = c["nees12_full_cov"]["nees_in_band_share"]
                met[model] += share >= GOAL
                parts = ["%.2f-%.2f" % (min(c[p]["rms_over_sigma"]), max(c[p]["rms_over_sigma"]))
                         for p in ("ra", "va", "rb", "vb")]
                print("| %s | %d | %s | %.3f%s | %.3f / %.3f | %.3f / %.3f | %s | %.0f | %.1f |" % (
                    name, seed, _label(model), share, "" if share >= GOAL else " (missed)", c["below"], c["above"],
                    c["a6"], c["b6"], " | ".join(parts), float(np.sqrt(np.sum(np.square(c["rb"]["rms_error"])))),
                    c["cpu_s"]), flush=True)
    print("\nRuns meeting the goal: %s\n" % ", ".join("%s %d of %d" % (m, met[m], len(vehicles) * len(SEEDS))
                                                      for m in MODELS))


def _cost_table():
    """Instructions per STKF cycle under micropython (callgrind), white and markov, without and with SatB's GNSS."""
    from ground.adcs.lean_scenario import stkf_scenario
    script = os.path.join(ROOT, "tests", "mp", "stkf_dmc.py")
    print("\nThe STKF's 1 Hz cycle under MicroPython (unix x64 port%s; J2; callgrind, cycles %d-%d): x86-64 "
          "instructions per cycle (the app cycle's goal: <= %.0f M, docs/BENCHMARKS.md)\n"
          % (", C kernels" if os.path.exists(os.path.join(ROOT, "firmware", "adcs", "adcsk.mpy")) else "",
             CG[0], CG[1], GOAL_INSTR / 1e6))
    print("| SatB's GNSS | white (M) | markov (M) | change (M) |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        for case, label in ((1, "none (the flight world's)"), (2, "relayed, lag 4 s")):
            path = os.path.join(d, "sc%d.json" % case)
            with open(path, "w") as fh:
                json.dump(stkf_scenario(CG[1] + 1, case=case), fh)
            m = {}
            for model in ("white", "markov"):
                n = [mp.run(script, [path, model, k], callgrind=True, heap="64M") for k in CG]
                m[model] = (n[1] - n[0]) / (CG[1] - CG[0]) / 1e6
            print("| %s | %.2f | %.2f | %+.2f |" % (label, m["white"], m["markov"], m["markov"] - m["white"]),
                  flush=True)


def main():
    vehicles = [(n, vehicle(n)) for n in SPACECRAFT]
    _noise_table(vehicles)
    _consistency_table(vehicles)
    _cost_table()


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
