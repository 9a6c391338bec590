"""The ADCS app's telemetry and commands (MicroPython): the payloads of a cycle's replies, packed to the packet
table's formats: RW_CMD to each wheel, MTQ_CMD (flight world), and ADCS_STATUS (mode, stale sensors, counters,
estimates), in the order ``cycle_replies`` sends them."""

import struct

from firmware.adcs.apkf_lean_model import NW     # the wheels the lean ADCS flies
from protocol.consts import (FMT_ADCS_STATUS, FMT_MTQ_CMD, FMT_RW_CMD, NODE_MTQ, NODE_RW0, P_ADCS_STATUS, P_MTQ_CMD,
                             P_RW_CMD)

NEVER = 65535


def commands(u, failed, tick=0):
    """[(dst, RW_CMD payload)] of cycle ``tick``: the torque u[i] (N m) to each wheel in use, coast (enable 0) to
    a failed one (bit i of ``failed``). Every wheel is expected to answer by the next tick (a failed one too: it
    may come back)."""
    out = []
    for i in range(NW):
        en = 0 if failed & (1 << i) else 1
        out.append((NODE_RW0 + i, struct.pack(FMT_RW_CMD, u[i] if en else 0.0, en, tick & 0xFF)))
    return out


def mtq_payload(m_cmd, tick):
    """MTQ_CMD of cycle ``tick``: the dipole m_cmd (A m^2) on the three rods."""
    return struct.pack(FMT_MTQ_CMD, m_cmd[0], m_cmd[1], m_cmd[2], 1, tick & 0xFF)


def status_payload(app, tick, cycle_us=0, n_rx_drop=0, n_rx_damaged=0):
    """ADCS_STATUS of cycle ``tick`` from the app's components: the APKF's attitude and rate (the star tracker's
    fix and zero before it starts), the STKF's rA and rB, the attitude's 1 sigma, the counters (mod 2^16): the
    link's drops and, of those, the damaged ones."""
    est, hl = app.est, app.health
    a = est.apkf
    x = a.x if a is not None else app.rd.qst
    w = (x[4], x[5], x[6]) if a is not None else (0.0, 0.0, 0.0)
    X = est.xs
    age = NEVER if hl.gnss_t < 0 else min(NEVER - 1, max(0, int(app.t - hl.gnss_t)))
    m = hl.miss_rw
    return struct.pack(FMT_ADCS_STATUS, tick & 0xFFFFFFFF, app.modes.mode, hl.stale, hl.failed,
                       m[0] & 0xFFFF, m[1] & 0xFFFF, m[2] & 0xFFFF, m[3] & 0xFFFF,
                       hl.miss_st & 0xFFFF, hl.miss_gnss & 0xFFFF, hl.miss_beacon & 0xFFFF,
                       hl.n_st_invalid & 0xFFFF, hl.n_beacon_invalid & 0xFFFF, hl.n_gnss_b & 0xFFFF,
                       hl.n_refused & 0xFFFF,
                       n_rx_drop & 0xFFFF, age, x[0], x[1], x[2], x[3], w[0], w[1], w[2],
                       X[0], X[1], X[2], X[6], X[7], X[8], est.sigma_att(), cycle_us & 0xFFFFFFFF, hl.magnetic,
                       n_rx_damaged & 0xFFFF)


def cycle_replies(app, cmds, tick, host, cycle_us=0, n_rx_drop=0, n_rx_damaged=0):
    """A cycle's replies [(pid, dst, payload)]: the RW_CMDs ``cmds`` (``commands``), in the flight world the
    magnetorquers' MTQ_CMD, then the ADCS_STATUS to ``host`` that closes the cycle."""
    out = [(P_RW_CMD, dst_w, pl) for dst_w, pl in cmds]
    if app.fly:
        out.append((P_MTQ_CMD, NODE_MTQ, mtq_payload(app.act.m_cmd, tick)))
    out.append((P_ADCS_STATUS, host, status_payload(app, tick, cycle_us, n_rx_drop, n_rx_damaged)))
    return out
