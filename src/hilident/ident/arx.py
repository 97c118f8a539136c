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

Examples
--------
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
    scale = np.sqrt(np.einsum("ij,ij->j", z, z))
    _check_determined(m, scale, na, nb, nk)
    # mode "r" returns R alone; numpy's stubs type every mode as the (Q, R) pair
    r = typing.cast(np.ndarray, np.linalg.qr(z / scale, mode="r"))
    theta, r_inv = _triangular_solution(r, scale, m, na, nb, nk)
    resid = z[:, p] - z[:, :p] @ theta
    rss = float(resid @ resid)
    y_rows = z[:, p]
    return _model(na, nb, nk, theta, r_inv, scale, rss, m, float(fit_percent(y_rows, y_rows - resid)))


def _check_determined(m: int, scale: np.ndarray, na: int, nb: int, nk: int) -> None:
    """Raise DataError when `m` rows cannot determine the parameters or a column is all zero.

    Parameters
    ----------
    m : int
        Number of regression rows.
    scale : ndarray, shape (na + nb + 1,)
        Euclidean norms of the columns of ``[Phi, y]``.
    """
    p = na + nb
    if m <= p:
        raise DataError(f"ARX(na={na}, nb={nb}, nk={nk}) needs more than {p} regression rows, got {m}")
    if np.any(scale[:p] == 0.0):
        raise DataError(f"a regressor column of ARX(na={na}, nb={nb}, nk={nk}) is all zero")


def _triangular_solution(
    r: np.ndarray, scale: np.ndarray, m: int, na: int, nb: int, nk: int
) -> tuple[np.ndarray, np.ndarray]:
    """Parameters and ``R11^-1`` from the R factor of the column-scaled ``[Phi, y]``.

    The regressors count as linearly dependent when the smallest singular value
    of ``R11`` is at most ``max(m, p) * eps`` times the largest (the scaled
    columns have unit norm, so this is a relative rank tolerance).

    Parameters
    ----------
    r : ndarray, shape (p + 1, p + 1)
        Upper-triangular factor of ``[Phi, y] / scale``.
    scale : ndarray, shape (p + 1,)
        Column norms that were divided out.
    m : int
        Number of regression rows (enters the rank tolerance).

    Returns
    -------
    theta : ndarray, shape (p,)
        Least-squares parameters in the units of the unscaled data.
    r_inv : ndarray, shape (p, p)
        Inverse of ``R11`` (scaled units), for the covariance.
    """
    p = na + nb
    r11 = r[:p, :p]
    sv = linalg.svdvals(r11)
    if sv[-1] <= sv[0] * max(m, p) * np.finfo(float).eps:
        raise DataError(
            f"regressors of ARX(na={na}, nb={nb}, nk={nk}) are linearly dependent: the input "
            f"is not exciting enough for nb={nb} or the orders are too high for the data"
        )
    theta = linalg.solve_triangular(r11, r[:p, p] * scale[p]) / scale[:p]
    # LAPACK trtri rather than a solve against the identity: the latter is a
    # level-3 call that OpenBLAS may hand to its worker threads (see _BLOCK_ELEMENTS)
    (trtri,) = linalg.get_lapack_funcs(("trtri",), (r11,))
    r_inv, info = trtri(r11)
    if info != 0:  # an exactly zero diagonal, which the rank test already excludes
        raise DataError(f"R factor of ARX(na={na}, nb={nb}, nk={nk}) is singular (LAPACK trtri info={info})")
    return theta, np.triu(r_inv)


def _model(
    na: int, nb: int, nk: int, theta: np.ndarray, r_inv: np.ndarray, scale: np.ndarray, rss: float, m: int, fit: float
) -> ArxModel:
    """The :class:`ArxModel` of a solved least-squares problem (`rss` is the residual sum of squares)."""
    p = na + nb
    sigma2 = rss / (m - p)
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
        fit_percent=fit,
        n_equations=m,
    )


