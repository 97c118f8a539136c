"""A record of one excitation period: which DFT lines are excited, and their noise from the lines left out."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.session.offline import excitation_lines, line_coherence

N = 1024


def multisine(lines: np.ndarray, seed: int = 0) -> np.ndarray:
    """One period of N samples, unit amplitude at ``lines``, random phases."""
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, lines.size)
    n = np.arange(N)
    return np.cos(2 * np.pi * np.outer(n, lines) / N + phase).sum(axis=1)


def test_an_odd_multisine_with_noise_everywhere_is_its_odd_lines():
    odd = np.arange(1, 200, 2)
    u = multisine(odd) + 0.05 * np.random.default_rng(1).standard_normal(N)
    lines, step = excitation_lines(np.abs(np.fft.rfft(u)) ** 2)
    assert step == 2  # the odd lines: one in two
    assert np.array_equal(lines, odd)


def test_a_grid_of_every_third_line_is_found():
    grid = np.arange(2, 300, 3)
    u = multisine(grid) + 0.05 * np.random.default_rng(2).standard_normal(N)
    lines, step = excitation_lines(np.abs(np.fft.rfft(u)) ** 2)
    assert step == 3 and np.array_equal(lines, grid)


def test_a_full_multisine_keeps_every_line_and_has_no_noise_lines():
    full = np.arange(1, 150)
    u = multisine(full)
    U = np.fft.rfft(u)
    lines, step = excitation_lines(np.abs(U) ** 2)
    assert step == 1 and np.array_equal(lines, full)
    # the lines either side of the band edges are quiet, but not those between: no coherence at all
    assert np.isnan(line_coherence(U, 2 * U, lines)).all()


def noisy_coherence(snr_db: float, trials: int = 20) -> np.ndarray:
    """line_coherence of a pure delay (|H| = 1) with white output noise ``snr_db`` under each line's signal."""
    odd = np.arange(1, 200, 2)
    u = multisine(odd)
    y = np.roll(u, 3)
    signal_per_line = (N / 2) ** 2  # |DFT|^2 of a unit cosine
    sigma = np.sqrt(signal_per_line * 10 ** (-snr_db / 10) / N)  # white noise of that power per line
    rng = np.random.default_rng(3)
    U = np.fft.rfft(u)
    return np.array([line_coherence(U, np.fft.rfft(y + sigma * rng.standard_normal(N)), odd) for _ in range(trials)])


@pytest.mark.parametrize("snr_db", [20.0, 30.0, 40.0])
def test_the_coherence_stands_for_the_noise_of_the_lines_left_out(snr_db):
    """(1 - coh) / coh is the relative variance of H the coherence stands for: here the noise-to-signal ratio."""
    coh = noisy_coherence(snr_db)
    assert np.mean((1 - coh) / coh) == pytest.approx(10 ** (-snr_db / 10), rel=0.1)


def test_at_equal_signal_and_noise_the_coherence_is_not_optimistic():
    coh = noisy_coherence(0.0)
    assert np.mean(coh) <= 0.5  # the true value; a peak there is far under the 0.8 threshold
