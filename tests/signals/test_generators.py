"""Tests of the basic excitation generators against analytic truth."""

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError, DataError
from hilident.signals import (
    band_limited_noise,
    chirp,
    crest_factor,
    fade,
    prbs,
    sine,
    square,
    step,
)


def _instantaneous_frequency(x, fs):
    phase = np.unwrap(np.angle(scipy.signal.hilbert(x)))
    return np.diff(phase) * fs / (2 * np.pi)


# --------------------------------------------------------------------------- sine / square / step


def test_sine_values_and_length():
    x = sine(2.0, 50.0, 1.0, 1000.0)
    assert x.dtype == np.float64 and x.shape == (1000,)
    assert x[0] == pytest.approx(0.0, abs=1e-12)
    assert x[5] == pytest.approx(2.0)  # quarter period of 50 Hz is 5 ms
    assert x[15] == pytest.approx(-2.0)
    spectrum = np.abs(np.fft.rfft(x))
    assert np.argmax(spectrum) == 50  # 1 s record: bin k is k Hz


def test_sine_phase():
    x = sine(1.0, 10.0, 0.1, 1000.0, phase_rad=np.pi / 2)
    assert x[0] == pytest.approx(1.0)


def test_square_levels_and_duty():
    x = square(3.0, 10.0, 1.0, 1000.0, duty=0.25)
    assert set(np.unique(x)) == {-3.0, 3.0}
    assert np.mean(x > 0) == pytest.approx(0.25, abs=0.01)
    assert x[0] == 3.0
    assert crest_factor(x) == pytest.approx(1.0)


def test_step_index():
    x = step(-1.5, 1.0, 100.0, step_time_s=0.25)
    assert np.all(x[:25] == 0.0)
    assert np.all(x[25:] == -1.5)
    assert step(1.0, 0.1, 100.0)[0] == 1.0


# --------------------------------------------------------------------------- chirp


def test_linear_chirp_follows_its_frequency_law():
    fs, duration, f0, f1 = 2000.0, 4.0, 5.0, 200.0
    x = chirp(1.5, f0, f1, duration, fs)
    assert x[0] == pytest.approx(0.0, abs=1e-12)  # starts without a step
    assert np.max(np.abs(x)) == pytest.approx(1.5, rel=1e-3)
    fi = _instantaneous_frequency(x, fs)
    t = (np.arange(fi.size) + 0.5) / fs
    interior = (t > 0.4) & (t < duration - 0.4)  # Hilbert edge effects
    slope, intercept = np.polyfit(t[interior], fi[interior], 1)
    assert intercept == pytest.approx(f0, abs=0.3)
    assert intercept + slope * duration == pytest.approx(f1, abs=0.3)


def test_log_chirp_follows_its_frequency_law():
    fs, duration, f0, f1 = 2000.0, 4.0, 10.0, 400.0
    x = chirp(1.0, f0, f1, duration, fs, method="logarithmic")
    fi = _instantaneous_frequency(x, fs)
    t = (np.arange(fi.size) + 0.5) / fs
    interior = (t > 0.4) & (t < duration - 0.4)
    slope, intercept = np.polyfit(t[interior], np.log(fi[interior]), 1)
    assert np.exp(intercept) == pytest.approx(f0, rel=0.02)
    assert np.exp(intercept + slope * duration) == pytest.approx(f1, rel=0.02)


def test_downward_chirp():
    fs = 1000.0
    fi = _instantaneous_frequency(chirp(1.0, 100.0, 10.0, 2.0, fs), fs)
    assert np.median(fi[200:400]) > np.median(fi[1600:1800])


# --------------------------------------------------------------------------- noise


def _band_energy_fraction(x, fs, f_min, f_max):
    p = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(x.size, 1 / fs)
    inside = (f >= f_min) & (f <= f_max)
    return p[~inside].sum() / p.sum(), p, f


def test_noise_rms_band_and_flatness():
    fs = 1000.0
    x = band_limited_noise(0.7, 20.0, 120.0, 20.0, fs, seed=3)
    assert x.shape == (20000,)
    assert np.sqrt(np.mean(x**2)) == pytest.approx(0.7, rel=1e-12)
    outside, p, f = _band_energy_fraction(x, fs, 20.0, 120.0)
    assert outside < 1e-20
    lower = p[(f >= 20) & (f < 70)].sum()
    upper = p[(f >= 70) & (f <= 120)].sum()
    assert 0.8 < lower / upper < 1.25  # flat in the band


