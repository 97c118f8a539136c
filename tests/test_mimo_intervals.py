"""95 % intervals of the modes' frequency and damping (independent groups of a record, and the maximum-likelihood
modal model) against a modal model with known modes and noise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from hilident.errors import ConfigError, DataError
from hilident.ident.mimo import modal_intervals, refine_poles
from hilident.ident.mimo.modal import MIN_GROUPS, modal_analysis
from test_mimo_modal import modal_frf

FN = np.array([40.0, 62.0])
ZETA = np.array([0.02, 0.01])
K = 8  # groups of the record
FREQ = np.arange(24.0, 87.0, 0.25)
BAND = (float(FREQ[0]), float(FREQ[-1]))
ORDERS = range(2, 17)
_rng = np.random.default_rng(7)
SHAPES = np.linalg.qr(_rng.standard_normal((3, 2)))[0].T  # (modes, outputs)
PARTICIPATION = _rng.standard_normal((2, 2))  # (modes, inputs)
H = modal_frf(FREQ, FN, ZETA, SHAPES, PARTICIPATION)
TRUTH = np.stack([FN, ZETA], axis=1)  # (modes, 2)


def groups_of(level: float, seed: int, k: int = K) -> list[np.ndarray]:
    """``k`` independent estimates of ``H``, each with complex noise of ``level sqrt(k)`` times the median |H|
    (per part), so that their mean, the whole record's estimate, has ``level``."""
    rng = np.random.default_rng(seed)
    sigma = level * np.median(np.abs(H)) * np.sqrt(k / 2.0)
    return [H + sigma * (rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape)) for _ in range(k)]


def trial(level: float, seed: int):
    groups = groups_of(level, seed)
    whole = np.mean(groups, axis=0)
    result = modal_analysis((FREQ, whole), BAND, ORDERS)
    return modal_intervals((FREQ, whole), [(FREQ, g) for g in groups], BAND, result)


def arrays(results) -> dict[str, np.ndarray]:
    """Estimates, half-widths, standard deviations and groups, each (trials, modes, 2) (frequency, damping)."""
    assert all(len(r.modes) == FN.size for r in results), [[m.frequency_hz for m in r.modes] for r in results]
    pick = {
        "estimate": lambda m: (m.frequency_hz, m.damping),
        "half": lambda m: (m.frequency_ci95_hz, m.damping_ci95),
        "std": lambda m: (m.frequency_std_hz, m.damping_std),
        "groups": lambda m: (m.n_groups, m.n_groups),
    }
    return {key: np.array([[get(m) for m in r.modes] for r in results]) for key, get in pick.items()}


@pytest.fixture(scope="module")
def noisy():
    return arrays([trial(0.05, seed) for seed in range(10)])


@pytest.fixture(scope="module")
def quiet():
    return arrays([trial(0.005, seed) for seed in range(3)])


def test_intervals_cover_the_true_frequency_and_damping(noisy):
    assert np.all(noisy["groups"] == K)
    covered = np.abs(noisy["estimate"] - TRUTH) <= noisy["half"]
    assert covered.mean() >= 0.8, covered.mean(axis=0)  # measured 40 of 40
    # and are no wider than they need be: a small part of the half-power bandwidth, of the damping ratio
    median = np.median(noisy["half"], axis=0)
    assert np.all(median[:, 0] < 0.05 * ZETA * FN), median  # measured 0.2 % and 1.4 % of zeta f_n
    assert np.all(median[:, 1] < 0.1 * ZETA), median  # measured 0.5 % and 1.7 % of zeta


def test_the_group_spread_is_the_estimates_random_error(noisy):
    # the standard deviation from the groups of one record against the spread of the estimate over ten records
    spread = noisy["estimate"].std(axis=0, ddof=1)
    estimated = np.sqrt(np.mean(noisy["std"] ** 2, axis=0))
    ratio = spread / estimated
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio  # measured 0.84 to 1.09


def test_the_random_part_alone_misses_the_lscf_bias(noisy):
    # LSCF's linearised fit is biased by noise beyond its random error (damping most): the interval's second
    # part, the difference from the maximum-likelihood fit, is what makes it cover
    t = stats.t.ppf(0.975, K - 1)
    random_only = np.abs(noisy["estimate"] - TRUTH) <= t * noisy["std"]
    covered = np.abs(noisy["estimate"] - TRUTH) <= noisy["half"]
    assert random_only.mean() < covered.mean()  # measured 5 of 40 against 40 of 40


def test_intervals_shrink_with_the_noise(noisy, quiet):
    ratio = np.median(quiet["half"], axis=0) / np.median(noisy["half"], axis=0)
    assert np.all(ratio < 0.35), ratio  # ten times less noise: measured 0.13 to 0.18
    assert np.all(np.abs(quiet["estimate"] - TRUTH) <= quiet["half"])


def test_refine_poles_finds_the_modal_models_poles_from_a_start_beside_them():
    wn = 2 * np.pi * FN
    exact = wn * (-ZETA + 1j * np.sqrt(1 - ZETA**2))
    start = 1.003 * wn * (-1.3 * ZETA + 1j * np.sqrt(1 - (1.3 * ZETA) ** 2))
    refined = refine_poles((FREQ, H), BAND, start)
    assert np.allclose(refined, exact, rtol=1e-7)
    # weights "std" of a (frequency, response) pair are refused as for the other steps
    with pytest.raises(ConfigError):
        refine_poles((FREQ, H), BAND, start, weights="std")


def test_too_few_groups_or_a_mode_found_in_too_few_give_no_interval():
    groups = groups_of(0.05, 11, k=5)
    whole = np.mean(groups, axis=0)
    result = modal_analysis((FREQ, whole), BAND, ORDERS)
    with pytest.raises(ConfigError) as e:
        modal_intervals((FREQ, whole), [(FREQ, g) for g in groups[: MIN_GROUPS - 1]], BAND, result)
    assert e.value.key == "groups"
    with pytest.raises(DataError, match="shape"):
        modal_intervals((FREQ, whole), [(FREQ, g) for g in groups[:-1]] + [(FREQ, groups[-1][:, :2])], BAND, result)
    # groups of noise only: a mode found in three of five still has an interval (and a note), in two none
    noise = [np.median(np.abs(H)) * np.exp(2j * np.pi * np.random.default_rng(k).random(H.shape)) for k in range(3)]
    partial = modal_intervals((FREQ, whole), [(FREQ, g) for g in groups[:3] + noise[:2]], BAND, result)
    assert [m.n_groups for m in partial.modes] == [3, 3]
    assert all(np.isfinite(m.frequency_ci95_hz) and np.isfinite(m.damping_ci95) for m in partial.modes)
    assert sum("found in 3 of 5 groups" in n for n in partial.notes) == 2
    missing = modal_intervals((FREQ, whole), [(FREQ, g) for g in groups[:2] + noise], BAND, result)
    assert [m.n_groups for m in missing.modes] == [2, 2]
    assert all(np.isnan(m.frequency_ci95_hz) and np.isnan(m.damping_std) for m in missing.modes)
    assert sum("no interval" in n for n in missing.notes) == 2
