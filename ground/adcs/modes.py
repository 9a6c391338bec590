"""The flight app's modes as the ground's analyses read them: their names in code order and codes (the packet
table's ``protocol.table.ADCS_MODES``), and the time a run spent in each. The modes themselves are decided by the
app (``firmware/adcs/modes.py``), which both body pointing worlds fly in process: nothing of them is restated here.
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