def _model_from_factor(r: np.ndarray, m: int, spread: float, na: int, nb: int, nk: int) -> ArxModel:
    """Least squares from the R factor of the unscaled ``[Phi, y]`` alone, never the data.

    ``R^T R = [Phi, y]^T [Phi, y]``, so the column norms of `r` are those of the
    data, ``r / norms`` is the factor of the column-scaled data (the same rank
    test as :func:`_solve`) and ``r[p, p]^2`` is the residual sum of squares.

    Parameters
    ----------
    r : ndarray, shape (p + 1, p + 1)
        Upper-triangular factor of ``[Phi, y]`` over `m` rows.
    m : int
        Number of regression rows.
    spread : float
        ``||y - mean(y)||`` over those rows, for the one-step fit percentage.

    Raises
    ------
    DataError
        As :func:`_solve`: too few rows, an all-zero column, dependent
        regressors, or a constant output.
    """
    scale = np.sqrt(np.einsum("ij,ij->j", r, r))
    _check_determined(m, scale, na, nb, nk)
    if spread == 0.0:
        raise DataError("y is constant; a fit percentage is undefined")
    theta, r_inv = _triangular_solution(r / scale, scale, m, na, nb, nk)
    rss = float(r[-1, -1] ** 2)
    return _model(na, nb, nk, theta, r_inv, scale, rss, m, float(100.0 * (1.0 - np.sqrt(rss) / spread)))


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
    decides where they start) so their losses are comparable. As MATLAB's
    ``arxstruc`` does, the regressor of the largest structure (every output
    lag of the grid, every input lag any ``(nb, nk)`` needs, and ``y``) is
    reduced once to its small triangular QR factor, streamed in blocks of rows;
    each candidate's parameters and loss then come from its columns of that
    factor, at a cost independent of the record length.

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
    infinite AIC/BIC, NaN loss and are never chosen. Dependent means: the
    smallest singular value of the candidate's column-normalised regressor
    matrix is at most ``max(N, p) * eps`` times its largest (``N`` common rows,
    ``p`` parameters, ``eps`` the float64 machine epsilon), decided from the
    candidate's small triangular factor, as :func:`fit_arx` decides it.

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
        raise ConfigError("criterion", f"must be 'aic', 'bic' or 'validation', got {criterion!r}")
    nas = _as_range("na_range", na_range)
    nbs = _as_range("nb_range", nb_range)
    nks = _as_range("nk_range", nk_range)
    tolerance = _checked_tolerance(tolerance, criterion)
    u, y = _signals(u, y)
    validation = _validation_data(u_val, y_val, criterion)

    grid = [(na, nb, nk) for na, nb, nk in product(nas, nbs, nks) if na + nb != 0]
    if not grid:
        raise ConfigError("na_range", "the grid holds only na=0, nb=0")
    shared, fits = _fit_grid(u, y, grid)
    rows = [_order_candidate(shared, orders, fit, validation) for orders, fit in zip(grid, fits, strict=True)]
    if all(np.isinf(r.aic) for r in rows):
        raise DataError("no candidate of the order grid can be determined from the data")

    c = rows[_smallest_adequate(rows, criterion, tolerance)]
    return OrderSearch(
        candidates=tuple(rows),
        model=_own_record_fit(shared, u, y, c.na, c.nb, c.nk),
        criterion=criterion,
    )


# Elements per block of rows when the shared factor is built. OpenBLAS hands the
# level-2 kernels of a QR to its worker threads above about 8192 elements; on a
# busy machine, waking (and then spinning) them costs far more than the work
# (measured: 0.2-0.9 s instead of 0.08 s for the whole search on 10^6 samples).
# The block also bounds the memory, whatever the record length.
_BLOCK_ELEMENTS = 8000


