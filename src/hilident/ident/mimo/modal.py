"""Modal parameters from every output and input at once: polyreference least-squares complex frequency domain
(LSCF, "PolyMAX") poles, a stabilisation diagram, and mode shapes by least-squares frequency domain (LSFD).

Steps, each usable alone:

* :func:`polyreference_lscf` -- for each model order ``p`` a right matrix-fraction model
  ``H(w) = N(w) D(w)^-1`` in the z-domain basis ``Omega = exp(-j w Ts)``, ``Ts = 1 / (2 f_max)`` of the band,
  with an ``n_in x n_in`` matrix denominator; its poles and participation vectors (:class:`PoleSet`).
* :func:`stabilisation` -- each pole of an order compared with the poles of the previous order: stable in
  frequency, damping and participation vector (:class:`StabilisationDiagram`, ready to plot).
* :func:`select_modes` -- the poles stable over the highest orders, grouped across orders into modes with a
  median frequency and damping and their spread; the shapes by :func:`lsfd`, a MAC matrix (:class:`ModalResult`).
* :func:`modal_analysis` -- the three in a row.
* :func:`modal_intervals` -- 95 % intervals of each mode's frequency and damping: the spread of the same
  estimate over independent groups of the record, and the difference from a maximum-likelihood fit of the
  modal model (:func:`refine_poles`) (:class:`Mode` ``frequency_ci95_hz``, ``damping_ci95``).

Sources: B. Peeters, H. Van der Auweraer, P. Guillaume, J. Leuridan, "The PolyMAX frequency-domain method: a new
standard for modal parameter estimation?", *Shock and Vibration* 11 (2004) 395-409; P. Guillaume, P. Verboven,
S. Vanlanduit, H. Van der Auweraer, B. Peeters, "A poly-reference implementation of the least-squares complex
frequency-domain estimator", Proc. IMAC XXI, 2003; W. Heylen, S. Lammens, P. Sas, *Modal Analysis Theory and
Testing*, KU Leuven 1997 (LSFD, residual terms, MAC).

Conventions as :class:`~hilident.ident.mimo.MimoResponse`: ``H[f, j, i]`` output ``j`` per input ``i``,
``H(w)`` the transfer function at ``s = j w``. A pole ``lambda = -zeta w_n + j w_n sqrt(1 - zeta^2)``;
natural frequency ``|lambda| / 2 pi`` Hz, damping ratio ``zeta = -Re(lambda) / |lambda|``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError
from hilident.ident.mimo.response import MimoResponse

__all__ = [
    "ModalResult",
    "Mode",
    "PoleSet",
    "StabilisationDiagram",
    "lsfd",
    "mac",
    "mac_matrix",
    "merge_split_modes",
    "modal_analysis",
    "modal_intervals",
    "polyreference_lscf",
    "refine_poles",
    "select_modes",
    "stabilisation",
]

#: Neighbouring modes with overlapping half-power bands whose shapes agree beyond this MAC are one mode.
SPLIT_MAC = 0.9

#: Labels of the stabilisation diagram, from least to most stable.
LABELS = ("new", "unstable", "frequency", "damping", "vector", "stable")

#: Fewest independent groups a mode must be found in for its interval (the t factor of 2 degrees of freedom, 4.3).
MIN_GROUPS = 3

#: A group's pole is taken for a mode only if their participation vectors agree to at least this MAC.
GROUP_MAC = 0.5


@dataclass(frozen=True, eq=False)
class PoleSet:
    """The physical poles of one model order.

    Attributes
    ----------
    order : int
        Polynomial order ``p`` of the matrix-fraction model.
    poles : ndarray of complex, shape (n,)
        Continuous-time poles ``lambda``, rad/s, positive imaginary part, sorted by frequency.
    frequency_hz : ndarray, shape (n,)
        Natural frequencies ``|lambda| / 2 pi``, Hz.
    damping : ndarray, shape (n,)
        Damping ratios ``-Re(lambda) / |lambda|``, in (0, 1).
    participation : ndarray of complex, shape (n, n_in)
        Modal participation vectors (left null vectors of the denominator at the pole), unit max magnitude.
    """

    order: int
    poles: np.ndarray
    frequency_hz: np.ndarray
    damping: np.ndarray
    participation: np.ndarray


@dataclass(frozen=True, eq=False)
class StabilisationDiagram:
    """Every physical pole of every order with its label, flat arrays of one entry per pole (for a plot).

    Attributes
    ----------
    order, frequency_hz, damping : ndarray, shape (n,)
        Model order, natural frequency (Hz) and damping ratio of each pole.
    label : ndarray of str, shape (n,)
        ``"new"`` (first order, nothing to compare), ``"unstable"`` (no pole of the previous order within the
        frequency tolerance), ``"frequency"`` (frequency only), ``"damping"`` (frequency and damping),
        ``"vector"`` (frequency and participation vector), ``"stable"`` (all three).
    previous : ndarray of int, shape (n,)
        Index (into these arrays) of the pole of the previous order it was compared with, -1 if none.
    participation : ndarray of complex, shape (n, n_in)
    poles : ndarray of complex, shape (n,)
        The continuous-time poles, rad/s.
    orders : tuple of int
        Every order of the diagram, those without a physical pole included.
    freq_tol, damp_tol, mac_tol : float
        The relative tolerances used.
    """

    order: np.ndarray
    frequency_hz: np.ndarray
    damping: np.ndarray
    label: np.ndarray
    previous: np.ndarray
    participation: np.ndarray
    poles: np.ndarray
    orders: tuple[int, ...]
    freq_tol: float
    damp_tol: float
    mac_tol: float


@dataclass(frozen=True, eq=False)
class Mode:
    """One identified mode.

    Attributes
    ----------
    frequency_hz : float
        Median natural frequency over the stable poles of the mode, Hz.
    damping : float
        Median damping ratio.
    frequency_ci_hz, damping_ci : tuple of float
        (min, max) over those poles: the spread across model orders, not a statistical interval (see
        ``frequency_ci95_hz``).
    shape : ndarray of complex, shape (n_out,)
        Mode shape over the outputs (first left singular vector of the LSFD residue matrix), unit max magnitude,
        its largest element real positive.
    participation : ndarray of complex, shape (n_in,)
        Participation vector over the inputs, normalised the same way.
    n_stable : int
        Number of orders at which the mode was labelled ``"stable"``.
    frequency_std_hz, damping_std : float
        Standard deviation (random error) of ``frequency_hz`` (Hz) and of ``damping`` (ratio), from the spread
        over independent groups of the record (:func:`modal_intervals`); NaN when not estimated.
    frequency_ci95_hz, damping_ci95 : float
        Half-width of the 95 % interval of ``frequency_hz`` (Hz) and of ``damping``: the standard deviation times
        Student's ``t_{0.975, n_groups - 1}`` plus the difference from the maximum-likelihood estimate
        (:func:`modal_intervals`); NaN when not estimated.
    n_groups : int
        Number of groups the mode was found in (0: no interval).
    """

    frequency_hz: float
    damping: float
    frequency_ci_hz: tuple[float, float]
    damping_ci: tuple[float, float]
    shape: np.ndarray
    participation: np.ndarray
    n_stable: int
    frequency_std_hz: float = math.nan
    damping_std: float = math.nan
    frequency_ci95_hz: float = math.nan
    damping_ci95: float = math.nan
    n_groups: int = 0


@dataclass(frozen=True, eq=False)
class ModalResult:
    """Modes selected from a stabilisation diagram, with their shapes and MAC matrix.

    Attributes
    ----------
    modes : tuple of Mode
        Sorted by frequency.
    stabilisation : StabilisationDiagram
    mac : ndarray, shape (n_modes, n_modes)
        MAC between the mode shapes.
    orders_used : tuple of int
        The model orders in the selection window.
    residues : ndarray of complex, shape (n_modes, n_out, n_in)
        LSFD residues ``R_r`` of ``H = sum_r R_r / (jw - lambda_r) + conj(R_r) / (jw - conj(lambda_r)) + ...``.
    notes : tuple of str
    """

    modes: tuple[Mode, ...]
    stabilisation: StabilisationDiagram
    mac: np.ndarray
    orders_used: tuple[int, ...]
    residues: np.ndarray
    notes: tuple[str, ...] = field(default=())


# --- checks ----------------------------------------------------------------------------------------------------


def _frf_arrays(frf: MimoResponse | tuple[ArrayLike, ArrayLike]) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (F,) and response (F, n_out, n_in) of a MimoResponse or a (frequency_hz, response) pair."""
    if isinstance(frf, MimoResponse):
        return frf.frequency_hz, frf.response
    try:
        f, h = frf
        f = np.asarray(f, dtype=np.float64)
        h = np.asarray(h, dtype=np.complex128)
    except (TypeError, ValueError) as exc:
        raise DataError(f"frf must be a MimoResponse or a (frequency_hz, response) pair: {exc}") from None
    if h.ndim == 2:
        h = h[:, :, None]
    if f.ndim != 1 or h.ndim != 3 or h.shape[0] != f.size:
        raise DataError(f"frequency_hz must be (F,) and response (F, n_out, n_in), got {f.shape} and {h.shape}")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(h))):
        raise DataError("frequency_hz and response must be finite")
    if f.size > 1 and np.any(np.diff(f) <= 0.0):
        raise DataError("frequency_hz must be strictly ascending")
    return f, h


