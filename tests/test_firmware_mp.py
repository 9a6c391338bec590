"""Run the firmware's MicroPython test scripts (tests/mp/firmware_*.py) under the real ``micropython`` binary.

Each script asserts its own checks and prints one JSON line of results last; the CPython side
compares those results with its own computation where the two runtimes must agree.
"""

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MICROPYTHON = os.path.join(os.path.dirname(sys.executable), "micropython")


def run_mp(script, *args, timeout=120):
    """Run tests/mp/<script> under micropython with the repo on its path; return its last JSON line."""
    if not os.path.exists(MICROPYTHON):
        pytest.skip("micropython binary not installed in the venv")
    env = dict(os.environ, MICROPYPATH=ROOT + ":.frozen")
    p = subprocess.run([MICROPYTHON, os.path.join(ROOT, "tests", "mp", script)] + [str(a) for a in args],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, "micropython %s failed:\n%s\n%s" % (script, p.stdout, p.stderr)
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    assert lines, "micropython %s printed no result:\n%s" % (script, p.stdout)
    return json.loads(lines[-1])


def test_controller_unit_checks_and_stream_identical_to_cpython(tmp_path):
    """Under micropython: the controller's unit checks pass, the calibration JSON loads from the filesystem
    into the same fixed-point table, and a 10 s closed loop gives the same word stream (CRC-32 over every
    24-bit word) as the same code under CPython."""
    sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
    try:
        import firmware_plant as fp
    finally:
        sys.path.pop(0)
    from firmware.hinv import load_file
    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps(fp.calibration()))
    res = run_mp("firmware_controller.py", 6378, 3, cal)
    assert res["checks"] == 8
    t = load_file(str(cal))
    assert res["table"] == {"h": t.h, "ax": t.ax, "ay": t.ay, "hq": t.hq}
    sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
    try:
        import firmware_controller as fc
    finally:
        sys.path.pop(0)
    crc, last, mode = fc.closed_loop(6378, 3)
    assert (res["crc"], res["last"], res["mode"]) == (crc, last, mode)
    assert mode == 1                      # still tracking after 10 s


def test_viper_path_gives_identical_codes_and_allocates_nothing():
    """Under micropython: the viper controller and the bytecode one, fed the same inputs and packets, agree
    on every word and every state slot over 3 x 19,134 ticks (30 s each: a closed loop through a beam flicker, a
    beam loss (ACQUIRE, its hold and ramp, back to TRACK), a commanded SAFE, CALIBRATE, HOLD, gain, command and
    table changes and a sustained saturation (SATURATED and back);
    random samples with dR clamps, saturation episodes and beam-threshold edges). The word CRCs equal those of
    the bytecode controller under CPython. The viper tick allocates nothing with the heap locked."""
    ticks = 19134
    res = run_mp("firmware_viper.py", ticks)
    sys.path.insert(0, os.path.join(ROOT, "tests", "mp"))
    try:
        import firmware_viper as fv
    finally:
        sys.path.pop(0)
    cl = res["closed"]
    assert cl["ticks"] == ticks + 1 and cl["mismatch"] == 0
    assert cl["fallbacks"] < 0.2 * ticks                 # the viper code ran the common tick
    assert all(n > 0 for n in cl["mode_ticks"][1:])      # TRACK, HOLD, CALIBRATE, SAFE, SATURATED, ACQUIRE ran
    assert cl["crc"] == fv.closed_loop(ticks, 3).crc & 0xFFFFFFFF
    for name, gain, lim, sign, cmd in (("saturating", 65535, 3000, 1.0, 16384), ("moderate", 1500, 32767, -1.0, 0)):
        r = res[name]
        assert r["ticks"] == ticks + 1 and r["mismatch"] == 0 and r["n_lost"] > 0
        assert r["crc"] == fv.random_run(ticks, 7, gain, lim, sign, cmd).crc & 0xFFFFFFFF
    assert res["saturating"]["n_sat"] > ticks // 2
    assert res["saturating"]["mode_ticks"][5] > 0 and res["saturating"]["n_sat_episodes"] > 1
    assert res["moderate"]["fallbacks"] < 0.2 * ticks    # clamped dR through the viper arithmetic
    assert res["alloc_bytes"] == 0


