"""``hilident identify`` of a record with several inputs and outputs (``[data] inputs``, ``outputs``).

Every output is estimated against every input at once (:func:`hilident.ident.mimo.mimo_h1`): the inputs that
act together are no noise to each other, as they are to a single-input estimate. The part of ``summary.json``
this gives (``mimo``) holds, per output, the multiple coherence over the band; the input matrix's condition
(correlated inputs cannot be told apart) and, per element, the response's peak; and the peaks of the complex
mode indicator function (the first singular value of ``H`` at each line, Shih et al. 1988), where the modes
every output sees stand out.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from hilident.config.tables import Config
from hilident.errors import DataError
from hilident.ident.mimo import MimoResponse, mimo_h1

__all__ = ["identify_channels", "mode_indicator_peaks"]

#: Fewest Welch segments averaged per input: fewer leave the multiple coherence and the spread meaningless.
MIN_AVERAGES_PER_INPUT = 4
#: A mode indicator peak must stand this far above its surroundings (prominence), dB.
PEAK_PROMINENCE_DB = 6.0


def identify_channels(
    inputs: np.ndarray, outputs: np.ndarray, sample_rate_hz: float, cfg: Config, source: str = ""
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

    Raises
    ------
    DataError
        The record is too short for the Welch segments ``[identification] segment_s`` asks.
    """
    d, ic = cfg.data, cfg.identification
    u, y, fs = np.asarray(inputs, dtype=float), np.asarray(outputs, dtype=float), float(sample_rate_hz)
    segment = int(round(ic.segment_s * fs))
    if len(u) < segment * (MIN_AVERAGES_PER_INPUT * u.shape[1] + 1) // 2:
        raise DataError(
            f"{source}: {len(u)} samples hold fewer than {MIN_AVERAGES_PER_INPUT} Welch segments of "
            f"identification.segment_s = {ic.segment_s:g} s per input: shorten it or record longer"
        )
    frf = mimo_h1(u, y, fs, segment)
    band = (ic.f_min_hz or 2.0 * fs / segment, ic.f_max_hz or 0.45 * fs)
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
        "resolution_hz": fs / segment,
        "band_hz": list(band),
        "multiple_coherence_median": [_median(frf.multiple_coherence[in_band, j]) for j in range(len(d.outputs))],
        "input_condition_median": _median(frf.input_condition[in_band]),
        "elements": _element_peaks(frf, in_band, d.inputs, d.outputs),
        "indicator_peaks": mode_indicator_peaks(frf, in_band),
        "warnings": list(frf.warnings),
    }
    return part, frf


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