def _band_lines(frequency_hz: np.ndarray, band_hz: ArrayLike) -> np.ndarray:
    """Boolean mask of the lines inside the band, which must lie within the data."""
    try:
        lo, hi = (float(v) for v in np.asarray(band_hz, dtype=np.float64).ravel())
    except (TypeError, ValueError):
        raise ConfigError("band_hz", f"must be a pair (f_min, f_max) in Hz, got {band_hz!r}") from None
    if not (0.0 <= lo < hi) or not math.isfinite(hi):
        raise ConfigError("band_hz", f"must satisfy 0 <= f_min < f_max, got ({lo}, {hi})")
    f = frequency_hz
    if lo < f[0] * (1 - 1e-9) or hi > f[-1] * (1 + 1e-9):
        raise ConfigError("band_hz", f"({lo}, {hi}) Hz reaches outside the data ({f[0]}, {f[-1]}) Hz")
    return (f >= lo) & (f <= hi)


def _orders(orders: int | Sequence[int]) -> list[int]:
    values = [orders] if isinstance(orders, (int, np.integer)) else list(orders)
    if not values:
        raise ConfigError("orders", "must hold at least one model order")
    for p in values:
        if isinstance(p, bool) or int(p) != p or p < 1:
            raise ConfigError("orders", f"every model order must be an integer >= 1, got {p!r}")
    return sorted({int(p) for p in values})


def _weights(frf: MimoResponse | tuple[ArrayLike, ArrayLike], weights, shape: tuple[int, ...]) -> np.ndarray:
    """Weights (F, n_out, n_in) >= 0: 1, ``1 / std`` for ``"std"``, or an array broadcast to the response."""
    if weights is None:
        return np.ones(shape)
    if isinstance(weights, str):
        if weights != "std" or not isinstance(frf, MimoResponse):
            raise ConfigError("weights", f"the only named weighting is 'std', of a MimoResponse; got {weights!r}")
        std = frf.std
        if not np.all(np.isfinite(std)) or np.any(std <= 0.0):
            raise DataError("weights 'std' needs a finite positive std at every line of the response")
        return 1.0 / std
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim == 1:
        w = w[:, None, None]
    elif w.ndim == 2:
        w = w[:, :, None]
    try:
        w = np.broadcast_to(w, shape).copy()
    except ValueError:
        raise ConfigError("weights", f"must broadcast to the response {shape}, got {np.shape(weights)}") from None
    if not np.all(np.isfinite(w)) or np.any(w < 0.0):
        raise ConfigError("weights", "must be finite and >= 0")
    return w


# --- LSCF ------------------------------------------------------------------------------------------------------


def _normal_blocks(omega: np.ndarray, h: np.ndarray, w: np.ndarray, p: int) -> tuple[np.ndarray, ...]:
    """The real normal equations of the highest order ``p``, per input ``i`` and output ``o``.

    Per output ``o`` and input ``i`` the weighted error ``w (N_o - H_o D)[:, i]`` over the lines is linear in the
    real numerator coefficients ``beta_oi`` (p+1) and the column ``i`` of the real denominator coefficients
    ``alpha`` ((p+1) n_in, power first): ``X beta + Y alpha`` with ``X[f, r] = w Omega_f^r`` and
    ``Y[f, (r, k)] = -w Omega_f^r H_f[o, k]``. Returns ``R = Re(X^H X)`` (n_in, n_out, p+1, p+1),
    ``S = Re(X^H Y)`` (n_in, n_out, p+1, (p+1) n_in) and ``T = Re(Y^H Y)`` (n_in, (p+1) n_in, (p+1) n_in), ``T``
    summed over the outputs. The columns of a lower order ``q`` are the first ``q + 1`` powers of each: its
    equations are the leading blocks of these (:func:`_order_matrix`), so one pass over the lines serves every
    order.
    """
    n_f, n_out, n_in = h.shape
    basis = omega[:, None] ** np.arange(p + 1)[None, :]
    size = (p + 1) * n_in
    r = np.zeros((n_in, n_out, p + 1, p + 1))
    s = np.zeros((n_in, n_out, p + 1, size))
    t = np.zeros((n_in, size, size))
    for i in range(n_in):
        for o in range(n_out):
            wo = w[:, o, i]
            x = wo[:, None] * basis
            y = -(wo[:, None, None] * basis[:, :, None] * h[:, o, None, :]).reshape(n_f, size)
            xh = x.conj().T
            r[i, o] = np.real(xh @ x)
            s[i, o] = np.real(xh @ y)
            t[i] += np.real(y.conj().T @ y)
    return r, s, t


