"""ARX models: least-squares fit, prediction, simulation and order search.

Sign convention (the lecture's): the output is a weighted sum of past outputs
and of delayed inputs, all with a plus sign::

    y(k) = a_1 y(k-1) + ... + a_na y(k-na)
         + b_0 u(k-nk) + b_1 u(k-nk-1) + ... + b_(nb-1) u(k-nk-nb+1) + e(k)

so the lecture's mass-spring-damper model ``y(k) = a1 y(k-1) + a2 y(k-2) +
b0 u(k)`` is ``na=2, nb=1, nk=0`` with ``a = (a1, a2)``, ``b = (b0,)``. The
model is linear in its parameters, so they follow from one least-squares solve
(thesis eqs. 2.39-2.44). In scipy's convention (``lfilter(b, a, u)``, powers of
``z^-1``) the same model is ``b = (0,)*nk + (b_0, ..., b_(nb-1))`` and
``a = (1, -a_1, ..., -a_na)``; see :func:`arx_to_ba`. Note the opposite sign
of the ``a`` coefficients.

Example
-------
>>> import numpy as np
>>> from scipy import signal
>>> from hilident.ident.arx import fit_arx, simulate
>>> rng = np.random.default_rng(0)
>>> u = rng.standard_normal(2000)
>>> y = signal.lfilter([0.0, 0.5], [1.0, -1.5, 0.7], u)  # a = (1.5, -0.7), b = (0.5,), nk = 1
>>> model = fit_arx(u, y, na=2, nb=1, nk=1)
>>> np.round(model.a, 6), np.round(model.b, 6)
(array([ 1.5, -0.7]), array([0.5]))
>>> y_free = simulate(model, u)
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from itertools import product

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg, signal

from hilident.errors import ConfigError, DataError
from hilident.ident.preprocess import check_signals
from hilident.ident.validation import fit_percent

__all__ = [
    "ArxModel",
    "OrderCandidate",
    "OrderSearch",
    "fit_arx",
    "predict",
    "simulate",
    "arx_to_ba",
    "arx_order_search",
]

# Residual sums of squares below this fraction of the output energy are
# rounding noise; flooring them keeps AIC/BIC finite on noise-free data and
# makes all exact models tie (the tie goes to the fewest parameters).
_RSS_FLOOR = 1e-24


@dataclass(frozen=True, eq=False)
class ArxModel:
    """An ARX model fitted by least squares (lecture sign convention).

    Attributes
    ----------
    na, nb, nk : int
        Number of past outputs, number of inputs, input delay in samples.
    params : ndarray, shape (na + nb,)
        ``(a_1, ..., a_na, b_0, ..., b_(nb-1))``.
    stderr : ndarray, shape (na + nb,)
        Standard errors of `params` from ``noise_variance * (Phi^T Phi)^-1``
        (exact for white equation noise; too small when the noise is coloured).
    covariance : ndarray, shape (na + nb, na + nb)
        Parameter covariance matrix.
    V : float
        Loss ``0.5 * sum(e^2)`` over the regression rows (thesis eq. 2.39).
    noise_variance : float
        ``sum(e^2) / (n_equations - n_params)``, unbiased estimate of var(e).
    fit_percent : float
        One-step-ahead NRMSE fit on the estimation data, % (100 = perfect).
    n_equations : int
        Number of regression rows used.
    """

    na: int
    nb: int
    nk: int
    params: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    V: float
    noise_variance: float
    fit_percent: float
    n_equations: int

    @property
    def a(self) -> np.ndarray:
        """Output coefficients ``(a_1, ..., a_na)``, lecture sign."""
        return self.params[: self.na]

    @property
    def b(self) -> np.ndarray:
        """Input coefficients; ``b[j]`` multiplies ``u(k - nk - j)``."""
        return self.params[self.na :]

    @property
    def n_params(self) -> int:
        return self.na + self.nb

    @property
    def max_lag(self) -> int:
        """Longest lag in the regressor: samples of history one prediction needs."""
        return max(self.na, self.nk + self.nb - 1, 0)

    @property
    def poles(self) -> np.ndarray:
        """Roots of ``z^na - a_1 z^(na-1) - ... - a_na`` (discrete-time poles)."""
        return np.roots(np.r_[1.0, -self.a]) if self.na else np.empty(0, complex)


@dataclass(frozen=True)
class OrderCandidate:
    """One row of an order search.

    ``aic = N ln(RSS/N) + 2 p`` and ``bic = N ln(RSS/N) + p ln N`` with ``N``
    the common number of regression rows and ``p = na + nb``.
    ``fit_validation_percent`` is the free-run simulation fit on the validation
    data (NaN when none was given).
    """

    na: int
    nb: int
    nk: int
    n_params: int
    V: float
    aic: float
    bic: float
    fit_percent: float
    fit_validation_percent: float


@dataclass(frozen=True, eq=False)
class OrderSearch:
    """Result of :func:`arx_order_search`: every candidate and the chosen model."""

    candidates: tuple[OrderCandidate, ...]
    model: ArxModel
    criterion: str


def _check_orders(na: int, nb: int, nk: int) -> tuple[int, int, int]:
    for key, value, low in (("na", na, 0), ("nb", nb, 0), ("nk", nk, 0)):
        if isinstance(value, bool) or int(value) != value or value < low:
            raise ConfigError(key, f"must be an integer >= {low}, got {value!r}")
    na, nb, nk = int(na), int(nb), int(nk)
    if na + nb == 0:
        raise ConfigError("na", "na + nb must be at least 1, got na=0, nb=0")
    return na, nb, nk


def _signals(u: ArrayLike, y: ArrayLike, tag: str = "") -> tuple[np.ndarray, np.ndarray]:
    sig = check_signals({f"u{tag}": u, f"y{tag}": y}, min_samples=4)
    return sig[f"u{tag}"], sig[f"y{tag}"]


def _finite(x: ArrayLike, name: str) -> np.ndarray:
    """1-D finite float64 array; unlike fitting, constant signals are fine here."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise DataError(f"signal {name!r} must be a finite 1-D array, got shape {x.shape}")
    return x


