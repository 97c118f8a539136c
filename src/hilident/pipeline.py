"""Pure composition of the identification steps: recorded arrays in, models and filters out.

No files, no devices: the session hands arrays to these functions and writes
what they return. The same functions serve ``hilident run`` and, later,
``hilident identify`` on recordings made elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilident.config import IdentificationConfig, NotchConfig
from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, notch_from_resonance
from hilident.ident import friction as fr
from hilident.ident.frequency import FrequencyResponse, frf_from_reference, h1_estimate, periodic_frf
from hilident.ident.preprocess import check_signals, detrend, lowpass
from hilident.ident.resonance import Resonance, find_resonances


@dataclass
class FrictionResult:
    """Friction identified from constant-velocity windows."""

    fit: fr.FrictionFit
    points: fr.SteadyStatePoints
    model: str


def identify_friction(velocity, torque, windows, model: str = "stribeck") -> FrictionResult:
    """Steady-state friction points and the fitted friction curve.

    Parameters
    ----------
    velocity, torque : array_like
        Recorded velocity (m/s) and measured torque (N·m) of the friction test.
    windows : sequence of (start, stop, nominal_velocity_mps)
        Sample ranges at constant velocity.
    model : {"stribeck", "coulomb_viscous"}
    """
    checked = check_signals({"velocity": velocity, "torque": torque})
    points = fr.steady_state_points(checked["velocity"], checked["torque"], windows)
    if len(points.v_mean) < 4:
        raise DataError(
            f"only {len(points.v_mean)} steady constant-velocity windows; a friction fit needs at least 4 "
            "(longer friction_test.hold_s, or slower accelerations)"
        )
    fit = fr.fit_stribeck(points.v_mean, points.tau_mean) if model == "stribeck" else fr.fit_coulomb_viscous(
        points.v_mean, points.tau_mean
    )
    return FrictionResult(fit=fit, points=points, model=model)


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
    """

    plant: FrequencyResponse
    loop: FrequencyResponse
    resonances: list[Resonance]
    warnings: list[str] = field(default_factory=list)


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
    period_samples: int | None = None,
    excited_bins=None,
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
    period_samples : int, optional
        Period of a periodic excitation: whole periods are averaged (no leakage).
        The record must start on a period boundary, transient already removed.
    excited_bins : array_like of int, optional
        DFT bins of one period that carry excitation (default: found from the data).
    """
    s = check_signals({"excitation": excitation, "torque": torque, "output": output, "velocity": velocity})
    warnings: list[str] = []
    u = s["torque"]
    if friction is not None:
        u = fr.compensate(u, s["velocity"], friction, velocity_deadband_mps)
    r, u, y = (_condition(x, cfg, sample_rate_hz) for x in (s["excitation"], u, s["output"]))
    seg = _segment(len(r), cfg, sample_rate_hz, period_samples, warnings)
    if seg is None:
        plant = periodic_frf(u, y, period_samples, sample_rate_hz, skip_periods=0, bins=excited_bins)
        loop = periodic_frf(r, y, period_samples, sample_rate_hz, skip_periods=0, bins=excited_bins)
    else:
        plant = frf_from_reference(r, u, y, sample_rate_hz, seg)
        loop = h1_estimate(r, y, sample_rate_hz, seg)
    resonances = find_resonances(
        plant, coherence_threshold=cfg.coherence_threshold, min_prominence_db=cfg.min_prominence_db,
        max_count=cfg.max_resonances, band_hz=band_hz,
    )
    if not resonances:
        warnings.append(
            f"no resonance with coherence >= {cfg.coherence_threshold:g} and prominence >= "
            f"{cfg.min_prominence_db:g} dB between {band_hz[0]:g} and {band_hz[1]:g} Hz"
        )
    return PlantResult(plant=plant, loop=loop, resonances=resonances, warnings=warnings)


def _condition(x: np.ndarray, cfg: IdentificationConfig, sample_rate_hz: float) -> np.ndarray:
    """Optional zero-phase low-pass, then a linear trend removed.

    The same filter on every signal of a ratio leaves the ratio intact.
    """
    if cfg.lowpass_hz:
        x = lowpass(x, cfg.lowpass_hz, sample_rate_hz)
    return detrend(x, "linear")


def _segment(n: int, cfg: IdentificationConfig, sample_rate_hz: float, period_samples, warnings: list[str]):
    """Welch segment length for a record of ``n`` samples, or None when whole periods are averaged."""
    if period_samples and n >= 2 * period_samples:
        return None
    if period_samples:
        warnings.append("fewer than two whole excitation periods recorded: Welch averaging used instead")
    seg = int(round(cfg.segment_s * sample_rate_hz))
    if seg > n // 2:
        seg = n // 2
        warnings.append(f"identification.segment_s longer than half the record: {seg / sample_rate_hz:g} s used")
    return seg


def loop_response(
    excitation, output, sample_rate_hz: float, cfg: IdentificationConfig,
    period_samples: int | None = None, excited_bins=None,
) -> tuple[FrequencyResponse, list[str]]:
    """Excitation-to-output response through the drive, as :func:`identify_plant` computes its ``loop``.

    This is all a verification run needs: no friction model, no resonance search.
    """
    s = check_signals({"excitation": excitation, "output": output})
    warnings: list[str] = []
    r, y = (_condition(x, cfg, sample_rate_hz) for x in (s["excitation"], s["output"]))
    seg = _segment(len(r), cfg, sample_rate_hz, period_samples, warnings)
    if seg is None:
        return periodic_frf(r, y, period_samples, sample_rate_hz, skip_periods=0, bins=excited_bins), warnings
    return h1_estimate(r, y, sample_rate_hz, seg), warnings


@dataclass
class NotchDesign:
    """One notch, designed for one resonance and assigned to a filter slot."""

    spec: NotchSpec
    biquad: Biquad
    slot: int
    sample_rate_hz: float
    resonance: Resonance


def design_notches(resonances, cfg: NotchConfig, filter_rate_hz: float, slots: list[int]) -> list[NotchDesign]:
    """A notch per resonance (most prominent first), as many as there are free slots.

    The width is ``width_factor`` times the half-power bandwidth ``2 zeta f`` but
    at least ``min_width_ratio * f``, so an identification error of a fraction of
    a percent in the centre frequency still leaves the resonance deep in the notch.
    """
    ordered = sorted(resonances, key=lambda r: -r.peak_magnitude_db)[: len(slots)]
    designs = []
    for slot, res in zip(slots, sorted(ordered, key=lambda r: r.frequency_hz)):
        zeta = res.damping_ratio if np.isfinite(res.damping_ratio) else 0.05
        spec = notch_from_resonance(
            res.frequency_hz, zeta, depth_db=cfg.depth_db, width_factor=cfg.width_factor,
            min_relative_width=cfg.min_width_ratio,
        )
        designs.append(NotchDesign(spec, design_notch(spec, filter_rate_hz), slot, filter_rate_hz, res))
    return designs


def peak_reductions(before: FrequencyResponse, after: FrequencyResponse, resonances, band_ratio: float = 0.05):
    """Measured reduction of each resonance between two runs with the same excitation.

    Both responses come from measurements; the notch design does not enter the
    numbers. For each resonance two figures are reported:

    * ``reduction_db``: ``|before| / |after|`` at the identified resonance
      frequency (nearest line), i.e. how much less the axis answers at the
      frequency where the plant resonates;
    * ``band_peak_reduction_db``: largest ``|before|`` over largest ``|after|``
      within ``± band_ratio`` of it, which also counts a peak that moved or the
      skirts the notch leaves.

    Returns
    -------
    list of dict
        ``frequency_hz``, ``before_db``, ``after_db``, ``reduction_db``,
        ``band_peak_reduction_db`` per resonance.
    """
    f = before.frequency_hz
    mag_before = np.abs(before.response)
    mag_after = np.abs(after.response)
    if len(after.frequency_hz) != len(f) or not np.allclose(after.frequency_hz, f):
        # e.g. a shorter verification record: compare on the identification's lines
        if f[0] < after.frequency_hz[0] or f[-1] > after.frequency_hz[-1]:
            raise DataError("the verification response does not cover the identification's frequencies")
        mag_after = np.exp(np.interp(np.log(f), np.log(after.frequency_hz), np.log(np.maximum(mag_after, 1e-300))))
    mag_after = np.maximum(mag_after, 1e-300)
    out = []
    for res in resonances:
        i = int(np.argmin(np.abs(f - res.frequency_hz)))
        band = np.flatnonzero(np.abs(f - res.frequency_hz) <= band_ratio * res.frequency_hz)
        band = band if len(band) else np.array([i])
        b_db, a_db = 20 * np.log10(mag_before[i]), 20 * np.log10(mag_after[i])
        out.append({
            "frequency_hz": float(f[i]),
            "before_db": float(b_db),
            "after_db": float(a_db),
            "reduction_db": float(b_db - a_db),
            "band_peak_reduction_db": float(20 * np.log10(mag_before[band].max() / mag_after[band].max())),
        })
    return out


def achieved_notch(design: NotchDesign, stored: Biquad) -> dict:
    """What the coefficients a device stores actually do, next to what was designed.

    A device rounds coefficients (REAL32, fixed point, scaled integers). For a
    notch far below the filter rate that rounding can move the notch; this
    reports where the stored section's minimum lies and its attenuation at the
    designed centre, both computed from the stored coefficients.
    """
    f0, fs = design.spec.center_hz, design.sample_rate_hz
    grid = np.linspace(0.5 * f0, 1.5 * f0, 4001)
    mag = np.abs(stored.response(grid, fs))
    at_center = float(np.abs(stored.response(np.array([f0]), fs))[0])
    return {
        "center_hz": float(grid[int(np.argmin(mag))]),
        "depth_db": float(-20 * np.log10(max(mag.min(), 1e-300))),
        "attenuation_at_design_center_db": float(-20 * np.log10(max(at_center, 1e-300))),
        "dc_gain": float(stored.dc_gain()),
        "stable": bool(stored.is_stable()),
    }


def resonance_records(resonances) -> list[dict]:
    """Resonances as plain records for ``summary.json``."""
    return [
        {"frequency_hz": r.frequency_hz, "damping_ratio": r.damping_ratio, "peak_magnitude_db": r.peak_magnitude_db,
         "coherence": r.coherence, "method": r.method}
        for r in resonances
    ]


def notch_records(designs: list[NotchDesign]) -> list[dict]:
    """Designed notches as plain records for ``summary.json`` (biquad ``b``, ``a`` in scipy convention)."""
    return [
        {"center_hz": d.spec.center_hz, "width_hz": d.spec.width_hz, "depth_db": d.spec.depth_db,
         "sample_rate_hz": d.sample_rate_hz, "slot": d.slot, "b": list(d.biquad.b), "a": list(d.biquad.a)}
        for d in designs
    ]


def notch_chain_response(designs: list[NotchDesign], frequency_hz) -> tuple[np.ndarray, np.ndarray] | None:
    """``(frequency_hz, response)`` of the designed notches in series, for plots; None without notches."""
    if not designs:
        return None
    from hilident.filters.notch import chain_response

    f = np.asarray(frequency_hz, dtype=float)
    return f, chain_response([d.biquad for d in designs], f, designs[0].sample_rate_hz)
