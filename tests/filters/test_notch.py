"""Notch design: analog prototype, pre-warped Tustin, quantisation, chains."""

import math

import numpy as np
import pytest
import scipy.optimize
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError, DataError
from hilident.filters import notch
from hilident.filters.biquad import Biquad, BiquadSection
from hilident.filters.notch import (
    NotchSpec,
    chain_response,
    design_notch,
    float32_biquad,
    notch_analog,
    notch_from_resonance,
    quantize_biquad,
    tustin_prewarped,
)


def db(h):
    return 20.0 * np.log10(np.abs(h))


def analog_mag(b_s, a_s, f):
    _, h = scipy.signal.freqs(b_s, a_s, worN=2 * np.pi * np.atleast_1d(f))
    return np.abs(h)


def deepest(biquad, center_hz, fs):
    """Frequency and magnitude of the deepest point near ``center_hz`` (bounded search)."""
    lo, hi = 0.8 * center_hz, min(1.2 * center_hz, 0.4999 * fs)
    res = scipy.optimize.minimize_scalar(
        lambda f: abs(biquad.response(f, fs)),
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 1e-10 * center_hz},
    )
    return res.x, res.fun


def half_power_edges(mag, center_hz, f_max_hz=None):
    """The two -3 dB frequencies of a notch with unit gain far from the centre."""
    g = lambda f: mag(f) ** 2 - 0.5  # noqa: E731
    top = 1e3 * center_hz if f_max_hz is None else f_max_hz
    f1 = scipy.optimize.brentq(g, 1e-6 * center_hz, center_hz, xtol=1e-14 * center_hz)
    f2 = scipy.optimize.brentq(g, center_hz, top, xtol=1e-14 * center_hz)
    return f1, f2


# --------------------------------------------------------------------------- analog prototype


def test_analog_width_is_half_power_bandwidth_of_infinite_notch():
    f0, width = 120.0, 17.0
    b_s, a_s = notch_analog(f0, width, math.inf)
    assert b_s[1] == 0.0  # eq. 2.63: zeros on the imaginary axis
    f1, f2 = half_power_edges(lambda f: analog_mag(b_s, a_s, f)[0], f0)
    assert f2 - f1 == pytest.approx(width, rel=1e-9)
    assert f1 * f2 == pytest.approx(f0**2, rel=1e-9)


@pytest.mark.parametrize("depth_db", [6.0, 20.0, 40.0])
def test_analog_depth_and_minimum_at_centre(depth_db):
    f0 = 50.0
    b_s, a_s = notch_analog(f0, 10.0, depth_db)
    assert db(analog_mag(b_s, a_s, f0)[0]) == pytest.approx(-depth_db, abs=1e-9)
    f = np.linspace(20.0, 80.0, 6001)
    assert f[np.argmin(analog_mag(b_s, a_s, f))] == pytest.approx(f0, abs=0.01)
    # same poles as the infinite notch: a finite depth attenuates less at the edges
    f1, f2 = half_power_edges(lambda x: analog_mag(*notch_analog(f0, 10.0, math.inf), x)[0], f0)
    assert np.all(db(analog_mag(b_s, a_s, [f1, f2])) > -3.0103)


# --------------------------------------------------------------------------- Tustin


