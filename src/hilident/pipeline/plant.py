"""The plant of one identification run: friction removed, frequency responses, resonances and a fitted model."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilident.config.tables import IdentificationConfig
from hilident.errors import ConfigError, DataError
from hilident.ident import friction as fr
from hilident.ident.frequency import FrequencyResponse, frf_from_reference, h1_estimate, periodic_frf
from hilident.ident.frfquality import frf_uncertainty
from hilident.ident.preprocess import check_signals
from hilident.ident.resonance import RejectedPeak, Resonance, screen_resonances
from hilident.pipeline.measurement import measurement_quality
from hilident.pipeline.mimo_identify import interval_blocks
from hilident.pipeline.plant_model import (
    PlantModel,
    fit_plant_model,
    model_notes,
    model_warnings,
    reconcile_resonances,
)
from hilident.pipeline.responses import (
    averaged_period,
    condition_signal,
    gapped_warnings,
    mean_period,
    missing_samples,
    welch_segment,
)


@dataclass
class PlantResult:
    """Frequency responses and resonances of one identification run.

    Attributes
    ----------
    plant : FrequencyResponse
        Net torque (measured minus friction) to output: the mechanics.
    loop : FrequencyResponse
        Excitation to output through the drive (filters and loops included):
        what the verification run compares.
    resonances : list of Resonance
    warnings : list of str
        What the user should act on.
    notes : list of str
        What is worth knowing and needs no action (``summary.json["notes"]``).
    outputs : dict of str to FrequencyResponse
        Net torque to each of ``identification.outputs`` (a load sensor), estimated as :attr:`plant` is, from
        the same samples: what :mod:`hilident.pipeline.output_modes` identifies together with it.
    output_groups : list of (FrequencyResponse, dict of str to FrequencyResponse)
        With ``outputs``: :attr:`plant` and :attr:`outputs` estimated again on each of several disjoint blocks of
        the record (:func:`hilident.pipeline.mimo_identify.interval_blocks`), for the joint modes' 95 %
        intervals; empty when the record holds too few blocks.
    """

    plant: FrequencyResponse
    loop: FrequencyResponse
    resonances: list[Resonance]
    warnings: list[str] = field(default_factory=list)
    model: PlantModel | None = None
    quality: dict = field(default_factory=dict)
    rejected: list[RejectedPeak] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    outputs: dict[str, FrequencyResponse] = field(default_factory=dict)
    output_groups: list[tuple[FrequencyResponse, dict[str, FrequencyResponse]]] = field(default_factory=list)


def analysis_band(cfg: IdentificationConfig, excitation_band_hz: tuple[float, float]) -> tuple[float, float]:
    """Band searched for resonances, Hz: ``[identification] f_min_hz``/``f_max_hz``, each defaulting to the
    excitation's band."""
    return (cfg.f_min_hz or excitation_band_hz[0], cfg.f_max_hz or excitation_band_hz[1])


