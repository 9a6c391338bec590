"""Emulated bench physics against closed forms: quadcell, DACs and mirrors, resizer, Eq. 7.8, true H."""

import math

import numpy as np
import pytest

from emulator.bench import Bench
from protocol.units import ARCSEC_PER_RAD
from emulator.config import default_config
from emulator.mirrors import AD5664R, INIT_WORDS, MEMS, PFSM, Modal, fsm_words
from emulator.optics import Optics, exit_pupil_z2, resizer_matrix
from emulator.quadcell import Quadcell, ratio_closed_form

DEG = math.pi / 180


def _quadcell(**over):
    q = dict(default_config()["q1"], rotation_deg=0.0, misalignment_deg=0.0, offset_m=[0.0, 0.0])
    q.update(over)
    return q


# --- quadcell ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("w", [0.5e-3, 1.0e-3, 1.5e-3])
def test_quadcell_ratio_is_erf_for_centred_gapfree_detector(w):
    """Vx/Vs = -erf(sqrt2 x/w) (Vx = left - right, Eq. 7.3); both models on a gap-free, large detector."""
    qc = Quadcell(_quadcell(gap_m=0.0, radius_m=20e-3), (w, w), 0.0, 1e-3)
    for x in np.linspace(-1.5 * w, 1.5 * w, 13):
        want = ratio_closed_form(x, w)
        for f in (qc.outputs_fast, qc.outputs_reference):
            vx, vy, vs = f(x, 0.0)
            assert vx / vs == pytest.approx(want, abs=1e-9)
            assert vy / vs == pytest.approx(0.0, abs=1e-9)
        vx, vy, vs = qc.outputs_fast(0.0, x)
        assert vy / vs == pytest.approx(-want, abs=1e-12)     # Vy = top - bottom


def test_quadcell_centre_slope_matches_hardware_facts():
    w = 1e-3
    qc = Quadcell(_quadcell(gap_m=0.0, radius_m=20e-3), (w, w), 0.0, 1e-3)
    h = 1e-7
    slope = (qc.outputs_fast(h, 0)[0] / qc.outputs_fast(h, 0)[2] - qc.outputs_fast(-h, 0)[0] /
             qc.outputs_fast(-h, 0)[2]) / (2 * h)
    assert slope == pytest.approx(-2 * math.sqrt(2) / (math.sqrt(math.pi) * w), rel=1e-6)


def test_quadcell_fast_matches_reference_inside_with_gap():
    qc = Quadcell(_quadcell(), (1e-3, 1e-3), 0.0, 1e-3)
    rng = np.random.default_rng(3)
    for x, y in rng.uniform(-0.4e-3, 0.4e-3, (30, 2)):
        assert qc.outputs_fast(x, y) == pytest.approx(qc.outputs_reference(x, y), abs=1e-9 * qc.volts)
    assert qc.n_reference == 30


def test_quadcell_gap_and_finite_size_reduce_signal():
    w = 1e-3
    gapped = Quadcell(_quadcell(gap_m=0.2e-3), (w, w), 0.0, 1e-3)
    clean = Quadcell(_quadcell(gap_m=0.0, radius_m=20e-3), (w, w), 0.0, 1e-3)
    assert gapped.outputs_reference(0, 0)[2] < clean.outputs_reference(0, 0)[2] * 0.9
    # far off-centre the fast path falls back to the reference, which sees the spot leave the disc
    edge = gapped.outputs_fast(4.5e-3, 0.0)
    assert edge[2] < 0.4 * gapped.volts
    assert gapped.n_reference == 2


def test_quadcell_tilted_ellipse_fast_path_corrected_to_reference():
    """A rotated elliptical spot is not separable: the fitted correction keeps the fast path on the reference."""
    qc = Quadcell(_quadcell(rotation_deg=30.0), (1.0e-3, 0.7e-3), 10.0, 1e-3)
    assert qc.corr is not None
    rng = np.random.default_rng(4)
    worst = 0.0
    for x, y in rng.uniform(-0.35e-3, 0.35e-3, (25, 2)):
        fast = qc.outputs_fast(x, y)
        ref = qc.outputs_reference(x, y)
        worst = max(worst, abs(fast[0] / fast[2] - ref[0] / ref[2]), abs(fast[1] / fast[2] - ref[1] / ref[2]))
    assert worst < 2e-4


