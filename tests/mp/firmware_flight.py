"""MicroPython: firmware/adcs/flight.py's slew, unloading law, null vector and gate on fixed inputs; prints the
results as one JSON line, for the tests to compare its MicroPython and CPython runs."""
import json
import math

from firmware.adcs import flight

DEG = math.pi / 180.0
s = flight.Slew(2.0 * DEG, 0.2 * DEG)
qc = [math.sin(0.5) * 0.6, math.sin(0.5) * -0.8, 0.0, math.cos(0.5)]
s.start([0.0, 0.0, 0.0, 1.0], qc)
wc = [0.0, 0.001, 0.0]
qr, wr = [0.0] * 4, [0.0] * 3
refs = []
n = 0
while s.active and n < 500:
    s.reference(qr, wr, qc, wc)
    refs.append(list(qr) + list(wr))
    flight.propagate(qc, list(qc), wc, 1.0)
    n += 1
m = [0.0] * 3
sat = flight.unloading(m, [2e-5, -1e-5, 3e-5], [1e-3, 2e-3, -5e-4], 2e-3, 0.3, [0.1, -0.15, 0.2])
C = [-0.577, -0.577, 0.577, 0.577, -0.577, 0.577, 0.577, -0.577, 0.577, 0.577, 0.577, 0.577]
nv = flight.null_vector(C)
P = [0.0] * 81
for i in range(9):
    P[i * 10] = 1e-8 * (i + 1)
nis = flight.nis3([1e-4, -2e-4, 5e-5], P, [1e-9, 0, 0, 0, 1e-9, 0, 0, 0, 9e-9])
print(json.dumps({"steps": n, "refs": refs, "m": m, "sat": sat, "null": nv, "nis": nis}))
