"""Fault injection on a link's byte stream, so a team can rehearse a bad harness (host side, CPython).

``LinkFaults.parse("bytes=0.01,frames=0.05,seed=1,silence=30:2,first=1")`` describes the faults; ``FaultyPort`` wraps
a byte port (its ``read``/``write``/``close``) and applies them to the frames in both directions, below the
framing, as a noisy cable would. Two framings:

- serial (``SERIAL``): a frame is the bytes up to and including its 0x00 delimiter (COBS), under a
  ``protocol.link.SerialLink`` (``inject``);
- CAN over slcan (``SLCAN``): a frame is one Lawicel line, up to and including its CR, in the ASCII stream
  between the host and the adapter (``protocol.slcanbus``); only lines carrying a CAN frame (``T``, ``t``,
  ``R``, ``r``, after any BEL answers) are dropped, as a CAN frame lost on the bus; bit flips hit every byte.

The faults:

- ``frames=P``: each frame is dropped with probability P;
- ``first=N``: the first N frames each way are dropped (on slcan the first N CAN frame lines: a lost HELLO, a
  lost first command; the commands that open the channel pass), counted with the dropped ones;
- ``bytes=P``: each byte of a frame that passes gets one random bit flipped with probability P (a delimiter
  may be hit too, merging or splitting frames: the decoder must cope);
- ``silence=START_S:LENGTH_S``: nothing passes while the clock reads START_S <= t < START_S + LENGTH_S
  (``LENGTH_S`` ``inf`` for good). The clock is a callable set by the tool (``FaultyPort.clock``); the HIL
  sets it to the virtual seconds since the play started (None before: no silence). Several items may be given;
- ``seed=N``: the generator's seed (one ``random.Random`` per direction).

Every action is counted (``counters()``). The pattern is reproducible for a seed given the same traffic; the
traffic itself depends on timing (resends), so two runs see different faults, by design.
"""

import math
import random

from protocol.distfile import SEED_MAX

KEYS = ("bytes", "frames", "seed", "silence", "first")
FIRST_MAX = 10 ** 6        # first=N: at most this many frames dropped at the start


class LinkFaults:
    """Parsed fault settings: ``p_byte``, ``p_frame``, ``seed``, ``silences`` [(start_s, length_s)], ``first``
    (frames dropped at the start, each way)."""

    def __init__(self, p_byte=0.0, p_frame=0.0, seed=0, silences=(), first=0):
        for name, p in (("bytes", p_byte), ("frames", p_frame)):
            if not (isinstance(p, (int, float)) and 0.0 <= p < 1.0):
                raise ValueError("--link-faults %s=%r: a probability in [0, 1)" % (name, p))
        for start, length in silences:
            if not (math.isfinite(start) and start >= 0 and length > 0):
                raise ValueError("--link-faults silence=%r:%r: START_S >= 0 and LENGTH_S > 0 seconds "
                                 "(LENGTH_S may be inf)" % (start, length))
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= SEED_MAX:
            raise ValueError("--link-faults seed=%r: a whole number from 0 to 2^32 - 1, as every fps seed "
                             "(random.Random would take -1 as 1)" % (seed,))
        if isinstance(first, bool) or not isinstance(first, int) or not 0 <= first <= FIRST_MAX:
            raise ValueError("--link-faults first=%r: a whole number of frames from 0 to %d" % (first, FIRST_MAX))
        self.first = int(first)
        self.p_byte = float(p_byte)
        self.p_frame = float(p_frame)
        self.seed = int(seed)
        self.silences = [(float(a), float(b)) for a, b in silences]

    @classmethod
    def parse(cls, spec):
        """From ``bytes=P,frames=P,seed=N,silence=START_S:LENGTH_S,first=N`` (any subset, any order)."""
        kw = {"p_byte": 0.0, "p_frame": 0.0, "seed": 0, "silences": [], "first": 0}
        if not spec or not spec.strip():
            raise ValueError("--link-faults: empty; give e.g. bytes=0.01,frames=0.05,seed=1")
        for item in spec.split(","):
            key, sep, val = item.strip().partition("=")
            if not sep or key not in KEYS:
                raise ValueError("--link-faults item %r: expected KEY=VALUE with KEY one of %s"
                                 % (item, ", ".join(KEYS)))
            try:
                if key in ("seed", "first"):
                    kw[key] = int(val)
                elif key == "silence":
                    a, sep2, b = val.partition(":")
                    if not sep2:
                        raise ValueError
                    kw["silences"].append((float(a), float(b)))
                else:
                    v = float(val)
                    if not math.isfinite(v):
                        raise ValueError
                    kw["p_byte" if key == "bytes" else "p_frame"] = v
            except ValueError:
                raise ValueError("--link-faults item %r: bad value (bytes/frames: a probability, seed: an "
                                 "integer, silence: START_S:LENGTH_S in seconds, first: a number of frames)"
                                 % item) from None
        return cls(**kw)

    def describe(self):
        parts = ["bytes=%g" % self.p_byte, "frames=%g" % self.p_frame, "seed=%d" % self.seed]
        parts += ["silence=%g:%g" % s for s in self.silences]
        if self.first:
            parts.append("first=%d" % self.first)
        return ",".join(parts)

    def as_dict(self):
        return {"bytes": self.p_byte, "frames": self.p_frame, "seed": self.seed,
                "silence": [list(s) for s in self.silences], "first": self.first}