@dataclass(frozen=True, eq=False)
class _SharedFactor:
    """The R factor of the largest structure's ``[Phi, y]``, shared by every candidate.

    Attributes
    ----------
    r : ndarray, shape (n_cols, n_cols)
        Upper-triangular, ``r^T r = Z^T Z`` for ``Z`` the rows ``first_row ..
        N-1`` of ``[y(k-1) .. y(k-max_na), u(k-j) for j in u_lags, y(k)]``.
    max_na : int
        Output lags in the factor (its first `max_na` columns).
    u_lags : tuple of int
        Input lags of the following columns, ascending.
    first_row : int
        First regression row ``k``, common to all candidates.
    n_rows : int
        Number of regression rows.
    energy : float
        ``sum y(k)^2`` over those rows.
    spread : float
        ``||y - mean(y)||`` over those rows.
    """

    r: np.ndarray
    max_na: int
    u_lags: tuple[int, ...]
    first_row: int
    n_rows: int
    energy: float
    spread: float

    @classmethod
    def of(cls, u: np.ndarray, y: np.ndarray, grid: list[tuple[int, int, int]]) -> _SharedFactor:
        """Factor for every ``(na, nb, nk)`` of `grid` over their common rows."""
        max_na = max(na for na, _, _ in grid)
        first_row = max(max_na, max(nk + nb - 1 for _, nb, nk in grid), 0)
        u_lags = tuple(sorted({j for _, nb, nk in grid for j in range(nk, nk + nb)}))
        y_rows = y[first_row:]
        return cls(
            r=_streamed_factor(u, y, max_na, u_lags, first_row),
            max_na=max_na,
            u_lags=u_lags,
            first_row=first_row,
            n_rows=y_rows.size,
            energy=_sum_of_squares(y_rows),
            spread=np.sqrt(_sum_of_squares(y_rows - y_rows.mean())) if y_rows.size else 0.0,
        )

    def columns(self, na: int, nb: int, nk: int) -> list[int]:
        """Columns of `r` that hold ``[Phi, y]`` of ``ARX(na, nb, nk)``, in that order."""
        u_col = {lag: self.max_na + i for i, lag in enumerate(self.u_lags)}
        return list(range(na)) + [u_col[j] for j in range(nk, nk + nb)] + [self.r.shape[1] - 1]

    def candidate_factor(self, na: int, nb: int, nk: int) -> np.ndarray:
        """R factor of the candidate's own ``[Phi, y]`` over the common rows.

        A column subset of a triangular factor is no longer triangular; one QR
        of the small ``(n_cols, p + 1)`` block makes it so again, at a cost
        independent of the record length.
        """
        cols = self.columns(na, nb, nk)
        block = self.r[: cols[-1] + 1, cols]
        return typing.cast(np.ndarray, np.linalg.qr(block, mode="r"))


