"""Multiple-input frequency responses: H1, Hv and zippered periodic estimates against a known 2-in, 3-out system."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse, h1_estimate
from hilident.ident.mimo import (
    MimoResponse,
    leave_one_out_h1,
    mimo_h1,
    mimo_hv,
    orthogonal_mimo_frf,
    orthogonal_multisine,
    periodic_mimo_frf,
    zippered_multisine,
)

FS = 1000.0
BAND = (5.0, 200.0)


def resonance(f0_hz, zeta, gain=1.0):
    """ZOH discretisation at FS of ``gain w0^2 / (s^2 + 2 zeta w0 s + w0^2)``: (b, a)."""
    w0 = 2.0 * np.pi * f0_hz
    b, a, _ = signal.cont2discrete(([gain * w0**2], [1.0, 2.0 * zeta * w0, w0**2]), 1.0 / FS, method="zoh")
    return np.ravel(b), a


#: SYSTEM[j][i]: output j's response to input i, six different second-order resonances.
SYSTEM = [
    [resonance(40.0, 0.3), resonance(120.0, 0.3, 0.5)],
    [resonance(70.0, 0.25, 0.8), resonance(50.0, 0.3)],
    [resonance(150.0, 0.3, 0.6), resonance(90.0, 0.25, 1.2)],
]


def simulate(u):
    """The outputs (N, 3) of SYSTEM for the inputs (N, 2), from rest."""
    return np.column_stack([sum(signal.lfilter(*SYSTEM[j][i], u[:, i]) for i in range(2)) for j in range(3)])


def truth(f_hz):
    """The exact responses (F, 3, 2) at the frequencies f_hz."""
    rows = [[signal.freqz(*SYSTEM[j][i], worN=f_hz, fs=FS)[1] for i in range(2)] for j in range(3)]
    return np.moveaxis(np.array(rows), -1, 0)


def in_band(frf, lo=BAND[0], hi=BAND[1]):
    return (frf.frequency_hz >= lo) & (frf.frequency_hz <= hi)


def coverage(estimate, std, true):
    """Fraction of the real and imaginary parts whose +-2 std interval holds the true value."""
    error = estimate - true
    return np.mean(np.concatenate([(np.abs(error.real) <= 2 * std).ravel(), (np.abs(error.imag) <= 2 * std).ravel()]))


@pytest.fixture(scope="module")
def white_inputs():
    """Two independent white-noise inputs and the noise-free outputs."""
    u = np.random.default_rng(1).standard_normal((1 << 19, 2))
    return u, simulate(u)


@pytest.fixture(scope="module")
def noisy_record():
    """Two independent white inputs; outputs with white noise of 0.3 rms (low SNR above the resonances)."""
    rng = np.random.default_rng(2)
    u = rng.standard_normal((1 << 17, 2))
    return u, simulate(u) + 0.3 * rng.standard_normal((u.shape[0], 3))


# --- H1 ----------------------------------------------------------------------------------------------------------


def test_leave_one_out_replicates_are_h1_of_the_segments_they_keep(noisy_record):
    u, y = noisy_record[0][:8192], noisy_record[1][:8192]
    replicates = leave_one_out_h1(u, y, FS, 1024, groups=5)  # 15 segments: blocks of 3
    assert len(replicates) == 5 and all(r.n_averages == 12 for r in replicates)
    # leaving the first block out is the record from its fourth segment on (segments start every 512 samples)
    later = mimo_h1(u[3 * 512 :], y[3 * 512 :], FS, 1024)
    np.testing.assert_allclose(replicates[0].response, later.response, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(replicates[0].std, later.std, rtol=1e-9, atol=1e-12)
    # the replicates' spread scaled by the jackknife is the order of the estimate's own standard deviation
    stack = np.array([r.response for r in replicates])
    jack = np.sqrt((5 - 1) / 5 * np.sum(np.abs(stack - stack.mean(0)) ** 2, axis=0) / 2)
    ratio = np.median(jack[in_band(later)] / mimo_h1(u, y, FS, 1024).std[in_band(later)])
    assert 0.5 < ratio < 2.0, ratio
    with pytest.raises(ConfigError, match="groups"):
        leave_one_out_h1(u, y, FS, 1024, groups=1)
    with pytest.raises(ConfigError, match="groups"):
        leave_one_out_h1(u[:3072], y[:3072], FS, 1024, groups=6)  # 5 segments
    with pytest.raises(ConfigError, match="groups"):
        leave_one_out_h1(u[:2048], y[:2048], FS, 1024, groups=2)  # 3 segments: a replicate would keep 1, not > 2


def test_h1_recovers_every_element_of_a_two_input_three_output_system(white_inputs):
    u, y = white_inputs
    frf = mimo_h1(u, y, FS, segment_length=2048)
    assert frf.response.shape == (1025, 3, 2) and frf.std.shape == (1025, 3, 2)
    assert frf.multiple_coherence.shape == (1025, 3) and frf.measured.all()
    assert frf.method == "h1" and frf.n_averages == 511 and frf.warnings == ()
    band = in_band(frf)
    relative = np.abs(frf.response[band] - truth(frf.frequency_hz[band])) / np.abs(truth(frf.frequency_hz[band]))
    assert relative.max() < 0.01  # measured: 0.57 % (leakage of the 2048-sample segments)
    assert frf.multiple_coherence[band].min() > 0.99  # measured: 0.9993
    # independent inputs: near 1 (the estimated input coherence is about 1/M, not 0); measured: median 1.08, max 1.25
    assert np.median(frf.input_condition[band]) < 1.15 and frf.input_condition[band].max() < 1.5


def test_multiple_coherence_falls_with_the_snr_and_std_covers_the_truth(noisy_record):
    u, y = noisy_record
    frf = mimo_h1(u, y, FS, segment_length=512)
    f = frf.frequency_hz
    # measured medians: 0.94, 0.97, 0.97 at 20 .. 80 Hz; 0.005, 0.004, 0.017 above 400 Hz (outputs rolled off)
    assert np.median(frf.multiple_coherence[(f >= 20) & (f <= 80)], axis=0).min() > 0.9
    assert np.median(frf.multiple_coherence[f > 400], axis=0).max() < 0.05
    band = in_band(frf, 5.0, 300.0)
    assert band.sum() * 12 > 1500  # enough intervals for a stable fraction
    assert 0.85 < coverage(frf.response[band], frf.std[band], truth(f[band])) < 0.995  # measured: 94.5 % of 1812


def test_single_input_estimate_sees_the_other_input_as_noise(white_inputs):
    u, y = white_inputs
    frf = mimo_h1(u, y, FS, segment_length=2048)
    alone = h1_estimate(u[:, 0], y[:, 1], FS, segment_length=2048)  # input 1 ignored
    other = h1_estimate(u[:, 1], y[:, 1], FS, segment_length=2048)  # input 0 ignored
    band = in_band(frf)
    assert np.median(alone.coherence[band]) < 0.85 and np.median(other.coherence[band]) < 0.35  # measured: 0.75, 0.25
    assert frf.multiple_coherence[band, 1].min() > 0.99
    # the unexplained power of the single-input view is thousands of times that of the two-input one; measured: 5400
    assert np.median(1 - alone.coherence[band]) > 1000 * np.median(1 - frf.multiple_coherence[band, 1])
    # independent inputs: the ordinary coherences add up to the multiple coherence (Bendat & Piersol, ch. 7)
    assert np.median(np.abs(alone.coherence + other.coherence - frf.multiple_coherence[:, 1])[band]) < 0.02
    element = frf.element(1, 0)
    assert isinstance(element, FrequencyResponse) and element.method == "h1"
    assert np.array_equal(element.response, frf.response[:, 1, 0])
    assert np.array_equal(element.coherence, frf.multiple_coherence[:, 1])
    # the single-input H1 of the same element is still unbiased (independent inputs), only noisier
    assert np.median(np.abs(alone.response[band] / frf.response[band, 1, 0] - 1)) < 0.05


def test_one_input_one_output_is_the_single_input_h1(noisy_record):
    u, y = noisy_record
    frf = mimo_h1(u[:, 0], y[:, 0], FS, segment_length=512)
    single = h1_estimate(u[:, 0], y[:, 0], FS, segment_length=512)
    assert frf.response.shape == (257, 1, 1)
    assert np.allclose(frf.response[1:, 0, 0], single.response[1:], rtol=1e-10)
    assert np.allclose(frf.multiple_coherence[1:, 0], single.coherence[1:], atol=1e-10)
    assert np.all(frf.input_condition[1:] == 1.0)


def test_correlated_inputs_are_warned_of_and_named(white_inputs):
    u, _ = white_inputs
    rng = np.random.default_rng(3)
    second = signal.lfilter([0.5], [1.0, -0.5], u[:, 0]) + 0.05 * rng.standard_normal(u.shape[0])
    correlated = np.column_stack([u[:, 0], second])[: 1 << 16]
    frf = mimo_h1(correlated, simulate(correlated), FS, segment_length=512)
    assert len(frf.warnings) == 1
    assert "correlated" in frf.warnings[0] and "input 0 and input 1" in frf.warnings[0]
    assert np.median(frf.input_condition[in_band(frf)]) > 100.0  # measured: 870
    # still solvable: the two-input H1 is near the truth, the single-input one is far off (input 1 rides along)
    band = in_band(frf)
    true = truth(frf.frequency_hz[band])
    assert np.median(np.abs(frf.response[band] - true) / np.abs(true)) < 0.15  # measured: 6 %
    alone = h1_estimate(correlated[:, 0], simulate(correlated)[:, 0], FS, segment_length=512)
    assert np.median(np.abs(alone.response[band] / true[:, 0, 0] - 1)) > 1.0  # measured: 3.2
    independent = mimo_h1(u[: 1 << 16], simulate(u[: 1 << 16]), FS, segment_length=512)
    assert independent.warnings == ()


def test_the_pair_named_is_the_coherent_one_among_three_inputs():
    rng = np.random.default_rng(4)
    u = rng.standard_normal((1 << 15, 3))
    u[:, 2] = u[:, 0] + 0.05 * rng.standard_normal(u.shape[0])
    frf = mimo_h1(u, u @ [1.0, 2.0, 3.0] + 0.1 * rng.standard_normal(u.shape[0]), FS, segment_length=256)
    assert len(frf.warnings) == 1 and "input 0 and input 2" in frf.warnings[0]
    assert np.allclose(frf.response[in_band(frf), 0, 1], 2.0, atol=0.05)  # the independent input is still fine


def test_identical_inputs_give_nan_not_an_exception():
    u = np.random.default_rng(5).standard_normal(1 << 14)
    y = signal.lfilter(*SYSTEM[0][0], u)
    frf = mimo_h1(np.column_stack([u, u]), y, FS, segment_length=256)
    assert np.all(np.isinf(frf.input_condition[1:]))
    assert np.all(np.isnan(frf.response[1:])) and np.all(np.isnan(frf.std[1:]))
    assert "input 0 and input 1" in frf.warnings[0]
    hv = mimo_hv(np.column_stack([u, u]), y, FS, segment_length=256)
    assert np.all(np.isnan(hv.response[1:]))


# --- Hv ----------------------------------------------------------------------------------------------------------


def test_hv_is_not_biased_by_noise_on_the_inputs(white_inputs):
    excitation, clean = white_inputs
    n = 1 << 17
    rng = np.random.default_rng(6)
    # the same noise level on every measured channel, the condition under which Hv is consistent
    u = excitation[:n] + 0.3 * rng.standard_normal((n, 2))
    y = clean[:n] + 0.3 * rng.standard_normal((n, 3))
    h1 = mimo_h1(u, y, FS, segment_length=512)
    hv = mimo_hv(u, y, FS, segment_length=512)
    assert hv.method == "hv" and hv.std.shape == h1.std.shape
    band = in_band(h1)
    exact = np.abs(truth(h1.frequency_hz[band]))
    h1_ratio = np.median(np.abs(h1.response[band]) / exact)
    hv_ratio = np.median(np.abs(hv.response[band]) / exact)
    assert h1_ratio < 0.95  # biased low by 1 / (1 + 0.3^2) = 0.917; measured: 0.915
    assert abs(hv_ratio - 1.0) < 0.02  # measured: 0.9996
    assert abs(hv_ratio - 1.0) < 0.25 * abs(h1_ratio - 1.0)
    assert np.array_equal(hv.multiple_coherence, h1.multiple_coherence)


# --- zippered periodic excitation --------------------------------------------------------------------------------

PERIOD = 2000


def test_zippered_multisine_deals_the_band_round_robin():
    x, lines = zippered_multisine(3, PERIOD, FS, (2.0, 200.0), rms=0.5, seed=7)
    assert x.shape == (PERIOD, 3)
    assert np.allclose(np.sqrt(np.mean(x**2, axis=0)), 0.5)
    every = np.concatenate(lines)
    assert every.size == np.unique(every).size  # disjoint
    assert np.array_equal(np.sort(every), np.arange(4, 401))  # 2 Hz .. 200 Hz at 0.5 Hz per bin
    for i, bins in enumerate(lines):
        assert np.all((bins - 4) % 3 == i) and np.all(np.diff(bins) == 3)
        spectrum = np.abs(np.fft.rfft(x[:, i]))
        others = np.setdiff1d(np.arange(spectrum.size), bins)
        assert spectrum[bins].min() > 1e6 * spectrum[others].max()  # each input excites its own bins only
    again, _ = zippered_multisine(3, PERIOD, FS, (2.0, 200.0), rms=0.5, seed=7)
    assert np.array_equal(x, again)
    assert not np.allclose(x, zippered_multisine(3, PERIOD, FS, (2.0, 200.0), rms=0.5, seed=8)[0])


def test_periodic_frf_is_exact_at_measured_bins_and_close_between(white_inputs):
    x, lines = zippered_multisine(2, PERIOD, FS, (2.0, 200.0), seed=3)
    u = np.tile(x, (4, 1))
    frf = periodic_mimo_frf(u, simulate(u), PERIOD, FS, lines, skip_periods=1)
    assert frf.method == "periodic" and frf.n_averages == 3 and frf.warnings == ()
    assert np.array_equal(frf.frequency_hz, np.arange(4, 401) * FS / PERIOD)
    assert np.array_equal(frf.measured[:, 0], np.isin(np.arange(4, 401), lines[0]))
    assert np.array_equal(frf.measured[:, 1], ~frf.measured[:, 0])
    relative = np.abs(frf.response - truth(frf.frequency_hz)) / np.abs(truth(frf.frequency_hz))
    measured = np.broadcast_to(frf.measured[:, None, :], relative.shape)
    assert relative[measured].max() < 1e-9  # measured: 6e-15
    # linear interpolation over 1 Hz; measured: 0.8 % at the band's edge (held constant there), 0.18 % inside
    assert relative[~measured].max() < 0.02
    assert np.all(np.isnan(frf.std[~measured])) and np.all(frf.std[measured] < 1e-9)
    assert np.allclose(frf.multiple_coherence, 1.0)
    assert np.all(np.isnan(frf.input_condition))
    element = frf.element(2, 1)
    assert np.array_equal(element.response, frf.response[:, 2, 1])


def test_periodic_std_and_coherence_from_the_scatter_over_periods():
    x, lines = zippered_multisine(2, PERIOD, FS, (2.0, 200.0), seed=3)
    u = np.tile(x, (41, 1))
    y = simulate(u) + 0.3 * np.random.default_rng(8).standard_normal((u.shape[0], 3))
    frf = periodic_mimo_frf(u, y, PERIOD, FS, lines)
    assert frf.n_averages == 40
    measured = np.broadcast_to(frf.measured[:, None, :], frf.response.shape)
    true = truth(frf.frequency_hz)
    assert 0.9 < coverage(frf.response[measured], frf.std[measured], true[measured]) < 0.99  # measured: 95.3 % of 2382
    f = frf.frequency_hz
    assert np.median(frf.multiple_coherence[(f > 20) & (f < 60)], axis=0).min() > 0.9  # measured: 0.96, 0.99, 0.99
    assert np.median(frf.multiple_coherence[f > 180, 0]) < 0.6  # output 0 rolled off at 40 Hz: noisy; measured: 0.45


def test_one_period_leaves_std_and_coherence_undefined():
    x, lines = zippered_multisine(2, PERIOD, FS, (2.0, 200.0), seed=3)
    u = np.tile(x, (2, 1))
    frf = periodic_mimo_frf(u, simulate(u), PERIOD, FS, lines)
    assert frf.n_averages == 1
    assert np.all(np.isnan(frf.std)) and np.all(np.isnan(frf.multiple_coherence))
    assert np.all(np.isfinite(frf.response))


def test_lines_that_do_not_match_the_signals_are_warned_of():
    x, lines = zippered_multisine(2, PERIOD, FS, (2.0, 200.0), seed=3)
    u = np.tile(x, (3, 1))
    frf = periodic_mimo_frf(u, simulate(u), PERIOD, FS, [lines[1], lines[0]])
    assert len(frf.warnings) == 2 and "not zippered" in frf.warnings[0]


# --- orthogonal periodic excitation ------------------------------------------------------------------------------


def test_orthogonal_multisine_patterns_are_the_dft_matrix():
    blocks, bins = orthogonal_multisine(3, 512, FS, (5.0, 300.0), rms=2.0, seed=1)
    assert blocks.shape == (3, 512, 3) and np.array_equal(bins, np.arange(3, 154))  # 1.95 Hz per bin
    assert np.allclose(np.sqrt(np.mean(blocks**2, axis=1)), 2.0)
    lines = np.fft.rfft(blocks, axis=1)[:, bins, :]  # (block, bin, input)
    pattern = lines / lines[:1, :, :1]  # relative to input 0 in block 0, per bin
    assert np.allclose(pattern, np.exp(-2j * np.pi * np.outer(range(3), range(3)) / 3)[:, None, :], atol=1e-12)
    two, _ = orthogonal_multisine(2, 512, FS, (5.0, 300.0), seed=1)
    assert np.allclose(two[1], two[0] * [1.0, -1.0])  # two inputs: the Hadamard signs


def test_orthogonal_frf_measures_every_element_at_every_bin():
    blocks, bins = orthogonal_multisine(2, PERIOD, FS, (2.0, 200.0), seed=4)
    inputs = [np.tile(block, (3, 1)) for block in blocks]
    frf = orthogonal_mimo_frf(inputs, [simulate(u) for u in inputs], PERIOD, FS, bins)
    assert frf.method == "orthogonal" and frf.n_averages == 2 and frf.measured.all()
    true = truth(frf.frequency_hz)
    assert np.max(np.abs(frf.response - true) / np.abs(true)) < 1e-9  # measured: 7e-15
    assert np.allclose(frf.input_condition, 1.0)


def test_orthogonal_frf_std_from_the_periods():
    blocks, bins = orthogonal_multisine(2, PERIOD, FS, (2.0, 200.0), seed=4)
    rng = np.random.default_rng(10)
    inputs = [np.tile(block, (21, 1)) for block in blocks]
    outputs = [simulate(u) + 0.3 * rng.standard_normal((u.shape[0], 3)) for u in inputs]
    frf = orthogonal_mimo_frf(inputs, outputs, PERIOD, FS, bins)
    assert 0.9 < coverage(frf.response, frf.std, truth(frf.frequency_hz)) < 0.99  # measured: 94.6 % of 4764
    f = frf.frequency_hz
    assert np.median(frf.multiple_coherence[(f > 20) & (f < 60)], axis=0).min() > 0.9  # measured: 0.98 .. 0.99


def test_three_inputs_one_output_from_three_orthogonal_experiments():
    elements = [SYSTEM[0][0], SYSTEM[1][0], SYSTEM[2][1]]
    blocks, bins = orthogonal_multisine(3, 1000, FS, (2.0, 250.0), seed=5)
    inputs = [np.tile(block, (3, 1)) for block in blocks]
    outputs = [sum(signal.lfilter(*elements[i], u[:, i]) for i in range(3)) for u in inputs]
    frf = orthogonal_mimo_frf(inputs, outputs, 1000, FS, bins)
    true = np.stack([signal.freqz(*e, worN=frf.frequency_hz, fs=FS)[1] for e in elements], axis=-1)
    assert frf.response.shape == (bins.size, 1, 3)
    assert np.max(np.abs(frf.response[:, 0, :] - true) / np.abs(true)) < 1e-9
    with pytest.raises(DataError, match="3 blocks"):
        orthogonal_mimo_frf(inputs[:2], outputs[:2], 1000, FS, bins)


# --- bad input ---------------------------------------------------------------------------------------------------


def test_bad_shapes_and_parameters_are_refused():
    rng = np.random.default_rng(9)
    u, y = rng.standard_normal((4096, 2)), rng.standard_normal((4096, 3))
    with pytest.raises(DataError, match="4000"):
        mimo_h1(u, y[:4000], FS, segment_length=256)
    with pytest.raises(DataError, match="transposed"):
        mimo_h1(u.T, y, FS, segment_length=256)
    bad = u.copy()
    bad[10, 1] = np.nan
    with pytest.raises(DataError, match="input 1"):
        mimo_hv(bad, y, FS, segment_length=256)
    assert mimo_h1(u, y, FS, segment_length=2048).n_averages == 3  # M = 3 > 2 inputs is enough ...
    with pytest.raises(ConfigError) as info:
        mimo_h1(u, y, FS, segment_length=2731)  # ... M = 2 is not
    assert info.value.key == "segment_length" and "2 inputs" in info.value.message
    with pytest.raises(ConfigError) as info:
        mimo_h1(u, y, FS, segment_length=256, condition_limit=0.5)
    assert info.value.key == "condition_limit"
    x, lines = zippered_multisine(2, 100, FS, (10.0, 400.0))
    with pytest.raises(ConfigError) as info:
        periodic_mimo_frf(np.tile(x, (3, 1)), np.tile(x, (3, 1)), 100, FS, [lines[0], lines[0]])
    assert info.value.key == "lines"
    with pytest.raises(ConfigError) as info:
        zippered_multisine(4, 100, FS, (10.0, 20.0))  # 2 bins of 10 Hz for 4 inputs
    assert info.value.key == "band_hz"


def test_response_container_checks_its_shapes():
    f = np.arange(4.0)
    h = np.ones((4, 3, 2), dtype=complex)
    ok = MimoResponse(f, h, np.ones((4, 3)), np.zeros((4, 3, 2)), np.ones(4), 5, "h1")
    assert len(ok) == 4 and ok.n_inputs == 2 and ok.n_outputs == 3 and ok.measured.shape == (4, 2)
    with pytest.raises(DataError, match="std"):
        MimoResponse(f, h, np.ones((4, 3)), np.zeros((4, 2, 3)), np.ones(4), 5, "h1")
    with pytest.raises(DataError, match="multiple_coherence"):
        MimoResponse(f, h, np.full((4, 3), 1.5), np.zeros((4, 3, 2)), np.ones(4), 5, "h1")
    with pytest.raises(ConfigError) as info:
        ok.element(0, 2)
    assert info.value.key == "i"
