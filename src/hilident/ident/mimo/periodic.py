"""Periodic excitation of a system with several inputs: zippered multisines (every input its own DFT bins) and
orthogonal multisines (every input every bin, in ``n_in`` experiments of orthogonal phase patterns)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import BLOCK_SAMPLES, _check_rate
from hilident.ident.mimo.response import MimoResponse, _as_columns, _checked_channels, _positive_int
from hilident.ident.mimo.spectral import _input_solve

__all__ = [
    "ZIPPER_LEAKAGE",
    "orthogonal_mimo_frf",
    "orthogonal_multisine",
    "periodic_mimo_frf",
    "zippered_lines",
    "zippered_multisine",
]

#: A line is excited where an input's power is within this of its peak, dB (:func:`zippered_lines`).
EXCITED_DB = -40.0
#: An excited line is one input's own where every other input's power is this far below, dB
#: (:func:`zippered_lines`).
ZIPPER_DB = -40.0

#: Power of the other inputs at an input's own lines, relative to its own, above which the lines are not
#: taken as that input's alone (-60 dB).
ZIPPER_LEAKAGE = 1e-6


def _band_bins(period: int, fs: float, band_hz) -> np.ndarray:
    """DFT bins ``k`` with ``f_lo <= k fs / period <= f_hi``, without DC and the Nyquist line."""
    try:
        f_lo, f_hi = (float(f) for f in band_hz)
    except (TypeError, ValueError):
        raise ConfigError("band_hz", f"must be (f_lo, f_hi) in Hz, got {band_hz!r}") from None
    if not 0.0 <= f_lo < f_hi:
        raise ConfigError("band_hz", f"must satisfy 0 <= f_lo < f_hi, got {band_hz!r}")
    resolution = fs / period
    first = max(1, int(np.ceil(f_lo / resolution - 1e-9)))
    last = min((period - 1) // 2, int(np.floor(f_hi / resolution + 1e-9)))
    return np.arange(first, last + 1)


def zippered_multisine(
    n_inputs: int,
    period_samples: int,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    rms: float = 1.0,
    seed: int = 0,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """One period of ``n_inputs`` random-phase multisines that excite disjoint, interleaved DFT bins.

    The bins ``k`` of the band (frequency ``k * sample_rate_hz /
    period_samples``, DC and Nyquist excluded) are dealt round-robin: bin ``k``
    goes to input ``(k - first) mod n_inputs``, ``first`` being the band's
    lowest bin. Every input thus excites every ``n_inputs``-th bin and no two
    share one, so at an input's bins the outputs respond to that input alone
    (Pintelon & Schoukens, "zippered" multisines). Flat amplitude,
    phases uniform at random.

    Parameters
    ----------
    n_inputs : int
        Number of inputs (columns).
    period_samples : int
        Samples per period.
    sample_rate_hz : float
        Sample rate, Hz.
    band_hz : (float, float)
        Lowest and highest excited frequency, Hz; must hold at least
        `n_inputs` bins.
    rms : float
        RMS value of each column, in the input's units.
    seed : int
        Seed of the ``numpy.random.default_rng`` drawing the phases.

    Returns
    -------
    signals : ndarray, shape (period_samples, n_inputs)
        One period of each input; repeat it (``np.tile``) for a record.
    lines : list of ndarray of int
        The DFT bins each input excites, ascending.
    """
    n = _positive_int(n_inputs, "n_inputs", 1)
    period = _positive_int(period_samples, "period_samples", 4)
    fs = _check_rate(sample_rate_hz)
    if not np.isfinite(rms) or rms <= 0.0:
        raise ConfigError("rms", f"must be a positive number, got {rms!r}")
    bins = _band_bins(period, fs, band_hz)
    if bins.size < n:
        raise ConfigError("band_hz", f"{band_hz!r} holds {bins.size} bins of {fs / period:g} Hz; {n} inputs need {n}")
    owner = (bins - bins[0]) % n
    spectrum = np.zeros((period // 2 + 1, n), dtype=np.complex128)
    phases = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, bins.size)
    spectrum[bins, owner] = np.exp(1j * phases)
    signals = np.fft.irfft(spectrum, n=period, axis=0)
    signals *= rms / np.sqrt(np.mean(signals**2, axis=0))
    return signals, [bins[owner == i] for i in range(n)]


def zippered_lines(inputs: ArrayLike, period_samples: int) -> list[np.ndarray] | None:
    """Each input's own DFT bins of one period when the inputs are zippered; None when they are not.

    A bin is excited where some input's mean power over the periods lies within :data:`EXCITED_DB` of its
    peak; it is an input's own where every other input's power there is :data:`ZIPPER_DB` below. The inputs
    are zippered when every excited bin is some input's own and every input owns a bin.
    """
    inputs = _as_columns(inputs, "inputs")
    n_periods = len(inputs) // period_samples
    if n_periods < 1 or inputs.shape[1] < 2:
        return None
    blocks = inputs[: n_periods * period_samples].reshape(n_periods, period_samples, -1)
    power = np.mean(np.abs(np.fft.rfft(blocks, axis=1)) ** 2, axis=0)[1:]  # (bins without DC, n_in)
    excited = power >= power.max(axis=0) * 10.0 ** (EXCITED_DB / 10.0)
    owner = np.argmax(power, axis=1)
    others = np.sort(power, axis=1)[:, -2]
    own = others <= power[np.arange(len(owner)), owner] * 10.0 ** (ZIPPER_DB / 10.0)
    any_excited = excited.any(axis=1)
    if not np.all(own[any_excited]):
        return None
    lines = [np.flatnonzero(any_excited & (owner == i)) + 1 for i in range(inputs.shape[1])]
    return lines if all(line.size for line in lines) else None


def _checked_lines(lines, n_in: int, period: int) -> list[np.ndarray]:
    """`lines` as one sorted int array per input, each in ``1..period // 2``, no bin shared."""
    if len(lines) != n_in:
        raise ConfigError("lines", f"must give the bins of each of the {n_in} inputs, got {len(lines)} arrays")
    out = []
    for i, bins in enumerate(lines):
        k = np.asarray(bins)
        if k.ndim != 1 or k.size == 0 or not np.issubdtype(k.dtype, np.integer):
            raise ConfigError("lines", f"input {i}'s bins must be a non-empty 1-D array of integers, got {bins!r}")
        if k.min() < 1 or k.max() > period // 2:
            raise ConfigError("lines", f"input {i}'s bins must lie in 1..{period // 2}, got {k.min()}..{k.max()}")
        out.append(np.unique(k).astype(np.int64))
    values, counts = np.unique(np.concatenate(out), return_counts=True)
    shared = values[counts > 1]
    if shared.size:
        raise ConfigError("lines", f"each bin must belong to one input; {shared.size} are shared, first {shared[0]}")
    return out


