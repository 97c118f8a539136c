"""Continuous <-> discrete state-space models, controllability, observability.

Notation of the thesis (section 2.3): the continuous model
``x' = A x + B u, y = C x + D u`` (eqs. 2.14-2.15) sampled with period ``dt``
(the thesis' ``h``) becomes ``x(k+1) = Phi x(k) + Gamma u(k), y(k) = C x(k) +
D u(k)`` (eqs. 2.16-2.17).

- :func:`zoh`: exact for a piecewise-constant input, ``Phi = e^(A dt)``,
  ``Gamma = int_0^dt e^(A s) ds B`` (eqs. 2.22-2.23), both from one matrix
  exponential of ``[[A, B], [0, 0]] dt``.
- :func:`forward_euler`: ``Phi = I + A dt``, ``Gamma = B dt`` (eqs. 2.28-2.29).
- :func:`tustin`: ``Phi = (I + A dt/2)(I - A dt/2)^-1`` (eq. 2.30), the
  bilinear map ``s = 2/dt (z-1)/(z+1)``, optionally pre-warped so one
  frequency maps exactly.

The state-space results are identical to ``scipy.signal.cont2discrete`` with
``method="zoh"``, ``"euler"`` and ``"bilinear"``; the inverses
:func:`d2c_zoh` and :func:`d2c_tustin` undo them.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.discretize import zoh, is_controllable, second_order_poles
>>> w0, zeta, dt = 2 * np.pi * 10.0, 0.05, 1e-3
>>> A = np.array([[0.0, 1.0], [-w0**2, -2 * zeta * w0]])
>>> sys = zoh(A, [[0.0], [w0**2]], [[1.0, 0.0]], [[0.0]], dt)
>>> bool(is_controllable(sys.Phi, sys.Gamma))
True
>>> a1, a2 = second_order_poles(w0, zeta, dt)
>>> np.allclose(np.poly(np.linalg.eigvals(sys.Phi)), [1.0, a1, a2])
True
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg, signal

from hilident.errors import ConfigError, DataError

__all__ = [
    "StateSpace",
    "DiscreteStateSpace",
    "zoh",
    "forward_euler",
    "tustin",
    "d2c_zoh",
    "d2c_tustin",
    "c2d_tf",
    "d2c_tf",
    "controllability_matrix",
    "observability_matrix",
    "is_controllable",
    "is_observable",
    "second_order_poles",
    "sampling_advice",
]


class StateSpace(NamedTuple):
    """Continuous-time ``x' = A x + B u, y = C x + D u``."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray


class DiscreteStateSpace(NamedTuple):
    """Discrete-time ``x(k+1) = Phi x(k) + Gamma u(k), y(k) = C x(k) + D u(k)``, period ``dt`` s."""

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float


def _abcd(A, B, C, D) -> tuple[np.ndarray, ...]:
    try:
        a, b, c, d = (np.asarray(m, dtype=np.float64) for m in signal.abcd_normalize(A, B, C, D))
    except ValueError as exc:
        raise DataError(f"inconsistent state-space matrices: {exc}") from None
    for name, m in zip("ABCD", (a, b, c, d), strict=True):
        if not np.all(np.isfinite(m)):
            raise DataError(f"matrix {name} has non-finite entries")
    return a, b, c, d


def _check_dt(dt: float) -> float:
    h = float(dt)
    if not np.isfinite(h) or h <= 0.0:
        raise ConfigError("dt", f"must be a positive sample period in s, got {dt!r}")
    return h


def _tustin_step(dt: float, prewarp_hz: float | None) -> float:
    """Step ``T'`` for which ``2/T' (z-1)/(z+1)`` maps ``prewarp_hz`` exactly.

    With ``wp = 2 pi prewarp_hz``: ``T' = 2 tan(wp dt / 2) / wp`` (``dt`` when
    not pre-warping).
    """
    if prewarp_hz is None:
        return dt
    fp = float(prewarp_hz)
    nyquist = 0.5 / dt
    if not np.isfinite(fp) or fp <= 0.0 or fp >= nyquist:
        raise ConfigError("prewarp_hz", f"must lie in (0, {nyquist:g}) Hz (below Nyquist), got {prewarp_hz!r}")
    wp = 2.0 * np.pi * fp
    return 2.0 * np.tan(wp * dt / 2.0) / wp


