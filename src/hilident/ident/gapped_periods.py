"""The excited lines of periods that miss a few samples: least squares on the samples that exist.

A period of a periodic excitation in steady state is a sum of the excited
lines, a constant and noise. When some of its samples do not exist (a cycle the
host's clock skipped, a lost frame), its DFT cannot be taken, and nothing is
filled in: the constant and the excited lines are fitted to the samples that
do exist, by least squares. On a whole period the lines are orthogonal and the
fit is the DFT itself; with ``g`` samples missing its normal matrix is the
whole period's (diagonal) less a rank-``g`` term, so the Woodbury identity
solves it with one ``g x g`` system per period. A period whose remaining samples
cannot tell its lines apart (that system close to singular) is not used.

Pure numerics: arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_PIVOT", "line_spectra", "mean_period"]

#: Smallest eigenvalue of ``I - A_g D^-1 A_g^T`` (1 for a period missing nothing) at which a period is still used:
#: the variance of the estimate grows by at most its inverse, and only along ``g`` of its directions. A multisine
#: that excites most bins of a short period leaves little room (each missing sample's diagonal term is about
#: ``1 - (2 L + 1) / P`` for ``L`` lines), so the bound is low.
MIN_PIVOT = 0.02


def mean_period(periods: np.ndarray, present: np.ndarray) -> np.ndarray:
    """One period of a periodic signal: each sample the mean over the periods that have it (0 where none does).

    Parameters
    ----------
    periods : ndarray, shape (M, P, ...)
        One period per row; values where ``present`` is False are ignored.
    present : ndarray of bool, shape (M, P)
        Which samples exist.
    """
    periods = np.asarray(periods, dtype=np.float64)
    present = np.asarray(present, dtype=bool)
    ok = present.reshape(present.shape + (1,) * (periods.ndim - 2))
    counts = np.maximum(ok.sum(axis=0), 1)
    return np.where(ok, periods, 0.0).sum(axis=0) / counts


def line_spectra(periods: np.ndarray, present: np.ndarray, bins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DFT values at ``bins`` of each period, the missing samples' periods fitted by least squares.

    Parameters
    ----------
    periods : ndarray, shape (M, P)
        One period per row; values where ``present`` is False are ignored.
    present : ndarray of bool, shape (M, P)
        Which samples exist.
    bins : ndarray of int
        DFT bins ``1 .. P // 2 - 1`` (the lines fitted; the constant is fitted too).

    Returns
    -------
    spectra : ndarray of complex, shape (M, len(bins))
        What ``numpy.fft.rfft`` of a whole period gives at ``bins``; for a
        period with missing samples, the least-squares estimate of it (NaN for
        a period not used).
    used : ndarray of bool, shape (M,)
        The periods whose lines could be told apart (every whole period).
    """
    periods = np.asarray(periods, dtype=np.float64)
    present = np.asarray(present, dtype=bool)
    k = np.asarray(bins, dtype=np.int64)
    n_periods, period = periods.shape
    if k.size and (k.min() < 1 or 2 * k.max() >= period):
        raise ValueError(f"bins must lie in 1 .. {period // 2 - 1} (no constant, no Nyquist line)")
    zero_filled = np.where(present, periods, 0.0)
    spectra = np.fft.rfft(zero_filled, axis=-1)[:, k]
    used = np.ones(n_periods, dtype=bool)
    for m in np.flatnonzero(~present.all(axis=1)):
        estimate = _fit_period(zero_filled[m], np.flatnonzero(~present[m]), k, period)
        if estimate is None:
            used[m] = False
            spectra[m] = np.nan
        else:
            spectra[m] = estimate
    return spectra, used


def _fit_period(x: np.ndarray, missing: np.ndarray, k: np.ndarray, period: int) -> np.ndarray | None:
    """Least-squares DFT values at ``k`` of one period ``x`` (zero at ``missing``); None when not identifiable.

    Model ``x[j] = c + sum_k a_k cos(w_k j) + b_k sin(w_k j)``, ``w_k = 2 pi k / P``,
    whose DFT at ``k`` is ``P / 2 (a_k - i b_k)``.
    """
    if missing.size == period:
        return None
    full = np.fft.rfft(x)
    # A^T x over the samples that exist (x is zero at the others): constant, cosines, sines
    rhs = np.concatenate(([full[0].real], full[k].real, -full[k].imag))
    gram = np.concatenate(([float(period)], np.full(2 * k.size, period / 2.0)))  # D: the whole period's
    phase = 2.0 * np.pi * np.outer(missing, k) / period
    rows = np.hstack((np.ones((missing.size, 1)), np.cos(phase), np.sin(phase)))  # A_g, one row per missing sample
    scaled = rows / gram  # A_g D^-1
    inner = np.eye(missing.size) - scaled @ rows.T  # I - A_g D^-1 A_g^T
    if np.linalg.eigvalsh(inner).min() < MIN_PIVOT:
        return None
    first = rhs / gram
    coef = first + scaled.T @ np.linalg.solve(inner, scaled @ rhs)
    a, b = coef[1 : 1 + k.size], coef[1 + k.size :]
    return period / 2.0 * (a - 1j * b)