# --- DACs and mirrors ------------------------------------------------------------------------------------
def test_ad660_code_voltage_angle():
    p = PFSM(default_config())
    assert p.code_to_v(0x8000) == 0.0
    assert p.code_to_v(0) == -10.0
    assert p.code_to_v(0xFFFF) == pytest.approx(10.0 - 20.0 / 65536)
    assert p.angle(10.0, 0) == pytest.approx(3.0 * DEG)        # +-10 V <-> +-3 deg mechanical
    for code in (0, 1234, 0x8000, 40000, 0xFFFF):
        assert p.v_to_code(p.code_to_v(code)) == code
    # one LSB is the thesis's 0.329 arcsec resolution
    assert (p.angle(p.code_to_v(0x8001), 0) / DEG * 3600) == pytest.approx(6.0 * 3600 / 65536, rel=1e-9)


def test_ad5664r_words_voltage_angle():
    cfg = default_config()
    cfg["mems"].update(gain_error=[0.0, 0.0], quadratic_per_v=[0.0, 0.0], cubic_per_v2=[0.0, 0.0],
                       cross_coupling=[0.0, 0.0])
    dac, mems = AD5664R(), MEMS(cfg)
    for w in INIT_WORDS:
        dac.write(w)
    for vx, vy in ((0.0, 0.0), (1.0, -0.5), (-2.4, 2.4), (0.0374, -0.0025)):
        for w in fsm_words(vx, vy, cfg):
            dac.write(w)
        tvx, tvy = mems.tilt_v(dac.outputs())
        assert tvx == pytest.approx(vx, abs=2.5 / 32768)
        assert tvy == pytest.approx(vy, abs=2.5 / 32768)
        ax, ay, clipped = mems.static_angle(tvx, tvy)
        assert not clipped
        assert ax == pytest.approx(0.5 * DEG * tvx) and ay == pytest.approx(0.5 * DEG * tvy)
    # one differential code (X+ up one, X- down one) is the thesis's 0.137 arcsec resolution (2.5 deg / 2^16)
    angles = []
    for vx in (0.0, 2.5 / 32768, 2 * 2.5 / 32768):
        for w in fsm_words(vx, 0.0, cfg):
            dac.write(w)
        angles.append(mems.static_angle(*mems.tilt_v(dac.outputs()))[0] / DEG * 3600)
    assert np.diff(angles) == pytest.approx([0.137, 0.137], abs=5e-4)


def test_ad5664r_matches_the_firmware_mapping():
    """The firmware's word encoder (firmware/ad5664r.py) and this decoder agree on volts."""
    from firmware import ad5664r as ad
    cfg = default_config()
    dac, mems = AD5664R(), MEMS(cfg)
    for w in ad.INIT_WORDS:
        dac.write(w)
    out = [0, 0, 0, 0]
    for v in (-2.0, -0.3, 0.0, 0.7, 2.4):
        code = int(round(v * ad.CODES_PER_VOLT))
        ad.command_words(code, -code, out)
        for w in out:
            dac.write(w)
        assert mems.tilt_v(dac.outputs()) == pytest.approx((v, -v), abs=1e-4)


def test_ad5664r_commands_power_reset_ldac_and_unknown():
    cfg = default_config()
    dac, mems = AD5664R(), MEMS(cfg)
    words = fsm_words(1.0, 1.0, cfg)
    for w in words:
        dac.write(w)
    assert dac.outputs() == [0, 0, 0, 0]                      # internal reference off at power-up
    dac.write(0x380001)
    assert mems.tilt_v(dac.outputs())[0] == pytest.approx(1.0, abs=1e-4)
    dac.write(0x200001)                                         # power command for A, mode 00 = normal: up
    assert dac.powered[0]
    dac.write(0x200031)                                         # A three-state
    assert not dac.powered[0] and dac.outputs()[0] == 0
    dac.write(0x20000F)
    assert dac.powered == [True] * 4
    # write input only: no change until an update
    dac.write((0 << 19) | (0 << 16) | 40000)
    assert dac.dac[0] != 40000
    dac.write((1 << 19) | (0 << 16))                            # update DAC A
    assert dac.dac[0] == 40000
    dac.write(0x30000F)                                         # LDAC mask: transparent
    dac.write((0 << 19) | (1 << 16) | 1234)
    assert dac.dac[1] == 1234
    dac.write(0x280000)                                         # reset registers, keep the reference
    assert dac.dac == [0] * 4 and dac.ref_on
    dac.write(0x280001)                                         # power-on reset
    assert not dac.ref_on and dac.ldac_mask == 0
    before = (list(dac.input), list(dac.dac))
    for bad in ((0 << 19) | (4 << 16) | 5, (3 << 19) | (6 << 16) | 5, 0x1000000, -1):
        dac.write(bad)
    assert dac.n_unknown == 4
    assert (dac.input, dac.dac) == before


