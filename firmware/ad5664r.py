"""AD5664R quad 16-bit DAC driving the MEMS FSM driver board: words, init sequence, volts-to-code mapping.

Pure (no hardware access); the firmware encodes with it and the emulator decodes with it, so the mapping
below is stated once. Word layout (AD5624R/44R/64R datasheet Rev. C, p. 21), 24 bits MSB first::

    DB23-22 don't care | DB21-19 command C2..C0 | DB18-16 address A2..A0 | DB15-0 data

Channel map and differential drive (ryuxik/NODE_files fsm.cpp, derived from the thesis's CtrlArduino):
X+ = A, X- = B, Y- = C, Y+ = D; per tick X+ = bias + x, X- = bias - x, Y+ = bias + y (command 000, write
input register), then Y- = bias - y with command 010 (write and update all), so all four change together.

Volts-to-code mapping (our choice, documented here once): the thesis's FSM tilt voltage V_tilt in
[-2.5, +2.5] V (+-1.25 deg mechanical, Sec. 7.3.2) spans the DAC's 65536 codes differentially:
x = round(V_tilt * CODES_PER_VOLT) with CODES_PER_VOLT = 65536 / 5 V = 13107.2 code/V (76.29 uV per code;
0.5 deg/V gives 0.137 arcsec mechanical per code, the resolution the thesis quotes). The bias is mid-scale
0x8000, and |x| <= TILT_LIMIT_CODE = 32767 keeps both channels of a pair inside [1, 65535].
A decoder recovers x = (P - N) / 2 from a pair (P, N) and checks (P + N) / 2 == BIAS_CODE.
"""

# its own shim, not protocol.compat's: the controller's 32 KB board has no RAM for one more module
try:
    from micropython import const
except ImportError:  # CPython
    def const(x):
        return x

# Commands C2..C0 (datasheet Table 8).
CMD_WRITE_INPUT = const(0)        # 000 write input register n
CMD_UPDATE = const(1)             # 001 update DAC register n
CMD_WRITE_UPDATE_ALL = const(2)   # 010 write input register n, update all
CMD_WRITE_UPDATE = const(3)       # 011 write and update DAC channel n
CMD_POWER = const(4)              # 100 power down / power up
CMD_RESET = const(5)              # 101 reset
CMD_LDAC = const(6)               # 110 LDAC register setup
CMD_REFERENCE = const(7)          # 111 internal reference on/off

# Addresses A2..A0 and the FSM channel map.
ADDR_A = const(0)
ADDR_B = const(1)
ADDR_C = const(2)
ADDR_D = const(3)
ADDR_ALL = const(7)
ADDR_XP = ADDR_A
ADDR_XN = ADDR_B
ADDR_YN = ADDR_C
ADDR_YP = ADDR_D

# Init sequence: full reset, internal reference on, power up all channels, LDAC setup (NODE_files fsm.cpp).
INIT_WORDS = (0x280001, 0x380001, 0x20000F, 0x300000)

BIAS_CODE = const(0x8000)         # mid-scale bias of every channel
TILT_LIMIT_CODE = const(32767)    # largest |x| (differential half-range), the mirror's +-2.5 V
CODES_PER_VOLT = 13107.2          # 65536 codes / 5 V of tilt voltage
FULL_SCALE_V = 2.5                # tilt voltage at |x| = 32768 (the mirror's +-1.25 deg mechanical)


def word(cmd, addr, data):
    """One 24-bit word: command, address, 16-bit data."""
    return ((cmd & 7) << 19) | ((addr & 7) << 16) | (data & 0xFFFF)


def decode(w):
    """(command, address, data) of a 24-bit word."""
    return (w >> 19) & 7, (w >> 16) & 7, w & 0xFFFF


# Command/address prefixes of the four per-tick words, in the order they are clocked out.
PREFIX_XP = const(0x000000)       # word(CMD_WRITE_INPUT, ADDR_A, 0)
PREFIX_XN = const(0x010000)       # word(CMD_WRITE_INPUT, ADDR_B, 0)
PREFIX_YP = const(0x030000)       # word(CMD_WRITE_INPUT, ADDR_D, 0)
PREFIX_YN = const(0x120000)       # word(CMD_WRITE_UPDATE_ALL, ADDR_C, 0)


def command_words(x_code, y_code, out):
    """Fill out[0..3] with the per-tick words for tilt codes x, y (|x|, |y| <= TILT_LIMIT_CODE)."""
    out[0] = PREFIX_XP | (BIAS_CODE + x_code)
    out[1] = PREFIX_XN | (BIAS_CODE - x_code)
    out[2] = PREFIX_YP | (BIAS_CODE + y_code)
    out[3] = PREFIX_YN | (BIAS_CODE - y_code)


def volts_to_code(v):
    """Tilt code for a tilt voltage (rounded, clipped to +-TILT_LIMIT_CODE)."""
    c = v * CODES_PER_VOLT
    c = int(c + 0.5) if c >= 0 else -int(-c + 0.5)
    if c > TILT_LIMIT_CODE:
        return TILT_LIMIT_CODE
    if c < -TILT_LIMIT_CODE:
        return -TILT_LIMIT_CODE
    return c


def code_to_volts(x_code):
    """Tilt voltage of a tilt code."""
    return x_code / CODES_PER_VOLT


def pair_to_code(p_code, n_code):
    """Tilt code from a channel pair (P = bias + x, N = bias - x); ValueError if the bias is not mid-scale."""
    if p_code + n_code != 2 * BIAS_CODE:
        raise ValueError("AD5664R pair (%d, %d) not centred on bias %d" % (p_code, n_code, BIAS_CODE))
    return (p_code - n_code) // 2