def test_noise_seed_reproducible():
    a = band_limited_noise(1.0, 1.0, 50.0, 2.0, 500.0, seed=11)
    b = band_limited_noise(1.0, 1.0, 50.0, 2.0, 500.0, seed=11)
    c = band_limited_noise(1.0, 1.0, 50.0, 2.0, 500.0, seed=12)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)


def test_noise_peak_limit_keeps_band():
    fs = 1000.0
    free = band_limited_noise(1.0, 5.0, 200.0, 10.0, fs, seed=1)
    assert np.max(np.abs(free)) > 3.0  # Gaussian noise: the limit below really bites
    x = band_limited_noise(1.0, 5.0, 200.0, 10.0, fs, seed=1, peak=1.8)
    assert np.max(np.abs(x)) <= 1.8
    rms = np.sqrt(np.mean(x**2))
    assert 0.8 < rms <= 1.0 + 1e-12
    assert _band_energy_fraction(x, fs, 5.0, 200.0)[0] < 1e-20


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    peak_over_rms=st.floats(1.0, 4.0),
)
def test_noise_never_exceeds_peak(seed, peak_over_rms):
    x = band_limited_noise(0.5, 10.0, 100.0, 1.0, 1000.0, seed=seed, peak=0.5 * peak_over_rms)
    assert np.max(np.abs(x)) <= 0.5 * peak_over_rms
    assert np.sqrt(np.mean(x**2)) <= 0.5 * (1 + 1e-12)


# --------------------------------------------------------------------------- PRBS


@pytest.mark.parametrize("n", [2, 5, 7, 10])
def test_prbs_period_balance_and_levels(n):
    x = prbs(0.4, n, 1, 1000.0)
    length = 2**n - 1
    assert x.shape == (length,)
    assert set(np.unique(x)) == {-0.4, 0.4}
    assert np.sum(x > 0) == 2 ** (n - 1)
    assert np.sum(x < 0) == 2 ** (n - 1) - 1


def test_prbs_is_maximum_length():
    # circular autocorrelation of a +-1 m-sequence: L at lag 0, -1 at every other lag
    s = prbs(1.0, 7, 1, 1000.0)
    acf = np.real(np.fft.ifft(np.abs(np.fft.fft(s)) ** 2))
    assert acf[0] == pytest.approx(127.0)
    np.testing.assert_allclose(acf[1:], -1.0, atol=1e-9)


def test_prbs_hold_and_periods():
    x = prbs(1.0, 6, 4, 1000.0, periods=3)
    period = 63 * 4
    assert x.size == 3 * period
    assert np.array_equal(x[:period], x[period : 2 * period])
    assert np.array_equal(x[:period], x[2 * period :])
    bits = x[:period].reshape(63, 4)
    assert np.all(bits == bits[:, :1])  # each bit held clock_divider samples
    assert np.array_equal(bits[:, 0], prbs(1.0, 6, 1, 1000.0))


# --------------------------------------------------------------------------- fade / crest


def test_fade_raised_cosine():
    fs = 1000.0
    x = np.ones(1000)
    y = fade(x, 0.1, fs)
    assert y[0] == 0.0 and y[-1] == pytest.approx(0.0, abs=1e-15)
    assert y[50] == pytest.approx(0.5)
    assert np.all(y[100:900] == 1.0)
    assert np.all(np.diff(y[:100]) > 0)
    np.testing.assert_allclose(y[:100], y[::-1][:100])
    assert np.all(x == 1.0)  # input untouched


def test_fade_zero_ramp_is_copy():
    x = np.arange(5.0)
    y = fade(x, 0.0, 100.0)
    assert np.array_equal(x, y) and y is not x


