import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.arx import (
    arx_order_search,
    arx_to_ba,
    fit_arx,
    predict,
    simulate,
)

# --- lecture: Euler-discretised mass-spring-damper, T = 1 ms -----------------

M, B, K, T = 5.0, 1.0, 10.0, 1e-3
DEN = M / T**2 + B / T + K
A1_TRUE = (2 * M / T**2 + B / T) / DEN
A2_TRUE = -(M / T**2) / DEN
B0_TRUE = 1.0 / DEN


def lecture_data(n=20000, seed=0, hold=20):
    """Random steps held for `hold` samples (rich at the plant's low frequencies)."""
    rng = np.random.default_rng(seed)
    u = 100.0 * np.repeat(rng.standard_normal(n // hold), hold)
    y = signal.lfilter([B0_TRUE], [1.0, -A1_TRUE, -A2_TRUE], u)
    return u, y


def test_lecture_coefficients_are_what_the_slides_print():
    assert round(A1_TRUE, 4) == 1.9998
    assert round(A2_TRUE, 4) == -0.9998
    # The slides print b0 = 1.984e-7 as their estimate; the exact value is 1/DEN.
    assert B0_TRUE == pytest.approx(1.9996e-7, rel=1e-4)


def test_lecture_msd_recovered():
    u, y = lecture_data()
    model = fit_arx(u, y, na=2, nb=1, nk=0)
    assert (model.na, model.nb, model.nk) == (2, 1, 0)
    assert round(model.a[0], 4) == 1.9998 and round(model.a[1], 4) == -0.9998
    assert model.a == pytest.approx([A1_TRUE, A2_TRUE], abs=5e-6)
    assert model.b[0] == pytest.approx(B0_TRUE, rel=0.005)
    assert model.fit_percent > 99.99
    assert model.n_equations == u.size - 2


def test_lecture_msd_with_tiny_equation_noise_has_honest_stderr():
    u, y = lecture_data(seed=3)
    rng = np.random.default_rng(3)
    e = 1e-6 * rng.standard_normal(u.size)
    y = y + signal.lfilter([1.0], [1.0, -A1_TRUE, -A2_TRUE], e)
    model = fit_arx(u, y, 2, 1, 0)
    truth = np.array([A1_TRUE, A2_TRUE, B0_TRUE])
    assert model.a == pytest.approx(truth[:2], abs=5e-5)
    assert model.b[0] == pytest.approx(B0_TRUE, rel=0.005)
    z = (model.params - truth) / model.stderr
    assert np.all(np.abs(z) < 4.0)
    assert model.noise_variance == pytest.approx(1e-12, rel=0.05)


# --- general behaviour --------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(
    na=st.integers(0, 3),
    nb=st.integers(1, 3),
    nk=st.integers(0, 2),
    seed=st.integers(0, 2**32 - 1),
)
def test_exact_recovery_of_random_stable_arx(na, nb, nk, seed):
    rng = np.random.default_rng(seed)
    poles = rng.uniform(0.1, 0.9, na) * np.exp(1j * rng.uniform(0, np.pi, na))
    poles = np.where(np.arange(na) % 2 == 0, poles.real, poles)  # keep it real-coefficient
    a_scipy = np.real(np.poly(poles)) if na else np.array([1.0])
    b_coef = rng.uniform(0.2, 1.0, nb) * rng.choice([-1, 1], nb)
    u = rng.standard_normal(400)
    y = signal.lfilter(np.r_[np.zeros(nk), b_coef], a_scipy, u)
    model = fit_arx(u, y, na, nb, nk)
    assert model.a == pytest.approx(-a_scipy[1:], abs=1e-8)
    assert model.b == pytest.approx(b_coef, abs=1e-8)
    b, a = arx_to_ba(model)
    assert a == pytest.approx(a_scipy, abs=1e-8)
    assert b[:nk] == pytest.approx(np.zeros(nk)) and b[nk:] == pytest.approx(b_coef, abs=1e-8)


def zoh_plant(f0_hz=5.0, zeta=0.1, fs=100.0):
    w0 = 2 * np.pi * f0_hz
    bd, ad, _ = signal.cont2discrete(([w0**2], [1.0, 2 * zeta * w0, w0**2]), 1 / fs, "zoh")
    return np.ravel(bd), ad  # b = (0, b1, b2): na = 2, nb = 2, nk = 1


def test_parameter_stderr_is_calibrated():
    """About 95 % of 2-sigma intervals contain the truth over repeated experiments."""
    bd, ad = zoh_plant()
    truth = np.r_[-ad[1:], bd[1:]]
    inside = 0
    runs = 40
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        u = rng.standard_normal(500)
        y = signal.lfilter(bd, ad, u) + signal.lfilter([1.0], ad, 0.05 * rng.standard_normal(500))
        model = fit_arx(u, y, 2, 2, 1)
        inside += np.sum(np.abs(model.params - truth) < 2 * model.stderr)
    assert 0.88 < inside / (4 * runs) < 0.99


def test_predict_and_simulate_reproduce_noise_free_data():
    bd, ad = zoh_plant()
    rng = np.random.default_rng(5)
    u = rng.standard_normal(800)
    y = signal.lfilter(bd, ad, u)
    model = fit_arx(u, y, 2, 2, 1)
    assert predict(model, u, y) == pytest.approx(y, abs=1e-10)
    assert simulate(model, u) == pytest.approx(y, abs=1e-9)
    # start mid-record from the measured history: continues the same trajectory
    sim = simulate(model, u[300:], y0=y[300:302])
    assert sim == pytest.approx(y[300:], abs=1e-9)


def test_poles_and_step_response_of_fitted_zoh_plant():
    w0, zeta, fs = 2 * np.pi * 5.0, 0.1, 100.0
    bd, ad = zoh_plant(5.0, zeta, fs)
    rng = np.random.default_rng(2)
    u = rng.standard_normal(600)
    model = fit_arx(u, signal.lfilter(bd, ad, u), 2, 2, 1)
    s = complex(-zeta * w0, w0 * np.sqrt(1 - zeta**2))
    expected = np.exp(np.array([s, s.conjugate()]) / fs)
    assert np.sort_complex(model.poles) == pytest.approx(np.sort_complex(expected), abs=1e-9)
    step = simulate(model, np.ones(2000))  # constant input is fine for simulation
    assert step[-1] == pytest.approx(1.0, abs=1e-6)  # static gain w0^2 / w0^2
    assert predict(model, np.ones(50), step[:50]) == pytest.approx(step[:50], abs=1e-9)


def test_one_step_prediction_beats_free_run_under_equation_noise():
    bd, ad = zoh_plant()
    rng = np.random.default_rng(9)
    u = rng.standard_normal(3000)
    y = signal.lfilter(bd, ad, u) + signal.lfilter([1.0], ad, 0.1 * rng.standard_normal(3000))
    model = fit_arx(u, y, 2, 2, 1)
    e_pred = (y - predict(model, u, y))[2:]
    e_sim = (y - simulate(model, u, y0=y[:2]))[2:]
    assert np.std(e_pred) == pytest.approx(0.1, rel=0.05)  # innovations are the noise itself
    assert np.std(e_sim) > 3 * np.std(e_pred)


# --- order search -------------------------------------------------------------


def second_order_data(seed, n=3000, noise=0.02, kind="equation"):
    bd, ad = zoh_plant()
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    y0 = signal.lfilter(bd, ad, u)
    white = noise * np.std(y0) * rng.standard_normal(n)
    y = y0 + (signal.lfilter([1.0], ad, white) if kind == "equation" else white)
    return u, y


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_order_search_bic_finds_true_structure(seed):
    u, y = second_order_data(seed)
    res = arx_order_search(u, y, range(1, 5), range(1, 4), range(0, 3), criterion="bic")
    assert (res.model.na, res.model.nb, res.model.nk) == (2, 2, 1)
    assert len(res.candidates) == 4 * 3 * 3
    assert res.criterion == "bic"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_order_search_aic_picks_na_2(seed):
    u, y = second_order_data(seed)
    res = arx_order_search(u, y, range(1, 5), range(1, 4), range(0, 3), criterion="aic")
    assert res.model.na == 2 and res.model.nk == 1


@pytest.mark.parametrize("seed", [0, 1])
def test_order_search_validation_picks_na_2(seed):
    u, y = second_order_data(seed, noise=0.005, kind="output")
    uv, yv = second_order_data(seed + 100, noise=0.005, kind="output")
    res = arx_order_search(u, y, range(1, 5), range(1, 4), range(0, 3), criterion="validation", u_val=uv, y_val=yv)
    assert res.model.na == 2
    chosen = [c for c in res.candidates if (c.na, c.nb, c.nk) == (2, 2, 1)][0]
    assert chosen.fit_validation_percent > 95.0
    too_low = [c for c in res.candidates if (c.na, c.nb, c.nk) == (1, 1, 1)][0]
    assert too_low.fit_validation_percent < chosen.fit_validation_percent - 20


def test_order_search_noise_free_ties_go_to_fewest_parameters():
    u, y = second_order_data(0, noise=0.0)
    res = arx_order_search(u, y, range(1, 5), range(1, 4), range(0, 3), criterion="aic")
    assert (res.model.na, res.model.nb, res.model.nk) == (2, 2, 1)


# --- size and errors ----------------------------------------------------------


def test_a_million_samples_fit_exactly():
    """A record of 10**6 samples fits (its speed is bench/ident.py's to measure, not a timed test's)."""
    rng = np.random.default_rng(0)
    u = rng.standard_normal(1_000_000)
    y = signal.lfilter([0, 0.5, 0.2, 0.1, 0.05], [1, -1.2, 0.5, -0.1, 0.02], u)
    model = fit_arx(u, y, 4, 4, 1)
    assert model.b == pytest.approx([0.5, 0.2, 0.1, 0.05], abs=1e-8)


def test_errors_name_the_argument():
    u, y = second_order_data(0, n=100)
    with pytest.raises(ConfigError, match="na"):
        fit_arx(u, y, -1, 1)
    with pytest.raises(ConfigError, match="nk"):
        fit_arx(u, y, 1, 1, 0.5)
    with pytest.raises(DataError, match="'y'"):
        fit_arx(u, y[:-1], 2, 2)
    with pytest.raises(DataError, match="regression rows"):
        fit_arx(u[:10], y[:10], 4, 4, 1)
    sine = np.sin(0.3 * np.arange(200))  # persistently exciting of order 2 only
    with pytest.raises(DataError, match="linearly dependent"):
        fit_arx(sine, signal.lfilter([0, 1.0], [1, -0.5], sine), 0, 3, 1)
    with pytest.raises(ConfigError, match="criterion"):
        arx_order_search(u, y, [2], [2], [1], criterion="mdl")
    with pytest.raises(ConfigError, match="u_val"):
        arx_order_search(u, y, [2], [2], [1], criterion="validation")