def zoh(A: ArrayLike, B: ArrayLike, C: ArrayLike, D: ArrayLike, dt: float) -> DiscreteStateSpace:
    """Zero-order-hold sampling (thesis eqs. 2.22-2.23).

    ``expm([[A, B], [0, 0]] dt) = [[Phi, Gamma], [0, I]]``, which evaluates the
    integral of eq. 2.23 without inverting ``A`` (``A`` may be singular, as for
    the rigid-body mode of the two-mass axis).

    Parameters
    ----------
    A, B, C, D : array_like
        Continuous model; 1-D ``B``/``C`` are taken as a column / a row.
    dt : float
        Sample period, s.
    """
    a, b, c, d = _abcd(A, B, C, D)
    h = _check_dt(dt)
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    e = linalg.expm(block * h)
    return DiscreteStateSpace(e[:n, :n], e[:n, n:], c, d, h)


def forward_euler(A: ArrayLike, B: ArrayLike, C: ArrayLike, D: ArrayLike, dt: float) -> DiscreteStateSpace:
    """Forward Euler, ``Phi = I + A dt``, ``Gamma = B dt`` (thesis eq. 2.29).

    Only accurate for ``|lambda(A)| dt << 1``; a lightly damped mode becomes
    unstable when ``dt > 2 zeta / w0``.
    """
    a, b, c, d = _abcd(A, B, C, D)
    h = _check_dt(dt)
    return DiscreteStateSpace(np.eye(a.shape[0]) + a * h, b * h, c, d, h)


def tustin(
    A: ArrayLike,
    B: ArrayLike,
    C: ArrayLike,
    D: ArrayLike,
    dt: float,
    prewarp_hz: float | None = None,
) -> DiscreteStateSpace:
    """Tustin (bilinear) discretisation (thesis eq. 2.30), optionally pre-warped.

    With ``M = I - A T/2``: ``Phi = M^-1 (I + A T/2)``, ``Gamma = M^-1 B T``,
    ``Cd = C M^-1``, ``Dd = D + C M^-1 B T/2`` -- the realisation of
    ``scipy.signal.cont2discrete(..., method="bilinear")``, whose transfer
    function is exactly ``H(2/T (z-1)/(z+1))``. ``T = dt`` without pre-warping;
    with `prewarp_hz` ``T = 2 tan(wp dt/2)/wp`` so that ``H_d(e^(j wp dt)) =
    H(j wp)`` at ``wp = 2 pi prewarp_hz`` (e.g. a notch or resonance frequency).

    Parameters
    ----------
    A, B, C, D : array_like
        Continuous model.
    dt : float
        Sample period, s.
    prewarp_hz : float, optional
        Frequency that maps without warping, Hz, below Nyquist.
    """
    a, b, c, d = _abcd(A, B, C, D)
    h = _check_dt(dt)
    t = _tustin_step(h, prewarp_hz)
    eye = np.eye(a.shape[0])
    m = eye - a * t / 2.0
    if np.linalg.cond(m) > 1e12:
        raise DataError(f"A has an eigenvalue at 2/T = {2 / t:g} 1/s; Tustin is undefined")
    lu = linalg.lu_factor(m)
    phi = linalg.lu_solve(lu, eye + a * t / 2.0)
    gamma = linalg.lu_solve(lu, b * t)
    cd = linalg.lu_solve(lu, c.T, trans=1).T
    return DiscreteStateSpace(phi, gamma, cd, d + cd @ b * (t / 2.0), h)


def _has_negative_real_eigenvalue(phi: np.ndarray) -> np.ndarray:
    lam = np.linalg.eigvals(phi)
    scale = max(1.0, float(np.max(np.abs(lam))))
    tol = 1e-9 * scale
    return lam[(np.abs(lam.imag) <= tol) & (lam.real <= tol)]


