"""The controller with its common tick (TRACK, beam present, the command inside its clamp with no saturation
run to end; a command that leaves the cached g H^-1 bin included) compiled by MicroPython's viper emitter to
machine code. MicroPython only; the .mpy needs ``mpy-cross -march``.

Same law, same integers, same order of operations as ``Controller.step`` (firmware/controller.py, Eq. 7.4,
7.12, 7.13), so the codes are identical (tests/mp/firmware_viper.py checks it over long runs). The state is
an ``array('i')`` (int32, every slot within +-2^30) with the slots and Q-formats of ``firmware.controller``;
the words an ``array('i')``. A new bin recomputes the cached g H^-1 here (in viper). Any other case (init tick,
other modes, SATURATED included, beam lost, saturation, the first tick off the clamp after a saturation run)
is detected before the loop's state is stored and handed whole to the bytecode ``Controller.step``, which
keeps the saturation counters and mode (on saturation the g H^-1 cache may already hold the new bin's, the
same values the bytecode step computes for it).
"""

import micropython
from array import array

from firmware.controller import Controller

from micropython import const

# The state slots again (viper needs them as constants of this module; tests/test_pil.py checks them against
# firmware.controller's).
_S_MODE = const(0)
_S_TICKS = const(1)
_S_VX = const(2)
_S_VY = const(3)
_S_RX = const(4)
_S_RY = const(5)
_S_VS = const(6)
_S_LOST = const(7)
_S_THR = const(8)
_S_RXC = const(9)
_S_RYC = const(10)
_S_LIM = const(11)
_S_NLIM = const(12)
_S_BXQ = const(13)
_S_BYQ = const(14)
_S_SHIFT = const(15)
_S_ROUND = const(16)
_S_GH = const(20)
_S_SAT_RUN = const(28)
_S_SIZE = const(33)
_TRACK = const(1)
_E_MAX = const(16383)
_COUNT_MAX = const(0x3FFFFFFF)


class ViperController(Controller):
    """``Controller`` whose ``step`` runs the common tick as viper machine code (same constructor)."""

    _tab = None
    _h16 = None

    def _state(self):
        return array("i", [0] * _S_SIZE)

    def _words(self):
        return array("i", [0, 0, 0, 0])

    def set_table(self, table):
        Controller.set_table(self, table)
        self._tab = self.table.t       # HinvTable's arrays, the layout _gain_hinv_viper reads
        self._h16 = self.table.h16

    def step_bytecode(self, vx, vy, vs):
        """The plain ``Controller.step`` (every case; the reference the viper path must match)."""
        return Controller.step(self, vx, vy, vs)

    @micropython.viper
    def step(self, vx: int, vy: int, vs: int) -> int:
        """One control tick (Eq. 7.4, 7.12, 7.13), as ``Controller.step``; returns 4."""
        s = ptr32(self._s)
        # A ptr32 load is zero-extended on a 64-bit port: ((x + b) & m) - b restores the sign of any
        # |x| < 2^30 on 32- and 64-bit ports alike (b = 2^30, m = 2^31 - 1, built at run time: 1 << 30 would be
        # folded into a constant that is no small int on a 32-bit port, so an object, not a viper int).
        b = 1
        b <<= 30
        m = (b << 1) - 1
        if s[_S_MODE] != _TRACK or vs < int(s[_S_THR]):
            return int(self.step_bytecode(vx, vy, vs))
        v_x = ((s[_S_VX] + b) & m) - b
        v_y = ((s[_S_VY] + b) & m) - b
        if ((v_x ^ (((s[_S_BXQ] + b) & m) - b)) | (v_y ^ (((s[_S_BYQ] + b) & m) - b))) >> 14:
            _gain_hinv_viper(self._tab, self._h16, self._s, self.gain, v_x >> 14, v_y >> 14)   # left its bin
        r = vs >> 1
        rx = (((2048 - vx) << 15) + r) // vs                 # Eq. 7.4, Q15
        ry = (((2048 - vy) << 15) + r) // vs
        ex = rx - (((s[_S_RXC] + b) & m) - b)                 # Eq. 7.13, clamped to +-0.5
        if ex > _E_MAX:
            ex = _E_MAX
        elif ex < -_E_MAX:
            ex = -_E_MAX
        ey = ry - (((s[_S_RYC] + b) & m) - b)
        if ey > _E_MAX:
            ey = _E_MAX
        elif ey < -_E_MAX:
            ey = -_E_MAX
        n = int(s[_S_SHIFT])
        r = int(s[_S_ROUND])
        k0 = ((s[_S_GH] + b) & m) - b
        k1 = ((s[_S_GH + 1] + b) & m) - b
        k2 = ((s[_S_GH + 2] + b) & m) - b
        k3 = ((s[_S_GH + 3] + b) & m) - b
        # Eq. 7.12: V -= (g H^-1) dR (high parts, then the low bytes' share), Q(15 + hq) -> Q8
        v_x -= (k0 * ex + k1 * ey + ((int(s[_S_GH + 4]) * ex + int(s[_S_GH + 5]) * ey + r) >> 8)) >> n
        v_y -= (k2 * ex + k3 * ey + ((int(s[_S_GH + 6]) * ex + int(s[_S_GH + 7]) * ey + r) >> 8)) >> n
        lim = int(s[_S_LIM])
        if v_x > lim or v_y > lim or v_x < -lim or v_y < -lim or s[_S_SAT_RUN] != 0:
            return int(self.step_bytecode(vx, vy, vs))       # saturation or a run ending: nothing stored yet
        s[_S_TICKS] = (s[_S_TICKS] + 1) & _COUNT_MAX
        s[_S_VS] = vs
        s[_S_LOST] = 0
        s[_S_RX] = rx
        s[_S_RY] = ry
        s[_S_VX] = v_x
        s[_S_VY] = v_y
        w = ptr32(self.words)
        r = (v_x + 128) >> 8
        w[0] = 0x008000 + r             # X+ = bias + x, cmd 000 addr A
        w[1] = 0x018000 - r             # X- = bias - x, cmd 000 addr B
        r = (v_y + 128) >> 8
        w[2] = 0x038000 + r             # Y+ = bias + y, cmd 000 addr D
        w[3] = 0x128000 - r             # Y- = bias - y, cmd 010 addr C (write, update all)
        return 4