def test_ad5664r_write_many_equals_word_by_word():
    """The inline decode of plain data writes leaves the DAC exactly as ``write`` per word, whatever the mix."""
    cfg = default_config()
    rng = np.random.default_rng(4)
    special = [0x280001, 0x280000, 0x380001, 0x380000, 0x20000F, 0x200031, 0x300000, 0x30000F, 0x300005,
               (1 << 19) | (7 << 16), (3 << 19) | (2 << 16) | 77, (0 << 19) | (7 << 16) | 99,
               (2 << 19) | (7 << 16) | 5, (0 << 19) | (5 << 16) | 1, 0x1000000, -3]
    pool = special + list(INIT_WORDS) + [w for v in (-1.0, 0.3, 2.0) for w in fsm_words(v, -v, cfg)]
    a, b = AD5664R(), AD5664R()
    seen_mask = seen_ref = False
    for _ in range(300):
        words = [pool[i] for i in rng.integers(0, len(pool), int(rng.integers(1, 9)))]
        for w in words:
            a.write(w)
        b.write_many(words)
        state = lambda d: (d.input, d.dac, d.powered, d.ref_on, d.ldac_mask, d.n_words, d.n_unknown, d.outputs())
        assert state(a) == state(b)
        seen_mask |= a.ldac_mask != 0
        seen_ref |= a.ref_on and a.outputs() != [0, 0, 0, 0]
    assert a.n_unknown > 0 and seen_mask and seen_ref      # fallbacks, transparent LDAC and live outputs seen


def test_mems_range_clips_and_bench_counts_it():
    b = Bench(noise=False)
    b.spi_words(INIT_WORDS)
    b.spi_words(fsm_words(2.45, 0.0, b.config))                # X curve passes 1.25 deg before 2.45 V
    assert b.m.clipped
    assert b.m.umx == pytest.approx(1.25 * DEG)
    for _ in range(3):
        b.advance_tick([0x8000] * 17, [0x8000] * 17)
    assert b.counters()["mems_clip_ticks"] == 3
    b.spi_words(fsm_words(1.0, 0.0, b.config))
    b.advance_tick([0x8000] * 17, [0x8000] * 17)
    assert b.counters()["mems_clip_ticks"] == 3


def _step_response(modal, dt, n):
    steps = modal.step(dt)
    z = [0j] * len(steps)
    y = []
    for _ in range(n):
        z = [p * zi + g * 1.0 for (p, g), zi in zip(steps, z)]
        y.append(modal.output(z))
    return np.array(y)


def test_pfsm_step_response_matches_second_order_closed_form():
    cfg = default_config()
    p = PFSM(cfg)
    wn, zeta = 2 * math.pi * cfg["pfsm"]["natural_hz"], cfg["pfsm"]["damping"]
    dt = 1 / 10600
    y = _step_response(p.modal, dt, 60)
    t = dt * np.arange(1, 61)
    wd = wn * math.sqrt(1 - zeta ** 2)
    want = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * t))
    assert np.max(np.abs(y - want)) < 1e-12
    assert p.modal.bandwidth_hz() > 850.0                      # Table 7.2


