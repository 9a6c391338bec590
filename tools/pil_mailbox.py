"""The controller board's mailbox (``firmware.pil_main.Meter``), read through QEMU's monitor after a run
(``tools.pil_board.read_target``): each kind of TICK exchange counted apart, with its distribution, in instructions
(``-icount shift=0``: one a virtual ns; the nRF51's TIMER0 at 16 MHz, 62.5 instructions a tick).

The kinds (``firmware.hal.stdio.K_*``): ``common`` (machine code, the cached H^-1 bin), ``bin_change``
(machine code, a new bin: the bilinear lookup in the step), ``status`` (a CTRL_STATUS tick: its FSM_SPI, then the
status packed and framed after it; machine code, ``firmware.hal.fast_status``), ``resend`` (a resent TICK answered
from the cache, bytecode: its count follows the host's load, so it is kept out of the totals), ``other`` (a TICK
the machine code leaves to the bytecode path: one after a stale TICK or a jump in the tick numbers)."""

MAGIC = 0x0C0FFEE                 # firmware.pil_main.MAGIC
KINDS = ("common", "bin_change", "status", "resend", "other")
BUCKETS = 18                      # firmware.pil_main.BUCKETS: a bucket per bit length of the ticks (0..17)
KIND_WORDS = 3 + BUCKETS
WIRE = 2 + len(KINDS) * KIND_WORDS  # firmware.pil_main._WIRE: the wire's words
WORDS = WIRE + 6
CYCLES_PER_TIMER_TICK = 100       # firmware.pil_main._CYCLES_PER_TICK: 62.5 instructions at CPI 1.6
PERIOD_CYCLES = 75259             # firmware.pil_main._PERIOD: 48 MHz / 637.8 Hz
INSN_PER_TIMER_TICK = 62.5        # firmware.hal.nrf51.INSN_PER_TICK
WHAT = ("one TICK exchange: its frame decoded, the step, the FSM_SPI framed, then CTRL_STATUS when due; the UART's own "
        "byte moves left out (firmware.hal.nrf51's machine code reads and writes: an interrupt or DMA on a board); "
        "-icount shift=0, TIMER0 at 16 MHz (62.5 instructions a tick), the clock reads taken off. By kind: common "
        "and bin_change answered in machine code (firmware.hal.fast_tick), bin_change with a new H^-1 bin; status "
        "the CTRL_STATUS ticks (machine code, firmware.hal.fast_status); resend a resent TICK answered from the cache "
        "(bytecode; left out of n, mean and max: their number follows the host's load); other the TICKs of the "
        "bytecode path. histogram: [lowest, "
        "highest instructions, count] by the duration's bit length in timer ticks")


def _kind(words, f):
    n, total, worst = words[0], words[1], words[2]
    hist = []
    for k, c in enumerate(words[3:3 + BUCKETS]):
        if c:
            lo = 0 if k == 0 else 1 << (k - 1)
            hist.append([lo * f, ((1 << k) - 1) * f, c])
    return {"n": n, "sum": total * f, "mean": total / n * f if n else None, "max": worst * f if n else None,
            "histogram": hist}


def wire(words):
    """The board's model of each tick on the wire (``firmware.pil_main.Meter.wire``): the baud, the latest
    FSM_SPI's end from its tick's start (cycles at 48 MHz, CPI 1.6) against the period, the ticks late."""
    byte, _, _, worst, late, n = words
    return {"what": "each tick (resends apart) on the bench's 637.8 Hz grid: the TICK's bytes in, the computation "
                    "(its instructions at CPI 1.6, 48 MHz) once they are in and the CPU is free, the FSM_SPI's bytes "
                    "out once the UART has sent what was queued before it (a status tick's CTRL_STATUS, packed and "
                    "sent after its FSM_SPI); 8N1, full duplex",
            "baud": round(10 * 48e6 / byte) if byte else None, "byte_cycles": byte, "period_cycles": PERIOD_CYCLES,
            "worst_cycles": worst, "worst_s": worst / 48e6, "late_ticks": late, "ticks": n}


def decode(box):
    """``instructions_per_step`` from the mailbox's words (None when the board wrote none): n, mean and max over
    the exchanges answered the first time, and ``kinds``: each kind's n, sum, mean, max and histogram."""
    if len(box) < WORDS or box[0] != MAGIC:
        return None
    f = INSN_PER_TIMER_TICK
    kinds = {name: _kind(box[2 + i * KIND_WORDS:2 + (i + 1) * KIND_WORDS], f) for i, name in enumerate(KINDS)}
    first = [kinds[k] for k in KINDS if k != "resend"]
    n = sum(k["n"] for k in first)
    if not n:
        return None
    total = sum(k["sum"] for k in first)
    fast = [kinds["common"], kinds["bin_change"]]
    nf = sum(k["n"] for k in fast)
    return {"what": WHAT, "n": n, "mean": total / n, "max": max(k["max"] or 0 for k in first),
            "resolution": f, "kinds": kinds, "wire": wire(box[WIRE:WIRE + 6]),
            "common": {"n": nf, "mean": sum(k["sum"] for k in fast) / nf if nf else None,
                       "max": max(k["max"] or 0 for k in fast) if nf else None}}
