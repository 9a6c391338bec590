"""Hardware abstraction: the only part of the firmware that touches hardware.

Every backend offers the same calls, so the controller and player objects never change:

- ``read_q1(out)``          fill out[0..2] with the Q1 counts vx, vy, vs (SAMD21 12-bit, 0..4095);
- ``spi_write(words, n)``   clock n AD5664R 24-bit words out to the MEMS driver, MSB first;
- ``send(pid, dst, payload)`` one packet to the link (telemetry, ACK/NACK);
- ``recv()``                packets waiting on the link, ``[(pid, src, dst, seq, payload)]`` (never blocks).

Backends, imported lazily by name so a missing module breaks only its own backend:

- ``board``   ``MachineHal``: MicroPython ``machine.ADC``/``SPI``/``Pin``/``UART`` on a board;
- ``link``    ``serve_controller``/``serve_player``: the same I/O carried over the protocol (TICK in,
              FSM_SPI out) on a serial device or pty (``protocol.stream``) or, under CPython, any
              ``protocol.link`` spec (CAN via slcan);
- ``inproc``  ``BenchHal``: direct calls into the emulator's Bench, for speed;
- ``slcan``   ``SlcanAdapter``/``CanPort``: CAN frames as the serial-CAN adapter's side of Lawicel on a pty
              (the ADCS on CAN; a board's ``machine.CAN`` backend replaces the adapter).
"""


def backend(name):
    """The backend module ``firmware.hal.<name>`` (board, link, inproc, slcan)."""
    if name == "board":
        from firmware.hal import board as m
    elif name == "link":
        from firmware.hal import link as m
    elif name == "inproc":
        from firmware.hal import inproc as m
    elif name == "slcan":
        from firmware.hal import slcan as m
    else:
        raise ValueError("unknown HAL backend %r (board, link, inproc, slcan)" % (name,))
    return m