def _order_matrix(blocks: tuple[np.ndarray, ...], p: int) -> np.ndarray:
    """Reduced normal matrices ``M_i = sum_o (T - S^T R^-1 S)`` of order ``p``, shape (n_in, (p+1) n_in, (p+1) n_in),
    from the leading blocks of :func:`_normal_blocks`.

    ``beta = -R^-1 S alpha`` eliminates the numerator; substituted, the cost is ``alpha_i^T M_i alpha_i``.
    """
    r, s, t = blocks
    n_in = t.shape[0]
    size = (p + 1) * n_in
    rp, sp = r[:, :, : p + 1, : p + 1], s[:, :, : p + 1, :size]
    try:
        solved = np.linalg.solve(rp, sp)
    except np.linalg.LinAlgError:  # an output weighted 0 over the band: its numerator is not determined
        solved = np.stack(
            [
                [np.linalg.lstsq(a, b, rcond=None)[0] for a, b in zip(ra, sa, strict=True)]
                for ra, sa in zip(rp, sp, strict=True)
            ]
        )
    return t[:, :size, :size] - np.einsum("iokr,iokc->irc", sp, solved)


def _denominator(m: np.ndarray, n_in: int) -> np.ndarray:
    """Denominator coefficients ``alpha`` (p+1, n_in, n_in), ``alpha_p = I``, from the reduced matrices.

    Column ``i`` minimises ``a^T M_i a`` with its last block fixed to ``e_i``: ``a_0 = -M_aa^-1 M_ab e_i``.
    """
    size = m.shape[1]
    p = size // n_in - 1
    alpha = np.zeros((size, n_in))
    alpha[p * n_in :, :] = np.eye(n_in)
    k = p * n_in
    for i in range(n_in):
        mi = m[i] / np.max(np.abs(np.diag(m[i])))
        alpha[:k, i] = -np.linalg.lstsq(mi[:k, :k], mi[:k, k + i], rcond=None)[0]
    return alpha.reshape(p + 1, n_in, n_in)


