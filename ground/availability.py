"""The fine loop's link availability, as a lasercom team reads a pass: the share of the play with the beam on
the partner within the requirement (the true error, not Q2's, which saturates), each outage with its start,
length, peak and cause, the time to re-acquire after each, and the pointing while in lock.

An outage is a run of samples beyond the requirement; two outages less than ``MERGE_S`` apart are one (the
beam did not stay back long enough to carry a frame). Its cause is read from the controller's telemetry
(CTRL_STATUS) at its start: the mode (SAFE and its reason, HOLD, SATURATED: the FSM on its clamp, ACQUIRE: the
beam lost, the mirror held until it is back), the beam flag (Q1 dark), or, in TRACK with the beam seen, the
disturbance beyond what the loop rejects.
"""

import numpy as np

MERGE_S = 0.05            # outages closer than this are one (s)
ADS1256_RAILS = (-0x800000, 0x7FFFFF)


def outages(t_s, radial_arcsec, requirement_arcsec, merge_s=MERGE_S):
    """(start index, end index exclusive) of each outage: samples beyond the requirement, merged across gaps
    shorter than ``merge_s``."""
    bad = np.asarray(radial_arcsec) > requirement_arcsec
    if not bad.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], bad.astype(np.int8), [0]))))
    runs = list(zip(edges[0::2].tolist(), edges[1::2].tolist()))
    merged = [runs[0]]
    for a, b in runs[1:]:
        if t_s[a] - t_s[merged[-1][1] - 1] < merge_s:
            merged[-1] = (merged[-1][0], b)
        else:
            merged.append((a, b))
    return merged


def cause(status, tick):
    """Why the beam left the requirement at ``tick``, from the last CTRL_STATUS at or before it (None: none
    received yet)."""
    from protocol import core
    st = None
    for s in status:
        if s["tick"] > tick:
            break
        st = s
    if st is None:
        return "no telemetry yet"
    mode = core.MODE_NAME.get(st["mode"], st["mode"])
    if mode == "SAFE":
        return "controller in SAFE (%s)" % core.SAFE_REASON.get(st["why"], st["why"])
    if mode == "ACQUIRE":
        return "beam off Q1: controller in ACQUIRE (%s), TRACK again once the beam is back" % (
            core.SAFE_REASON.get(st["why"], st["why"]))
    if mode == "SATURATED" or st.get("sat"):
        return "FSM on its clamp (body error beyond the FSM's range)"
    if not st.get("beam", True):
        return "beam off Q1"
    if mode != "TRACK":
        return "controller in %s" % mode
    return "disturbance beyond the loop's rejection (TRACK, beam on Q1)"


def q2_saturated(q2):
    """Q2 samples with a channel on the ADS1256's rails: their error is not the beam's."""
    q2 = np.asarray(q2)
    if q2.size == 0:
        return 0
    ch = q2[:, 2:5]
    return int(np.any((ch <= ADS1256_RAILS[0]) | (ch >= ADS1256_RAILS[1]), axis=1).sum())


UNPLAYABLE = "body error beyond the bench's P-FSM range: not playable"


def availability(t_s, truth_arcsec, requirement_arcsec, status=(), tick_of=None, unplayable=()):
    """The ``availability`` block of a summary from the true error at each Q2 sample (t_s from the play's
    start; truth (n, 2) in arcsec). ``status``: the CTRL_STATUS dicts of the play; ``tick_of(t_s)`` the tick
    at a time, to find the cause. ``unplayable``: (start, end) windows of the play the bench held at its
    P-FSM's edge: out of lock whatever the truth there says. Empty input gives None figures."""
    t = np.asarray(t_s, dtype=float)
    r = np.hypot(*np.asarray(truth_arcsec, dtype=float).reshape(-1, 2).T) if len(t) else np.zeros(0)
    held = np.zeros(len(t), bool)
    for a, b in unplayable:
        held |= (t >= a) & (t < b)
    r = np.where(held, np.inf, r)
    if len(t) == 0:
        return {"availability": None, "outages": [], "n_outages": 0, "longest_outage_s": None,
                "reacquisition_s": [], "in_lock": None}
    runs = outages(t, r, requirement_arcsec)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    out = []
    for a, b in runs:
        length = float(t[b - 1] - t[a]) + dt
        why = cause(status, tick_of(t[a])) if tick_of is not None and status else None
        if held[a:b].any():
            why = UNPLAYABLE
        peak = r[a:b][np.isfinite(r[a:b])]
        out.append({"start_s": round(float(t[a]), 4), "length_s": round(length, 4),
                    "peak_arcsec": round(float(peak.max()), 3) if peak.size else None, "ended": b < len(t),
                    "cause": why})
    lock = np.ones(len(t), bool)
    for a, b in runs:
        lock[a:b] = False
    x, y = np.asarray(truth_arcsec, dtype=float).reshape(-1, 2)[lock].T if lock.any() else (np.zeros(0),) * 2
    return {"availability": float(lock.mean()), "outages": out[:50], "n_outages": len(out),
            "longest_outage_s": max((o["length_s"] for o in out), default=0.0),
            "reacquisition_s": [o["length_s"] for o in out if o["ended"]][:50],
            "in_lock": {"samples": int(lock.sum()),
                        "std_arcsec": [float(x.std()), float(y.std())] if lock.any() else None,
                        "max_radial_arcsec": float(np.hypot(x, y).max()) if lock.any() else None}}
