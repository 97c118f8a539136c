"""One two-mass model from the frequency responses measured at several positions.

The gantry of the thesis (eqs. 2.3-2.4) has a stiffness and a damping that
depend on where the cart is, ``k(p1)`` and ``d(p1)``. Measured at one position,
a frequency response gives that position's mode only; the masses are the same
everywhere, so all positions together determine one model::

    m1 p1'' = c tau - b p1' - k(p) (p1 - p2) - d(p) (p1' - p2')
    m2 p2'' =                 k(p) (p1 - p2) - d(p) (p2' - p1')

    k(p) = sum_j k_j p^j        d(p) = sum_j d_j p^j

with ``p`` the (held) cart position, ``c`` the torque-to-force constant and
``b`` a viscous term on the cart, which stands for the friction that damps the
rigid-body motion. The cart velocity per motor torque is then

    H(s) = c (m2 s^2 + Z) / (m1 m2 s^3 + (m1 + m2) s Z + b (m2 s^2 + Z)),   Z = d(p) s + k(p).

:func:`fit_workspace_two_mass` estimates ``m1, m2, b, k_j, d_j`` from every
position's response at once by nonlinear least squares on the complex
logarithm of ``H`` (log-magnitude and phase errors), each bin weighted by
``sqrt(coh / (1 - coh))``, the inverse of the standard deviation of an H1
estimate's logarithm that its coherence implies (up to a common factor, which
the residual variance supplies). Given the sample rate, the model is the
sampled one a recording sees (torque held over each sample), not the
continuous one. :func:`compare_modes` sets the joint model's
mode at each position beside a per-position estimate.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.map_fit import fit_workspace_two_mass, two_mass_velocity_response
>>> positions = [0.1, 0.3, 0.5, 0.7, 0.9]
>>> f = np.linspace(2.0, 120.0, 300)
>>> truth = dict(m1=8.0, m2=2.0, b=15.0, torque_constant=10.0)
>>> frf = [two_mass_velocity_response(f, k=2e5 * (1 - 1.2 * p + 1.2 * p**2), d=30.0, **truth)
...        for p in positions]
>>> fit = fit_workspace_two_mass(positions, [f] * 5, frf, [np.ones(f.size)] * 5, torque_constant=10.0)
>>> [round(float(x), 4) for x in fit.k_coefficients]
[200000.0, -240000.0, 240000.0]
>>> round(fit.mode_at(0.5).frequency_hz, 2)
47.08
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError

__all__ = [
    "WorkspaceMode",
    "PositionFit",
    "WorkspaceFit",
    "ModeComparison",
    "fit_workspace_two_mass",
    "fit_workspace_responses",
    "compare_modes",
    "two_mass_velocity_response",
]

# Two-sided 95 % quantile of the normal distribution.
_Z95 = 1.959963984540054
# Coherence is clipped to this range for the weights: 1 (a noise-free response) would weigh a bin infinitely.
_COH_MIN, _COH_MAX = 1e-3, 0.9999
# Points on which k(p) must stay positive over the mapped range.
_RANGE_POINTS = 201
# Damping ratio assumed for the start value of d.
_START_DAMPING_RATIO = 0.02


def two_mass_velocity_response(
    frequency_hz: ArrayLike,
    *,
    m1: float,
    m2: float,
    k: float,
    d: float,
    torque_constant: float,
    b: float = 0.0,
    delay_s: float = 0.0,
    sample_rate_hz: float | None = None,
) -> np.ndarray:
    """Cart velocity per motor torque of the two-mass model with a viscous term on the cart.

    Parameters
    ----------
    frequency_hz : array_like
        Frequencies, Hz (> 0: the rigid-body pole sits at 0 Hz when ``b = 0``).
    m1, m2 : float
        Cart (driven) and load mass, kg.
    k : float
        Coupling stiffness at the position, N/m.
    d : float
        Coupling damping at the position, N·s/m.
    torque_constant : float
        ``c``, N/(N·m): the force on the cart is ``c * tau``.
    b : float
        Viscous damping of the cart to ground, N·s/m.
    delay_s : float
        A pure delay, s, as ``exp(-j 2 pi f delay_s)``.
    sample_rate_hz : float, optional
        When given, the response of the sampled system: the torque held over each sample
        (zero-order hold) and the velocity sampled, as a drive's recording sees it
        (``(1 - z^-1) Z{H(s) / s}`` at ``z = exp(j 2 pi f / sample_rate_hz)``). Without it the
        continuous ``H(j 2 pi f)``.

    Returns
    -------
    ndarray of complex
        ``H = v1 / tau``, (m/s)/(N·m).

    Examples
    --------
    >>> h = two_mass_velocity_response([1.0, 100.0], m1=8.0, m2=2.0, k=8e4, d=20.0, torque_constant=10.0)
    >>> [round(float(abs(x)), 5) for x in h]
    [0.15912, 0.00205]
    >>> hd = two_mass_velocity_response([1.0, 100.0], m1=8.0, m2=2.0, k=8e4, d=20.0, torque_constant=10.0,
    ...                                 sample_rate_hz=1000.0)
    >>> [round(float(abs(x)), 5) for x in hd]
    [0.15912, 0.00208]
    """
    f = np.asarray(frequency_hz, dtype=float)
    core = _Core(f.ravel(), float(torque_constant), _check_rate(sample_rate_hz), float(delay_s))
    h = core.response(m1, m2, b, np.array([float(k)]), np.array([float(d)]))
    return h.reshape(f.shape)


class WorkspaceMode(NamedTuple):
    """The coupled mode of the joint model at one position.

    Attributes
    ----------
    position_m : float
    frequency_hz : float
        Undamped natural frequency ``|lambda| / 2 pi`` of the complex pole pair, Hz.
    damping_ratio : float
        ``-Re(lambda) / |lambda|``.
    frequency_ci95_hz : float
        Half-width of the 95 % interval of `frequency_hz`, Hz, by the delta method through the
        parameters' covariance.
    """

    position_m: float
    frequency_hz: float
    damping_ratio: float
    frequency_ci95_hz: float


@dataclass(frozen=True)
class PositionFit:
    """How well the joint model explains one position's response.

    Attributes
    ----------
    position_m : float
    bins : int
        Frequencies used at this position.
    fit_percent : float
        ``100 (1 - ||H - H_model|| / ||H - mean H||)`` over the bins used (complex ``H``).
    relative_error_rms : float
        rms over the bins of ``|H_model / H - 1|``.
    """

    position_m: float
    bins: int
    fit_percent: float
    relative_error_rms: float


@dataclass(frozen=True, eq=False)
class WorkspaceFit:
    """The two-mass model fitted jointly to every position's frequency response.

    Attributes
    ----------
    torque_constant : float
        ``c`` the fit was given, N/(N·m).
    m1, m2 : float
        Cart and load mass, kg.
    b : float
        Viscous damping of the cart, N·s/m (0 and not estimated when the fit was told so).
    k_coefficients : ndarray
        ``k_j`` of ``k(p) = sum_j k_j p^j`` with ``p`` in m: ``k_j`` in N/m^(j+1).
    d_coefficients : ndarray
        ``d_j`` of ``d(p) = sum_j d_j p^j``: ``d_j`` in N·s/m^(j+1).
    parameter_names : tuple of str
        Names of the estimated parameters in the order of `covariance`: ``"m1", "m2"``, ``"b"``
        when estimated, ``"k0", "k1", ...``, ``"d0", ...``.
    covariance : ndarray
        Covariance of the estimated parameters (SI units as above), the residual variance times
        the inverse of ``J^T J`` at the solution.
    position_range_m : (float, float)
        Least and greatest position measured: where the model holds.
    positions : tuple of PositionFit
    converged : bool
        The solver stopped on a tolerance (not on its evaluation limit).
    message : str
        The solver's reason for stopping.
    evaluations : int
        Residual evaluations used.
    residual_rms : float
        rms of the weighted log residuals (about 1 per bin when the coherence weights are right
        and the model explains the data).
    delay_s : float
        The pure delay assumed in the model, s.
    lag_s : float
        Time constant of the measured velocity's first-order lag, s: estimated when ``"lag"`` is
        among `parameter_names`, else 0.
    sample_rate_hz : float or None
        Sample rate of the sampled model, Hz; None for the continuous one.
    warnings : tuple of str
    """

    torque_constant: float
    m1: float
    m2: float
    b: float
    k_coefficients: np.ndarray
    d_coefficients: np.ndarray
    parameter_names: tuple[str, ...]
    covariance: np.ndarray
    position_range_m: tuple[float, float]
    positions: tuple[PositionFit, ...]
    converged: bool
    message: str
    evaluations: int
    residual_rms: float
    delay_s: float = 0.0
    lag_s: float = 0.0
    sample_rate_hz: float | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)

    # -- parameters -------------------------------------------------------------------------

    @property
    def b_estimated(self) -> bool:
        """True when ``b`` was a free parameter of the fit."""
        return "b" in self.parameter_names

    @property
    def lag_estimated(self) -> bool:
        """True when the velocity's lag was a free parameter of the fit (its standard deviation: ``std["lag"]``)."""
        return "lag" in self.parameter_names

    @property
    def std(self) -> dict[str, float]:
        """Standard deviation of each estimated parameter, by name (SI units)."""
        return {
            n: float(math.sqrt(max(v, 0.0)))
            for n, v in zip(self.parameter_names, np.diag(self.covariance), strict=True)
        }

    @property
    def values(self) -> dict[str, float]:
        """Each estimated parameter, by name (SI units)."""
        return dict(zip(self.parameter_names, self._vector().tolist(), strict=True))

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix of the estimated parameters (order of `parameter_names`)."""
        sd = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = self.covariance / np.outer(sd, sd)
        return np.where(np.isfinite(r), r, 0.0)

    @property
    def k_std(self) -> np.ndarray:
        """Standard deviations of `k_coefficients`, N/m^(j+1)."""
        sd = self.std
        return np.array([sd[f"k{j}"] for j in range(self.k_coefficients.size)])

    @property
    def d_std(self) -> np.ndarray:
        """Standard deviations of `d_coefficients`, N·s/m^(j+1)."""
        sd = self.std
        return np.array([sd[f"d{j}"] for j in range(self.d_coefficients.size)])

    def _vector(self) -> np.ndarray:
        head = [self.m1, self.m2] + ([self.b] if self.b_estimated else [])
        tail = [self.lag_s] if self.lag_estimated else []
        return np.concatenate((head, self.k_coefficients, self.d_coefficients, tail))

    def _with_vector(self, v: np.ndarray) -> tuple[float, float, float, np.ndarray, np.ndarray]:
        """(m1, m2, b, k coefficients, d coefficients) from a parameter vector; the lag does not move the mode."""
        i = 3 if self.b_estimated else 2
        nk, nd = self.k_coefficients.size, self.d_coefficients.size
        return (
            float(v[0]),
            float(v[1]),
            float(v[2]) if self.b_estimated else self.b,
            v[i : i + nk],
            v[i + nk : i + nk + nd],
        )

    # -- the model over the workspace ------------------------------------------------------

    def k_of(self, position_m: ArrayLike) -> np.ndarray | float:
        """Stiffness ``k(p)``, N/m, at `position_m` (m); a float for a scalar position."""
        out = np.polynomial.polynomial.polyval(np.asarray(position_m, dtype=float), self.k_coefficients)
        return float(out) if np.ndim(out) == 0 else out

    def d_of(self, position_m: ArrayLike) -> np.ndarray | float:
        """Damping ``d(p)``, N·s/m, at `position_m` (m); a float for a scalar position."""
        out = np.polynomial.polynomial.polyval(np.asarray(position_m, dtype=float), self.d_coefficients)
        return float(out) if np.ndim(out) == 0 else out

    def response(self, position_m: float, frequency_hz: ArrayLike) -> np.ndarray:
        """The model's cart velocity per torque at `position_m`, (m/s)/(N·m), as measured (with the lag)."""
        h = two_mass_velocity_response(
            frequency_hz,
            m1=self.m1,
            m2=self.m2,
            k=float(self.k_of(position_m)),
            d=float(self.d_of(position_m)),
            b=self.b,
            torque_constant=self.torque_constant,
            delay_s=self.delay_s,
            sample_rate_hz=self.sample_rate_hz,
        )
        return h / (1.0 + 2j * np.pi * np.asarray(frequency_hz, dtype=float) * self.lag_s)

    def inside_range(self, position_m: float) -> bool:
        """True when `position_m` lies within the measured positions (the model is not extrapolated)."""
        lo, hi = self.position_range_m
        return lo <= float(position_m) <= hi

    def mode_at(self, position_m: float) -> WorkspaceMode:
        """The coupled mode at `position_m` (m), with the 95 % interval of its frequency.

        Outside `position_range_m` the polynomial is extrapolated and the interval grows fast;
        :meth:`inside_range` tells.
        """
        p = float(position_m)
        v = self._vector()
        f0, z0 = _mode(*self._with_vector(v), p)
        grad = np.zeros(v.size)
        for i in range(v.size):
            h = 1e-6 * max(abs(v[i]), math.sqrt(self.covariance[i, i]), 1e-12)
            up, down = v.copy(), v.copy()
            up[i] += h
            down[i] -= h
            grad[i] = (_mode(*self._with_vector(up), p)[0] - _mode(*self._with_vector(down), p)[0]) / (2.0 * h)
        var = float(grad @ self.covariance @ grad)
        return WorkspaceMode(p, f0, z0, _Z95 * math.sqrt(max(var, 0.0)))

    # -- summary.json ------------------------------------------------------------------------

    def as_dict(self) -> dict[str, Any]:
        """Plain data for ``summary.json``: unit-suffixed keys, coefficients with their units."""
        sd = self.std
        out: dict[str, Any] = {
            "model": "two_mass_workspace",
            "torque_constant_n_per_nm": self.torque_constant,
            "m1_kg": self.m1,
            "m1_std_kg": sd["m1"],
            "m2_kg": self.m2,
            "m2_std_kg": sd["m2"],
            "b_ns_per_m": self.b,
            "b_std_ns_per_m": sd.get("b"),
            "b_estimated": self.b_estimated,
            "k_n_per_m": _polynomial_dict(self.k_coefficients, self.k_std, "N/m"),
            "d_ns_per_m": _polynomial_dict(self.d_coefficients, self.d_std, "N*s/m"),
            "parameter_names": list(self.parameter_names),
            "correlation": self.correlation.tolist(),
            "position_range_m": list(self.position_range_m),
            "delay_s": self.delay_s,
            "velocity_lag_s": self.lag_s,
            "velocity_lag_std_s": sd.get("lag"),
            "lag_estimated": self.lag_estimated,
            "sample_rate_hz": self.sample_rate_hz,
            "positions": [],
            "converged": self.converged,
            "message": self.message,
            "evaluations": self.evaluations,
            "residual_rms": self.residual_rms,
            "warnings": list(self.warnings),
        }
        for pos in self.positions:
            mode = self.mode_at(pos.position_m)
            out["positions"].append(
                {
                    "position_m": pos.position_m,
                    "frequency_hz": mode.frequency_hz,
                    "frequency_ci95_hz": mode.frequency_ci95_hz,
                    "damping_ratio": mode.damping_ratio,
                    "k_n_per_m": self.k_of(pos.position_m),
                    "d_ns_per_m": self.d_of(pos.position_m),
                    "bins": pos.bins,
                    "fit_percent": pos.fit_percent,
                    "relative_error_rms": pos.relative_error_rms,
                }
            )
        return out


