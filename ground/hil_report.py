"""What a fine-pointing run's summary and report say of it: the controller's mode changes and saturation episodes
from its status, the jitter's harmonics in the Q2 error, and the verdict's lines (``fps hil`` and ``fps system``
write them; ``ground.hil`` runs the loop)."""

import os

import numpy as np

from firmware.ad5664r import CODES_PER_VOLT
from firmware.controller import ACQ_TICKS, SAT_TICKS, SATURATED
from ground import report
from ground.fileio import read_json

SAT_ON = "FSM command on its clamp for %d ticks in a row" % SAT_TICKS
SAT_OFF = "FSM command off its clamp"
BEAM_BACK = "beam back on Q1 for %d ticks in a row" % ACQ_TICKS
MAX_MODE_LINES = 12       # the verdict's mode-change lines; summary.json's mode_changes holds them all


def mode_changes(rig, tick0):
    """Each mode change seen in CTRL_STATUS: time from ``tick0`` (the play's start; before it, negative), modes
    and why (SAFE's and ACQUIRE's reason from CTRL_STATUS.why, the controller's own SATURATED entry and return,
    its return from ACQUIRE when the beam is back, or commanded). Before the play only the changes the ground did
    not command (its calibration and set-up command many)."""
    from protocol import core
    out = []
    if rig is None:
        return out
    prev = None
    sat, acq, track = core.MODE["SATURATED"], core.MODE["ACQUIRE"], core.MODE["TRACK"]
    for tick, mode, why in rig.mode_log:
        if prev is not None and mode != prev:
            if mode == core.MODE["SAFE"] or mode == acq:
                reason = core.SAFE_REASON.get(why, why)
            elif mode == sat:
                reason = SAT_ON
            elif prev == sat and mode == track:
                reason = SAT_OFF
            elif prev == acq and mode == track:
                reason = BEAM_BACK
            else:
                reason = "commanded"
            if tick < tick0 and reason == "commanded":
                prev = mode
                continue
            out.append({"t_s": round((tick - tick0) / rig.rate_hz, 4), "tick": tick,
                        "from": core.MODE_NAME.get(prev, prev), "to": core.MODE_NAME.get(mode, mode),
                        "why": reason})
        prev = mode
    return out


def saturation_summary(status, rate_hz, tick0, before=None):
    """The ``saturation`` block of ``summary.json``: the fine loop's time on its FSM clamp during a play, from
    its CTRL_STATUS telemetry.

    status: decoded CTRL_STATUS dicts in tick order (``ground.rig.decode_status``; ``Recorder.status``);
    rate_hz: the control rate; tick0: the play's first tick (times count from it); before: the last CTRL_STATUS
    before the play (None: counting starts at the first of ``status``).

    Returns ``{"threshold_ticks", "threshold_s", "ticks", "seconds", "episodes", "episodes_unseen"}``: ``ticks``
    the ticks the law hit its clamp (CTRL_STATUS.n_sat, from ``before`` on); ``episodes`` each sustained
    saturation (a run of ``threshold_ticks``, the controller's SAT_TICKS, that put it in SATURATED) seen in the
    telemetry and not over before tick0, as ``{"start_tick", "start_s", "ticks", "seconds", "max_command_code",
    "ended"}``: start_s < 0 when it began before the play; ticks the controller's run length (beam-lost holds
    on the clamp included), exact when CTRL_STATUS comes at least every threshold_ticks ticks, else at least
    that; max_command_code per axis the command of largest magnitude in the episode's CTRL_STATUS (AD5664R tilt
    codes, the clamp is +-limit_code); ended false when still under way at the last CTRL_STATUS.
    ``episodes_unseen``: episodes that began and ended between two CTRL_STATUS (decim > threshold_ticks)."""
    seq = ([before] if before is not None else []) + list(status)
    out = {"threshold_ticks": SAT_TICKS, "threshold_s": round(SAT_TICKS / rate_hz, 4), "ticks": 0, "seconds": 0.0,
           "episodes": [], "episodes_unseen": 0}
    if not seq:
        return out
    out["ticks"] = n = max(0, seq[-1]["n_sat"] - seq[0]["n_sat"])
    out["seconds"] = round(n / rate_hz, 4)
    episodes, cur, prev = [], None, None
    for s in seq:
        run = s["sat_run"]
        start = s["tick"] - run + 1 if run else None
        sustained = run > 0 and (s["mode"] == SATURATED or run >= SAT_TICKS)
        new = sustained and (cur is None or start != cur["start_tick"])
        unseen = 0
        if prev is not None:   # entries into SATURATED since the last status, less one still under way here
            unseen = max(0, ((s["n_sat_episodes"] - prev["n_sat_episodes"]) & 0xFFFF) - (1 if new else 0))
            out["episodes_unseen"] += unseen
        if cur is not None and start != cur["start_tick"]:     # its run ended since the last status
            if not unseen and s["sat_last"] >= cur["ticks"]:    # sat_last is its length, none ended since
                cur["ticks"] = s["sat_last"]
            cur["ended"] = True
            cur = None
        if sustained:
            if new:
                cur = {"start_tick": start, "ticks": run, "max_command_code": [0, 0], "ended": False}
                episodes.append(cur)
            cur["ticks"] = run
            m = cur["max_command_code"]
            for a in (0, 1):
                c = int(round(s["v_cmd"][a] * CODES_PER_VOLT))
                if abs(c) > abs(m[a]):
                    m[a] = c
        prev = s
    for e in episodes:
        if e["start_tick"] + e["ticks"] <= tick0:
            continue                                            # over before the play began
        e["start_s"] = round((e["start_tick"] - tick0) / rate_hz, 4)
        e["seconds"] = round(e["ticks"] / rate_hz, 4)
        out["episodes"].append({k: e[k] for k in ("start_tick", "start_s", "ticks", "seconds", "max_command_code",
                                                  "ended")})
    return out


