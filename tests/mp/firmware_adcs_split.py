# Under micropython: where one 1 Hz ADCS cycle's time goes. Replays a recorded session (config argv[1], bursts
# argv[2], as firmware_adcs_app.py) through firmware/adcs/app.py and its CAN HAL (firmware/hal/slcan.py: the
# Lawicel ASCII of each burst parsed by SlcanAdapter, frames and ISO-TP reassembled by CanPort, the device
# payloads unpacked by App.on_packet; RW_CMD x4 and ADCS_STATUS (ISO-TP, its flow control given) sent as T
# lines to /dev/null). Prints JSON: microseconds per part summed over cycles [argv[3], argv[4]) (ticks_us),
# parts apkf (Estimation.run_apkf + attitude), stkf (predict + GNSS updates + get), beacon (LeanStkf.update_beacon), control
# (App.control incl. the command rate), cycle (the whole App.cycle + commands), hal.
import json
import sys

from firmware.adcs.app import App
from protocol.consts import P_ADCS_STATUS as P_STATUS
from firmware.hal.slcan import CanPort, SlcanAdapter
from protocol import can as canmap
from protocol import core
from protocol.stream import ticks_diff, ticks_us

with open(sys.argv[1]) as fh:
    cfg = json.load(fh)
with open(sys.argv[2]) as fh:
    rec = json.load(fh)
k0, k1 = int(sys.argv[3]), int(sys.argv[4])
app = App(cfg)
ad = SlcanAdapter("/dev/null")
ad.lw.is_open = True
port = CanPort(ad, "ADCS")
me, host = port.node, core.NODE["SPACECRAFT"]
HEX = "0123456789ABCDEF"
acc = {"apkf": 0, "stkf": 0, "beacon": 0, "control": 0, "cycle": 0, "hal": 0}
on = [False]


def timed(name, fn):
    def w(*a, **kw):
        if not on[0]:
            return fn(*a, **kw)
        t0 = ticks_us()
        r = fn(*a, **kw)
        acc[name] += ticks_diff(ticks_us(), t0)
        return r
    return w


app.est.run_apkf = timed("apkf", app.est.run_apkf)
app.est.attitude = timed("apkf", app.est.attitude)
app.est.run_stkf = timed("stkf", app.est.run_stkf)
app.est.stkf.update_beacon = timed("beacon", app.est.stkf.update_beacon)
app.control = timed("control", app.control)


def slcan_lines(pkts):
    """The burst as the host's Lawicel T lines (ISO-TP FF + CFs; the adapter's flow control goes out)."""
    out = bytearray()
    for pid, src, hx in pkts:
        for cid, data in canmap.encode_frames(pid, src, me, bytes.fromhex(hx)):
            out.extend(b"T%08X%d" % (cid, len(data)))
            for v in data:
                out.append(ord(HEX[v >> 4]))
                out.append(ord(HEX[v & 15]))
            out.append(13)
    return out


status_rx = canmap.can_id(P_STATUS, host, me, True)       # the channel the status's flow control comes on
FC = [(status_rx, True, bytes((0x30, 0, 0)))]


def poll_fc(timeout_ms):
    return FC


ad.poll = poll_fc
tick_pkt = core.PACKET_ID["ADCS_TICK"]
for k in range(k1):
    tick, t_ms, pkts = rec[k]
    lines = slcan_lines(pkts + [[tick_pkt, host, core.encode_payload(tick_pkt, tick=tick, t_ms=t_ms).hex()]])
    on[0] = k >= k0
    t0 = ticks_us()
    for i in range(0, len(lines), len(ad._buf)):
        chunk = lines[i:i + len(ad._buf)]
        ad._buf[0:len(chunk)] = chunk
        out = []
        ad.lw.feed(ad._buf, len(chunk), out)
        port._frames(out)
    for pid, src, dst, seq, payload in port.recv_ms(0):
        if pid != tick_pkt:
            app.on_packet(pid, src, payload)
    t1 = ticks_us()
    u = app.cycle(tick, t_ms / 1000.0)
    cmds = app.commands(u)
    t2 = ticks_us()
    for dst_w, pl in cmds:
        port.send_raw(core.PACKET_ID["RW_CMD"], me, dst_w, pl)
    port.send_raw(P_STATUS, me, host, app.status_payload(tick, 0, 0))
    t3 = ticks_us()
    if on[0]:
        acc["hal"] += ticks_diff(t1, t0) + ticks_diff(t3, t2)
        acc["cycle"] += ticks_diff(t2, t1)
acc["cycles"] = k1 - k0
acc["counters"] = port.counters()
print(json.dumps(acc))
