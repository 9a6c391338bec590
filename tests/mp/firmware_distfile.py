# Runs under micropython: the distfile reader (protocol/distfile.py) on this runtime.
# argv: path of a distfile written by CPython. Prints a JSON line with what it read.
import io
import json
import sys

from protocol import distfile as d

path = sys.argv[1]
with open(path, "rb") as f:
    data = f.read()
whole = d.parse(data)
with open(path, "rb") as f:
    r = d.Reader(f)
    same = all(r.sample(i) == whole.sample(i) for i in range(whole.count))
    head = [r.sample(i) for i in range(3)]

# Every single-byte corruption of the header and CRC, and every truncation, is refused.
refused = 0
tried = 0
for i in list(range(d.HEADER_SIZE)) + list(range(len(data) - 4, len(data))):
    bad = bytearray(data)
    bad[i] ^= 0x41
    for parse in (d.parse, lambda b: d.Reader(io.BytesIO(b))):
        tried += 1
        try:
            parse(bytes(bad))
        except d.DistfileError:
            refused += 1
for n in (0, 10, d.HEADER_SIZE, len(data) - 1):
    tried += 1
    try:
        d.Reader(io.BytesIO(data[:n]))
    except d.DistfileError:
        refused += 1

# pack on this runtime gives the same bytes as CPython for the same samples.
xs, ys = whole.samples()
repacked = d.pack(xs, ys, period_us=whole.period_us, kind=whole.kind, scale=whole.scale,
                  source=whole.source, seed=whole.seed)
print(json.dumps({"count": whole.count, "seed": whole.seed, "source": whole.source, "period_us": whole.period_us,
                  "kind": whole.kind, "same": same, "head": head, "tried": tried, "refused": refused,
                  "repacked_equal": repacked == data}))
