"""Decoder robustness: fuzzing against a reference decoder, sequence tracking, encoder range errors."""

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import core, host
from tests import fuzz_frames


def test_fuzz_100k_cases_host_decoder():
    counts = fuzz_frames.run(100000, seed=11)
    for kind in fuzz_frames.KINDS:   # every kind of damage was exercised ...
        assert counts[kind] > 1000, kind
    for reason in core.DROP_REASONS:  # ... and every drop reason was hit
        assert counts["drop_" + reason] > 100, reason


def test_fuzz_20k_cases_pure_decoder():
    counts = fuzz_frames.run(20000, seed=12, decoder_cls=core.Decoder)
    assert counts["packets"] > 20000


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=1500), st.integers(1, 300))
def test_decoder_never_raises_and_matches_reference(data, chunk):
    dec = host.Decoder()
    got = []
    for i in range(0, len(data), chunk):
        got += dec.feed(data[i:i + chunk])
    ref, drops = fuzz_frames.reference_decode(data)
    assert got == ref
    assert dict((r, dec.drops[r]) for r in core.DROP_REASONS) == drops


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(sorted(core.PACKET)), st.randoms(use_true_random=False), st.integers(0, 255))
def test_random_valid_fields_round_trip(pid, rng, seq):
    pkt = core.PACKET[pid]
    values = fuzz_frames.random_fields(pkt, rng)
    frame = host.encode_packet(pid, 0x20, 0x10, seq, values)
    [(p, src, dst, q, payload)] = core.Decoder().feed(frame)
    assert (p, src, dst, q) == (pid, 0x20, 0x10, seq)
    assert core.payload_dict(pid, payload) == values


def test_sequence_gaps_and_duplicates_per_source():
    dec = host.Decoder()
    pay = core.encode_payload("ACK")
    stream = b"".join(host.encode_frame(0x02, src, 0x01, seq, pay)
                      for src, seq in ((0x10, 254), (0x10, 255), (0x10, 2), (0x20, 7), (0x10, 2), (0x20, 8),
                                       (0x10, 100), (0x10, 99), (0x10, 100)))
    assert len(dec.feed(stream)) == 9
    # 255 -> 2 wraps and misses 0, 1; 2 -> 100 misses 97; a step back (100 -> 99) is late, not a gap
    assert dec.gaps == {0x10: 2 + 97}
    assert dec.dups == {0x10: 1}
    c = dec.counters()
    assert (c["seq_gaps"], c["seq_dups"], c["frames"]) == (99, 1, 9)


@pytest.mark.parametrize("name", sorted(core.PACKET_ID))
def test_out_of_range_values_name_field_value_and_range(name):
    pkt = core.packet_def(name)
    rng = random.Random(5)
    tested = 0
    for f in pkt.fields:
        lo, hi = core.field_range(f)
        if f[1].endswith("s"):
            with pytest.raises(ValueError, match=r"%s\.%s" % (name, f[0])):
                core.encode_payload(name, **{f[0]: bytes(int(f[1][:-1]) + 1)})
            tested += 1
            continue
        for bad in ([hi + rng.randint(1, 9)] if hi is not None else []) + ([lo - 1] if lo is not None else []):
            with pytest.raises(ValueError) as e:
                host.encode_packet(name, 1, 2, 0, **{f[0]: bad})
            shown = float(bad) if f[1] in "fd" else bad
            assert str(e.value) == "%s.%s = %r out of range [%r, %r]" % (name, f[0], shown, lo, hi)
            tested += 1
    assert tested or all(f[1] in "fd" and f[4] is None for f in pkt.fields)


def test_unknown_packet_and_field_names():
    with pytest.raises(ValueError, match="unknown packet name 'NOPE'"):
        core.encode_payload("NOPE")
    with pytest.raises(ValueError, match="TICK has no field 'vz'"):
        core.encode_payload("TICK", vz=1)
    with pytest.raises(ValueError, match="TICK.vx: expected an integer"):
        core.encode_payload("TICK", vx=1.5)


@pytest.mark.parametrize("argv", [["abc"], ["0"], ["2.5"], ["10", "--fast"]])
def test_make_fuzz_entry_point_refuses_bad_args_without_a_traceback(argv, capsys):
    """``python -m tests.fuzz_frames N [--pure]``: a bad N or option is a usage error (exit 2), not a
    ValueError traceback (or, for 0, a run of nothing reported as "no violations")."""
    with pytest.raises(SystemExit) as e:
        fuzz_frames.main(argv)
    assert e.value.code == 2 and "usage:" in capsys.readouterr().err


def test_make_fuzz_entry_point_takes_pure_before_or_after_n(capsys):
    """``--pure`` first used to be read as N (a ValueError traceback)."""
    assert fuzz_frames.main(["--pure", "20"]) == 0 and fuzz_frames.main(["1e1", "--pure"]) == 0
    out = capsys.readouterr().out
    assert "| pure fuzz, 20 cases" in out and "| pure fuzz, 10 cases" in out
