"""Periods that miss samples: their excited lines by least squares on the samples that exist."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hilident.errors import DataError
from hilident.ident.frequency import periodic_frf
from hilident.ident.gapped_periods import line_spectra

P = 400
BINS = np.arange(3, 80, 2)


def multisine(rng, periods: int) -> np.ndarray:
    t = np.arange(P * periods)
    phases = rng.uniform(0, 2 * np.pi, BINS.size)
    return sum(np.cos(2 * np.pi * k * t / P + ph) for k, ph in zip(BINS, phases, strict=True))


def test_a_whole_period_reads_as_its_dft():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((3, P))
    spectra, used = line_spectra(x, np.ones_like(x, dtype=bool), BINS)
    assert used.all()
    np.testing.assert_allclose(spectra, np.fft.rfft(x, axis=-1)[:, BINS], atol=1e-9)


@pytest.mark.parametrize("missing", [1, 3, 40])
def test_the_lines_of_a_period_missing_samples_are_found_exactly_and_its_missing_values_never_read(missing):
    rng = np.random.default_rng(missing)
    x = 0.4 + multisine(rng, 1)
    periods = np.tile(x, (2, 1))
    present = np.ones_like(periods, dtype=bool)
    present[1, rng.choice(P, missing, replace=False)] = False
    periods[~present] = np.nan  # never read
    spectra, used = line_spectra(periods, present, BINS)
    assert used.all()
    np.testing.assert_allclose(spectra[1], np.fft.rfft(x)[BINS], atol=1e-9 * P)


def test_a_period_whose_samples_cannot_tell_its_lines_apart_is_not_used():
    x = np.ones((2, P))
    present = np.ones_like(x, dtype=bool)
    present[1, : P - 2 * BINS.size] = False  # fewer samples left than unknowns
    spectra, used = line_spectra(x, present, BINS)
    assert used.tolist() == [True, False] and np.isnan(spectra[1]).all()


def test_bins_at_the_constant_or_nyquist_are_refused():
    x = np.ones((1, P))
    with pytest.raises(ValueError, match="bins"):
        line_spectra(x, np.ones_like(x, dtype=bool), np.array([0, 5]))
    with pytest.raises(ValueError, match="bins"):
        line_spectra(x, np.ones_like(x, dtype=bool), np.array([P // 2]))


def resonant_record(rng, periods: int, noise: float):
    """A lightly damped mode driven by a multisine in steady state (its first period is the lead-in)."""
    b, a = signal.cheby1(2, 1, 0.1)  # a resonant low-pass: a peak at its corner
    u = multisine(rng, periods)
    y = signal.lfilter(b, a, u) + noise * rng.standard_normal(u.size)
    true = np.fft.rfft(signal.lfilter(b, a, np.tile(u[:P], 20))[-P:])[BINS] / np.fft.rfft(u[:P])[BINS]
    return u, y, true


def test_an_frf_from_a_record_with_skipped_samples_matches_the_whole_record_and_the_truth():
    rng = np.random.default_rng(7)
    u, y, true = resonant_record(rng, periods=9, noise=0.01)
    present = np.ones(u.size, dtype=bool)
    present[rng.choice(np.arange(P, u.size), 40, replace=False)] = False  # about 1 % of the analysed samples
    whole = periodic_frf(u, y, P, 1000.0, skip_periods=1, bins=BINS)
    gapped = periodic_frf(
        np.where(present, u, np.nan), np.where(present, y, np.nan), P, 1000.0, 1, BINS, present=present
    )
    assert gapped.n_averages == whole.n_averages == 8
    np.testing.assert_allclose(gapped.response, true, rtol=0.02)
    np.testing.assert_allclose(gapped.response, whole.response, rtol=0.01)
    assert gapped.coherence.min() > 0.98


def test_the_excited_bins_are_found_in_a_record_with_missing_samples_too():
    rng = np.random.default_rng(3)
    u, y, _ = resonant_record(rng, periods=4, noise=0.0)
    present = np.ones(u.size, dtype=bool)
    present[[P + 10, 2 * P + 11, 3 * P + 250]] = False
    frf = periodic_frf(u, y, P, 1000.0, skip_periods=1, present=present)
    np.testing.assert_array_equal(frf.frequency_hz, BINS * 1000.0 / P)


def test_too_few_periods_with_samples_enough_is_a_data_error():
    rng = np.random.default_rng(4)
    u, y, _ = resonant_record(rng, periods=3, noise=0.0)
    present = np.ones(u.size, dtype=bool)
    present[2 * P : 2 * P + 300] = False
    with pytest.raises(DataError, match="only 1 of 2 periods"):
        periodic_frf(u, y, P, 1000.0, skip_periods=1, bins=BINS, present=present)
