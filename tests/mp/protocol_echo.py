"""Echo peer for cross-process link tests and the benchmark; runs under CPython and MicroPython.

    protocol_echo.py SPEC NODE

SPEC ``stream:PATH`` uses ``protocol.stream.StreamLink`` (the only choice under MicroPython); any other
SPEC goes to ``protocol.link.open_link``. Announces itself with HELLO to the sender-to-be (GROUND),
then sends every packet it receives back to its source with the same id and payload, until the peer
leaves; prints its counters as one line on exit.
"""

import sys

spec, node = sys.argv[1], sys.argv[2]
if spec.startswith("stream:"):
    from protocol.stream import StreamLink
    link = StreamLink(spec[len("stream:"):], node)
    wait = 1000   # ms
else:
    from protocol.link import open_link
    link = open_link(spec, node)
    wait = 1.0    # s
link.send("HELLO", "GROUND", node=link.node)
while not link.closed:
    for p in link.recv(wait):
        link.send_raw(p[0], link.node, p[1], p[4])
c = link.counters()
print(" ".join("%s=%d" % (k, c[k]) for k in sorted(c)))
link.close()
