"""Black-box identification of a continuous-time ODE and its order (lecture, "Black Box").

The structure is unknown, so the general linear ODE is assumed::

    a_n y^(n) + ... + a_1 y' + a_0 y = b_m u^(m) + ... + b_1 u' + b_0 u

Divided by ``a0`` (lecture) it becomes linear in the normalised parameters,
with ``y`` alone on the left::

    y = -a1 y' - ... - an y^(n) + b0 u + b1 u' + ... + bm u^(m)

(``a_i`` and ``b_j`` here are the lecture's ``a~_i = a_i / a0`` and
``b~_j = b_j / a0``). Every candidate ``(n, m)`` with ``1 <= n <= n_max``,
``0 <= m <= min(m_max, n - 1)`` is fitted by least squares on state-variable
filter derivatives of ``u`` and ``y`` -- one filter, of order ``n_max + 1``,
for all candidates, so their costs compare.

Order selection
---------------
More parameters always lower ``V``; the lecture keeps the model whose extra
parameters come out "close to zero". Here a candidate is *adequate* when each
of its parameters is significant: ``|theta| >= 2 stderr`` and its term carries
at least `min_contribution` of the output (``rms(theta * regressor) /
rms(y)``). Among adequate (and, by default, stable) candidates the one with the lowest
information criterion wins::

    AIC = N_eff ln(2 V / N) + 2 p
    BIC = N_eff ln(2 V / N) + p ln(N_eff)

with ``V = 1/2 sum e^2`` over the ``N`` rows used, ``p`` parameters and
``N_eff = 2 cutoff_hz * duration`` independent samples (filtered residuals are
correlated; see :mod:`hilident.ident.greybox`). The transfer function of the
chosen model is ``Y/U = (bm s^m + ... + b0) / (an s^n + ... + a1 s + 1)``.

Examples
--------
>>> import numpy as np
>>> from scipy import signal
>>> from hilident.ident.blackbox import ode_order_search, select_order
>>> fs = 1000.0
>>> rng = np.random.default_rng(0)
>>> u = signal.sosfiltfilt(signal.butter(4, 2.0, fs=fs, output="sos"), rng.standard_normal(60000))
>>> numd, dend, _ = signal.cont2discrete(([1.0], [0.5, 1.0]), 1 / fs, method="foh")
>>> y = signal.lfilter(np.ravel(numd), dend, u)
>>> best = select_order(ode_order_search(u, y, fs, cutoff_hz=5.0, n_max=2, m_max=1))
>>> best.n, best.m, round(best.fit.params["a1"], 4)
(1, 0, 0.5)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError
from hilident.ident.derivatives import settling_samples, state_variable_filter
from hilident.ident.greybox import LinearFit, fit_linear
from hilident.ident.preprocess import check_signals

__all__ = ["OdeCandidate", "ode_order_search", "select_order"]

_CRITERIA = ("aic", "bic")


@dataclass(frozen=True, eq=False)
class OdeCandidate:
    """One fitted ``(n, m)`` model of the order search.

    Attributes
    ----------
    n, m : int
        Order of the output and of the input derivatives.
    fit : LinearFit
        Parameters ``a1..an`` (normalised output coefficients, s^k) and
        ``b0..bm`` (normalised input coefficients, units of y/u times s^j),
        with stderr, ``cost_V``, fit %.
    aic, bic : float
        Information criteria (module docstring).
    insignificant : tuple of str
        Parameters with ``|theta| < 2 stderr`` or a contribution below
        ``min_contribution``.
    error : str or None
        Why the candidate could not be fitted (then `fit` is None).
    """

    n: int
    m: int
    fit: LinearFit | None
    aic: float
    bic: float
    insignificant: tuple[str, ...]
    error: str | None = None

    @property
    def adequate(self) -> bool:
        """Fitted and every parameter significant."""
        return self.fit is not None and not self.insignificant

    @property
    def stable(self) -> bool:
        """All poles (roots of ``den``) strictly in the left half plane."""
        if self.fit is None:
            return False
        return bool(np.all(np.roots(self.den).real < 0.0))

    @property
    def den(self) -> np.ndarray:
        """Denominator ``[an, ..., a1, 1]`` (descending powers of s)."""
        p = self._fit().params
        return np.array([p[f"a{i}"] for i in range(self.n, 0, -1)] + [1.0])

    @property
    def num(self) -> np.ndarray:
        """Numerator ``[bm, ..., b0]`` (descending powers of s)."""
        p = self._fit().params
        return np.array([p[f"b{j}"] for j in range(self.m, -1, -1)])

    def transfer_function(self) -> tuple[np.ndarray, np.ndarray]:
        """``(num, den)`` for ``scipy.signal.lti`` / ``freqs``, den monic (leading 1)."""
        den = self.den
        return self.num / den[0], den / den[0]

    def _fit(self) -> LinearFit:
        if self.fit is None:
            raise DataError(f"model n={self.n}, m={self.m} was not fitted: {self.error}")
        return self.fit


def _check_int(key: str, value, low: int) -> int:
    if int(value) != value or value < low:
        raise ConfigError(key, f"must be an integer >= {low}, got {value!r}")
    return int(value)


def ode_order_search(
    u: ArrayLike,
    y: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float,
    n_max: int = 3,
    m_max: int = 1,
    order: int | None = None,
    kind: str = "butterworth",
    decimate: int = 1,
    min_contribution: float = 0.01,
) -> list[OdeCandidate]:
    """Fit the normalised ODE for every ``(n, m)`` and report cost, criteria and significance.

    Parameters
    ----------
    u, y : array_like
        Input and output samples (e.g. force in N, position in m); remove
        offsets first (:func:`hilident.ident.preprocess.detrend`) if the
        system is not at rest at zero.
    sample_rate_hz : float
        Sample rate, Hz.
    cutoff_hz : float
        SVF corner, Hz: above the excited band and the dynamics, as low as that
        allows (noise on ``y^(k)`` grows steeply with it).
    n_max, m_max : int
        Largest output order and input derivative tried (``m < n`` always).
    order : int, optional
        SVF order, at least ``n_max + 1`` (default).
    kind : str
        SVF kind, see :func:`hilident.ident.derivatives.state_variable_filter`.
    decimate : int
        Use every `decimate`-th filtered sample.
    min_contribution : float
        Smallest share of the output a term must carry to count as significant.

    Returns
    -------
    list of OdeCandidate
        Ordered by ``n``, then ``m``. Candidates the data cannot identify
        (collinear regressors) are returned with ``fit=None`` and ``error`` set.
    """
    n_max = _check_int("n_max", n_max, 1)
    m_max = _check_int("m_max", m_max, 0)
    decimate = _check_int("decimate", decimate, 1)
    if not (np.isfinite(min_contribution) and 0.0 <= min_contribution < 1.0):
        raise ConfigError("min_contribution", f"must lie in [0, 1), got {min_contribution!r}")
    sig = check_signals({"u": u, "y": y})
    fs = float(sample_rate_hz)
    order = n_max + 1 if order is None else order
    m_top = min(m_max, n_max - 1)
    Y = state_variable_filter(sig["y"], fs, cutoff_hz, n_max, order=order, kind=kind)
    U = state_variable_filter(sig["u"], fs, cutoff_hz, m_top, order=order, kind=kind)
    edge = settling_samples(fs, cutoff_hz, order, kind=kind)
    rows = np.arange(edge, Y.shape[1] - edge, decimate)
    if rows.size <= n_max + m_top + 2:
        raise DataError(
            f"{Y.shape[1]} samples leave {max(rows.size, 0)} after dropping {edge} filter-settling "
            "samples at each end; record longer or raise cutoff_hz"
        )
    regressors = {f"a{i}": -Y[i, rows] for i in range(1, n_max + 1)}
    regressors.update({f"b{j}": U[j, rows] for j in range(m_top + 1)})
    target = Y[0, rows]
    N = rows.size
    n_eff = min(float(N), N * decimate * 2.0 * float(cutoff_hz) / fs)

    out = []
    for n in range(1, n_max + 1):
        for m in range(min(m_max, n - 1) + 1):
            names = [f"a{i}" for i in range(1, n + 1)] + [f"b{j}" for j in range(m + 1)]
            try:
                fit = fit_linear(regressors, target, names, n_effective=n_eff)
            except DataError as exc:
                out.append(OdeCandidate(n, m, None, np.inf, np.inf, tuple(names), str(exc)))
                continue
            p = len(names)
            log_v = np.log(2.0 * fit.cost_V / N) if fit.cost_V > 0 else -np.inf
            out.append(
                OdeCandidate(
                    n=n,
                    m=m,
                    fit=fit,
                    aic=float(fit.n_effective * log_v + 2.0 * p),
                    bic=float(fit.n_effective * log_v + p * np.log(fit.n_effective)),
                    insignificant=fit.insignificant(2.0, min_contribution),
                )
            )
    return out


def select_order(
    candidates: Sequence[OdeCandidate], criterion: str = "bic", require_stable: bool = True
) -> OdeCandidate:
    """The adequate candidate with the lowest information criterion.

    Adequate: fitted, every parameter significant (see module docstring) and,
    with `require_stable`, all poles in the left half plane. The ``a0``
    normalisation already assumes a finite static gain (no integrator); an
    unstable fit of such a plant means the extra parameters fitted noise (too
    high a cutoff). Ties (equal criterion) go to the smaller model.

    Raises
    ------
    DataError
        No candidate is adequate; the message lists each one's insignificant
        parameters.
    """
    if criterion not in _CRITERIA:
        raise ConfigError("criterion", f"must be one of {_CRITERIA}, got {criterion!r}")
    ok = [c for c in candidates if c.adequate and (c.stable or not require_stable)]
    if not ok:

        def why(c: OdeCandidate) -> str:
            if c.error:
                return c.error
            if c.insignificant:
                return "insignificant " + ", ".join(c.insignificant)
            return "unstable"

        detail = "; ".join(f"n={c.n}, m={c.m}: {why(c)}" for c in candidates)
        raise DataError(f"no candidate model has only significant parameters ({detail})")
    return min(ok, key=lambda c: (getattr(c, criterion), c.n + c.m, c.n))
