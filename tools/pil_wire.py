"""The controller's link on the wire: the UART's bytes per tick (``protocol.frame.frame_bytes``: COBS and CRC-16
framing of the packet table's payloads) and the baud at which the lockstep loop closes, for a ``--runtime qemu``
run's summary.json (``target.wire``) and docs/PIL.md.

An exchange is a TICK down, the FSM_SPI up (and CTRL_STATUS, every 64th tick, after it), 8N1 framing: 10 bits a
byte, full duplex. ``schedule`` lays ticks on the bench's grid as the board's meter does
(``firmware.pil_main.Meter.wire``): the TICK's bytes in, the computation (instructions x CPI at the clock) once they
are in and the CPU is free, the FSM_SPI's bytes out once it is framed and the UART has sent what was queued before
it (a DMA channel or an interrupt sends them); a status tick's CTRL_STATUS packed after its FSM_SPI and queued
behind it. The loop closes at a baud when every FSM_SPI's last byte leaves within its tick."""

from protocol import consts, frame

BITS_PER_BYTE = 10                 # 8N1: a start bit, 8 data bits, a stop bit
STANDARD_BAUDS = (115200, 230400, 460800, 921600, 1000000, 2000000, 3000000)   # the SAMD21's SERCOM: up to 3 Mbaud
USB_FS_FRAME_S = 1e-3              # USB full speed: the host polls a CDC-ACM device's bulk endpoints once a frame


def tick_bytes():
    """{"common": TICK + FSM_SPI, "status": the same + CTRL_STATUS, "mean": per tick with a status every 64th}."""
    common = frame.frame_bytes(consts.SIZES[consts.P_TICK]) + frame.frame_bytes(consts.SIZES[consts.P_FSM_SPI])
    status = common + frame.frame_bytes(consts.SIZES[consts.P_CTRL_STATUS])
    return {"common": common, "status": status, "mean": common + (status - common) / 64.0,
            "tick": frame.frame_bytes(consts.SIZES[consts.P_TICK]),
            "fsm_spi": frame.frame_bytes(consts.SIZES[consts.P_FSM_SPI]),
            "ctrl_status": frame.frame_bytes(consts.SIZES[consts.P_CTRL_STATUS])}


def least_baud(n_bytes, compute_s, period_s):
    """The least baud at which ``n_bytes`` and ``compute_s`` of computation fit in ``period_s`` (None: never)."""
    left = period_s - compute_s
    return BITS_PER_BYTE * n_bytes / left if left > 0 else None


def schedule(ticks, baud, period_s):
    """(latest FSM_SPI end from its tick's start, ticks whose FSM_SPI ended after the tick) for ``ticks``:
    (seconds until its FSM_SPI is framed, seconds after that, a CTRL_STATUS follows), one a ``period_s``."""
    b = tick_bytes()
    byte = BITS_PER_BYTE / baud
    rx, fsm, status = b["tick"] * byte, b["fsm_spi"] * byte, b["ctrl_status"] * byte
    cpu = tx = worst = 0.0
    late = 0
    for first, rest, with_status in ticks:
        ready = max(rx, cpu) + first
        end = max(ready, tx) + fsm
        worst = max(worst, end)
        late += end > period_s
        cpu = ready + rest
        tx = max(cpu, end) + status if with_status else end
        cpu, tx = max(cpu - period_s, 0.0), max(tx - period_s, 0.0)
    return worst, late


def worst_sequence(common_s, status_s, n=64):
    """The run's worst figures in a row: ``n`` common ticks of ``common_s``, a status tick (its FSM_SPI framed
    within ``common_s``, the whole tick within ``status_s``, the status tick's largest: bounds on both), ``n``
    more."""
    c = (common_s, 0.0, False)
    return [c] * n + [(common_s, max(status_s - common_s, 0.0), True)] + [c] * n


def least_baud_worst(common_s, status_s, period_s, lo=1e4, hi=1e8):
    """The least baud (to 0.1 %) at which ``worst_sequence`` closes the loop; None: not below ``hi``."""
    ticks = worst_sequence(common_s, status_s)
    if schedule(ticks, hi, period_s)[1]:
        return None
    while hi / lo > 1.001:
        mid = (lo * hi) ** 0.5
        lo, hi = (lo, mid) if not schedule(ticks, mid, period_s)[1] else (mid, hi)
    return hi


def figures(common_insn, status_insn, rate_hz=637.8, clock_hz=48e6, cpi=1.6, baud=115200, common_max=None):
    """The wire's figures for a run: bytes per tick, their time at ``baud``, the least baud (and the least
    standard one) at which a common tick alone closes the loop (``common_insn``, its mean), and at which the run's
    worst figures in a row do (``worst_sequence``: ``common_max`` and ``status_insn``, the largest), given their
    instructions (None: unknown) at ``cpi`` and ``clock_hz``; USB full speed's bound."""
    b = tick_bytes()
    period = 1.0 / rate_hz
    out = {"bytes_per_tick": b, "bits_per_byte": BITS_PER_BYTE, "tick_s": period, "cpi": cpi, "clock_hz": clock_hz,
           "baud": baud, "wire_s_common": BITS_PER_BYTE * b["common"] / baud,
           "ticks_on_the_wire_common": BITS_PER_BYTE * b["common"] / baud / period,
           "usb_full_speed": "the host polls the bulk endpoints once a 1 ms frame: a TICK and its answer take two "
                             "frames at worst (2 ms), more than the %.3f ms tick" % (1e3 * period)}
    sec = cpi / clock_hz
    need = None if common_insn is None else least_baud(b["common"], common_insn * sec, period)
    worst = None if None in (common_max, status_insn) else least_baud_worst(common_max * sec, status_insn * sec,
                                                                            period)
    for kind, v in (("common", need), ("worst", worst)):
        out["least_baud_" + kind] = v
        out["least_standard_baud_" + kind] = None if v is None else next((s for s in STANDARD_BAUDS if s >= v), None)
    return out
