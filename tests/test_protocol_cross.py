"""Two processes exchange every packet type over each cross-process transport, byte-exact:
pty serial with the peer under the micropython binary (StreamLink) and under CPython (pyserial), and
slcan over a pty (this process is the Lawicel adapter, the peer uses python-can's slcan interface)."""

import os
import random
import subprocess
import sys

import pytest

from protocol import core, host, link
from tests import fuzz_frames

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.dirname(sys.executable)
ECHO = os.path.join(ROOT, "tests", "mp", "protocol_echo.py")

CASES = {
    "serial-micropython": ("pty", os.path.join(BIN, "micropython"), "stream:"),
    "serial-cpython-pyserial": ("pty", sys.executable, "serial:"),
    "slcan-cpython": ("slcan-pty", sys.executable, "slcan:"),
}


def start_peer(case):
    spec, exe, prefix = CASES[case]
    here = link.open_link(spec, "GROUND")
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen", PYTHONPATH=ROOT)
    proc = subprocess.Popen([exe, ECHO, prefix + here.peer_path, "CONTROLLER"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    hello = here.recv(20.0)
    if not hello:
        proc.kill()
        pytest.fail("peer did not say HELLO: %s" % (proc.communicate()[1],))
    assert hello[0][:3] == (core.PACKET_ID["HELLO"], 0x10, 0x01)
    return here, proc


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_packet_type_byte_exact_across_processes(case):
    here, proc = start_peer(case)
    rng = random.Random(sorted(CASES).index(case))
    serial = isinstance(here, link.SerialLink)
    if serial:   # damage first: the peer's decoder must count it and resync
        bad = bytearray(host.encode_packet("HELLO", 0x01, 0x10, 0, node=1))
        bad[3] ^= 0x40                          # source byte: COBS still valid, CRC not
        here.write(b"\x05junk\x00" + bytes(bad))   # a 4-byte body (too short), then the bad frame
    try:
        for rnd in range(3):
            for pid in sorted(core.PACKET):
                payload = core.encode_payload(pid, fuzz_frames.random_fields(core.PACKET[pid], rng))
                here.send(pid, "CONTROLLER", payload)
                [(p, src, dst, seq, back)] = here.recv(10.0)
                assert (p, src, dst, back) == (pid, 0x10, 0x01, payload), core.PACKET[pid].name
    finally:
        here.close()
    out, err = proc.communicate(timeout=20)   # the peer notices we left and exits
    assert proc.returncode == 0, err
    counters = dict(kv.split("=") for kv in out.split())
    n = 3 * len(core.PACKET)
    assert int(counters["frames"]) == n and int(counters["tx_frames"]) == n + 1
    drops = dict((r, int(counters.get(r, 0))) for r in core.DROP_REASONS)
    assert drops == dict((r, int(serial and r in ("too_short", "bad_crc"))) for r in core.DROP_REASONS)


@pytest.mark.parametrize("case", ["serial-micropython", "slcan-cpython"])
def test_peer_leaving_is_detected(case):
    here, proc = start_peer(case)
    proc.kill()
    proc.wait(10)
    assert here.recv(5.0) == [] and here.closed
    here.close()
