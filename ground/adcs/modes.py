"""The thesis world's mode log (``fps adcs bps``, Sec. 6.4): INIT until the APKF starts, HOLD (rate damping while
it converges), POINT (the PD of Eq. 6.5 on the command). The names and codes are the packet table's
(``protocol.table.ADCS_MODES``), as the flight app's. The flight world's modes are the flight app's own
(``firmware/adcs/app.py``, flown in process by ``ground/adcs/flight_world.py``): nothing of them is restated here.
"""

from protocol import table

MODES = tuple(name for name, _ in sorted(table.ADCS_MODES, key=lambda m: m[1]))
MODE_CODE = dict(table.ADCS_MODES)


def time_in(changes, t_end, mode="INIT", t0=0.0):
    """Seconds spent in each mode (``MODES``) up to ``t_end``, from the mode at ``t0`` and its ``changes``
    ({"t_s", "from", "to"} each, in time order)."""
    out = dict.fromkeys(MODES, 0.0)
    t = t0
    for c in changes:
        out[mode] += c["t_s"] - t
        t, mode = c["t_s"], c["to"]
    out[mode] += float(t_end) - t
    return out


class ModeLog:
    """The flight software's mode and its history: ``changes`` holds one {"t_s", "from", "to", "reason"} per
    change; ``time_in(t_end)`` the seconds spent in each mode up to ``t_end``."""

    def __init__(self, mode="INIT", t=0.0):
        self.mode = mode
        self.t0 = float(t)
        self.changes = []

    def set(self, mode, t, reason):
        if mode not in MODES:
            raise ValueError("unknown mode %r (modes: %s)" % (mode, ", ".join(MODES)))
        if mode != self.mode:
            self.changes.append({"t_s": float(t), "from": self.mode, "to": mode, "reason": reason})
            self.mode = mode

    def time_in(self, t_end):
        return time_in(self.changes, t_end, self.changes[0]["from"] if self.changes else self.mode, self.t0)
