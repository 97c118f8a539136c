"""How far one run's measurement can be trusted: uncertainty, resolution, input spectrum and sampling."""

from __future__ import annotations

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.ident.discretize import sampling_advice
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.frfquality import check_resolution, frf_uncertainty, input_spectrum
from hilident.ident.resonance import Resonance
from hilident.pipeline.findings import Finding


def measurement_quality(
    plant: FrequencyResponse,
    resonances: list[Resonance],
    excitation,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    period_samples: int | None,
    antiresonances_hz=(),
) -> tuple[dict, list[str], list[str]]:
    """Uncertainty at the resonances, resolution, input spectrum and the sampling rule of one run.

    Parameters
    ----------
    plant : FrequencyResponse
        The plant's measured response.
    resonances : list of Resonance
    excitation : array_like
        The excitation played, N·m (or the unit of its mode).
    sample_rate_hz : float
    band_hz : (float, float)
        Band searched for resonances, Hz.
    period_samples : int or None
        Period of a periodic excitation, samples.
    antiresonances_hz : sequence of float
        Anti-resonances of the fitted model, Hz.

    Returns
    -------
    (dict, list of str, list of str)
        ``summary.json["measurement"]``, the warnings (something to act
        on) and the notes (worth knowing, nothing to change: the sampling
        rule, which only a discrete-time model needs).
    """
    warnings: list[str] = []
    out: dict = {
        "frequency_resolution_hz": float(np.median(np.diff(plant.frequency_hz))) if len(plant) > 1 else None,
        "n_averages": plant.n_averages,
    }
    if plant.n_averages >= 2:
        out["uncertainty"] = _uncertainty(plant, resonances, band_hz)
    if len(plant) > 1:
        out["resolution"], more = _resolution(plant, resonances, antiresonances_hz)
        warnings += more
    spectrum, more = _input_spectrum(excitation, sample_rate_hz, band_hz, period_samples)
    if spectrum is not None:
        out["input_spectrum"] = spectrum
    warnings += more
    out["sampling"] = {
        "sample_rate_hz": sample_rate_hz,
        "rule": "omega0 * h = 0.2 .. 0.6 (for discrete-time models)",
        "resonances": [_sampling_rule(r.frequency_hz, sample_rate_hz) for r in resonances],
    }
    if band_hz[1] > 0.4 * sample_rate_hz:
        warnings.append(
            f"the band reaches {band_hz[1]:g} Hz, above 40 % of the {sample_rate_hz:g} Hz sample rate: "
            "anti-aliasing and hold effects distort the top of the band"
        )
    return out, warnings, sampling_notes(out["sampling"]["resonances"], sample_rate_hz)


def _uncertainty(plant: FrequencyResponse, resonances: list[Resonance], band_hz: tuple[float, float]) -> dict:
    """95 % bounds of the response at each resonance and the median scatter over the band."""
    unc = frf_uncertainty(plant)
    rows = []
    for r in resonances:
        i = int(np.argmin(np.abs(plant.frequency_hz - r.frequency_hz)))
        rows.append(
            {
                "frequency_hz": r.frequency_hz,
                "magnitude_rel_std": float(unc.magnitude_rel_std[i]),
                "magnitude_bounds_db": [float(unc.lower_db[i]), float(unc.upper_db[i])],
                "phase_bound_deg": float(unc.phase_bound_deg[i]),
                "confidence": unc.confidence,
            }
        )
    in_band = (plant.frequency_hz >= band_hz[0]) & (plant.frequency_hz <= band_hz[1])
    return {
        "at_resonances": rows,
        "median_magnitude_rel_std": float(np.nanmedian(unc.magnitude_rel_std[in_band])) if in_band.any() else None,
    }


def _resolution(plant: FrequencyResponse, resonances: list[Resonance], antiresonances_hz) -> tuple[dict, list[str]]:
    """Bins across each half-power bandwidth and to the lowest anti-resonance, with what a finer grid needs."""
    check = check_resolution(plant, [(r.frequency_hz, r.damping_ratio) for r in resonances], antiresonances_hz)
    out = {
        "resolution_hz": check.resolution_hz,
        "resonances": check.bins_per_bandwidth,
        "lowest_antiresonance": check.antiresonance,
        "required_record_s": check.required_record_s,
    }
    return out, list(check.warnings)