def jitter_harmonics(distfile_path, rec, t0_us, rig):
    """For a jitter distfile (its F.jitter.json sidecar): each wheel harmonic's amplitude in the file, as
    played (x the player kernel's gain, ``resample.player_gain``), after the FSM loop (the truth at the Q2
    instants) and the loop model's prediction (played x |S|, ground.response.LoopModel). None for other
    distfiles."""
    side = distfile_path + ".jitter.json"
    if not os.path.exists(side) or rig is None:
        return None
    try:
        j = read_json(side, "the distfile's jitter sidecar")
        freqs = [float(v) for v in j["wheel_hz"]]
        file_amp = np.asarray(j["file_amp_arcsec"], float).reshape(len(freqs), 2)
        gain = np.asarray(j["player_gain"], float)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return {"error": "%s: %s" % (side, exc)}
    q2, truth = rec.arrays()
    if len(q2) < 4 * len(freqs) + 2:
        return None
    from ground.jitter import harmonic_amplitudes
    from ground.response import LoopModel
    t = (q2[:, 1] - t0_us) * 1e-6
    after = harmonic_amplitudes(t, truth, freqs)
    fs = [f for f in freqs]
    model = np.column_stack([np.abs(LoopModel(rig.config, rig.rate_hz, 0.5, ax).s_truth(fs)) for ax in (0, 1)])
    played = file_amp * gain[:, None]
    return [{"wheel_hz": f, "file_arcsec": file_amp[i].tolist(), "played_arcsec": played[i].tolist(),
             "after_loop_arcsec": after[i].tolist(), "model_after_arcsec": (played[i] * model[i]).tolist()}
            for i, f in enumerate(freqs)]


def _nonzero(d):
    return ", ".join("%s=%s" % (k, v) for k, v in sorted(d.items()) if v not in (0, None, "", [])) or "all zero"


def wire_deadline(s):
    """A ``--runtime qemu`` run's ticks on the wire (the board's meter, ``firmware.pil_main.Meter.wire``): None for
    the other runtimes, else the board's figures with ``met``: every FSM_SPI's last byte out within its tick."""
    b = ((s.get("target") or {}).get("wire") or {}).get("board")
    if not b or not b.get("ticks"):
        return None
    return dict(b, met=not b["late_ticks"] and b["worst_cycles"] <= b["period_cycles"])


