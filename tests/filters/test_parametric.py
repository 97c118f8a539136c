"""Sections drives build from physical parameters, and the notch a stored section achieves."""

import math

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch
from hilident.filters.parametric import (
    achieved_notch,
    attenuation_db,
    notch_width_hz,
    rejection_band_section,
    two_frequency_section,
)

RATE = 4000.0


def analog_quadratic(f_hz, damping, s):
    w = 2 * np.pi * f_hz
    return s * s / w**2 + 2 * damping * s / w + 1


@settings(max_examples=30, deadline=None)
@given(fz=st.floats(5.0, 1600.0), fp=st.floats(5.0, 1600.0), dz=st.floats(0.0, 2.0), dp=st.floats(0.01, 2.0))
def test_two_frequency_section_is_each_quadratic_prewarped_at_its_own_frequency(fz, fp, dz, dp):
    section = two_frequency_section(fz, dz, fp, dp, RATE)
    f = np.array([1.0, 0.5 * fz, fz, fp, 1.7 * fp, 0.45 * RATE])
    t = np.tan(np.pi * f / RATE)
    kz = 2 * np.pi * fz / np.tan(np.pi * fz / RATE)
    kp = 2 * np.pi * fp / np.tan(np.pi * fp / RATE)
    expected = analog_quadratic(fz, dz, 1j * kz * t) / analog_quadratic(fp, dp, 1j * kp * t)
    np.testing.assert_allclose(section.response(f, RATE), expected, rtol=1e-7, atol=1e-9)
    assert section.dc_gain() == pytest.approx(1.0, abs=1e-9)


def test_two_frequency_section_with_one_frequency_is_the_designed_notch():
    spec = NotchSpec(300.0, 60.0, 30.0)
    dp = spec.width_hz / (2 * spec.center_hz)
    section = two_frequency_section(300.0, dp * 10 ** (-30 / 20), 300.0, dp, RATE)
    designed = design_notch(spec, RATE)
    np.testing.assert_allclose(section.b, designed.b, rtol=1e-12)
    np.testing.assert_allclose(section.a, designed.a, rtol=1e-12)


def test_two_frequency_section_refuses_what_no_drive_can_run():
    with pytest.raises(DataError, match="half the 4000 Hz"):
        two_frequency_section(2500.0, 0.1, 300.0, 0.1, RATE)
    with pytest.raises(DataError, match="damping"):
        two_frequency_section(300.0, -0.1, 300.0, 0.1, RATE)
    with pytest.raises(DataError, match="damping"):
        two_frequency_section(300.0, 0.1, 300.0, 0.0, RATE)


def vendor_rejection_band(x, center_hz, band_hz, rate):
    """The vendor's difference equation as published, with its own sign convention."""
    f, bw = center_hz / rate, band_hz / rate
    r = 1 - 3 * bw
    c = math.cos(2 * math.pi * f)
    k = (1 - 2 * r * c + r * r) / (2 - 2 * c)
    a0, a1, a2, b1, b2 = k, -2 * k * c, k, 2 * r * c, -r * r
    y = np.zeros_like(x)
    for n in range(len(x)):
        y[n] = (
            a0 * x[n]
            + (a1 * x[n - 1] if n >= 1 else 0)
            + (a2 * x[n - 2] if n >= 2 else 0)
            + (b1 * y[n - 1] if n >= 1 else 0)
            + (b2 * y[n - 2] if n >= 2 else 0)
        )
    return y


def test_rejection_band_section_runs_the_vendor_difference_equation():
    x = np.random.default_rng(3).standard_normal(400)
    section = rejection_band_section(120.0, 15.0, RATE)
    got = scipy.signal.lfilter(section.b, section.a, x)
    np.testing.assert_allclose(got, vendor_rejection_band(x, 120.0, 15.0, RATE), rtol=1e-10, atol=1e-12)
    assert section.dc_gain() == pytest.approx(1.0, abs=1e-12)
    assert attenuation_db(section, 120.0, RATE) > 200.0  # zeros on the unit circle
    # the -3 dB band is close to 3 band / pi for a narrow band
    f = np.linspace(60.0, 180.0, 240001)
    below = f[np.abs(section.response(f, RATE)) < 2**-0.5]
    assert below[-1] - below[0] == pytest.approx(3 * 15.0 / math.pi, rel=0.03)


def test_rejection_band_section_refuses_a_band_beyond_the_rate():
    with pytest.raises(DataError, match="pole radius"):
        rejection_band_section(120.0, 2000.0, RATE)
    with pytest.raises(DataError, match="half the"):
        rejection_band_section(2000.0, 10.0, RATE)


@settings(max_examples=40, deadline=None)
@given(center=st.floats(5.0, 1600.0), rel_width=st.floats(0.05, 1.0), depth=st.floats(3.0, 60.0))
def test_achieved_notch_inverts_the_design(center, rel_width, depth):
    spec = NotchSpec(center, rel_width * center, depth)
    got = achieved_notch(design_notch(spec, RATE), RATE, center * 1.1)
    assert got.center_hz == pytest.approx(center, rel=1e-6)
    assert got.width_hz == pytest.approx(spec.width_hz, rel=1e-6)
    assert got.depth_db == pytest.approx(depth, abs=1e-4)


def test_achieved_notch_of_something_that_is_no_notch():
    boost = design_notch(NotchSpec(300.0, 60.0, 20.0), RATE)
    b0 = boost.b[0]
    inverse = Biquad(tuple(x / b0 for x in boost.a), tuple(x / b0 for x in boost.b))  # a resonator
    with pytest.raises(DataError, match="does not attenuate"):
        achieved_notch(inverse, RATE, 300.0)
    assert notch_width_hz(Biquad.identity(), RATE, 300.0) == 0.0
