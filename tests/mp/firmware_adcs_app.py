# Under micropython (or CPython): replay a recorded ADCS session's sensor bursts (JSON argv[2], config argv[1])
# through the ADCS application (firmware/adcs/app.py, no CAN) and print the last status and wheel torques.
# argv[3] (optional): replay only that many cycles (bench/bench_adcs_can.py's callgrind differences).
# argv[4] == "heap": also the heap bytes per cycle (gc.mem_alloc deltas, gc off in each cycle).
import json
import sys

from firmware.adcs.app import App
from protocol import core

with open(sys.argv[1]) as fh:
    cfg = json.load(fh)
with open(sys.argv[2]) as fh:
    rec = json.load(fh)
n = int(sys.argv[3]) if len(sys.argv) > 3 else len(rec)
heap = len(sys.argv) > 4 and sys.argv[4] == "heap"
if heap:
    import gc
app = App(cfg)
hs = []
u = None
for tick, t_ms, pkts in rec[:n]:
    for pid, src, hx in pkts:
        app.on_packet(pid, src, bytes.fromhex(hx))
    if heap:
        gc.collect()
        gc.disable()
        m0 = gc.mem_alloc()
    u = app.cycle(tick, t_ms / 1000.0)
    app.commands(u)
    if heap:
        hs.append(gc.mem_alloc() - m0)
        gc.enable()
st = core.payload_dict(core.PACKET_ID["ADCS_STATUS"], app.status_payload(n - 1))
out = {"u": list(u), "status": st}
if heap:
    out["heap"] = hs
print(json.dumps(out))