def _input_spectrum(
    excitation, sample_rate_hz: float, band_hz: tuple[float, float], period_samples: int | None
) -> tuple[dict | None, list[str]]:
    """Level, spread and coverage of the excitation over the band (None when it cannot be computed)."""
    try:
        spec = input_spectrum(
            excitation, sample_rate_hz, band_hz, segment_length=period_samples, periodic=bool(period_samples)
        )
    except (DataError, ConfigError) as exc:
        return None, [f"input spectrum: {exc}"]
    warnings = []
    if spec.coverage < 0.5:
        warnings.append(
            f"the excitation covers only {100 * spec.coverage:.0f} % of {band_hz[0]:g}-{band_hz[1]:g} Hz "
            f"within 20 dB of its strongest line: the response is poorly excited elsewhere"
        )
    return spec.to_dict(), warnings


def _sampling_rule(frequency_hz: float, sample_rate_hz: float) -> dict:
    """The ``omega0 h = 0.2 .. 0.6`` rule (thesis eq. 2.37) for a resonance, with whether the rate meets it."""
    a = sampling_advice(2 * np.pi * frequency_hz)
    return {
        "frequency_hz": frequency_hz,
        "sample_rate_min_hz": a["sample_rate_min_hz"],
        "sample_rate_max_hz": a["sample_rate_max_hz"],
        "nyquist_sample_rate_min_hz": a["nyquist_sample_rate_min_hz"],
        "within_rule": bool(a["sample_rate_min_hz"] <= sample_rate_hz <= a["sample_rate_max_hz"]),
    }


#: A rate above the rule: the decimation that meets it (``{subjects}`` is left for the resonances).
_FINER_THAN_RULE = (
    "sampling: {fs:g} Hz samples the resonance(s) at {{subjects}} finer than the omega0 * h = 0.2 .. 0.6 rule "
    "for discrete-time models asks (sampling.within_rule: false); hilident fits no discrete-time model and its "
    "frequency response and notches do not depend on it: to fit one (ARX, discretised grey-box) to these "
    "records, decimate them by {factor} (to {decimated:.4g} Hz) first"
)
#: A rate below the rule: what it limits (``{subjects}`` is left for the resonances and their omega0 * h).
_COARSER_THAN_RULE = (
    "sampling: {fs:g} Hz samples the resonance(s) at {{subjects}} more coarsely than the "
    "omega0 * h = 0.2 .. 0.6 rule for discrete-time models asks (sampling.within_rule: false); hilident fits no "
    "discrete-time model, and the frequency response and notches hold up to {nyquist:g} Hz (Nyquist): the rate "
    "limits only a discrete-time model of these records (ARX, discretised grey-box), which would place such a "
    "mode poorly"
)


def sampling_notes(rules: list[dict], sample_rate_hz: float) -> list[str]:
    """Notes on the resonances whose sampling breaks the ``omega0 h = 0.2 .. 0.6`` rule.

    The rule is for discrete-time models (ARX, a discretised grey-box);
    hilident fits none (``[model]`` is a continuous-time regression on
    state-variable-filtered signals), and the frequency response and the
    notches do not depend on it. So nothing here asks for a change: a rate
    above the rule gets a decimation hint for whoever fits such a model to
    the records, a rate below it what it limits. Each note is a
    :class:`~hilident.pipeline.findings.Finding` per resonance, so that one
    cause reads as one line over resonances and mapped positions.

    Parameters
    ----------
    rules : list of dict
        ``summary.json["measurement"]["sampling"]["resonances"]``.
    sample_rate_hz : float
    """
    fs = float(sample_rate_hz)
    notes: list[str] = []
    for rule in rules:
        if rule["within_rule"]:
            continue
        subject = f"{rule['frequency_hz']:.4g} Hz"
        if fs > rule["sample_rate_max_hz"]:
            factor = int(np.ceil(fs / rule["sample_rate_max_hz"]))
            notes.append(Finding(_FINER_THAN_RULE.format(fs=fs, factor=factor, decimated=fs / factor), subject))
        else:
            omega_h = 2 * np.pi * rule["frequency_hz"] / fs
            notes.append(
                Finding(_COARSER_THAN_RULE.format(fs=fs, nyquist=fs / 2), f"{subject} (omega0 * h = {omega_h:.2g})")
            )
    return notes
