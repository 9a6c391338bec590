"""The controller board's timing within a control tick (DESIGN: "The board's timing is part of the bench").

A tick starts when the board starts reading Q1. The three Q1 channels (X, Y, SUM, in that read order) are each
held by the ADC at their own instant, the arithmetic runs, and the four AD5664R words go out over SPI; the
MEMS driver takes the new command when the last word is latched (AD5664R datasheet: the 24th falling SCLK edge).

``arduino-zero`` (the default, the thesis's CtrlArduino on an Arduino Zero, Sec. 7.2): three ``analogRead``
calls in sequence with the Arduino core's default ADC set-up. One ``analogRead`` takes about 426 us (prescaler
DIV512 from 48 MHz, i.e. a 93.75 kHz ADC clock, SAMPLEN 63: 32 ADC clocks of sampling, then 7 of conversion;
the core's init() in wiring.c, arduino/ArduinoCore-samd). The input is held at the end of the sampling phase,
about 75 us (7 ADC clocks: 1 + 12/2 for 12 bits, SAMD21 datasheet's propagation delay) before the result is
ready, so channel i (0, 1, 2) is sampled at (i + 1) 426 - 75 us: 351, 777, 1203 us. The arithmetic takes
``compute_us`` = 250 us (assumed: no public figure; it and the SPI time fill the 1568 us the thesis's 637.8 Hz
loop takes) and the SPI words ``spi_us`` = 40 us (4 words of 24 bits at the core's default 4 MHz plus the
chip-select handling). The words land 3 x 426 + 250 + 40 = 1568 us after the tick start: 1217 us after the first
sample, just inside the following tick at 637.8 Hz (period 1567.9 us).

``zero-latency``: every channel sampled at the tick start and the words acting at once (the bench before the
timing model, kept for comparison and for tests that need the ideal loop).

A ``custom`` board keeps the preset's formula with the user's numbers (e.g. a fast loop that configures the ADC
itself: ``adc_read_us`` 20).
"""

TIMINGS = ("arduino-zero", "zero-latency", "custom")


class BoardTiming:
    """Sample instants (s after the tick start, X, Y, SUM) and the words' landing instant (s after the tick
    start; it may lie in a later tick). ``latency_s``: landing after the first sample."""

    def __init__(self, sample_s, land_s, name):
        self.sample_s = tuple(float(t) for t in sample_s)
        self.land_s = float(land_s)
        self.name = name
        if min(self.sample_s) < 0 or self.land_s < max(self.sample_s):
            raise ValueError("board timing %s: the words (at %.1f us) cannot land before the last sample (%.1f us)"
                             % (name, self.land_s * 1e6, max(self.sample_s) * 1e6))

    @property
    def zero(self):
        return self.land_s == 0.0 and not any(self.sample_s)

    @property
    def latency_s(self):
        return self.land_s - self.sample_s[0]

    def split(self, period_s):
        """(d, f): the words of tick k act in tick k + d, f seconds after its start. Refuses a period shorter
        than the reads (the channels must be sampled within their tick)."""
        if max(self.sample_s) >= period_s and not self.zero:
            raise ValueError("board timing %s samples Q1 until %.1f us after the tick start, longer than the "
                             "%.1f us tick (%.1f Hz): use a faster board (board.adc_read_us) or "
                             "board.timing zero-latency" % (self.name, max(self.sample_s) * 1e6, period_s * 1e6,
                                                            1.0 / period_s))
        d = int(self.land_s // period_s)
        f = self.land_s - d * period_s
        if f >= period_s * (1 - 1e-12):
            d, f = d + 1, 0.0
        return d, f

    def as_dict(self):
        return {"timing": self.name, "sample_us": [round(t * 1e6, 3) for t in self.sample_s],
                "land_us": round(self.land_s * 1e6, 3), "latency_us": round(self.latency_s * 1e6, 3)}


def board_timing(cfg):
    """The BoardTiming of a validated bench config (its ``board`` section)."""
    b = cfg["board"]
    if b["timing"] == "zero-latency":
        return BoardTiming((0.0, 0.0, 0.0), 0.0, "zero-latency")
    read, hold = b["adc_read_us"] * 1e-6, b["hold_before_end_us"] * 1e-6
    if hold >= read:
        raise ValueError("config board.hold_before_end_us must be smaller than board.adc_read_us")
    samples = [(i + 1) * read - hold for i in range(3)]
    land = 3 * read + (b["compute_us"] + b["spi_us"]) * 1e-6
    return BoardTiming(samples, land, b["timing"])
