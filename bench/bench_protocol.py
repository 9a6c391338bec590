"""Protocol benchmark: frame encode+decode throughput (host and pure paths, CPython and MicroPython; pure
beside viper under MicroPython), the round trip of a ~32-byte packet between two processes over pty serial
and slcan-over-pty CAN, and the lockstep round trip (TICK -> FSM_SPI) against the MicroPython firmware.

Goal: host path >= 100,000 frames/s encode+decode on one core. Reference for the round trip
(measured on a 2-core machine of this kind): a 64-byte frame between two processes over a pty,
median 84 us, p99 161 us.
Goal for the MicroPython HIL: >= 12x real time at 637.8 Hz, i.e. <= 130 us per lockstep tick in all
(emulator included; the round trip here is the link and firmware share of it).
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
RATE_HZ = 637.8
GOAL_TICK_US = 1e6 / RATE_HZ / 12   # 12x real time
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


def rate_script(exe, name, n, path="pure"):
    r = subprocess.run([exe, MP_BENCH, name, str(n), path], capture_output=True, text=True, env=_env(),
                       timeout=300)
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


def lockstep_round_trip(n):
    """(median_us, p99_us) of TICK -> FSM_SPI through emulator.lockstep.RemoteController (the HIL's own
    CPython path) with the MicroPython firmware (firmware.main controller) on the pty slave."""
    from emulator.lockstep import RemoteController
    here = link.open_link("pty", "BENCH")
    env = dict(_env(), MICROPYPATH=ROOT + ":.frozen")
    proc = subprocess.Popen([os.path.join(BIN, "micropython"), "-m", "firmware.main", "controller", "--link",
                             "serial:" + here.peer_path], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    try:
        rc = RemoteController(here, timeout_s=5.0)
        if not rc.wait_peer(20.0):
            raise RuntimeError("firmware did not start: %s" % proc.stderr.read())
        ts = []
        for i in range(n + n // 10):
            t0 = time.perf_counter()
            if rc.on_tick(i, i * 1568, 2048, 2048, 1000) is None:
                raise RuntimeError("no FSM_SPI for tick %d" % i)
            if i >= n // 10:
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
        print("| pure core | MicroPython | %s | %.0f | (reference; the firmware runs viper, below) |"
              % (name, rate_script(mp, name, 20000)))
    print("| host (crcmod + cobs) | MicroPython | - | n/a: crcmod and cobs are CPython packages | |")
    print()
    print("| packet | MicroPython pure frames/s | MicroPython viper frames/s (Encoder + Decoder) | speedup "
          "| us per frame pure -> viper |")
    print("|---|---|---|---|---|")
    for name in ("TICK", "FSM_SPI", RTT_PACKET):
        pure, fast = rate_script(mp, name, 20000), rate_script(mp, name, 100000, "fast")
        print("| %s | %.0f | %.0f | %.1fx | %.1f -> %.1f |" % (name, pure, fast, fast / pure, 1e6 / pure, 1e6 / fast))
    print()
    print("| round trip, %s (%d-byte payload), two processes | peer | median us | p99 us | reference |"
          % (RTT_PACKET, core.packet_def(RTT_PACKET).size))
    print("|---|---|---|---|---|")
    ref = "64-byte frame: median 84, p99 161 (2-core reference)"
    for label, spec, exe, prefix, n in (
            ("pty serial", "pty", sys.executable, "serial:", 3000),
            ("pty serial", "pty", mp, "stream:", 3000),
            ("slcan over pty (CAN, ISO-TP)", "slcan-pty", sys.executable, "slcan:", 300)):
        med, p99 = round_trip(spec, exe, prefix, n)
        peer = "%s %s" % ("MicroPython" if exe == mp else "CPython", prefix.rstrip(":"))
        print("| %s | %s | %.0f | %.0f | %s |" % (label, peer, med, p99, ref if "serial" in label else ""))
    med, p99 = lockstep_round_trip(5000)
    print("| lockstep TICK -> FSM_SPI, pty serial (RemoteController) | MicroPython firmware.main | %.0f | %.0f "
          "| whole HIL tick <= %.0f us for 12x at %.1f Hz |" % (med, p99, GOAL_TICK_US, RATE_HZ))


if __name__ == "__main__":
    from bench.run import standalone
    standalone(main)
