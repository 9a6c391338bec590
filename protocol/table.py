"""The packet table: the single contract between firmware, emulator and ground.

Every packet is declared once here. Encoders, decoders, ``PROTOCOL.md``, the CAN DBC file and the
``fps protocol`` CLI are all derived from this table; nothing else may restate an id, a field or a
scale. The module imports and runs under MicroPython (plain tuples, no typing, no dataclasses).

A packet is ``(id, name, src, dst, doc, fields)``; ``src``/``dst`` are node names (``"*"`` = any).
A field is ``(name, fmt, unit, scale, lo, hi, default, doc)``:

- ``fmt``   one little-endian ``struct`` code (``B b H h I i f d``) or ``"<n>s"`` for a byte string;
- ``scale`` physical value = raw × scale, in ``unit`` (scale 1 for counts and enums);
- ``lo``/``hi`` the valid *raw* range (``None`` = the format's own range); encoders refuse outside it.
"""

PROTOCOL_VERSION = 1

# Node addresses (8 bits). Reaction wheels take RW0 + index.
NODES = (
    ("GROUND", 0x01, "ground station / test control software"),
    ("CONTROLLER", 0x10, "fine-pointing controller MCU (CtrlArduino, Q1 + MEMS FSM)"),
    ("PLAYER", 0x11, "disturbance player MCU (SimArduino, P-FSM)"),
    ("RECORDER", 0x12, "Q2 recorder (ADS1256 on a Raspberry Pi)"),
    ("BENCH", 0x20, "optical bench emulator (device side of the links)"),
    ("ADCS", 0x30, "attitude determination and control computer"),
    ("RW0", 0x40, "reaction wheel 0"),
    ("RW1", 0x41, "reaction wheel 1"),
    ("RW2", 0x42, "reaction wheel 2"),
    ("RW3", 0x43, "reaction wheel 3"),
    ("STARTRACKER", 0x50, "star tracker"),
    ("GNSS", 0x51, "GNSS receiver"),
    ("BEACON", 0x52, "beacon camera"),
    ("MTQ", 0x53, "magnetorquer driver (three rods)"),
    ("MAGNETOMETER", 0x54, "three-axis magnetometer"),
    ("SPACECRAFT", 0x60, "spacecraft dynamics emulator"),
    ("BROADCAST", 0xFF, "every node"),
)

# Controller modes (CTRL_SETTINGS.mode, CTRL_STATUS.mode). SATURATED is TRACK with the FSM command held on its
# clamp for a sustained run (firmware.controller.SAT_TICKS): the law still runs. ACQUIRE is TRACK without the beam
# (Q1's sum below its threshold for firmware.controller.ACQ_TICKS ticks in a row): no law, the mirror held, then
# returned to its centre; TRACK again once the beam has been back as long. The controller enters and leaves both
# on its own, and the ground cannot command them (CTRL_SETTINGS.mode stops at SAFE).
MODES = (("IDLE", 0), ("TRACK", 1), ("HOLD", 2), ("CALIBRATE", 3), ("SAFE", 4), ("SATURATED", 5), ("ACQUIRE", 6))

# Why the controller last left TRACK on its own or entered SAFE (CTRL_STATUS.why): BEAM_LOST is ACQUIRE's.
SAFE_REASONS = (("NONE", 0), ("BEAM_LOST", 1), ("LINK_SILENT", 2), ("COMMANDED", 3))

# Error codes carried by NACK.code (0 is never sent: it means "no error").
ERRORS = (
    ("OK", 0, "no error"),
    ("UNKNOWN_PACKET", 1, "packet id not handled by this node"),
    ("BAD_VALUE", 2, "a field is out of range"),
    ("BAD_STATE", 3, "not allowed in the current mode"),
    ("BAD_SEQUENCE", 4, "chunk out of order or transfer not begun"),
    ("BAD_CRC", 5, "transfer CRC-32 mismatch"),
    ("BAD_CONTENT", 6, "transfer content malformed (table or distfile refused)"),
    ("TOO_LARGE", 7, "transfer larger than the node can hold"),
    ("BUSY", 8, "node busy"),
)

# ADCS flight software modes (ADCS_STATUS.adcs_mode). SLEW and ACQUIRE are the flight world's (a rate-limited
# slew to the partner; after it, the command held until the star tracker answers again).
ADCS_MODES = (("INIT", 0), ("HOLD", 1), ("POINT", 2), ("DEGRADED", 3), ("SLEW", 4), ("ACQUIRE", 5))

