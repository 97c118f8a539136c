"""Model validation: fit percentage, residual tests and an overfitting check.

A model is judged on data it was not fitted to (thesis section 2.4): its
simulated or predicted output is compared with the measurement
(:func:`fit_percent`), its residuals should be white and uncorrelated with
past inputs (:func:`residual_analysis`), and a fit that is much worse on
validation data than on estimation data means the model learnt the noise
(:func:`overfitting_warning`).

Examples
--------
>>> import numpy as np
>>> from hilident.ident.validation import fit_percent, residual_analysis
>>> rng = np.random.default_rng(1)
>>> y = np.sin(np.linspace(0, 20, 1000))
>>> round(float(fit_percent(y, y + 0.01 * rng.standard_normal(1000))), 0)
99.0
>>> res = residual_analysis(rng.standard_normal(2000), rng.standard_normal(2000), max_lag=10)
>>> bool(res.bound < 0.06)
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal, stats

from hilident.errors import ConfigError, DataError

__all__ = ["fit_percent", "ResidualAnalysis", "residual_analysis", "overfitting_warning"]


def fit_percent(y: ArrayLike, yhat: ArrayLike) -> np.ndarray | float:
    """Normalised root-mean-square fit, % (MATLAB ``compare``/``goodnessOfFit`` NRMSE).

    ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)`` along the last axis: 100 is
    a perfect model, 0 is no better than the mean of `y`, and it is negative
    (unbounded) for worse models.

    Parameters
    ----------
    y : array_like
        Measured output.
    yhat : array_like
        Model output (simulated or predicted), same shape.

    Returns
    -------
    float or ndarray
        A float for 1-D input, else an array over the leading axes.
    """
    y = np.asarray(y, dtype=np.float64)
    yhat = np.asarray(yhat, dtype=np.float64)
    if y.shape != yhat.shape:
        raise DataError(f"y has shape {y.shape} but yhat has shape {yhat.shape}")
    if y.shape[-1] < 2:
        raise DataError(f"need at least 2 samples, got {y.shape[-1]}")
    spread = np.linalg.norm(y - y.mean(axis=-1, keepdims=True), axis=-1)
    if np.any(spread == 0.0):
        raise DataError("y is constant; a fit percentage is undefined")
    fit = 100.0 * (1.0 - np.linalg.norm(y - yhat, axis=-1) / spread)
    return float(fit) if np.ndim(fit) == 0 else fit


@dataclass(frozen=True, eq=False)
class ResidualAnalysis:
    """Correlation tests of prediction residuals (Ljung's ``resid``).

    Attributes
    ----------
    lags : ndarray
        ``0 .. max_lag`` for `autocorr`.
    autocorr : ndarray
        Normalised autocorrelation of the residuals, ``autocorr[0] == 1``.
    cross_lags : ndarray
        ``-max_lag .. max_lag`` for `crosscorr` (empty without input).
    crosscorr : ndarray
        Normalised cross-correlation ``r_eu(tau) = sum e(k) u(k - tau) /
        (N s_e s_u)``; positive lags: the input leads the residual (missing
        dynamics), negative lags: the residual leads the input (feedback).
    bound : float
        Half-width of the confidence band, ``z / sqrt(N)`` (2.58/sqrt(N) at 99 %).
    white : bool
        Every ``|autocorr[1:]|`` inside the band.
    independent : bool
        Every ``|crosscorr|`` inside the band (True without input).
    ljung_box_p : float
        p-value of the Ljung-Box portmanteau test over lags ``1 .. max_lag``:
        a joint whiteness test. With many lags, some single value may leave a
        99 % band by chance (about 1 in 100 lags) even for white residuals;
        a small p-value (< 0.01) is the stronger evidence of colour.
    """

    lags: np.ndarray
    autocorr: np.ndarray
    cross_lags: np.ndarray
    crosscorr: np.ndarray
    bound: float
    white: bool
    independent: bool
    ljung_box_p: float


def _normalised_xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """``sum_k a(k) b(k - tau) / (N s_a s_b)`` for ``tau = -max_lag .. max_lag``."""
    n = a.size
    full = signal.correlate(a, b, mode="full", method="fft")  # index n-1 is lag 0
    mid = n - 1
    return full[mid - max_lag : mid + max_lag + 1] / (n * a.std() * b.std())


def residual_analysis(
    residuals: ArrayLike,
    u: ArrayLike | None = None,
    max_lag: int = 25,
    confidence: float = 0.99,
) -> ResidualAnalysis:
    """Whiteness and input-independence tests of model residuals.

    Parameters
    ----------
    residuals : array_like
        ``y - yhat`` of a one-step-ahead prediction (skip the first samples
        that had no full history).
    u : array_like, optional
        Input over the same samples.
    max_lag : int
        Largest lag tested, samples.
    confidence : float
        Two-sided level of the band; 0.99 gives ``+-2.58 / sqrt(N)``.

    Returns
    -------
    ResidualAnalysis
    """
    e = np.asarray(residuals, dtype=np.float64)
    if e.ndim != 1 or not np.all(np.isfinite(e)):
        raise DataError(f"residuals must be a finite 1-D array, got shape {e.shape}")
    if isinstance(max_lag, bool) or int(max_lag) != max_lag or max_lag < 1:
        raise ConfigError("max_lag", f"must be a positive integer, got {max_lag!r}")
    max_lag = int(max_lag)
    if e.size <= 2 * max_lag:
        raise DataError(f"{e.size} residuals are too few for max_lag={max_lag}")
    if not 0.0 < confidence < 1.0:
        raise ConfigError("confidence", f"must lie in (0, 1), got {confidence!r}")
    e = e - e.mean()
    if not np.any(e):
        raise DataError("residuals are constant; nothing to test")
    n = e.size
    bound = float(stats.norm.ppf(0.5 + confidence / 2.0) / np.sqrt(n))
    auto = _normalised_xcorr(e, e, max_lag)[max_lag:]
    lags = np.arange(max_lag + 1)
    q = n * (n + 2) * np.sum(auto[1:] ** 2 / (n - lags[1:]))
    p_value = float(stats.chi2.sf(q, df=max_lag))
    if u is None:
        cross_lags, cross = np.empty(0, int), np.empty(0)
    else:
        uu = np.asarray(u, dtype=np.float64)
        if uu.shape != e.shape or not np.all(np.isfinite(uu)):
            raise DataError(f"u must be finite with the residuals' shape {e.shape}, got {uu.shape}")
        uu = uu - uu.mean()
        if not np.any(uu):
            raise DataError("input u is constant; cross-correlation undefined")
        cross_lags = np.arange(-max_lag, max_lag + 1)
        cross = _normalised_xcorr(e, uu, max_lag)
    return ResidualAnalysis(
        lags=lags,
        autocorr=auto,
        cross_lags=cross_lags,
        crosscorr=cross,
        bound=bound,
        white=bool(np.all(np.abs(auto[1:]) < bound)),
        independent=bool(np.all(np.abs(cross) < bound)),
        ljung_box_p=p_value,
    )


def overfitting_warning(fit_estimation: float, fit_validation: float, drop_percent: float = 10.0) -> str | None:
    """A warning when the validation fit is much worse than the estimation fit.

    Parameters
    ----------
    fit_estimation, fit_validation : float
        Fit percentages (:func:`fit_percent`) of the same model on the
        estimation and on fresh validation data.
    drop_percent : float
        Largest acceptable drop, percentage points.

    Returns
    -------
    str or None
        A one-line warning naming both fits, or None if the drop is acceptable.
        A non-finite validation fit (the model diverges) always warns.
    """
    if not np.isfinite(drop_percent) or drop_percent < 0:
        raise ConfigError("drop_percent", f"must be a number >= 0, got {drop_percent!r}")
    fe, fv = float(fit_estimation), float(fit_validation)
    if np.isnan(fe):
        raise DataError("fit_estimation is NaN")
    if np.isfinite(fv) and fe - fv <= drop_percent:
        return None
    return (
        f"possible overfitting: fit {fe:.1f} % on estimation data but {fv:.1f} % on "
        f"validation data (drop {fe - fv:.1f} points > {drop_percent:g}); "
        f"try a lower model order or more data"
    )
