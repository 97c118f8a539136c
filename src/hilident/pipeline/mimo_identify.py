"""``hilident identify`` of a record with several inputs and outputs (``[data] inputs``, ``outputs``).

Every output is estimated against every input at once (:func:`hilident.ident.mimo.mimo_h1`): the inputs that
act together are no noise to each other, as they are to a single-input estimate. The part of ``summary.json``
this gives (``mimo``) holds, per output, the multiple coherence over the band; the input matrix's condition
(correlated inputs cannot be told apart) and, per element, the response's peak; the peaks of the complex
mode indicator function (the first singular value of ``H`` at each line, Shih et al. 1988), where the modes
every output sees stand out; and the modes from all outputs and inputs at once
(:func:`hilident.ident.mimo.modal_analysis`: polyreference LSCF over model orders, the poles stable over the
highest ones, LSFD shapes), each with its frequency, damping, their spread over the orders, its shape over
the outputs and its participation from the inputs, and the MAC between the modes' shapes; each mode's 95 %
intervals of frequency and damping (:func:`hilident.ident.mimo.modal_intervals`, from independent groups of
the record, :func:`_interval_groups`) and the stabilisation diagram (``stabilisation``).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
from scipy import signal

from hilident.config.tables import Config, IdentificationConfig
from hilident.errors import ConfigError, DataError
from hilident.ident.mimo import (
    MimoResponse,
    Mode,
    leave_one_out_h1,
    mimo_h1,
    modal_analysis,
    periodic_mimo_frf,
    zippered_lines,
)
from hilident.ident.mimo.modal import ModalResult, lsfd, merge_split_modes, modal_intervals
from hilident.ident.preprocess import remove_drift
from hilident.numbers import finite_or_none

__all__ = [
    "ChannelEstimate",
    "Groups",
    "estimate_channels",
    "identify_channels",
    "interval_blocks",
    "mode_indicator_peaks",
]

#: Fewest Welch segments averaged per input: fewer leave the multiple coherence and the spread meaningless.
MIN_AVERAGES_PER_INPUT = 4
#: Shortest Welch segment, samples, a record may be read with.
MIN_SEGMENT = 64
#: A mode indicator peak must stand this far above its surroundings (prominence), dB.
PEAK_PROMINENCE_DB = 6.0
#: Model orders of the modal estimate: order ``p`` of an ``n_in``-input model has ``p n_in`` poles. A structure
#: with a dozen lightly damped modes in the band gives some of them a stable pole only above order 40 (the rest
#: model the noise and the window's leakage); every order shares one pass over the lines, so the highest costs
#: little more than the lowest.
MODAL_ORDERS = range(2, 65)
#: Relative change of a pole's damping between neighbouring orders still called stable. Looser than the
#: frequency's (1 %): a mode whose half-power band spans about one line has its damping resolved only to some
#: 10 % by the lines (and widened by the window), and a 5 % criterion leaves such modes never stable.
STABLE_DAMPING = 0.1
#: The modes' 95 % intervals: the record is split into at most this many independent groups ...
INTERVAL_GROUPS = 8
#: ... of at least this many Welch segments per input each (or one period or more each) ...
GROUP_AVERAGES_PER_INPUT = 3
#: ... and the modes have no interval when fewer groups than this fit in the record.
MIN_INTERVAL_GROUPS = 4


def identify_channels(
    inputs: np.ndarray,
    outputs: np.ndarray,
    sample_rate_hz: float,
    cfg: Config,
    source: str = "",
    period_samples: int | None = None,
) -> tuple[dict, MimoResponse]:
    """The ``mimo`` part of the summary for the record mapped by ``cfg.data``, and its estimate.

    Parameters
    ----------
    inputs, outputs : ndarray, shape (N, n_in) and (N, n_out)
        The columns of ``data.inputs`` and ``data.outputs``, scaled to SI units.
    sample_rate_hz : float
    cfg : Config
        Its ``[data]`` names the channels; ``[identification]`` gives the Welch segment and the band.
    source : str
        The data file, for messages.
    period_samples : int, optional
        The excitation's period when the record is whole periods of it: where every input excites its own
        lines (a zippered multisine, :func:`hilident.ident.mimo.zippered_lines`), each element is read at its
        input's lines with no window (:func:`hilident.ident.mimo.periodic_mimo_frf`); else the Welch estimate.
    Raises
    ------
    DataError
        The record is too short for even the shortest Welch segments (:func:`welch_segment`).
    """
    d, ic = cfg.data, cfg.identification
    est = estimate_channels(inputs, outputs, sample_rate_hz, ic, source, period_samples)
    u, y, fs, frf, band, segment, lines = est.u, est.y, est.fs, est.response, est.band_hz, est.segment, est.lines
    notes, resolution = est.notes, est.resolution_hz
    in_band = (frf.frequency_hz >= band[0]) & (frf.frequency_hz <= band[1])
    units = d.output_units or [""] * len(d.outputs)
    part = {
        "inputs": [
            {"column": c, "scale": s} for c, s in zip(d.inputs, d.input_scales or [1.0] * len(d.inputs), strict=True)
        ],
        "outputs": [
            {"column": c, "scale": s, "unit": unit}
            for c, s, unit in zip(d.outputs, d.output_scales or [1.0] * len(d.outputs), units, strict=True)
        ],
        "method": frf.method,
        "n_averages": frf.n_averages,
        "resolution_hz": resolution,
        "band_hz": list(band),
        "multiple_coherence_median": [_median(frf.multiple_coherence[in_band, j]) for j in range(len(d.outputs))],
        "input_condition_median": _median(frf.input_condition[in_band]),
        "elements": _element_peaks(frf, in_band, d.inputs, d.outputs),
        "indicator_peaks": mode_indicator_peaks(frf, in_band),
        **_modal_part(frf, band, _groups_or_none(u, y, fs, frf, segment, period_samples, lines)),
        "warnings": notes + list(frf.warnings),
    }
    return part, frf


@dataclasses.dataclass
class ChannelEstimate:
    """The response matrix of a record of several inputs and outputs, and how it was read.

    Attributes
    ----------
    response : MimoResponse
    u, y : ndarray
        The inputs and outputs as analysed (a periodic record's drift removed).
    fs, resolution_hz : float
        Sample rate and line spacing, Hz.
    band_hz : (float, float)
        The band the figures are taken over, Hz.
    segment : int
        The Welch segment, samples (``identification.segment_s`` for a periodic record, whose response needs none).
    lines : list or None
        Each input's own lines of a zippered record; None for the Welch estimate.
    notes : list of str
    """

    response: MimoResponse
    u: np.ndarray
    y: np.ndarray
    fs: float
    resolution_hz: float
    band_hz: tuple[float, float]
    segment: int
    lines: list | None
    notes: list[str]


def estimate_channels(
    inputs: np.ndarray,
    outputs: np.ndarray,
    sample_rate_hz: float,
    ic: IdentificationConfig,
    source: str = "",
    period_samples: int | None = None,
    lines: list | None = None,
) -> ChannelEstimate:
    """The response matrix alone of :func:`identify_channels` (no modal fit): periodic at each input's own
    lines for whole periods of a zippered multisine, else the Welch H1 estimate.

    ``ic`` is ``[identification]`` (``segment_s``, ``f_min_hz``, ``f_max_hz``). ``lines``: each input's own bins
    as the excitation was designed, read whatever the recorded inputs show (a set-point a drive held leaks a little
    onto other lines, which the detection from the record refuses); default: found in the record
    (:func:`hilident.ident.mimo.zippered_lines`).
    """
    notes: list[str] = []
    segment = int(round(ic.segment_s * sample_rate_hz))
    u, y, fs = np.asarray(inputs, dtype=float), np.asarray(outputs, dtype=float), float(sample_rate_hz)
    if not period_samples:
        lines = None
    elif lines is None:
        lines = zippered_lines(u, period_samples)
    if lines is not None:
        assert period_samples is not None
        periods = len(u) // period_samples
        # a drift no excitation line holds (an integrating output, a position, under a load that changes) leaks
        # onto every line of an unwindowed period: removed first, sparing the periodic response
        u, y = (np.column_stack([remove_drift(c, period_samples) for c in x.T]) for x in (u, y))
        frf = periodic_mimo_frf(u, y, period_samples, fs, lines, skip_periods=1 if periods >= 3 else 0)
        resolution = fs / period_samples
        band = (ic.f_min_hz or float(frf.frequency_hz[0]), ic.f_max_hz or float(frf.frequency_hz[-1]))
    else:
        segment, shortened = welch_segment(len(u), u.shape[1], fs, ic.segment_s, source)
        if shortened:
            notes.append(shortened)
        frf = mimo_h1(u, y, fs, segment)
        resolution = fs / segment
        band = (ic.f_min_hz or 2.0 * resolution, ic.f_max_hz or 0.45 * fs)
    return ChannelEstimate(frf, u, y, fs, resolution, band, segment, lines, notes)


def welch_segment(n: int, n_in: int, sample_rate_hz: float, segment_s: float, source: str = "") -> tuple[int, str]:
    """The Welch segment (samples) for ``n`` samples of ``n_in`` inputs, and why it is not ``segment_s``.

    ``identification.segment_s`` when the record holds :data:`MIN_AVERAGES_PER_INPUT` segments per input with
    half overlap and it is at least :data:`MIN_SEGMENT` samples; else the longest segment that does (a record
    too short for the default, or sampled so slowly that the default is a few samples, is read, not refused),
    with a note saying so (empty when unchanged).

    Raises
    ------
    DataError
        Not even segments of :data:`MIN_SEGMENT` samples fit.
    """
    wanted = int(round(segment_s * sample_rate_hz))
    averages = MIN_AVERAGES_PER_INPUT * n_in
    if wanted >= MIN_SEGMENT and n >= wanted * (averages + 1) // 2:
        return wanted, ""
    longest = 2 * n // (averages + 1)
    if longest < MIN_SEGMENT:
        raise DataError(
            f"{source}: {n} samples hold fewer than {MIN_AVERAGES_PER_INPUT} Welch segments of {MIN_SEGMENT} "
            f"samples per input: record longer"
        )
    why = (
        f"is {wanted} samples at {sample_rate_hz:g} Hz, fewer than {MIN_SEGMENT}"
        if wanted < MIN_SEGMENT
        else f"needs {wanted * (averages + 1) // 2} samples for {MIN_AVERAGES_PER_INPUT} segments per input; the "
        f"record has {n}"
    )
    return longest, (
        f"identification.segment_s = {segment_s:g} s {why}: segments of {longest / sample_rate_hz:.4g} s used "
        f"(lines every {sample_rate_hz / longest:.3g} Hz)"
    )


def _modal_part(frf: MimoResponse, band: tuple[float, float], groups: Groups | None = None) -> dict:
    """``modes``, ``mode_mac``, ``modal_notes`` and the residual terms of the modal estimate (weighted by each
    element's spread).

    The residues and residuals are fitted once more by LSFD at the poles the modes report (their median frequency
    and damping; a merged mode's mean), so that ``pole_rad_per_s``, ``residue_real``/``residue_imag``,
    ``lower_residual`` and ``upper_residual`` are one consistent model of the response in the band.
    """
    weights = _modal_weights(frf)
    try:
        result = merge_split_modes(modal_analysis(frf, band, MODAL_ORDERS, weights=weights, damp_tol=STABLE_DAMPING))
        result = _with_intervals(result, frf, band, weights, groups or Groups([]))
        poles = np.array([_pole(m) for m in result.modes], dtype=complex)
        residues, lower, upper = lsfd(frf, band, poles, weights)
    except (DataError, np.linalg.LinAlgError) as exc:  # too few lines for the orders, a singular fit
        return {
            "modes": [],
            "mode_mac": [],
            "modal_notes": [f"no modal estimate: {exc}"],
            "lower_residual": None,
            "upper_residual": None,
        }
    return {
        "modes": [_mode_record(m, lam, r) for m, lam, r in zip(result.modes, poles, residues, strict=True)],
        "mode_mac": np.round(result.mac, 4).tolist() if result.modes else [],
        "modal_notes": list(result.notes),
        "stabilisation": _stabilisation_record(result),
        "lower_residual": lower.tolist(),
        "upper_residual": upper.tolist(),
    }


def _modal_weights(frf: MimoResponse) -> np.ndarray:
    """Each element's weight in the modal fit: ``1 / std`` where it was measured with a spread, 0 where it has
    none; for a periodic (zippered) estimate, or where no element has a spread, 1 where it was measured and 0
    where it was interpolated (another input's lines: a period's scatter is too few periods to weight by)."""
    std = frf.std
    known = np.isfinite(std) & (std > 0.0)
    if frf.method == "periodic" or not known.any():
        measured = frf.measured if frf.measured is not None else np.ones((std.shape[0], std.shape[2]), dtype=bool)
        return np.broadcast_to(measured[:, None, :], std.shape).astype(float)
    weights = np.zeros(std.shape)
    weights[known] = 1.0 / std[known]
    return weights


def _pole(m: Mode) -> complex:
    """The continuous pole of mode ``m``, rad/s: ``-zeta w_n + j w_n sqrt(1 - zeta^2)``, ``w_n = 2 pi f_n``."""
    wn = 2.0 * np.pi * m.frequency_hz
    return complex(-m.damping * wn, wn * np.sqrt(1.0 - m.damping**2))


def _mode_record(m: Mode, pole: complex, residue: np.ndarray) -> dict:
    """One mode of ``summary.json["mimo"]["modes"]``; ``pole`` (rad/s) and its LSFD ``residue`` (n_out, n_in)
    in the outputs' units per input unit, times rad/s."""
    return {
        "frequency_hz": m.frequency_hz,
        "damping_ratio": m.damping,
        "frequency_range_hz": list(m.frequency_ci_hz),
        "damping_range": list(m.damping_ci),
        "frequency_ci95_hz": finite_or_none(m.frequency_ci95_hz),
        "damping_ci95": finite_or_none(m.damping_ci95),
        "interval_groups": m.n_groups,
        "frequency_std_hz": finite_or_none(m.frequency_std_hz),
        "damping_std": finite_or_none(m.damping_std),
        "shape_magnitude": np.abs(m.shape).tolist(),
        "shape_phase_deg": np.degrees(np.angle(m.shape)).tolist(),
        "participation_magnitude": np.abs(m.participation).tolist(),
        "stable_orders": m.n_stable,
        "pole_rad_per_s": [float(pole.real), float(pole.imag)],
        "residue_real": np.real(residue).tolist(),
        "residue_imag": np.imag(residue).tolist(),
    }


def _median(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else None


def _element_peaks(frf: MimoResponse, in_band: np.ndarray, inputs: list[str], outputs: list[str]) -> list[dict]:
    """Per output and input, where the response's magnitude peaks in the band."""
    f = frf.frequency_hz[in_band]
    out = []
    for j, output in enumerate(outputs):
        for i, inp in enumerate(inputs):
            magnitude = np.abs(frf.response[in_band, j, i])
            if not np.isfinite(magnitude).any():
                continue
            k = int(np.nanargmax(magnitude))
            out.append({"output": output, "input": inp, "peak_hz": float(f[k]), "peak_magnitude": float(magnitude[k])})
    return out


def mode_indicator_peaks(frf: MimoResponse, in_band: np.ndarray) -> list[dict]:
    """Peaks of the complex mode indicator function in the band: the first singular value of ``H`` per line.

    A lightly damped mode seen by any output and driven by any input lifts the first singular value; the
    second lifts where two modes lie close. A peak is kept when it stands :data:`PEAK_PROMINENCE_DB` above
    its surroundings. Each: frequency, the first and second singular values in dB and the mean multiple
    coherence of the outputs there.
    """
    lines = np.flatnonzero(in_band & np.all(np.isfinite(frf.response), axis=(1, 2)))
    if lines.size < 3:
        return []
    singular = np.linalg.svd(frf.response[lines], compute_uv=False)  # (lines, min(n_out, n_in)), descending
    first_db = 20.0 * np.log10(np.maximum(singular[:, 0], np.finfo(float).tiny))
    peaks, _ = signal.find_peaks(first_db, prominence=PEAK_PROMINENCE_DB)
    out = []
    for k in peaks:
        line = lines[k]
        second = singular[k, 1] if singular.shape[1] > 1 else np.nan
        out.append(
            {
                "frequency_hz": float(frf.frequency_hz[line]),
                "first_singular_db": float(first_db[k]),
                "second_singular_db": float(20.0 * np.log10(second)) if np.isfinite(second) and second > 0 else None,
                "multiple_coherence": _median(frf.multiple_coherence[line]),
            }
        )
    return out


# --- the modes' intervals and stabilisation diagram ---------------------------------------------------------------


class Groups(NamedTuple):
    """Estimates of the record's response for the modes' intervals: independent groups of it, or (``jackknife``)
    the leave-one-block-out replicates of a record too short for those."""

    estimates: list[MimoResponse]
    jackknife: bool = False


def _groups_or_none(*args) -> Groups:
    """:func:`_interval_groups`, or none when a block cannot be estimated alone (an input silent in it, ...)."""
    try:
        return _interval_groups(*args)
    except (DataError, ConfigError):
        return Groups([])


def _interval_groups(
    u: np.ndarray,
    y: np.ndarray,
    fs: float,
    frf: MimoResponse,
    segment: int,
    period_samples: int | None,
    lines: list[np.ndarray] | None,
) -> Groups:
    """Up to :data:`INTERVAL_GROUPS` estimates of ``frf`` from disjoint consecutive blocks of the record, for the
    modes' intervals (:func:`hilident.ident.mimo.modal.modal_intervals`); a Welch record where fewer than
    :data:`MIN_INTERVAL_GROUPS` fit gets the jackknife's replicates instead (:func:`leave_one_out_h1`: every
    segment but one block of them, up to one segment per replicate), a periodic one none.

    Welch: blocks of at least ``GROUP_AVERAGES_PER_INPUT n_in`` segments each, estimated as the whole record with
    the same segment (the blocks share no segment, so their estimates are independent). Periodic (zippered): the
    periods after the transient the whole estimate skipped, in consecutive groups of one period or more.
    """
    if frf.method == "periodic" and period_samples and lines is not None:
        skip = 1 if len(u) // period_samples >= 3 else 0
        blocks = interval_blocks(len(u), period_samples, segment, skip_periods=skip)
        return Groups([periodic_mimo_frf(u[a:b], y[a:b], period_samples, fs, lines, skip_periods=0) for a, b in blocks])
    blocks = interval_blocks(len(u), None, segment, n_inputs=u.shape[1])
    if not blocks:
        replicates = min(INTERVAL_GROUPS, frf.n_averages)
        return Groups(leave_one_out_h1(u, y, fs, segment, replicates), jackknife=True)
    return Groups([mimo_h1(u[a:b], y[a:b], fs, segment) for a, b in blocks])


def interval_blocks(
    n: int,
    period: int | None,
    segment: int,
    n_inputs: int = 1,
    periods_per_block: int = 1,
    skip_periods: int = 0,
) -> list[tuple[int, int]]:
    """Disjoint consecutive blocks of a record of ``n`` samples, each estimated as the whole record is, for the
    modes' intervals; none when fewer than :data:`MIN_INTERVAL_GROUPS` fit.

    Whole periods of ``period`` samples after ``skip_periods`` (a transient), ``periods_per_block`` or more per
    block; else (``period`` None) blocks of at least ``GROUP_AVERAGES_PER_INPUT n_inputs`` Welch segments of
    ``segment`` samples overlapping by half. At most :data:`INTERVAL_GROUPS` blocks.
    """
    if period is not None:
        periods = n // period - skip_periods
        k = min(INTERVAL_GROUPS, periods // periods_per_block)
        if k < MIN_INTERVAL_GROUPS:
            return []
        edges = [(skip_periods + round(g * periods / k)) * period for g in range(k + 1)]
    else:
        per_group = GROUP_AVERAGES_PER_INPUT * n_inputs
        k = min(INTERVAL_GROUPS, n // max(1, segment * (per_group + 1) // 2))
        if k < MIN_INTERVAL_GROUPS:
            return []
        edges = [round(g * n / k) for g in range(k + 1)]
    return list(zip(edges[:-1], edges[1:], strict=True))


def _with_intervals(
    result: ModalResult, frf: MimoResponse, band: tuple[float, float], weights: np.ndarray, found: Groups
) -> ModalResult:
    """``result`` with the modes' 95 % intervals from ``found`` (the whole record's weights), or a note why none."""
    if not result.modes:
        return result
    groups = found.estimates
    if len(groups) < MIN_INTERVAL_GROUPS:
        note = (
            f"no 95 % intervals of the modes: the record holds fewer than {MIN_INTERVAL_GROUPS} independent groups "
            f"of {GROUP_AVERAGES_PER_INPUT} Welch segments per input (or periods): record longer"
        )
        return dataclasses.replace(result, notes=(*result.notes, note))
    try:
        with_intervals = modal_intervals(frf, groups, band, result, weights, jackknife=found.jackknife)
    except (DataError, np.linalg.LinAlgError) as exc:
        return dataclasses.replace(result, notes=(*result.notes, f"no 95 % intervals of the modes: {exc}"))
    sizes = sorted({g.n_averages for g in groups})
    unit = "period" if groups[0].method == "periodic" else "Welch segment"
    each = f"{sizes[0]}" if len(sizes) == 1 else f"{sizes[0]} to {sizes[-1]}"
    if found.jackknife:
        note = (
            f"95 % intervals of the modes: the record holds too few Welch segments for {MIN_INTERVAL_GROUPS} "
            f"independent groups, so the jackknife of {len(groups)} replicates, each fitted on {each} of its "
            f"{frf.n_averages} segments (one block left out), plus the difference from a maximum-likelihood fit of "
            "the modes"
        )
        return dataclasses.replace(with_intervals, notes=(*with_intervals.notes, note))
    note = (
        f"95 % intervals of the modes: the spread of {len(groups)} independent groups of the record ({each} "
        f"{unit}{'' if each == '1' else 's'} each), each fitted as the whole record, plus the difference from a "
        "maximum-likelihood fit of the modes"
    )
    return dataclasses.replace(with_intervals, notes=(*with_intervals.notes, note))


def _stabilisation_record(result: ModalResult) -> dict:
    """``summary.json["mimo"]["stabilisation"]``: every physical pole of every order with its label, and the
    orders the modes were selected over (the figure ``stabilisation.png`` is drawn from it)."""
    d = result.stabilisation
    return {
        "order": [int(p) for p in d.order],
        "frequency_hz": [float(f"{f:.6g}") for f in d.frequency_hz],
        "damping_ratio": [float(f"{z:.4g}") for z in d.damping],
        "label": [str(label) for label in d.label],
        "orders_used": list(result.orders_used),
    }