# ADCS_STATUS.stale bits: the sensor gave nothing usable this cycle (missed, invalid or too old). The byte is
# full: MAGNETOMETER and MTQ_TLM have no bit, so they are not named in ADCS_TICK.burst nor asked for again by
# ADCS_MISSING (they ride in the burst unnamed; a lost one is a missed reading).
ADCS_STALE = (("STARTRACKER", 0), ("GNSS_A", 1), ("GNSS_B", 2), ("BEACON", 3), ("RW0", 4), ("RW1", 5),
              ("RW2", 6), ("RW3", 7))

# Player actions (PLAYER_CTRL.action).
PLAYER_ACTIONS = (("STOP", 0), ("START", 1), ("LOOP", 2), ("ONESHOT", 3))

CHUNK_BYTES = 48  # data bytes per upload chunk

_Q15 = 1.0 / 32768.0
_CHUNK = (
    ("offset", "I", "B", 1, None, None, 0, "byte offset of this chunk in the transfer"),
    ("length", "B", "B", 1, 0, CHUNK_BYTES, 0, "valid bytes in data"),
    ("data", "%ds" % CHUNK_BYTES, "", 1, None, None, b"", "chunk bytes, zero padded"),
)
_BEGIN = (
    ("total", "I", "B", 1, 1, 1 << 20, 1, "transfer length in bytes"),
    ("crc32", "I", "", 1, None, None, 0, "CRC-32 (IEEE) of the whole transfer"),
)
_END = (("total", "I", "B", 1, 0, 1 << 20, 0, "bytes sent, checked against BEGIN"),)