@pytest.mark.parametrize(
    "b_s, a_s",
    [
        ([1.0, 3.0, 2.0e4], [1.0, 150.0, 2.0e4]),
        ([2.0, 0.0, 5.0e5], [1.0, 40.0, 4.0e5]),
        ([0.0, 1.0, 300.0], [0.0, 1.0, 30.0]),  # first order
        ([5.0], [1.0, 20.0, 1.0e4]),
    ],
)
def test_tustin_matches_scipy_bilinear_with_warped_rate(b_s, a_s):
    fs, fp = 2000.0, 300.0
    k = 2 * np.pi * fp / np.tan(np.pi * fp / fs)
    bz, az = scipy.signal.bilinear(np.trim_zeros(b_s, "f"), np.trim_zeros(a_s, "f"), fs=k / 2)
    got = tustin_prewarped(b_s, a_s, fs, fp)
    np.testing.assert_allclose(got.a, np.pad(az, (0, 3 - len(az))), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(got.b, np.pad(bz, (0, 3 - len(bz))), rtol=1e-10, atol=1e-12)
    # and the response is matched exactly at the pre-warp frequency
    h_analog = scipy.signal.freqs(b_s, a_s, worN=[2 * np.pi * fp])[1][0]
    assert got.response(fp, fs) == pytest.approx(h_analog, rel=1e-10)


def test_tustin_rejects_third_order():
    with pytest.raises(DataError):
        tustin_prewarped([1.0], [1.0, 2.0, 3.0, 4.0], 1000.0, 100.0)


# --------------------------------------------------------------------------- design_notch


@pytest.mark.parametrize(
    "center_hz, fs",
    [
        (20.0, 4000.0),
        (120.0, 1000.0),
        (300.0, 1000.0),
        (1200.0, 4000.0),
        (440.0, 1000.0),
        (3.0, 16000.0),
    ],
)
@pytest.mark.parametrize("depth_db", [10.0, 30.0])
def test_centre_lands_exactly_at_center_hz(center_hz, fs, depth_db):
    spec = NotchSpec(center_hz, 0.15 * center_hz, depth_db)
    bq = design_notch(spec, fs)
    assert db(bq.response(center_hz, fs)) == pytest.approx(-depth_db, abs=0.01)
    f_min, h_min = deepest(bq, center_hz, fs)
    assert f_min == pytest.approx(center_hz, rel=1e-5)
    assert db(h_min) == pytest.approx(-depth_db, abs=0.01)


def test_without_prewarping_the_centre_would_miss():
    fs, center = 1000.0, 300.0
    b_s, a_s = notch_analog(center, 30.0, 30.0)
    bz, az = scipy.signal.bilinear(b_s, a_s, fs=fs)
    plain = Biquad(tuple(bz), tuple(az))
    f_plain, _ = deepest(plain, center, fs)
    assert abs(f_plain - center) > 0.05 * center  # plain Tustin lands far off ...
    f_warped, _ = deepest(design_notch(NotchSpec(center, 30.0, 30.0), fs), center, fs)
    assert f_warped == pytest.approx(center, rel=1e-6)  # ... pre-warped does not


def test_unity_gain_at_dc_and_far_away():
    fs = 8000.0
    bq = design_notch(NotchSpec(200.0, 20.0, 40.0), fs)
    assert abs(bq.dc_gain() - 1.0) < 1e-12
    assert abs(bq.response(fs / 2, fs)) == pytest.approx(1.0, abs=1e-12)  # s = inf maps to Nyquist
    far = np.array([1.0, 10.0, 20.0, 2000.0, 3900.0])
    assert np.all(np.abs(db(bq.response(far, fs))) < 0.05)


def test_digital_width_is_the_warped_analog_width():
    fs, center, width = 1000.0, 250.0, 40.0
    bq = design_notch(NotchSpec(center, width, math.inf), fs)
    f1, f2 = half_power_edges(lambda f: abs(bq.response(f, fs)), center, fs / 2)
    k = 2 * np.pi * center / np.tan(np.pi * center / fs)
    analog_edges = k * np.tan(np.pi * np.array([f1, f2]) / fs) / (2 * np.pi)
    assert analog_edges[1] - analog_edges[0] == pytest.approx(width, rel=1e-8)
    assert f2 - f1 < width  # warping narrows it near Nyquist


def test_digital_width_at_low_centre_matches_width_hz():
    fs, center, width = 10000.0, 50.0, 8.0
    bq = design_notch(NotchSpec(center, width, math.inf), fs)
    f1, f2 = half_power_edges(lambda f: abs(bq.response(f, fs)), center, fs / 2)
    assert f2 - f1 == pytest.approx(width, rel=1e-3)


def test_running_section_attenuates_a_sine_at_the_centre():
    fs, center, depth = 2000.0, 80.0, 26.0
    bq = design_notch(NotchSpec(center, 16.0, depth), fs)
    section = BiquadSection(bq)
    t = np.arange(4000) / fs
    y = np.array([section.step(x) for x in np.sin(2 * np.pi * center * t)])
    steady = y[2000:]
    assert np.max(np.abs(steady)) == pytest.approx(10 ** (-depth / 20), rel=0.02)


def test_design_raises_on_centre_at_nyquist():
    with pytest.raises(ConfigError) as info:
        design_notch(NotchSpec(500.0, 20.0, 30.0), 1000.0)
    assert info.value.key == "center_hz"
    assert "500 Hz" in str(info.value)


def test_design_rejects_bad_dc_gain(monkeypatch):
    bad = Biquad((1.0, -1.9, 0.91 + 1e-6), (1.0, -1.9, 0.91))
    monkeypatch.setattr(notch, "tustin_prewarped", lambda *args: bad)
    with pytest.raises(DataError, match="DC gain"):
        design_notch(NotchSpec(20.0, 2.0, 30.0), 4000.0)


def test_design_rejects_unstable_section(monkeypatch):
    bad = Biquad((1.0, -2.0, 1.0), (1.0, -2.0, 1.0))
    monkeypatch.setattr(notch, "tustin_prewarped", lambda *args: bad)
    with pytest.raises(DataError, match="unstable"):
        design_notch(NotchSpec(20.0, 2.0, 30.0), 4000.0)


@settings(max_examples=60, deadline=None)
@given(
    center_ratio=st.floats(0.002, 0.45),
    relative_width=st.floats(0.01, 1.5),
    depth_db=st.floats(3.0, 60.0),
    fs=st.sampled_from([500.0, 1000.0, 4000.0, 8000.0, 16000.0]),
)
def test_property_design(center_ratio, relative_width, depth_db, fs):
    center = center_ratio * fs
    bq = design_notch(NotchSpec(center, relative_width * center, depth_db), fs)
    assert np.all(np.abs(bq.poles()) < 1.0)
    assert abs(bq.dc_gain() - 1.0) <= 1e-9
    h0 = abs(bq.response(center, fs))
    assert db(h0) == pytest.approx(-depth_db, abs=0.01)
    nearby = center * np.array([1 - 1e-3, 1 + 1e-3])
    nearby = nearby[nearby < fs / 2]
    assert np.all(np.abs(bq.response(nearby, fs)) >= h0)
    assert np.all(np.abs(bq.response(np.linspace(0, fs / 2, 257), fs)) <= 1.0 + 1e-9)


# --------------------------------------------------------------------------- notch_from_resonance


def test_notch_from_resonance_rule():
    spec = notch_from_resonance(100.0, 0.05, depth_db=25.0)
    assert spec == NotchSpec(100.0, 2.0 * 2 * 0.05 * 100.0, 25.0)
    lightly_damped = notch_from_resonance(100.0, 0.001)
    assert lightly_damped.width_hz == pytest.approx(10.0)  # floor: 10 % of the frequency
    assert lightly_damped.depth_db == 30.0
    assert notch_from_resonance(100.0, 0.05, width_factor=3.0).width_hz == pytest.approx(30.0)
    with pytest.raises(ConfigError) as info:
        notch_from_resonance(100.0, 1.2)
    assert info.value.key == "damping_ratio"


def test_notch_from_resonance_covers_the_resonance_peak():
    # the notch's -3 dB band contains the resonance's half-power band
    f, zeta = 60.0, 0.03
    spec = notch_from_resonance(f, zeta)
    b_s, a_s = notch_analog(spec.center_hz, spec.width_hz, math.inf)
    f1, f2 = half_power_edges(lambda x: analog_mag(b_s, a_s, x)[0], f)
    assert f1 < f * (1 - zeta) and f2 > f * (1 + zeta)


# --------------------------------------------------------------------------- quantisation


def test_quantised_20hz_notch_at_4khz_keeps_working():
    fs = 4000.0
    spec = notch_from_resonance(20.0, 0.02, depth_db=30.0)
    q = quantize_biquad(design_notch(spec, fs), fractional_bits=16)
    coefficients = np.array(q.b + q.a[1:]) * 2**16
    np.testing.assert_array_equal(coefficients, np.round(coefficients))  # on the grid
    assert np.all(np.abs(q.poles()) < 1.0)
    assert q.dc_gain() == 1.0
    f_min, h_min = deepest(q, 20.0, fs)
    assert db(h_min) == pytest.approx(-30.0, abs=1.0)
    assert abs(f_min - 20.0) < 0.1 * spec.width_hz


def test_too_coarse_formats_raise():
    bq = design_notch(NotchSpec(20.0, 2.0, 30.0), 4000.0)
    with pytest.raises(DataError, match="unstable"):
        quantize_biquad(bq, fractional_bits=8)  # a2 rounds onto the unit circle
    with pytest.raises(DataError, match="overflows"):
        quantize_biquad(bq, fractional_bits=15, total_bits=16)  # a1 ~ -2 needs Q2.x
    with pytest.raises(ConfigError) as info:
        quantize_biquad(bq, fractional_bits=32, total_bits=32)
    assert info.value.key == "fractional_bits"


def test_quantise_without_dc_correction_is_plain_rounding():
    bq = design_notch(NotchSpec(20.0, 4.0, 30.0), 4000.0)
    q = quantize_biquad(bq, 16, preserve_dc=False)
    np.testing.assert_array_equal(q.b, np.round(np.array(bq.b) * 2**16) / 2**16)
    np.testing.assert_array_equal(q.a, np.round(np.array(bq.a) * 2**16) / 2**16)


def test_float32_biquad():
    bq = design_notch(NotchSpec(150.0, 20.0, 30.0), 8000.0)
    q = float32_biquad(bq)
    for x in q.b + q.a:
        assert float(np.float32(x)) == x
    assert np.all(np.abs(q.poles()) < 1.0)
    assert db(q.response(150.0, 8000.0)) == pytest.approx(-30.0, abs=0.5)


# --------------------------------------------------------------------------- chains


def test_chain_response_is_product_and_matches_sos():
    fs = 4000.0
    sections = [
        design_notch(NotchSpec(80.0, 10.0, 30.0), fs),
        design_notch(NotchSpec(310.0, 40.0, 20.0), fs),
    ]
    f = np.linspace(1.0, 1999.0, 500)
    h = chain_response(sections, f, fs)
    sos = np.array([s.b + s.a for s in sections])
    _, h_ref = scipy.signal.sosfreqz(sos, worN=f, fs=fs)
    np.testing.assert_allclose(h, h_ref, rtol=1e-9, atol=1e-12)
    assert db(chain_response(sections, 80.0, fs)) == pytest.approx(-30.0, abs=0.3)
    np.testing.assert_array_equal(chain_response([], f, fs), np.ones_like(f))


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "call, key",
    [
        (lambda: NotchSpec(0.0, 1.0, 30.0), "center_hz"),
        (lambda: NotchSpec(10.0, -1.0, 30.0), "width_hz"),
        (lambda: NotchSpec(10.0, 1.0, 0.0), "depth_db"),
        (lambda: NotchSpec(10.0, 1.0, float("nan")), "depth_db"),
        (lambda: notch_analog(10.0, 0.0, 30.0), "width_hz"),
        (lambda: tustin_prewarped([1, 0, 1], [1, 1, 1], 1000.0, 500.0), "prewarp_hz"),
        (lambda: design_notch(NotchSpec(10.0, 1.0, 30.0), 0.0), "sample_rate_hz"),
        (lambda: notch_from_resonance(-5.0, 0.1), "frequency_hz"),
        (lambda: quantize_biquad(Biquad.identity(), 4, total_bits=1), "total_bits"),
    ],
)
def test_invalid_arguments_name_the_key(call, key):
    with pytest.raises(ConfigError) as info:
        call()
    assert info.value.key == key