class _Direction:
    """Faults for one direction: frame drops (the first ``faults.first``, then at random), bit flips at a
    geometric distance, silence."""

    def __init__(self, faults, seed):
        self.f = faults
        self.first_left = faults.first
        self.rng = random.Random(seed)
        self.next_flip = self._gap()
        self.frames = 0
        self.dropped = 0
        self.flipped = 0
        self.silenced = 0

    def _gap(self):
        p = self.f.p_byte
        if p <= 0:
            return -1
        d = math.log(1.0 - p)
        if d == 0.0:            # p below 1.1e-16: 1 - p rounds to 1
            d = math.log1p(-p)
        g = math.log(1.0 - self.rng.random()) / d
        return int(g) if g < 1e18 else 10 ** 18    # 1e-320 would overflow int(): as good as never

    def frame(self, data, silent, droppable=True):
        """The frame as it arrives (b"" if it is lost)."""
        self.frames += 1
        if silent:
            self.silenced += 1
            return b""
        if self.first_left and droppable:
            self.first_left -= 1
            self.dropped += 1
            return b""
        if self.f.p_frame and droppable and self.rng.random() < self.f.p_frame:
            self.dropped += 1
            return b""
        if self.next_flip < 0:
            return data
        if self.next_flip >= len(data):
            self.next_flip -= len(data)
            return data
        buf = bytearray(data)
        i = self.next_flip
        while i < len(buf):
            buf[i] ^= 1 << self.rng.randrange(8)
            self.flipped += 1
            i += 1 + self._gap()
        self.next_flip = i - len(buf)
        return bytes(buf)


class Framing:
    """Where a frame ends (``delim``) and whether a frame may be dropped whole (``droppable(frame)``)."""

    def __init__(self, name, delim, droppable=None):
        self.name = name
        self.delim = delim
        self.droppable = droppable


def _slcan_frame(chunk):
    i = 0
    while i < len(chunk) and chunk[i] == 7:     # BEL answers before the line
        i += 1
    return i < len(chunk) and chunk[i] in b"TtRr"


SERIAL = Framing("serial", b"\x00")
SLCAN = Framing("slcan", b"\r", _slcan_frame)


class FaultyPort:
    """A port (``read(timeout)``, ``write(data)``, ``close()``) whose frames (``framing``) meet ``faults``
    both ways."""

    def __init__(self, port, faults, clock=None, framing=SERIAL):
        self.port = port
        self.faults = faults
        self.clock = clock
        self.framing = framing
        self.tx = _Direction(faults, faults.seed * 2 + 1)
        self.rx = _Direction(faults, faults.seed * 2 + 2)
        self._rx_part = b""
        self._tx_part = b""

    def silent(self):
        if not self.faults.silences or self.clock is None:
            return False
        t = self.clock()
        if t is None:
            return False
        return any(a <= t < a + b for a, b in self.faults.silences)

    def _pass(self, direction, data, part):
        """Whole frames of ``part + data`` through ``direction``; returns (bytes out, unfinished tail)."""
        data = part + bytes(data)
        out = []
        silent = self.silent()
        start = 0
        delim, droppable = self.framing.delim, self.framing.droppable
        while True:
            end = data.find(delim, start)
            if end < 0:
                break
            chunk = data[start:end + 1]
            out.append(direction.frame(chunk, silent, droppable is None or droppable(chunk)))
            start = end + 1
        return b"".join(out), data[start:]

    def read(self, timeout):
        data = self.port.read(timeout)
        if not data:
            return data
        out, self._rx_part = self._pass(self.rx, data, self._rx_part)
        return out

    def write(self, data):
        out, self._tx_part = self._pass(self.tx, data, self._tx_part)
        if out:
            self.port.write(out)

    def close(self):
        self.port.close()

    def counters(self):
        d = {}
        for name, s in (("tx", self.tx), ("rx", self.rx)):
            d.update({"fault_%s_frames" % name: s.frames, "fault_%s_dropped" % name: s.dropped,
                      "fault_%s_bits_flipped" % name: s.flipped, "fault_%s_silenced" % name: s.silenced})
        return d


def inject(link, faults, clock=None):
    """Wrap a ``protocol.link.SerialLink``'s port, or the Lawicel stream of a ``protocol.link.CanLink`` on an
    slcan bus (``protocol.slcanbus``), with ``faults``; returns the ``FaultyPort``."""
    port = getattr(link, "_port", None)
    if port is None:
        inj = getattr(getattr(link, "bus", None), "inject_faults", None)
        if inj is None:
            raise ValueError("--link-faults: injected on a serial link or an slcan adapter's stream only (this "
                             "link is neither)")
        return inj(faults, clock)
    fp = FaultyPort(port, faults, clock)
    link._port = fp
    return fp
