"""``fps system``'s constants and what the other parts share."""

ADCS_KINDS = ("firmware", "ground")
FIGURE = "system_pointing.png"
RUNTIMES = ("micropython", "cpython", "qemu")
LEAD_S = 2.0              # ADCS seconds simulated beyond the play: the last chunk's interpolation stencil
STENCIL_S = 0.25          # the 10 Hz samples needed beyond a distfile sample (two steps of 0.1 s, and a margin)
WAIT_S = 600.0            # longest wait for the ADCS's progress (a message other than its heartbeat)
HEARTBEAT_S = 1.0         # the ADCS process says it is alive this often, whatever it is doing
SILENT_S = 10.0           # no message at all for this long (heartbeat included): the ADCS stopped answering
START_S = 60.0            # the ADCS process's first message (its heartbeat) is due within this of its start
STOP_S = (2.0, 3.0, 2.0)  # close(): the ADCS process's time to end when asked, after SIGTERM, after SIGKILL
GOAL_RTF = 5.0            # the 600 s run >= 5x real time on 2 cores
def firmware_available():
    """True when the ADCS-on-CAN session (``emulator.adcs_session``) is part of this build."""
    import importlib.util
    return importlib.util.find_spec("emulator.adcs_session") is not None