def _companion_poles(alpha: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time poles and participation vectors of ``D(Omega) = sum_r alpha_r Omega^r``.

    The left null vectors ``l`` of ``D`` (``D^T l = 0``) are the eigenvectors' first block of the companion
    matrix of ``sum_r alpha_r^T z^r``. A root ``z`` of ``Omega = exp(-s Ts)`` is a pole ``lambda = -ln(z) / Ts``.
    """
    p, n_in = alpha.shape[0] - 1, alpha.shape[1]
    comp = np.zeros((p * n_in, p * n_in))
    if p > 1:
        comp[: (p - 1) * n_in, n_in:] = np.eye((p - 1) * n_in)
    comp[(p - 1) * n_in :, :] = -np.concatenate([alpha[r].T for r in range(p)], axis=1)
    z, vectors = np.linalg.eig(comp)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -np.log(z.astype(np.complex128)) / ts
    return lam, vectors[:n_in, :].T


def _physical(lam: np.ndarray, part: np.ndarray, band: tuple[float, float], order: int) -> PoleSet:
    """The poles with positive imaginary part, 0 < damping < 1 and frequency in the band, sorted."""
    with np.errstate(divide="ignore", invalid="ignore"):
        fn = np.abs(lam) / (2.0 * np.pi)
        zeta = -np.real(lam) / np.abs(lam)
    keep = np.isfinite(lam) & (np.imag(lam) > 0.0) & (zeta > 0.0) & (zeta < 1.0) & (fn >= band[0]) & (fn <= band[1])
    idx = np.flatnonzero(keep)
    idx = idx[np.argsort(fn[idx])]
    return PoleSet(order, lam[idx], fn[idx], zeta[idx], _unit_max(part[idx]))


def _unit_max(v: np.ndarray) -> np.ndarray:
    """Each row scaled so its largest element is 1 (real positive); zero rows unchanged."""
    v = np.atleast_2d(np.asarray(v, dtype=np.complex128))
    k = np.argmax(np.abs(v), axis=1)
    ref = v[np.arange(v.shape[0]), k]
    ref = np.where(ref == 0.0, 1.0, ref)
    return v / ref[:, None]


def polyreference_lscf(
    frf: MimoResponse | tuple[ArrayLike, ArrayLike],
    band_hz: tuple[float, float],
    orders: int | Sequence[int],
    weights: ArrayLike | str | None = None,
) -> list[PoleSet]:
    """Poles and participation vectors of polyreference LSCF (PolyMAX) models of each order.

    Model (Peeters et al. 2004, Guillaume et al. 2003): ``H(w) = N(w) D(w)^-1`` with
    ``N(w) = sum_{r=0}^p Omega^r beta_r`` (n_out x n_in) and ``D(w) = sum_{r=0}^p Omega^r alpha_r``
    (n_in x n_in), real coefficients, ``Omega = exp(-j w Ts)``, ``Ts = 1 / (2 f_max)`` with ``f_max`` the band's
    upper edge. The weighted linearised error ``w_f (N - H D)`` is minimised in least squares; the numerator is
    eliminated from the normal equations and the denominator solved with ``alpha_p = I``. Its roots are the
    eigenvalues ``z`` of the block companion matrix, poles ``lambda = -ln(z) / Ts``.

    Parameters
    ----------
    frf : MimoResponse or (frequency_hz, response)
        Measured response; ``response`` (F, n_out, n_in) complex, frequencies in Hz ascending.
    band_hz : (float, float)
        Frequency band fitted, Hz, within the data.
    orders : int or sequence of int
        Model orders ``p >= 1``; each gives ``p n_in`` poles (physical ones and their conjugates, and
        computational ones).
    weights : array or "std", optional
        Weight of each line's error: shape (F,), (F, n_out) or (F, n_out, n_in) over the whole ``frf`` grid, or
        ``"std"`` for ``1 / std`` of a MimoResponse. Default 1 (outputs with larger responses weigh more).

    Returns
    -------
    list of PoleSet
        One per order, ascending; only physical poles (positive imaginary part, damping in (0, 1), frequency in
        the band).
    """
    f, h = _frf_arrays(frf)
    p_list = _orders(orders)
    lines = _band_lines(f, band_hz)
    w = _weights(frf, weights, h.shape)[lines]
    f_band, h_band = f[lines], h[lines]
    n_out, n_in, p_top = h.shape[1], h.shape[2], p_list[-1]
    # real equations per input column: 2 F n_out; unknowns (p+1) n_out numerator and p n_in denominator
    if 2 * f_band.size < p_top + 1 or 2 * f_band.size * n_out < (p_top + 1) * n_out + p_top * n_in:
        raise DataError(
            f"{f_band.size} lines in the band are too few for order {p_top} with {n_in} inputs and {n_out} outputs"
        )
    ts = 1.0 / (2.0 * f_band[-1])
    omega = np.exp(-2j * np.pi * f_band * ts)
    band = (float(f_band[0]), float(f_band[-1]))
    result = []
    blocks = _normal_blocks(omega, h_band, w, p_top)
    for p in p_list:
        alpha = _denominator(_order_matrix(blocks, p), n_in)
        lam, part = _companion_poles(alpha, ts)
        result.append(_physical(lam, part, band, p))
    return result


# --- stabilisation -----------------------------------------------------------------------------------------------


def mac(a: ArrayLike, b: ArrayLike) -> float:
    """Modal assurance criterion ``|a^H b|^2 / ((a^H a)(b^H b))`` of two complex vectors, in [0, 1].

    1 for vectors equal up to a complex factor, 0 for orthogonal ones; 0 if either is zero.
    """
    x = np.asarray(a, dtype=np.complex128).ravel()
    y = np.asarray(b, dtype=np.complex128).ravel()
    if x.size != y.size:
        raise DataError(f"mac needs vectors of equal length, got {x.size} and {y.size}")
    den = np.real(np.vdot(x, x)) * np.real(np.vdot(y, y))
    return float(abs(np.vdot(x, y)) ** 2 / den) if den > 0.0 else 0.0


def mac_matrix(shapes: ArrayLike, other: ArrayLike | None = None) -> np.ndarray:
    """MAC between every row of ``shapes`` and every row of ``other`` (default ``shapes``)."""
    a = np.atleast_2d(np.asarray(shapes, dtype=np.complex128))
    b = a if other is None else np.atleast_2d(np.asarray(other, dtype=np.complex128))
    return np.array([[mac(x, y) for y in b] for x in a]).reshape(a.shape[0], b.shape[0])


def _match(cur: PoleSet, prev: PoleSet, freq_tol: float) -> np.ndarray:
    """One-to-one matches of ``cur``'s poles to ``prev``'s by nearest relative frequency within tolerance."""
    match = np.full(cur.frequency_hz.size, -1)
    if cur.frequency_hz.size == 0 or prev.frequency_hz.size == 0:
        return match
    d = np.abs(cur.frequency_hz[:, None] - prev.frequency_hz[None, :]) / prev.frequency_hz[None, :]
    taken = np.zeros(prev.frequency_hz.size, dtype=bool)
    for flat in np.argsort(d, axis=None):
        k, j = np.unravel_index(flat, d.shape)
        if d[k, j] > freq_tol:
            break
        if match[k] < 0 and not taken[j]:
            match[k], taken[j] = j, True
    return match


def _label(cur: PoleSet, k: int, prev: PoleSet, j: int, damp_tol: float, mac_tol: float) -> str:
    """Label of pole ``k`` of ``cur`` matched in frequency to pole ``j`` of ``prev``."""
    if j < 0:
        return "unstable"
    damp_ok = abs(cur.damping[k] - prev.damping[j]) <= damp_tol * prev.damping[j]
    vec_ok = mac(cur.participation[k], prev.participation[j]) >= 1.0 - mac_tol
    return {(True, True): "stable", (True, False): "damping", (False, True): "vector"}.get(
        (bool(damp_ok), bool(vec_ok)), "frequency"
    )


def stabilisation(
    poles_by_order: Sequence[PoleSet],
    freq_tol: float = 0.01,
    damp_tol: float = 0.05,
    mac_tol: float = 0.02,
) -> StabilisationDiagram:
    """Label every pole by comparison with the poles of the previous order in the list.

    A pole is matched one-to-one to the pole of the previous order nearest in frequency, if within
    ``freq_tol`` (relative); it is then stable in damping if the damping ratios differ by at most ``damp_tol``
    (relative) and in vector if the participation vectors' MAC is at least ``1 - mac_tol``. The PolyMAX
    defaults are 1 %, 5 % and 2 %.

    Returns
    -------
    StabilisationDiagram
        One entry per pole, orders ascending; see its labels.
    """
    for key, value in (("freq_tol", freq_tol), ("damp_tol", damp_tol), ("mac_tol", mac_tol)):
        if not (0.0 < float(value) < 1.0):
            raise ConfigError(key, f"must lie in (0, 1), got {value!r}")
    sets = sorted(poles_by_order, key=lambda s: s.order)
    if not sets:
        raise DataError("poles_by_order is empty")
    labels: list[str] = []
    previous: list[int] = []
    offset = prev_offset = 0
    for n, cur in enumerate(sets):
        if n == 0:
            labels += ["new"] * cur.frequency_hz.size
            previous += [-1] * cur.frequency_hz.size
        else:
            match = _match(cur, sets[n - 1], freq_tol)
            labels += [_label(cur, k, sets[n - 1], j, damp_tol, mac_tol) for k, j in enumerate(match)]
            previous += [prev_offset + j if j >= 0 else -1 for j in match]
        prev_offset, offset = offset, offset + cur.frequency_hz.size
    n_in = next((s.participation.shape[1] for s in sets if s.participation.size), 1)
    return StabilisationDiagram(
        order=np.concatenate([np.full(s.frequency_hz.size, s.order) for s in sets]),
        frequency_hz=np.concatenate([s.frequency_hz for s in sets]),
        damping=np.concatenate([s.damping for s in sets]),
        label=np.array(labels, dtype=object),
        previous=np.array(previous, dtype=int),
        participation=np.concatenate([s.participation.reshape(-1, n_in) for s in sets]),
        poles=np.concatenate([s.poles for s in sets]),
        orders=tuple(s.order for s in sets),
        freq_tol=float(freq_tol),
        damp_tol=float(damp_tol),
        mac_tol=float(mac_tol),
    )


# --- LSFD --------------------------------------------------------------------------------------------------------


def lsfd(
    frf: MimoResponse | tuple[ArrayLike, ArrayLike],
    band_hz: tuple[float, float],
    poles: ArrayLike,
    weights: ArrayLike | str | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residues of fixed poles by least squares in the frequency domain, per output/input pair.

    ``H(w) = sum_r [R_r / (jw - lambda_r) + conj(R_r) / (jw - conj(lambda_r))] + L / (jw)^2 + U`` with real
    lower and upper residuals ``L`` and ``U`` (the modes below and above the band).

    Returns
    -------
    residues : ndarray of complex, shape (n_modes, n_out, n_in)
    lower, upper : ndarray, shape (n_out, n_in)
    """
    f, h = _frf_arrays(frf)
    lines = _band_lines(f, band_hz)
    w = _weights(frf, weights, h.shape)[lines]
    lam = np.atleast_1d(np.asarray(poles, dtype=np.complex128))
    s = 2j * np.pi * f[lines]
    a = 1.0 / (s[:, None] - lam[None, :])
    b = 1.0 / (s[:, None] - np.conj(lam)[None, :])
    # real unknowns: Re R_r, Im R_r, L, U
    basis = np.concatenate([a + b, 1j * (a - b), (1.0 / s**2)[:, None], np.ones((s.size, 1))], axis=1)
    n_modes, (n_out, n_in) = lam.size, h.shape[1:]
    if 2 * s.size < basis.shape[1]:
        raise DataError(f"{s.size} lines in the band are too few for {n_modes} modes")
    residues = np.zeros((n_modes, n_out, n_in), dtype=np.complex128)
    lower, upper = np.zeros((n_out, n_in)), np.zeros((n_out, n_in))
    for j in range(n_out):
        for i in range(n_in):
            wi = w[:, j, i][:, None]
            lhs = np.concatenate([np.real(wi * basis), np.imag(wi * basis)])
            rhs = np.concatenate([np.real(w[:, j, i] * h[lines, j, i]), np.imag(w[:, j, i] * h[lines, j, i])])
            x = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
            residues[:, j, i] = x[:n_modes] + 1j * x[n_modes : 2 * n_modes]
            lower[j, i], upper[j, i] = x[-2], x[-1]
    return residues, lower, upper


# --- selection ---------------------------------------------------------------------------------------------------


def _chains(diagram: StabilisationDiagram, window: list[int]) -> list[list[int]]:
    """For every pole of the highest order, the indices of its chain of matched predecessors within the window."""
    top = np.flatnonzero(diagram.order == window[-1])
    chains = []
    for k in top:
        chain = [int(k)]
        while diagram.previous[chain[-1]] >= 0 and diagram.order[diagram.previous[chain[-1]]] >= window[0]:
            chain.append(int(diagram.previous[chain[-1]]))
        chains.append(chain)
    return chains


def _shape(residue: np.ndarray) -> np.ndarray:
    """First left singular vector of a residue matrix, unit max magnitude."""
    u, _, _ = np.linalg.svd(residue)
    return _unit_max(u[:, 0])[0]


def select_modes(
    frf: MimoResponse | tuple[ArrayLike, ArrayLike],
    band_hz: tuple[float, float],
    diagram: StabilisationDiagram,
    n_orders: int = 6,
    min_stable_fraction: float = 0.8,
    weights: ArrayLike | str | None = None,
) -> ModalResult:
    """The modes stable over the highest model orders, their spread, LSFD shapes and MAC matrix.

    Window: the ``n_orders`` highest orders of the diagram. Every pole of the highest order is followed back
    through its matched predecessors (:func:`stabilisation`); the chain is a mode if it is labelled
    ``"stable"`` at no fewer than ``ceil(min_stable_fraction (n - 1))`` of the ``n - 1`` comparisons in the
    window (the lowest order of the window is the reference of the first comparison). The default, 4 of 5,
    keeps a true mode whose vector or damping wobbles once and rejects a computational pole, which rarely
    stays stable for more than two orders in a row. Frequency and damping are the medians over the chain's
    stable poles, the interval their (min, max). Shapes: :func:`lsfd` with those poles fixed.
    """
    if isinstance(n_orders, bool) or int(n_orders) != n_orders or n_orders < 2:
        raise ConfigError("n_orders", f"must be an integer >= 2, got {n_orders!r}")
    if not (0.0 < float(min_stable_fraction) <= 1.0):
        raise ConfigError("min_stable_fraction", f"must lie in (0, 1], got {min_stable_fraction!r}")
    all_orders = list(diagram.orders)
    if len(all_orders) < 2:
        raise DataError("the stabilisation diagram needs at least two orders")
    window = all_orders[-min(int(n_orders), len(all_orders)) :]
    need = math.ceil(min_stable_fraction * (len(window) - 1) - 1e-9)
    picked = []
    for chain in _chains(diagram, window):
        stable = [k for k in chain if diagram.label[k] == "stable"]
        if len(stable) >= max(need, 1):
            picked.append((chain[0], stable))
    picked.sort(key=lambda c: float(np.median(diagram.frequency_hz[c[1]])))
    lam = np.array([diagram.poles[top] for top, _ in picked], dtype=np.complex128)
    n_out = _frf_arrays(frf)[1].shape[1]
    n_in = diagram.participation.shape[1]
    residues = lsfd(frf, band_hz, lam, weights)[0] if lam.size else np.zeros((0, n_out, n_in), complex)
    modes = tuple(_mode(diagram, top, stable, residues[r]) for r, (top, stable) in enumerate(picked))
    notes = [f"window orders {window[0]}..{window[-1]}, mode if stable at >= {need} of {len(window) - 1} steps"]
    if not modes:
        notes.append("no pole was stable over the window: raise the orders or widen the tolerances")
    shapes_mac = mac_matrix([m.shape for m in modes]) if modes else np.zeros((0, 0))
    notes += _split_notes(modes, shapes_mac)
    return ModalResult(
        modes=modes,
        stabilisation=diagram,
        mac=shapes_mac,
        orders_used=tuple(window),
        residues=residues,
        notes=tuple(notes),
    )


def _split(a: Mode, b: Mode, shapes_mac: float, mac_limit: float = SPLIT_MAC) -> bool:
    """Whether neighbouring modes ``a`` and ``b`` are one mode fitted twice: their half-power bands overlap and
    their shapes agree (MAC above ``mac_limit``). Two true modes this close have distinct shapes (else the inputs
    could not separate them); a split mode, from a poorly weighted fit or leakage, gives two poles with one shape.
    """
    overlap = abs(b.frequency_hz - a.frequency_hz) < a.damping * a.frequency_hz + b.damping * b.frequency_hz
    return bool(overlap and shapes_mac > mac_limit)


def _split_notes(modes: tuple[Mode, ...], shapes_mac: np.ndarray) -> list[str]:
    """Warnings for neighbouring modes that are one mode fitted twice (:func:`_split`). Weighting by ``1 / std``
    usually cures it."""
    notes = []
    for r in range(len(modes) - 1):
        a, b = modes[r], modes[r + 1]
        if _split(a, b, shapes_mac[r, r + 1]):
            notes.append(
                f"modes at {a.frequency_hz:.4g} and {b.frequency_hz:.4g} Hz overlap with the same shape "
                f"(MAC {shapes_mac[r, r + 1]:.2f}): probably one mode split in two; try weights='std'"
            )
    return notes


def merge_split_modes(result: ModalResult) -> ModalResult:
    """``result`` with each pair of neighbouring modes that is one mode fitted twice (:func:`_split`) taken as one,
    as a zippered record gives them (each input seen on its own lines).

    The merged mode: the mean frequency and damping, both ranges, the shape and residue of the one stable over
    more orders, each input's larger participation. The split notes of ``result`` give way to notes of the merges;
    the MAC is that of the modes kept.
    """
    modes: list[Mode] = []
    residues: list[np.ndarray] = []
    merges = []
    for k, mode in enumerate(result.modes):
        if modes and _split(modes[-1], mode, result.mac[k - 1, k]):
            last = modes[-1]
            stronger = k if mode.n_stable > last.n_stable else None
            modes[-1] = _merged(last, mode)
            if stronger is not None:
                residues[-1] = result.residues[k]
            merges.append(
                f"poles at {last.frequency_hz:.5g} and {mode.frequency_hz:.5g} Hz with one shape (MAC "
                f"{result.mac[k - 1, k]:.2f}) and overlapping half-power bands taken as one mode"
            )
        else:
            modes.append(mode)
            residues.append(result.residues[k])
    if not merges:
        return result
    split_notes = set(_split_notes(result.modes, result.mac))
    return dataclasses.replace(
        result,
        modes=tuple(modes),
        mac=mac_matrix([m.shape for m in modes]),
        residues=np.array(residues),
        notes=tuple(n for n in result.notes if n not in split_notes) + tuple(merges),
    )


def _merged(a: Mode, b: Mode) -> Mode:
    stronger = b if b.n_stable > a.n_stable else a
    return Mode(
        frequency_hz=0.5 * (a.frequency_hz + b.frequency_hz),
        damping=0.5 * (a.damping + b.damping),
        frequency_ci_hz=(
            min(a.frequency_ci_hz[0], b.frequency_ci_hz[0]),
            max(a.frequency_ci_hz[1], b.frequency_ci_hz[1]),
        ),
        damping_ci=(min(a.damping_ci[0], b.damping_ci[0]), max(a.damping_ci[1], b.damping_ci[1])),
        shape=stronger.shape,
        participation=np.maximum(np.abs(a.participation), np.abs(b.participation)).astype(complex),
        n_stable=max(a.n_stable, b.n_stable),
    )


def _mode(diagram: StabilisationDiagram, top: int, stable: list[int], residue: np.ndarray) -> Mode:
    fn, zeta = diagram.frequency_hz[stable], diagram.damping[stable]
    return Mode(
        frequency_hz=float(np.median(fn)),
        damping=float(np.median(zeta)),
        frequency_ci_hz=(float(fn.min()), float(fn.max())),
        damping_ci=(float(zeta.min()), float(zeta.max())),
        shape=_shape(residue),
        participation=_unit_max(diagram.participation[top])[0],
        n_stable=len(stable),
    )


def modal_analysis(
    frf: MimoResponse | tuple[ArrayLike, ArrayLike],
    band_hz: tuple[float, float],
    orders: int | Sequence[int],
    weights: ArrayLike | str | None = None,
    freq_tol: float = 0.01,
    damp_tol: float = 0.05,
    mac_tol: float = 0.02,
    n_orders: int = 6,
    min_stable_fraction: float = 0.8,
) -> ModalResult:
    """:func:`polyreference_lscf`, :func:`stabilisation` and :func:`select_modes` in a row."""
    poles = polyreference_lscf(frf, band_hz, orders, weights)
    diagram = stabilisation(poles, freq_tol, damp_tol, mac_tol)
    return select_modes(frf, band_hz, diagram, n_orders, min_stable_fraction, weights)


# --- intervals ---------------------------------------------------------------------------------------------------


def refine_poles(
    frf: MimoResponse | tuple[ArrayLike, ArrayLike],
    band_hz: tuple[float, float],
    poles: ArrayLike,
    weights: ArrayLike | str | None = None,
) -> np.ndarray:
    """The poles of the modal model fitted to the response by weighted nonlinear least squares, from ``poles``.

    Model as :func:`lsfd`: ``H = sum_r [R_r / (jw - lambda_r) + conj(R_r) / (jw - conj(lambda_r))] + L / (jw)^2 +
    U``. The weighted output error ``w (H_measured - H)`` over every element and line of the band is minimised over
    the poles' natural frequencies and damping ratios (Levenberg-Marquardt), the residues and residual terms being
    solved by linear least squares at each step (variable projection). With weights ``1 / std`` this is the
    maximum-likelihood estimate of the modal model for circular complex Gaussian errors (Pintelon & Schoukens
    2012), which LSCF is not: its linearised equation error ``N - H D`` weighs the noise by the denominator, and
    the noise biases its poles (the reason for the refinement of B. Peeters, M. El-Kafafy, P. Guillaume, "The new
    PolyMAX Plus method: confident modal parameter estimation even in very noisy cases", Proc. ISMA 2012).

    Parameters
    ----------
    frf, band_hz, weights
        As for :func:`lsfd`; lines where the response is not finite are left out.
    poles : array_like of complex, shape (n_modes,)
        Starting poles, rad/s (the selected modes' LSCF poles).

    Returns
    -------
    ndarray of complex, shape (n_modes,)
        The fitted poles, rad/s, in the order given; NaN where a damping ratio left (0, 1).
    """
    f, h = _frf_arrays(frf)
    lines = _band_lines(f, band_hz)
    w, hb = _weights(frf, weights, h.shape)[lines], h[lines]
    bad = ~np.isfinite(hb)
    w, hb = np.where(bad, 0.0, w), np.where(bad, 0.0, hb)
    lam = np.atleast_1d(np.asarray(poles, dtype=np.complex128))
    if 2 * lines.sum() * hb.shape[1] * hb.shape[2] < 2 * lam.size + 2:
        raise DataError(f"{int(lines.sum())} lines in the band are too few to refine {lam.size} poles")
    from scipy import optimize  # scipy only once a refinement is asked for

    start = np.concatenate([np.log(np.abs(lam)), -np.real(lam) / np.abs(lam)])
    fit = optimize.least_squares(_model_error, start, args=(2j * np.pi * f[lines], hb, w), method="lm", x_scale="jac")
    wn, zeta = np.exp(fit.x[: lam.size]), fit.x[lam.size :]
    ok = (zeta > 0.0) & (zeta < 1.0)
    refined = wn * (-zeta + 1j * np.sqrt(np.where(ok, 1.0 - zeta**2, 0.0)))
    return np.where(ok, refined, np.nan)


def _model_error(theta: np.ndarray, s: np.ndarray, h: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted output errors (real and imaginary parts of every element and line) of the modal model with poles
    ``theta = (ln w_n, zeta)`` and its residues and residuals solved by linear least squares."""
    n = theta.size // 2
    wn, zeta = np.exp(theta[:n]), theta[n:]
    lam = wn * (-zeta + 1j * np.sqrt(np.clip(1.0 - zeta**2, 1e-12, None)))
    a = 1.0 / (s[:, None] - lam[None, :])
    b = 1.0 / (s[:, None] - np.conj(lam)[None, :])
    basis = np.concatenate([a + b, 1j * (a - b), (1.0 / s**2)[:, None], np.ones((s.size, 1))], axis=1)
    errors = []
    for j in range(h.shape[1]):
        for i in range(h.shape[2]):
            weighted = w[:, j, i, None] * basis
            lhs = np.concatenate([np.real(weighted), np.imag(weighted)])
            target = w[:, j, i] * h[:, j, i]
            rhs = np.concatenate([np.real(target), np.imag(target)])
            errors.append(rhs - lhs @ np.linalg.lstsq(lhs, rhs, rcond=None)[0])
    return np.concatenate(errors)


def modal_intervals(
    frf: MimoResponse | tuple[ArrayLike, ArrayLike],
    groups: Sequence[MimoResponse | tuple[ArrayLike, ArrayLike]],
    band_hz: tuple[float, float],
    result: ModalResult,
    weights: ArrayLike | str | None = None,
    jackknife: bool = False,
) -> ModalResult:
    """``result`` with a 95 % interval of each mode's frequency and damping: its random error, from independent
    groups of the record (or the jackknife's replicates of it), and its systematic error, from a second
    estimator.

    Random error: the sample mean and sample variance of an estimate repeated on ``K`` independent experiments
    (R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain Approach*, 2nd ed., Wiley-IEEE 2012),
    the experiments being disjoint parts of one record. Each of the ``K`` groups (disjoint Welch segments, or
    periods; each an estimate of the same response on the same lines) is fitted as the whole record was, by
    :func:`polyreference_lscf` at the orders of ``result.orders_used`` with the same ``weights``. At each order
    the pole nearest each mode is taken when it lies within the mode's half-power half-bandwidth ``zeta f_n``
    (at most half the gap to its neighbours) and the MAC of its participation vector's magnitudes with the
    mode's is at least :data:`GROUP_MAC`; the group's frequency and damping of the mode are the medians over
    the orders where one was found (at least half of them), as the whole record's are over its stable poles.
    The whole record's estimate is, to first order, the mean of the ``K`` group estimates, so its standard
    deviation is ``s / sqrt(K)``, ``s`` their sample standard deviation over the ``n`` groups that found the
    mode.

    Systematic error: LSCF's linearised least squares is biased by noise (often by more than its random
    error, in damping most), and a Welch estimate of a resonance narrower than a few lines is biased by the
    window's leakage. The modal model is therefore also fitted by maximum likelihood (:func:`refine_poles`) from
    the mode's poles; the difference ``d`` of the two estimates is a systematic error of at least one of them.

    Interval: ``estimate +- (t_{0.975, n - 1} s / sqrt(K) + |d|)`` (Student's t: ``s`` is estimated from few
    groups). It holds both the interval of the LSCF estimate and that of the maximum-likelihood one, so it
    covers the true value with at least 95 % probability when either estimator is unbiased (the
    maximum-likelihood one's random error is, asymptotically, at most LSCF's). Where both are biased alike (the
    leakage of a resonance far narrower than a line) it does not. Needs ``n >= MIN_GROUPS``; a mode found in fewer
    groups has none (NaN, a note), and one whose refinement failed the random part only (a note).

    Why not first-order covariance propagation of the response's standard deviation through the LSCF
    denominator (R. Pintelon, P. Guillaume, J. Schoukens, "Uncertainty calculation in (operational) modal
    analysis", *Mech. Syst. Signal Process.* 21 (2007) 2359-2373): the selection here is a median over orders
    of matched stable poles, which has no derivative, the per-line standard deviation omits the window's
    leakage and the correlation of overlapping segments, and the propagation, like the group spread, is blind
    to the estimator's bias. The group spread needs no derivative and includes every random step of the
    estimate, at the price of ``K`` more fits. It assumes the record stationary (the same system and noise in
    every group) and the groups independent (Welch blocks share no segment).

    Parameters
    ----------
    frf : MimoResponse or (frequency_hz, response)
        The whole record's estimate ``result`` was fitted to.
    groups : sequence of MimoResponse or (frequency_hz, response)
        ``K >= MIN_GROUPS`` estimates of the response from disjoint parts of the record, on the lines of
        ``frf`` (same shape, Hz).
    band_hz : (float, float)
        The band ``result`` was fitted over, Hz.
    result : ModalResult
        The whole record's modes (:func:`modal_analysis`, optionally :func:`merge_split_modes`).
    weights : array or "std", optional
        As for :func:`polyreference_lscf`: the whole record's weights (an array on the common grid) keep the
        groups' fits the same estimator as the whole record's; ``"std"`` weighs each group by its own spread.
    jackknife : bool
        ``groups`` are leave-one-block-out replicates of the whole record (:func:`~hilident.ident.mimo.spectral.
        leave_one_out_h1`), for a record too short for independent groups: the standard deviation is then the
        jackknife's, ``sqrt((n - 1) / n sum (theta_k - mean)^2)`` over the ``n`` replicates that found the mode
        (Efron & Tibshirani 1993, ch. 11), with the same Student factor.

    Returns
    -------
    ModalResult
        ``result`` with each mode's ``frequency_std_hz``, ``damping_std``, ``frequency_ci95_hz``,
        ``damping_ci95`` and ``n_groups`` set, and notes on the modes whose interval is partial or missing or
        dominated by the systematic part.

    Raises
    ------
    ConfigError
        Fewer than :data:`MIN_GROUPS` groups.
    DataError
        A group's lines differ from ``frf``'s, or are too few for the orders.
    """
    if len(groups) < MIN_GROUPS:
        raise ConfigError("groups", f"an interval needs at least {MIN_GROUPS} groups, got {len(groups)}")
    shape = _frf_arrays(frf)[1].shape
    if any(_frf_arrays(g)[1].shape != shape for g in groups):
        raise DataError(f"every group's response must have the shape {shape} of the whole record's")
    if not result.modes:
        return result
    orders = list(result.orders_used)
    tolerance = _match_tolerance(result.modes)
    found = np.array(
        [_group_estimates(polyreference_lscf(g, band_hz, orders, weights), result.modes, tolerance) for g in groups]
    )  # (K, n_modes, 2): frequency Hz, damping
    refined = _refined(frf, band_hz, result.modes, weights, tolerance)
    modes, notes = [], []
    for r, mode in enumerate(result.modes):
        with_interval, message = _with_interval(mode, found[:, r, :], refined[r], jackknife)
        modes.append(with_interval)
        notes += [message] if message else []
    return dataclasses.replace(result, modes=tuple(modes), notes=result.notes + tuple(notes))


def _match_tolerance(modes: Sequence[Mode]) -> np.ndarray:
    """Per mode, how far (Hz) another estimate of it may lie: its half-power half-bandwidth ``zeta f_n`` (at least
    0.1 % of ``f_n``), at most half the gap to either neighbouring mode, so no pole can be two modes'."""
    freq = np.array([m.frequency_hz for m in modes])
    tol = np.maximum(np.array([m.damping for m in modes]), 1e-3) * freq
    gaps = np.diff(freq) / 2.0
    tol[:-1] = np.minimum(tol[:-1], gaps)
    tol[1:] = np.minimum(tol[1:], gaps)
    return tol


def _nearest_pole(poles: PoleSet, mode: Mode, tolerance: float) -> int:
    """Index of the pole of ``poles`` nearest ``mode`` in frequency within ``tolerance`` (Hz) whose participation
    agrees with the mode's in magnitude (MAC of the magnitudes >= :data:`GROUP_MAC`: a merged mode,
    :func:`merge_split_modes`, keeps only those), -1 if none."""
    distance = np.abs(poles.frequency_hz - mode.frequency_hz)
    near = np.flatnonzero(distance <= tolerance)
    reference = np.abs(mode.participation)
    near = near[[mac(np.abs(poles.participation[k]), reference) >= GROUP_MAC for k in near]]
    return int(near[np.argmin(distance[near])]) if near.size else -1


def _group_estimates(poles: list[PoleSet], modes: Sequence[Mode], tolerance: np.ndarray) -> np.ndarray:
    """One group's (frequency Hz, damping) of each mode, shape (n_modes, 2): the medians over the orders of the
    matched poles (:func:`_nearest_pole`), NaN for a mode matched at fewer than half the orders."""
    picked = np.full((len(modes), len(poles), 2), np.nan)
    for k, pole_set in enumerate(poles):
        for r, mode in enumerate(modes):
            j = _nearest_pole(pole_set, mode, tolerance[r])
            if j >= 0:
                picked[r, k] = pole_set.frequency_hz[j], pole_set.damping[j]
    out = np.full((len(modes), 2), np.nan)
    for r in range(len(modes)):
        matched = picked[r, np.isfinite(picked[r, :, 0])]
        if 2 * matched.shape[0] >= len(poles):
            out[r] = np.median(matched, axis=0)
    return out


def _refined(
    frf: MimoResponse | tuple[ArrayLike, ArrayLike],
    band_hz: tuple[float, float],
    modes: Sequence[Mode],
    weights: ArrayLike | str | None,
    tolerance: np.ndarray,
) -> np.ndarray:
    """(frequency Hz, damping) of each mode by :func:`refine_poles`, shape (n_modes, 2); NaN where the fit failed
    or left the mode's tolerance (it then fitted something else)."""
    wn = 2.0 * np.pi * np.array([m.frequency_hz for m in modes])
    zeta = np.array([m.damping for m in modes])
    try:
        lam = refine_poles(frf, band_hz, wn * (-zeta + 1j * np.sqrt(1.0 - zeta**2)), weights)
    except (DataError, ValueError, np.linalg.LinAlgError):
        return np.full((len(modes), 2), np.nan)
    with np.errstate(invalid="ignore"):
        out = np.column_stack([np.abs(lam) / (2.0 * np.pi), -np.real(lam) / np.abs(lam)])
    far = ~(np.abs(out[:, 0] - wn / (2.0 * np.pi)) <= tolerance)
    out[far] = np.nan
    return out


def _with_interval(mode: Mode, estimates: np.ndarray, refined: np.ndarray, jackknife: bool = False) -> tuple[Mode, str]:
    """``mode`` with its standard deviations from the groups' ``estimates`` (K, 2) (independent groups, or the
    ``jackknife``'s replicates) and 95 % half-widths that add the difference from the ``refined`` (frequency,
    damping); and a note (empty when there is nothing to say)."""
    from scipy import stats  # the t quantile; scipy only once an interval is asked for

    n_total = estimates.shape[0]
    ok = estimates[np.isfinite(estimates[:, 0]) & np.isfinite(estimates[:, 1])]
    n = ok.shape[0]
    where = f"mode at {mode.frequency_hz:.5g} Hz"
    if n < MIN_GROUPS:
        return dataclasses.replace(mode, n_groups=n), f"{where}: found in {n} of {n_total} groups, no interval"
    std = ok.std(axis=0, ddof=0) * math.sqrt(n - 1) if jackknife else ok.std(axis=0, ddof=1) / math.sqrt(n_total)
    random = float(stats.t.ppf(0.975, n - 1)) * std
    systematic = np.abs(refined - [mode.frequency_hz, mode.damping])
    half = random + np.nan_to_num(systematic, nan=0.0)
    interval = dataclasses.replace(
        mode,
        frequency_std_hz=float(std[0]),
        damping_std=float(std[1]),
        frequency_ci95_hz=float(half[0]),
        damping_ci95=float(half[1]),
        n_groups=n,
    )
    return interval, _interval_note(where, n, n_total, random, systematic)


def _interval_note(where: str, n: int, n_total: int, random: np.ndarray, systematic: np.ndarray) -> str:
    """What the interval of a mode found in ``n`` of ``n_total`` groups leaves out or is made of, if anything."""
    notes = [f"found in {n} of {n_total} groups"] if n < n_total else []
    if not np.all(np.isfinite(systematic)):
        notes.append("the maximum-likelihood fit did not settle near it: its interval is the random error only")
    elif np.any(systematic > random):
        notes.append(
            f"the LSCF and maximum-likelihood estimates differ by {systematic[0]:.2g} Hz and {systematic[1]:.2g} in "
            "damping, more than their random error (a bias: leakage of a resonance only a few lines wide, or noise); "
            "the interval includes it"
        )
    return f"{where}: {'; '.join(notes)}" if notes else ""