def _polynomial_dict(coefficients: np.ndarray, std: np.ndarray, unit: str) -> dict[str, Any]:
    units = [unit if j == 0 else f"{unit}^{j + 1}" for j in range(coefficients.size)]
    return {
        "coefficients": coefficients.tolist(),
        "std": std.tolist(),
        "units": units,
        "variable": "position_m",
        "form": "sum_j c_j * position_m**j",
    }


def _mode(m1: float, m2: float, b: float, kc: np.ndarray, dc: np.ndarray, p: float) -> tuple[float, float]:
    """``(frequency_hz, damping_ratio)`` of the complex pole pair of the model at position `p`."""
    k = float(np.polynomial.polynomial.polyval(p, kc))
    d = float(np.polynomial.polynomial.polyval(p, dc))
    total = m1 + m2
    roots = np.roots([m1 * m2, total * d + b * m2, total * k + b * d, b * k])
    pair = roots[np.imag(roots) > 0]
    if pair.size:
        lam = pair[0]
        w = float(abs(lam))
        return w / (2.0 * math.pi), float(-lam.real) / w
    # overdamped: the two fastest real roots stand for the pair
    real = np.sort(np.abs(np.real(roots)))[-2:]
    w = math.sqrt(float(real[0] * real[1]))
    return w / (2.0 * math.pi), float(real[0] + real[1]) / (2.0 * w)