def _period_lines(x: np.ndarray, period: int, skip: int, n_periods: int, bins: np.ndarray) -> np.ndarray:
    """DFT of each whole period of every column of `x` at `bins`: shape (n_periods, len(bins), columns).

    A block of periods (about :data:`BLOCK_SAMPLES` values) is transformed at a
    time, so only the lines asked for are ever kept.
    """
    n_channels = x.shape[1]
    per_block = max(1, BLOCK_SAMPLES // (period * n_channels))
    out = np.empty((n_periods, bins.size, n_channels), dtype=np.complex128)
    for first in range(0, n_periods, per_block):
        last = min(first + per_block, n_periods)
        block = x[(skip + first) * period : (skip + last) * period].reshape(last - first, period, n_channels)
        out[first:last] = np.fft.rfft(block, axis=1)[:, bins, :]
    return out


def _zipper_warnings(U: np.ndarray, owner: np.ndarray) -> tuple[str, ...]:
    """Warnings where an input has power at another input's lines (the signals are not zippered as told)."""
    power = np.abs(U.mean(axis=0)) ** 2  # (bins, n_in): periodic power of each input at each line
    own = power[np.arange(owner.size), owner]
    warnings = []
    for i in range(U.shape[2]):
        others = owner != i
        leaking = power[others, i] > ZIPPER_LEAKAGE * own[others]
        if leaking.any():
            warnings.append(
                f"input {i} has power at {int(leaking.sum())} of the other inputs' lines (above -60 dB of the input "
                "each line belongs to): the signals are not zippered as `lines` says, and the responses there are "
                "biased"
            )
    return tuple(warnings)


def _spread_over_inputs(
    frequency_hz: np.ndarray, values: np.ndarray, owner: np.ndarray, n_in: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per input, the values at its own lines and linear interpolation (real, imaginary parts) at the others.

    `values` (bins, n_out) holds each line's response to the input that owns
    it; returns the response (bins, n_out, n_in) and the mask (bins, n_in) of
    the measured entries. Beyond an input's first and last line its values
    are held constant (``np.interp``).
    """
    response = np.empty((*values.shape, n_in), dtype=np.complex128)
    measured = owner[:, None] == np.arange(n_in)
    for i in range(n_in):
        own = measured[:, i]
        for j in range(values.shape[1]):
            known = values[own, j]
            response[:, j, i] = np.interp(frequency_hz, frequency_hz[own], known.real) + 1j * np.interp(
                frequency_hz, frequency_hz[own], known.imag
            )
    return response, measured


def _period_statistics(U_own: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Response ``mean Y / mean U``, the std of its parts and the period-scatter coherence, per line and output.

    ``U_own`` (periods, bins) is each line's owning input, ``Y`` (periods,
    bins, n_out) the outputs. The std is the standard error of the mean of
    the per-period ratios ``Y_m / U_m``, per real (= imaginary) part; the
    coherence ``1 - s_Y^2 / mean |Y_m|^2`` with ``s_Y^2`` the sample variance
    of ``Y_m`` over the periods. Both are NaN with one period.
    """
    n_periods = Y.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        response = Y.mean(axis=0) / U_own.mean(axis=0)[:, None]
        ratios = Y / U_own[:, :, None]
    response = np.where(np.isfinite(response), response, np.nan)
    if n_periods < 2:
        nan = np.full(response.shape, np.nan)
        return response, nan, nan.copy()
    scatter = np.sum(np.abs(ratios - ratios.mean(axis=0)) ** 2, axis=0) / (n_periods - 1)
    std = np.sqrt(scatter / n_periods / 2.0)
    noise = np.sum(np.abs(Y - Y.mean(axis=0)) ** 2, axis=0) / (n_periods - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        coherence = 1.0 - noise / np.mean(np.abs(Y) ** 2, axis=0)
    return response, std, np.where(np.isfinite(coherence), np.clip(coherence, 0.0, 1.0), np.nan)


def periodic_mimo_frf(
    inputs: ArrayLike,
    outputs: ArrayLike,
    period_samples: int,
    sample_rate_hz: float,
    lines,
    skip_periods: int = 1,
) -> MimoResponse:
    """Multiple-input response from a periodic excitation in which every input owns its own DFT bins.

    The record is cut into whole periods; the first `skip_periods` are
    dropped (transient), the rest transformed without a window (no leakage
    in steady state). At the bins input ``i`` excites alone (see
    :func:`zippered_multisine`) ``H[:, j, i] = mean_m Y_j,m / mean_m U_i,m``.
    The result lies on the union of all inputs' bins: each element is measured
    at its own input's bins and linearly interpolated (real and imaginary
    parts, in frequency) at the others; :attr:`MimoResponse.measured` tells
    which. Interpolation is only as good as the response is smooth on the
    scale of ``n_in`` bins: use more bins per resonance (a longer period)
    where it is not.

    * ``std``: the standard error of the mean of the per-period ratios
      ``Y_j,m / U_i,m`` (per real, equal imaginary, part) at measured
      entries; NaN at interpolated ones (their interpolation error is unknown)
      and with a single period.
    * ``multiple_coherence``: ``1 - s_Y^2 / mean_m |Y_j,m|^2`` at each line,
      ``s_Y^2`` the variance of the output's line over the periods. With the
      excitation repeated exactly the periodic part is what the inputs
      explain and the scatter is noise, so this is the periodic analogue of
      the fraction of output power explained (cf. the coherence of
      :func:`~hilident.ident.frequency.periodic_frf`). NaN with one period.
    * ``input_condition``: NaN (no matrix is inverted).

    A warning is added when an input has power at another input's bins (more
    than -60 dB of that input's): the signals are then not zippered as
    `lines` says.

    Parameters
    ----------
    inputs : array_like, shape (N, n_in) or (N,)
        Measured inputs, one column each.
    outputs : array_like, shape (N, n_out) or (N,)
        Measured outputs.
    period_samples : int
        Samples per excitation period.
    sample_rate_hz : float
        Sample rate, Hz.
    lines : sequence of array_like of int
        ``lines[i]``: the DFT bins (``1 .. period_samples // 2``) input ``i``
        excites, e.g. the second value returned by :func:`zippered_multisine`.
        No bin may belong to two inputs.
    skip_periods : int
        Leading periods to drop.

    Returns
    -------
    MimoResponse
        ``method="periodic"``, ``n_averages`` = periods used.
    """
    fs = _check_rate(sample_rate_hz)
    u_columns, y_columns = _checked_channels(inputs, outputs)
    u, y = np.column_stack(u_columns), np.column_stack(y_columns)
    period = _positive_int(period_samples, "period_samples", 4)
    skip = _positive_int(skip_periods, "skip_periods", 0)
    n_in = u.shape[1]
    per_input = _checked_lines(lines, n_in, period)
    n_periods = u.shape[0] // period - skip
    if n_periods < 1:
        raise DataError(f"{u.shape[0]} samples hold {u.shape[0] // period} periods of {period}; {skip} are skipped")
    bins = np.concatenate(per_input)
    owner = np.concatenate([np.full(k.size, i) for i, k in enumerate(per_input)])
    order = np.argsort(bins)
    bins, owner = bins[order], owner[order]
    U = _period_lines(u, period, skip, n_periods, bins)
    Y = _period_lines(y, period, skip, n_periods, bins)
    response, std, coherence = _period_statistics(U[:, np.arange(bins.size), owner], Y)
    frequency_hz = bins * fs / period
    full_response, measured = _spread_over_inputs(frequency_hz, response, owner, n_in)
    full_std = np.where(measured[:, None, :], std[:, :, None], np.nan)
    return MimoResponse(
        frequency_hz=frequency_hz,
        response=full_response,
        multiple_coherence=coherence,
        std=full_std,
        input_condition=np.full(bins.size, np.nan),
        n_averages=n_periods,
        method="periodic",
        warnings=_zipper_warnings(U, owner),
        measured=measured,
    )


# --- periodic excitation: orthogonal multisines ----------------------------------------------------------------


def orthogonal_multisine(
    n_inputs: int,
    period_samples: int,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    rms: float = 1.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """``n_inputs`` experiments ("blocks") in which every input excites every bin of the band, in orthogonal patterns.

    One random-phase multisine ``X(k)`` (flat amplitude) is applied to all
    inputs, in block ``b`` to input ``i`` as ``T[b, i] X(k)`` with the unitary
    pattern ``T[b, i] = exp(-2 pi j b i / n_inputs)`` (the DFT matrix; for two
    inputs the Hadamard signs ``[[1, 1], [1, -1]]``). The inputs' spectra over
    the blocks then form ``X(k) T``, as well conditioned as can be at every
    bin, and :func:`orthogonal_mimo_frf` measures every element at every bin
    (Pintelon & Schoukens, orthogonal multisines) -- at the cost of
    ``n_inputs`` experiments instead of one.

    Parameters
    ----------
    n_inputs, period_samples, sample_rate_hz, band_hz, rms, seed
        As for :func:`zippered_multisine`; every column of every block has
        the given rms.

    Returns
    -------
    signals : ndarray, shape (n_inputs, period_samples, n_inputs)
        ``signals[b]``: one period of every input in block ``b``; each block
        is played (repeated, ``np.tile``) as an experiment of its own.
    bins : ndarray of int
        The DFT bins excited, ascending.
    """
    n = _positive_int(n_inputs, "n_inputs", 1)
    period = _positive_int(period_samples, "period_samples", 4)
    fs = _check_rate(sample_rate_hz)
    if not np.isfinite(rms) or rms <= 0.0:
        raise ConfigError("rms", f"must be a positive number, got {rms!r}")
    bins = _band_bins(period, fs, band_hz)
    if bins.size == 0:
        raise ConfigError("band_hz", f"{band_hz!r} holds no bin of {fs / period:g} Hz")
    base = np.zeros(period // 2 + 1, dtype=np.complex128)
    base[bins] = np.exp(1j * np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, bins.size))
    pattern = np.exp(-2j * np.pi * np.outer(np.arange(n), np.arange(n)) / n)
    signals = np.fft.irfft(pattern[:, None, :] * base[None, :, None], n=period, axis=1)
    signals *= rms / np.sqrt(np.mean(signals**2, axis=1, keepdims=True))
    return signals, bins


def _block_solve(U: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``H = Y U^H (U U^H)^-1`` over the blocks per line: ``U`` (blocks, lines, n_in), ``Y`` (blocks, lines, n_out).

    Returns ``h[:, i, j] = H_ji`` and the input condition, by
    :func:`_input_solve` on the block sums ``sum_b conj(U_b) U_b^T`` and
    ``sum_b conj(U_b) Y_b^T`` (the same normal equations as H1's).
    """
    s_uu = np.einsum("blk,bli->lki", np.conj(U), U)
    s_uy = np.einsum("blk,blj->lkj", np.conj(U), Y)
    h, condition, _ = _input_solve(s_uu, s_uy)
    return h, condition


def _block_records(inputs, outputs) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each block's inputs (N_b, n_in) and outputs (N_b, n_out), validated, the same channels in every block."""
    if len(inputs) != len(outputs) or len(inputs) == 0:
        raise DataError(f"inputs and outputs must hold the same number of blocks, got {len(inputs)} and {len(outputs)}")
    u_blocks, y_blocks = [], []
    for u_b, y_b in zip(inputs, outputs, strict=True):
        u_columns, y_columns = _checked_channels(u_b, y_b)
        u_blocks.append(np.column_stack(u_columns))
        y_blocks.append(np.column_stack(y_columns))
    shapes = {(u.shape[1], y.shape[1]) for u, y in zip(u_blocks, y_blocks, strict=True)}
    if len(shapes) > 1:
        raise DataError(f"every block must have the same inputs and outputs, got (n_in, n_out) of {sorted(shapes)}")
    n_in = u_blocks[0].shape[1]
    if len(u_blocks) < n_in:
        raise DataError(f"{n_in} inputs need at least {n_in} blocks (experiments), got {len(u_blocks)}")
    return u_blocks, y_blocks


def orthogonal_mimo_frf(
    inputs,
    outputs,
    period_samples: int,
    sample_rate_hz: float,
    bins: ArrayLike,
    skip_periods: int = 1,
) -> MimoResponse:
    """Multiple-input response from several periodic experiments ("blocks"), e.g. of :func:`orthogonal_multisine`.

    Each block's record is cut into whole periods, the first `skip_periods`
    dropped (each block starts its own transient), the rest transformed
    without a window and averaged: ``U_b(k)`` (n_in) and ``Y_b(k)`` (n_out).
    Over the ``B >= n_in`` blocks ``Y = H U`` per bin, solved as
    ``H = Y U^H (U U^H)^-1`` (exactly ``Y U^-1`` for ``B = n_in``) with the
    measured inputs, so the pattern need not be played exactly. Every
    element is measured at every bin (``measured`` all True).

    * ``std``: the standard error of the mean of the per-period solutions
      ``H_m`` (period ``m`` of every block), per real (= imaginary) part; NaN
      with one period.
    * ``multiple_coherence``: ``1 - sum_b s_Yb^2 / sum_b mean_m |Y_b,m|^2``,
      the scatter of the output over the periods against its power, as for
      :func:`periodic_mimo_frf`; NaN with one period.
    * ``input_condition``: of ``U U^H`` scaled to unit diagonal, 1 for an
      orthogonal pattern; ``inf`` (and NaN response) where singular.

    Parameters
    ----------
    inputs : sequence of array_like, each (N_b, n_in)
        The measured inputs of each block.
    outputs : sequence of array_like, each (N_b, n_out)
        The measured outputs of each block.
    period_samples : int
        Samples per period.
    sample_rate_hz : float
        Sample rate, Hz.
    bins : array_like of int
        The DFT bins (``1 .. period_samples // 2``) to read, e.g. the second
        value returned by :func:`orthogonal_multisine`.
    skip_periods : int
        Leading periods of each block to drop.

    Returns
    -------
    MimoResponse
        ``method="orthogonal"``, ``n_averages`` = periods used per block (the
        fewest any block has).
    """
    fs = _check_rate(sample_rate_hz)
    period = _positive_int(period_samples, "period_samples", 4)
    skip = _positive_int(skip_periods, "skip_periods", 0)
    u_blocks, y_blocks = _block_records(inputs, outputs)
    k = _checked_lines([bins], 1, period)[0]
    n_periods = min(u.shape[0] // period for u in u_blocks) - skip
    if n_periods < 1:
        raise DataError(f"the shortest block holds {n_periods + skip} periods of {period}; {skip} are skipped")
    U = np.stack([_period_lines(u, period, skip, n_periods, k) for u in u_blocks])  # (blocks, periods, bins, n_in)
    Y = np.stack([_period_lines(y, period, skip, n_periods, k) for y in y_blocks])
    h, condition = _block_solve(U.mean(axis=1), Y.mean(axis=1))
    std = np.full(h.shape, np.nan)
    coherence = np.full((k.size, Y.shape[3]), np.nan)
    if n_periods > 1:
        n_blocks, n_in, n_out = U.shape[0], U.shape[3], Y.shape[3]
        per_period = _block_solve(U.reshape(n_blocks, -1, n_in), Y.reshape(n_blocks, -1, n_out))[0]
        per_period = per_period.reshape(n_periods, k.size, n_in, n_out)
        scatter = np.sum(np.abs(per_period - per_period.mean(axis=0)) ** 2, axis=0) / (n_periods - 1)
        std = np.sqrt(scatter / n_periods / 2.0)
        noise = np.sum(np.abs(Y - Y.mean(axis=1, keepdims=True)) ** 2, axis=(0, 1)) / (n_periods - 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            coherence = 1.0 - noise / np.sum(np.mean(np.abs(Y) ** 2, axis=1), axis=0)
        coherence = np.where(np.isfinite(coherence), np.clip(coherence, 0.0, 1.0), np.nan)
    return MimoResponse(
        frequency_hz=k * fs / period,
        response=np.swapaxes(h, 1, 2),
        multiple_coherence=coherence,
        std=np.swapaxes(std, 1, 2),
        input_condition=condition,
        n_averages=n_periods,
        method="orthogonal",
    )
