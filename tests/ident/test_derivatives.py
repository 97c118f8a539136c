import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.derivatives import (
    finite_difference_derivatives,
    settling_samples,
    state_variable_filter,
    svf_sections,
)

FS = 1000.0


def interior(fc, order, kind="butterworth"):
    n = settling_samples(FS, fc, order, kind=kind)
    return slice(n, -n)


@pytest.mark.parametrize("kind", ["butterworth", "repeated_pole"])
@pytest.mark.parametrize("f0", [0.5, 4.0, 15.0])
def test_sine_derivatives_match_tustin_differentiator(kind, f0):
    # Row k must be S(z)^k times row 0, S the Tustin differentiator: for a sine
    # that is gain (2 fs tan(w T / 2))^k and a phase lead of k * 90 degrees.
    fc, n_der = 20.0, 3
    t = np.arange(20000) / FS
    w = 2 * np.pi * f0
    d = state_variable_filter(np.sin(w * t), FS, fc, n_der, kind=kind)
    _, h = signal.sosfreqz(svf_sections(FS, fc, 0, order=n_der + 1, kind=kind)[0], [f0], fs=FS)
    gain = abs(h[0]) ** 2  # forward and backward pass
    w_tustin = 2 * FS * np.tan(w / FS / 2)
    mid = interior(fc, n_der + 1, kind)
    for k in range(n_der + 1):
        expected = gain * w_tustin**k * np.sin(w * t + k * np.pi / 2)
        scale = gain * w_tustin**k
        np.testing.assert_allclose(d[k, mid], expected[mid], rtol=0, atol=1e-5 * scale)


def test_derivative_gain_close_to_exact_well_below_nyquist():
    f0 = 2.0
    t = np.arange(20000) / FS
    w = 2 * np.pi * f0
    d = state_variable_filter(np.cos(w * t), FS, 20.0, 2)
    mid = interior(20.0, 3)
    # relative gain error of the Tustin derivative is about (w T)^2 / 12 = 1.3e-5
    np.testing.assert_allclose(d[2, mid], -(w**2) * d[0, mid], rtol=0, atol=3e-5 * w**2)


def test_quadratic_is_differentiated_exactly():
    # zero-phase, unit DC gain: a polynomial of degree 2 keeps its derivatives
    t = np.arange(5000) / FS
    x = 3.0 + 2.0 * t - 0.5 * t**2
    d = state_variable_filter(x, FS, 10.0, 2)
    mid = interior(10.0, 3)
    np.testing.assert_allclose(d[1, mid], (2.0 - t)[mid], atol=1e-9)
    np.testing.assert_allclose(d[2, mid], -1.0, atol=1e-5)  # edge transient < tol
    fd = finite_difference_derivatives(x, FS, 2)
    np.testing.assert_allclose(fd[1, 2:-2], (2.0 - t)[2:-2], atol=1e-9)
    np.testing.assert_allclose(fd[2, 2:-2], -1.0, atol=1e-6)


@pytest.mark.parametrize("zero_phase", [True, False])
def test_ode_holds_for_filtered_signals(zero_phase):
    # m y'' + b y' + k y = u holds for the filtered u, y (lecture, "Signal Filtering")
    m, b, k = 5.0, 1.0, 10.0
    rng = np.random.default_rng(0)
    u = signal.sosfilt(signal.butter(4, 3.0, fs=FS, output="sos"), rng.standard_normal(40000))
    numd, dend, _ = signal.cont2discrete(([1.0], [m, b, k]), 1 / FS, method="foh")
    y = signal.lfilter(np.ravel(numd), dend, u)
    Y = state_variable_filter(y, FS, 5.0, 2, zero_phase=zero_phase)
    U = state_variable_filter(u, FS, 5.0, 0, order=3, zero_phase=zero_phase)[0]
    n = settling_samples(FS, 5.0, 3)
    # causal mode has no end transient to drop, but its start needs the same settling
    mid = slice(n, -n) if zero_phase else slice(n, None)
    lhs = m * Y[2] + b * Y[1] + k * Y[0]
    err = lhs[mid] - U[mid]
    assert np.sqrt(np.mean(err**2)) < 1e-3 * np.sqrt(np.mean(U[mid] ** 2))


def test_svf_suppresses_noise_that_finite_differences_amplify():
    rng = np.random.default_rng(1)
    t = np.arange(30000) / FS
    w = 2 * np.pi * 0.5
    clean = np.sin(w * t)
    x = clean + 0.01 * rng.standard_normal(t.size)
    mid = interior(3.0, 3)
    svf_err = state_variable_filter(x, FS, 3.0, 2)[2] - state_variable_filter(clean, FS, 3.0, 2)[2]
    fd_err = finite_difference_derivatives(x, FS, 2)[2] - finite_difference_derivatives(clean, FS, 2)[2]
    signal_rms = w**2 / np.sqrt(2)
    assert np.std(svf_err[mid]) < 0.05 * signal_rms
    assert np.std(fd_err[mid]) > 100 * signal_rms


@settings(max_examples=20, deadline=None)
@given(a=st.floats(-10, 10), c=st.floats(-10, 10), seed=st.integers(0, 2**16))
def test_svf_is_linear(a, c, seed):
    assume(abs(a) + abs(c) > 1e-3)
    rng = np.random.default_rng(seed)
    x, z = rng.standard_normal((2, 400))
    lhs = state_variable_filter(a * x + c * z, FS, 50.0, 2)
    rhs = a * state_variable_filter(x, FS, 50.0, 2) + c * state_variable_filter(z, FS, 50.0, 2)
    for k in range(3):
        np.testing.assert_allclose(lhs[k], rhs[k], rtol=0, atol=1e-10 * np.abs(rhs[k]).max())


def test_settling_grows_as_cutoff_falls():
    assert settling_samples(FS, 2.0, 3) > settling_samples(FS, 20.0, 3) > 0
    assert settling_samples(FS, 20.0, 5) > settling_samples(FS, 20.0, 3)


def test_output_shape_and_short_signal():
    d = state_variable_filter(np.arange(100.0) ** 2, FS, 100.0, 3)
    assert d.shape == (4, 100)
    assert np.all(np.isfinite(d))
    assert finite_difference_derivatives(np.arange(20.0), FS, 3).shape == (4, 20)


def test_rejects_bad_arguments():
    x = np.random.default_rng(0).standard_normal(1000)
    with pytest.raises(ConfigError, match="order"):
        state_variable_filter(x, FS, 10.0, 2, order=2)
    with pytest.raises(ConfigError, match="cutoff_hz"):
        state_variable_filter(x, FS, 600.0, 2)
    with pytest.raises(ConfigError, match="sample_rate_hz"):
        state_variable_filter(x, -1.0, 10.0, 2)
    with pytest.raises(ConfigError, match="kind"):
        state_variable_filter(x, FS, 10.0, 2, kind="cheby")
    with pytest.raises(ConfigError, match="n_derivatives"):
        state_variable_filter(x, FS, 10.0, -1)
    bad = x.copy()
    bad[5] = np.nan
    with pytest.raises(DataError, match="non-finite"):
        state_variable_filter(bad, FS, 10.0, 2)
    with pytest.raises(ConfigError, match="'n'|\\[n\\]"):
        finite_difference_derivatives(x, FS, 1.5)
