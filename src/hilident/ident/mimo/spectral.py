"""Welch estimates of a system with several inputs and outputs: ``H1`` (noise on the outputs) and ``Hv`` (noise on
inputs and outputs alike), with multiple coherence, standard deviations and the input matrix's condition."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError
from hilident.ident.frequency import _check_rate, _cross_spectra, _segment_blocks, _welch_setup
from hilident.ident.mimo.response import MimoResponse, _checked_channels

__all__ = ["CORRELATED_FRACTION", "POWER_FLOOR", "SINGULAR_CONDITION", "leave_one_out_h1", "mimo_h1", "mimo_hv"]

#: Input condition number beyond which a line's input matrix is taken as singular (response NaN): the
#: averaged spectra carry rounding of about 1e-16 relative, which the solve would magnify this much.
SINGULAR_CONDITION = 1e12

#: An input "has power" at a line when its auto spectrum there is within this factor (-40 dB) of its peak.
POWER_FLOOR = 1e-4

#: Fraction of the powered lines whose input condition may exceed the limit before a correlation warning.
CORRELATED_FRACTION = 0.1


class _Spectra(NamedTuple):
    """Welch-averaged spectral matrices, ``S_ab = E[conj(A) B]`` as in :func:`_cross_spectra`."""

    frequency_hz: np.ndarray
    s_uu: np.ndarray  # (F, n_in, n_in) Hermitian, s_uu[:, k, i] = S_{u_k u_i}
    s_uy: np.ndarray  # (F, n_in, n_out), s_uy[:, k, j] = S_{u_k y_j}
    s_yy: np.ndarray  # (F, n_out) real
    n_averages: int


def _welch_spectra(
    inputs: ArrayLike,
    outputs: ArrayLike,
    fs: float,
    segment_length: int,
    overlap: float,
    window: str,
    detrend: str | bool,
) -> _Spectra:
    u, y = _checked_channels(inputs, outputs)
    n_in, n_out = len(u), len(y)
    nperseg, noverlap, n_avg = _welch_setup(u[0].size, segment_length, overlap)
    if n_avg <= n_in:
        raise ConfigError(
            "segment_length",
            f"{nperseg} samples per segment give {n_avg} averages; {n_in} inputs need more than {n_in} "
            "(shorter segments or a longer record)",
        )
    signals = {f"u{i}": x for i, x in enumerate(u)} | {f"y{j}": x for j, x in enumerate(y)}
    pairs = [(f"u{k}", f"u{i}") for k in range(n_in) for i in range(k, n_in)]
    pairs += [(f"u{k}", f"y{j}") for k in range(n_in) for j in range(n_out)]
    pairs += [(f"y{j}", f"y{j}") for j in range(n_out)]
    S = _cross_spectra(signals, pairs, nperseg, noverlap, window, detrend)
    n_f = nperseg // 2 + 1
    s_uu = np.empty((n_f, n_in, n_in), dtype=np.complex128)
    for k in range(n_in):
        for i in range(k, n_in):
            s_uu[:, k, i] = S[f"u{k}", f"u{i}"]
            s_uu[:, i, k] = np.conj(S[f"u{k}", f"u{i}"])
    s_uy = np.stack([np.stack([S[f"u{k}", f"y{j}"] for j in range(n_out)], axis=-1) for k in range(n_in)], axis=1)
    s_yy = np.stack([np.real(S[f"y{j}", f"y{j}"]) for j in range(n_out)], axis=-1)
    return _Spectra(np.fft.rfftfreq(nperseg, 1.0 / fs), s_uu, s_uy.astype(np.complex128), s_yy, n_avg)


def _input_coherence_matrix(s_uu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``S_uu`` scaled to unit diagonal, the scale ``sqrt(diag S_uu)``, and which lines have power on every input."""
    power = np.real(np.diagonal(s_uu, axis1=1, axis2=2))
    powered = np.all(power > 0.0, axis=1)
    scale = np.sqrt(np.where(powered[:, None], power, 1.0))
    return s_uu / (scale[:, :, None] * scale[:, None, :]), scale, powered


