"""Every encoder refuses non-finite floats and floats beyond a field's range (float32, or the table's bounds),
with a ValueError naming packet, field and value: the pure core, the host path, CAN, a link's send, the
``fps protocol encode`` command and the core under MicroPython."""

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ground import cli
from protocol import can as canmap
from protocol import core, host, link
from tests.test_firmware_mp import run_mp

FLOAT_FIELDS = [(p.name, f) for p in core.PACKET.values() for f in p.fields if f[1] in ("f", "d")]


def _bounds(f):
    lo, hi = core.field_range(f)
    return (-core.FLOAT32_MAX if lo is None else lo), (core.FLOAT32_MAX if hi is None else hi)


def _bad_values(f):
    lo, hi = _bounds(f)
    out = [math.inf, -math.inf, 1e40, -1e40, 3.4028236e38, 10 ** 400, -10 ** 400]
    if f[4] is not None:
        out += [lo - 1e-3, lo * 2 - 1]
    if f[5] is not None:
        out += [hi + 1e-3, hi * 2 + 1]
    return out


def test_every_float_field_is_covered():
    assert len(FLOAT_FIELDS) >= 10 and {n for n, _ in FLOAT_FIELDS} >= {"RW_CMD", "RW_TLM", "STARTRACKER",
                                                                          "BEACON"}


@pytest.mark.parametrize("name, f", FLOAT_FIELDS, ids=["%s.%s" % (n, f[0]) for n, f in FLOAT_FIELDS])
def test_non_finite_and_out_of_range_refused_by_every_encoder(name, f):
    lo, hi = _bounds(f)
    for v in _bad_values(f) + [math.nan]:
        for enc in (lambda **kw: core.encode_payload(name, **kw),
                    lambda **kw: host.encode_packet(name, 1, 2, 0, **kw),
                    lambda **kw: canmap.encode_packet(name, 1, 2, **kw),
                    lambda **kw: core.encode_packet(name, 1, 2, 0, **kw)):
            with pytest.raises(ValueError) as e:
                enc(**{f[0]: v})
            msg = str(e.value)
            assert msg.startswith("%s.%s" % (name, f[0])), msg
            if v == v:
                assert msg.endswith("out of range [%r, %r]" % (lo, hi)), msg
    for v in (lo, hi, 0.0):
        payload = core.encode_payload(name, **{f[0]: v})
        assert core.payload_dict(core.PACKET_ID[name], payload)[f[0]] == struct.unpack("<f", struct.pack(
            "<f", v))[0]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(FLOAT_FIELDS), st.floats(allow_nan=True, allow_infinity=True, width=64))
def test_hypothesis_any_double_encodes_or_is_refused_cleanly(nf, v):
    """Any double either encodes (finite, within the field's range, and decodes to its float32 rounding) or
    is refused with a ValueError; never OverflowError or struct.error, never inf/nan on the wire."""
    name, f = nf
    lo, hi = _bounds(f)
    try:
        payload = core.encode_payload(name, **{f[0]: v})
    except ValueError as e:
        assert not (math.isfinite(v) and lo <= v <= hi), (v, e)
        assert str(e).startswith("%s.%s" % (name, f[0]))
        return
    assert math.isfinite(v) and lo <= v <= hi
    got = core.payload_dict(core.PACKET_ID[name], payload)[f[0]]
    assert math.isfinite(got) and got == struct.unpack("<f", struct.pack("<f", v))[0]


def test_link_send_refuses():
    lk = link.open_link("inproc", "ADCS")
    try:
        with pytest.raises(ValueError, match=r"RW_CMD\.torque = inf out of range"):
            lk.send("RW_CMD", "RW0", torque=math.inf)
    finally:
        lk.close()


@pytest.mark.parametrize("text", ["1e40", "-1e40", "inf", "-inf", "nan", "infinity", "3.5e38", "1e309"])
def test_fps_protocol_encode_prints_a_clear_error(capsys, text):
    rc = cli.main(["protocol", "encode", "RW_CMD", "torque=" + text])
    out, err = capsys.readouterr()
    assert rc in (1, 2) and out == ""
    assert "Traceback" not in err and "fps protocol: error: RW_CMD.torque" in err, err


def test_micropython_core_refuses_the_same():
    res = run_mp("protocol_floats.py")
    assert res["cases"] == ["RW_CMD.torque"] * 5 + ["RW_TLM.speed", "STARTRACKER.q0", "BEACON.uz"]
    assert res["max_ok"] == core.encode_payload("RW_CMD", torque=core.FLOAT32_MAX, enable=1).hex()