def identify_plant(
    excitation,
    torque,
    output,
    velocity,
    sample_rate_hz: float,
    cfg: IdentificationConfig,
    band_hz: tuple[float, float],
    friction: fr.StribeckParams | None = None,
    velocity_deadband_mps: float = 0.0,
    friction_slowest_mps: float = 0.0,
    period_samples: int | None = None,
    excited_bins=None,
    present=None,
    extra_outputs: dict | None = None,
) -> PlantResult:
    """Friction removal, preprocessing, FRF with coherence and resonance picking.

    Parameters
    ----------
    excitation : array_like
        The excitation the drive actually played (torque, N·m).
    torque : array_like
        Measured motor torque, N·m.
    output : array_like
        Output channel (e.g. motor velocity, m/s).
    velocity : array_like
        Motor velocity, m/s (for the friction model).
    sample_rate_hz : float
    cfg : IdentificationConfig
    band_hz : (float, float)
        Band searched for resonances.
    friction : StribeckParams, optional
        Friction to remove from the torque first.
    velocity_deadband_mps, friction_slowest_mps : float
        No compensation up to the first speed; the friction curve not extrapolated below the second, the
        slowest speed it was measured at (m/s; :func:`hilident.ident.friction.compensate`).
    period_samples : int, optional
        Period of a periodic excitation: whole periods are averaged (no leakage).
        The record must start on a period boundary, transient already removed.
    excited_bins : array_like of int, optional
        DFT bins of one period that carry excitation (default: found from the data).
    present : array_like of bool, optional
        Which samples exist (default: all). Whole periods that miss some
        samples are read by least squares on those they have
        (:func:`~hilident.ident.frequency.periodic_frf`); nothing is filled in.
    extra_outputs : dict of str to array_like, optional
        Further outputs (``identification.outputs``), each estimated against the same net torque
        (:attr:`PlantResult.outputs`); one with a sample out of its sensor's range (NaN) is left out, with a
        warning.
    """
    gaps = missing_samples(present)
    warnings: list[str] = [] if gaps is None else gapped_warnings(cfg, gaps, period_samples)
    if gaps is not None:  # what is missing is never looked at: zeros pass the finite-value check
        same = excitation is torque
        excitation, torque, output, velocity = (np.where(gaps, x, 0.0) for x in (excitation, torque, output, velocity))
        excitation = torque if same else excitation
    # only read here, never written: no copies of a long record
    s = check_signals({"excitation": excitation, "torque": torque, "output": output, "velocity": velocity}, copy=False)
    u = s["torque"]
    if friction is not None:
        u = fr.compensate(u, s["velocity"], friction, velocity_deadband_mps, friction_slowest_mps)
    u, y = (condition_signal(x, cfg, sample_rate_hz, period_samples, gaps) for x in (u, s["output"]))
    # a recording without an excitation column gives the torque as excitation: condition it once
    r = (
        u
        if s["excitation"] is s["torque"] and friction is None
        else condition_signal(s["excitation"], cfg, sample_rate_hz, period_samples, gaps)
    )
    del s
    averaged = averaged_period(len(r), period_samples)
    if averaged is not None:
        plant = periodic_frf(u, y, averaged, sample_rate_hz, skip_periods=0, bins=excited_bins, present=gaps)
        loop = periodic_frf(r, y, averaged, sample_rate_hz, skip_periods=0, bins=excited_bins, present=gaps)
        if gaps is not None:  # the excitation's spectrum from its mean period (it is periodic; nothing filled in)
            r = mean_period(r, gaps, averaged)
    else:
        seg = welch_segment(len(r), cfg, sample_rate_hz, period_samples, warnings)
        plant = frf_from_reference(r, u, y, sample_rate_hz, seg)
        loop = h1_estimate(r, y, sample_rate_hz, seg)

    def estimate(y_other: np.ndarray, block: slice = slice(None)) -> FrequencyResponse:
        """As the plant's: same torque, periods, segments (on ``block`` of the record)."""
        if averaged is not None:
            present = gaps[block] if gaps is not None else None
            return periodic_frf(
                u[block], y_other[block], averaged, sample_rate_hz, skip_periods=0, bins=excited_bins, present=present
            )
        return frf_from_reference(r[block], u[block], y_other[block], sample_rate_hz, seg)

    others = _other_outputs(extra_outputs or {}, cfg, sample_rate_hz, period_samples, gaps, warnings)
    outputs = {name: estimate(x) for name, x in others.items()}
    output_groups = []
    if others:
        # an averaged estimate needs two periods: two or more per block
        for a, b in interval_blocks(len(u), averaged, 0 if averaged is not None else seg, periods_per_block=2):
            block = slice(a, b)
            output_groups.append((estimate(y, block), {name: estimate(x, block) for name, x in others.items()}))
    screened = resonances_and_model(plant, cfg, band_hz)
    model = screened.model
    antires = [hz for hz, _ in model.roots.antiresonances] if model else []
    quality, more, notes = measurement_quality(
        plant, screened.resonances, r, sample_rate_hz, band_hz, averaged, antires
    )
    return PlantResult(
        plant=plant,
        loop=loop,
        resonances=screened.resonances,
        warnings=warnings + screened.warnings + more,
        model=model,
        quality=quality,
        rejected=screened.rejected,
        notes=screened.notes + notes,
        outputs=outputs,
        output_groups=output_groups,
    )


def _other_outputs(extra: dict, cfg, sample_rate_hz, period_samples, gaps, warnings: list[str]) -> dict:
    """Each further output conditioned as the plant's output is; a channel with a missing reading is left out."""
    out = {}
    for name, values in extra.items():
        x = np.asarray(values, dtype=float)
        if gaps is not None:
            x = np.where(gaps, x, 0.0)
        bad = int(np.count_nonzero(~np.isfinite(x)))
        if bad:
            warnings.append(
                f"identification.outputs: {name} has {bad} of {x.size} samples out of its sensor's range or "
                "missing (NaN): left out of the joint estimate (a smaller excitation keeps it in range)"
            )
            continue
        out[name] = condition_signal(x, cfg, sample_rate_hz, period_samples, gaps)
    return out


