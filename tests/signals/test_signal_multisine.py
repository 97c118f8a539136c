"""Multisine: exact bins, peak scaling, Schroeder crest factor."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError
from hilident.signals import Multisine, crest_factor, multisine


def test_lines_are_exact_bins_without_leakage():
    fs = 1000.0
    ms = multisine(0.8, 3.0, 47.0, period_s=0.5, n_periods=3, sample_rate_hz=fs)
    assert isinstance(ms, Multisine)
    assert ms.period_samples == 500
    assert ms.samples.shape == (1500,)
    # 0.5 s period -> 2 Hz lines: 4, 6, ..., 46 Hz are bins 2..23
    np.testing.assert_array_equal(ms.excited_bins, np.arange(2, 24))
    np.testing.assert_allclose(ms.frequency_hz, np.arange(4.0, 47.0, 2.0))

    spectrum = np.abs(np.fft.rfft(ms.samples[: ms.period_samples])) ** 2
    excited = np.zeros(spectrum.size, bool)
    excited[ms.excited_bins] = True
    assert spectrum[~excited].sum() < 1e-20 * spectrum.sum()
    # equal amplitude on every line
    np.testing.assert_allclose(spectrum[excited], spectrum[excited].mean(), rtol=1e-9)
    # the whole record (3 periods) has lines on every third bin only
    whole = np.abs(np.fft.rfft(ms.samples)) ** 2
    lines = np.zeros(whole.size, bool)
    lines[3 * ms.excited_bins] = True
    assert whole[~lines].sum() < 1e-20 * whole.sum()


def test_periods_repeat():
    ms = multisine(1.0, 1.0, 100.0, 1.0, 4, 1000.0)
    p = ms.samples.reshape(4, ms.period_samples)
    assert np.all(p == p[0])


@settings(max_examples=30, deadline=None)
@given(
    amplitude=st.floats(1e-3, 1e3),
    f_max=st.floats(20.0, 490.0),
    phases=st.sampled_from(["schroeder", "random"]),
    spacing=st.sampled_from(["linear", "log"]),
)
def test_peak_equals_amplitude(amplitude, f_max, phases, spacing):
    ms = multisine(amplitude, 2.0, f_max, 1.0, 2, 1000.0, phases=phases, spacing=spacing, seed=5)
    assert np.max(np.abs(ms.samples)) == amplitude


def test_schroeder_crest_factor_beats_random_phases():
    fs = 1000.0
    schroeder = multisine(1.0, 1.0, 200.0, 1.0, 1, fs).samples
    random_cf = [
        crest_factor(multisine(1.0, 1.0, 200.0, 1.0, 1, fs, phases="random", seed=s).samples) for s in range(10)
    ]
    assert crest_factor(schroeder) < 1.8
    assert crest_factor(schroeder) < 0.7 * min(random_cf)


def test_log_spacing_is_roughly_logarithmic():
    ms = multisine(1.0, 1.0, 400.0, 10.0, 1, 1000.0, spacing="log", lines_per_decade=10)
    bins = ms.excited_bins
    assert np.all(np.diff(bins) > 0)  # unique and sorted
    assert bins[0] == 10 and bins[-1] == 4000
    ratios = bins[1:] / bins[:-1]
    np.testing.assert_allclose(ratios, 10 ** (1 / 10), rtol=0.1)
    # at least lines_per_decade lines per decade, not many more
    assert 10 * np.log10(400) <= bins.size - 1 <= 10 * np.log10(400) + 2


def test_log_spacing_is_denser_than_log_only_where_bins_run_out():
    ms = multisine(1.0, 1.0, 100.0, 1.0, 1, 1000.0, spacing="log", lines_per_decade=30)
    bins = ms.excited_bins
    assert bins[0] == 1 and bins[-1] == 100
    assert len(set(bins.tolist())) == bins.size
    assert np.all(np.diff(bins)[:3] == 1)


def test_user_phases_and_reproducible_random():
    ms = multisine(1.0, 10.0, 30.0, 1.0, 1, 100.0, phases=np.zeros(21))
    assert ms.samples[0] == 1.0  # all cosines in phase at t = 0
    a = multisine(1.0, 10.0, 30.0, 1.0, 1, 100.0, phases="random", seed=3).samples
    b = multisine(1.0, 10.0, 30.0, 1.0, 1, 100.0, phases="random", seed=3).samples
    assert np.array_equal(a, b)


def test_result_is_read_only():
    ms = multisine(1.0, 1.0, 10.0, 1.0, 1, 100.0)
    with pytest.raises(ValueError):
        ms.samples[0] = 0.0


@pytest.mark.parametrize(
    "kwargs, key",
    [
        (dict(f_max_hz=500.0), "f_max_hz"),
        (dict(f_min_hz=60.0, f_max_hz=50.0), "f_min_hz"),
        (dict(f_min_hz=10.2, f_max_hz=10.8), "period_s"),
        (dict(period_s=0.0), "period_s"),
        (dict(n_periods=0), "n_periods"),
        (dict(spacing="octave"), "spacing"),
        (dict(phases="random"), "seed"),
        (dict(phases="zero"), "phases"),
        (dict(phases=[0.0, 1.0]), "phases"),
        (dict(amplitude=-1.0), "amplitude"),
    ],
)
def test_invalid_arguments_name_the_key(kwargs, key):
    args = dict(
        amplitude=1.0,
        f_min_hz=1.0,
        f_max_hz=100.0,
        period_s=1.0,
        n_periods=1,
        sample_rate_hz=1000.0,
    )
    args.update(kwargs)
    with pytest.raises(ConfigError) as info:
        multisine(**args)
    assert info.value.key == key