def _regressors(u, y, y_lags, u_lags, n0):
    """Rows k = n0..N-1 of [y(k-i) for i in y_lags, u(k-j) for j in u_lags, y(k)].

    Column slices of the signals, no loop over samples; Fortran order so each
    column copy is contiguous and LAPACK gets the layout it wants.
    """
    n = y.size
    z = np.empty((n - n0, len(y_lags) + len(u_lags) + 1), order="F")
    for col, i in enumerate(y_lags):
        z[:, col] = y[n0 - i : n - i]
    for col, j in enumerate(u_lags, start=len(y_lags)):
        z[:, col] = u[n0 - j : n - j]
    z[:, -1] = y[n0:]
    return z


def _solve(z: np.ndarray, na: int, nb: int, nk: int) -> ArxModel:
    """Least squares on the augmented regressor ``z = [Phi, y]``.

    One Householder QR of the column-scaled ``[Phi, y]`` gives ``R = [[R11, r],
    [0, rho]]``: ``theta = R11^-1 r`` and ``(Phi^T Phi)^-1 = R11^-1 R11^-T``,
    without forming the badly conditioned normal equations (the lecture's
    ``a1 = 1.9998`` case has nearly collinear output columns).
    """
    m, p = z.shape[0], z.shape[1] - 1
    if m <= p:
        raise DataError(
            f"ARX(na={na}, nb={nb}, nk={nk}) needs more than {p} regression rows, got {m}"
        )
    scale = np.sqrt(np.einsum("ij,ij->j", z, z))
    if np.any(scale[:p] == 0.0):
        raise DataError(f"a regressor column of ARX(na={na}, nb={nb}, nk={nk}) is all zero")
    # mode "r" returns R alone; numpy's stubs type every mode as the (Q, R) pair
    r = typing.cast(np.ndarray, np.linalg.qr(z / scale, mode="r"))
    r11 = r[:p, :p]
    sv = linalg.svdvals(r11)
    if sv[-1] <= sv[0] * max(m, p) * np.finfo(float).eps:
        raise DataError(
            f"regressors of ARX(na={na}, nb={nb}, nk={nk}) are linearly dependent: the input "
            f"is not exciting enough for nb={nb} or the orders are too high for the data"
        )
    theta = linalg.solve_triangular(r11, r[:p, p] * scale[p]) / scale[:p]
    resid = z[:, p] - z[:, :p] @ theta
    rss = float(resid @ resid)
    y_rows = z[:, p]
    sigma2 = rss / (m - p)
    r_inv = linalg.solve_triangular(r11, np.eye(p))
    cov = sigma2 * (r_inv @ r_inv.T) / np.outer(scale[:p], scale[:p])
    return ArxModel(
        na=na,
        nb=nb,
        nk=nk,
        params=theta,
        stderr=np.sqrt(np.diag(cov)),
        covariance=cov,
        V=0.5 * rss,
        noise_variance=sigma2,
        fit_percent=float(fit_percent(y_rows, y_rows - resid)),
        n_equations=m,
    )