@dataclass
class ScreenedResonances:
    """The resonances the measured peaks and the fitted model both support (:func:`resonances_and_model`).

    Attributes
    ----------
    resonances, rejected : list of Resonance, list of RejectedPeak
        Reported resonances and rejected peaks, by frequency.
    model : PlantModel or None
        The transfer function fitted on the way (None: not asked for, or no fit).
    warnings, notes : list of str
        What to act on; what is worth knowing and needs no action.
    """

    resonances: list[Resonance]
    rejected: list[RejectedPeak]
    model: PlantModel | None
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def resonances_and_model(
    plant: FrequencyResponse, cfg: IdentificationConfig, band_hz: tuple[float, float]
) -> ScreenedResonances:
    """Screened peaks, the fitted model, and the one list of resonances both support."""
    # every candidate first: the count limit applies to the peaks the model confirms
    found, rejected = screen_resonances(
        plant,
        coherence_threshold=cfg.coherence_threshold,
        min_prominence_db=cfg.min_prominence_db,
        max_count=_MAX_CANDIDATES,
        band_hz=band_hz,
    )
    warnings: list[str] = []
    model = _fitted_model(plant, cfg, band_hz, warnings)
    notes = model_notes(model) if model is not None else []
    if model is not None:
        warnings += model_warnings(model)
    resolution = float(np.median(np.diff(plant.frequency_hz))) if len(plant) > 1 else 0.0
    found, rejected, more = reconcile_resonances(found, rejected, model, cfg.model_max_order, resolution)
    confirmed = found
    found, rejected = _most_prominent(found, rejected, cfg.max_resonances)
    dropped = [f"at {r.frequency_hz:.4g} Hz" for r in confirmed if r not in found]
    warnings += [w for w in more if not any(d in w for d in dropped)]
    if model is not None:
        _note_modes_beyond_count(model, found, cfg.max_resonances)
    if not found:
        warnings.append(
            f"no resonance with coherence >= {cfg.coherence_threshold:g} and prominence >= "
            f"{cfg.min_prominence_db:g} dB between {band_hz[0]:g} and {band_hz[1]:g} Hz"
            + (f" ({len(rejected)} peak(s) rejected, see rejected_peaks)" if rejected else "")
        )
    return ScreenedResonances(found, rejected, model, warnings, notes)


def _fitted_model(
    plant: FrequencyResponse, cfg: IdentificationConfig, band_hz: tuple[float, float], warnings: list[str]
) -> PlantModel | None:
    """The transfer function ``[identification]`` asks for (None: none asked for, or the fit failed: a warning)."""
    if not cfg.model_max_order:
        return None
    try:
        return fit_plant_model(
            plant,
            band_hz,
            cfg.model_max_order,
            cfg.coherence_threshold,
            cfg.model_order,
            cfg.model_relative_degree,
            cfg.model_integrators,
            cfg.model_criterion,
        )
    except (DataError, ConfigError) as exc:
        warnings.append(f"transfer-function fit: {exc}")
        return None


def _note_modes_beyond_count(model: PlantModel, reported: list[Resonance], max_resonances: int) -> None:
    """A model mode confirmed by a resonance that the count limit dropped is noted as not reported, with why."""
    kept = {r.frequency_hz for r in reported}
    for note in model.mode_notes:
        if note["reported"] and note["resonance_hz"] not in kept:
            note.update(
                reported=False,
                reason=f"beyond identification.max_resonances = {max_resonances} (the most prominent are reported)",
            )
            del note["resonance_hz"]


#: Peaks refined before the model and the count limit decide (``max_resonances`` may be at most 16).
_MAX_CANDIDATES = 16


def _most_prominent(found: list[Resonance], rejected: list[RejectedPeak], max_count: int):
    """The `max_count` most prominent resonances; the others join the rejected peaks with the reason."""
    ranked = sorted(found, key=lambda r: -np.nan_to_num(r.prominence_db, nan=-np.inf))
    kept, dropped = ranked[:max_count], ranked[max_count:]
    rejected = rejected + [
        RejectedPeak(
            r.frequency_hz,
            r.peak_magnitude_db,
            r.coherence,
            f"beyond identification.max_resonances = {max_count} (prominence "
            f"{r.prominence_db:.1f} dB; the most prominent are reported)",
        )
        for r in dropped
    ]
    return sorted(kept, key=lambda r: r.frequency_hz), sorted(rejected, key=lambda r: r.frequency_hz)


def bode_extras(plant: PlantResult) -> dict:
    """The fitted model's curve and the plant response's 95 % band, as
    :func:`~hilident.plots.bode.plot_bode` takes them."""
    extras: dict = {}
    if plant.model is not None:
        f = plant.plant.frequency_hz
        fine = np.geomspace(max(f[f > 0].min(), 1e-3), f.max(), 2000) if np.any(f > 0) else f
        fit = plant.model.fit
        extras["model"] = (
            f"fitted model ({fit.n_num}/{fit.n_den + fit.integrators}, {plant.model.criterion})",
            fine,
            fit.response(fine),
        )
    if plant.plant.n_averages >= 2 and np.all(np.isfinite(plant.plant.coherence)):
        unc = frf_uncertainty(plant.plant)
        extras["bounds_db"] = (unc.lower_db, unc.upper_db)
    return extras