def test_mems_step_response_matches_ode_and_bandwidth():
    cfg = default_config()
    m = MEMS(cfg)
    dt = 1 / 637.8 / 17
    y = _step_response(m.modal, dt, 120)
    # independent check: RK4 on the state-space cascade with a fine step
    a, b, c = m.modal.a, m.modal.b_ss, m.modal.c_ss
    x = np.zeros(4)
    h = dt / 50
    ref = []
    f = lambda s: a @ s + b
    for _ in range(120):
        for _ in range(50):
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        ref.append(c @ x)
    assert np.max(np.abs(y - np.array(ref))) < 1e-7
    assert y[-1] == pytest.approx(1.0, abs=0.02)
    bw = m.modal.bandwidth_hz()
    assert 650.0 < bw < 2 * cfg["mems"]["resonance_hz"]      # > 650 Hz (Table 7.2)
    assert abs(m.modal.response(bw)) == pytest.approx(0.5 ** 0.5, rel=1e-6)


def test_modal_bandwidth_follows_configuration():
    slow = Modal([(200.0, 0.7071)])
    fast = Modal([(2000.0, 0.7071)])
    assert slow.bandwidth_hz() == pytest.approx(200.0, rel=1e-3)   # Butterworth: -3 dB at f_n
    assert fast.bandwidth_hz() == pytest.approx(2000.0, rel=1e-3)


# --- optics ----------------------------------------------------------------------------------------------
def test_resizer_exit_pupil_eq_7_2():
    f1, f2 = 0.05, 0.10
    for z1 in (0.0, 0.03, 0.05, 0.07):
        z2 = exit_pupil_z2(f1, f2, z1)
        assert z2 == pytest.approx(f2 / f1 * (f1 + f2 - f2 / f1 * z1))
        m = resizer_matrix(f1, f2, z1, z2)
        assert m[0, 1] == pytest.approx(0.0, abs=1e-15)              # any angle passes x2 = 0
        assert m[1, 1] == pytest.approx(-f1 / f2)                       # angular magnification
        assert m[0, 0] == pytest.approx(-f2 / f1)                       # beam resizing
    # off the pupil the beam walks by B alpha, B = f1 + f2 - (f2/f1) z1 - (f1/f2) z2 (Eq. 7.1)
    m = resizer_matrix(f1, f2, 0.05, 0.13)
    assert m[0, 1] == pytest.approx(f1 + f2 - f2 / f1 * 0.05 - f1 / f2 * 0.13)


def test_bench_beam_does_not_walk_on_fsm_and_spot_is_2mm():
    o = Optics(default_config())
    assert o.walk == pytest.approx(0.0, abs=1e-15)
    assert o.ang_mag == pytest.approx(-0.5)
    assert 2 * o.spot["q1"][0] == pytest.approx(2.0e-3, rel=0.01)     # 1 mm beam x 2 (Sec. 7.2.1)
    cfg = default_config()
    cfg["resizer"]["fsm_offset_m"] = 0.02
    assert Optics(cfg).walk == pytest.approx(-0.05 / 0.10 * 0.02)     # B = -(f1/f2) dz off the pupil


def test_eq_7_8_pfsm_volts_per_arcsec_and_sky_error():
    b = Bench(noise=False)
    assert b.pfsm_v_for_error(1.0) == pytest.approx(0.012343, rel=2e-4)
    b.spi_words(INIT_WORDS)
    b.spi_words(fsm_words(0.0, 0.0, b.config))
    for err in (-30.0, 12.0):
        v = b.pfsm_v_for_error(err)
        b.settle((v, v))
        ex, ey = b.true_error_arcsec()
        assert ex + b.bore[0] * b._sky == pytest.approx(err, rel=1e-9)
        assert ey + b.bore[1] * b._sky == pytest.approx(err, rel=1e-9)
    # the FSM cancels it: theta_e + 2 theta_FSM / 13.33 (Eq. 7.5)
    b.settle((0.0, 0.0))
    b.spi_words(fsm_words(0.1, 0.0, b.config))
    b.settle((0.0, 0.0))
    ex0 = b.true_error_arcsec()[0] + b.bore[0] * b._sky
    assert ex0 == pytest.approx(2 * b.m.umx * ARCSEC_PER_RAD / 13.33, rel=1e-9)


