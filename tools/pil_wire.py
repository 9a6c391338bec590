"""The controller's link on the wire: the UART's bytes per tick (``protocol.frame.frame_bytes``: COBS and CRC-16
framing of the packet table's payloads) and the baud at which the lockstep loop closes, for a ``--runtime qemu``
run's summary.json (``target.wire``) and docs/PIL.md.

An exchange is a TICK down, the FSM_SPI up (and CTRL_STATUS, every 64th tick), in sequence: the answer goes out once
the step is done. 8N1 framing: 10 bits a byte. The loop closes at a baud when a tick's bytes on the wire and its
computation (instructions x CPI at the clock) fit within one tick period."""

from protocol import consts, frame

BITS_PER_BYTE = 10                 # 8N1: a start bit, 8 data bits, a stop bit
STANDARD_BAUDS = (115200, 230400, 460800, 921600, 1000000, 2000000, 3000000)   # the SAMD21's SERCOM: up to 3 Mbaud
USB_FS_FRAME_S = 1e-3              # USB full speed: the host polls a CDC-ACM device's bulk endpoints once a frame


def tick_bytes():
    """{"common": TICK + FSM_SPI, "status": the same + CTRL_STATUS, "mean": per tick with a status every 64th}."""
    common = frame.frame_bytes(consts.SIZES[consts.P_TICK]) + frame.frame_bytes(consts.SIZES[consts.P_FSM_SPI])
    status = common + frame.frame_bytes(consts.SIZES[consts.P_CTRL_STATUS])
    return {"common": common, "status": status, "mean": common + (status - common) / 64.0}


def least_baud(n_bytes, compute_s, period_s):
    """The least baud at which ``n_bytes`` and ``compute_s`` of computation fit in ``period_s`` (None: never)."""
    left = period_s - compute_s
    return BITS_PER_BYTE * n_bytes / left if left > 0 else None


def figures(common_insn, status_insn, rate_hz=637.8, clock_hz=48e6, cpi=1.6, baud=115200):
    """The wire's figures for a run: bytes per tick, their time at ``baud``, and the least baud (and the least
    standard one) at which a common tick and a status tick close the loop, given their instructions (None:
    unknown) at ``cpi`` and ``clock_hz``; USB full speed's bound."""
    b = tick_bytes()
    period = 1.0 / rate_hz
    out = {"bytes_per_tick": b, "bits_per_byte": BITS_PER_BYTE, "tick_s": period, "cpi": cpi, "clock_hz": clock_hz,
           "baud": baud, "wire_s_common": BITS_PER_BYTE * b["common"] / baud,
           "ticks_on_the_wire_common": BITS_PER_BYTE * b["common"] / baud / period,
           "usb_full_speed": "the host polls the bulk endpoints once a 1 ms frame: a TICK and its answer take two "
                             "frames at worst (2 ms), more than the %.3f ms tick" % (1e3 * period)}
    for kind, insn in (("common", common_insn), ("status", status_insn)):
        need = None if insn is None else least_baud(b[kind], insn * cpi / clock_hz, period)
        out["least_baud_" + kind] = need
        out["least_standard_baud_" + kind] = None if need is None else next(
            (s for s in STANDARD_BAUDS if s >= need), None)
    return out