def fit_arx(u: ArrayLike, y: ArrayLike, na: int, nb: int, nk: int = 0) -> ArxModel:
    """Fit ``y(k) = sum a_i y(k-i) + sum_{j=nk}^{nk+nb-1} b u(k-j)`` by least squares.

    Parameters
    ----------
    u, y : array_like
        Input and output records of equal length (any consistent units).
    na : int
        Number of past outputs (model order of the denominator), >= 0.
    nb : int
        Number of input coefficients, >= 0.
    nk : int
        Input delay, samples; ``nk=0`` lets ``u(k)`` act on ``y(k)`` as in the
        lecture's Euler model, a zero-order-hold sampled plant has ``nk >= 1``.

    Returns
    -------
    ArxModel
        Parameters, their standard errors, loss and one-step fit. Rows start at
        ``k = max(na, nk + nb - 1)`` so every regressor is inside the record.

    Raises
    ------
    DataError
        Signals invalid (see :func:`~hilident.ident.preprocess.check_signals`),
        too short, or regressors linearly dependent.
    ConfigError
        Orders negative or not integers.
    """
    na, nb, nk = _check_orders(na, nb, nk)
    u, y = _signals(u, y)
    u_lags = list(range(nk, nk + nb))
    n0 = max(na, nk + nb - 1, 0)
    return _solve(_regressors(u, y, range(1, na + 1), u_lags, n0), na, nb, nk)


def arx_to_ba(model: ArxModel) -> tuple[np.ndarray, np.ndarray]:
    """The model as scipy ``(b, a)`` in powers of ``z^-1`` for ``lfilter``.

    ``b = (0,)*nk + (b_0, ..., b_(nb-1))``, ``a = (1, -a_1, ..., -a_na)``.
    """
    b = np.r_[np.zeros(model.nk), model.b] if model.nb else np.zeros(1)
    return b, np.r_[1.0, -model.a]


def predict(model: ArxModel, u: ArrayLike, y: ArrayLike) -> np.ndarray:
    """One-step-ahead prediction from measured past outputs and inputs.

    ``yhat(k) = sum a_i y(k-i) + sum b_j u(k-nk-j)``. The first
    ``model.max_lag`` samples have no full history and are returned as
    measured (zero residual); skip them when scoring.
    """
    u, y = _finite(u, "u"), _finite(y, "y")
    if u.size != y.size:
        raise DataError(f"u has {u.size} samples but y has {y.size}")
    b, a = arx_to_ba(model)
    yhat = signal.lfilter(b, [1.0], u) + signal.lfilter(np.r_[0.0, model.a], [1.0], y)
    n0 = min(model.max_lag, y.size)
    yhat[:n0] = y[:n0]
    return yhat


