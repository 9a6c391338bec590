"""AD660 16-bit DAC driving the P-FSM (Optics in Motion OIM5001): error angle to offset-binary code.

Eq. 7.7-7.8: theta_P-FSM = 13.33 theta_e, and +-3 deg of P-FSM maps to +-10 V, so
V = 0.012343 V/arcsec x theta_e (arcsec). The AD660's bipolar output is offset binary over +-10 V:
code = 0x8000 + V x 65536 / 20 V, clipped to 0..65535 (the packet table's PFSM_DAC scale is 20/65536 V).
"""

V_PER_ARCSEC = 0.012343          # Eq. 7.8
CODES_PER_VOLT = 3276.8          # 65536 codes / 20 V
ZERO_CODE = 0x8000
CODE_MAX = 0xFFFF


def arcsec_to_code_q2(theta_arcsec):
    """The AD660 code for an error angle in Q2 (code x 4, rounded), clipped to 0 .. 4 x 65535."""
    c = (ZERO_CODE + theta_arcsec * (V_PER_ARCSEC * CODES_PER_VOLT)) * 4.0
    if c <= 0.0:
        return 0
    if c >= CODE_MAX * 4:
        return CODE_MAX * 4
    return int(c + 0.5)


def arcsec_to_code(theta_arcsec):
    """The AD660 code for an error angle (rounded, clipped)."""
    return (arcsec_to_code_q2(theta_arcsec) + 2) >> 2


def code_to_arcsec(code):
    """The error angle a code stands for (inverse of Eq. 7.8)."""
    return (code - ZERO_CODE) / (V_PER_ARCSEC * CODES_PER_VOLT)
