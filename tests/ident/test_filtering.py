"""RC low-pass, moving average and decimation against their analytic responses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError, DataError
from hilident.ident.filtering import (
    decimate,
    decimation_filter,
    moving_average,
    rc_alpha,
    rc_lowpass,
)


def tone(f_hz, fs, n, phase=0.0):
    return np.cos(2.0 * np.pi * f_hz * np.arange(n) / fs + phase)


def lock_in(y, f_hz, fs, start=0):
    """Complex amplitude of the f_hz component of y[start:] (an integer number of periods)."""
    n = np.arange(start, y.size)
    return 2.0 * np.mean(y[start:] * np.exp(-2j * np.pi * f_hz * n / fs))


# --- RC low-pass (thesis eqs. 2.64-2.67) --------------------------------------


def test_rc_matches_the_difference_equation_sample_by_sample():
    rng = np.random.default_rng(0)
    x = rng.standard_normal(300) + 2.0
    fc, fs = 15.0, 1000.0
    rc = 1.0 / (2.0 * math.pi * fc)
    dt = 1.0 / fs
    for initial, y_prev in (("zero", 0.0), ("first", x[0])):
        expected = []
        for xi in x:
            # eq. 2.65 solved for y_i: RC (y_i - y_{i-1}) / dt = x_i - y_i
            y_prev = (xi + rc / dt * y_prev) / (1.0 + rc / dt)
            expected.append(y_prev)
        got = rc_lowpass(x, fc, fs, initial=initial)
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(ratio=st.floats(min_value=0.002, max_value=0.1))
def test_rc_gain_at_cutoff_is_minus_3db_within_the_discretisation_error(ratio):
    fs = 1000.0
    fc = ratio * fs
    # Whole periods of fc for the lock-in; the transient has died after 12 RC.
    period = fs / fc
    settle = int(12 * fs / (2 * math.pi * fc)) + 1
    n_periods = max(20, int(np.ceil(2000 / period)))
    n_lock = int(round(n_periods * period))
    # pick fc so that n_lock samples hold exactly n_periods periods
    fc = n_periods * fs / n_lock
    x = tone(fc, fs, settle + n_lock)
    y = rc_lowpass(x, fc, fs, initial="zero")
    gain_db = 20 * np.log10(abs(lock_in(y, fc, fs, start=settle)))
    w = 2 * math.pi * fc / fs
    lower = -10 * np.log10(2 + w)
    upper = -10 * np.log10(2 + w - w * w * (1 + w) / 12)
    # the derived bracket: -3.01 dB lowered by 10 log10(1 + w/2), up to O(w^2)
    assert lower - 1e-6 <= gain_db <= upper + 1e-6
    assert upper - lower < 0.25 * w * w  # tight next to the O(w) offset


def test_rc_settled_start_passes_a_constant_and_decays_like_the_rc_circuit():
    fs, fc = 2000.0, 5.0
    np.testing.assert_allclose(rc_lowpass(np.full(100, 3.5), fc, fs), 3.5, rtol=1e-12)
    y = rc_lowpass(np.ones(2000), fc, fs, initial="zero")
    tau_samples = fs / (2 * math.pi * fc)  # RC in samples (63.7)
    # step response 1 - (1 - alpha)^(i+1) vs the circuit's 1 - exp(-t/RC): close when dt << RC
    t = np.arange(2000) / fs
    np.testing.assert_allclose(y, 1 - np.exp(-t * 2 * math.pi * fc), atol=1.0 / tau_samples)


def test_rc_filters_along_the_last_axis():
    x = np.vstack([np.zeros(50), np.ones(50)])
    y = rc_lowpass(x, 10.0, 100.0, initial="zero")
    assert y.shape == x.shape
    assert np.all(y[0] == 0.0)
    np.testing.assert_allclose(y[1], rc_lowpass(x[1], 10.0, 100.0, initial="zero"))


# --- moving average -------------------------------------------------------------


@pytest.mark.parametrize("n_taps", [4, 5, 10, 21])
def test_moving_average_removes_tones_at_multiples_of_fs_over_n(n_taps):
    fs = 1000.0
    n = 4000
    for k in range(1, (n_taps - 1) // 2 + 1):
        f = k * fs / n_taps
        y = moving_average(tone(f, fs, n, phase=0.3), n_taps)
        assert np.max(np.abs(y[n_taps:])) < 1e-12
    # midway between two zeros the tone passes with the Dirichlet kernel's gain
    f = 1.5 * fs / n_taps  # period 2 n_taps / 3 samples: 3 periods in 2 n_taps samples
    w = 2 * np.pi * f / fs
    expected = abs(np.sin(n_taps * w / 2) / (n_taps * np.sin(w / 2)))
    y = moving_average(tone(f, fs, n_taps + 100 * 2 * n_taps), n_taps, initial="zero")
    assert abs(lock_in(y, f, fs, start=n_taps)) == pytest.approx(expected, rel=1e-9)


def test_moving_average_is_the_mean_of_the_last_n_samples():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(200)
    y = moving_average(x, 7, initial="zero")
    padded = np.concatenate([np.zeros(6), x])
    expected = [padded[i : i + 7].mean() for i in range(200)]
    np.testing.assert_allclose(y, expected, atol=1e-14)
    y1 = moving_average(x, 7)  # "first": history equal to x[0]
    padded = np.concatenate([np.full(6, x[0]), x])
    np.testing.assert_allclose(y1, [padded[i : i + 7].mean() for i in range(200)], atol=1e-14)
    np.testing.assert_array_equal(moving_average(x, 1), x)


# --- decimation -----------------------------------------------------------------


@pytest.mark.parametrize("factor", [4, 8, 10])
def test_decimate_suppresses_aliases_by_60db_and_keeps_the_band(factor):
    fs = 4000.0
    fs_new = fs / factor
    n = 64000  # 16 s: 1/16 Hz resolution, every tone below on an exact bin
    f_in = round(0.3 * fs_new)  # in band
    f_alias_target = round(0.25 * fs_new)
    f_high = fs_new - f_alias_target  # above new Nyquist; folds onto f_alias_target
    f_near = fs_new / 2 + 5.0  # just above new Nyquist; folds to fs_new/2 - 5
    x = tone(f_in, fs, n) + tone(f_high, fs, n, 0.4) + tone(f_near, fs, n, 1.1)
    y, rate = decimate(x, factor, fs)
    assert rate == fs_new
    assert y.size == math.ceil(n / factor)
    edge = 200  # drop the edges: the padding is only an approximation there
    start = edge
    kept = lock_in(y[: y.size - edge], f_in, fs_new, start=start)
    assert abs(20 * np.log10(abs(kept))) < 0.1
    # phase kept too: the filter's delay is removed
    assert abs(np.angle(kept)) < 1e-3
    for f_folded in (f_alias_target, fs_new - f_near):
        alias = abs(lock_in(y[: y.size - edge], f_folded, fs_new, start=start))
        assert 20 * np.log10(alias) < -60
    # without the filter the alias is there at full amplitude: the test can fail
    naive = x[::factor]
    assert abs(lock_in(naive[: naive.size - edge], f_alias_target, fs_new, start=start)) > 0.9


def test_decimation_filter_meets_its_specification():
    from scipy.signal import freqz

    taps = decimation_filter(8, attenuation_db=80.0, passband_fraction=0.8)
    assert taps.size % 2 == 1
    np.testing.assert_allclose(taps, taps[::-1])  # linear phase
    f = np.linspace(0, 0.5, 4001)  # cycles per sample
    _, h = freqz(taps, worN=2 * np.pi * f)
    mag_db = 20 * np.log10(np.abs(h) + 1e-300)
    passband = f <= 0.8 / 16
    stopband = f >= 1 / 16
    assert np.max(np.abs(mag_db[passband])) < 0.01
    assert np.max(mag_db[stopband]) < -79.0


def test_decimate_factor_one_and_axis():
    x = np.arange(20.0).reshape(2, 10)
    y, rate = decimate(x, 1, 100.0)
    np.testing.assert_array_equal(y, x)
    assert rate == 100.0
    y, rate = decimate(np.vstack([np.ones(400), 2 * np.ones(400)]), 4, 100.0)
    assert y.shape == (2, 100) and rate == 25.0
    np.testing.assert_allclose(y, [[1.0] * 100, [2.0] * 100], atol=1e-9)


def test_decimate_keeps_a_ramp_straight_at_the_edges():
    fs = 1000.0
    x = 0.5 + 0.2 * np.arange(3000) / fs  # a drifting position
    y, _ = decimate(x, 5, fs)
    np.testing.assert_allclose(y, x[::5], atol=1e-6)


# --- argument checks ------------------------------------------------------------


@pytest.mark.parametrize(
    "call, key",
    [
        (lambda: rc_lowpass(np.ones(10), 600.0, 1000.0), "cutoff_hz"),
        (lambda: rc_lowpass(np.ones(10), -1.0, 1000.0), "cutoff_hz"),
        (lambda: rc_lowpass(np.ones(10), 10.0, 0.0), "sample_rate_hz"),
        (lambda: rc_lowpass(np.ones(10), 10.0, 100.0, initial="last"), "initial"),
        (lambda: rc_alpha(10.0, float("nan")), "sample_rate_hz"),
        (lambda: moving_average(np.ones(10), 0), "n_taps"),
        (lambda: moving_average(np.ones(10), 2.5), "n_taps"),
        (lambda: decimate(np.ones(10), 0, 100.0), "factor"),
        (lambda: decimate(np.ones(10), True, 100.0), "factor"),
        (lambda: decimate(np.ones(100), 2, -5.0), "sample_rate_hz"),
        (lambda: decimate(np.ones(100), 2, 100.0, attenuation_db=5.0), "attenuation_db"),
        (lambda: decimate(np.ones(100), 2, 100.0, passband_fraction=1.0), "passband_fraction"),
    ],
)
def test_bad_arguments_name_the_argument(call, key):
    with pytest.raises(ConfigError) as err:
        call()
    assert err.value.key == key
    assert key in str(err.value)


@pytest.mark.parametrize(
    "call",
    [
        lambda: rc_lowpass([1.0, np.nan, 2.0], 10.0, 100.0),
        lambda: moving_average([1.0, np.inf], 2),
        lambda: decimate(np.ones(3), 4, 100.0),
        lambda: rc_lowpass(3.0, 10.0, 100.0),
    ],
)
def test_unusable_data_raises_data_error(call):
    with pytest.raises(DataError):
        call()