def d2c_zoh(Phi: ArrayLike, Gamma: ArrayLike, C: ArrayLike, D: ArrayLike, dt: float) -> StateSpace:
    """Inverse of :func:`zoh` by the matrix logarithm.

    ``logm([[Phi, Gamma], [0, I]]) / dt = [[A, B], [0, 0]]``.

    Raises
    ------
    DataError
        If ``Phi`` has an eigenvalue on the closed negative real axis (including
        0): no real continuous model samples to it (a pole at ``z < 0`` is a
        mode at Nyquist, or the result of sampling too slowly).
    """
    phi, gamma, c, d = _abcd(Phi, Gamma, C, D)
    h = _check_dt(dt)
    bad = _has_negative_real_eigenvalue(phi)
    if bad.size:
        raise DataError(
            f"Phi has real eigenvalue(s) <= 0 ({', '.join(f'{v.real:.4g}' for v in bad)}); "
            "no real continuous-time model has this zero-order-hold sampling"
        )
    n, m = gamma.shape
    block = np.eye(n + m)
    block[:n, :n] = phi
    block[:n, n:] = gamma
    log = linalg.logm(block)
    if np.iscomplexobj(log):
        if np.max(np.abs(log.imag)) > 1e-8 * max(1.0, np.max(np.abs(log.real))):
            raise DataError("matrix logarithm of Phi is not real; no real continuous model")
        log = log.real
    log = log / h
    return StateSpace(log[:n, :n], log[:n, n:], c, d)


def d2c_tustin(
    Phi: ArrayLike,
    Gamma: ArrayLike,
    C: ArrayLike,
    D: ArrayLike,
    dt: float,
    prewarp_hz: float | None = None,
) -> StateSpace:
    """Inverse of :func:`tustin` (same `dt` and `prewarp_hz`).

    With ``N = (Phi + I)^-1``: ``A = 2/T (Phi - I) N``, ``B = 2/T N Gamma``,
    ``C = 2 Cd N``, ``D = Dd - Cd N Gamma``.

    Raises
    ------
    DataError
        If ``Phi`` has an eigenvalue at -1 (maps to infinity).
    """
    phi, gamma, cd, dd = _abcd(Phi, Gamma, C, D)
    h = _check_dt(dt)
    t = _tustin_step(h, prewarp_hz)
    eye = np.eye(phi.shape[0])
    p = phi + eye
    if np.linalg.cond(p) > 1e12:
        raise DataError("Phi has an eigenvalue at z = -1; the inverse Tustin map is undefined")
    lu = linalg.lu_factor(p)
    n_gamma = linalg.lu_solve(lu, gamma)
    c_n = linalg.lu_solve(lu, cd.T, trans=1).T
    a = (2.0 / t) * linalg.lu_solve(lu, phi - eye)  # (Phi+I)^-1 and (Phi-I) commute
    return StateSpace(a, (2.0 / t) * n_gamma, 2.0 * c_n, dd - cd @ n_gamma)


_C2D = {"zoh": zoh, "euler": forward_euler, "tustin": tustin}


