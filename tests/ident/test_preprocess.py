import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.preprocess import (
    bandpass,
    central_difference,
    check_signals,
    detrend,
    highpass,
    lowpass,
    remove_drift,
)

FS = 1000.0


def sine(freq_hz, n=4000, fs=FS, amplitude=1.0):
    return amplitude * np.sin(2 * np.pi * freq_hz * np.arange(n) / fs)


# --- check_signals -----------------------------------------------------------


def test_check_signals_returns_float64_copies():
    raw = {"torque": [1, 2, 3, 4] * 5, "velocity": np.arange(20, dtype=np.float32)}
    out = check_signals(raw)
    assert set(out) == {"torque", "velocity"}
    for x in out.values():
        assert x.dtype == np.float64 and x.shape == (20,)
    out["velocity"][0] = 99.0
    assert raw["velocity"][0] == 0.0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_check_signals_names_nonfinite_signal(bad):
    v = np.arange(50.0)
    v[17] = bad
    with pytest.raises(DataError, match=r"'velocity'.*index 17"):
        check_signals({"torque": np.arange(50.0), "velocity": v})


def test_check_signals_names_length_mismatch():
    with pytest.raises(DataError, match=r"'position' has 40 samples but 'torque' has 50"):
        check_signals({"torque": np.arange(50.0), "position": np.arange(40.0)})


def test_check_signals_too_few_samples():
    with pytest.raises(DataError, match=r"'torque' has 10 samples, at least 16"):
        check_signals({"torque": np.arange(10.0)})
    assert check_signals({"torque": np.arange(10.0)}, min_samples=10)["torque"].size == 10


def test_check_signals_constant_signal():
    with pytest.raises(DataError, match=r"'velocity' is constant"):
        check_signals({"torque": np.arange(20.0), "velocity": np.full(20, 0.3)})


def test_check_signals_rejects_2d():
    with pytest.raises(DataError, match=r"'torque' must be 1-D"):
        check_signals({"torque": np.ones((4, 20))})


# --- detrend -----------------------------------------------------------------


def test_detrend_linear_removes_line_keeps_oscillation():
    t = np.arange(2000) / FS
    osc = sine(7.0, 2000)
    out = detrend(3.0 + 2.5 * t + osc, kind="linear")
    # what remains is the oscillation minus its own (small) LS line
    assert np.allclose(out, detrend(osc, "linear"), atol=1e-12)
    assert abs(out.mean()) < 1e-12
    assert np.polyfit(t, out, 1)[0] == pytest.approx(0.0, abs=1e-10)


def test_detrend_linear_of_a_long_record_equals_scipy_in_bounded_memory():
    rng = np.random.default_rng(5)
    n = 2_000_001  # several blocks of the time axis, the last one partial
    x = 4.0 - 3e-5 * np.arange(n) + rng.standard_normal(n)
    want = signal.detrend(x, type="linear")
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        got = detrend(x, "linear")
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)
    # the result (8 bytes a sample) and one block of the time axis; a whole time axis would add 8 more
    assert peak < 12 * n, f"{peak / n:.1f} bytes a sample"


def test_detrend_constant_removes_mean_only():
    x = np.arange(100.0)
    out = detrend(x, kind="constant")
    assert np.allclose(out, x - 49.5)


def test_detrend_bad_kind():
    with pytest.raises(ConfigError, match="kind"):
        detrend(np.arange(10.0), kind="quadratic")


# --- filters -----------------------------------------------------------------


def test_lowpass_passes_slow_rejects_fast_without_phase_shift():
    slow, fast = sine(2.0), sine(200.0)
    out = lowpass(slow + fast, cutoff_hz=20.0, sample_rate_hz=FS)
    core = slice(500, -500)  # away from the edges
    assert np.max(np.abs(out[core] - slow[core])) < 1e-3  # zero phase: no lag
    # 4th-order Butterworth run twice: (200/20)^-16 ~ -160 dB for the 200 Hz part
    assert np.std(out[core] - slow[core]) < 1e-4


def test_lowpass_is_minus_6_db_at_cutoff():
    x = sine(50.0, 8000)
    out = lowpass(x, cutoff_hz=50.0, sample_rate_hz=FS, order=3)
    core = slice(2000, -2000)
    gain = np.std(out[core]) / np.std(x[core])
    assert gain == pytest.approx(0.5, rel=0.02)


