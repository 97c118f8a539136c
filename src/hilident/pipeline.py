"""Pure composition of the identification steps: recorded arrays in, models and filters out.

No files, no devices: the session hands arrays to these functions and writes
what they return. The same functions serve ``hilident run`` and, later,
``hilident identify`` on recordings made elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilident.config import IdentificationConfig, ModelConfig, NotchConfig
from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, notch_from_resonance
from hilident.ident import friction as fr
from hilident.ident import greybox
from hilident.ident.validation import overfitting_warning
from hilident.ident.discretize import sampling_advice
from hilident.ident.frequency import FrequencyResponse, frf_from_reference, h1_estimate, periodic_frf
from hilident.ident.frfquality import check_resolution, frf_uncertainty, input_spectrum
from hilident.ident.preprocess import check_signals, detrend, lowpass
from hilident.ident.resonance import Resonance, find_resonances
from hilident.ident.tffit import ModalModel, TfFit, modal_form
from hilident.ident.tffit import select_order as select_tf_order


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
    model: "PlantModel | None" = None
    quality: dict = field(default_factory=dict)


@dataclass
class PlantModel:
    """A transfer function fitted to the plant's measured response.

    Attributes
    ----------
    fit : TfFit
    modal : ModalModel
        The same transfer function as resonances and anti-resonances.
    candidates : list of dict
        Orders tried: ``n_num``, ``n_den``, ``weighted_cost``, ``selected``.
    """

    fit: TfFit
    modal: ModalModel
    candidates: list

    def to_dict(self) -> dict:
        f, m = self.fit, self.modal
        return {
            "n_num": f.n_num, "n_den": f.n_den, "integrators": f.integrators, "band_hz": list(f.band_hz),
            "fit_db_rms": f.fit_db_rms, "phase_rms_deg": f.phase_rms_deg, "weighted_cost": f.weighted_cost,
            "stable": f.stable, "gain": m.gain,
            "resonances": [{"frequency_hz": hz, "damping_ratio": z} for hz, z in m.resonances],
            "antiresonances": [{"frequency_hz": hz, "damping_ratio": z} for hz, z in m.antiresonances],
            "real_poles_hz": list(m.real_poles_hz), "real_zeros_hz": list(m.real_zeros_hz),
            "poles_rad_s": [[p.real, p.imag] for p in f.poles], "zeros_rad_s": [[z.real, z.imag] for z in f.zeros],
            "num": list(f.num), "den": list(f.den), "candidates": self.candidates,
        }


def _slope_db_per_decade(frf: FrequencyResponse, lo: float, hi: float) -> float:
    keep = (frf.frequency_hz >= lo) & (frf.frequency_hz <= hi) & np.isfinite(frf.response) & (frf.response != 0)
    if keep.sum() < 3:
        return float("nan")
    x = np.log10(frf.frequency_hz[keep])
    return float(np.polyfit(x, 20 * np.log10(np.abs(frf.response[keep])), 1)[0])


def fit_plant_model(frf: FrequencyResponse, band_hz: tuple[float, float], max_order: int,
                    coherence_threshold: float = 0.0) -> PlantModel:
    """Transfer function and modal form of a measured plant response.

    The integrators (rigid-body modes: a velocity response of a free axis has
    one) are read from the slope over the lowest fifth of the band on a log
    axis, the relative degree from the slope over the highest fifth; then
    :func:`~hilident.ident.tffit.select_order` picks the smallest adequate
    order up to ``max_order``, weighting each bin by its coherence.

    Raises
    ------
    DataError
        No stable fit, or too few coherent bins.
    """
    f_lo, f_hi = band_hz
    frf = frf.band(f_lo, f_hi)
    keep = frf.coherence >= coherence_threshold if np.all(np.isfinite(frf.coherence)) else np.ones(len(frf), bool)
    if keep.sum() < 8:
        raise DataError(f"only {int(keep.sum())} bins with coherence >= {coherence_threshold:g} to fit a model to")
    frf = FrequencyResponse(frf.frequency_hz[keep], frf.response[keep], frf.coherence[keep], frf.n_averages,
                            frf.method)
    decade = np.log10(f_hi / f_lo)
    low = _slope_db_per_decade(frf, f_lo, f_lo * 10 ** (decade / 5))
    high = _slope_db_per_decade(frf, f_hi / 10 ** (decade / 5), f_hi)
    integrators = int(np.clip(np.round(-low / 20.0), 0, 2)) if np.isfinite(low) else 0
    relative = int(np.clip(np.round(-high / 20.0), 0, 4)) if np.isfinite(high) else integrators
    relative_free = max(relative - integrators, 0)
    weights = "coherence" if np.all(np.isfinite(frf.coherence)) and frf.n_averages > 1 else None
    if weights == "coherence":
        # a bin with coherence 1 (noise-free) would get infinite weight
        frf = FrequencyResponse(frf.frequency_hz, frf.response, np.minimum(frf.coherence, 0.9999), frf.n_averages,
                                frf.method)
    fit, table = select_tf_order(frf, max_order=max(max_order, relative_free, 1), relative_degree=relative_free,
                                 integrators=integrators, weights=weights)
    candidates = [{"n_num": r.n_num, "n_den": r.n_den, "selected": r.selected,
                   "weighted_cost": None if r.fit is None else r.fit.weighted_cost} for r in table]
    return PlantModel(fit=fit, modal=modal_form(fit), candidates=candidates)


def bode_extras(plant: PlantResult) -> dict:
    """The fitted model's curve and the plant response's 95 % band, as :func:`report.plot_bode` takes them."""
    extras: dict = {}
    if plant.model is not None:
        f = plant.plant.frequency_hz
        fine = np.geomspace(max(f[f > 0].min(), 1e-3), f.max(), 2000) if np.any(f > 0) else f
        fit = plant.model.fit
        extras["model"] = (f"fitted model ({fit.n_num}/{fit.n_den + fit.integrators})", fine, fit.response(fine))
    if plant.plant.n_averages >= 2 and np.all(np.isfinite(plant.plant.coherence)):
        unc = frf_uncertainty(plant.plant)
        extras["bounds_db"] = (unc.lower_db, unc.upper_db)
    return extras


def measurement_quality(plant: FrequencyResponse, resonances: list[Resonance], excitation, sample_rate_hz: float,
                        band_hz: tuple[float, float], period_samples: int | None,
                        antiresonances_hz=()) -> tuple[dict, list[str]]:
    """Uncertainty at the resonances, resolution, input spectrum and sampling advice of one run."""
    warnings: list[str] = []
    out: dict = {"frequency_resolution_hz": float(np.median(np.diff(plant.frequency_hz))) if len(plant) > 1 else None,
                 "n_averages": plant.n_averages}
    if plant.n_averages >= 2:
        unc = frf_uncertainty(plant)
        rows = []
        for r in resonances:
            i = int(np.argmin(np.abs(plant.frequency_hz - r.frequency_hz)))
            rows.append({"frequency_hz": r.frequency_hz, "magnitude_rel_std": float(unc.magnitude_rel_std[i]),
                         "magnitude_bounds_db": [float(unc.lower_db[i]), float(unc.upper_db[i])],
                         "phase_bound_deg": float(unc.phase_bound_deg[i]), "confidence": unc.confidence})
        in_band = (plant.frequency_hz >= band_hz[0]) & (plant.frequency_hz <= band_hz[1])
        out["uncertainty"] = {
            "at_resonances": rows,
            "median_magnitude_rel_std": float(np.nanmedian(unc.magnitude_rel_std[in_band])) if in_band.any() else None,
        }
    if len(plant) > 1:
        check = check_resolution(plant, [(r.frequency_hz, r.damping_ratio) for r in resonances], antiresonances_hz)
        out["resolution"] = {"resolution_hz": check.resolution_hz, "resonances": check.bins_per_bandwidth,
                             "lowest_antiresonance": check.antiresonance,
                             "required_record_s": check.required_record_s}
        warnings += check.warnings
    try:
        spec = input_spectrum(excitation, sample_rate_hz, band_hz, segment_length=period_samples,
                              periodic=bool(period_samples))
        out["input_spectrum"] = spec.to_dict()
        if spec.coverage < 0.5:
            warnings.append(
                f"the excitation covers only {100 * spec.coverage:.0f} % of {band_hz[0]:g}-{band_hz[1]:g} Hz "
                f"within 20 dB of its strongest line: the response is poorly excited elsewhere"
            )
    except (DataError, ConfigError) as exc:
        warnings.append(f"input spectrum: {exc}")
    advice = []
    for r in resonances:
        a = sampling_advice(2 * np.pi * r.frequency_hz)
        advice.append({"frequency_hz": r.frequency_hz, "sample_rate_min_hz": a["sample_rate_min_hz"],
                       "sample_rate_max_hz": a["sample_rate_max_hz"],
                       "nyquist_sample_rate_min_hz": a["nyquist_sample_rate_min_hz"],
                       "within_rule": bool(a["sample_rate_min_hz"] <= sample_rate_hz <= a["sample_rate_max_hz"])})
    out["sampling"] = {"sample_rate_hz": sample_rate_hz, "rule": "omega0 * h = 0.2 .. 0.6 (for discrete-time models)",
                       "resonances": advice}
    if band_hz[1] > 0.4 * sample_rate_hz:
        warnings.append(f"the band reaches {band_hz[1]:g} Hz, above 40 % of the {sample_rate_hz:g} Hz sample rate: "
                        "anti-aliasing and hold effects distort the top of the band")
    return out, warnings


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
    # only read here, never written: no copies of a long record
    s = check_signals({"excitation": excitation, "torque": torque, "output": output, "velocity": velocity},
                      copy=False)
    warnings: list[str] = []
    u = s["torque"]
    if friction is not None:
        u = fr.compensate(u, s["velocity"], friction, velocity_deadband_mps)
    u, y = (_condition(x, cfg, sample_rate_hz) for x in (u, s["output"]))
    # a recording without an excitation column gives the torque as excitation: condition it once
    r = u if s["excitation"] is s["torque"] and friction is None else _condition(s["excitation"], cfg, sample_rate_hz)
    del s
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
    model = None
    if cfg.model_max_order:
        try:
            model = fit_plant_model(plant, band_hz, cfg.model_max_order, cfg.coherence_threshold)
        except (DataError, ConfigError) as exc:
            warnings.append(f"transfer-function fit: {exc}")
    antires = [hz for hz, _ in model.modal.antiresonances] if model else []
    quality, more = measurement_quality(plant, resonances, r, sample_rate_hz, band_hz,
                                        period_samples if seg is None else None, antires)
    return PlantResult(plant=plant, loop=loop, resonances=resonances, warnings=warnings + more, model=model,
                       quality=quality)


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
    s = check_signals({"excitation": excitation, "output": output}, copy=False)
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


# --- grey-box model of the axis ----------------------------------------------------------


def greybox_regression(cfg: ModelConfig, torque, position, sample_rate_hz: float):
    """The regression ``[model]`` asks for, every key honoured (asymmetric, min_speed, decimate, input_hold)."""
    force = cfg.c * np.asarray(torque, dtype=float)
    cutoff = cfg.cutoff_hz or sample_rate_hz / 10.0
    if cfg.kind == "mass_spring_damper":
        return greybox.mass_spring_damper_regression(force, position, sample_rate_hz, cutoff, decimate=cfg.decimate,
                                                     input_hold=cfg.input_hold)
    return greybox.rigid_axis_regression(position, force, sample_rate_hz, cutoff, asymmetric=cfg.asymmetric,
                                         decimate=cfg.decimate, min_speed=cfg.min_speed or None,
                                         input_hold=cfg.input_hold)


@dataclass
class GreyBoxResult:
    """A grey-box model fitted on one stretch of data and checked on others.

    Attributes
    ----------
    fit : LinearFit
        Parameters with standard deviations, from the estimation data.
    estimation : dict
        :func:`~hilident.ident.greybox.validate_fit` on the estimation data.
    validation : dict of str to dict
        The same on each validation record, by name.
    warnings : list of str
    """

    kind: str
    fit: greybox.LinearFit
    estimation: dict
    validation: dict
    warnings: list

    def to_dict(self) -> dict:
        return {"kind": self.kind, **self.fit.to_dict(), "estimation": self.estimation, "validation": self.validation}


def fit_greybox(cfg: ModelConfig, torque, position, sample_rate_hz: float,
                validation_records: dict | None = None) -> GreyBoxResult:
    """Fit ``[model]`` to torque and position and validate it.

    With no separate validation record, the last ``cfg.holdout`` of the data is
    kept out of the fit and used as one (``"holdout"``).

    Parameters
    ----------
    cfg : ModelConfig
    torque, position : array_like
        Motor torque (N·m; times ``cfg.c`` gives the force) and position (m).
    sample_rate_hz : float
    validation_records : dict of str to (torque, position), optional
        Other records of the same axis.
    """
    torque = np.asarray(torque, dtype=float)
    position = np.asarray(position, dtype=float)
    records = dict(validation_records or {})
    if not records and cfg.holdout > 0:
        cut = int(round(len(torque) * (1.0 - cfg.holdout)))
        records["holdout"] = (torque[cut:], position[cut:])
        torque, position = torque[:cut], position[:cut]
    est = greybox_regression(cfg, torque, position, sample_rate_hz)
    fit = greybox.fit_regression(est)
    warnings = list(fit.warnings)
    estimation = greybox.validate_fit(fit, est)
    if est.low_speed_rows:
        why = "model.min_speed" if cfg.min_speed else "2 % of the RMS speed; model.min_speed sets it"
        warnings.append(f"{cfg.kind}: {est.low_speed_rows} of {est.low_speed_rows + estimation['samples']} rows "
                        f"slower than {est.min_speed:.3g} ({why}) left out of the fit")
    checked = {}
    for name, (tq, pos) in records.items():
        try:
            checked[name] = greybox.validate_fit(fit, greybox_regression(cfg, tq, pos, sample_rate_hz))
        except DataError as exc:
            warnings.append(f"{cfg.kind} validation on {name}: {exc}")
            continue
        w = overfitting_warning(estimation["fit_percent"], checked[name]["fit_percent"])
        if w:
            warnings.append(f"{cfg.kind} on {name}: {w}")
    return GreyBoxResult(cfg.kind, fit, estimation, checked, warnings)


# ------------------------------------------------------------------ gap-free selection

#: Gaps listed one by one in a :class:`GapFreeSelection` (the count is always exact).
MAX_LISTED_GAPS = 100


def contiguous_runs(sample_index) -> list[tuple[int, int]]:
    """``(start, stop)`` row ranges over which ``sample_index`` increases by exactly 1."""
    index = np.asarray(sample_index, dtype=np.int64)
    if len(index) == 0:
        return []
    breaks = np.flatnonzero(np.diff(index) != 1) + 1
    edges = np.concatenate(([0], breaks, [len(index)]))
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


@dataclass
class GapFreeSelection:
    """The rows of a gappy recording that may be analysed as one record.

    Attributes
    ----------
    keep : ndarray of bool
        One flag per row: True for the rows analysed.
    segments : list of (int, int)
        ``(start, stop)`` row ranges of the kept rows, each gap-free (a
        segment ends where a kept row does not follow its predecessor on
        the sample clock).
    gaps : list of dict
        Up to :data:`MAX_LISTED_GAPS` breaks of the recording: ``row`` (first
        row after the break), ``sample_index`` (its index) and
        ``missing_samples`` (negative or zero: out of order or repeated).
    n_gaps : int
        All breaks, listed or not.
    missing_samples : int
        Samples absent between the first and the last row.
    period_samples : int or None
        Period used (whole periods mode), else None (longest stretch mode).
    warnings : list of str
    """

    keep: np.ndarray
    segments: list[tuple[int, int]]
    gaps: list[dict]
    n_gaps: int
    missing_samples: int
    period_samples: int | None
    warnings: list[str] = field(default_factory=list)

    @property
    def used_rows(self) -> int:
        return int(self.keep.sum())

    def to_dict(self) -> dict:
        return {"rows": int(len(self.keep)), "used_rows": self.used_rows, "segments": len(self.segments),
                "gaps": self.gaps, "n_gaps": self.n_gaps, "missing_samples": self.missing_samples,
                "period_samples": self.period_samples}


def select_gap_free(sample_index, period_samples: int | None = None, name: str = "recording") -> GapFreeSelection:
    """Rows to analyse: whole gap-free periods of a periodic excitation, else the longest gap-free stretch.

    Nothing is ever filled in or spliced mid-period: periods of a periodic
    excitation in steady state can be joined end to end, so a lost block costs
    only the period it fell in. Period 0 (``sample_index < period_samples``) is
    the lead-in that lets the transient die out and is never used. Without a
    period only the longest stretch without a break is kept.

    Parameters
    ----------
    sample_index : array_like of int
        Index of each recorded row on the device's sample clock (0 = first
        excitation sample); a step other than +1 is a break.
    period_samples : int, optional
        Period of the excitation, samples.
    name : str
        Names the recording in warnings and errors.

    Raises
    ------
    DataError
        No rows, or fewer than two whole gap-free periods.
    """
    index = np.asarray(sample_index, dtype=np.int64)
    runs = contiguous_runs(index)
    if not runs:
        raise DataError(f"{name}: no samples were recorded")
    step = np.diff(index)
    breaks = np.flatnonzero(step != 1)
    gaps = [{"row": int(b + 1), "sample_index": int(index[b + 1]), "missing_samples": int(step[b] - 1)}
            for b in breaks[:MAX_LISTED_GAPS]]
    missing = int(np.clip(step[breaks] - 1, 0, None).sum()) if len(breaks) else 0
    if period_samples:
        keep, warnings = _whole_periods(index, runs, int(period_samples), name)
    else:
        keep, warnings = _longest_run(len(index), runs, name)
    segments = _kept_segments(keep, step)
    return GapFreeSelection(keep, segments, gaps, len(breaks), missing, int(period_samples) if period_samples else None,
                            warnings)


def _kept_segments(keep: np.ndarray, step: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` ranges of kept rows that follow each other on the sample clock."""
    joined = np.concatenate(([False], (step == 1) & keep[:-1] & keep[1:]))  # row r continues row r - 1
    starts = np.flatnonzero(keep & ~joined)
    stops = np.flatnonzero(keep & ~np.concatenate((joined[1:], [False]))) + 1
    return [(int(a), int(b)) for a, b in zip(starts, stops)]