def _input_solve(s_uu: np.ndarray, s_uy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H1 as ``h[:, i, j] = (S_uu^-1 S_uy)[i, j]``, the input condition numbers and ``diag(S_uu^-1)``.

    The system is solved with ``S_uu`` scaled to unit diagonal (inputs of very
    different units or levels then cost no accuracy); lines where that matrix
    is singular (or an input has no power) give NaN and condition ``inf``.
    """
    n_f, n_in = s_uu.shape[:2]
    coherence_matrix, scale, powered = _input_coherence_matrix(s_uu)
    condition = np.full(n_f, np.inf)
    inverse_diagonal = np.full((n_f, n_in), np.nan)
    h = np.full(s_uy.shape, np.nan, dtype=np.complex128)
    if not powered.any():
        return h, condition, inverse_diagonal
    eigenvalues, eigenvectors = np.linalg.eigh(coherence_matrix[powered])
    largest, smallest = eigenvalues[:, -1], eigenvalues[:, 0]
    regular = smallest * SINGULAR_CONDITION > largest
    with np.errstate(divide="ignore"):
        condition[powered] = np.where(regular, largest / np.where(regular, smallest, 1.0), np.inf)
    lines = np.flatnonzero(powered)[regular]
    if lines.size:
        s = scale[lines][:, :, None]
        h[lines] = np.linalg.solve(coherence_matrix[lines], s_uy[lines] / s) / s
        # diag(C^-1) from C = V diag(w) V^H; diag(S_uu^-1) = diag(C^-1) / diag(S_uu)
        v, w = eigenvectors[regular], eigenvalues[regular]
        inverse_diagonal[lines] = np.sum(np.abs(v) ** 2 / w[:, None, :], axis=2) / s[:, :, 0] ** 2
    return h, condition, inverse_diagonal


def _multiple_coherence(h1: np.ndarray, s_uy: np.ndarray, s_yy: np.ndarray) -> np.ndarray:
    """``gamma2_j = (S_yu S_uu^-1 S_uy)_jj / S_yy_jj`` (Bendat & Piersol, ch. 7), from the H1 solution."""
    explained = np.real(np.sum(np.conj(s_uy) * h1, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        gamma2 = explained / s_yy
    return np.where(np.isfinite(gamma2), np.clip(gamma2, 0.0, 1.0), np.nan)


def _residual_spectrum(h: np.ndarray, spectra: _Spectra) -> np.ndarray:
    """Spectrum of the residual ``v_j = y_j - sum_i H_ji u_i`` for a fitted ``h[:, i, j] = H_ji``.

    ``S_vv = S_yy - 2 Re(h^H S_uy) + h^H S_uu h``. For the H1 solution this
    equals ``S_yy (1 - gamma2)``; written out in full it also holds for any
    other estimate (Hv).
    """
    cross = np.real(np.sum(np.conj(h) * spectra.s_uy, axis=1))
    quadratic = np.real(np.einsum("fkj,fki,fij->fj", np.conj(h), spectra.s_uu, h))
    return np.maximum(spectra.s_yy - 2.0 * cross + quadratic, 0.0)


def _hv_solution(spectra: _Spectra, condition: np.ndarray) -> np.ndarray:
    """Hv per output: the eigenvector ``[h; -1]`` of the smallest eigenvalue of ``[[S_uu, S_uy_j], [S_yu_j, S_yy_j]]``.

    In the convention ``S_ab = E[conj(A) B]`` the noise power of the combination
    ``w^T [u; y_j]`` is ``w^H S w``, least (total least squares) for the
    eigenvector of the smallest eigenvalue; scaled to end in ``-1`` it is
    ``[h; -1]``. Lines whose inputs are singular give NaN, as for H1.
    """
    n_f, n_in, n_out = spectra.s_uy.shape
    joint = np.empty((n_f, n_out, n_in + 1, n_in + 1), dtype=np.complex128)
    joint[:, :, :n_in, :n_in] = spectra.s_uu[:, None]
    joint[:, :, :n_in, n_in] = np.swapaxes(spectra.s_uy, 1, 2)
    joint[:, :, n_in, :n_in] = np.conj(np.swapaxes(spectra.s_uy, 1, 2))
    joint[:, :, n_in, n_in] = spectra.s_yy
    h = np.full((n_f, n_in, n_out), np.nan, dtype=np.complex128)
    lines = np.isfinite(condition)
    if lines.any():
        smallest = np.linalg.eigh(joint[lines])[1][..., 0]  # (lines, n_out, n_in + 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            h[lines] = np.swapaxes(-smallest[..., :n_in] / smallest[..., n_in:], 1, 2)
    return h


def _powered_lines(frequency_hz: np.ndarray, s_uu: np.ndarray) -> np.ndarray:
    """Lines other than DC at which every input is within :data:`POWER_FLOOR` of its own peak power."""
    power = np.real(np.diagonal(s_uu, axis1=1, axis2=2))
    return (frequency_hz > 0.0) & np.all(power >= POWER_FLOOR * power.max(axis=0), axis=1)


def _correlation_warnings(spectra: _Spectra, condition: np.ndarray, condition_limit: float) -> tuple[str, ...]:
    """A warning when the inputs are correlated on more than :data:`CORRELATED_FRACTION` of their band."""
    n_in = spectra.s_uu.shape[1]
    band = _powered_lines(spectra.frequency_hz, spectra.s_uu)
    if n_in < 2 or not band.any():
        return ()
    high = condition[band] > condition_limit
    if high.mean() <= CORRELATED_FRACTION:
        return ()
    coherence_matrix = _input_coherence_matrix(spectra.s_uu[band])[0]
    pair_coherence = np.mean(np.abs(coherence_matrix) ** 2, axis=0)
    pair_coherence[np.tril_indices(n_in)] = -1.0  # each pair once, not an input with itself
    k, i = np.unravel_index(np.argmax(pair_coherence), pair_coherence.shape)
    return (
        f"inputs are correlated: the input condition number exceeds {condition_limit:g} on "
        f"{100.0 * high.mean():.0f} % of the {int(band.sum())} lines where the inputs have power (median "
        f"{np.median(condition[band]):.3g}); input {k} and input {i} are the most coherent pair (mean coherence "
        f"{pair_coherence[k, i]:.3f}), and the responses to inputs that move together cannot be told apart: "
        "excite them independently",
    )


def _welch_estimate(
    inputs: ArrayLike,
    outputs: ArrayLike,
    sample_rate_hz: float,
    segment_length: int,
    overlap: float,
    window: str,
    detrend: str | bool,
    condition_limit: float,
    method: str,
) -> MimoResponse:
    fs = _check_rate(sample_rate_hz)
    if not np.isfinite(condition_limit) or condition_limit < 1.0:
        raise ConfigError("condition_limit", f"must be a number >= 1, got {condition_limit!r}")
    spectra = _welch_spectra(inputs, outputs, fs, segment_length, overlap, window, detrend)
    return _from_spectra(spectra, condition_limit, method)


def _from_spectra(spectra: _Spectra, condition_limit: float, method: str) -> MimoResponse:
    """The estimate ``method`` ("h1" or "hv") from averaged spectral matrices."""
    h1, condition, inverse_diagonal = _input_solve(spectra.s_uu, spectra.s_uy)
    h = h1 if method == "h1" else _hv_solution(spectra, condition)
    n_in = spectra.s_uu.shape[1]
    # Var(H_ji) = S_vv_j [S_uu^-1]_ii / (M - n_in) of the complex element; half of it on each part
    variance = _residual_spectrum(h, spectra)[:, None, :] * inverse_diagonal[:, :, None] / (spectra.n_averages - n_in)
    return MimoResponse(
        frequency_hz=spectra.frequency_hz,
        response=np.swapaxes(h, 1, 2),
        multiple_coherence=_multiple_coherence(h1, spectra.s_uy, spectra.s_yy),
        std=np.swapaxes(np.sqrt(variance / 2.0), 1, 2),
        input_condition=condition,
        n_averages=spectra.n_averages,
        method=method,
        warnings=_correlation_warnings(spectra, condition, condition_limit),
    )


def mimo_h1(
    inputs: ArrayLike,
    outputs: ArrayLike,
    sample_rate_hz: float,
    segment_length: int,
    overlap: float = 0.5,
    window: str = "hann",
    detrend: str | bool = "constant",
    condition_limit: float = 100.0,
) -> MimoResponse:
    """Multiple-input H1 estimate ``H = S_yu S_uu^-1`` with multiple coherence and standard deviations.

    Welch averaging as :func:`~hilident.ident.frequency.h1_estimate`: every
    input and output is cut into segments, detrended, windowed and
    transformed; the cross-spectral matrices are averaged over the ``M``
    segments. Per frequency ``H`` solves ``H S_uu = S_yu`` (no explicit
    inverse); it is unbiased by noise on the outputs, not by noise on the
    inputs (see :func:`mimo_hv`).

    * Multiple coherence (Bendat & Piersol, ch. 7):
      ``gamma2_j = (S_yu S_uu^-1 S_uy)_jj / S_yy_jj``, the fraction of output
      ``j``'s power explained linearly by all inputs together.
    * Noise on output ``j``, from the residual of the fitted response:
      ``S_vv_j = S_yy_j - 2 Re(H_j S_uy_j) + H_j S_uu H_j^H`` (which is
      ``S_yy_j (1 - gamma2_j)`` for H1).
    * Variance of an element (Pintelon & Schoukens; Bendat & Piersol,
      ch. 9): ``Var(H_ji) = S_vv_j [S_uu^-1]_ii / (M - n_in)`` of the
      complex error; ``M - n_in`` because the fit takes ``n_in`` of the ``M``
      segments' degrees of freedom from the residual. Exact for
      non-overlapping segments and Gaussian noise; with overlap the segments
      are not independent and the figure is a little optimistic.

    Parameters
    ----------
    inputs : array_like, shape (N, n_in) or (N,)
        Measured inputs (e.g. torques, N·m), one column each.
    outputs : array_like, shape (N, n_out) or (N,)
        Measured outputs (e.g. velocities, m/s), one column each.
    sample_rate_hz : float
        Sample rate, Hz.
    segment_length : int
        Samples per segment; the frequency resolution is
        ``sample_rate_hz / segment_length``. It must leave more than ``n_in``
        segments.
    overlap : float
        Fraction of a segment shared with the next one, in [0, 1).
    window : str
        Window name for ``scipy.signal.get_window``.
    detrend : {"constant", "linear", False}
        Per-segment detrending.
    condition_limit : float
        Input condition number (see :attr:`MimoResponse.input_condition`)
        above which a line counts as ill-conditioned; more than 10 % of such
        lines among those where every input has power (within 40 dB of its
        peak) give a warning naming the most coherent pair of inputs. 100
        is a coherence of about 0.96 between two inputs.

    Returns
    -------
    MimoResponse
        ``method="h1"``, ``n_averages`` = number of segments; NaN response
        where the input matrix is singular.

    Raises
    ------
    DataError
        Inputs and outputs of different lengths, bad shapes, non-finite or
        constant channels.
    ConfigError
        A bad parameter; ``segment_length`` leaving ``M <= n_in`` segments.
    """
    return _welch_estimate(
        inputs, outputs, sample_rate_hz, segment_length, overlap, window, detrend, condition_limit, "h1"
    )


def leave_one_out_h1(
    inputs: ArrayLike,
    outputs: ArrayLike,
    sample_rate_hz: float,
    segment_length: int,
    groups: int,
    overlap: float = 0.5,
    window: str = "hann",
    detrend: str | bool = "constant",
    condition_limit: float = 100.0,
) -> list[MimoResponse]:
    """The jackknife's replicates of :func:`mimo_h1`: ``groups`` estimates, each from every Welch segment of the
    record but one contiguous block of them (the blocks split the segments as evenly as they go).

    For a record too short for several independent parts: the spread of the replicates of an estimate ``theta``
    gives its standard error ``sqrt((K - 1) / K sum_k (theta_k - mean)^2)`` (B. Efron, R. Tibshirani, *An
    Introduction to the Bootstrap*, Chapman & Hall 1993, ch. 11), used by
    :func:`hilident.ident.mimo.modal_intervals` with ``jackknife=True``. Each replicate is :func:`mimo_h1` of the
    segments it keeps (same segments, window and detrending as the whole record's).

    Parameters
    ----------
    inputs, outputs, sample_rate_hz, segment_length, overlap, window, detrend, condition_limit
        As for :func:`mimo_h1`.
    groups : int
        Number of replicates ``K``, at least 2 and at most the number of segments; every replicate must keep
        more segments than there are inputs.

    Returns
    -------
    list of MimoResponse
        ``K`` estimates on the whole record's lines.

    Raises
    ------
    ConfigError
        ``groups`` out of range, or a replicate left with no more segments than inputs.
    """
    fs = _check_rate(sample_rate_hz)
    u, y = _checked_channels(inputs, outputs)
    nperseg, noverlap, n_avg = _welch_setup(u[0].size, segment_length, overlap)
    if int(groups) != groups or not 2 <= groups <= n_avg or n_avg - -(-n_avg // int(groups)) <= len(u):
        raise ConfigError(
            "groups", f"must leave more than {len(u)} of the {n_avg} segments in each of 2 or more, got {groups!r}"
        )
    signals = {f"u{i}": x for i, x in enumerate(u)} | {f"y{j}": x for j, x in enumerate(y)}
    parts: dict[str, list[np.ndarray]] = {name: [] for name in signals}
    for _, ffts in _segment_blocks(signals, nperseg, noverlap, window, detrend):
        for name, x in ffts.items():
            parts[name].append(x)
    big_u = np.stack([np.concatenate(parts[f"u{i}"]) for i in range(len(u))], axis=-1)  # (M, F, n_in)
    big_y = np.stack([np.concatenate(parts[f"y{j}"]) for j in range(len(y))], axis=-1)  # (M, F, n_out)
    s_uu = np.conj(big_u)[..., :, None] * big_u[..., None, :]  # per segment: conj(U_k) U_i
    s_uy = np.conj(big_u)[..., :, None] * big_y[..., None, :]
    s_yy = big_y.real**2 + big_y.imag**2
    frequency = np.fft.rfftfreq(nperseg, 1.0 / fs)
    edges = np.round(np.linspace(0, n_avg, int(groups) + 1)).astype(int)
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        keep = np.r_[0:a, b:n_avg]
        spectra = _Spectra(frequency, s_uu[keep].mean(0), s_uy[keep].mean(0), s_yy[keep].mean(0), keep.size)
        out.append(_from_spectra(spectra, condition_limit, "h1"))
    return out


def mimo_hv(
    inputs: ArrayLike,
    outputs: ArrayLike,
    sample_rate_hz: float,
    segment_length: int,
    overlap: float = 0.5,
    window: str = "hann",
    detrend: str | bool = "constant",
    condition_limit: float = 100.0,
) -> MimoResponse:
    """Multiple-input Hv (total least squares) estimate, for noise on the inputs as well as the outputs.

    Per frequency and output ``j`` the response row ``h`` is read from the
    eigenvector of the smallest eigenvalue of the Hermitian matrix
    ``[[S_uu, S_uy_j], [S_y_j u, S_yy_jj]]``, which is ``[h; -1]`` up to scale:
    the linear relation between inputs and output that leaves the least noise
    when every channel is allowed an error (Pintelon & Schoukens,
    "Hv"). H1 is biased low by noise on the measured inputs (by
    ``S_uu / (S_uu + S_nn)`` for one input); Hv is not, provided the noise
    spectra of the inputs and of the output are equal in the units given
    -- the classic assumption of Hv. Scale the channels so beforehand when
    their noise levels differ.

    The multiple coherence is that of H1 (a property of the spectra, not of
    the estimator). The standard deviation uses the H1 formula of
    :func:`mimo_h1` with the residual noise of the Hv fit: a fair measure of
    the random error, which ignores the errors in the inputs.

    Parameters
    ----------
    inputs, outputs, sample_rate_hz, segment_length, overlap, window, detrend, condition_limit
        As for :func:`mimo_h1`.

    Returns
    -------
    MimoResponse
        ``method="hv"``.
    """
    return _welch_estimate(
        inputs, outputs, sample_rate_hz, segment_length, overlap, window, detrend, condition_limit, "hv"
    )
