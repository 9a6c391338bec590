"""``fps protocol``: table/PROTOCOL.md, JSON, DBC, encode and decode round trips, clear errors."""

import json
import os
import random

import cantools
import pytest

from ground import cli
from protocol import can as canmap
from protocol import core, host
from protocol import cli as pcli
from tests import fuzz_frames

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def fps(capsys, *args):
    rc = cli.main(["protocol"] + list(args))
    out, err = capsys.readouterr()
    return rc, out, err


def test_protocol_md_is_fresh(capsys):
    rc, out, _ = fps(capsys, "table")
    assert rc == 0
    with open(os.path.join(ROOT, "protocol", "PROTOCOL.md")) as f:
        assert f.read() == out, "protocol/PROTOCOL.md is stale: run make protocol-doc"
    for must in ("## Serial framing", "## CAN", "| 28..26 | priority", "## Nodes", "## Error codes",
                 "| 0x10 | CONTROLLER |", "### CTRL_STATUS"):
        assert must in out


def test_table_json_lists_every_packet_and_field(capsys):
    rc, out, _ = fps(capsys, "table", "--json")
    doc = json.loads(out)
    assert rc == 0 and doc["version"] == core.table.PROTOCOL_VERSION
    assert [p["id"] for p in doc["packets"]] == sorted(core.PACKET)
    for p in doc["packets"]:
        d = core.PACKET[p["id"]]
        assert p["name"] == d.name and p["size"] == d.size
        assert [(f["name"], f["format"], f["unit"], f["scale"]) for f in p["fields"]] == \
            [(f[0], f[1], f[2], f[3]) for f in d.fields]
        for f, decl in zip(p["fields"], d.fields):
            assert (f["min"], f["max"]) == core.field_range(decl)
    assert {n["name"]: n["address"] for n in doc["nodes"]} == core.NODE


def test_dbc_file_written_and_loadable(capsys, tmp_path, monkeypatch):
    path = tmp_path / "p.dbc"
    rc, _, _ = fps(capsys, "dbc", "-o", str(path))
    assert rc == 0 and [p.name for p in tmp_path.iterdir()] == ["p.dbc"]   # no temp file left behind
    db = cantools.database.load_file(str(path))
    assert len(db.messages) == sum(1 for p in core.PACKET if canmap.is_single(p))
    monkeypatch.chdir(tmp_path)
    rc, out, _ = fps(capsys, "dbc", "-o", "-")            # standard output, not a file named '-'
    assert rc == 0 and not os.path.exists("-")
    assert len(cantools.database.load_string(out, "dbc").messages) == len(db.messages)


def test_encode_serial_matches_library_and_decodes_back(capsys, tmp_path):
    rc, out, _ = fps(capsys, "encode", "CTRL_SETTINGS", "mode=TRACK", "rx_cmd=-100", "gain=0x4000",
                     "--src", "GROUND", "--dst", "16", "--seq", "7")
    assert rc == 0
    frame = bytes.fromhex(out.strip())
    assert frame == host.encode_packet("CTRL_SETTINGS", 0x01, 0x10, 7, mode=1, rx_cmd=-100, gain=0x4000)
    cap = tmp_path / "cap.bin"
    cap.write_bytes(b"\x00\x01junk\x00" + frame + frame[:4])
    rc, out, _ = fps(capsys, "decode", "--serial", str(cap))
    lines = [json.loads(s) for s in out.splitlines()]
    assert lines[0]["name"] == "CTRL_SETTINGS" and lines[0]["seq"] == 7 and lines[0]["dst"] == "CONTROLLER"
    assert lines[0]["fields"]["mode"] == 1 and lines[0]["fields"]["rx_cmd"] == -100
    assert lines[1]["summary"]["frames"] == 1 and lines[1]["summary"]["drops"]["bad_cobs"] == 1


def test_encode_can_then_decode_candump_log_every_packet(capsys, tmp_path):
    rng = random.Random(8)
    log = []
    want = []
    for pid in sorted(core.PACKET):
        values = fuzz_frames.random_fields(core.PACKET[pid], rng)
        args = ["%s=%s" % (k, v.hex() if isinstance(v, bytes) else repr(v)) for k, v in values.items()]
        rc, out, _ = fps(capsys, "encode", core.PACKET[pid].name, *args, "--can", "--src", "BENCH",
                         "--dst", "0x10")
        assert rc == 0
        lines = out.splitlines()
        assert len(lines) == (1 if canmap.is_single(pid) else len(canmap.encode_packet(pid, 0x20, 0x10, values)))
        log += lines
        want.append((core.PACKET[pid].name, values))
    log.insert(3, "not a candump line")
    path = tmp_path / "can.log"
    path.write_text("\n".join(log) + "\n")
    rc, out, _ = fps(capsys, "decode", "--can", str(path))
    rows = [json.loads(s) for s in out.splitlines()]
    summary = rows.pop()["summary"]
    assert summary["frames"] == len(core.PACKET) and summary["drops"]["bad_line"] == 1
    assert summary["dropped"] == 1
    for row, (name, values) in zip(rows, want):
        exp = dict((k, v.hex() if isinstance(v, bytes) else v) for k, v in values.items())
        if "length" in exp:
            exp["data"] = exp["data"][:2 * exp["length"]]
        assert (row["name"], row["src"], row["dst"], row["seq"], row["fields"]) == \
            (name, "BENCH", "CONTROLLER", None, exp)


@pytest.mark.parametrize("args, message", [
    (["encode", "TICK", "vs=5000"], "TICK.vs = 5000 out of range [0, 4095]"),
    (["encode", "NOPE"], "unknown packet name 'NOPE'"),
    (["encode", "TICK", "foo=1"], "TICK has no field 'foo'"),
    (["encode", "TICK", "vx"], "expected FIELD=VALUE, got 'vx'"),
    (["encode", "TICK", "vx=abc"], "TICK.vx: cannot read 'abc' as a number"),
    (["encode", "TICK", "--dst", "MARS"], "unknown node 'MARS'"),
    (["encode", "TICK", "--dst", "300"], "node address 300 out of range [0, 255]"),
    (["encode", "TICK", "--seq", "256"], "--seq 256 out of range [0, 255]"),
])
def test_encode_errors_are_clear(capsys, args, message):
    rc, out, err = fps(capsys, *args)
    assert rc == 2 and out == "" and message in err


def test_node_arg_accepts_names_and_numbers():
    assert pcli.node_arg("CONTROLLER") == pcli.node_arg("controller") == pcli.node_arg("16") == 0x10
    assert pcli.node_arg("0xff") == 0xFF