def verdict_rows(s):
    """The verdict's rows: the Q2 samples' largest radial error against the requirement (met None until the run
    completes); on the PIL board, the worst tick with the UART's bytes (``wire_deadline``)."""
    q2 = s.get("q2") or {}
    rows = [("every Q2 sample within %.2f″ (largest radial error, arcsec)" % report.REQUIREMENT_ARCSEC,
             q2.get("max_radial_arcsec"), report.REQUIREMENT_ARCSEC,
             bool(s.get("requirement_met")) if s.get("complete") else None)]
    w = wire_deadline(s)
    if w is not None:
        rows.append(("every tick's FSM_SPI out within the tick, the UART at %d baud (the board's worst, cycles at "
                     "48 MHz, CPI 1.6)" % w["baud"], w["worst_cycles"], w["period_cycles"], w["met"]))
    return rows


def report_md(s, title="fps hil: the emulated hardware in the loop (Sec. 7.5)"):
    """report.md: the verdict table, the thesis's figures beside ours, the FSM saturation and the closing
    lines."""
    from ground.verdict import table
    return "\n".join(["# " + title, ""] + table(verdict_rows(s)) + [
        report.table(s), "", report.saturation_md(s.get("saturation")), ""] +
        ["- " + line for line in verdict_lines(s)]) + "\n"


def verdict_lines(s):
    """The closing lines: requirement, beam, FSM saturation, mode changes, link faults (every run, failed or
    not). The SATURATED entries and returns are summed up in the saturation line, not listed one by one."""
    lines = []
    q2 = s.get("q2") or {}
    if s.get("error"):
        lines.append("FAILED: %s" % s["error"])
    elif s.get("interrupted"):
        lines.append("INTERRUPTED after %.1f s of virtual time: partial run, complete=false" % s["duration_s"])
    if s.get("complete"):
        if s.get("requirement_met"):
            lines.append("requirement met: all %d Q2 samples within %.2f″" % (s["q2_samples"],
                                                                            report.REQUIREMENT_ARCSEC))
        else:
            share = q2.get("within_requirement")
            lines.append("REQUIREMENT MISSED: %s of %d Q2 samples within %.2f″, largest %s″" % (
                "—" if share is None else "%.4f %%" % (100 * share), s.get("q2_samples", 0),
                report.REQUIREMENT_ARCSEC, _fmt_num(q2.get("max_radial_arcsec"))))
    w = wire_deadline(s)
    if w is not None:
        lines.append("%s: the worst tick %d cycles from its TICK's first byte to its FSM_SPI's last at %d baud, "
                     "of %d; %d of %d ticks late (the board's meter, CPI 1.6 at 48 MHz)" % (
                         "deadlines met on the wire" if w["met"] else "DEADLINE MISSED on the wire",
                         w["worst_cycles"], w["baud"], w["period_cycles"], w["late_ticks"], w["ticks"]))
    if s.get("q2_beam_lost_samples"):
        lines.append("BEAM LOST on Q2 in %d samples" % s["q2_beam_lost_samples"])
    av = s.get("availability") or {}
    if av.get("availability") is not None:
        lines.append(availability_line(av, (s.get("truth") or {}).get("max_radial_arcsec")))
    sat = s.get("saturation")
    if sat and (sat.get("episodes") or sat.get("episodes_unseen")):
        ep = sat["episodes"]
        k = len(ep) + sat.get("episodes_unseen", 0)
        text = "FSM SATURATED: %d sustained episode%s (>= %d ticks on the clamp)" % (k, "" if k == 1 else "s",
                                                                                 sat["threshold_ticks"])
        if ep:
            big = max(ep, key=lambda e: e["ticks"])
            text += ", longest %d ticks (%.2f s) from t = %.2f s%s" % (
                big["ticks"], big["seconds"], big["start_s"], "" if big["ended"] else ", still on it at the end")
        if len(ep) < k:
            text += ", %d of them between two CTRL_STATUS" % (k - len(ep))
        lines.append(text + "; %d ticks (%.2f s) on the clamp in all" % (sat["ticks"], sat["seconds"]))
    elif sat and sat.get("ticks"):
        lines.append("FSM command on its clamp for %d ticks (%.2f s) in all, never %d in a row" % (
            sat["ticks"], sat["seconds"], sat["threshold_ticks"]))
    changes = [m for m in s.get("mode_changes", [])
               if (m["from"], m["to"]) not in (("TRACK", "SATURATED"), ("SATURATED", "TRACK"))]
    for m in changes[:MAX_MODE_LINES]:
        lines.append("controller left %s for %s at t = %.2f s (%s)" % (m["from"], m["to"], m["t_s"], m["why"])
                     if m["from"] == "TRACK" else
                     "controller went from %s to %s at t = %.2f s (%s)" % (m["from"], m["to"], m["t_s"],
                                                                          m["why"]))
    if len(changes) > MAX_MODE_LINES:
        lines.append("and %d more mode changes (summary.json's mode_changes)" % (len(changes) - MAX_MODE_LINES))
    acq = acquire_line(s.get("mode_changes", []), s.get("duration_s"))
    if acq:
        lines.append(acq)
    b = (s.get("link") or {}).get("bench") or {}
    if b.get("controller_resent") or b.get("command_retries") or b.get("overruns"):
        lines.append("link: %d TICKs resent, %d command retries (normal: a frame that came late or damaged is sent "
                     "again while the clock waits, so no tick is lost), %d overruns (ticks the mirror held)" % (
                         b.get("controller_resent", 0), b.get("command_retries", 0), b.get("overruns", 0)))
    return lines