def test_highpass_and_bandpass():
    slow, mid, fast = sine(1.0, 8000), sine(40.0, 8000), sine(300.0, 8000)
    core = slice(2000, -2000)
    hp = highpass(slow + fast, cutoff_hz=50.0, sample_rate_hz=FS)
    assert np.max(np.abs(hp[core] - fast[core])) < 1e-3
    bp = bandpass(slow + mid + fast, 20.0, 80.0, FS)
    assert np.max(np.abs(bp[core] - mid[core])) < 2e-2


@pytest.mark.parametrize("cutoff", [500.0, 600.0, 0.0, -1.0, np.nan])
def test_lowpass_cutoff_must_be_below_nyquist(cutoff):
    with pytest.raises(ConfigError, match="cutoff_hz"):
        lowpass(sine(5.0), cutoff_hz=cutoff, sample_rate_hz=FS)


def test_bandpass_band_checks():
    with pytest.raises(ConfigError, match="high_hz"):
        bandpass(sine(5.0), 10.0, 500.0, FS)
    with pytest.raises(ConfigError, match="low_hz"):
        bandpass(sine(5.0), 80.0, 20.0, FS)
    with pytest.raises(ConfigError, match="sample_rate_hz"):
        highpass(sine(5.0), 10.0, 0.0)


def test_filter_too_short_signal_is_data_error():
    with pytest.raises(DataError, match="too short"):
        lowpass(np.ones(5), 10.0, FS, order=4)


@settings(max_examples=25, deadline=None)
@given(
    offset=st.floats(-100, 100),
    cutoff=st.floats(1.0, 400.0),
    order=st.integers(1, 6),
)
def test_lowpass_keeps_dc(offset, cutoff, order):
    out = lowpass(np.full(600, offset), cutoff, FS, order=order)
    assert np.allclose(out, offset, atol=1e-9 * max(1.0, abs(offset)))


# --- differentiation ---------------------------------------------------------


def test_central_difference_of_sine_is_cosine():
    f = 3.0
    t = np.arange(3000) / FS
    pos = 0.01 * np.sin(2 * np.pi * f * t)
    vel = central_difference(pos, FS)
    truth = 0.01 * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    # central difference error ~ (w T)^2 / 6 relative inside
    assert np.max(np.abs(vel[1:-1] - truth[1:-1])) < 0.01 * 2 * np.pi * f * 1e-4
    assert np.max(np.abs(vel - truth)) < 0.01 * 2 * np.pi * f * 0.02  # one-sided ends


@settings(max_examples=25, deadline=None)
@given(a=st.floats(-10, 10), b=st.floats(-10, 10), c=st.floats(-10, 10))
def test_central_difference_exact_for_quadratic_inside(a, b, c):
    t = np.arange(200) / 100.0
    x = a + b * t + c * t**2
    d = central_difference(x, 100.0)
    assert np.allclose(d[1:-1], b + 2 * c * t[1:-1], atol=1e-8)


# --- remove_drift --------------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(coefs=st.lists(st.floats(-5.0, 5.0), min_size=4, max_size=4), periods=st.integers(2, 9), tail=st.integers(0, 99))
def test_remove_drift_takes_a_cubic_and_leaves_any_periodic_signal(coefs, periods, tail):
    rng = np.random.default_rng(periods * 100 + tail)
    period = 100
    one_period = rng.standard_normal(period)
    n = periods * period + tail
    periodic = np.resize(one_period, n)
    t = np.linspace(-1.0, 1.0, n)
    drift = np.polynomial.polynomial.polyval(t, coefs)
    y = remove_drift(periodic + drift, period_samples=period)
    expected = periodic - periodic[: periods * period].mean()
    assert np.allclose(y, expected, atol=1e-9 * (1 + np.abs(coefs).sum()))


def test_remove_drift_without_two_periods_removes_a_line_only():
    x = sine(3.0) + np.linspace(0.0, 2.0, 4000)
    assert np.array_equal(remove_drift(x), detrend(x, "linear"))
    assert np.array_equal(remove_drift(x, period_samples=3000), detrend(x, "linear"))


def test_a_cubic_fit_alone_would_bend_a_periodic_response_that_remove_drift_keeps():
    # the response of a two-period record: an ordinary cubic detrend takes part of its lowest line
    period = 500
    x = np.resize(sine(2.0, n=period), 2 * period)
    t = np.linspace(-1.0, 1.0, x.size)
    plain = x - np.polynomial.legendre.Legendre.fit(t, x, 3)(t)
    assert np.max(np.abs(plain - x)) > 0.05
    assert np.max(np.abs(remove_drift(x, period_samples=period) - (x - x.mean()))) < 1e-12