@micropython.viper
def _gain_hinv_viper(t: ptr32, h: ptr16, s: ptr32, g: int, bx: int, by: int):
    """``Controller._gain_hinv`` with ``HinvTable.hinv_into`` inlined: g H^-1 at the centre of bin (bx, by)
    into the state's slots. t is the table's [nx, ny, ax..., ay..., rdx..., rdy...] and h its H^-1 entries, int16
    (Q-formats of ``firmware.hinv``), every entry within +-2^30; the same integer steps as the bytecode, so the
    same result. A ptr16 load is zero-extended: ((x + 2^15) & 0xFFFF) - 2^15 restores its sign."""
    b = 1
    b <<= 30                           # 2^30 and 2^31 - 1 built at run time, as in step
    m = (b << 1) - 1
    nx = int(t[0])
    ny = int(t[1])
    oax = 2
    oay = oax + nx
    orx = oay + ny
    ory = orx + nx - 1
    x = (bx << 6) + 32
    y = (by << 6) + 32
    i = 0
    n = nx - 2
    while i < n and x >= ((t[oax + i + 1] + b) & m) - b:
        i += 1
    a = ((t[oax + i] + b) & m) - b
    if x <= a:
        tx = 0
    elif x >= ((t[oax + i + 1] + b) & m) - b:
        tx = 4096
    else:
        tx = ((x - a) * int(t[orx + i])) >> 12
    j = 0
    n = ny - 2
    while j < n and y >= ((t[oay + j + 1] + b) & m) - b:
        j += 1
    a = ((t[oay + j] + b) & m) - b
    if y <= a:
        ty = 0
    elif y >= ((t[oay + j + 1] + b) & m) - b:
        ty = 4096
    else:
        ty = ((y - a) * int(t[ory + j])) >> 12
    k = (j * nx + i) << 2
    q = k + (nx << 2)
    e = 0
    while e < 4:
        a = ((h[k + e] + 0x8000) & 0xFFFF) - 0x8000
        u = a + (((((h[k + 4 + e] + 0x8000) & 0xFFFF) - 0x8000 - a) * tx) >> 12)
        a = ((h[q + e] + 0x8000) & 0xFFFF) - 0x8000
        v = a + (((((h[q + 4 + e] + 0x8000) & 0xFFFF) - 0x8000 - a) * tx) >> 12)
        v = (g * (u + (((v - u) * ty) >> 12)) + 64) >> 7
        s[_S_GH + e] = v >> 8
        s[_S_GH + 4 + e] = v & 255
        e += 1
    s[_S_BXQ] = bx << 14
    s[_S_BYQ] = by << 14
