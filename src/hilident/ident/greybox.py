"""Grey-box identification: least squares on models that are linear in their parameters.

The structure is known, the parameters are not (lecture, "Grey Box"). Every
model here is written as ``target = sum_i theta_i * regressor_i``; the
parameters minimise the lecture's cost ``V = 1/2 sum e^2`` with
``e = target - A theta``. Derivatives come from the state-variable filter of
:mod:`hilident.ident.derivatives`, which filters input and output alike so the
model equation still holds for the filtered signals.

* :func:`fit_linear` -- named regressors in, :class:`LinearFit` out (parameters,
  standard errors, fit %, condition number, excitation warnings).
* :func:`check_excitation` -- is every parameter identifiable from these data?
* :func:`fit_mass_spring_damper` -- ``m y'' + b y' + k y = F``.
* :func:`fit_dc_motor_speed` -- ``JL/kt w'' + (JR+bL)/kt w' + (bR+kt ke)/kt w = V``.
* :func:`fit_rigid_axis` -- ``M q'' + Fv q' + Fc sign(q') + offset = force``.
* :func:`fit_torque_constant` -- thesis eqs. 3.3-3.4, ``M p'' = c (tau - tau_fr)``.

Standard errors assume independent residuals. Filtered, oversampled signals
have strongly correlated residuals, so the ``fit_*`` convenience functions
pass an effective sample count ``n_effective = 2 * cutoff_hz * duration`` (the
number of independent values a signal band-limited to `cutoff_hz` holds) and
the covariance is scaled by ``N / n_effective``. It is an approximation; treat
the standard errors as indicative, not exact.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.greybox import fit_linear
>>> rng = np.random.default_rng(0)
>>> x1, x2 = rng.standard_normal((2, 1000))
>>> fit = fit_linear({"a": x1, "b": x2}, 2.0 * x1 - 0.5 * x2)
>>> round(fit.params["a"], 6), round(fit.params["b"], 6)
(2.0, -0.5)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError
from hilident.ident.derivatives import (
    finite_difference_derivatives,
    settling_samples,
    state_variable_filter,
)
from hilident.ident.preprocess import check_signals
from hilident.ident.validation import fit_percent

__all__ = [
    "LinearFit",
    "fit_linear",
    "check_excitation",
    "fit_mass_spring_damper",
    "fit_dc_motor_speed",
    "fit_rigid_axis",
    "fit_torque_constant",
    "DC_MOTOR_NAMES",
]

#: Names of the combined DC-motor parameters (lecture, "Example: DC Motor Speed").
DC_MOTOR_NAMES = ("JL/kt", "(JR+bL)/kt", "(bR+kt*ke)/kt")


@dataclass(frozen=True, eq=False)
class LinearFit:
    """Result of a linear least-squares fit.

    Attributes
    ----------
    names : tuple of str
        Parameter names, in column order.
    params : dict of str to float
        Estimates.
    stderr : dict of str to float
        Standard errors, ``sqrt(diag(covariance))``.
    relative_stderr_percent : dict of str to float
        ``100 * stderr / |param|`` (inf for a zero estimate).
    contribution : dict of str to float
        ``rms(param * regressor) / rms(target)``: how much of the target the
        term carries. Near zero for a redundant term.
    covariance : ndarray, shape (p, p)
        ``s^2 (A^T A)^-1 * N / n_effective`` with ``s^2 = sum e^2 / (N - p)``.
    residual_rms : float
        RMS of ``target - A theta``, in target units.
    cost_V : float
        ``1/2 sum e^2`` (the lecture's V).
    fit_percent : float
        ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` (NRMSE, as MATLAB's
        ``compare``); 100 is a perfect fit.
    condition_number : float
        Condition number of ``A^T A`` with every column of ``A`` scaled to
        unit norm (scale-free measure of near-collinearity).
    n_samples : int
        Rows used.
    n_effective : float
        Effective number of independent rows used for the covariance.
    warnings : tuple of str
        Weak excitation and insignificant parameters.
    """

    names: tuple[str, ...]
    params: dict[str, float]
    stderr: dict[str, float]
    relative_stderr_percent: dict[str, float]
    contribution: dict[str, float]
    covariance: np.ndarray
    residual_rms: float
    cost_V: float
    fit_percent: float
    condition_number: float
    n_samples: int
    n_effective: float
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @property
    def theta(self) -> np.ndarray:
        """Parameters as a vector in column order."""
        return np.array([self.params[n] for n in self.names])

    def insignificant(self, n_sigma: float = 2.0, min_contribution: float = 0.0) -> tuple[str, ...]:
        """Names with ``|param| < n_sigma * stderr`` or contribution below `min_contribution`."""
        return tuple(
            n
            for n in self.names
            if abs(self.params[n]) < n_sigma * self.stderr[n] or self.contribution[n] < min_contribution
        )

    def predict(self, regressors: Mapping[str, ArrayLike]) -> np.ndarray:
        """``A theta`` for new regressors (same names)."""
        missing = [n for n in self.names if n not in regressors]
        if missing:
            raise DataError(f"regressors {missing} missing for prediction")
        cols = [np.asarray(regressors[n], dtype=np.float64) for n in self.names]
        return np.sum([c * self.params[n] for n, c in zip(self.names, cols, strict=True)], axis=0)

    def to_dict(self) -> dict:
        """Plain data (e.g. for summary.json)."""
        return {
            "params": dict(self.params),
            "stderr": dict(self.stderr),
            "relative_stderr_percent": dict(self.relative_stderr_percent),
            "contribution": dict(self.contribution),
            "residual_rms": self.residual_rms,
            "cost_V": self.cost_V,
            "fit_percent": self.fit_percent,
            "condition_number": self.condition_number,
            "n_samples": self.n_samples,
            "n_effective": self.n_effective,
            "warnings": list(self.warnings),
        }


# --- excitation --------------------------------------------------------------


def _scaled_svd(A: np.ndarray):
    norms = np.linalg.norm(A, axis=0)
    safe = np.where(norms > 0.0, norms, 1.0)
    U, s, Vt = np.linalg.svd(A / safe, full_matrices=False)
    return norms, U, s, Vt


def _excitation_report(norms, s, Vt, names, max_condition, warn_condition) -> list[str]:
    zero = [n for n, c in zip(names, norms, strict=False) if c == 0.0]
    if zero:
        raise DataError(
            f"parameters {zero} are not identifiable: their regressor columns are all zero "
            "(the data never excite these terms)"
        )
    smax = s[0]
    warnings = []
    bad: list[str] = []
    detail = []
    for si, v in zip(s, Vt, strict=False):
        cond = np.inf if si == 0.0 else (smax / si) ** 2
        if cond <= warn_condition:
            continue
        v = v / np.abs(v).max()
        involved = [n for n, c in zip(names, v, strict=False) if abs(c) >= 0.1]
        # the same dependency between the unscaled columns, for the message
        w = v / norms
        w = w / np.abs(w[[names.index(n) for n in involved]]).max()
        relation = "columns " + " ".join(f"{w[names.index(n)]:+.3g}*{n}" for n in involved) + " ~ 0"
        if cond > max_condition:
            bad.extend(n for n in involved if n not in bad)
            detail.append(f"{relation} (condition {cond:.3g})")
        else:
            warnings.append(
                f"weak excitation: parameters {involved} have nearly collinear regressors, "
                f"{relation} (condition number {cond:.3g} > {warn_condition:g}); "
                "their estimates are sensitive to noise"
            )
    if bad:
        raise DataError(
            f"parameters {bad} are not identifiable from these data: their regressor "
            f"columns are (nearly) collinear, {'; '.join(detail)}, max_condition="
            f"{max_condition:g}. Excite more richly (more frequencies, both directions)."
        )
    return warnings


def check_excitation(
    A: ArrayLike,
    names: Sequence[str],
    max_condition: float = 1e8,
    warn_condition: float = 1e5,
) -> list[str]:
    """Check that every column of the regressor matrix `A` carries its own information.

    Columns are scaled to unit norm (so units do not matter) and decomposed by
    SVD; the condition number of the scaled ``A^T A`` belonging to singular
    value ``s_i`` is ``(s_max / s_i)^2``. The right singular vector of a tiny
    ``s_i`` is the near-dependency between columns; parameters with a weight of
    at least 10 % of the largest in it are the ones that cannot be told apart.

    Parameters
    ----------
    A : array_like, shape (N, p)
        Regressor matrix.
    names : sequence of str
        Parameter name per column.
    max_condition : float
        Above this condition number the fit is refused.
    warn_condition : float
        Above this (and up to `max_condition`) a warning is returned.

    Returns
    -------
    list of str
        Warnings for weak but usable excitation (empty when all is well).

    Raises
    ------
    DataError
        A column is all zero, or columns are collinear beyond `max_condition`;
        the message names the parameters.
    """
    A = np.asarray(A, dtype=np.float64)
    names = tuple(names)
    if A.ndim != 2 or A.shape[1] != len(names):
        raise DataError(f"A must have shape (N, {len(names)}) for names {names}, got {A.shape}")
    if not (0.0 < warn_condition <= max_condition):
        raise ConfigError("warn_condition", f"must lie in (0, max_condition={max_condition!r}], got {warn_condition!r}")
    if not np.all(np.isfinite(A)):
        raise DataError("regressor matrix contains NaN or inf")
    if A.shape[0] < A.shape[1]:
        raise DataError(f"{A.shape[0]} rows cannot determine {A.shape[1]} parameters {names}")
    norms, _, s, Vt = _scaled_svd(A)
    return _excitation_report(norms, s, Vt, names, max_condition, warn_condition)


# --- least squares -----------------------------------------------------------


def _column(name: str, values: ArrayLike, n: int | None) -> np.ndarray:
    try:
        x = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"regressor {name!r} is not numeric: {exc}") from None
    if x.ndim != 1:
        raise DataError(f"regressor {name!r} must be 1-D, got shape {x.shape}")
    if n is not None and x.size != n:
        raise DataError(f"regressor {name!r} has {x.size} samples, the target has {n}")
    if not np.all(np.isfinite(x)):
        raise DataError(f"regressor {name!r} contains NaN or inf")
    return x


def fit_linear(
    regressors: Mapping[str, ArrayLike],
    target: ArrayLike,
    names: Sequence[str] | None = None,
    *,
    n_effective: float | None = None,
    max_condition: float = 1e8,
    warn_condition: float = 1e5,
) -> LinearFit:
    """Least squares ``target ~ sum_i theta_i * regressors[name_i]``.

    Solved by SVD of the column-scaled regressor matrix (as ``lstsq``), never
    by inverting ``A^T A``.

    Parameters
    ----------
    regressors : mapping of str to array_like
        One 1-D column per parameter name; constant columns (an offset) are fine.
    target : array_like
        Left-hand side, same length.
    names : sequence of str, optional
        Which regressors to use and in which order (default: all, in mapping order).
    n_effective : float, optional
        Number of independent rows when the rows are correlated (filtered,
        oversampled data); the covariance is scaled by ``N / n_effective``.
        Default ``N``.
    max_condition, warn_condition : float
        Thresholds of :func:`check_excitation`.

    Returns
    -------
    LinearFit

    Raises
    ------
    DataError
        Non-finite or mismatched data, too few rows, or a parameter that the
        data cannot identify (named in the message).
    """
    y = check_signals({"target": target}, min_samples=1)["target"]
    names = _regressor_names(regressors, names)
    N, p = y.size, len(names)
    A = np.column_stack([_column(n, regressors[n], N) for n in names])
    if N <= p:
        raise DataError(f"{N} samples cannot determine {p} parameters {names}; need more than {p}")
    n_eff = _effective_rows(n_effective, N, p)

    warnings = check_excitation(A, names, max_condition, warn_condition)
    norms, U, s, Vt = _scaled_svd(A)
    theta = (Vt.T @ ((U.T @ y) / s)) / norms
    e = y - A @ theta
    sse = float(e @ e)
    s2 = sse / (N - p)
    # (A^T A)^-1 = D^-1 V diag(1/s^2) V^T D^-1 with D = diag(norms)
    W = Vt.T / s
    cov = (W @ W.T) / np.outer(norms, norms) * s2 * (N / n_eff)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))

    fit = fit_percent(y, y - e) if np.ptp(y) > 0 else float("nan")
    params = {n: float(t) for n, t in zip(names, theta, strict=False)}
    stderr = {n: float(v) for n, v in zip(names, se, strict=False)}
    warnings += _insignificant(params, stderr)
    return LinearFit(
        names=names,
        params=params,
        stderr=stderr,
        relative_stderr_percent=_relative_stderr(params, stderr),
        contribution=_contributions(A, theta, y, names),
        covariance=cov,
        residual_rms=float(np.sqrt(sse / N)),
        cost_V=0.5 * sse,
        fit_percent=float(fit),
        condition_number=float((s[0] / s[-1]) ** 2),
        n_samples=int(N),
        n_effective=n_eff,
        warnings=tuple(warnings),
    )


def _regressor_names(regressors: Mapping[str, ArrayLike], names: Sequence[str] | None) -> tuple[str, ...]:
    """The regressors to use, checked: given, unique and present (default: all, in mapping order)."""
    names = tuple(regressors) if names is None else tuple(names)
    if not names:
        raise DataError("no regressors given")
    if len(set(names)) != len(names):
        raise ConfigError("names", f"must be unique, got {names}")
    missing = [n for n in names if n not in regressors]
    if missing:
        raise ConfigError("names", f"{missing} are not among the regressors {list(regressors)}")
    return names


def _effective_rows(n_effective: float | None, N: int, p: int) -> float:
    """Independent rows of the regression (at most `N`, more than the `p` parameters)."""
    if n_effective is None:
        return float(N)
    n_eff = float(n_effective)
    if not np.isfinite(n_eff) or n_eff <= p:
        raise DataError(
            f"n_effective={n_effective!r} must exceed the number of parameters {p}: record longer or raise the cutoff"
        )
    return min(n_eff, float(N))


def _relative_stderr(params: dict[str, float], stderr: dict[str, float]) -> dict[str, float]:
    """Standard error in % of each value (inf for a value of 0)."""
    return {n: (100.0 * stderr[n] / abs(params[n]) if params[n] != 0.0 else float("inf")) for n in params}


def _contributions(A: np.ndarray, theta: np.ndarray, y: np.ndarray, names: tuple[str, ...]) -> dict[str, float]:
    """RMS of each term ``theta_i A[:, i]`` relative to the RMS of the target (0 for a zero target)."""
    y_rms = float(np.sqrt(np.mean(y**2)))
    return {
        n: float(np.sqrt(np.mean((A[:, i] * theta[i]) ** 2)) / y_rms) if y_rms > 0 else 0.0 for i, n in enumerate(names)
    }


def _insignificant(params: dict[str, float], stderr: dict[str, float]) -> list[str]:
    """A warning per parameter smaller than twice its standard error."""
    return [
        f"parameter {n!r} = {params[n]:.4g} is not significant (stderr {stderr[n]:.3g}, |value| < 2 stderr)"
        for n in params
        if abs(params[n]) < 2.0 * stderr[n]
    ]


# --- shared plumbing for the physical models ---------------------------------


def _check_decimate(decimate: int) -> int:
    if int(decimate) != decimate or decimate < 1:
        raise ConfigError("decimate", f"must be an integer >= 1, got {decimate!r}")
    return int(decimate)


def _bandwidth_samples(n_rows: int, decimate: int, cutoff_hz: float, fs: float) -> float:
    """Independent values in `n_rows` rows spaced `decimate` samples, band-limited to cutoff."""
    return n_rows * decimate * 2.0 * cutoff_hz / fs


def _hold_to_sample(u: np.ndarray, input_hold: str) -> np.ndarray:
    if input_hold == "sample":
        return u
    if input_hold == "zoh":
        # a value held over [kT, (k+1)T) acts like a continuous signal delayed by
        # T/2; its value at kT is about the mean of the held values either side
        return np.concatenate([u[:1], 0.5 * (u[1:] + u[:-1])])
    raise ConfigError("input_hold", f"must be 'sample' or 'zoh', got {input_hold!r}")


def _lowpass_like(x: np.ndarray, fs, cutoff_hz, order, kind) -> np.ndarray:
    """Row 0 of the SVF for a regressor that may legitimately be constant."""
    if np.ptp(x) == 0.0:
        return x.copy()
    return state_variable_filter(x, fs, cutoff_hz, 0, order=order, kind=kind)[0]


@dataclass(frozen=True)
class Regression:
    """Regressors and target of a linear-in-parameters model, rows already chosen.

    Attributes
    ----------
    regressors : dict of str to ndarray
        One column per parameter name.
    target : ndarray
        What ``sum(param * regressor)`` should equal.
    n_effective : float or None
        Independent rows (a low-pass makes neighbouring rows alike).
    low_speed_rows : int
        Rows left out because the filtered speed was below ``min_speed``.
    min_speed : float or None
        That threshold (m/s or rad/s); None when no rows are selected by speed.
    """

    regressors: dict
    target: np.ndarray
    n_effective: float | None = None
    low_speed_rows: int = 0
    min_speed: float | None = None


def _second_order_regression(
    u_name: str,
    y_name: str,
    u: ArrayLike,
    y: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float | None,
    method: str,
    order: int,
    kind: str,
    decimate: int,
    input_hold: str,
    names: tuple[str, str, str],
) -> Regression:
    sig = check_signals({u_name: u, y_name: y})
    u, y = _hold_to_sample(sig[u_name], input_hold), sig[y_name]
    fs = float(sample_rate_hz)
    decimate = _check_decimate(decimate)
    if method == "svf":
        if cutoff_hz is None:
            raise ConfigError("cutoff_hz", "is required for method='svf'")
        Y = state_variable_filter(y, fs, cutoff_hz, 2, order=order, kind=kind)
        Uf = state_variable_filter(u, fs, cutoff_hz, 0, order=order, kind=kind)[0]
        edge = settling_samples(fs, cutoff_hz, order, kind=kind)
    elif method == "difference":
        Y = finite_difference_derivatives(y, fs, 2)
        Uf = u
        edge = 2
    else:
        raise ConfigError("method", f"must be 'svf' or 'difference', got {method!r}")
    rows = np.arange(edge, y.size - edge, decimate)
    if rows.size <= 3:
        raise DataError(
            f"{y.size} samples leave {max(rows.size, 0)} after dropping {edge} filter-settling "
            "samples at each end; record longer or raise cutoff_hz"
        )
    n_eff = (
        _bandwidth_samples(rows.size, decimate, cutoff_hz, fs) if method == "svf" and cutoff_hz is not None else None
    )
    reg = {names[0]: Y[2, rows], names[1]: Y[1, rows], names[2]: Y[0, rows]}
    return Regression(reg, Uf[rows], n_eff)


def fit_regression(regression: Regression) -> LinearFit:
    """:func:`fit_linear` on a prepared :class:`Regression` (every column a parameter)."""
    return fit_linear(
        regression.regressors, regression.target, tuple(regression.regressors), n_effective=regression.n_effective
    )


def _second_order_fit(*args) -> LinearFit:
    return fit_regression(_second_order_regression(*args))


def mass_spring_damper_regression(
    force: ArrayLike,
    position: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float | None = None,
    method: str = "svf",
    order: int = 3,
    kind: str = "butterworth",
    decimate: int = 1,
    input_hold: str = "sample",
) -> Regression:
    """The regressors :func:`fit_mass_spring_damper` fits, e.g. to validate a fit on another record."""
    return _second_order_regression(
        "force",
        "position",
        force,
        position,
        sample_rate_hz,
        cutoff_hz,
        method,
        order,
        kind,
        decimate,
        input_hold,
        ("m", "b", "k"),
    )


def validate_fit(fit: LinearFit, regression: Regression, max_lag: int = 25) -> dict:
    """Fit % and residual tests of ``fit`` on another record's regression.

    Returns
    -------
    dict
        ``fit_percent`` (NRMSE, as MATLAB ``compare``), ``relative_error``
        (``||e|| / ||y||``, the figure identification benchmarks publish; unlike
        fit % it does not remove the mean of the target), ``residual_rms``,
        ``residuals_white`` and ``ljung_box_p`` (autocorrelation of the
        residuals within the 99 % band), ``independent_of_input`` (their
        cross-correlation with the first regressor within the band), ``samples``.
    """
    from hilident.ident.validation import fit_percent, residual_analysis

    predicted = fit.predict(regression.regressors)
    target = np.asarray(regression.target, dtype=float)
    residuals = target - predicted
    norm = float(np.linalg.norm(target))
    out: dict[str, Any] = {
        "fit_percent": float(fit_percent(target, predicted)),
        "relative_error": float(np.linalg.norm(residuals) / norm) if norm > 0 else float("inf"),
        "residual_rms": float(np.sqrt(np.mean(residuals**2))),
        "samples": int(target.size),
        "low_speed_rows_excluded": int(regression.low_speed_rows),
    }
    if regression.min_speed is not None:
        out["min_speed"] = regression.min_speed
    lag = int(min(max_lag, max(1, target.size // 4 - 1)))
    try:
        ra = residual_analysis(residuals, regression.regressors[fit.names[0]], max_lag=lag)
        out.update(residuals_white=ra.white, ljung_box_p=ra.ljung_box_p, independent_of_input=ra.independent)
    except (DataError, ConfigError):
        out.update(residuals_white=None, ljung_box_p=None, independent_of_input=None)
    return out


# --- physical models ---------------------------------------------------------


def fit_mass_spring_damper(
    force: ArrayLike,
    position: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float | None = None,
    method: str = "svf",
    order: int = 3,
    kind: str = "butterworth",
    decimate: int = 1,
    input_hold: str = "sample",
) -> LinearFit:
    """Grey-box fit of ``m y'' + b y' + k y = F`` (lecture, "Grey Box").

    Parameters
    ----------
    force : array_like
        Applied force F, N.
    position : array_like
        Displacement y, m.
    sample_rate_hz : float
        Sample rate, Hz.
    cutoff_hz : float
        SVF corner, Hz (required for ``method="svf"``): above the resonance
        and the excited band, as low as that allows (noise on ``y''`` grows
        like ``cutoff^5``).
    method : {"svf", "difference"}
        ``"svf"``: state-variable filter on force and position (recommended).
        ``"difference"``: central differences of the raw position, force
        unfiltered -- the naive way, which noise ruins.
    order, kind
        SVF order (>= 3) and kind, see :func:`state_variable_filter`.
    decimate : int
        Use every `decimate`-th sample in the regression (after filtering).
    input_hold : {"sample", "zoh"}
        ``"sample"``: `force` holds samples of a continuous force. ``"zoh"``:
        each value was held constant until the next sample (a commanded
        force); it is moved by half a sample (mean of neighbouring values)
        so that damping is not biased by about ``(T/2)(k - m w^2)``.

    Returns
    -------
    LinearFit
        Parameters ``m`` (kg), ``b`` (N·s/m), ``k`` (N/m); target is the
        (filtered) force.
    """
    return fit_regression(
        mass_spring_damper_regression(
            force,
            position,
            sample_rate_hz,
            cutoff_hz,
            method,
            order,
            kind,
            decimate,
            input_hold,
        )
    )


def fit_dc_motor_speed(
    voltage: ArrayLike,
    speed: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float | None = None,
    method: str = "svf",
    order: int = 3,
    kind: str = "butterworth",
    decimate: int = 1,
    input_hold: str = "sample",
) -> LinearFit:
    """Combined DC-motor parameters from voltage and speed (lecture, "Example: DC Motor Speed").

    Fits ``JL/kt w'' + (JR+bL)/kt w' + (bR+kt ke)/kt w = V``; the individual
    J, L, R, b, kt, ke cannot be separated from these data. Arguments as
    :func:`fit_mass_spring_damper` with voltage (V) for force and angular
    speed (rad/s) for position.

    Returns
    -------
    LinearFit
        Parameters named ``"JL/kt"`` (V·s^3/rad), ``"(JR+bL)/kt"`` (V·s^2/rad)
        and ``"(bR+kt*ke)/kt"`` (V·s/rad), as in :data:`DC_MOTOR_NAMES`.
    """
    return _second_order_fit(
        "voltage",
        "speed",
        voltage,
        speed,
        sample_rate_hz,
        cutoff_hz,
        method,
        order,
        kind,
        decimate,
        input_hold,
        DC_MOTOR_NAMES,
    )


def fit_rigid_axis(
    position: ArrayLike,
    force: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float,
    asymmetric: bool = False,
    decimate: int = 1,
    min_speed: float | None = None,
    order: int = 3,
    kind: str = "butterworth",
    input_hold: str = "sample",
) -> LinearFit:
    """Inverse dynamics of a rigid axis with Coulomb and viscous friction.

    Model (symmetric)::

        M q'' + Fv q' + Fc sign(q') + offset = force

    and with ``asymmetric=True``::

        M q'' + Fv+ max(q', 0) + Fv- min(q', 0) + Fc+ [q' > 0] - Fc- [q' < 0] = force

    so ``Fc+`` and ``Fc-`` are both positive magnitudes for the usual friction.
    It has no ``offset``: every row used moves, so ``[q' > 0] + [q' < 0] = 1``
    and a constant load would be the same column; it shows as half the
    difference of ``Fc+`` and ``Fc-``.
    ``offset`` takes up a constant load (gravity on an inclined axis, a
    torque-sensor bias).

    ``q'`` and ``q''`` come from the state-variable filter of `position`, the
    force is filtered by the same low-pass. Friction is a nonlinear function of
    the velocity, so its regressors are built from the filtered velocity and
    then passed through the same low-pass as everything else (filtering after
    the nonlinearity, as the plant does). Rows with ``|q'| < min_speed`` are
    left out: there the sign of the velocity is uncertain (noise, zero
    crossings smeared by the filter) and a stuck axis has any friction between
    ``-Fs`` and ``Fs``, which the model cannot express.

    Parameters
    ----------
    position : array_like
        Axis position q, m (or rad).
    force : array_like
        Motor force, N (or torque, N·m).
    sample_rate_hz : float
        Sample rate, Hz.
    cutoff_hz : float
        SVF corner, Hz: above the excited band, far below Nyquist.
    asymmetric : bool
        Separate friction per direction.
    decimate : int
        Use every `decimate`-th filtered sample in the regression.
    min_speed : float, optional
        Rows with a slower filtered speed are dropped, m/s. Default: 2 % of
        the RMS filtered speed.
    order, kind, input_hold
        See :func:`fit_mass_spring_damper`.

    Returns
    -------
    LinearFit
        ``M``, ``Fv``, ``Fc``, ``offset`` (or ``M``, ``Fv+``, ``Fv-``, ``Fc+``,
        ``Fc-``).

    Raises
    ------
    DataError
        A parameter is not identifiable, e.g. ``Fc`` and ``offset`` when the
        axis only moved one way, or ``Fc-`` when it never moved backwards.
    """
    return fit_regression(
        rigid_axis_regression(
            position, force, sample_rate_hz, cutoff_hz, asymmetric, decimate, min_speed, order, kind, input_hold
        )
    )


def rigid_axis_regression(
    position: ArrayLike,
    force: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float,
    asymmetric: bool = False,
    decimate: int = 1,
    min_speed: float | None = None,
    order: int = 3,
    kind: str = "butterworth",
    input_hold: str = "sample",
) -> Regression:
    """The regressors and target :func:`fit_rigid_axis` fits (same parameters), e.g. to validate on another record."""
    sig = check_signals({"position": position, "force": force})
    q, f = sig["position"], _hold_to_sample(sig["force"], input_hold)
    fs = float(sample_rate_hz)
    decimate = _check_decimate(decimate)
    Q = state_variable_filter(q, fs, cutoff_hz, 2, order=order, kind=kind)
    F = state_variable_filter(f, fs, cutoff_hz, 0, order=order, kind=kind)[0]
    v = Q[1]
    edge = settling_samples(fs, cutoff_hz, order, kind=kind)
    if min_speed is None:
        min_speed = 0.02 * float(np.sqrt(np.mean(v[edge:-edge] ** 2))) if edge < v.size // 2 else 0.0
    elif not (np.isfinite(min_speed) and min_speed >= 0.0):
        raise ConfigError("min_speed", f"must be >= 0, got {min_speed!r}")

    def lp(x):
        return _lowpass_like(x, fs, cutoff_hz, order, kind)

    if asymmetric:
        reg = {
            "M": Q[2],
            "Fv+": lp(np.maximum(v, 0.0)),
            "Fv-": lp(np.minimum(v, 0.0)),
            "Fc+": lp((v > 0).astype(float)),
            "Fc-": lp(-(v < 0).astype(float)),
        }
    else:
        reg = {"M": Q[2], "Fv": v, "Fc": lp(np.sign(v)), "offset": np.ones_like(v)}
    rows = np.arange(edge, v.size - edge, decimate)
    candidates = rows.size
    rows = rows[np.abs(v[rows]) >= min_speed]
    if rows.size <= len(reg):
        raise DataError(
            f"only {rows.size} usable samples after dropping filter settling and speeds below "
            f"min_speed={min_speed:g}; record longer or move faster"
        )
    n_eff = _bandwidth_samples(rows.size, decimate, cutoff_hz, fs)
    return Regression(
        {k: c[rows] for k, c in reg.items()}, F[rows], n_eff, int(candidates - rows.size), float(min_speed)
    )


def fit_torque_constant(
    torque: ArrayLike,
    friction_torque: ArrayLike,
    mass: float,
    acceleration: ArrayLike,
    n_effective: float | None = None,
) -> LinearFit:
    """Torque-to-force conversion ``c`` from ``M p'' = c (tau - tau_fr)`` (thesis eqs. 3.3-3.4).

    With ``Phi = tau - tau_fr`` and ``y = M p''``, ``c = (Phi^T Phi)^-1 Phi^T y``
    (solved as least squares, with its standard error).

    Parameters
    ----------
    torque : array_like
        Motor torque tau_m, N·m.
    friction_torque : array_like
        Friction torque tau_fr at the same samples, N·m (e.g. from
        :func:`hilident.ident.friction.stribeck`).
    mass : float
        Moved mass M, kg.
    acceleration : array_like
        Acceleration p'', m/s^2. Filter torque, friction torque and position
        alike (e.g. :func:`state_variable_filter`) before calling.
    n_effective : float, optional
        See :func:`fit_linear`.

    Returns
    -------
    LinearFit
        One parameter ``c`` in N per N·m (1/m).
    """
    M = float(mass)
    if not np.isfinite(M) or M <= 0.0:
        raise ConfigError("mass", f"must be a positive number of kg, got {mass!r}")
    sig = check_signals({"torque": torque, "acceleration": acceleration}, min_samples=2)
    tau_fr = _column("friction_torque", friction_torque, sig["torque"].size)
    phi = sig["torque"] - tau_fr
    return fit_linear({"c": phi}, M * sig["acceleration"], ("c",), n_effective=n_effective)