# --- true H ----------------------------------------------------------------------------------------------
def test_true_h_at_centre_resembles_eq_7_18():
    pt = Bench(noise=False).true_h((0.0, 0.0), 0.01)
    (a, b), (c, d) = pt["H"]
    for got, want in ((a, -8.5221), (c, 0.0717), (b, -0.0370), (d, 7.6871)):
        assert math.copysign(1, got) == math.copysign(1, want)
        assert abs(got - want) <= 0.2 * abs(want)
    assert pt["v0"][0] == pytest.approx(0.0374, abs=0.01) and abs(pt["v0"][1]) < 0.01
    assert pt["residual"] < 1e-3


def test_true_h_x_varies_more_than_y_and_nulls_near_1p5_v():
    b = Bench(noise=False)
    centre = np.array(b.true_h((0.0, 0.0))["H"])
    dx, dy, v0s = [], [], []
    for p in ((-5.0, -5.0), (5.0, 5.0), (-5.0, 5.0), (5.0, -5.0)):
        pt = b.true_h(p)
        h = np.array(pt["H"])
        dx.append(np.linalg.norm(h[:, 0] - centre[:, 0]) / np.linalg.norm(centre[:, 0]))
        dy.append(np.linalg.norm(h[:, 1] - centre[:, 1]) / np.linalg.norm(centre[:, 1]))
        v0s.append(np.abs(pt["v0"]))
    assert max(dx) > 3 * max(dy)
    assert 0.05 < max(dx) < 0.15 and max(dy) < 0.02                # Fig. 7-17: 0.05-12 %, 0-1.4 %
    assert np.all((np.array(v0s) > 1.2) & (np.array(v0s) < 1.8))


def test_true_h_follows_a_rotated_quadcell_and_unequal_gains():
    """The calibration acceptance config: Q1 rotated 30 deg, unequal MEMS axis gains."""
    base = np.array(Bench(noise=False).true_h((0.0, 0.0))["H"])
    cfg = default_config()
    cfg["q1"]["misalignment_deg"] = 30.0
    cfg["mems"]["gain_error"] = [0.15, -0.15]
    pt = Bench(cfg, noise=False).true_h((0.0, 0.0))
    h = np.array(pt["H"])
    assert pt["residual"] < 1e-3
    # the columns scale with the axis gains; the rotation mixes X and Y by sin 30 deg
    for col, g0, g1 in ((0, 0.02, 0.15), (1, -0.08, -0.15)):
        assert np.linalg.norm(h[:, col]) == pytest.approx(np.linalg.norm(base[:, col]) * (1 + g1) / (1 + g0),
                                                          rel=0.02)
    assert abs(h[1, 0] / h[0, 0]) == pytest.approx(math.tan(30 * DEG), rel=0.05)


def test_spot_ellipticity_scales_h_along_the_minor_axis():
    cfg = default_config()
    cfg["laser"]["ellipticity"] = 0.8                    # minor axis along the beam's y
    round_h = np.array(Bench(noise=False).true_h((0.0, 0.0))["H"])
    ell_h = np.array(Bench(cfg, noise=False).true_h((0.0, 0.0))["H"])
    assert ell_h[0, 0] == pytest.approx(round_h[0, 0], rel=0.01)
    assert ell_h[1, 1] == pytest.approx(round_h[1, 1] / 0.8, rel=0.03)


def test_q1_noise_matches_its_budget_and_grows_off_centre():
    b = Bench(seed=7)
    b.spi_words(INIT_WORDS)
    b.spi_words(fsm_words(0.0375, -0.0026, b.config))
    b.settle()
    centre = np.array([b.q1_sample() for _ in range(4000)], dtype=float)
    k = b.adc1.k
    want = math.hypot(k * b.q1.noise_sigma_v(0.0, 0.0), b.config["adc_q1"]["noise_counts"])
    assert np.std(centre[:, 0]) == pytest.approx(math.sqrt(want ** 2 + 1 / 12), rel=0.1)   # + quantization
    cfg = default_config()
    cfg["q1"]["position_noise_v_per_m"] = 2.0
    off = Bench(cfg, seed=7)
    off.spi_words(INIT_WORDS)
    off.spi_words(fsm_words(0.0375 + 0.1, -0.0026, off.config))
    off.settle()
    samples = np.array([off.q1_sample() for _ in range(4000)], dtype=float)
    assert np.std(samples[:, 2]) > 1.5 * np.std(centre[:, 2])
