import numpy as np
import pytest
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.blackbox import OdeCandidate, ode_order_search, select_order

FS = 1000.0
T = 1.0 / FS


def band_limited_noise(n, bandwidth_hz, rms, seed):
    rng = np.random.default_rng(seed)
    sos = signal.butter(4, bandwidth_hz, fs=FS, output="sos")
    u = signal.sosfilt(sos, rng.standard_normal(n))
    return u * rms / np.std(u), rng


def simulate_tf(num, den, u):
    """Exact response to the piecewise-linear interpolation of u."""
    numd, dend, _ = signal.cont2discrete((num, den), T, method="foh")
    return signal.lfilter(np.ravel(numd), dend, u)


def with_noise(y, rng, relative=0.01):
    return y + relative * np.std(y) * rng.standard_normal(y.size)


@pytest.fixture(scope="module")
def msd_search():
    """Lecture's MSD (m=5, b=1, k=10), 300 s at 1 kHz, 1 % position noise, n<=3, m<=1."""
    force, rng = band_limited_noise(300_000, 2.0, 10.0, seed=1)
    y = with_noise(simulate_tf([1.0], [5.0, 1.0, 10.0], force), rng)
    return ode_order_search(force, y, FS, cutoff_hz=2.0, n_max=3, m_max=1)


def by_order(candidates):
    return {(c.n, c.m): c for c in candidates}


def test_search_covers_the_lecture_grid(msd_search):
    orders = [(c.n, c.m) for c in msd_search]
    assert orders == [(1, 0), (2, 0), (2, 1), (3, 0), (3, 1)]
    c = by_order(msd_search)
    assert c[(3, 1)].fit.names == ("a1", "a2", "a3", "b0", "b1")
    # nested models: more parameters never raise V
    assert c[(2, 0)].fit.cost_V <= c[(1, 0)].fit.cost_V
    assert c[(3, 0)].fit.cost_V <= c[(2, 0)].fit.cost_V
    assert c[(3, 1)].fit.cost_V <= min(c[(3, 0)].fit.cost_V, c[(2, 1)].fit.cost_V)
    # a first-order model cannot describe the resonance
    assert c[(1, 0)].fit.cost_V > 1000 * c[(2, 0)].fit.cost_V


def test_redundant_parameters_are_flagged(msd_search):
    c = by_order(msd_search)
    assert c[(2, 0)].insignificant == ()
    assert c[(2, 1)].insignificant == ("b1",)
    assert c[(3, 0)].insignificant == ("a3",)
    assert set(c[(3, 1)].insignificant) == {"a3", "b1"}


def test_selects_second_order_and_recovers_m_b_k(msd_search):
    best = select_order(msd_search)
    assert (best.n, best.m) == (2, 0)
    p = best.fit.params
    # lecture: -a2 y'' - a1 y' + b0 u = y  ->  (a2/b0) y'' + (a1/b0) y' + (1/b0) y = u
    m, b, k = p["a2"] / p["b0"], p["a1"] / p["b0"], 1.0 / p["b0"]
    assert m == pytest.approx(5.0, rel=0.01)
    assert b == pytest.approx(1.0, rel=0.01)
    assert k == pytest.approx(10.0, rel=0.01)
    assert best.stable
    # same choice by AIC
    assert (select_order(msd_search, criterion="aic").n, select_order(msd_search, "aic").m) == (2, 0)


def test_transfer_function_matches_the_plant(msd_search):
    best = select_order(msd_search)
    num, den = best.transfer_function()
    assert den[0] == 1.0
    w = 2 * np.pi * np.array([0.05, 0.2, 0.225, 0.5, 1.0, 2.0])
    _, h_fit = signal.freqs(num, den, worN=w)
    _, h_true = signal.freqs([1.0], [5.0, 1.0, 10.0], worN=w)
    np.testing.assert_allclose(h_fit, h_true, rtol=0.01)
    # usable by scipy.signal directly
    t, step = signal.step(signal.lti(num, den), T=np.linspace(0, 5, 50))
    assert step[-1] > 0


def test_selects_a_model_with_a_zero():
    # (0.5 s + 1) / (0.05 s^2 + 0.3 s + 1): needs n = 2, m = 1
    u, rng = band_limited_noise(120_000, 3.0, 1.0, seed=3)
    y = with_noise(simulate_tf([0.5, 1.0], [0.05, 0.3, 1.0], u), rng)
    best = select_order(ode_order_search(u, y, FS, cutoff_hz=3.0, n_max=3, m_max=1))
    assert (best.n, best.m) == (2, 1)
    np.testing.assert_allclose(best.den, [0.05, 0.3, 1.0], rtol=0.01)
    np.testing.assert_allclose(best.num, [0.5, 1.0], rtol=0.01)


def test_first_order_system():
    u, rng = band_limited_noise(60_000, 2.0, 1.0, seed=4)
    y = with_noise(simulate_tf([2.0], [0.5, 1.0], u), rng)
    best = select_order(ode_order_search(u, y, FS, cutoff_hz=3.0, n_max=2, m_max=1))
    assert (best.n, best.m) == (1, 0)
    assert best.fit.params["a1"] == pytest.approx(0.5, rel=0.01)
    assert best.fit.params["b0"] == pytest.approx(2.0, rel=0.01)


def test_single_sine_cannot_identify_second_order():
    # one frequency spans only two dimensions: u, y, y', y'' are collinear
    t = np.arange(20_000) / FS
    w = 2 * np.pi * 0.5
    u = np.sin(w * t)
    _, g = signal.freqs([1.0], [5.0, 1.0, 10.0], worN=[w])
    y = abs(g[0]) * np.sin(w * t + np.angle(g[0]))  # steady state: no transient
    cands = ode_order_search(u, y, FS, cutoff_hz=3.0, n_max=2, m_max=0)
    second = by_order(cands)[(2, 0)]
    assert second.fit is None
    assert "not identifiable" in second.error
    with pytest.raises(DataError, match="not fitted"):
        second.transfer_function()


def test_unrelated_output_has_no_adequate_model():
    u, rng = band_limited_noise(20_000, 2.0, 1.0, seed=5)
    y, _ = band_limited_noise(20_000, 2.0, 1.0, seed=6)
    cands = ode_order_search(u, y, FS, cutoff_hz=3.0, n_max=1, m_max=0)
    with pytest.raises(DataError, match="no candidate"):
        select_order(cands, require_stable=False)


def test_argument_errors(msd_search):
    u, _ = band_limited_noise(5000, 2.0, 1.0, seed=7)
    y = simulate_tf([1.0], [0.5, 1.0], u)
    with pytest.raises(ConfigError, match="n_max"):
        ode_order_search(u, y, FS, 3.0, n_max=0)
    with pytest.raises(ConfigError, match="order"):
        ode_order_search(u, y, FS, 3.0, n_max=3, order=3)
    with pytest.raises(ConfigError, match="min_contribution"):
        ode_order_search(u, y, FS, 3.0, min_contribution=1.5)
    with pytest.raises(ConfigError, match="criterion"):
        select_order(msd_search, criterion="fpe")
    with pytest.raises(DataError, match="'y'"):
        ode_order_search(u, y[:-1], FS, 3.0)
    with pytest.raises(DataError, match="settling"):
        ode_order_search(u[:300], y[:300], FS, 0.5)
    assert isinstance(msd_search[0], OdeCandidate)
