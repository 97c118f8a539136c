"""The uncertainty-aware notch width: closed form, and the rule the pipeline designs with."""

import math

import numpy as np
import pytest
import scipy.signal

from hilident.config.tables import NotchConfig, parse_config
from hilident.errors import ConfigError
from hilident.filters.notch import (
    NotchSpec,
    design_notch,
    interval_width_hz,
    notch_analog,
    width_for_attenuation_hz,
)
from hilident.ident.resonance import Resonance
from hilident.pipeline.notches import design_notches
from hilident.pipeline.records import notch_records

FS = 4000.0


def attenuation_freqz(biquad, frequencies_hz, fs=FS):
    _, h = scipy.signal.freqz(biquad.b, biquad.a, worN=np.atleast_1d(frequencies_hz), fs=fs)
    return -20.0 * np.log10(np.abs(h))


@pytest.mark.parametrize("fs", [FS, 250.0])
@pytest.mark.parametrize("target, depth", [(20.0, 40.0), (12.0, 30.0), (20.0, math.inf)])
def test_closed_form_width_is_the_least_that_reaches_the_target_on_the_discrete_notch(fs, target, depth):
    f0, ends = 50.0, [47.0, 53.0]
    width = width_for_attenuation_hz(f0, ends, target, depth, fs)
    at = attenuation_freqz(design_notch(NotchSpec(f0, width, depth), fs), ends, fs)
    assert at.min() == pytest.approx(target, abs=1e-6)  # exact at the worse end
    assert np.all(at >= target - 1e-6)
    narrower = attenuation_freqz(design_notch(NotchSpec(f0, 0.99 * width, depth), fs), ends, fs)
    assert narrower.min() < target


def test_closed_form_without_a_rate_is_exact_for_the_analog_prototype():
    f0, ends = 120.0, [110.0, 130.0]
    width = width_for_attenuation_hz(f0, ends, 20.0, 40.0)
    b_s, a_s = notch_analog(f0, width, 40.0)
    _, h = scipy.signal.freqs(b_s, a_s, worN=2 * np.pi * np.array(ends))
    assert (-20 * np.log10(np.abs(h))).min() == pytest.approx(20.0, abs=1e-9)


def test_interval_width_needs_nothing_without_an_interval_and_refuses_an_unreachable_target():
    assert interval_width_hz(50.0, float("nan"), 20.0, 30.0, FS) == 0.0
    assert interval_width_hz(50.0, 0.0, 20.0, 30.0, FS) == 0.0
    with pytest.raises(ConfigError, match="attenuation_db"):
        interval_width_hz(50.0, 0.5, 30.0, 30.0, FS)
    with pytest.raises(ConfigError, match="frequency_ci95_hz"):
        interval_width_hz(50.0, -0.5, 20.0, 30.0, FS)
    with pytest.raises(ConfigError, match="Nyquist"):
        width_for_attenuation_hz(1900.0, [1800.0, 2100.0], 20.0, 30.0, FS)


def resonance(f, zeta, ci):
    return Resonance(frequency_hz=f, damping_ratio=zeta, peak_magnitude_db=20.0, coherence=0.99, frequency_ci95_hz=ci)


def test_a_narrow_resonance_with_a_wide_interval_gets_the_wider_notch():
    # 2 zeta f = 0.5 Hz, the floor 1 Hz; the interval +-0.2 Hz needs about 4 Hz for 20 dB at its ends
    cfg = NotchConfig(width_factor=1.0, min_width_ratio=0.02, min_reduction_db=0.0, target_attenuation_db=20.0)
    res = resonance(50.0, 0.005, 0.2)
    (d,) = design_notches([res], cfg, FS, [0])
    assert d.width_reason == "frequency uncertainty"
    assert d.spec.width_hz > 3.0 * max(2 * 0.005 * 50.0, 0.02 * 50.0)
    at = attenuation_freqz(d.biquad, [50.0 - 0.2, 50.0 + 0.2])
    assert at.min() >= 20.0 - 1e-6
    assert d.attenuation_at_ci95_db == pytest.approx(at.min(), abs=1e-6)
    (rec,) = notch_records([d])
    assert rec["width_reason"] == "frequency uncertainty"
    assert rec["attenuation_at_ci95_db"] == pytest.approx(at.min(), abs=1e-6)


def test_a_wide_resonance_keeps_the_width_of_its_bandwidth():
    cfg = NotchConfig(width_factor=1.0, min_width_ratio=0.02, min_reduction_db=0.0, target_attenuation_db=20.0)
    (d,) = design_notches([resonance(50.0, 0.1, 0.1)], cfg, FS, [0])
    assert d.width_reason == "resonance bandwidth"
    assert d.spec.width_hz == pytest.approx(2 * 0.1 * 50.0)
    assert attenuation_freqz(d.biquad, [49.9, 50.1]).min() >= 20.0
    (floor,) = design_notches([resonance(50.0, 0.001, 0.01)], NotchConfig(min_reduction_db=0.0), FS, [0])
    assert floor.width_reason == "minimum width ratio"
    assert floor.spec.width_hz == pytest.approx(NotchConfig().min_width_ratio * 50.0)


def test_a_width_grown_for_the_band_figure_says_so():
    cfg = NotchConfig(width_factor=1.0, min_width_ratio=0.02, min_reduction_db=20.0)
    (d,) = design_notches([resonance(50.0, 0.02, 0.01)], cfg, FS, [0])
    assert d.spec.width_hz > max(2 * 0.02 * 50.0, 0.02 * 50.0, interval_width_hz(50.0, 0.01, 20.0, 30.0, FS))
    assert d.width_reason == "band figure"


LIMITS = "[limits]\ntorque_nm = 10\nvelocity_mps = 1\nposition_min_m = -1\nposition_max_m = 1\n"


def test_target_key_has_a_default_and_is_checked():
    assert parse_config(LIMITS).notch.target_attenuation_db == 20.0
    assert parse_config(LIMITS + "[notch]\ntarget_attenuation_db = 26\n").notch.target_attenuation_db == 26.0
    with pytest.raises(ConfigError, match="notch.target_attenuation_db"):
        parse_config(LIMITS + "[notch]\ntarget_attenuation_db = -1\n", "bench.toml")
