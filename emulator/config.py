"""Bench configuration: one JSON document holds every parameter of the emulated optical bench.

The default preset, "thesis bench", follows Ch. 7 of the thesis (Fig. 7-2/7-3, Tables 7.1-7.3) and is tuned so
the true H at the centre resembles Eq. 7.18. A user file overrides any subset of the keys; unknown keys,
wrong types and out-of-range values are refused with a ValueError naming the dotted key. Units are in the key
names (``_m``, ``_hz``, ``_deg``, ``_v``); a key with another unit (``wavelength_nm``) is unknown and refused.

Parameters not given by the thesis or the datasheets are marked "assumed" below.
"""

import copy
import json
import math


PRESET = "thesis bench"

_DEFAULT = {
    "preset": PRESET,
    "laser": {
        "power_w": 7.5e-4,            # assumed: gives Vs ~ 1.5 V on each quadcell behind the 50:50 splitter
        "wavelength_m": 633e-9,       # HeNe-like visible source (PDQ80A responsivity quoted at 633 nm)
        "waist_radius_m": 0.5e-3,     # 1/e^2 radius: "approximately 1 mm diameter" (Sec. 7.2.1)
        "ellipticity": 1.0,           # spot minor/major 1/e^2 radius ratio (1 = round)
        "ellipse_angle_deg": 0.0,     # major axis angle in the beam frame
    },
    "pfsm": {                          # Optics in Motion OIM5001 driven by two AD660 (Table 7.2)
        "range_deg": 3.0,             # mechanical, at +-range_v
        "range_v": 10.0,
        "natural_hz": 1100.0,         # assumed, gives a -3 dB bandwidth > 850 Hz
        "damping": 0.6,               # assumed
        "gain_error": [0.0, 0.0],     # relative, X and Y
    },
    "resizer": {                       # L1/L2 beam resizer (Sec. 7.2.1, Eq. 7.1-7.2)
        "f1_m": 0.050,
        "f2_m": 0.100,
        "z1_m": 0.050,                # P-FSM to L1
        "fsm_offset_m": 0.0,          # MEMS FSM distance beyond the exit pupil (0 = at the exit pupil)
    },
    "mems": {                          # Mirrorcle 13L2.2 behind an AD5664R driver (Table 7.2; the two datasheets)
        "deg_per_v": 0.5,             # mechanical tilt per tilt volt (Eq. 7.9)
        "range_deg": 1.25,            # mechanical clip
        "full_scale_tilt_v": 2.5,     # tilt volts for a differential of full_scale_codes
        "full_scale_codes": 32768,    # (code X+ - code X-)/2 giving full_scale_tilt_v
        "driver_cutoff_hz": 800.0,    # assumed, ~ f_resonance / 2.5 (Mirrorcle note)
        "resonance_hz": 2000.0,       # assumed
        "resonance_q": 15.0,          # assumed
        "gain_error": [0.02, -0.08],  # assumed, relative, X and Y (sets |h_x| > |h_y|, Eq. 7.18)
        "quadratic_per_v": [0.015, 0.0005],   # angle-voltage curve: V + q V^2 + c V^3 (X less linear)
        "cubic_per_v2": [0.010, 0.001],
        "cross_coupling": [0.0032, 0.0100],   # X angle += k0 * Y angle, Y angle += k1 * X angle
    },
    "splitter": {"q1_fraction": 0.5},  # 50:50 cube (Table 7.1): Q1 in the reflected arm
    "q1": {                            # Thorlabs PDQ80A (Table 7.3) in the reflected arm, via BS and AM
        "distance_m": 0.28,           # FSM to detector along the beam
        "rotation_deg": 180.0,        # BS + AM reflections image the beam rotated by 180 deg
        "misalignment_deg": 0.1,      # extra rotation about the optical axis
        "offset_m": [0.187e-3, -0.010e-3],  # detector centre off the beam axis (V0 ~ (0.037, -0.003) V)
        "radius_m": 3.9e-3,           # sensor diameter 7.8 mm
        "gap_m": 0.1e-3,              # assumed quadrant gap
        "responsivity_a_per_w": 0.4,
        "transimpedance_v_per_a": 1.0e4,
        "bandwidth_hz": 150e3,
        "noise_v": 1.0e-4,            # assumed electronics noise, 1 sigma per output
        "position_noise_v_per_m": 0.05,   # assumed, sigma grows with the spot's distance from the centre
        "amp_gain": 1.0,              # inverting amplifier gain G (docs/INTERFACES.md, Q1 chain)
    },
    "q2": {                            # second PDQ80A in the transmitted arm, recorder
        "distance_m": 0.25,
        "rotation_deg": 0.0,
        "misalignment_deg": -0.2,
        "offset_m": [-0.1749e-3, 0.0034e-3],  # assumed: no source gives it; set so Q2's boresight differs from
                                            # Q1's by the thesis's measured mean error (-0.49, -0.29)" (Sec. 7.5)
        "radius_m": 3.9e-3,
        "gap_m": 0.1e-3,
        "responsivity_a_per_w": 0.4,
        "transimpedance_v_per_a": 1.0e4,
        "bandwidth_hz": 150e3,
        "noise_v": 1.0e-4,
        "position_noise_v_per_m": 0.05,
        "amp_gain": 1.5,
    },
    "adc_q1": {                        # SAMD21 12-bit, 0-3.3 V (SAMD21 datasheet)
        "bits": 12,
        "vref_v": 3.3,
        "noise_counts": 0.7,          # assumed, 1 sigma
    },
    "adc_q2": {                        # ADS1256 24-bit two's complement, FS = 2 VREF / PGA
        "vref_v": 2.5,
        "pga": 1,
        "noise_counts": 8.0,          # assumed, 1 sigma
        "rate_hz": 630.0,
    },
    "flight_magnification": 13.33,    # Table 2.1, 80 mm / 6 mm, as used in Eq. 7.7-7.8
    "board": {                         # the controller board's timing in a tick (emulator.timing)
        "timing": "arduino-zero",     # arduino-zero (thesis board) | zero-latency (ideal) | custom
        "adc_read_us": 426.0,         # one analogRead, Arduino core defaults (ArduinoCore-samd's init() in wiring.c)
        "hold_before_end_us": 75.0,   # sample held 7 ADC clocks before the result (SAMD21 datasheet)
        "compute_us": 250.0,          # assumed: arithmetic, fills the 1568 us period with the SPI
        "spi_us": 40.0,               # 4 x 24-bit words at 4 MHz plus chip-select handling
    },
}

