"""Edges of protocol/ and emulator/ found in review: files, bad input, the packet table as the one contract,
the orbit truth cache and the emulator's README. The links' edges are in tests/test_protocol_link_edges.py, the
bench's serve and the ADCS session's in tests/test_emulator_serve_and_session_edges.py."""

import json
import os
import stat

import pytest

from emulator.fileio import write_json
from ground.cli import main as fps


# --- files people keep: written atomically with the umask's permissions -----------------------------------
def test_dbc_and_emulator_json_get_the_umask_not_mkstemps_0600(tmp_path):
    old = os.umask(0o022)
    try:
        assert fps(["protocol", "dbc", "-o", str(tmp_path / "fps.dbc")]) == 0
        write_json(str(tmp_path / "summary.json"), {"complete": True}, make_folder=False)
    finally:
        os.umask(old)
    for name in ("fps.dbc", "summary.json"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644, name
    assert json.loads((tmp_path / "summary.json").read_text()) == {"complete": True}
    assert sorted(os.listdir(tmp_path)) == ["fps.dbc", "summary.json"]      # no temp files left


def test_emulator_json_writer_fsyncs_before_the_rename(tmp_path, monkeypatch):
    p = tmp_path / "truth.json"
    write_json(str(p), {"old": 1}, make_folder=False)

    def fsync(fd):
        raise KeyboardInterrupt       # the machine stops between write and rename
    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(KeyboardInterrupt):
        write_json(str(p), {"new": 2}, make_folder=False)
    assert json.loads(p.read_text()) == {"old": 1} and os.listdir(tmp_path) == ["truth.json"]


# --- the packet table is the one contract ----------------------------------------------------------------
def test_gnss_payload_takes_its_scales_from_the_table(monkeypatch):
    from emulator import adcs_bus
    from protocol import core
    pkt = core.PACKET[core.PACKET_ID["GNSS"]]
    z = (6878137.255, -1234.5678, 42.0, 7612.3456, -0.12345, 0.0)
    names = ("x", "y", "z", "vx", "vy", "vz")
    d = core.payload_dict(pkt.id, adcs_bus.gnss_payload(5, 1, z))
    scale = dict((f[0], f[3]) for f in pkt.fields)
    assert (d["t_ms"], d["sat"]) == (5, 1)
    assert all(abs(d[n] * scale[n] - v) <= 0.5 * scale[n] for n, v in zip(names, z))
    # a table with other scales (cm -> dm, 0.1 mm/s -> mm/s): the emulator follows it, it does not restate it
    other = tuple(f[:3] + ({"m": 0.1, "m/s": 1e-3}[f[2]],) + f[4:] if f[0] in names else f for f in pkt.fields)
    monkeypatch.setattr(pkt, "fields", other)
    d = core.payload_dict(pkt.id, adcs_bus.gnss_payload(5, 1, z))
    assert [d[n] for n in names] == [68781373, -12346, 420, 7612346, -123, 0]


def test_remote_controller_counts_wrong_length_answers_instead_of_raising():
    """A link that does not check payload lengths (a test double, a new transport) hands over a short FSM_SPI
    and CTRL_STATUS: counted as bad, neither applied nor passed to the ground."""
    from emulator.lockstep import RemoteController
    from protocol import core
    rc = RemoteController(link=None)
    spi, status = core.PACKET_ID["FSM_SPI"], core.PACKET_ID["CTRL_STATUS"]
    good = core.encode_payload(spi, tick=7, n=1, w0=0x123456)
    rc._pending.extend([(spi, 0x10, 0x20, 0, good[:-1]), (status, 0x10, 0x01, 1, bytes(8)),
                        (spi, 0x10, 0x20, 2, good)])
    words, got_status = rc._sort(7)
    assert words == [0x123456] and not got_status
    assert rc.n_bad == 2 and len(rc.inbox) == 0


# --- distfile and H-table blobs: what float32 cannot hold is refused by name ------------------------------
@pytest.mark.parametrize("kw, what", [
    (dict(xs=[1e39, 0.0], ys=[0.0, 0.0]), "sample 0"),
    (dict(xs=[0.0, 0.0], ys=[0.0, -1e39]), "sample 1"),
    (dict(xs=[1.0, 0.0], ys=[0.0, 0.0], kind=0, scale=1e-50), "scale"),
    (dict(xs=[1.0, 0.0], ys=[0.0, 0.0], kind=0, scale=1e39), "scale"),
])
def test_distfile_pack_refuses_what_float32_cannot_hold(kw, what):
    from protocol import distfile
    with pytest.raises(distfile.DistfileError, match=what):
        distfile.pack(**kw)


def test_htable_pack_refuses_an_h_beyond_float32():
    from protocol import htable
    with pytest.raises(htable.HTableError, match="float32"):
        htable.pack(htable.Grid([0.0, 1.0], [0.0, 1.0], [(1e39, 0.0, 0.0, 1.0)] + [(1.0, 0.0, 0.0, 1.0)] * 3))


# --- bench config files --------------------------------------------------------------------------------------
def test_bench_config_with_a_huge_integer_is_bad_input_not_an_internal_error(tmp_path, capsys):
    p = tmp_path / "bench.json"
    p.write_text('{"laser": {"power_w": 1%s}}' % ("0" * 400))       # valid JSON, an int no float can hold
    assert fps(["emulator", "config", "--config", str(p)]) == 2
    err = capsys.readouterr().err
    assert "laser.power_w" in err and "internal error" not in err


@pytest.mark.parametrize("text, msg", [
    ('{"mems": {"full_scale_codes": 1e400}}', "mems.full_scale_codes = inf is out of range [1, 65536]"),
    ('{"mems": {"full_scale_codes": NaN}}', "mems.full_scale_codes = nan is out of range [1, 65536]"),
    ('{"board": {"adc_read_us": "5"}}', "board.adc_read_us: expected a number, got '5'"),
    ('{"laser": ' + "[" * 100000 + "]" * 100000 + "}", "its arrays and objects nest too deeply to read")])
def test_a_bad_bench_config_names_the_file_and_the_key(tmp_path, capsys, text, msg):
    p = tmp_path / "bench.json"
    p.write_text(text)
    assert fps(["emulator", "config", "--config", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "fps emulator: error: config %s: %s" % (p, msg), err


# --- the orbit truth cache -----------------------------------------------------------------------------------
def test_a_damaged_orbit_truth_cache_is_computed_again_not_trusted_or_fatal(tmp_path):
    import io

    import numpy as np

    from emulator import orbits
    t, x = orbits.truth_samples("two-body", 20.0, cache_dir=str(tmp_path))
    (path,) = [os.path.join(tmp_path, "truth_cache", n) for n in os.listdir(tmp_path / "truth_cache")]
    short = io.BytesIO()
    np.savez(short, t=t[:5], x=x[:5])
    for damage in (b"", b"not a zip file", short.getvalue()):
        with open(path, "wb") as f:
            f.write(damage)
        t2, x2 = orbits.truth_samples("two-body", 20.0, cache_dir=str(tmp_path))
        assert np.array_equal(t2, t) and np.array_equal(x2, x)
        with np.load(path) as z:                      # and the file is whole again
            assert z["x"].shape == x.shape


def test_emulator_readme_names_every_module_and_the_default_board_timing():
    import re
    root = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "emulator")
    text = open(os.path.join(root, "README.md")).read()
    listed = set(re.findall(r"^\| `(\w+\.py)` \|", text, re.M))
    assert {n for n in os.listdir(root) if n.endswith(".py") and n != "__init__.py"} <= listed
    from emulator.config import default_config
    from emulator.timing import board_timing
    t = board_timing(default_config()).as_dict()
    assert t["timing"] in text and "%.0f us" % t["land_us"] in text
    assert "%.0f, %.0f and %.0f us" % tuple(t["sample_us"]) in text


# --- fps protocol decode: one strict JSON line per packet ----------------------------------------------------
def test_decode_writes_strict_json_for_non_finite_float_fields(tmp_path, capsys):
    import struct

    from protocol import core, host
    pid = core.PACKET_ID["RW_TLM"]
    cap = tmp_path / "cap.bin"
    cap.write_bytes(host.encode_frame(pid, 0x40, 0x30, 0, struct.pack("<ff", float("nan"), float("-inf")))
                    + host.encode_frame(pid, 0x40, 0x30, 1, struct.pack("<ff", 1.5, 0.0)))
    assert fps(["protocol", "decode", "--serial", str(cap)]) == 0

    def refuse(name):
        raise ValueError("not JSON: %s" % name)
    lines = [json.loads(ln, parse_constant=refuse) for ln in capsys.readouterr().out.splitlines()]
    assert [ln["fields"] for ln in lines[:2]] == [{"speed": "nan", "torque": "-inf"}, {"speed": 1.5, "torque": 0.0}]
    assert lines[2]["summary"]["frames"] == 2
