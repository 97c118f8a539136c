"""Peaks that are not reported say why; reported resonances carry their uncertainty."""

import numpy as np
import pytest
from test_resonance import analytic_frf, simulate_h1, two_mass

from hilident.ident.frequency import FrequencyResponse
from hilident.ident.resonance import find_resonances, screen_resonances


def test_low_coherence_peak_is_rejected_with_its_coherence():
    num, den = two_mass()
    f = np.arange(1.0, 50.0, 0.25)
    frf = analytic_frf(num, den, f)
    coh = np.where(np.abs(f - 20.0) < 2.0, 0.6, 0.99)  # the mode, measured badly
    frf = FrequencyResponse(f, frf.response, coh, 8, "h1")
    found, rejected = screen_resonances(frf, coherence_threshold=0.8, min_prominence_db=6.0)
    assert found == []
    (peak,) = [p for p in rejected if abs(p.frequency_hz - 20.0) < 0.5]
    assert "coherence 0.600" in peak.reason and "coherence_threshold = 0.8" in peak.reason
    assert find_resonances(frf, coherence_threshold=0.8, min_prominence_db=6.0) == found


def test_noise_peak_is_rejected_as_within_the_scatter():
    # white noise around a flat response: every peak is a ripple of the estimate
    rng = np.random.default_rng(4)
    f = np.arange(1.0, 100.0, 0.5)
    h = 1.0 + 0.3 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    frf = FrequencyResponse(f, h, np.full(f.size, 0.85), 4, "h1")
    found, rejected = screen_resonances(frf, coherence_threshold=0.8, min_prominence_db=3.0, max_rejected=5)
    assert found == []
    assert 0 < len(rejected) <= 5
    assert all("scatter" in p.reason for p in rejected)


def test_count_limit_and_duplicates_are_reasons_too():
    # two modes; only one may be reported
    f = np.arange(1.0, 100.0, 0.25)
    s = 2j * np.pi * f
    h = sum(1.0 / (s**2 + 2 * 0.02 * w * s + w**2) * w**2 for w in (2 * np.pi * 20.0, 2 * np.pi * 60.0))
    frf = FrequencyResponse(f, h, np.full(f.size, 0.999), 20, "h1")
    found, rejected = screen_resonances(frf, max_count=1)
    assert len(found) == 1
    assert any("max_resonances" in p.reason for p in rejected)


def test_frequency_interval_covers_the_truth_and_shrinks_with_less_noise():
    num, den = two_mass(zeta=0.02)
    misses, widths = 0, {}
    for noise in (0.02, 0.1):
        widths[noise] = []
        for seed in range(4):
            frf = simulate_h1(num, den, seconds=60, noise_rel=noise, seed=seed, segment_length=4096)
            (res,) = find_resonances(frf)
            assert res.method == "fit" and res.frequency_ci95_hz > 0
            widths[noise].append(res.frequency_ci95_hz)
            # adjacent Welch lines are correlated: allow twice the stated interval
            misses += abs(res.frequency_hz - 20.0) > 2 * res.frequency_ci95_hz
            assert 0 < res.local_fit_db_rms < 3.0 and res.local_noise_db_rms > 0
            assert 0 < res.local_fit_ratio < 3.0  # one mode explains the peak to within its scatter
            assert res.prominence_db >= 3.0
    assert misses <= 1
    assert np.median(widths[0.02]) < np.median(widths[0.1])


def test_noise_free_mode_has_a_tight_interval_and_fit():
    num, den = two_mass(zeta=0.02)
    frf = analytic_frf(num, den, np.arange(1.0, 50.0, 0.25), coherence=0.999)
    (res,) = find_resonances(frf)
    assert res.frequency_ci95_hz < 1e-3 * res.bandwidth_hz
    assert res.local_fit_db_rms < 1e-3 and res.local_fit_ratio < 1e-2
    assert res.bandwidth_hz == pytest.approx(2 * 0.02 * 20.0, rel=1e-3)


def test_two_modes_in_one_peak_fit_badly():
    # two modes 0.6 Hz apart read as one peak on 0.25 Hz lines: one pole pair cannot explain it
    f = np.arange(1.0, 60.0, 0.25)
    s = 2j * np.pi * f
    h = sum(w**2 / (s**2 + 2 * 0.01 * w * s + w**2) for w in (2 * np.pi * 20.0, 2 * np.pi * 20.6))
    frf = FrequencyResponse(f, h, np.full(f.size, 0.99), 20, "h1")
    fits = [r for r in find_resonances(frf, max_count=4) if r.method == "fit"]
    assert fits and max(r.local_fit_ratio for r in fits) > 3.0
