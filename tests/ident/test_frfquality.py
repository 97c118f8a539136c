import numpy as np
import pytest
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse, h1_estimate
from hilident.ident.frfquality import check_resolution, frf_uncertainty, input_spectrum
from hilident.signals.generators import multisine

FS = 1000.0


def test_predicted_magnitude_error_matches_monte_carlo():
    # a resonant plant with output noise: 300 independent H1 estimates of 16 averages each
    b, a = signal.cheby1(4, 1.0, 0.2)
    rng = np.random.default_rng(4)
    seg, n_avg, trials = 256, 16, 300
    mags, predicted = [], []
    for _ in range(trials):
        u = rng.standard_normal(seg * n_avg)
        y = signal.lfilter(b, a, u) + 0.3 * rng.standard_normal(u.size)
        frf = h1_estimate(u, y, FS, seg, overlap=0.0)
        mags.append(np.abs(frf.response))
        predicted.append(frf_uncertainty(frf).magnitude_rel_std)
    mags, predicted = np.array(mags), np.array(predicted)
    true = np.abs(signal.freqz(b, a, worN=frf.frequency_hz, fs=FS)[1])
    band = (frf.frequency_hz > 20) & (frf.frequency_hz < 80)  # coherence 0.5 .. 0.95 here
    coh = frf.coherence[band]
    assert coh.min() > 0.3 and coh.max() < 0.99
    empirical = mags[:, band].std(axis=0) / true[band]
    ratio = empirical / np.median(predicted[:, band], axis=0)
    assert 0.8 < np.median(ratio) < 1.25
    # and the 95 % band holds the truth about 95 % of the time
    u95 = frf_uncertainty(frf, 0.95)
    inside = np.abs(mags[:, band] / true[band] - 1) <= 1.96 * predicted[:, band]
    assert 0.9 < inside.mean() < 0.99
    assert np.all(u95.upper_db[band] > 0) and np.all(u95.lower_db[band] < 0)


def test_uncertainty_shrinks_with_averages_and_coherence():
    f = np.array([1.0, 2.0, 3.0])
    h = np.ones(3, dtype=complex)
    few = frf_uncertainty(FrequencyResponse(f, h, np.array([0.5, 0.9, 0.99]), 4, "h1"))
    many = frf_uncertainty(FrequencyResponse(f, h, np.array([0.5, 0.9, 0.99]), 16, "h1"))
    assert np.all(np.diff(few.magnitude_rel_std) < 0)
    np.testing.assert_allclose(many.magnitude_rel_std, few.magnitude_rel_std / 2)
    zero = frf_uncertainty(FrequencyResponse(f, h, np.array([0.0, 0.5, 1.0]), 4, "h1"))
    assert np.isinf(zero.magnitude_rel_std[0]) and zero.lower_db[0] == -np.inf
    assert zero.magnitude_rel_std[2] == 0 and zero.upper_db[2] == 0


def test_uncertainty_refuses_a_single_average():
    frf = FrequencyResponse(np.array([1.0]), np.array([1.0 + 0j]), np.array([1.0]), 1, "h1")
    with pytest.raises(DataError, match="at least 2"):
        frf_uncertainty(frf)
    with pytest.raises(ConfigError, match="confidence"):
        frf_uncertainty(FrequencyResponse(np.array([1.0]), np.array([1.0 + 0j]), np.array([1.0]), 3, "h1"), 1.5)


def frf_with_resolution(df, f_max=100.0):
    f = np.arange(df, f_max, df)
    return FrequencyResponse(f, np.ones_like(f, dtype=complex), np.ones_like(f), 4, "periodic")


def test_resolution_check_counts_bins_across_the_half_power_bandwidth():
    # gantry: 21.8 Hz with zeta 0.018 -> 0.785 Hz bandwidth; anti-resonance 19.47 Hz
    fine = check_resolution(frf_with_resolution(0.25), [(21.8, 0.018)], [19.47])
    assert fine.bins_per_bandwidth[0]["bins"] == pytest.approx(0.7848 / 0.25, rel=1e-3)
    assert fine.antiresonance["bins"] == pytest.approx((21.8 - 19.47) / 0.25)
    assert fine.warnings == []
    assert fine.required_record_s == pytest.approx(2 / 0.7848, rel=1e-3)
    coarse = check_resolution(frf_with_resolution(1.0), [(21.8, 0.018)], [19.47])
    assert len(coarse.warnings) == 2
    assert "over-estimated" in coarse.warnings[0] and "anti-resonance" in coarse.warnings[1]


def test_resolution_check_without_damping_or_antiresonance():
    check = check_resolution(frf_with_resolution(0.5), [(30.0, np.nan)])
    assert check.antiresonance is None and check.warnings == []
    assert check.required_record_s == 0.0


def test_input_spectrum_of_a_multisine_covers_its_band_flatly():
    ms = multisine(1.0, 2.0, 80.0, 2.0, 4, FS)
    spec = input_spectrum(ms.samples, FS, (2.0, 80.0), segment_length=ms.period_samples, periodic=True)
    hann = input_spectrum(ms.samples, FS, (2.0, 80.0), segment_length=ms.period_samples)
    assert hann.spread_db > 2.0  # a window smears neighbouring lines into each other
    assert spec.spread_db < 1.0 and spec.coverage == 1.0
    assert spec.crest_factor < 2.0
    outside = input_spectrum(ms.samples, FS, (100.0, 200.0), segment_length=ms.period_samples, periodic=True)
    assert outside.level_max_db < spec.level_min_db - 60


def test_input_spectrum_of_a_narrow_sine_shows_poor_coverage():
    t = np.arange(20000) / FS
    spec = input_spectrum(np.sin(2 * np.pi * 10 * t), FS, (2.0, 80.0))
    assert spec.coverage < 0.1 and spec.spread_db > 60
    assert spec.rms == pytest.approx(np.sqrt(0.5), rel=1e-3)
    with pytest.raises(ConfigError, match="band_hz"):
        input_spectrum(np.sin(2 * np.pi * 10 * t), FS, (80.0, 2.0))