def _longest_run(n: int, runs, name: str) -> tuple[np.ndarray, list[str]]:
    a, b = max(runs, key=lambda r: r[1] - r[0])
    keep = np.zeros(n, dtype=bool)
    keep[a:b] = True
    warnings = []
    if len(runs) > 1:
        warnings.append(f"{name}: recording has {len(runs) - 1} gap(s); the longest contiguous stretch "
                        f"({b - a} samples) was analysed")
    return keep, warnings


def _whole_periods(index: np.ndarray, runs, period: int, name: str) -> tuple[np.ndarray, list[str]]:
    keep = np.zeros(len(index), dtype=bool)
    taken: set[int] = set()
    for a, b in runs:
        first = max(1, -(-int(index[a]) // period))  # first period starting inside the run (period 0 is the lead-in)
        last = (int(index[b - 1]) + 1) // period  # periods ending inside the run: < last
        for p in range(first, last):
            if p in taken:  # a repeated stretch of samples never counts twice
                continue
            taken.add(p)
            start = a + p * period - int(index[a])
            keep[start:start + period] = True
    n_complete = len(taken)
    total = max(int(index.max()) // period, 0)
    warnings = []
    if n_complete < total:
        warnings.append(
            f"{name}: {total - n_complete} of {total} excitation periods had lost samples and were left out")
    if n_complete < 2:
        raise DataError(f"{name}: only {n_complete} complete excitation period(s) recorded; at least 2 are needed "
                        "(check the line: lost or corrupt frames)")
    return keep, warnings


def excitation_period_samples(excitation, sample_rate_hz: float) -> int | None:
    """Period in samples of the excitation ``[excitation]`` describes, None when it is not periodic.

    Mirrors how the session builds the excitation: a multisine is periodic,
    a PRBS is when at least three of its sequences are played.

    Parameters
    ----------
    excitation : ExcitationConfig
    sample_rate_hz : float
    """
    fs = float(sample_rate_hz)
    if excitation.kind == "multisine":
        period = int(round(excitation.period_s * fs))
        return period if period >= 1 else None
    if excitation.kind == "prbs":
        length = (2 ** int(excitation.register_length) - 1) * int(excitation.clock_divider)
        periods = max(1, int(round(excitation.duration_s * fs / length)))
        return length if periods >= 3 else None
    return None