def c2d_tf(
    num: ArrayLike,
    den: ArrayLike,
    dt: float,
    method: str = "zoh",
    prewarp_hz: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Discretise a SISO transfer function ``num(s)/den(s)``.

    Goes through the state-space functions of this module (``tf2ss``,
    discretise, ``ss2tf``); the result equals
    ``scipy.signal.cont2discrete((num, den), dt, method)`` with
    ``"zoh"``, ``"euler"`` and ``"bilinear"`` for ``"tustin"``.

    Parameters
    ----------
    num, den : array_like
        Polynomial coefficients in descending powers of ``s``; proper.
    dt : float
        Sample period, s.
    method : {"zoh", "euler", "tustin"}
    prewarp_hz : float, optional
        Only for ``"tustin"``.

    Returns
    -------
    (num_d, den_d) : ndarrays
        Coefficients in descending powers of ``z`` with ``den_d[0] == 1``,
        ``num_d`` padded to the length of ``den_d``.
    """
    if method not in _C2D:
        raise ConfigError("method", f"must be one of {sorted(_C2D)}, got {method!r}")
    if prewarp_hz is not None and method != "tustin":
        raise ConfigError("prewarp_hz", f"only applies to method 'tustin', not {method!r}")
    a, b, c, d = _tf2ss(num, den)
    if method == "tustin":
        sys = tustin(a, b, c, d, dt, prewarp_hz)
    else:
        sys = _C2D[method](a, b, c, d, dt)
    return _ss2tf(sys.Phi, sys.Gamma, sys.C, sys.D)


def d2c_tf(
    num: ArrayLike,
    den: ArrayLike,
    dt: float,
    method: str = "zoh",
    prewarp_hz: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`c2d_tf` for ``"zoh"`` and ``"tustin"``.

    Returns ``(num, den)`` in descending powers of ``s`` with ``den[0] == 1``.
    """
    if method not in ("zoh", "tustin"):
        raise ConfigError("method", f"must be 'zoh' or 'tustin', got {method!r}")
    a, b, c, d = _tf2ss(num, den)
    if method == "tustin":
        sys = d2c_tustin(a, b, c, d, dt, prewarp_hz)
    else:
        if prewarp_hz is not None:
            raise ConfigError("prewarp_hz", "only applies to method 'tustin'")
        sys = d2c_zoh(a, b, c, d, dt)
    return _ss2tf(*sys)


def _tf2ss(num, den):
    num = np.atleast_1d(np.asarray(num, dtype=np.float64))
    den = np.atleast_1d(np.asarray(den, dtype=np.float64))
    if num.ndim != 1 or den.ndim != 1:
        raise DataError("num and den must be 1-D coefficient arrays (SISO)")
    den_t = np.trim_zeros(den, "f")
    if den_t.size == 0:
        raise DataError("den is all zeros")
    # Leading numerator terms at rounding level (a sampled strictly proper
    # system) are zeros; left in, scipy would warn about bad coefficients.
    big = np.max(np.abs(num)) if num.size else 0.0
    lead = np.flatnonzero(np.abs(num) > 1e-13 * big)
    num = num[lead[0] :] if lead.size else np.zeros(1)
    if num.size > den_t.size:
        raise DataError(f"num of degree {num.size - 1} > den degree {den_t.size - 1}; not proper")
    return signal.tf2ss(num, den_t)


def _ss2tf(a, b, c, d):
    num, den = signal.ss2tf(a, b, c, d)
    num = np.ravel(num) / den[0]
    den = den / den[0]
    return num, den


def controllability_matrix(Phi: ArrayLike, Gamma: ArrayLike) -> np.ndarray:
    """``W_c = [Gamma, Phi Gamma, ..., Phi^(n-1) Gamma]`` (thesis eq. 2.31)."""
    phi = np.atleast_2d(np.asarray(Phi, dtype=np.float64))
    gamma = np.asarray(Gamma, dtype=np.float64)
    n = phi.shape[0]
    if phi.shape != (n, n):
        raise DataError(f"Phi must be square, got shape {phi.shape}")
    if gamma.ndim == 1:
        gamma = gamma[:, None]
    if gamma.shape[0] != n:
        raise DataError(f"Gamma must have {n} rows, got shape {gamma.shape}")
    blocks = [gamma]
    for _ in range(n - 1):
        blocks.append(phi @ blocks[-1])
    return np.hstack(blocks)


def observability_matrix(Phi: ArrayLike, C: ArrayLike) -> np.ndarray:
    """``W_o = [C; C Phi; ...; C Phi^(n-1)]`` (thesis eq. 2.32)."""
    phi = np.atleast_2d(np.asarray(Phi, dtype=np.float64))
    c = np.atleast_2d(np.asarray(C, dtype=np.float64))
    if c.shape[1] != phi.shape[0]:
        raise DataError(f"C must have {phi.shape[0]} columns, got shape {c.shape}")
    return controllability_matrix(phi.T, c.T).T


def _rank(w: np.ndarray, rtol: float | None, axis: int) -> int:
    """Numerical rank after scaling each state to unit norm.

    Scaling a state (a row of ``W_c``, a column of ``W_o``) is a change of
    state units and does not change the rank, but it stops a state in mm from
    looking negligible next to one in m/s. Singular values below
    ``rtol * s_max`` count as zero; default ``rtol = max(shape) * eps``
    (numpy's ``matrix_rank``) times 1e3 for the rounding of the powers of Phi.
    """
    norms = np.linalg.norm(w, axis=axis, keepdims=True)
    norms[norms == 0.0] = 1.0
    s = linalg.svdvals(w / norms)
    if s.size == 0 or s[0] == 0.0:
        return 0
    if rtol is None:
        rtol = 1e3 * max(w.shape) * np.finfo(float).eps
    return int(np.sum(s > rtol * s[0]))


def is_controllable(Phi: ArrayLike, Gamma: ArrayLike, rtol: float | None = None) -> bool:
    """``rank(W_c) == n`` (thesis eq. 2.31); see :func:`_rank` for `rtol`."""
    w = controllability_matrix(Phi, Gamma)
    return _rank(w, rtol, axis=1) == w.shape[0]


def is_observable(Phi: ArrayLike, C: ArrayLike, rtol: float | None = None) -> bool:
    """``rank(W_o) == n`` (thesis eq. 2.32); see :func:`_rank` for `rtol`."""
    w = observability_matrix(Phi, C)
    return _rank(w, rtol, axis=0) == w.shape[1]


def second_order_poles(omega0: float, zeta: float, dt: float) -> tuple[float, float]:
    """Characteristic polynomial ``z^2 + a1 z + a2`` of a sampled second-order system.

    Thesis eqs. 2.33-2.36: for ``w0^2 / (s^2 + 2 zeta w0 s + w0^2)`` sampled
    with period ``dt`` (any hold: the poles are ``e^(p dt)``),
    ``a1 = -2 e^(-zeta w0 dt) cos(sqrt(1 - zeta^2) w0 dt)``,
    ``a2 = e^(-2 zeta w0 dt)``. For ``zeta >= 1`` the cosine becomes a
    hyperbolic cosine. Note the scipy sign convention (``a = (1, a1, a2)``),
    opposite to the ARX coefficients of :mod:`hilident.ident.arx`.

    Parameters
    ----------
    omega0 : float
        Natural frequency, rad/s.
    zeta : float
        Damping ratio, >= 0.
    dt : float
        Sample period, s.
    """
    w0, z = float(omega0), float(zeta)
    if not np.isfinite(w0) or w0 <= 0.0:
        raise ConfigError("omega0", f"must be a positive frequency in rad/s, got {omega0!r}")
    if not np.isfinite(z) or z < 0.0:
        raise ConfigError("zeta", f"must be >= 0, got {zeta!r}")
    h = _check_dt(dt)
    wd_h = np.sqrt(complex(1.0 - z * z)) * w0 * h  # imaginary when overdamped: cos -> cosh
    a1 = -2.0 * np.exp(-z * w0 * h) * np.cos(wd_h).real
    a2 = np.exp(-2.0 * z * w0 * h)
    return float(a1), float(a2)


def sampling_advice(omega0_rad_s: float) -> dict[str, float]:
    """Sample period range for a mode at `omega0_rad_s` (thesis eq. 2.37).

    The rule ``w0 h = 0.2 .. 0.6`` gives about 10-31 samples per period of
    the dominant (closed-loop) mode; Nyquist (``w0 h < pi``) is the hard
    limit for seeing the mode at all.

    Returns
    -------
    dict
        ``h_min_s``, ``h_max_s`` (rule of thumb), ``sample_rate_min_hz``,
        ``sample_rate_max_hz`` (= 1/h_max, 1/h_min), ``samples_per_period_min``,
        ``samples_per_period_max``, ``nyquist_h_max_s`` (= pi / w0) and
        ``nyquist_sample_rate_min_hz`` (= w0 / pi).
    """
    w0 = float(omega0_rad_s)
    if not np.isfinite(w0) or w0 <= 0.0:
        raise ConfigError("omega0_rad_s", f"must be a positive frequency in rad/s, got {omega0_rad_s!r}")
    h_min, h_max = 0.2 / w0, 0.6 / w0
    return {
        "h_min_s": h_min,
        "h_max_s": h_max,
        "sample_rate_min_hz": 1.0 / h_max,
        "sample_rate_max_hz": 1.0 / h_min,
        "samples_per_period_min": 2.0 * np.pi / 0.6,
        "samples_per_period_max": 2.0 * np.pi / 0.2,
        "nyquist_h_max_s": np.pi / w0,
        "nyquist_sample_rate_min_hz": w0 / np.pi,
    }
