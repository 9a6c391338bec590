"""``machine`` HAL for a MicroPython board (the thesis's CtrlArduino role): ADC, SPI, Pin, UART.

Peripherals are passed in already made (duck-typed like micropython-lib's drivers, so tests use small fakes);
``MachineHal.from_pins`` builds them with ``machine``. The AD5664R takes 24-bit words MSB first with SYNC
low for the word and data latched on SCLK falling edges (SPI mode 1). The SAMD21's 12-bit ADC reads through
``read_u16`` (0..65535), shifted back to 12-bit counts. The driver amplifier enable pin is high = enabled.
"""

from protocol import core
from protocol.compat import ticks_add, ticks_diff, ticks_us

P_STATUS = core.PACKET_ID["CTRL_STATUS"]
GROUND = core.NODE["GROUND"]

class MachineHal:
    """ADC channels for vx, vy, vs; SPI bus and SYNC pin for the AD5664R; optional enable pin and UART link."""

    def __init__(self, adc_x, adc_y, adc_s, spi, sync, enable=None, uart=None, node="CONTROLLER"):
        self.adc = (adc_x, adc_y, adc_s)
        self.spi = spi
        self.sync = sync
        self.enable = enable
        self.uart = uart
        self.node = core.node_id(node)
        self._b = bytearray(3)
        self._dec = core.Decoder()
        self._seq = 0
        sync.value(1)

    @classmethod
    def from_pins(cls, adc_pins, spi_id, sync_pin, enable_pin=None, uart_id=None, baudrate=19200,
                  spi_baud=10000000):
        """Build the peripherals with MicroPython's ``machine`` (pin names/numbers as the port takes them)."""
        import machine
        adcs = [machine.ADC(machine.Pin(p)) for p in adc_pins]
        spi = machine.SPI(spi_id, baudrate=spi_baud, polarity=0, phase=1, bits=8, firstbit=machine.SPI.MSB)
        sync = machine.Pin(sync_pin, machine.Pin.OUT, value=1)
        enable = machine.Pin(enable_pin, machine.Pin.OUT, value=0) if enable_pin is not None else None
        uart = machine.UART(uart_id, baudrate) if uart_id is not None else None
        return cls(adcs[0], adcs[1], adcs[2], spi, sync, enable, uart)

    def read_q1(self, out):
        a = self.adc
        out[0] = a[0].read_u16() >> 4
        out[1] = a[1].read_u16() >> 4
        out[2] = a[2].read_u16() >> 4

    def spi_write(self, words, n):
        b = self._b
        for k in range(n):
            w = words[k]
            b[0] = (w >> 16) & 0xFF
            b[1] = (w >> 8) & 0xFF
            b[2] = w & 0xFF
            self.sync.value(0)
            self.spi.write(b)
            self.sync.value(1)

    def amp(self, on):
        """Driver amplifier enable (NODE_files: set the angles to 0 and wait 10 ms before disabling)."""
        if self.enable is not None:
            self.enable.value(1 if on else 0)

    def send(self, pid, dst, payload):
        if self.uart is not None:
            self.uart.write(core.encode_frame(pid, self.node, dst, self._seq, payload))
            self._seq = (self._seq + 1) & 0xFF

    def recv(self):
        u = self.uart
        if u is None:
            return []
        n = u.any()
        if not n:
            return []
        return self._dec.feed(u.read(n))

def run(ctl, hal, rate_hz=637.8, ticks=None):
    """The board's main loop: one control tick every 1/rate_hz (busy-wait paced by ticks_us), packets from the
    UART handled between ticks, status every ``ctl.decim`` ticks. Runs forever unless ``ticks`` is given."""
    num = 10000000                       # period = num / (rate_hz * 10) us, kept exact by an accumulator
    den = int(rate_hz * 10 + 0.5)
    acc = 0
    t = ticks_us()
    k = 0
    hal.amp(True)
    while ticks is None or k < ticks:
        ctl.tick()
        for pid, src, dst, seq, payload in hal.recv():
            if dst == hal.node or dst == 0xFF:
                for rpid, rdst, rpayload in ctl.handle(pid, src, seq, payload):
                    hal.send(rpid, rdst, rpayload)
        if ctl.status_due():
            hal.send(P_STATUS, GROUND, ctl.status_payload())
        acc += num
        t = ticks_add(t, acc // den)
        acc %= den
        while ticks_diff(t, ticks_us()) > 0:
            pass
        k += 1
    return k