# Dotted key -> (lo, hi) for numbers (inclusive), or a tuple of choices for strings.
_RANGES = {
    "laser.power_w": (1e-7, 1.0),
    "laser.wavelength_m": (200e-9, 2e-6),
    "laser.waist_radius_m": (1e-5, 5e-3),
    "laser.ellipticity": (0.2, 1.0),
    "laser.ellipse_angle_deg": (-180.0, 180.0),
    "pfsm.range_deg": (0.01, 10.0),
    "pfsm.range_v": (0.1, 100.0),
    "pfsm.natural_hz": (10.0, 1e5),
    "pfsm.damping": (0.05, 0.99),
    "pfsm.gain_error": (-0.5, 0.5),
    "resizer.f1_m": (1e-3, 2.0),
    "resizer.f2_m": (1e-3, 2.0),
    "resizer.z1_m": (0.0, 2.0),
    "resizer.fsm_offset_m": (-1.0, 1.0),
    "mems.deg_per_v": (1e-3, 10.0),
    "mems.range_deg": (0.01, 20.0),
    "mems.full_scale_tilt_v": (0.01, 1000.0),
    "mems.full_scale_codes": (1, 65536),
    "mems.driver_cutoff_hz": (10.0, 1e5),
    "mems.resonance_hz": (10.0, 1e5),
    "mems.resonance_q": (0.55, 1000.0),
    "mems.gain_error": (-0.5, 0.5),
    "mems.quadratic_per_v": (-0.2, 0.2),
    "mems.cubic_per_v2": (-0.2, 0.2),
    "mems.cross_coupling": (-0.2, 0.2),
    "splitter.q1_fraction": (0.01, 0.99),
    "adc_q1.bits": (12, 12),           # the controller firmware reads 12-bit counts (TICK Q1: 0..4095)
    "adc_q1.vref_v": (0.5, 10.0),
    "adc_q1.noise_counts": (0.0, 100.0),
    "adc_q2.vref_v": (0.5, 5.0),
    "adc_q2.pga": (1, 64),
    "adc_q2.noise_counts": (0.0, 1e5),
    "adc_q2.rate_hz": (1.0, 30000.0),
    "flight_magnification": (0.1, 1000.0),
    "preset": None,
    "board.timing": ("arduino-zero", "zero-latency", "custom"),
    "board.adc_read_us": (0.1, 1e5),
    "board.hold_before_end_us": (0.0, 1e5),
    "board.compute_us": (0.0, 1e6),
    "board.spi_us": (0.0, 1e5),
}
for _q in ("q1", "q2"):
    _RANGES.update({
        _q + ".distance_m": (1e-3, 10.0),
        _q + ".rotation_deg": (-360.0, 360.0),
        _q + ".misalignment_deg": (-45.0, 45.0),
        _q + ".offset_m": (-5e-3, 5e-3),
        _q + ".radius_m": (1e-4, 0.05),
        _q + ".gap_m": (0.0, 1e-3),
        _q + ".responsivity_a_per_w": (1e-3, 2.0),
        _q + ".transimpedance_v_per_a": (1.0, 1e9),
        _q + ".bandwidth_hz": (1.0, 1e9),
        _q + ".noise_v": (0.0, 1.0),
        _q + ".position_noise_v_per_m": (0.0, 1e4),
        _q + ".amp_gain": (1e-3, 1e3),
    })