def simulate(model: ArxModel, u: ArrayLike, y0: ArrayLike | None = None) -> np.ndarray:
    """Free-run simulation: the model's own past outputs replace measurements.

    Parameters
    ----------
    model : ArxModel
    u : array_like
        Input record.
    y0 : array_like, optional
        The first ``len(y0)`` outputs, taken as known (e.g. ``y_meas[:model.na]``);
        the simulation continues from them with ``u[:len(y0)]`` as past inputs.
        Values before the record are zero. Default: zero initial state.

    Returns
    -------
    ndarray
        Simulated output, same length as `u` (starts with `y0`).
    """
    u = _finite(u, "u")
    b, a = arx_to_ba(model)
    if y0 is None:
        return signal.lfilter(b, a, u)
    y0 = np.asarray(y0, dtype=np.float64).ravel()
    m = y0.size
    if m > u.size or not np.all(np.isfinite(y0)):
        raise DataError(f"y0 must be finite and not longer than u ({u.size}), got {m} samples")
    zi = signal.lfiltic(b, a, y0[::-1], u[:m][::-1])
    out = np.empty_like(u)
    out[:m] = y0
    out[m:] = signal.lfilter(b, a, u[m:], zi=zi)[0]
    return out


def _as_range(key: str, values) -> list[int]:
    vals: list[typing.Any] = [values] if np.isscalar(values) else list(values)
    if not vals:
        raise ConfigError(key, "must contain at least one order")
    for v in vals:
        if isinstance(v, bool) or int(v) != v or v < 0:
            raise ConfigError(key, f"orders must be integers >= 0, got {v!r}")
    return sorted({int(v) for v in vals})


def arx_order_search(
    u: ArrayLike,
    y: ArrayLike,
    na_range,
    nb_range,
    nk_range=(0,),
    criterion: str = "aic",
    u_val: ArrayLike | None = None,
    y_val: ArrayLike | None = None,
    tolerance: float | None = None,
) -> OrderSearch:
    """Fit every ``(na, nb, nk)`` of a grid and choose the smallest adequate model.

    All candidates use the same regression rows (the longest lag of the grid
    decides where they start) so their losses are comparable.

    Parameters
    ----------
    u, y : array_like
        Estimation data.
    na_range, nb_range, nk_range : iterable of int or int
        Orders to try.
    criterion : {"aic", "bic", "validation"}
        ``"aic"``/``"bic"``: information criterion on the estimation data.
        ``"validation"``: free-run simulation fit on (`u_val`, `y_val`).
    u_val, y_val : array_like, optional
        Validation data (required for ``"validation"``; otherwise, when given,
        only filled into the table).
    tolerance : float, optional
        "Adequate" means within `tolerance` of the best value: criterion units
        for AIC/BIC (default 2, the usual "no real difference" margin of an
        information criterion), percentage points of fit for validation
        (default 0.5). Among the adequate models the one with the fewest
        parameters wins; ties go to the better criterion.

    Candidates whose regressors are linearly dependent (more parameters than
    the data determine, e.g. over-parametrised models on noise-free data) get
    infinite AIC/BIC, NaN loss and are never chosen.

    ARX assumes the noise enters as white equation error. Under white
    measurement noise on `y` the estimates are biased and higher orders
    compensate, so AIC/BIC then tend to pick orders above the plant's;
    validation on fresh data with a tolerance is the more robust choice.

    Returns
    -------
    OrderSearch
        ``candidates`` (one row per grid point, in grid order), the chosen
        ``model`` (refitted on its own full record) and the ``criterion``.
    """
    if criterion not in ("aic", "bic", "validation"):
        raise ConfigError(
            "criterion", f"must be 'aic', 'bic' or 'validation', got {criterion!r}"
        )
    nas = _as_range("na_range", na_range)
    nbs = _as_range("nb_range", nb_range)
    nks = _as_range("nk_range", nk_range)
    tolerance = _checked_tolerance(tolerance, criterion)
    u, y = _signals(u, y)
    validation = _validation_data(u_val, y_val, criterion)

    max_na, max_u_lag = max(nas), max(nk + nb - 1 for nk in nks for nb in nbs)
    n0 = max(max_na, max_u_lag, 0)
    u_lag_all = list(range(0, max(max_u_lag, -1) + 1))
    full = _regressors(u, y, range(1, max_na + 1), u_lag_all, n0)
    rows = [
        _order_candidate(full, max_na, na, nb, nk, n0, validation)
        for na, nb, nk in product(nas, nbs, nks)
        if na + nb != 0
    ]
    if not rows:
        raise ConfigError("na_range", "the grid holds only na=0, nb=0")
    if all(np.isinf(r.aic) for r in rows):
        raise DataError("no candidate of the order grid can be determined from the data")

    c = rows[_smallest_adequate(rows, criterion, tolerance)]
    return OrderSearch(
        candidates=tuple(rows),
        model=fit_arx(u, y, c.na, c.nb, c.nk),
        criterion=criterion,
    )


