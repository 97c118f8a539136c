import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.arx import fit_arx, predict
from hilident.ident.validation import fit_percent, overfitting_warning, residual_analysis


def zoh_plant(zeta, f0_hz=5.0, fs=100.0):
    w0 = 2 * np.pi * f0_hz
    bd, ad, _ = signal.cont2discrete(([w0**2], [1.0, 2 * zeta * w0, w0**2]), 1 / fs, "zoh")
    return np.ravel(bd), ad  # ARX(na=2, nb=2, nk=1)


def arx_data(seed, n, noise_rel, zeta=0.1):
    """Data whose true model is ARX(2, 2, 1) with white equation noise."""
    bd, ad = zoh_plant(zeta)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    y0 = signal.lfilter(bd, ad, u)
    e = noise_rel * np.std(y0) * rng.standard_normal(n)
    return u, y0 + signal.lfilter([1.0], ad, e)


# --- fit_percent --------------------------------------------------------------


def test_fit_percent_reference_values():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full(4, y.mean())) == pytest.approx(0.0)
    # error norm equal to half the spread -> 50 %
    spread = np.linalg.norm(y - y.mean())
    d = np.array([1.0, -1.0, 1.0, -1.0]) * spread / 4.0
    assert fit_percent(y, y + d) == pytest.approx(50.0)
    assert fit_percent(y, -y) < 0.0


@settings(max_examples=30, deadline=None)
@given(scale=st.floats(1e-3, 1e3), offset=st.floats(-1e3, 1e3), seed=st.integers(0, 1000))
def test_fit_percent_is_invariant_to_units_and_offset(scale, offset, seed):
    rng = np.random.default_rng(seed)
    y = rng.standard_normal(50)
    yhat = y + 0.3 * rng.standard_normal(50)
    assert fit_percent(scale * y + offset, scale * yhat + offset) == pytest.approx(fit_percent(y, yhat), abs=1e-6)


def test_fit_percent_rows_and_errors():
    y = np.vstack([np.arange(5.0), np.arange(5.0) ** 2])
    assert fit_percent(y, y) == pytest.approx([100.0, 100.0])
    with pytest.raises(DataError, match="shape"):
        fit_percent(np.ones(3), np.ones(4))
    with pytest.raises(DataError, match="constant"):
        fit_percent(np.ones(5), np.zeros(5))


# --- residual_analysis --------------------------------------------------------


def test_band_and_lag_conventions():
    rng = np.random.default_rng(0)
    n = 10000
    u = rng.standard_normal(n + 3)
    e = u[:-3] + 0.5 * rng.standard_normal(n)  # e(k) = u(k - 3) + noise
    res = residual_analysis(e, u[3:], max_lag=10)
    assert res.bound == pytest.approx(2.5758 / np.sqrt(n), rel=1e-4)
    assert res.autocorr[0] == pytest.approx(1.0)
    assert res.cross_lags[np.argmax(np.abs(res.crosscorr))] == 3
    assert res.crosscorr[res.cross_lags == 3][0] == pytest.approx(1 / np.sqrt(1.25), abs=0.02)
    assert not res.independent and res.white


def test_ar1_residuals_have_geometric_autocorrelation_and_fail():
    rng = np.random.default_rng(1)
    e = signal.lfilter([1.0], [1.0, -0.6], rng.standard_normal(20000))
    res = residual_analysis(e, max_lag=5)
    assert res.autocorr == pytest.approx(0.6 ** np.arange(6), abs=0.03)
    assert not res.white and res.ljung_box_p < 1e-10
    assert res.independent and res.crosscorr.size == 0


def test_correct_arx_model_passes_too_low_order_fails():
    """Over repeated experiments: right order is white and independent of u
    (allowing for the chance of one of 20-41 lags leaving a 99 % band), too
    low an order always fails."""
    runs = 20
    white = independent = lb_ok = 0
    for seed in range(runs):
        u, y = arx_data(seed, 2000, 0.05)
        good = fit_arx(u, y, 2, 2, 1)
        e = (y - predict(good, u, y))[2:]
        res = residual_analysis(e, u[2:], max_lag=20)
        white += res.white
        independent += res.independent
        lb_ok += res.ljung_box_p > 0.01

        low = fit_arx(u, y, 1, 1, 1)
        e_low = (y - predict(low, u, y))[1:]
        res_low = residual_analysis(e_low, u[1:], max_lag=20)
        assert not res_low.white and not res_low.independent
        assert res_low.ljung_box_p < 1e-6
    assert white >= 13  # expected about 0.99**20 * 20 = 16
    assert independent >= 9  # expected about 0.99**41 * 20 = 13
    assert lb_ok >= 17


def test_residual_analysis_errors():
    e = np.random.default_rng(0).standard_normal(100)
    with pytest.raises(ConfigError, match="max_lag"):
        residual_analysis(e, max_lag=0)
    with pytest.raises(DataError, match="too few"):
        residual_analysis(e, max_lag=60)
    with pytest.raises(DataError, match="shape"):
        residual_analysis(e, e[:-1])
    with pytest.raises(ConfigError, match="confidence"):
        residual_analysis(e, confidence=99)


# --- overfitting --------------------------------------------------------------


def test_overfit_high_order_model_on_short_noisy_data_warns():
    """Short record (50 samples), 30 parameters: the estimation fit is inflated
    and the validation fit drops; the true order does not warn."""
    warned_high = warned_true = 0
    drops_high = []
    for seed in range(10):
        u, y = arx_data(seed, 50, 0.3, zeta=0.4)
        uv, yv = arx_data(seed + 1000, 2000, 0.3, zeta=0.4)
        for order in (2, 15):
            model = fit_arx(u, y, order, order, 1)
            fit_est = fit_percent(y[order:], predict(model, u, y)[order:])
            fit_val = fit_percent(yv[order:], predict(model, uv, yv)[order:])
            warning = overfitting_warning(fit_est, fit_val)
            if order == 2:
                warned_true += warning is not None
            else:
                warned_high += warning is not None
                drops_high.append(fit_est - fit_val)
    assert warned_high >= 8 and warned_true == 0
    assert np.median(drops_high) > 20


def test_overfitting_warning_rules():
    assert overfitting_warning(90.0, 85.0) is None
    msg = overfitting_warning(90.0, 70.0)
    assert "90.0" in msg and "70.0" in msg and "overfitting" in msg
    assert overfitting_warning(90.0, 84.0, drop_percent=5) is not None
    assert overfitting_warning(90.0, -np.inf) is not None
    assert overfitting_warning(90.0, np.nan) is not None
    with pytest.raises(ConfigError, match="drop_percent"):
        overfitting_warning(90.0, 80.0, drop_percent=-1)