_INTEGER = {"mems.full_scale_codes", "adc_q1.bits", "adc_q2.pga"}


def default_config():
    """A fresh copy of the "thesis bench" preset."""
    return copy.deepcopy(_DEFAULT)


def _merge(base, over, path):
    if not isinstance(over, dict):
        raise ValueError("config %s: expected an object, got %r" % (path or "<root>", over))
    for key, val in over.items():
        dotted = path + "." + key if path else key
        if key not in base:
            raise ValueError("config key %r is unknown (known here: %s)"
                             % (dotted, ", ".join(sorted(base))))
        if isinstance(base[key], dict):
            _merge(base[key], val, dotted)
        else:
            base[key] = val


def _check_number(key, val, lo, hi):
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise ValueError("config %s: expected a number, got %r" % (key, val))
    if isinstance(val, int) and not -1e300 < val < 1e300:     # math.isfinite would raise OverflowError
        raise ValueError("config %s = an integer of %d bits is out of range [%g, %g]" % (key, val.bit_length(), lo,
                                                                                         hi))
    if not math.isfinite(val) or not lo <= val <= hi:
        raise ValueError("config %s = %r is out of range [%g, %g]" % (key, val, lo, hi))
    if key in _INTEGER and val != int(val):
        raise ValueError("config %s: expected an integer, got %r" % (key, val))


def _validate(cfg, ref, path=""):
    for key, ref_val in ref.items():
        dotted = path + "." + key if path else key
        val = cfg[key]
        if isinstance(ref_val, dict):
            _validate(val, ref_val, dotted)
            continue
        rng = _RANGES[dotted]
        if rng and isinstance(rng[0], str):
            if val not in rng:
                raise ValueError("config %s = %r is not one of %s" % (dotted, val, ", ".join(rng)))
        elif rng is None:
            if not isinstance(val, str):
                raise ValueError("config %s: expected a string, got %r" % (dotted, val))
        elif isinstance(ref_val, list):
            if not isinstance(val, list) or len(val) != len(ref_val):
                raise ValueError("config %s: expected a list of %d numbers, got %r"
                                 % (dotted, len(ref_val), val))
            for v in val:
                _check_number(dotted, v, *rng)
        else:
            _check_number(dotted, val, *rng)


def validate(cfg):
    """Merge a (partial) config over the preset, check its keys, types and ranges; return the merged config."""
    merged = default_config()
    _merge(merged, cfg, "")
    _validate(merged, _DEFAULT)
    m = merged
    if m["resizer"]["z1_m"] >= m["resizer"]["f1_m"] / m["resizer"]["f2_m"] * (
            m["resizer"]["f1_m"] + m["resizer"]["f2_m"]):
        raise ValueError("config resizer.z1_m = %g puts the exit pupil before L2 (Eq. 7.2): "
                         "need z1 < (f1/f2)(f1 + f2)" % m["resizer"]["z1_m"])
    if abs(m["mems"]["driver_cutoff_hz"] - m["mems"]["resonance_hz"]) < 1.0:
        raise ValueError("config mems.driver_cutoff_hz must differ from mems.resonance_hz")
    if m["board"]["hold_before_end_us"] >= m["board"]["adc_read_us"]:
        raise ValueError("config board.hold_before_end_us must be smaller than board.adc_read_us")
    for q in ("q1", "q2"):
        if m[q]["gap_m"] >= m[q]["radius_m"]:
            raise ValueError("config %s.gap_m must be smaller than %s.radius_m" % (q, q))
    return merged


def load_config(path=None):
    """Load and validate a JSON config file (None = the default preset), merged over the preset."""
    if path is None:
        return default_config()
    from emulator.fileio import read_json
    cfg = read_json(path, "config")
    try:
        return validate(cfg)
    except ValueError as exc:
        msg = str(exc)
        raise ValueError("config %s: %s" % (path, msg[7:] if msg.startswith("config ") else msg)) from None


def dumps(cfg):
    return json.dumps(cfg, indent=2, sort_keys=False) + "\n"

