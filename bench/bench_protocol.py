"""Protocol benchmark: frame encode+decode throughput (host and pure paths, CPython and MicroPython)
and the round trip of a ~32-byte packet between two processes over pty serial and slcan-over-pty CAN.

Goal (issue 2): host path >= 100,000 frames/s encode+decode on one core. Reference for the round trip
(HARDWARE_FACTS, Links): a 64-byte frame between two processes over a pty, median 84 us, p99 161 us.
"""

import os
import subprocess
import sys
import time

from protocol import core, host, link

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.dirname(sys.executable)
MP_BENCH = os.path.join(ROOT, "tests", "mp", "protocol_bench.py")
ECHO = os.path.join(ROOT, "tests", "mp", "protocol_echo.py")
GOAL_HOST = 100000
RTT_PACKET = "CTRL_STATUS"   # 34-byte payload, the table's nearest to 32 bytes


def _env():
    return dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)


def rate_host(name, n):
    pkt = core.packet_def(name)
    payload = core.encode_payload(pkt.id)
    dec = host.Decoder()
    enc = host.encode_frame
    t0 = time.perf_counter()
    got = 0
    for i in range(n):
        got += len(dec.feed(enc(pkt.id, 0x20, 0x10, i & 0xFF, payload)))
    dt = time.perf_counter() - t0
    assert got == n
    return n / dt


def rate_script(exe, name, n):
    r = subprocess.run([exe, MP_BENCH, name, str(n)], capture_output=True, text=True, env=_env(), timeout=300)
    if r.returncode:
        raise RuntimeError(r.stderr.strip())
    return float(r.stdout.split()[-1])


def round_trip(spec, exe, prefix, n):
    """(median_us, p99_us) of RTT_PACKET sent and echoed back by a peer process."""
    here = link.open_link(spec, "GROUND")
    proc = subprocess.Popen([exe, ECHO, prefix + here.peer_path, "CONTROLLER"], env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        if not here.recv(20.0):
            raise RuntimeError("peer did not start: %s" % proc.stderr.read())
        payload = core.encode_payload(RTT_PACKET, tick=1)
        ts = []
        for i in range(n + n // 10):
            t0 = time.perf_counter()
            here.send(RTT_PACKET, "CONTROLLER", payload)
            if not here.recv(5.0):
                raise RuntimeError("no echo")
            if i >= n // 10:   # the first tenth warms up
                ts.append(time.perf_counter() - t0)
    finally:
        here.close()
        proc.wait(20)
    ts.sort()
    return ts[len(ts) // 2] * 1e6, ts[int(len(ts) * 0.99)] * 1e6


def main():
    mp = os.path.join(BIN, "micropython")
    print("| path | interpreter | packet | frames/s encode+decode | goal |")
    print("|---|---|---|---|---|")
    for name in ("TICK", RTT_PACKET):
        r = rate_host(name, 200000)
        print("| host (crcmod + cobs) | CPython | %s | %.0f | >= %d %s |" % (
            name, r, GOAL_HOST, "met" if r >= GOAL_HOST else "NOT met"))
        pure = rate_script(sys.executable, name, 20000)
        print("| pure core | CPython | %s | %.0f | (firmware path) |" % (name, pure))
        print("| pure core | MicroPython | %s | %.0f | (firmware path) |" % (name, rate_script(mp, name, 20000)))
    print("| host (crcmod + cobs) | MicroPython | - | n/a: crcmod and cobs are CPython packages | |")
    print()
    print("| round trip, %s (%d-byte payload), two processes | peer | median us | p99 us | reference |"
          % (RTT_PACKET, core.packet_def(RTT_PACKET).size))
    print("|---|---|---|---|---|")
    ref = "64-byte frame: median 84, p99 161 (HARDWARE_FACTS)"
    for label, spec, exe, prefix, n in (
            ("pty serial", "pty", sys.executable, "serial:", 3000),
            ("pty serial", "pty", mp, "stream:", 3000),
            ("slcan over pty (CAN, ISO-TP)", "slcan-pty", sys.executable, "slcan:", 300)):
        med, p99 = round_trip(spec, exe, prefix, n)
        peer = "%s %s" % ("MicroPython" if exe == mp else "CPython", prefix.rstrip(":"))
        print("| %s | %s | %.0f | %.0f | %s |" % (label, peer, med, p99, ref if "serial" in label else ""))


if __name__ == "__main__":
    main()