# --------------------------------------------------------------------------------- the fit


@dataclass
class _Data:
    """The bins used, stacked over the positions."""

    frequency_hz: np.ndarray
    h: np.ndarray  # measured response
    weight: np.ndarray  # see _weights
    x: np.ndarray  # scaled position of each bin's position
    per_position: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # (f, h, coh) used at each position


def _checked_inputs(positions_m, frequency_hz, frf, coherence, band_hz) -> tuple[np.ndarray, list]:
    try:
        positions = np.asarray(positions_m, dtype=float).ravel()
    except (TypeError, ValueError):
        raise DataError(f"positions_m must be numbers, got {positions_m!r:.80}") from None
    if not np.all(np.isfinite(positions)):
        raise DataError(f"positions_m must be finite, got {positions.tolist()}")
    n = positions.size
    if not (len(frequency_hz) == len(frf) == len(coherence) == n):
        raise DataError(
            f"one frequency grid, response and coherence per position: {n} positions, "
            f"{len(frequency_hz)} grids, {len(frf)} responses, {len(coherence)} coherences"
        )
    if np.unique(positions).size != n:
        raise DataError(f"positions_m must be distinct, got {positions.tolist()}")
    lo, hi = (0.0, math.inf) if band_hz is None else (float(band_hz[0]), float(band_hz[1]))
    if not lo < hi:
        raise ConfigError("band_hz", f"must be (low, high) with low < high, got {band_hz!r}")
    used = []
    for i, (f, h, c) in enumerate(zip(frequency_hz, frf, coherence, strict=True)):
        f = np.asarray(f, dtype=float).ravel()
        h = np.asarray(h, dtype=complex).ravel()
        c = np.asarray(c, dtype=float).ravel()
        if not f.size == h.size == c.size:
            raise DataError(
                f"position {positions[i]:g} m: frequency_hz, frf and coherence differ in length "
                f"({f.size}, {h.size}, {c.size})"
            )
        keep = (
            np.isfinite(f)
            & (f > 0.0)
            & (f >= lo)
            & (f <= hi)
            & np.isfinite(h)
            & (h != 0.0)
            & np.isfinite(c)
            & (c > 0.0)
        )
        if not keep.any():
            raise DataError(
                f"position {positions[i]:g} m: no usable frequency (finite, non-zero response with "
                f"coherence > 0 within {lo:g}..{hi:g} Hz)"
            )
        order = np.argsort(f[keep], kind="stable")  # ascending: the weights average neighbouring bins
        used.append((f[keep][order], h[keep][order], np.clip(c[keep][order], _COH_MIN, _COH_MAX)))
    return positions, used