def _checked_tolerance(tolerance: float | None, criterion: str) -> float:
    """`tolerance`, or its default for `criterion` (0.5 % fit for validation, 2 for AIC/BIC)."""
    if tolerance is None:
        tolerance = 0.5 if criterion == "validation" else 2.0
    if not np.isfinite(tolerance) or tolerance < 0:
        raise ConfigError("tolerance", f"must be a number >= 0, got {tolerance!r}")
    return tolerance


def _validation_data(u_val, y_val, criterion: str) -> tuple[np.ndarray, np.ndarray] | None:
    """Checked ``(u_val, y_val)``, or None when neither is given."""
    if criterion == "validation" and not (u_val is not None and y_val is not None):
        raise ConfigError("u_val", "criterion 'validation' needs both u_val and y_val")
    if u_val is None and y_val is None:
        return None
    if u_val is None or y_val is None:
        raise ConfigError("u_val" if u_val is None else "y_val", "give both u_val and y_val")
    return _signals(u_val, y_val, tag="_val")


def _order_candidate(full: np.ndarray, max_na: int, na: int, nb: int, nk: int, n0: int,
                     validation: tuple[np.ndarray, np.ndarray] | None) -> OrderCandidate:
    """One row of :func:`arx_order_search`, fitted on the columns of the shared regressor matrix `full`."""
    n_rows = full.shape[0]
    energy = float(full[:, -1] @ full[:, -1])
    cols = list(range(na)) + [max_na + j for j in range(nk, nk + nb)] + [full.shape[1] - 1]
    p = na + nb
    try:
        model = _solve(full[:, cols], na, nb, nk)
    except DataError:  # rank deficient: the data cannot determine p parameters
        nan = float("nan")
        return OrderCandidate(na, nb, nk, p, nan, np.inf, np.inf, nan, -np.inf)
    rss = max(2.0 * model.V, _RSS_FLOOR * energy, np.finfo(float).tiny)
    base = n_rows * np.log(rss / n_rows)
    return OrderCandidate(
        na=na,
        nb=nb,
        nk=nk,
        n_params=p,
        V=model.V,
        aic=float(base + 2 * p),
        bic=float(base + p * np.log(n_rows)),
        fit_percent=model.fit_percent,
        fit_validation_percent=_validation_fit(model, validation, n0),
    )


def _validation_fit(model: ArxModel, validation: tuple[np.ndarray, np.ndarray] | None, n0: int) -> float:
    """Free-run simulation fit (%) on the validation data; NaN without them, -inf when it diverges."""
    if validation is None:
        return np.nan
    u_val, y_val = validation
    y_sim = simulate(model, u_val, y0=y_val[:n0])
    with np.errstate(all="ignore"):
        fit_val = float(fit_percent(y_val[n0:], y_sim[n0:]))
    return fit_val if np.isfinite(fit_val) else -np.inf


def _smallest_adequate(rows: list[OrderCandidate], criterion: str, tolerance: float) -> int:
    """Index of the candidate with the fewest parameters within `tolerance` of the best score."""
    if criterion == "validation":
        score = np.array([-r.fit_validation_percent for r in rows])
    else:
        score = np.array([getattr(r, criterion) for r in rows])
    best = np.min(score)
    adequate = [i for i, s in enumerate(score) if s <= best + tolerance]
    return min(adequate, key=lambda i: (rows[i].n_params, score[i]))
