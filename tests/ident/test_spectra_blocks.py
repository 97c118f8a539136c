"""Spectra summed a block of segments at a time: the same numbers as all at once, in memory bounded by the data."""

import tracemalloc

import numpy as np
import pytest
from scipy import signal

from hilident.ident.frequency import _cross_spectra, _period_sums, frf_from_reference, h1_estimate, welch_psd
from hilident.ident.frfquality import excited_band, input_spectrum

FS = 1000.0


def all_at_once(signals, pairs, nperseg, noverlap, window, detrend):
    """Every segment transformed at once and the products averaged: the reference."""
    win = signal.get_window(window, nperseg)
    ffts = {}
    for name, x in signals.items():
        seg = np.lib.stride_tricks.sliding_window_view(x, nperseg)[:: nperseg - noverlap]
        if detrend:
            seg = signal.detrend(seg, axis=-1, type=detrend)
        ffts[name] = np.fft.rfft(seg * win, axis=-1)
    return {(a, b): np.mean(np.conj(ffts[a]) * ffts[b], axis=0) for a, b in pairs}


def random_signals(n, seed):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n) + 0.3
    return {"r": u, "u": u + 0.1 * rng.standard_normal(n), "y": signal.lfilter([0.3, 0.1], [1.0, -0.7], u)}


@pytest.mark.parametrize(
    "nperseg, noverlap, detrend, block_samples",
    [
        (64, 32, "constant", 64 * 7),  # 7 segments a block, the last block partial
        (100, 37, "linear", 333),  # block not a multiple of the segment
        (50, 0, False, 1),  # one segment a block (the block is smaller than a segment)
        (256, 128, "constant", 10**9),  # one block holds everything
    ],
)
def test_blockwise_cross_spectra_equal_all_at_once(nperseg, noverlap, detrend, block_samples):
    sig = random_signals(10_007, seed=nperseg)
    pairs = [("r", "r"), ("u", "u"), ("y", "y"), ("r", "u"), ("r", "y"), ("u", "y")]
    got = _cross_spectra(sig, pairs, nperseg, noverlap, "hann", detrend, block_samples=block_samples)
    want = all_at_once(sig, pairs, nperseg, noverlap, "hann", detrend)
    assert set(got) == set(want)
    for pair in pairs:
        scale = np.max(np.abs(want[pair]))
        np.testing.assert_allclose(got[pair], want[pair], rtol=1e-11, atol=1e-13 * scale, err_msg=str(pair))


def test_blockwise_period_sums_equal_all_at_once():
    rng = np.random.default_rng(3)
    period, skip, n_periods = 96, 2, 23
    u = rng.standard_normal(period * 26 + 17)
    y = signal.lfilter([0.2], [1.0, -0.8], u) + 0.01 * rng.standard_normal(u.size)
    got = _period_sums(u, y, period, skip, n_periods, block_samples=period * 5)
    sl = slice(skip * period, (skip + n_periods) * period)
    U = np.fft.rfft(u[sl].reshape(n_periods, period), axis=-1)
    Y = np.fft.rfft(y[sl].reshape(n_periods, period), axis=-1)
    want = {
        "u": U.sum(axis=0),
        "y": Y.sum(axis=0),
        "uy": np.sum(np.conj(U) * Y, axis=0),
        "uu": np.sum(np.abs(U) ** 2, axis=0),
        "yy": np.sum(np.abs(Y) ** 2, axis=0),
    }
    for name, value in want.items():
        np.testing.assert_allclose(got[name], value, rtol=1e-11, atol=1e-12 * np.max(np.abs(value)), err_msg=name)


@pytest.mark.parametrize(
    "nperseg, noverlap, window, detrend, subtract",
    [
        (512, None, "hann", "constant", 0.0),  # scipy.signal.welch's defaults
        (301, None, "hann", "constant", 0.0),  # odd segment: no Nyquist bin
        (400, 0, "boxcar", False, 0.0),  # whole periods, as input_spectrum reads a multisine
        (256, None, "hann", False, 0.7),  # an offset taken off without detrending: DC and its leakage change
    ],
)
def test_welch_psd_equals_scipy_welch(nperseg, noverlap, window, detrend, subtract):
    x = random_signals(20_011, seed=7)["y"]
    f, p = welch_psd(x, FS, nperseg, noverlap=noverlap, window=window, detrend=detrend, subtract=subtract)
    f_ref, p_ref = signal.welch(x - subtract, fs=FS, window=window, nperseg=nperseg, noverlap=noverlap, detrend=detrend)
    np.testing.assert_array_equal(f, f_ref)
    np.testing.assert_allclose(p, p_ref, rtol=1e-10, atol=1e-14 * p_ref.max())


def traced_peak(fn, *args, **kwargs) -> int:
    """Peak of the memory ``fn`` allocates above what was held when it was called, bytes."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        fn(*args, **kwargs)
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


N_LONG = 2_000_000


@pytest.fixture(scope="module")
def long_record():
    sig = random_signals(N_LONG, seed=11)
    return sig["r"], sig["u"], sig["y"]


def test_h1_estimate_memory_bounded_by_the_data(long_record):
    r, _, y = long_record
    peak = traced_peak(h1_estimate, r, y, FS, 4000)
    # all segments at once held ~16 bytes a sample per signal in transforms alone, plus copies of both inputs
    assert peak < 40 * N_LONG, f"{peak / N_LONG:.1f} bytes a sample"


def test_reference_estimate_memory_bounded_by_the_data(long_record):
    peak = traced_peak(frf_from_reference, *long_record, FS, 4000)
    assert peak < 40 * N_LONG, f"{peak / N_LONG:.1f} bytes a sample"


def test_input_spectrum_and_excited_band_memory_bounded_by_the_data(long_record):
    r = long_record[0]
    # a block of segments; scipy.signal.welch on a centred copy held ~40 bytes a sample
    assert traced_peak(excited_band, r, FS, 4000) < 8 * N_LONG
    assert traced_peak(input_spectrum, r, FS, (1.0, 200.0)) < 8 * N_LONG


def test_input_spectrum_rms_and_crest_factor():
    t = np.arange(100_000) / FS
    x = 3.0 + 2.0 * np.sin(2 * np.pi * 17.0 * t)  # whole periods: rms sqrt(2), peak 2 about the mean
    spec = input_spectrum(x, FS, (5.0, 50.0))
    assert spec.rms == pytest.approx(np.sqrt(2.0), rel=1e-9)
    assert spec.crest_factor == pytest.approx(np.sqrt(2.0), rel=1e-6)