def test_control_tick_allocates_nothing_over_10000_ticks():
    res = run_mp("firmware_alloc.py")
    assert res["ticks"] == 10000 and res["words_out"] == 4 * 10001
    assert res["alloc_bytes"] == 0                      # the board's path: tick() with the heap locked
    assert res["step_alloc_bytes"] < 256                 # step() unlocked: at most one borrowed call frame
    assert res["leak_caught"]                            # the heap lock does catch an allocation
    assert res["control_alloc_bytes"] > 10000 * 16     # the same measurement sees a tuple per iteration
    assert res["n_lost"] > 0 and res["mode"] == 4        # the beam-lost and SAFE paths ran too


def test_mpy_cross_compiles_everything_and_the_mpy_build_runs(tmp_path):
    from tools import mpy_build
    rows = mpy_build.build(str(tmp_path))
    names = [r[0] for r in rows]
    for need in ("firmware/controller.py", "firmware/hinv.py", "firmware/ad5664r.py", "protocol/core.py",
                 "protocol/distfile.py", "protocol/table.py"):
        assert need in names
    assert all(r[3] > 0 and os.path.exists(r[1]) for r in rows)
    assert not any(n.startswith("protocol/") and n[9:] in ("host.py", "link.py", "can.py") for n in names)
    # the compiled firmware (not the sources) runs the controller checks under micropython
    env = dict(os.environ, MICROPYPATH=str(tmp_path) + ":.frozen")
    p = subprocess.run([MICROPYTHON, os.path.join(ROOT, "tests", "mp", "firmware_controller.py"), "200", "1"],
                       cwd=os.path.join(ROOT, "tests", "mp"), env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout.splitlines()[-1])["checks"] == 8
    # and the viper controller's .mpy (native code for this port) matches the compiled bytecode one
    assert os.path.exists(os.path.join(str(tmp_path), "firmware", "controller_viper.mpy"))
    p = subprocess.run([MICROPYTHON, os.path.join(ROOT, "tests", "mp", "firmware_viper.py"), "3000"],
                       cwd=os.path.join(ROOT, "tests", "mp"), env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    res = json.loads(p.stdout.splitlines()[-1])
    assert res["closed"]["mismatch"] == 0 and res["closed"]["fallbacks"] < 1000 and res["moderate"]["mismatch"] == 0


def test_the_boards_machine_code_tick_answers_as_the_bytecode_path():
    """Under micropython: a board's link with the common TICK in machine code (firmware.hal.fast_tick) answers a
    stream with a resend, a gap, a stale TICK, a damaged frame, a sequence gap, a TICK beyond the ADC, one to
    another node and one broadcast, a settings change, a new session and an oversized frame with the same bytes,
    controller state, link counters and telemetry as the bytecode path; it answers most ticks itself, and the
    common tick allocates nothing with the heap locked, new H^-1 bins included."""
    res = run_mp("firmware_fast_tick.py", 1300)
    assert res["same"] == {"bytes": True, "state": True, "counters": True, "telemetry": True}, res
    c = res["counters"]
    assert c["bad_crc"] == 1 and c["oversize"] == 1 and c["seq_gaps"] >= 2 and res["n_dup"] == 1 and res["n_gap"] == 3
    assert res["mode"] == 1 and res["answered_fast"] > 0.9 * res["frames"]
    ok, bins = res["locked"]
    assert ok == 598 and bins > 10


def test_the_viper_player_writes_the_bytecode_players_codes():
    """Under micropython: the viper player (firmware/player_viper.py) writes the codes of the bytecode Player on
    every update of loop and one-shot plays, in blocks of 1, 7 and 64, with a phase of fixed steps (shift 0) and
    one divided per code (shift > 0), float32 and int32 distfiles, through the DAC's clip at steps."""
    runs = run_mp("firmware_player_viper.py")["runs"]
    assert len(runs) == 24 and all(r["bad"] == 0 for r in runs), [r for r in runs if r["bad"]]
    assert {r["shift"] for r in runs} == {0, 2} and all(r["n"] >= 12000 for r in runs)
    assert all(0 < r["clipped"] < r["n"] // 10 for r in runs)
