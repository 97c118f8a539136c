"""``hilident identify`` of a record with several inputs and outputs (``[data] inputs``, ``outputs``).

Every output is estimated against every input at once (:func:`hilident.ident.mimo.mimo_h1`): the inputs that
act together are no noise to each other, as they are to a single-input estimate. The part of ``summary.json``
this gives (``mimo``) holds, per output, the multiple coherence over the band; the input matrix's condition
(correlated inputs cannot be told apart) and, per element, the response's peak; the peaks of the complex
mode indicator function (the first singular value of ``H`` at each line, Shih et al. 1988), where the modes
every output sees stand out; and the modes from all outputs and inputs at once
(:func:`hilident.ident.mimo.modal_analysis`: polyreference LSCF over model orders, the poles stable over the
highest ones, LSFD shapes), each with its frequency, damping, their spread over the orders, its shape over
the outputs and its participation from the inputs, and the MAC between the modes' shapes.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from hilident.config.tables import Config
from hilident.errors import DataError
from hilident.ident.mimo import MimoResponse, Mode, mimo_h1, modal_analysis, periodic_mimo_frf, zippered_lines
from hilident.ident.mimo.modal import merge_split_modes

__all__ = ["identify_channels", "mode_indicator_peaks"]

#: Fewest Welch segments averaged per input: fewer leave the multiple coherence and the spread meaningless.
MIN_AVERAGES_PER_INPUT = 4
#: A mode indicator peak must stand this far above its surroundings (prominence), dB.
PEAK_PROMINENCE_DB = 6.0
#: Model orders of the modal estimate: order ``p`` of an ``n_in``-input model has ``p n_in`` poles.
MODAL_ORDERS = range(2, 33)


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
        The record is too short for the Welch segments ``[identification] segment_s`` asks.
    """
    d, ic = cfg.data, cfg.identification
    u, y, fs = np.asarray(inputs, dtype=float), np.asarray(outputs, dtype=float), float(sample_rate_hz)
    lines = zippered_lines(u, period_samples) if period_samples else None
    if lines is not None:
        assert period_samples is not None
        periods = len(u) // period_samples
        frf = periodic_mimo_frf(u, y, period_samples, fs, lines, skip_periods=1 if periods >= 3 else 0)
        resolution = fs / period_samples
        band = (ic.f_min_hz or float(frf.frequency_hz[0]), ic.f_max_hz or float(frf.frequency_hz[-1]))
    else:
        segment = int(round(ic.segment_s * fs))
        if len(u) < segment * (MIN_AVERAGES_PER_INPUT * u.shape[1] + 1) // 2:
            raise DataError(
                f"{source}: {len(u)} samples hold fewer than {MIN_AVERAGES_PER_INPUT} Welch segments of "
                f"identification.segment_s = {ic.segment_s:g} s per input: shorten it or record longer"
            )
        frf = mimo_h1(u, y, fs, segment)
        resolution = fs / segment
        band = (ic.f_min_hz or 2.0 * resolution, ic.f_max_hz or 0.45 * fs)
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
        **_modal_part(frf, band),
        "warnings": list(frf.warnings),
    }
    return part, frf


def _modal_part(frf: MimoResponse, band: tuple[float, float]) -> dict:
    """``modes``, ``mode_mac`` and ``modal_notes`` of the modal estimate (weighted by each element's spread)."""
    try:
        result = merge_split_modes(modal_analysis(frf, band, MODAL_ORDERS, weights=_modal_weights(frf)))
    except (DataError, np.linalg.LinAlgError) as exc:  # too few lines for the orders, a singular fit
        return {"modes": [], "mode_mac": [], "modal_notes": [f"no modal estimate: {exc}"]}
    return {
        "modes": [_mode_record(m) for m in result.modes],
        "mode_mac": np.round(result.mac, 4).tolist() if result.modes else [],
        "modal_notes": list(result.notes),
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


def _mode_record(m: Mode) -> dict:
    return {
        "frequency_hz": m.frequency_hz,
        "damping_ratio": m.damping,
        "frequency_range_hz": list(m.frequency_ci_hz),
        "damping_range": list(m.damping_ci),
        "shape_magnitude": np.abs(m.shape).tolist(),
        "shape_phase_deg": np.degrees(np.angle(m.shape)).tolist(),
        "participation_magnitude": np.abs(m.participation).tolist(),
        "stable_orders": m.n_stable,
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