PACKETS = (
    # --- link management -------------------------------------------------------------------------
    (0x01, "HELLO", "*", "*", "node announces itself and its protocol and firmware versions", (
        ("proto", "B", "", 1, None, None, PROTOCOL_VERSION, "protocol version spoken"),
        ("node", "B", "", 1, None, None, 0, "sender's node address"),
        ("fw_major", "B", "", 1, None, None, 0, "firmware major version"),
        ("fw_minor", "B", "", 1, None, None, 1, "firmware minor version"),
        ("caps", "H", "", 1, None, None, 0, "capability bits (node specific)"),
    )),
    (0x02, "ACK", "*", "*", "a command was accepted", (
        ("ref_id", "B", "", 1, None, None, 0, "packet id acknowledged"),
        ("ref_seq", "B", "", 1, None, None, 0, "sequence number acknowledged"),
    )),
    (0x03, "NACK", "*", "*", "a command was refused, with an error code (table ERRORS)", (
        ("ref_id", "B", "", 1, None, None, 0, "packet id refused"),
        ("ref_seq", "B", "", 1, None, None, 0, "sequence number refused"),
        ("code", "B", "", 1, 1, 255, 1, "error code, see ERRORS"),
    )),
    # --- lockstep fine-pointing loop ------------------------------------------------------------
    (0x10, "TICK", "BENCH", "CONTROLLER",
     "lockstep tick: the controller's Q1 sample (SAMD21 12-bit counts after the inverting amplifier)", (
        ("tick", "I", "", 1, None, None, 0, "control tick number"),
        ("t_us", "I", "us", 1, None, None, 0, "virtual time of the sample"),
        ("vx", "H", "count", 1, 0, 4095, 2048, "Q1 X difference, ADC counts"),
        ("vy", "H", "count", 1, 0, 4095, 2048, "Q1 Y difference, ADC counts"),
        ("vs", "H", "count", 1, 0, 4095, 0, "Q1 sum, ADC counts"),
    )),
    (0x11, "FSM_SPI", "CONTROLLER", "BENCH",
     "AD5664R 24-bit SPI words to the MEMS FSM driver, in the order clocked out (n used, rest 0)", (
        ("tick", "I", "", 1, None, None, 0, "control tick this command answers"),
        ("n", "B", "", 1, 0, 4, 0, "number of words used"),
        ("w0", "I", "", 1, 0, 0xFFFFFF, 0, "AD5664R word 0"),
        ("w1", "I", "", 1, 0, 0xFFFFFF, 0, "AD5664R word 1"),
        ("w2", "I", "", 1, 0, 0xFFFFFF, 0, "AD5664R word 2"),
        ("w3", "I", "", 1, 0, 0xFFFFFF, 0, "AD5664R word 3"),
    )),
    (0x12, "PFSM_DAC", "PLAYER", "BENCH", "AD660 offset-binary codes for the P-FSM (0x8000 = 0 V, +-10 V)", (
        ("sample", "I", "", 1, None, None, 0, "player sample number"),
        ("x", "H", "code", 1, None, None, 0x8000, "X axis AD660 code (offset binary: V = (code - 32768) * 20 / 65536)"),
        ("y", "H", "code", 1, None, None, 0x8000, "Y axis AD660 code (offset binary)"),
    )),
    (0x13, "Q2_SAMPLE", "BENCH", "RECORDER", "ADS1256 24-bit two's complement counts of Q2 (630 Hz)", (
        ("sample", "I", "", 1, None, None, 0, "recorder sample number"),
        ("t_us", "I", "us", 1, None, None, 0, "virtual time of the sample"),
        ("vx", "i", "count", 1, -0x800000, 0x7FFFFF, 0, "Q2 X difference"),
        ("vy", "i", "count", 1, -0x800000, 0x7FFFFF, 0, "Q2 Y difference"),
        ("vs", "i", "count", 1, -0x800000, 0x7FFFFF, 0, "Q2 sum"),
    )),
    # --- controller settings and telemetry ------------------------------------------------------
    (0x20, "CTRL_SETTINGS", "GROUND", "CONTROLLER", "mode, ratio command (Eq. 7.13) and loop gain (Eq. 7.12)", (
        ("mode", "B", "", 1, 0, 4, 0, "controller mode, see MODES"),
        ("rx_cmd", "h", "", _Q15, -16384, 16384, 0, "Rx command, Q15"),
        ("ry_cmd", "h", "", _Q15, -16384, 16384, 0, "Ry command, Q15"),
        ("gain", "H", "", _Q15, 0, 65535, 16384, "integral gain g, Q15 (0 keeps the current gain)"),
        ("decim", "H", "tick", 1, 0, 65535, 64, "status telemetry every decim ticks (0 = off)"),
        ("safe_ticks", "H", "tick", 1, 1, 65535, 638, "ticks of link silence before SAFE"),
    )),
    (0x21, "CTRL_SET_FSM", "GROUND", "CONTROLLER", "CALIBRATE mode: set the FSM tilt voltages directly", (
        ("vx", "i", "V", 1e-6, -2500000, 2500000, 0, "X tilt voltage"),
        ("vy", "i", "V", 1e-6, -2500000, 2500000, 0, "Y tilt voltage"),
    )),
    (0x22, "CTRL_STATUS", "CONTROLLER", "GROUND", "controller status telemetry", (
        ("tick", "I", "", 1, None, None, 0, "control tick"),
        ("mode", "B", "", 1, 0, 6, 0,
         "controller mode, see MODES (5 SATURATED: a sustained saturation; 6 ACQUIRE: the beam lost, waiting)"),
        ("flags", "B", "", 1, None, None, 0, "bit0 beam present, bit1 saturated this tick, bit2 table loaded"),
        ("vx", "i", "V", 1e-6, -2500000, 2500000, 0, "commanded X tilt voltage"),
        ("vy", "i", "V", 1e-6, -2500000, 2500000, 0, "commanded Y tilt voltage"),
        ("rx", "h", "", _Q15, None, None, 0, "measured Rx, Q15"),
        ("ry", "h", "", _Q15, None, None, 0, "measured Ry, Q15"),
        ("vs", "H", "count", 1, 0, 4095, 0, "Q1 sum, ADC counts"),
        ("code_xp", "H", "code", 1, None, None, 0, "AD5664R X+ code"),
        ("code_xn", "H", "code", 1, None, None, 0, "AD5664R X- code"),
        ("code_yp", "H", "code", 1, None, None, 0, "AD5664R Y+ code"),
        ("code_yn", "H", "code", 1, None, None, 0, "AD5664R Y- code"),
        ("n_lost", "H", "", 1, None, None, 0, "ticks with the beam below threshold (wraps)"),
        ("n_sat", "I", "tick", 1, None, None, 0,
         "ticks the integral law's command hit its clamp on either axis (stops at 2^30 - 1)"),
        ("n_unknown", "H", "", 1, None, None, 0, "unknown packets ignored (wraps)"),
        ("why", "B", "", 1, 0, 3, 0,
         "why the controller last entered SAFE or ACQUIRE, see SAFE_REASONS"),
        ("n_dup", "H", "", 1, None, None, 0, "resent TICKs answered again without a step (wraps)"),
        ("n_gap", "H", "", 1, None, None, 0, "ticks the bench ran without this controller (wraps)"),
        ("n_rx_drop", "H", "", 1, None, None, 0,
         "frames or transfers its link dropped, and TICKs dropped as stale or out of range (wraps)"),
        ("sat_run", "I", "tick", 1, None, None, 0,
         "ticks the command has stayed on its clamp up to this one (beam-lost holds included; 0 = off it)"),
        ("sat_last", "I", "tick", 1, None, None, 0,
         "length of the last sustained saturation (a run that entered SATURATED) once ended (0 = none yet)"),
        ("n_sat_episodes", "H", "", 1, None, None, 0, "sustained saturations: entries into SATURATED (wraps)"),
    )),
    (0x23, "HTABLE_BEGIN", "GROUND", "CONTROLLER", "begin an H-table upload", _BEGIN),
    (0x24, "HTABLE_CHUNK", "GROUND", "CONTROLLER", "one chunk of an H-table upload", _CHUNK),
    (0x25, "HTABLE_END", "GROUND", "CONTROLLER", "end an H-table upload: verify and swap in", _END),
    # --- disturbance player ---------------------------------------------------------------------
    (0x30, "PLAYER_CTRL", "GROUND", "PLAYER", "start, stop, loop or one-shot the loaded distfile", (
        ("action", "B", "", 1, 0, 3, 0, "see PLAYER_ACTIONS"),
        ("rate_hz", "H", "Hz", 1, 100, 50000, 10600, "P-FSM update rate"),
    )),
    (0x31, "PLAYER_STATUS", "PLAYER", "GROUND", "player state", (
        ("state", "B", "", 1, 0, 3, 0, "current action, see PLAYER_ACTIONS"),
        ("sample", "I", "", 1, None, None, 0, "distfile sample being played"),
        ("count", "I", "", 1, None, None, 0, "samples in the loaded distfile"),
    )),
    (0x32, "DIST_BEGIN", "GROUND", "PLAYER", "begin a distfile upload", _BEGIN),
    (0x33, "DIST_CHUNK", "GROUND", "PLAYER", "one chunk of a distfile upload", _CHUNK),
    (0x34, "DIST_END", "GROUND", "PLAYER", "end a distfile upload: verify and swap in", _END),
    # --- spacecraft: reaction wheels and attitude sensors ---------------------------------------
    (0x40, "RW_CMD", "ADCS", "RW0", "reaction wheel torque command (dst RW0..RW3)", (
        ("torque", "f", "N m", 1, None, None, 0.0, "motor torque command"),
        ("enable", "B", "", 1, 0, 1, 1, "1 = drive, 0 = coast"),
        ("cycle", "B", "", 1, None, None, 0, "ADCS cycle (mod 256) the command belongs to; the wheel ignores it"),
    )),
    (0x41, "RW_TLM", "RW0", "ADCS", "reaction wheel telemetry (src RW0..RW3)", (
        ("speed", "f", "rpm", 1, None, None, 0.0, "measured wheel speed (10 rpm 1-sigma noise)"),
        ("torque", "f", "N m", 1, None, None, 0.0, "applied motor torque"),
    )),
    (0x42, "STARTRACKER", "STARTRACKER", "ADCS", "star tracker attitude, inertial to body (Sec. 4.7)", (
        ("t_ms", "I", "ms", 1, None, None, 0, "measurement time"),
        ("q0", "f", "", 1, -1.0, 1.0, 0.0, "quaternion x"),
        ("q1", "f", "", 1, -1.0, 1.0, 0.0, "quaternion y"),
        ("q2", "f", "", 1, -1.0, 1.0, 0.0, "quaternion z"),
        ("q3", "f", "", 1, -1.0, 1.0, 1.0, "quaternion scalar"),
        ("valid", "B", "", 1, 0, 1, 1, "0 when |w| >= 0.1 deg/s (the thesis: output only below it)"),
    )),
    (0x43, "GNSS", "GNSS", "ADCS", "GNSS fix, J2000 (Eq. 5.10-5.12)", (
        ("t_ms", "I", "ms", 1, None, None, 0, "measurement time"),
        ("sat", "B", "", 1, 0, 1, 0, "0 = own spacecraft (A), 1 = partner (B) via ground relay"),
        ("x", "i", "m", 0.01, None, None, 0, "position x"),
        ("y", "i", "m", 0.01, None, None, 0, "position y"),
        ("z", "i", "m", 0.01, None, None, 0, "position z"),
        ("vx", "i", "m/s", 1e-4, None, None, 0, "velocity x"),
        ("vy", "i", "m/s", 1e-4, None, None, 0, "velocity y"),
        ("vz", "i", "m/s", 1e-4, None, None, 0, "velocity z"),
    )),
    (0x44, "BEACON", "BEACON", "ADCS", "beacon unit vector in the body frame (Eq. 5.13-5.17)", (
        ("t_ms", "I", "ms", 1, None, None, 0, "measurement time"),
        ("ux", "f", "", 1, -1.0, 1.0, 0.0, "unit vector x"),
        ("uy", "f", "", 1, -1.0, 1.0, 0.0, "unit vector y"),
        ("uz", "f", "", 1, -1.0, 1.0, 1.0, "unit vector z"),
        ("valid", "B", "", 1, 0, 1, 1, "1 = beacon in view"),
    )),
    (0x45, "ADCS_TICK", "SPACECRAFT", "ADCS",
     "lockstep: open this 1 Hz cycle; its sensor burst follows; run the cycle once the burst named here is in "
     "(emulated spacecraft only)", (
        ("tick", "I", "", 1, None, None, 0, "ADCS cycle number"),
        ("t_ms", "I", "ms", 1, None, None, 0, "virtual time of the sensor burst"),
        ("burst", "B", "", 1, None, None, 0, "packets the burst holds, ADCS_STALE bits (GNSS_B: n_gnss_b > 0)"),
        ("n_gnss_b", "B", "", 1, 0, 16, 0, "SatB GNSS fixes (relayed) in the burst"),
    )),
    (0x46, "ADCS_STATUS", "ADCS", "*", "ADCS status, once per 1 Hz cycle after the wheel commands", (
        ("tick", "I", "", 1, None, None, 0, "ADCS cycle this status closes"),
        ("adcs_mode", "B", "", 1, 0, 5, 0, "see ADCS_MODES"),
        ("stale", "B", "", 1, None, None, 0, "sensors without a usable reading this cycle, see ADCS_STALE"),
        ("wheels_failed", "B", "", 1, 0, 15, 0, "bit i: wheel i declared failed (3 missed replies in a row)"),
        ("miss_rw0", "H", "", 1, None, None, 0, "RW_TLM replies of wheel 0 missed by their deadline (wraps)"),
        ("miss_rw1", "H", "", 1, None, None, 0, "RW_TLM replies of wheel 1 missed (wraps)"),
        ("miss_rw2", "H", "", 1, None, None, 0, "RW_TLM replies of wheel 2 missed (wraps)"),
        ("miss_rw3", "H", "", 1, None, None, 0, "RW_TLM replies of wheel 3 missed (wraps)"),
        ("miss_st", "H", "", 1, None, None, 0, "cycles without a STARTRACKER packet (wraps)"),
        ("miss_gnss", "H", "", 1, None, None, 0, "cycles without SatA's GNSS (wraps)"),
        ("miss_beacon", "H", "", 1, None, None, 0, "cycles without a BEACON packet (wraps)"),
        ("n_st_invalid", "H", "", 1, None, None, 0, "STARTRACKER packets flagged invalid (wraps)"),
        ("n_beacon_invalid", "H", "", 1, None, None, 0, "BEACON packets flagged invalid (wraps)"),
        ("n_gnss_b", "H", "", 1, None, None, 0, "SatB GNSS fixes fused (wraps)"),
        ("n_refused", "H", "", 1, None, None, 0, "STKF measurements refused (NaN, out of order, too old; wraps)"),
        ("n_rx_drop", "H", "", 1, None, None, 0, "CAN frames or ISO-TP transfers dropped (wraps)"),
        ("gnss_age_s", "H", "s", 1, None, None, 0, "age of SatA's newest GNSS fix (65535 = never)"),
        ("q0", "f", "", 1, None, None, 0.0, "estimated attitude, quaternion x"),
        ("q1", "f", "", 1, None, None, 0.0, "quaternion y"),
        ("q2", "f", "", 1, None, None, 0.0, "quaternion z"),
        ("q3", "f", "", 1, None, None, 1.0, "quaternion scalar"),
        ("wx", "f", "rad/s", 1, None, None, 0.0, "estimated body rate x"),
        ("wy", "f", "rad/s", 1, None, None, 0.0, "estimated body rate y"),
        ("wz", "f", "rad/s", 1, None, None, 0.0, "estimated body rate z"),
        ("rax", "f", "m", 1, None, None, 0.0, "estimated SatA position x, J2000"),
        ("ray", "f", "m", 1, None, None, 0.0, "estimated SatA position y"),
        ("raz", "f", "m", 1, None, None, 0.0, "estimated SatA position z"),
        ("rbx", "f", "m", 1, None, None, 0.0, "estimated SatB position x, J2000"),
        ("rby", "f", "m", 1, None, None, 0.0, "estimated SatB position y"),
        ("rbz", "f", "m", 1, None, None, 0.0, "estimated SatB position z"),
        ("att_sigma", "f", "rad", 1, None, None, 0.0, "APKF attitude 1 sigma, sqrt(trace 4 P_qq)"),
        ("cycle_us", "I", "us", 1, None, None, 0, "time the cycle took on this computer"),
        ("magnetic_failed", "B", "", 1, 0, 15, 0, "bits 0-2: rod i out of the unloading (its driver silent in 3 "
         "MTQ_TLM in a row); bit 3: the magnetometer silent 3 cycles in a row (the unloading on the field model)"),
        ("n_rx_damaged", "H", "", 1, None, None, 0, "of n_rx_drop, those that arrived damaged (the rest came too "
         "late or were cut off: slowness, not the wire; wraps)"),
    )),
    (0x47, "ADCS_MISSING", "ADCS", "SPACECRAFT",
     "lockstep: the open cycle's burst lacks these packets, send them again (answers a resent ADCS_TICK)", (
        ("tick", "I", "", 1, None, None, 0, "ADCS cycle open"),
        ("missing", "B", "", 1, None, None, 0, "ADCS_STALE bits of the packets not received (GNSS_B: some)"),
    )),
    # --- spacecraft: magnetorquers and magnetometer (body frame; the rods' axes and limit, the magnetometer's
    # noise and bias are the spacecraft file's) -------------------------------------------------------------
    (0x48, "MTQ_CMD", "ADCS", "MTQ",
     "magnetorquer dipole command, body frame: the driver shares it among its rods by least squares and clips "
     "each rod at its dipole limit; answered by MTQ_TLM", (
        ("mx", "f", "A m^2", 1, None, None, 0.0, "commanded dipole x, body frame"),
        ("my", "f", "A m^2", 1, None, None, 0.0, "commanded dipole y"),
        ("mz", "f", "A m^2", 1, None, None, 0.0, "commanded dipole z"),
        ("enable", "B", "", 1, 0, 1, 1, "1 = drive, 0 = every rod off (dipole 0)"),
        ("cycle", "B", "", 1, None, None, 0, "ADCS cycle (mod 256) the command belongs to; the driver ignores it"),
    )),
    (0x49, "MTQ_TLM", "MTQ", "ADCS", "magnetorquer telemetry: the dipole the rods apply", (
        ("mx", "f", "A m^2", 1, None, None, 0.0, "applied dipole x after the per-rod limit, body frame"),
        ("my", "f", "A m^2", 1, None, None, 0.0, "applied dipole y"),
        ("mz", "f", "A m^2", 1, None, None, 0.0, "applied dipole z"),
        ("saturated", "B", "", 1, 0, 7, 0, "bit i: rod i clipped at its dipole limit (rods in the spacecraft "
         "file's order)"),
        ("silent", "B", "", 1, 0, 7, 0, "bit i: rod i's driver did not answer the board (the rod gives no "
         "dipole)"),
    )),
    (0x4A, "MAGNETOMETER", "MAGNETOMETER", "ADCS",
     "magnetic field in the body frame (sensor axes on the body axes), nT as scaled integers", (
        ("t_ms", "I", "ms", 1, None, None, 0, "measurement time"),
        ("bx", "i", "nT", 0.1, -1000000, 1000000, 0, "field x, body frame (full scale +-100000 nT)"),
        ("by", "i", "nT", 0.1, -1000000, 1000000, 0, "field y"),
        ("bz", "i", "nT", 0.1, -1000000, 1000000, 0, "field z"),
        ("valid", "B", "", 1, 0, 1, 1, "1 = a reading; 0 = none (beyond full scale on an axis, or failed)"),
    )),
)