def acquire_line(changes, duration_s):
    """One line on the beam's losses during the play: how often the controller entered ACQUIRE, for how long in
    all and at most, and whether TRACK came back each time (None: never in ACQUIRE during the play)."""
    spans, start = [], None
    for m in changes:
        if m["to"] == "ACQUIRE":
            start = max(0.0, m["t_s"])
        elif m["from"] == "ACQUIRE" and start is not None:
            spans.append((start, m["t_s"], m["to"]))
            start = None
    if start is not None:
        spans.append((start, duration_s if duration_s is not None else start, None))
    spans = [sp for sp in spans if sp[1] >= 0]
    if not spans:
        return None
    big = max(spans, key=lambda sp: sp[1] - sp[0])
    back = sum(1 for sp in spans if sp[2] == "TRACK")
    return ("beam lost: ACQUIRE %d time%s, %.2f s in all, longest %.2f s from t = %.2f s; TRACK again %d time%s%s"
            % (len(spans), "" if len(spans) == 1 else "s", sum(b - a for a, b, _ in spans), big[1] - big[0],
               big[0], back, "" if back == 1 else "s", "" if spans[-1][2] is not None else
               ", still in ACQUIRE at the end"))


def availability_line(av, truth_max):
    """One line: the share of the play in lock on the true error, the outages, the largest true error, and
    Q2's saturated samples (whose error is the ADC's rail, not the beam's)."""
    text = "availability %.2f %% of the play within %.2f″ (true error, largest %s″)" % (
        100 * av["availability"], report.REQUIREMENT_ARCSEC, _fmt_num(truth_max))
    n = av["n_outages"]
    if n:
        big = max(av["outages"], key=lambda o: o["length_s"])
        text += ": %d outage%s, longest %.3f s from t = %.2f s, %s" % (
            n, "" if n == 1 else "s", big["length_s"], big["start_s"], big["cause"] or "cause unknown")
        if not av["outages"][-1]["ended"]:
            text += "; not re-acquired by the end"
    if av.get("q2_saturated_samples"):
        text += "; Q2 on its ADC's rails in %d samples" % av["q2_saturated_samples"]
    return text


def _fmt_num(v):
    return "—" if v is None else "%.2f" % v


def _rate(pairs, first):
    """Virtual/wall over the first (or last) 60 virtual seconds of chunks."""
    sel, acc = [], 0.0
    for v, w in (pairs if first else reversed(pairs)):
        if acc >= 60.0:
            break
        sel.append((v, w))
        acc += v
    wall = sum(w for _, w in sel)
    return acc / wall if wall > 0 else None


def _per_10s(pairs):
    out, v_acc, w_acc = [], 0.0, 0.0
    for v, w in pairs:
        v_acc += v
        w_acc += w
        if v_acc >= 10.0 - 1e-9:
            out.append(round(v_acc / w_acc, 2) if w_acc > 0 else None)
            v_acc = w_acc = 0.0
    return out