def _streamed_factor(u: np.ndarray, y: np.ndarray, max_na: int, u_lags: tuple[int, ...], first_row: int) -> np.ndarray:
    """R factor of ``[y(k-1) .. y(k-max_na), u(k-j) for j in u_lags, y(k)]``, rows k >= `first_row`.

    The rows are built and reduced about :data:`_BLOCK_ELEMENTS` values at a
    time: each block is stacked under the factor so far and reduced by one
    Householder QR (LAPACK ``geqrf``), so memory is one block, never the whole
    regressor, and every step is an orthogonal transformation of the data (no
    normal equations).

    Returns
    -------
    ndarray, shape (n_cols, n_cols)
        Upper triangular; rows beyond the number of regression rows are zero.
    """
    n_cols = max_na + len(u_lags) + 1
    n = y.size
    block_rows = max(1, _BLOCK_ELEMENTS // n_cols)
    buf = np.zeros((block_rows + n_cols, n_cols), order="F")
    (geqrf,) = linalg.get_lapack_funcs(("geqrf",), (buf,))
    r = np.zeros((n_cols, n_cols))
    k = 0  # rows of the factor so far, on top of the block
    for start in range(first_row, n, block_rows):
        stop = min(n, start + block_rows)
        m = stop - start
        buf[:k] = r[:k]
        for col in range(max_na):
            buf[k : k + m, col] = y[start - col - 1 : stop - col - 1]
        for col, lag in enumerate(u_lags, start=max_na):
            buf[k : k + m, col] = u[start - lag : stop - lag]
        buf[k : k + m, -1] = y[start:stop]
        qr, _, _, info = geqrf(buf[: k + m])
        if info != 0:  # only an invalid argument makes geqrf fail
            raise DataError(f"QR of the ARX regressors failed (LAPACK geqrf info={info})")
        k = min(k + m, n_cols)
        r = np.triu(qr[:k])
    out = np.zeros((n_cols, n_cols))
    out[:k] = r[:k]
    return out


def _fit_grid(
    u: np.ndarray, y: np.ndarray, grid: list[tuple[int, int, int]]
) -> tuple[_SharedFactor, list[ArxModel | None]]:
    """Every ``(na, nb, nk)`` of `grid` fitted on the common rows (None: undetermined), and their factor."""
    shared = _SharedFactor.of(u, y, grid)
    return shared, [_candidate_fit(shared, na, nb, nk) for na, nb, nk in grid]


def _candidate_fit(shared: _SharedFactor, na: int, nb: int, nk: int) -> ArxModel | None:
    """The candidate fitted on the common rows from the shared factor; None when undetermined."""
    try:
        return _model_from_factor(shared.candidate_factor(na, nb, nk), shared.n_rows, shared.spread, na, nb, nk)
    except DataError:  # rank deficient: the data cannot determine p parameters
        return None


def _own_record_fit(shared: _SharedFactor, u: np.ndarray, y: np.ndarray, na: int, nb: int, nk: int) -> ArxModel:
    """``fit_arx(u, y, na, nb, nk)`` from the shared factor and the rows before the common ones.

    A candidate's own record starts at ``max(na, nk + nb - 1)``, at most a few
    rows before the common first row; those rows are stacked under the
    candidate's factor and reduced once more.
    """
    first = max(na, nk + nb - 1, 0)
    head = _regressors(u[: shared.first_row], y[: shared.first_row], range(1, na + 1), range(nk, nk + nb), first)
    r = typing.cast(np.ndarray, np.linalg.qr(np.vstack([shared.candidate_factor(na, nb, nk), head]), mode="r"))
    y_rows = y[first:]
    return _model_from_factor(r, y_rows.size, np.sqrt(_sum_of_squares(y_rows - y_rows.mean())), na, nb, nk)


def _sum_of_squares(x: np.ndarray) -> float:
    """``sum(x**2)``; not ``x @ x``, whose BLAS ``ddot`` wakes worker threads (see :data:`_BLOCK_ELEMENTS`)."""
    return float(np.einsum("i,i->", x, x))


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


def _order_candidate(
    shared: _SharedFactor,
    orders: tuple[int, int, int],
    fit: ArxModel | None,
    validation: tuple[np.ndarray, np.ndarray] | None,
) -> OrderCandidate:
    """One row of :func:`arx_order_search` from the candidate's fit on the common rows (None: undetermined)."""
    na, nb, nk = orders
    p = na + nb
    if fit is None:
        nan = float("nan")
        return OrderCandidate(na, nb, nk, p, nan, np.inf, np.inf, nan, -np.inf)
    n_rows = shared.n_rows
    rss = max(2.0 * fit.V, _RSS_FLOOR * shared.energy, np.finfo(float).tiny)
    base = n_rows * np.log(rss / n_rows)
    return OrderCandidate(
        na=na,
        nb=nb,
        nk=nk,
        n_params=p,
        V=fit.V,
        aic=float(base + 2 * p),
        bic=float(base + p * np.log(n_rows)),
        fit_percent=fit.fit_percent,
        fit_validation_percent=_validation_fit(fit, validation, shared.first_row),
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
