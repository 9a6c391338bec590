"""What a run reports of its link: both sides' counters (the bench's and the controller's), for ``fps hil``,
``fps calibrate`` and ``fps system`` (below ``ground.hil`` and ``ground.calibrate``, which both use it)."""


def link_counters(rig):
    """Both sides' link counters: the bench's (lockstep, commands, decoder, injected faults) and the
    controller's as of its last CTRL_STATUS."""
    if rig is None:
        return {"bench": {}, "controller": None}
    bench = dict(rig.lockstep.counters())
    bench["command_retries"] = rig.n_cmd_retries
    bench["stale_replies"] = getattr(rig, "n_stale_replies", 0)   # late ACKs of an earlier copy, dropped
    bench["hello_tries"] = getattr(rig, "hello_tries", 0)
    st = rig.last_status
    ctl = None if st is None else {"at_tick": st["tick"], "resent_ticks_answered": st["n_dup"],
                                   "gap_ticks": st["n_gap"], "rx_frames_dropped": st["n_rx_drop"],
                                   "unknown_packets": st["n_unknown"]}
    return {"bench": bench, "controller": ctl}