def test_crest_factor_known_values():
    assert crest_factor(sine(1.0, 10.0, 1.0, 1000.0)) == pytest.approx(np.sqrt(2), rel=1e-9)
    assert crest_factor([1.0, -1.0, 1.0]) == pytest.approx(1.0)
    assert crest_factor([0.0, 0.0, 3.0]) == pytest.approx(np.sqrt(3))
    with pytest.raises(DataError):
        crest_factor(np.zeros(4))
    with pytest.raises(DataError):
        crest_factor([])


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "call, key",
    [
        (lambda: sine(1.0, 600.0, 1.0, 1000.0), "frequency_hz"),
        (lambda: sine(1.0, 500.0, 1.0, 1000.0), "frequency_hz"),
        (lambda: sine(1.0, 10.0, 0.0, 1000.0), "duration_s"),
        (lambda: sine(1.0, 10.0, 1e-5, 1000.0), "duration_s"),
        (lambda: sine(1.0, 10.0, 1.0, -1.0), "sample_rate_hz"),
        (lambda: sine(float("nan"), 10.0, 1.0, 1000.0), "amplitude"),
        (lambda: square(1.0, 10.0, 1.0, 1000.0, duty=1.0), "duty"),
        (lambda: chirp(1.0, 1.0, 600.0, 1.0, 1000.0), "f1_hz"),
        (lambda: chirp(1.0, 0.0, 100.0, 1.0, 1000.0, method="logarithmic"), "f0_hz"),
        (lambda: chirp(1.0, 1.0, 100.0, 1.0, 1000.0, method="cubic"), "method"),
        (lambda: step(1.0, 1.0, 100.0, step_time_s=1.0), "step_time_s"),
        (lambda: band_limited_noise(1.0, 100.0, 50.0, 1.0, 1000.0, seed=0), "f_min_hz"),
        (lambda: band_limited_noise(1.0, 10.0, 600.0, 1.0, 1000.0, seed=0), "f_max_hz"),
        (lambda: band_limited_noise(1.0, 10.0, 100.0, 1.0, 1000.0, seed=0, peak=0.5), "peak"),
        (lambda: band_limited_noise(0.0, 10.0, 100.0, 1.0, 1000.0, seed=0), "rms"),
        (lambda: band_limited_noise(1.0, 10.0, 100.0, 1.0, 1000.0, seed=None), "seed"),
        (lambda: band_limited_noise(1.0, 10.2, 10.8, 1.0, 1000.0, seed=0), "duration_s"),
        (lambda: prbs(1.0, 1, 1, 1000.0), "register_length"),
        (lambda: prbs(1.0, 33, 1, 1000.0), "register_length"),
        (lambda: prbs(1.0, 7.5, 1, 1000.0), "register_length"),
        (lambda: prbs(1.0, 7, 0, 1000.0), "clock_divider"),
        (lambda: prbs(1.0, 7, 1, 1000.0, periods=0), "periods"),
        (lambda: fade(np.ones(10), 0.6, 10.0), "ramp_s"),
    ],
)
def test_invalid_arguments_name_the_key(call, key):
    with pytest.raises(ConfigError) as info:
        call()
    assert info.value.key == key
    assert f"[{key}]" in str(info.value)


def test_nyquist_message_names_the_limit():
    with pytest.raises(ConfigError, match="Nyquist frequency 500 Hz, got 600"):
        band_limited_noise(1.0, 10.0, 600.0, 1.0, 1000.0, seed=0)


@pytest.mark.parametrize(
    "build, key",
    [
        (lambda: prbs(1.0, 32, 1, 1000.0), "register_length"),
        (lambda: prbs(1.0, 10, 2**40, 1000.0), "clock_divider"),
        (lambda: prbs(1.0, 20, 1, 1000.0, periods=10**6), "periods"),
        (lambda: sine(1.0, 10.0, 1e9, 1000.0), "duration_s"),
        (lambda: band_limited_noise(1.0, 1.0, 10.0, 1e300, 1000.0, seed=1), "duration_s"),
    ],
)
def test_signals_beyond_the_size_bound_are_refused_before_allocating(build, key):
    import tracemalloc

    tracemalloc.start()
    try:
        with pytest.raises(ConfigError) as err:
            build()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert err.value.key == key and "(2**25)" in str(err.value) and peak < 4 * 2**20


def test_numpy_values_are_printed_plainly():
    with pytest.raises(ConfigError) as err:
        sine(np.float64(np.nan), 10.0, 1.0, 1000.0)
    assert str(err.value) == "[amplitude] must be finite, got nan"
    with pytest.raises(ConfigError, match=r"got 2\.5$"):
        prbs(1.0, np.float64(2.5), 1, 1000.0)