#: Neighbouring bins over which the noise-to-signal ratio of the coherence is averaged for the weights.
_WEIGHT_BINS = 7


def _weights(coh: np.ndarray) -> np.ndarray:
    """``sqrt(coh / (1 - coh))`` with ``(1 - coh) / coh`` averaged over neighbouring bins.

    A coherence estimated from the same data as ``H`` is high where noise happened to raise
    ``|H|``; weighting each bin by its own coherence pulls the fit towards such bins. Averaged
    over a few neighbours the weight keeps its trend over frequency and loses most of that
    correlation.
    """
    ratio = (1.0 - coh) / coh
    n = min(_WEIGHT_BINS, ratio.size)
    if n > 1:
        kernel = np.ones(n)
        ratio = np.convolve(ratio, kernel, mode="same") / np.convolve(np.ones(ratio.size), kernel, mode="same")
    return 1.0 / np.sqrt(ratio)


def _position_scale(positions: np.ndarray) -> tuple[float, float]:
    """Centre and half-width of the positions: the polynomials are fitted in ``(p - centre) / half``."""
    lo, hi = float(positions.min()), float(positions.max())
    half = 0.5 * (hi - lo)
    return 0.5 * (hi + lo), half if half > 0.0 else 1.0


def _to_power_basis(n: int, centre: float, half: float) -> np.ndarray:
    """Matrix taking the `n` coefficients of a polynomial in ``x = (p - centre) / half`` to those in ``p``."""
    P = np.polynomial.Polynomial
    x_of_p = P([-centre / half, 1.0 / half])
    T = np.zeros((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        coef = P(e)(x_of_p).coef
        T[: coef.size, j] = coef
    return T


def _pick_mode(f: np.ndarray, h: np.ndarray, coh: np.ndarray) -> tuple[float, float] | None:
    """Resonance and anti-resonance (Hz) of a velocity response: the peak of ``|H f|`` and the dip below it."""
    good = coh >= 0.5 if np.count_nonzero(coh >= 0.5) >= 5 else np.ones(f.size, dtype=bool)
    f, g = f[good], np.abs(h[good]) * f[good]
    if f.size < 5:
        return None
    i = int(np.argmax(g[1:-1])) + 1
    below = np.arange(i)
    j = int(below[np.argmin(g[below])]) if below.size else 0
    if j == 0 or not f[j] < f[i]:
        return float(f[i]), math.nan
    return float(f[i]), float(f[j])


def _start_values(
    positions, data: _Data, c: float, resonance_hz, k_degree: int, d_degree: int, centre: float, half: float
) -> dict[str, Any]:
    """Masses, ``k`` and ``d`` polynomials to start from, from each position's resonance and anti-resonance."""
    n = positions.size
    picked = [_pick_mode(*fhc) for fhc in data.per_position]
    if resonance_hz is not None:
        given = np.asarray(resonance_hz, dtype=float).ravel()
        if given.size != n or not np.all(np.isfinite(given) & (given > 0.0)):
            raise DataError(f"resonance_hz needs one positive frequency per position ({n}), got {given.tolist()}")
        fr = given
    else:
        if any(m is None for m in picked):
            bad = [float(p) for p, m in zip(positions, picked, strict=True) if m is None]
            raise DataError(f"no resonance could be picked at positions {bad} m (fewer than 5 usable bins)")
        fr = np.array([m[0] for m in picked])  # type: ignore[index]
    fa = np.array([m[1] if m is not None else math.nan for m in picked])
    ratio = (fa / fr) ** 2  # = m1 / (m1 + m2)
    ratio = ratio[np.isfinite(ratio) & (ratio > 0.0) & (ratio < 1.0)]
    share = float(np.clip(np.median(ratio), 0.05, 0.95)) if ratio.size else 0.8
    # 1/m1 from the level of H against the undamped shape (s^2 + wa^2) / (s (s^2 + wr^2)): a median over the bins
    # is not thrown by the singular bins at the resonance and the anti-resonance.
    levels = []
    for (f, h, _), f_r in zip(data.per_position, fr, strict=True):
        s = 2j * np.pi * f
        wr2 = (2.0 * np.pi * f_r) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            level = np.abs(h) / (c * np.abs((s * s + share * wr2) / (s * (s * s + wr2))))
        levels.append(level[np.isfinite(level) & (level > 0.0)])
    pooled = np.concatenate(levels)
    if not pooled.size:
        raise DataError("no frequency away from the picked resonances sets the level of the responses")
    inv_m1 = float(np.median(pooled))
    m1 = 1.0 / inv_m1
    total = m1 / share
    m2 = total - m1
    mu = m1 * m2 / total
    wr = 2.0 * np.pi * fr
    k_at = mu * wr**2
    x = (positions - centre) / half
    a_k = np.polynomial.polynomial.polyfit(x, k_at, k_degree)
    d_at = 2.0 * _START_DAMPING_RATIO * wr * mu
    a_d = np.zeros(d_degree + 1)
    a_d[0] = float(np.mean(d_at))
    f_low = float(min(f.min() for f, _, _ in data.per_position))
    return {
        "m1": m1,
        "m2": m2,
        "a_k": a_k,
        "a_d": a_d,
        "k_ref": float(np.mean(k_at)),
        "d_ref": float(np.mean(d_at)),
        "b_ref": total * 2.0 * np.pi * f_low,
    }


#: Aliases either side of each frequency summed for the sampled response (the remainder after the
#: rigid-body asymptote falls off as 1 / k^3; 8 leaves an error below 1e-6 relative on a gantry's response).
_ALIASES = 8


def _check_rate(sample_rate_hz: float | None) -> float | None:
    if sample_rate_hz is None:
        return None
    fs = float(sample_rate_hz)
    if not (math.isfinite(fs) and fs > 0.0):
        raise ConfigError("sample_rate_hz", f"must be a positive number, Hz, got {sample_rate_hz!r}")
    return fs


class _Core:
    """The model's response and its derivatives at a set of bins, continuous or sampled.

    Parameters: frequency of each bin (Hz), ``c``, the sample rate (None: continuous) and the delay.
    """

    def __init__(self, frequency_hz: np.ndarray, c: float, sample_rate_hz: float | None, delay_s: float):
        self.c = c
        w = 2.0 * np.pi * frequency_hz
        self.shift = np.exp(-1j * w * delay_s)
        self.fs = sample_rate_hz
        if sample_rate_hz is None:
            self.s = (1j * w)[:, None]
            return
        T = 1.0 / sample_rate_hz
        k = np.arange(-_ALIASES, _ALIASES + 1)
        self.s = 1j * (w[:, None] + k[None, :] * 2.0 * np.pi * sample_rate_hz)
        # H_d = sum_k H(s_k) (1 - exp(-s_k T)) / (s_k T); the asymptote c / (m1 s) is summed in closed form
        # (c T / (m1 (z - 1))) and only the remainder aliased, which converges fast.
        self.hold = (1.0 - np.exp(-1j * w * T))[:, None] / (self.s * T)
        self.integrator = T / (np.exp(1j * w * T) - 1.0)

    def _parts(self, m1, m2, b, k, d):
        s = self.s
        z = d[:, None] * s + k[:, None]
        num = m2 * s * s + z
        den = m1 * m2 * s**3 + (m1 + m2) * s * z + b * num
        return s, z, num, den

    def response(self, m1: float, m2: float, b: float, k_at: np.ndarray, d_at: np.ndarray) -> np.ndarray:
        """``H`` at each bin with ``k``, ``d`` given per bin (or one value for all)."""
        n = self.s.shape[0]
        k = np.broadcast_to(k_at, (n,))
        d = np.broadcast_to(d_at, (n,))
        s, z, num, den = self._parts(m1, m2, b, k, d)
        h = self.c * num / den
        if self.fs is None:
            return h[:, 0] * self.shift
        a = self.c / m1
        return (((h - a / s) * self.hold).sum(axis=1) + a * self.integrator) * self.shift

    def response_and_gradient(self, m1, m2, b, k, d):
        """``H`` and ``dH / d(m1, m2, b, k, d)`` per bin (the last axis of the gradient)."""
        s, z, num, den = self._parts(m1, m2, b, k, d)
        h = self.c * num / den
        total = m1 + m2
        dlog = np.stack(
            [
                -(m2 * s**3 + s * z) / den,
                s * s / num - (m1 * s**3 + s * z + b * s * s) / den,
                -num / den,
                1.0 / num - (total * s + b) / den,
            ],
            axis=-1,
        )
        dlog = np.concatenate((dlog, (dlog[..., 3] * s)[..., None]), axis=-1)  # d(H)/dd = s dH/dk
        grad = h[..., None] * dlog
        if self.fs is None:
            return h[:, 0] * self.shift, grad[:, 0, :] * self.shift[:, None]
        a = self.c / m1
        hd = ((h - a / s) * self.hold).sum(axis=1) + a * self.integrator
        grad = (grad * self.hold[..., None]).sum(axis=1)
        # the asymptote depends on m1: d(a)/d(m1) = -a / m1, added back in both its aliased and closed forms
        da = -a / m1
        grad[:, 0] += -(da / s * self.hold).sum(axis=1) + da * self.integrator
        return hd * self.shift, grad * self.shift[:, None]


class _Model:
    """Residuals and their Jacobian in the scaled parameters ``theta``.

    ``theta = [ln m1, ln m2, (b / b_ref), a_k / k_ref, a_d / d_ref]`` with ``a_k``, ``a_d`` the coefficients of
    ``k`` and ``d`` in the scaled position ``x``.
    """

    def __init__(
        self,
        data: _Data,
        core: _Core,
        nk: int,
        nd: int,
        fit_b: bool,
        refs: tuple[float, float, float],
        lag_ref: float | None = None,
    ):
        self.data, self.core, self.nk, self.nd, self.fit_b = data, core, nk, nd, fit_b
        self.k_ref, self.d_ref, self.b_ref = refs
        self.lag_ref = lag_ref  # None: no lag is estimated
        self.vk = np.vander(data.x, nk, increasing=True)
        self.vd = np.vander(data.x, nd, increasing=True)
        self.jw = 2j * np.pi * data.frequency_hz

    def unpack(self, theta: np.ndarray):
        m1, m2 = math.exp(theta[0]), math.exp(theta[1])
        i = 2
        b = 0.0
        if self.fit_b:
            b = theta[2] * self.b_ref
            i = 3
        a_k = theta[i : i + self.nk] * self.k_ref
        a_d = theta[i + self.nk : i + self.nk + self.nd] * self.d_ref
        return m1, m2, b, a_k, a_d

    def lag(self, theta) -> float:
        """The estimated lag's time constant, s (0 when none is estimated)."""
        return 0.0 if self.lag_ref is None else float(theta[-1]) * self.lag_ref

    def _at_bins(self, theta):
        m1, m2, b, a_k, a_d = self.unpack(theta)
        return m1, m2, b, self.vk @ a_k, self.vd @ a_d

    def residuals(self, theta) -> np.ndarray:
        h = self.core.response(*self._at_bins(theta))
        e = self.data.weight * (np.log(h / self.data.h) - np.log1p(self.jw * self.lag(theta)))
        return np.concatenate((e.real, e.imag))

    def jacobian(self, theta) -> np.ndarray:
        m1, m2, b, k, d = self._at_bins(theta)
        h, g = self.core.response_and_gradient(m1, m2, b, k, d)
        dlog = g / h[:, None]  # d log H / d(m1, m2, b, k, d)
        cols = [m1 * dlog[:, 0], m2 * dlog[:, 1]]
        if self.fit_b:
            cols.append(self.b_ref * dlog[:, 2])
        cols += [self.k_ref * dlog[:, 3] * self.vk[:, j] for j in range(self.nk)]
        cols += [self.d_ref * dlog[:, 4] * self.vd[:, j] for j in range(self.nd)]
        if self.lag_ref is not None:
            cols.append(-self.lag_ref * self.jw / (1.0 + self.jw * self.lag(theta)))
        J = np.stack(cols, axis=1) * self.data.weight[:, None]
        return np.concatenate((J.real, J.imag), axis=0)


def _check_degree(key: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ConfigError(key, f"must be an integer >= 0, got {value!r}")
    return int(value)


def _check_k_positive(kc: np.ndarray, lo: float, hi: float, when: str) -> None:
    grid = np.linspace(lo, hi, _RANGE_POINTS)
    k = np.polynomial.polynomial.polyval(grid, kc)
    if np.any(k <= 0.0):
        worst = int(np.argmin(k))
        raise DataError(
            f"{when}, k(p) is not positive everywhere in the mapped range {lo:g}..{hi:g} m "
            f"(k({grid[worst]:.4g} m) = {k[worst]:.4g} N/m): the data do not support a stiffness "
            f"polynomial of this degree; lower k_degree or measure at more positions"
        )


def fit_workspace_two_mass(
    positions_m: ArrayLike,
    frequency_hz: Sequence[ArrayLike],
    frf: Sequence[ArrayLike],
    coherence: Sequence[ArrayLike],
    *,
    torque_constant: float,
    k_degree: int = 2,
    d_degree: int = 0,
    band_hz: tuple[float, float] | None = None,
    estimate_cart_damping: bool = True,
    sample_rate_hz: float | None = None,
    delay_s: float = 0.0,
    estimate_lag: bool = False,
    resonance_hz: ArrayLike | None = None,
    max_evaluations: int = 400,
) -> WorkspaceFit:
    """Fit one two-mass model with position-dependent ``k(p)`` and ``d(p)`` to all positions' responses.

    Parameters
    ----------
    positions_m : array_like
        Cart position of each measured response, m (distinct).
    frequency_hz : sequence of array_like
        Frequency grid of each response, Hz (each position may have its own).
    frf : sequence of array_like of complex
        Cart velocity per motor torque at each position, (m/s)/(N·m).
    coherence : sequence of array_like
        Coherence of each response, in [0, 1]. Each bin is weighted by ``sqrt(coh / (1 - coh))``
        with the noise-to-signal ratio ``(1 - coh) / coh`` averaged over 7 neighbouring bins
        (coherence clipped to 0.001..0.9999); bins with coherence 0 or NaN are left out.
    torque_constant : float
        ``c``, N/(N·m): the force on the cart is ``c * tau``. It must be given: with ``c`` free the
        masses, ``b``, ``k`` and ``d`` all scale with it and leave ``H`` unchanged, so ``c`` and
        the rest cannot be told apart from a torque-to-velocity response.
    k_degree, d_degree : int
        Degree of the polynomials ``k(p)`` and ``d(p)`` in ``p``. The number of positions must be
        at least ``degree + 1`` for both.
    band_hz : (float, float), optional
        Only frequencies in ``low <= f <= high`` are used (the band the model should explain:
        above a second mode or below where friction stops being viscous the two-mass model does
        not hold). Default: every frequency above 0 Hz.
    estimate_cart_damping : bool
        Estimate ``b`` (default); False holds ``b = 0``.
    sample_rate_hz : float, optional
        Sample rate of the records the responses were estimated from, Hz. Given, the model is the
        sampled one (torque held over each sample, velocity sampled: see
        :func:`two_mass_velocity_response`), which a continuous model misses by half a sample of
        delay and by aliasing, a bias of order ``(f / sample_rate_hz)^2`` on the masses and
        ``k(p)``. Omitted, the continuous ``H(j 2 pi f)``.
    delay_s : float
        A known pure delay in the measured response beyond the hold, s (a drive's transport
        delay; exact for whole samples).
    estimate_lag : bool
        Also estimate a first-order lag ``1 / (1 + j 2 pi f lag_s)`` of the measured velocity
        (``"lag"`` among the parameters, s). A drive's velocity is an estimate: a difference of
        encoder counts, low-pass filtered and computed a tick late. To a model without it, the
        filter's phase reads as negative cart damping and its droop in magnitude as a heavier
        cart, which shift the masses and ``k(p)`` by percents. Well below the filter's corner a
        pure delay of a tick looks the same as a lag of that time constant, so one parameter
        holds both.
    resonance_hz : array_like, optional
        Resonance frequency at each position (e.g. from a per-position analysis) for the start
        values; by default picked as the peak of ``|H f|`` over the bins with coherence >= 0.5.
    max_evaluations : int
        Limit on residual evaluations of the solver.

    Returns
    -------
    WorkspaceFit

    Raises
    ------
    ConfigError
        A degree, the torque constant, the band or the delay out of range.
    DataError
        Fewer positions than the coefficients of ``k(p)`` or ``d(p)``, mismatched or unusable
        arrays, no usable frequency at a position, fewer bins than parameters, or ``k(p)`` not
        positive everywhere in the mapped range (at the start or at the solution).

    Notes
    -----
    Start values do not depend on a lucky guess: at each position the resonance ``f_r`` and
    the anti-resonance ``f_a`` below it are picked; ``(f_a / f_r)^2 = m1 / (m1 + m2)`` gives
    the mass ratio, the level of ``H`` against the undamped shape gives ``m1``, each ``f_r``
    gives ``k`` at its position, and the polynomial through those is ``k(p)``'s start.
    The residuals are ``w * log(H_model / H)`` (real and imaginary parts: log-magnitude and
    phase errors); the standard deviations come from ``s^2 (J^T J)^-1`` with ``s^2`` the
    residual variance, so they hold when the bins' errors are independent (true of a
    periodic excitation's bins; Welch estimates correlate neighbouring bins and understate them).
    """
    k_degree = _check_degree("k_degree", k_degree)
    d_degree = _check_degree("d_degree", d_degree)
    c = _check_torque_constant(torque_constant)
    delay = _check_delay(delay_s)
    fs = _check_rate(sample_rate_hz)
    positions, used = _checked_inputs(positions_m, frequency_hz, frf, coherence, band_hz)
    _check_enough_positions(positions.size, k_degree, d_degree)
    _check_below_nyquist(used, fs)
    centre, half = _position_scale(positions)
    data = _stacked_data(positions, used, centre, half)
    nk, nd = k_degree + 1, d_degree + 1
    fit_b, fit_lag = bool(estimate_cart_damping), bool(estimate_lag)
    names = _parameter_names(nk, nd, fit_b, fit_lag)
    _check_enough_bins(data.frequency_hz.size, len(names))
    lo, hi = float(positions.min()), float(positions.max())

    start = _start_values(positions, data, c, resonance_hz, k_degree, d_degree, centre, half)
    T_k = _to_power_basis(nk, centre, half)
    T_d = _to_power_basis(nd, centre, half)
    _check_k_positive(
        T_k @ start["a_k"], lo, hi, "at the start values (a polynomial through each position's resonance)"
    )
    core = _Core(data.frequency_hz, c, fs, delay)
    # the lag in units of a tenth of the period of the highest frequency used: order 1 where it matters
    lag_ref = 0.1 / float(data.frequency_hz.max()) if fit_lag else None
    model = _Model(data, core, nk, nd, fit_b, (start["k_ref"], start["d_ref"], start["b_ref"]), lag_ref)
    result = _solve(model, _start_theta(start, fit_b, fit_lag), max_evaluations)
    m1, m2, b, a_k, a_d = model.unpack(result.x)
    k_coef = T_k @ a_k
    d_coef = T_d @ a_d
    _check_k_positive(k_coef, lo, hi, "at the solution")
    if m1 <= 0.0 or m2 <= 0.0:  # pragma: no cover - exp() keeps them positive
        raise DataError("the joint fit gave a non-positive mass")
    fit = WorkspaceFit(
        torque_constant=c,
        m1=m1,
        m2=m2,
        b=b,
        k_coefficients=k_coef,
        d_coefficients=d_coef,
        parameter_names=names,
        covariance=_parameter_covariance(result, _si_jacobian(model, result.x, T_k, T_d)),
        position_range_m=(lo, hi),
        positions=(),
        converged=bool(result.status > 0),
        message=str(result.message),
        evaluations=int(result.nfev),
        residual_rms=float(np.sqrt(np.mean(result.fun**2))),
        delay_s=delay,
        lag_s=model.lag(result.x),
        sample_rate_hz=fs,
        warnings=_fit_warnings(result, d_coef, lo, hi),
    )
    return replace(fit, positions=_position_fits(fit, positions, used))


def _check_torque_constant(torque_constant: float) -> float:
    """``torque_constant`` (N/(N·m)) as a float, refused unless positive and finite."""
    c = float(torque_constant)
    if not (math.isfinite(c) and c > 0.0):
        raise ConfigError("torque_constant", f"must be a positive number, N/(N*m), got {torque_constant!r}")
    return c


def _check_delay(delay_s: float) -> float:
    """``delay_s`` (s) as a float, refused unless finite and not negative."""
    delay = float(delay_s)
    if not (math.isfinite(delay) and delay >= 0.0):
        raise ConfigError("delay_s", f"must be >= 0 s, got {delay_s!r}")
    return delay


def _check_enough_positions(n_positions: int, k_degree: int, d_degree: int) -> None:
    """Refuse fewer positions than the coefficients of the higher-degree polynomial, naming it."""
    need = max(k_degree, d_degree) + 1
    if n_positions < need:
        raise DataError(
            f"{n_positions} positions cannot determine the {need} coefficients of "
            f"{'k(p)' if k_degree >= d_degree else 'd(p)'} (k_degree={k_degree}, d_degree={d_degree}): "
            f"measure at {need} or more positions or lower the degree"
        )


def _check_below_nyquist(used: list, fs: float | None) -> None:
    """Refuse a frequency used above half the sample rate ``fs`` (Hz; None: the continuous model, no limit)."""
    if fs is not None and any(f.max() > fs / 2.0 for f, _, _ in used):
        raise DataError(
            f"frequencies above the Nyquist frequency {fs / 2.0:g} Hz of sample_rate_hz = {fs:g} Hz; "
            "give the rate the responses were estimated at, or a band_hz below it"
        )


def _check_enough_bins(n_bins: int, n_par: int) -> None:
    """Refuse fewer residuals (two per bin: log-magnitude and phase) than one more than the parameters."""
    if 2 * n_bins <= n_par:
        raise DataError(f"{n_bins} usable frequencies over all positions cannot determine {n_par} parameters")


def _stacked_data(positions: np.ndarray, used: list, centre: float, half: float) -> _Data:
    """The bins used at every position stacked into one set, each with its weight and scaled position.

    ``centre`` and ``half`` (m) scale the positions as :func:`_position_scale` gives them.
    """
    x_pos = (positions - centre) / half
    owner = np.repeat(np.arange(positions.size), [f.size for f, _, _ in used])
    return _Data(
        frequency_hz=np.concatenate([f for f, _, _ in used]),
        h=np.concatenate([h for _, h, _ in used]),
        weight=np.concatenate([_weights(c_) for _, _, c_ in used]),
        x=x_pos[owner],
        per_position=used,
    )


def _parameter_names(nk: int, nd: int, fit_b: bool, fit_lag: bool) -> tuple[str, ...]:
    """Names of the estimated parameters in the order of ``theta``: masses, ``b``, ``k_j``, ``d_j``, lag."""
    return (
        ("m1", "m2")
        + (("b",) if fit_b else ())
        + tuple(f"k{j}" for j in range(nk))
        + tuple(f"d{j}" for j in range(nd))
        + (("lag",) if fit_lag else ())
    )


def _start_theta(start: dict[str, Any], fit_b: bool, fit_lag: bool) -> np.ndarray:
    """The scaled parameters ``theta`` of :class:`_Model` at the start values (``b`` and the lag start at 0)."""
    return np.concatenate(
        (
            [math.log(start["m1"]), math.log(start["m2"])],
            [0.0] if fit_b else [],
            start["a_k"] / start["k_ref"],
            start["a_d"] / start["d_ref"],
            [0.0] if fit_lag else [],
        )
    )


def _solve(model: _Model, theta0: np.ndarray, max_evaluations: int):
    """Levenberg-Marquardt on the model's residuals from ``theta0``: :func:`scipy.optimize.least_squares`'s result."""
    from scipy.optimize import least_squares

    return least_squares(
        model.residuals,
        theta0,
        jac=model.jacobian,
        method="lm",
        x_scale="jac",
        max_nfev=int(max_evaluations),
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )


def _si_jacobian(model: _Model, theta: np.ndarray, T_k: np.ndarray, T_d: np.ndarray) -> np.ndarray:
    """Derivative of the SI parameters (order of :func:`_parameter_names`) by the scaled ``theta``.

    Diagonal but for the polynomial coefficients, which ``T_k``, ``T_d`` take from the scaled position to metres;
    ``d m / d ln m = m`` for the masses.
    """
    n_par = theta.size
    m1, m2 = model.unpack(theta)[:2]
    nk, nd = model.nk, model.nd
    G = np.zeros((n_par, n_par))
    G[0, 0], G[1, 1] = m1, m2
    i = 2
    if model.fit_b:
        G[2, 2] = model.b_ref
        i = 3
    G[i : i + nk, i : i + nk] = T_k * model.k_ref
    G[i + nk : i + nk + nd, i + nk : i + nk + nd] = T_d * model.d_ref
    if model.lag_ref is not None:
        G[-1, -1] = model.lag_ref
    return G


def _parameter_covariance(result, si_jacobian: np.ndarray) -> np.ndarray:
    """Covariance of the SI parameters: ``s^2 (J^T J)^-1`` in ``theta``, carried through ``si_jacobian``.

    ``s^2`` is the residual variance, the residuals' sum of squares over their degrees of freedom.
    """
    J = result.jac
    n_par = si_jacobian.shape[0]
    dof = max(J.shape[0] - n_par, 1)
    s2 = float(result.fun @ result.fun) / dof
    cov_theta = s2 * np.linalg.pinv(J.T @ J)
    return si_jacobian @ cov_theta @ si_jacobian.T


def _fit_warnings(result, d_coef: np.ndarray, lo: float, hi: float) -> tuple[str, ...]:
    """What a reader should know about a fit: the solver stopped short, ``d(p)`` negative within ``lo..hi`` m."""
    warnings = []
    if not result.status > 0:
        warnings.append(
            f"the joint fit stopped before converging after {result.nfev} evaluations "
            f"({result.message}); its parameters are the last iterate"
        )
    d_grid = np.polynomial.polynomial.polyval(np.linspace(lo, hi, _RANGE_POINTS), d_coef)
    if np.any(d_grid < 0.0):
        warnings.append(
            f"d(p) is negative somewhere in {lo:g}..{hi:g} m (min {d_grid.min():.4g} N*s/m): the damping "
            "is poorly determined; lower d_degree"
        )
    return tuple(warnings)


def _position_fits(fit: WorkspaceFit, positions: np.ndarray, used: list) -> tuple[PositionFit, ...]:
    """How well ``fit`` explains each position's bins used: scored against the fit's own response, lag included."""
    return tuple(_position_fit(fit, p, f, h) for p, (f, h, _) in zip(positions, used, strict=True))


def _position_fit(fit: WorkspaceFit, position_m: float, f: np.ndarray, h: np.ndarray) -> PositionFit:
    """How well ``fit`` explains the response ``h`` measured at ``position_m`` (m) on the bins ``f`` (Hz)."""
    h_model = fit.response(position_m, f)
    spread = np.linalg.norm(h - h.mean())
    fit_pct = 100.0 * (1.0 - np.linalg.norm(h - h_model) / spread) if spread > 0 else math.nan
    rel = float(np.sqrt(np.mean(np.abs(h_model / h - 1.0) ** 2)))
    return PositionFit(float(position_m), int(f.size), float(fit_pct), rel)


def fit_workspace_responses(positions_m: ArrayLike, responses: Sequence[Any], **options: Any) -> WorkspaceFit:
    """:func:`fit_workspace_two_mass` on one measured response per position.

    Parameters
    ----------
    positions_m : array_like
        Cart position of each response, m.
    responses : sequence of FrequencyResponse
        Anything with ``frequency_hz``, ``response`` and ``coherence`` arrays (as
        :class:`~hilident.ident.frequency.FrequencyResponse`), cart velocity per motor torque.
    **options
        The keyword arguments of :func:`fit_workspace_two_mass` (``torque_constant`` is required).
    """
    return fit_workspace_two_mass(
        positions_m,
        [r.frequency_hz for r in responses],
        [r.response for r in responses],
        [r.coherence for r in responses],
        **options,
    )


# --------------------------------------------------------------------------- comparison


@dataclass(frozen=True)
class ModeComparison:
    """The joint model's mode beside a per-position estimate at one position.

    Attributes
    ----------
    position_m : float
    joint_frequency_hz, joint_ci95_hz : float
        The joint model's mode and the half-width of its 95 % interval, Hz.
    local_frequency_hz, local_ci95_hz : float
        The per-position estimate and its 95 % half-width, Hz (NaN when unknown).
    difference_percent : float
        ``100 (joint - local) / local``.
    combined_ci95_hz : float
        ``sqrt(joint_ci95^2 + local_ci95^2)``: the 95 % half-width of the difference of two
        independent estimates.
    within_interval : bool
        ``|joint - local| <= combined_ci95_hz``.
    """

    position_m: float
    joint_frequency_hz: float
    joint_ci95_hz: float
    local_frequency_hz: float
    local_ci95_hz: float
    difference_percent: float
    combined_ci95_hz: float
    within_interval: bool

    def as_dict(self) -> dict[str, Any]:
        return {
            "position_m": self.position_m,
            "joint_frequency_hz": self.joint_frequency_hz,
            "joint_frequency_ci95_hz": self.joint_ci95_hz,
            "local_frequency_hz": self.local_frequency_hz,
            "local_frequency_ci95_hz": self.local_ci95_hz,
            "difference_percent": self.difference_percent,
            "combined_ci95_hz": self.combined_ci95_hz,
            "within_interval": self.within_interval,
        }


def compare_modes(
    fit: WorkspaceFit, positions_m: ArrayLike, frequency_hz: ArrayLike, frequency_ci95_hz: ArrayLike | None = None
) -> list[ModeComparison]:
    """The joint model's mode against per-position estimates of the mode frequency.

    Parameters
    ----------
    fit : WorkspaceFit
    positions_m : array_like
        Positions of the per-position estimates, m.
    frequency_hz : array_like
        Mode frequency estimated at each position on its own, Hz.
    frequency_ci95_hz : array_like, optional
        Half-width of each estimate's 95 % interval, Hz (NaN or omitted: unknown, taken as 0 in
        the combined interval).

    Returns
    -------
    list of ModeComparison
        One per position, in the order given.
    """
    p = np.asarray(positions_m, dtype=float).ravel()
    f = np.asarray(frequency_hz, dtype=float).ravel()
    ci = np.full(p.size, math.nan) if frequency_ci95_hz is None else np.asarray(frequency_ci95_hz, dtype=float).ravel()
    if not p.size == f.size == ci.size:
        raise DataError(
            f"positions_m, frequency_hz and frequency_ci95_hz differ in length ({p.size}, {f.size}, {ci.size})"
        )
    if not np.all(np.isfinite(f) & (f > 0.0)):
        raise DataError(f"frequency_hz must be positive and finite, got {f.tolist()}")
    out = []
    for pos, f_local, ci_local in zip(p, f, ci, strict=True):
        mode = fit.mode_at(float(pos))
        combined = math.hypot(mode.frequency_ci95_hz, 0.0 if not math.isfinite(ci_local) else float(ci_local))
        diff = mode.frequency_hz - float(f_local)
        out.append(
            ModeComparison(
                float(pos),
                mode.frequency_hz,
                mode.frequency_ci95_hz,
                float(f_local),
                float(ci_local),
                100.0 * diff / float(f_local),
                combined,
                abs(diff) <= combined,
            )
        )
    return out
