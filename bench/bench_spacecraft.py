"""Spacecraft emulator speed: real-time factor of a 600 s propagation, RK4 at 0.1 s, four wheels (Ch. 6 setup)."""

import time

import numpy as np

from bench import verdict
from protocol import core
from emulator.spacecraft import Spacecraft, SpacecraftDevices, WheelParams, Wheels
from emulator.spacecraft.wheels import RPM

DURATION = 600.0
DT = 0.1
GOAL = "600 s well under a minute: > 10x"


def _spacecraft(environment=True, jitter=False, dt=DT):
    wheels = Wheels(WheelParams(jitter=jitter), rng=np.random.default_rng(0))
    kw = {} if environment else dict(orbit=None)
    return Spacecraft(wheels=wheels, dt=dt, omega=np.radians([1.0, 0.0, 0.0]),
                      omega_rw=np.array([1000.0, -1500.0, 800.0, 2000.0]) * RPM, **kw)


def _run(sc, duration, devices=None):
    """Propagate; with devices, an ADCS at 1 Hz sends RW_CMD to each wheel and reads a star tracker packet."""
    adcs = core.NODE["ADCS"]
    per_s = int(round(1.0 / sc.dt))
    n = int(round(duration / sc.dt))
    t0 = time.perf_counter()
    for k in range(n):
        if devices is not None and k % per_s == 0:
            for i in range(4):
                payload = core.encode_payload("RW_CMD", torque=1e-5 * np.sin(0.01 * k + i))
                devices.handle(core.PACKET_ID["RW_CMD"], adcs, core.NODE["RW%d" % i], payload)
            devices.startracker()
        sc.step()
    return time.perf_counter() - t0, n


def main():
    rows = []
    for name, sc, dev in (
            ("body + wheels, no environment", _spacecraft(environment=False), False),
            ("+ gravity gradient + residual dipole", _spacecraft(), False),
            ("+ RW_CMD/RW_TLM x4 and STARTRACKER at 1 Hz", _spacecraft(), True)):
        wall, n = _run(sc, DURATION, SpacecraftDevices(sc) if dev else None)
        rows.append((name, DT, wall, n, GOAL))
    sc = _spacecraft(jitter=True, dt=5e-4)
    wall, n = _run(sc, 10.0)
    rows.append(("jitter on, 10 s (step must resolve 10 000 rpm)", 5e-4, wall, n, "none set"))
    print("| case | step (s) | wall (s) | us per step | real-time factor | goal |")
    print("|---|---|---|---|---|---|")
    for name, dt, wall, n, goal in rows:
        rtf = n * dt / wall
        print("| %s | %g | %.2f | %.0f | %.1fx | %s%s |" % (name, dt, wall, 1e6 * wall / n, rtf, goal,
                                                            verdict(rtf, 10.0, at_most=False) if goal == GOAL else ""))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
