"""Pure composition of the identification steps: recorded arrays in, models and filters out.

No files, no devices: the session hands arrays to these functions and writes
what they return. The same functions serve ``hilident run`` and, later,
``hilident identify`` on recordings made elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from hilident.config.tables import IdentificationConfig, ModelConfig, NotchConfig
from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, interval_width_hz, notch_from_resonance
from hilident.filters.parametric import attenuation_db
from hilident.ident import friction as fr
from hilident.ident import greybox
from hilident.ident.discretize import sampling_advice
from hilident.ident.frequency import FrequencyResponse, frf_from_reference, h1_estimate, periodic_frf
from hilident.ident.frfquality import check_resolution, estimate_error_std, frf_uncertainty, input_spectrum
from hilident.ident.preprocess import check_signals, lowpass, remove_drift
from hilident.ident.resonance import RejectedPeak, Resonance, screen_resonances
from hilident.ident.tffit import ModalModel, RootReport, TfFit, classify_roots, modal_form, select_structure
from hilident.ident.validation import overfitting_warning


@dataclass
class FrictionResult:
    """Friction identified from constant-velocity windows."""

    fit: fr.FrictionFit
    points: fr.SteadyStatePoints
    model: str
    warnings: list[str] = field(default_factory=list)

    @property
    def slowest_mps(self) -> float:
        """The slowest steady speed the friction was measured at, m/s: the curve is not extrapolated below it."""
        speeds = np.abs(np.asarray(self.points.v_mean, dtype=float))
        speeds = speeds[speeds > 0.0]
        return float(speeds.min()) if speeds.size else 0.0


def identify_friction(velocity, torque, windows, model: str = "stribeck") -> FrictionResult:
    """Steady-state friction points and the fitted friction curve.

    Parameters
    ----------
    velocity, torque : array_like
        Recorded velocity (m/s) and measured torque (N·m) of the friction test.
    windows : sequence of (start, stop, nominal_velocity_mps)
        Sample ranges at constant velocity.
    model : {"stribeck", "coulomb_viscous"}
        ``"stribeck"``: the Stribeck structure the points support (Coulomb + viscous,
        fixed exponents or all six parameters, by AICc; :func:`~hilident.ident.friction.fit_friction`).
    """
    checked = check_signals({"velocity": velocity, "torque": torque})
    points = fr.steady_state_points(checked["velocity"], checked["torque"], windows)
    if len(points.v_mean) < 4:
        raise DataError(
            f"only {len(points.v_mean)} steady constant-velocity windows; a friction fit needs at least 4 "
            "(longer friction_test.hold_s, or slower accelerations)"
        )
    fit = (
        fr.fit_friction(points.v_mean, points.tau_mean)
        if model == "stribeck"
        else fr.fit_coulomb_viscous(points.v_mean, points.tau_mean)
    )
    loose = fr.undetermined(fit)
    warnings = []
    if loose:
        se = ", ".join(f"{n} {getattr(fit.params, n):.3g} +- {fit.stderr[n]:.2g}" for n in loose)
        warnings.append(
            f"friction: {se}: not determined by the {fit.n_points} points (standard error above the "
            "value); measure more speeds around where the torque bends (friction_test.speeds_mps) or "
            "hold each longer (friction_test.hold_s) before trusting them"
        )
    return FrictionResult(fit=fit, points=points, model=model, warnings=warnings)


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
    model: PlantModel | None = None
    quality: dict = field(default_factory=dict)
    rejected: list[RejectedPeak] = field(default_factory=list)


@dataclass
class PlantModel:
    """A transfer function fitted to the plant's measured response.

    Attributes
    ----------
    fit : TfFit
    modal : ModalModel
        The same transfer function as resonances and anti-resonances (every
        root, supported or not).
    candidates : list of dict
        Structures tried: ``n_num``, ``n_den``, ``integrators``,
        ``weighted_cost``, ``mdl``, ``aic``, ``selected``.
    roots : RootReport
        The roots the data support (modes) and those they do not (flagged
        poles, right-half-plane zeros).
    criterion : str
        What chose the structure.
    mode_notes : list of dict
        One per supported mode: ``frequency_hz``, ``damping_ratio``,
        ``reported`` (a top-level resonance confirms it) and, when not,
        ``reason``. Set by :func:`identify_plant`.
    """

    fit: TfFit
    modal: ModalModel
    candidates: list
    roots: RootReport
    criterion: str = "mdl"
    mode_notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        f, m = self.fit, self.modal
        roots = self.roots or classify_roots(f)
        out = {
            "n_num": f.n_num,
            "n_den": f.n_den,
            "integrators": f.integrators,
            "relative_degree": f.n_den + f.integrators - f.n_num,
            "criterion": self.criterion,
            "band_hz": list(f.band_hz),
            "fit_db_rms": f.fit_db_rms,
            "phase_rms_deg": f.phase_rms_deg,
            "weighted_cost": f.weighted_cost,
            "gain": m.gain,
            **roots.to_dict(),
            "poles_rad_s": [[p.real, p.imag] for p in f.poles],
            "zeros_rad_s": [[z.real, z.imag] for z in f.zeros],
            "num": list(f.num),
            "den": list(f.den),
            "candidates": self.candidates,
        }
        if self.mode_notes:
            out["resonances"] = self.mode_notes
        return out


def _auto(value) -> int | None:
    """``"auto"`` (or None) -> None, else the integer a string config key holds."""
    return None if value in (None, "auto") else int(value)


def fit_plant_model(
    frf: FrequencyResponse,
    band_hz: tuple[float, float],
    max_order: int,
    coherence_threshold: float = 0.0,
    order=None,
    relative_degree=None,
    integrators=None,
    criterion: str = "mdl",
) -> PlantModel:
    """Transfer function and modal form of a measured plant response.

    Numerator and denominator degrees, integrators (rigid-body modes) and
    relative degree are chosen by
    :func:`~hilident.ident.tffit.select_structure` with a criterion that
    penalises order (MDL on the coherence-weighted complex error by
    default), each bin weighted by its coherence; any of them can be fixed.
    The roots are then sorted by :func:`~hilident.ident.tffit.classify_roots`
    into modes the data support and flagged poles / right-half-plane zeros.

    Parameters
    ----------
    frf : FrequencyResponse
    band_hz : (float, float)
        Band fitted, Hz.
    max_order : int
        Highest denominator degree tried (integrators included).
    coherence_threshold : float
        Bins under it are left out.
    order, relative_degree, integrators : int or "auto", optional
        Fixed structure (``[identification] model_order``,
        ``model_relative_degree``, ``model_integrators``).
    criterion : {"mdl", "aic", "validation"}

    Raises
    ------
    DataError
        No fit, or too few coherent bins.
    """
    f_lo, f_hi = band_hz
    frf = frf.band(f_lo, f_hi)
    keep = frf.coherence >= coherence_threshold if np.all(np.isfinite(frf.coherence)) else np.ones(len(frf), bool)
    if keep.sum() < 8:
        raise DataError(f"only {int(keep.sum())} bins with coherence >= {coherence_threshold:g} to fit a model to")
    resolution = float(np.median(np.diff(frf.frequency_hz))) if len(frf) > 1 else None
    frf = FrequencyResponse(frf.frequency_hz[keep], frf.response[keep], frf.coherence[keep], frf.n_averages, frf.method)
    weights = "coherence" if np.all(np.isfinite(frf.coherence)) and frf.n_averages > 1 else None
    if weights == "coherence":
        # a bin with coherence 1 (noise-free) would get infinite weight
        frf = FrequencyResponse(
            frf.frequency_hz, frf.response, np.minimum(frf.coherence, 0.9999), frf.n_averages, frf.method
        )
    order, relative_degree, integrators = _auto(order), _auto(relative_degree), _auto(integrators)
    top = max(max_order, order or 1, 1)
    fit, table = select_structure(
        frf,
        max_order=top,
        order=order,
        relative_degree=relative_degree,
        integrators=integrators,
        criterion=criterion,
        weights=weights,
    )
    candidates = [
        {
            "n_num": r.n_num,
            "n_den": r.n_den,
            "integrators": r.integrators,
            "selected": r.selected,
            "weighted_cost": None if r.fit is None else r.fit.weighted_cost,
            "mdl": None if r.fit is None else r.bic,
            "aic": None if r.fit is None else r.aic,
        }
        for r in table
    ]
    roots = classify_roots(
        fit, band_hz=(float(frf.frequency_hz.min()), float(frf.frequency_hz.max())), resolution_hz=resolution
    )
    return PlantModel(fit=fit, modal=modal_form(fit), candidates=candidates, roots=roots, criterion=criterion)


def reconcile_resonances(
    found: list[Resonance], rejected: list[RejectedPeak], model: PlantModel | None, max_order: int, resolution_hz: float
) -> tuple[list[Resonance], list[RejectedPeak], list[str]]:
    """One list of resonances: measured peaks that the fitted model confirms.

    A peak is confirmed by a mode of the model (``model.roots.modes``) within
    its half-power bandwidth, its 95 % frequency interval or two lines,
    whichever is widest. An unconfirmed peak is rejected with the reason,
    unless the model used every pole ``max_order`` allows (it may then lack
    the poles for this mode): a warning says so and the peak stays. When the
    model misses the data as a whole (weighted cost over ``_MISFIT_RATIO``
    and more than ``_MISFIT_DB`` rms) it confirms nothing: a peak stays only
    on local evidence good enough for a notch (:func:`notch_eligibility`)
    and a half-power bandwidth of at least one line. Each model mode is noted
    in ``model.mode_notes`` as reported or not, with the reason.

    Parameters
    ----------
    found, rejected : as :func:`~hilident.ident.resonance.screen_resonances` returns them
    model : PlantModel or None
        Without a model every screened peak is reported.
    max_order : int
        ``[identification] model_max_order``.
    resolution_hz : float
        Line spacing of the response, Hz.

    Returns
    -------
    (list of Resonance, list of RejectedPeak, list of str)
        Reported resonances, rejected peaks (both by frequency) and warnings.
    """
    if model is None or model.roots is None:
        return list(found), list(rejected), []
    modes = list(model.roots.modes)
    at_limit = model.fit.n_den + model.fit.integrators >= max_order
    misfit = _misfits(model.fit)
    kept, rejected, warnings = [], list(rejected), []
    matched: dict[int, float] = {}
    for r in found:
        reach = max(
            r.bandwidth_hz if np.isfinite(r.bandwidth_hz) else 0.0,
            r.frequency_ci95_hz if np.isfinite(r.frequency_ci95_hz) else 0.0,
            2.0 * resolution_hz,
        )
        near = [j for j, (fm, _) in enumerate(modes) if abs(fm - r.frequency_hz) <= reach]
        if misfit:
            # the model cannot confirm anything; a peak stands on its own local evidence only
            ok = notch_eligibility(r)
            if ok["notchable"] and not r.bandwidth_hz >= resolution_hz:
                # a fitted mode narrower than a line rests on the skirts of one or two bins: one noisy line
                # fits that as well as a mode does (a weak excitation showed a 68.7 Hz "mode" of a 94 Hz plant)
                ok = {
                    "notchable": False,
                    "reason": f"its half-power bandwidth ({r.bandwidth_hz:.3g} Hz) is narrower "
                    f"than the line spacing ({resolution_hz:.3g} Hz): one line's error may make the peak",
                }
            if ok["notchable"]:
                kept.append(r)
                warnings.append(
                    f"the resonance at {r.frequency_hz:.4g} Hz rests on its local fit alone: the fitted "
                    "model misses the measured response as a whole"
                )
            else:
                rejected.append(
                    RejectedPeak(
                        r.frequency_hz,
                        r.peak_magnitude_db,
                        r.coherence,
                        "not confirmed: the fitted model misses the measured response as a whole "
                        f"({model.fit.fit_db_rms:.1f} dB rms) and {ok['reason']}",
                    )
                )
        elif near:
            j = min(near, key=lambda j: abs(modes[j][0] - r.frequency_hz))
            matched[j] = r.frequency_hz
            kept.append(r)
        elif at_limit:
            kept.append(r)
            warnings.append(
                f"the resonance at {r.frequency_hz:.4g} Hz has no mode in the fitted model, which uses all "
                f"identification.model_max_order = {max_order} poles: raise it to let the model hold this mode"
            )
        else:
            rejected.append(
                RejectedPeak(
                    r.frequency_hz,
                    r.peak_magnitude_db,
                    r.coherence,
                    f"not confirmed by the fitted model (no pole pair within {reach:.3g} Hz; "
                    f"the model's structure {model.fit.n_num}/"
                    f"{model.fit.n_den + model.fit.integrators} was chosen by {model.criterion})",
                )
            )
    notes = []
    for j, (fm, zm) in enumerate(modes):
        if j in matched:
            notes.append({"frequency_hz": fm, "damping_ratio": zm, "reported": True, "resonance_hz": matched[j]})
            continue
        peak = min(rejected, key=lambda p: abs(p.frequency_hz - fm), default=None)
        if peak is not None and abs(peak.frequency_hz - fm) <= max(2.0 * zm * fm, 2.0 * resolution_hz):
            why = f"its peak in the measured response was rejected: {peak.reason}"
        else:
            why = "no peak of the measured response stands out of the scatter there"
        notes.append({"frequency_hz": fm, "damping_ratio": zm, "reported": False, "reason": why})
    model.mode_notes = notes
    return kept, sorted(rejected, key=lambda p: p.frequency_hz), warnings


def coherence_amplitude_factor(coherence: float, target: float) -> float:
    """Factor on the excitation amplitude that lifts `coherence` to `target` when the noise stays as measured.

    Coherence is ``SNR / (1 + SNR)`` with the power ratio ``SNR`` growing as
    the amplitude squared, so the factor is
    ``sqrt((t / (1 - t)) / (c / (1 - c)))``. NaN for a coherence of 0 or 1.
    """
    c, t = float(coherence), min(float(target), 0.999)
    if not (0.0 < c < 1.0):
        return float("nan")
    return float(np.sqrt((t / (1.0 - t)) / (c / (1.0 - c))))


#: A notch needs the local fit's error within this many times the scatter of each bin
#: (:attr:`Resonance.local_fit_ratio`), or, without coherence, within NOTCH_FIT_FLOOR_DB rms.
NOTCH_FIT_NOISE_RATIO = 3.0
NOTCH_FIT_FLOOR_DB = 1.0
#: A notch needs the 95 % interval of its resonance's frequency within this fraction of the frequency either side
#: (the precision a notch is placed with and verified against): a damped mode's half-power bandwidth alone would
#: allow an interval of +-zeta, several per cent.
NOTCH_FREQUENCY_TOLERANCE = 0.005


def notch_eligibility(res: Resonance) -> dict:
    """Whether a resonance may be notched, and why not.

    A notch needs a resonance from a local fit whose 95 % frequency interval
    (full width ``2 frequency_ci95_hz``) is narrower than its half-power
    bandwidth ``2 zeta f`` and within :data:`NOTCH_FREQUENCY_TOLERANCE` of
    the frequency either side, and whose fit error is within
    :data:`NOTCH_FIT_NOISE_RATIO` times the scatter of each bin
    (``local_fit_ratio``; without coherence, :data:`NOTCH_FIT_FLOOR_DB` rms).

    Returns
    -------
    dict
        ``frequency_hz``, ``notchable`` (bool), ``reason`` ("" when
        notchable) and ``amplitude_factor``: by how much the excitation
        amplitude would have to grow for the interval to be half the bandwidth
        (and, when it is wider than the tolerance, half the tolerance; the
        interval shrinks as ``1 / (amplitude sqrt(averages))`` while the noise
        dominates; 1.0 when nothing needs to change, NaN when unknown).
    """
    out = {"frequency_hz": res.frequency_hz, "notchable": False, "reason": "", "amplitude_factor": float("nan")}
    if res.method != "fit" or not np.isfinite(res.frequency_ci95_hz):
        out["reason"] = (
            f"no local fit of the peak at {res.frequency_hz:.4g} Hz (method {res.method!r}): "
            "its frequency and damping are read off the frequency grid"
        )
        return out
    interval, bandwidth = 2.0 * res.frequency_ci95_hz, res.bandwidth_hz
    tolerance_hz = NOTCH_FREQUENCY_TOLERANCE * res.frequency_hz
    factor = float(max(1.0, 2.0 * interval / bandwidth))
    out["amplitude_factor"] = factor
    if not interval < bandwidth:
        out["reason"] = (
            f"the 95 % interval of its frequency ({res.frequency_hz:.4g} +- "
            f"{res.frequency_ci95_hz:.3g} Hz) is not narrower than its half-power bandwidth "
            f"({bandwidth:.3g} Hz): a notch could miss it"
        )
        return out
    if not res.frequency_ci95_hz <= tolerance_hz:
        out["amplitude_factor"] = float(max(factor, 2.0 * res.frequency_ci95_hz / tolerance_hz))
        out["reason"] = (
            f"the 95 % interval of its frequency ({res.frequency_hz:.4g} +- "
            f"{res.frequency_ci95_hz:.3g} Hz) is wider than +-{100 * NOTCH_FREQUENCY_TOLERANCE:g} % "
            "of it: the notch could sit off the mode by more than that"
        )
        return out
    if np.isfinite(res.local_fit_ratio):
        if not res.local_fit_ratio <= NOTCH_FIT_NOISE_RATIO:
            out["reason"] = (
                f"the local fit misses the measured peak by {res.local_fit_ratio:.1f} times the "
                f"scatter of the estimate ({res.local_fit_db_rms:.2f} dB rms; allowed "
                f"{NOTCH_FIT_NOISE_RATIO:g} times): the peak is not one clean mode"
            )
            return out
    elif not res.local_fit_db_rms <= NOTCH_FIT_FLOOR_DB:
        out["reason"] = (
            f"the local fit misses the measured peak by {res.local_fit_db_rms:.2f} dB rms (allowed "
            f"{NOTCH_FIT_FLOOR_DB:g} dB without a coherence to judge it by): the peak is not one "
            "clean mode"
        )
        return out
    out["notchable"] = True
    return out


@dataclass
class NotchDecision:
    """Which identified resonances get a notch, and why the others do not.

    Attributes
    ----------
    resonances : list of Resonance
        The resonances the evidence supports a notch for (:func:`notch_eligibility`).
    warnings : list of str
        What the user should know: each refused resonance with its reason and
        what to change, or why nothing was found.
    skipped_reason : str or None
        ``upload.skipped_reason`` of ``summary.json`` when no notch is
        designed, else None.
    """

    resonances: list
    warnings: list[str] = field(default_factory=list)
    skipped_reason: str | None = None


def notch_decision(
    plant: PlantResult, coherence_threshold: float, amplitude_key: str, amplitude: float | None = None
) -> NotchDecision:
    """The resonances of an identification run that may be notched, with the reasons for the others.

    This is the whole decision between identification and upload: a
    resonance gets a notch only when :func:`notch_eligibility` allows it;
    when none does (or none was identified) the reason is given, with the
    amplitude that would have reached the evidence when the measurement
    tells it (:func:`coherence_amplitude_factor`).

    Parameters
    ----------
    plant : PlantResult
        What :func:`identify_plant` returned.
    coherence_threshold : float
        ``[identification] coherence_threshold``.
    amplitude_key : str
        The ``[excitation]`` key holding the amplitude (``amplitude_nm``, ...), named in the advice.
    amplitude : float, optional
        The amplitude played, in that key's unit; None when it is not a number
        the advice can scale.

    Returns
    -------
    NotchDecision
    """

    def raise_to(factor: float) -> str:
        if not (np.isfinite(factor) and factor > 1.0):
            # no figure from the measurement (a misfit, a peak without a fit): friction and noise
            # weigh less at a higher amplitude, so try twice the amplitude
            value = f" to {2 * amplitude:.3g}" if amplitude else ""
            return (
                f"; try excitation.{amplitude_key}{value} (x2): friction and noise distort a peak less "
                "at a higher amplitude"
            )
        value = f" to {amplitude * factor:.3g}" if amplitude else ""
        return (
            f"; raise excitation.{amplitude_key}{value} (x{factor:.2g}) or record {factor**2:.2g} times "
            "as many periods (excitation.duration_s)"
        )

    if not plant.resonances:
        low = [p for p in plant.rejected if p.coherence < coherence_threshold]
        hint = ""
        if low:
            peak = max(low, key=lambda p: p.peak_magnitude_db)
            target = min(coherence_threshold + 0.1, 0.95)
            hint = (
                f"; the strongest peak ({peak.frequency_hz:.4g} Hz) has coherence {peak.coherence:.2f} "
                f"(target {target:.2f})" + raise_to(coherence_amplitude_factor(peak.coherence, target))
            )
        elif plant.rejected:
            hint = raise_to(float("nan"))
        reason = "no resonance was identified, so no notch was designed (see rejected_peaks)" + hint
        return NotchDecision([], [reason] if hint else [], reason)
    keep, reasons = [], []
    for r in plant.resonances:
        ok = notch_eligibility(r)
        if ok["notchable"]:
            keep.append(r)
        else:
            reasons.append(f"no notch at {r.frequency_hz:.4g} Hz: {ok['reason']}{raise_to(ok['amplitude_factor'])}")
    return NotchDecision(keep, reasons, None if keep else "; ".join(reasons))


def bode_extras(plant: PlantResult) -> dict:
    """The fitted model's curve and the plant response's 95 % band, as :func:`report.plot_bode` takes them."""
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


def measurement_quality(
    plant: FrequencyResponse,
    resonances: list[Resonance],
    excitation,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    period_samples: int | None,
    antiresonances_hz=(),
) -> tuple[dict, list[str]]:
    """Uncertainty at the resonances, resolution, input spectrum and sampling advice of one run."""
    warnings: list[str] = []
    out: dict = {
        "frequency_resolution_hz": float(np.median(np.diff(plant.frequency_hz))) if len(plant) > 1 else None,
        "n_averages": plant.n_averages,
    }
    if plant.n_averages >= 2:
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
        out["uncertainty"] = {
            "at_resonances": rows,
            "median_magnitude_rel_std": float(np.nanmedian(unc.magnitude_rel_std[in_band])) if in_band.any() else None,
        }
    if len(plant) > 1:
        check = check_resolution(plant, [(r.frequency_hz, r.damping_ratio) for r in resonances], antiresonances_hz)
        out["resolution"] = {
            "resolution_hz": check.resolution_hz,
            "resonances": check.bins_per_bandwidth,
            "lowest_antiresonance": check.antiresonance,
            "required_record_s": check.required_record_s,
        }
        warnings += check.warnings
    try:
        spec = input_spectrum(
            excitation, sample_rate_hz, band_hz, segment_length=period_samples, periodic=bool(period_samples)
        )
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
        advice.append(
            {
                "frequency_hz": r.frequency_hz,
                "sample_rate_min_hz": a["sample_rate_min_hz"],
                "sample_rate_max_hz": a["sample_rate_max_hz"],
                "nyquist_sample_rate_min_hz": a["nyquist_sample_rate_min_hz"],
                "within_rule": bool(a["sample_rate_min_hz"] <= sample_rate_hz <= a["sample_rate_max_hz"]),
            }
        )
    out["sampling"] = {
        "sample_rate_hz": sample_rate_hz,
        "rule": "omega0 * h = 0.2 .. 0.6 (for discrete-time models)",
        "resonances": advice,
    }
    warnings += _sampling_warnings(advice, sample_rate_hz)
    if band_hz[1] > 0.4 * sample_rate_hz:
        warnings.append(
            f"the band reaches {band_hz[1]:g} Hz, above 40 % of the {sample_rate_hz:g} Hz sample rate: "
            "anti-aliasing and hold effects distort the top of the band"
        )
    return out, warnings


def _sampling_warnings(advice: list[dict], sample_rate_hz: float) -> list[str]:
    """What to change when the sample rate breaks the ``omega0 h = 0.2 .. 0.6`` rule for a resonance."""
    out = []
    for a in advice:
        if a["within_rule"]:
            continue
        f0, lo, hi = a["frequency_hz"], a["sample_rate_min_hz"], a["sample_rate_max_hz"]
        if sample_rate_hz > hi:
            factor = int(np.ceil(sample_rate_hz / hi))
            change = (
                f"decimate by {factor} (to {sample_rate_hz / factor:.4g} Hz) before fitting a discrete-time "
                "model (ARX, discretised grey-box)"
            )
        else:
            change = f"sample at {lo:.4g} Hz or faster (run.sample_rate_hz)"
        out.append(
            f"sampling: {sample_rate_hz:g} Hz is outside {lo:.4g}-{hi:.4g} Hz, the omega0 * h = 0.2 .. 0.6 "
            f"rule for the {f0:.4g} Hz resonance (sampling.within_rule: false): {change}; the frequency "
            "response and the notch do not depend on it"
        )
    return out


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
    """
    # only read here, never written: no copies of a long record
    s = check_signals({"excitation": excitation, "torque": torque, "output": output, "velocity": velocity}, copy=False)
    warnings: list[str] = []
    u = s["torque"]
    if friction is not None:
        u = fr.compensate(u, s["velocity"], friction, velocity_deadband_mps, friction_slowest_mps)
    u, y = (_condition(x, cfg, sample_rate_hz, period_samples) for x in (u, s["output"]))
    # a recording without an excitation column gives the torque as excitation: condition it once
    r = (
        u
        if s["excitation"] is s["torque"] and friction is None
        else _condition(s["excitation"], cfg, sample_rate_hz, period_samples)
    )
    del s
    averaged = _averaged_period(len(r), period_samples)
    if averaged is not None:
        plant = periodic_frf(u, y, averaged, sample_rate_hz, skip_periods=0, bins=excited_bins)
        loop = periodic_frf(r, y, averaged, sample_rate_hz, skip_periods=0, bins=excited_bins)
    else:
        seg = _segment(len(r), cfg, sample_rate_hz, period_samples, warnings)
        plant = frf_from_reference(r, u, y, sample_rate_hz, seg)
        loop = h1_estimate(r, y, sample_rate_hz, seg)
    resonances, rejected, more = _resonances_and_model(plant, cfg, band_hz)
    warnings += more
    model = more.model
    antires = [hz for hz, _ in model.roots.antiresonances] if model else []
    quality, more = measurement_quality(plant, resonances, r, sample_rate_hz, band_hz, averaged, antires)
    return PlantResult(
        plant=plant,
        loop=loop,
        resonances=resonances,
        warnings=warnings + more,
        model=model,
        quality=quality,
        rejected=rejected,
    )


class _Notes(list):
    """Warnings, and the model fitted on the way."""

    model: PlantModel | None = None


def _resonances_and_model(plant: FrequencyResponse, cfg: IdentificationConfig, band_hz):
    """Screened peaks, the fitted model, and the one list of resonances both support."""
    notes = _Notes()
    # every candidate first: the count limit applies to the peaks the model confirms
    found, rejected = screen_resonances(
        plant,
        coherence_threshold=cfg.coherence_threshold,
        min_prominence_db=cfg.min_prominence_db,
        max_count=_MAX_CANDIDATES,
        band_hz=band_hz,
    )
    if cfg.model_max_order:
        try:
            notes.model = fit_plant_model(
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
            notes.append(f"transfer-function fit: {exc}")
    if notes.model is not None:
        notes += _model_warnings(notes.model)
    resolution = float(np.median(np.diff(plant.frequency_hz))) if len(plant) > 1 else 0.0
    found, rejected, more = reconcile_resonances(found, rejected, notes.model, cfg.model_max_order, resolution)
    confirmed = found
    found, rejected = _most_prominent(found, rejected, cfg.max_resonances)
    dropped = [f"at {r.frequency_hz:.4g} Hz" for r in confirmed if r not in found]
    notes += [w for w in more if not any(d in w for d in dropped)]
    if notes.model is not None and notes.model.mode_notes:
        kept = {r.frequency_hz for r in found}
        for note in notes.model.mode_notes:
            if note["reported"] and note["resonance_hz"] not in kept:
                note.update(
                    reported=False,
                    reason="beyond identification.max_resonances = "
                    f"{cfg.max_resonances} (the most prominent are reported)",
                )
                del note["resonance_hz"]
    if not found:
        notes.append(
            f"no resonance with coherence >= {cfg.coherence_threshold:g} and prominence >= "
            f"{cfg.min_prominence_db:g} dB between {band_hz[0]:g} and {band_hz[1]:g} Hz"
            + (f" ({len(rejected)} peak(s) rejected, see rejected_peaks)" if rejected else "")
        )
    return found, rejected, notes


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


def _model_warnings(model: PlantModel) -> list[str]:
    roots = model.roots
    out = []
    if roots.flagged_poles:
        out.append(
            "transfer-function fit: "
            + "; ".join(
                f"pole at {p['frequency_hz']:.4g} Hz not reported as a mode ({p['reason']})"
                for p in roots.flagged_poles
            )
        )
    if roots.rhp_zeros:
        out.append(
            "transfer-function fit: right-half-plane zero(s) at "
            + ", ".join(
                f"{z['frequency_hz']:.4g} Hz"
                + (
                    f" (the phase of a {1e3 * z['equivalent_delay_s']:.3g} ms delay)"
                    if "equivalent_delay_s" in z
                    else ""
                )
                for z in roots.rhp_zeros
            )
            + " (non-minimum phase, usually a delay or a non-collocated sensor; not anti-resonances)"
        )
    if not roots.stable:
        out.append(f"transfer-function fit: the model is not stable ({roots.stability})")
    fit = model.fit
    if _misfits(fit):
        out.append(
            f"transfer-function fit: the best structure misses the measured response by "
            f"{fit.fit_db_rms:.1f} dB rms, {np.sqrt(fit.weighted_cost):.1f} times the scatter the coherence "
            "implies: the response is not that of a linear plant at this amplitude (friction sticking, "
            "backlash) or the excitation is too weak for its coherence to mean much (raise the excitation "
            "amplitude)"
        )
    return out


#: Weighted cost (about 1 when the model explains the data to within the noise) above which a fit is called a
#: misfit, when it also misses by more than _MISFIT_DB rms (a fit within a dB is useful however small the noise).
_MISFIT_RATIO = 10.0
_MISFIT_DB = 1.0


def _misfits(fit: TfFit) -> bool:
    """The coherence-weighted fit misses the data by far more than their scatter, and by more than a dB."""
    return fit.weighting == "coherence" and fit.weighted_cost > _MISFIT_RATIO and fit.fit_db_rms > _MISFIT_DB


def _condition(
    x: np.ndarray, cfg: IdentificationConfig, sample_rate_hz: float, period_samples: int | None
) -> np.ndarray:
    """Optional zero-phase low-pass, then the mean and a slow drift removed (:func:`remove_drift`).

    The same filter on every signal of a ratio leaves the ratio intact.
    """
    if cfg.lowpass_hz:
        x = lowpass(x, cfg.lowpass_hz, sample_rate_hz)
    return remove_drift(x, period_samples)


def _averaged_period(n: int, period_samples: int | None) -> int | None:
    """The period, samples, when a record of ``n`` samples holds two whole periods to average; else None."""
    return period_samples if period_samples and n >= 2 * period_samples else None


def _segment(
    n: int, cfg: IdentificationConfig, sample_rate_hz: float, period_samples: int | None, warnings: list[str]
) -> int:
    """Welch segment length for a record of ``n`` samples that does not hold two whole periods."""
    if period_samples:
        warnings.append("fewer than two whole excitation periods recorded: Welch averaging used instead")
    seg = int(round(cfg.segment_s * sample_rate_hz))
    if seg > n // 2:
        seg = n // 2
        warnings.append(f"identification.segment_s longer than half the record: {seg / sample_rate_hz:g} s used")
    return seg


def loop_response(
    excitation,
    output,
    sample_rate_hz: float,
    cfg: IdentificationConfig,
    period_samples: int | None = None,
    excited_bins=None,
) -> tuple[FrequencyResponse, list[str]]:
    """Excitation-to-output response through the drive, as :func:`identify_plant` computes its ``loop``.

    This is all a verification run needs: no friction model, no resonance search.
    """
    s = check_signals({"excitation": excitation, "output": output}, copy=False)
    warnings: list[str] = []
    r, y = (_condition(x, cfg, sample_rate_hz, period_samples) for x in (s["excitation"], s["output"]))
    averaged = _averaged_period(len(r), period_samples)
    if averaged is not None:
        return periodic_frf(r, y, averaged, sample_rate_hz, skip_periods=0, bins=excited_bins), warnings
    return h1_estimate(r, y, sample_rate_hz, _segment(len(r), cfg, sample_rate_hz, period_samples, warnings)), warnings


def pooled_loop_response(
    excitations, outputs, sample_rate_hz: float, cfg: IdentificationConfig, period_samples: int, excited_bins=None
) -> FrequencyResponse:
    """:func:`loop_response` over several records of one periodic excitation, their periods averaged together.

    Each record (whole steady-state periods, its lead-in dropped: :func:`select_gap_free`) is conditioned
    on its own, since its drift is its own, and then every period of every record is one average of
    :func:`~hilident.ident.frequency.periodic_frf`. A record whose length is no whole number of periods is
    an error, because splicing it would leak.
    """
    pairs = list(zip(excitations, outputs, strict=True))
    if not pairs:
        raise DataError("no records to pool")
    for r, _ in pairs:
        if len(r) % period_samples or len(r) < period_samples:
            raise DataError(f"a record of {len(r)} samples holds no whole number of {period_samples}-sample periods")
    r = np.concatenate([_condition(np.asarray(x, dtype=float), cfg, sample_rate_hz, period_samples) for x, _ in pairs])
    y = np.concatenate([_condition(np.asarray(x, dtype=float), cfg, sample_rate_hz, period_samples) for _, x in pairs])
    return periodic_frf(r, y, period_samples, sample_rate_hz, skip_periods=0, bins=excited_bins)


def filtered_plant_response(to_output: FrequencyResponse, to_command: FrequencyResponse) -> FrequencyResponse:
    """The filter slots and the plant together, ``N G``, measured in closed loop: command to output.

    The excitation enters ahead of the filter slots while a loop holds the axis, so the command
    entering the slots (controller output plus injection) and the output both respond to it:
    ``to_output = y/r = N G S`` and ``to_command = u/r = S`` (both :func:`loop_response` of one
    record), and their ratio is ``N G`` whatever the loop adds (the indirect method of
    :func:`hilident.ident.frequency.frf_from_reference`). It is what an open-loop torque run
    measures, so a band figure on it compares with one of a single-position run. The coherence is
    the product of the two responses' coherences.
    """
    # u/r is never zero on an excited line: the excitation itself is part of the command
    return replace(
        to_output,
        response=to_output.response / to_command.response,
        coherence=to_output.coherence * to_command.coherence,
    )


@dataclass
class NotchDesign:
    """One notch, designed for one resonance and assigned to a filter slot.

    Attributes
    ----------
    predicted_band_reduction_db : float
        Band figure (see :func:`peak_reductions`) the notch gives on the
        resonance's local model, worst case over its 95 % frequency interval.
    warning : str
        Set when the width search could not reach the target.
    width_reason : str
        What set ``spec.width_hz`` (:data:`WIDTH_REASONS`); "" when unknown
        (a notch taken over from a file).
    attenuation_at_ci95_db : float
        Attenuation of ``biquad`` at the worse end of the resonance's 95 %
        frequency interval ``f -+ frequency_ci95_hz``, dB (NaN without an interval).
    """

    spec: NotchSpec
    biquad: Biquad
    slot: int
    sample_rate_hz: float
    resonance: Resonance
    predicted_band_reduction_db: float = float("nan")
    warning: str = ""
    width_reason: str = ""
    attenuation_at_ci95_db: float = float("nan")


#: Why a designed notch is as wide as it is: today's rule (``width_factor`` half-power bandwidths, at least
#: ``min_width_ratio`` of the centre), the 95 % interval of the frequency (``target_attenuation_db`` at both of its
#: ends), the width search for the predicted band figure (``min_reduction_db``), or the range a mapped mode moves
#: through (``[map]``: the covering notch; its ``attenuation_at_ci95_db`` is the worst case over that range).
WIDTH_REASONS = (
    "resonance bandwidth",
    "minimum width ratio",
    "frequency uncertainty",
    "band figure",
    "workspace range",
)


def band_of(frequency_hz: float, damping_ratio: float, bandwidths: float) -> tuple[float, float]:
    """``f -+ bandwidths * 2 zeta f``, the band of the verification's band figure, Hz (at least +-1 % of f)."""
    half = bandwidths * 2.0 * damping_ratio * frequency_hz if np.isfinite(damping_ratio) else 0.0
    half = max(half, 0.01 * frequency_hz)
    return max(frequency_hz - half, 0.0), frequency_hz + half


def predicted_band_reduction_db(
    res: Resonance, biquad: Biquad, sample_rate_hz: float, bandwidths: float, response: FrequencyResponse | None = None
) -> float:
    """Band figure (:func:`peak_reductions`) a notch is predicted to give on a resonance, dB.

    With the measured `response` (the loop the verification will measure
    again, e.g. ``PlantResult.loop``), the prediction is that response with
    and without the notch in series, over :func:`band_of` around the
    resonance: it includes the background the mode sits on and the
    estimate's own resolution, which is what the verification sees. The
    verification measures the notched response through the same noise: its
    estimate's expected magnitude is ``sqrt(|H N|^2 + |H|^2 (1 - g) / (n g))``
    (``g`` the coherence, ``n`` the averages; the H1 estimate's random error,
    Bendat & Piersol), so a notch cannot be predicted deeper than the noise
    floor lets the verification see. Without it, a single mode ``1 / (1 - r^2
    + 2 j zeta r)``, worst case over the resonance's 95 % frequency interval.
    """
    zeta = res.damping_ratio if np.isfinite(res.damping_ratio) else 0.05
    if response is not None:
        lo, hi = band_of(res.frequency_hz, zeta, bandwidths)
        f = response.frequency_hz
        band = (f >= lo) & (f <= hi) & np.isfinite(response.response)
        if band.sum() >= 2:
            h = response.response[band]
            g = np.clip(np.nan_to_num(response.coherence[band], nan=1.0), 1e-6, 1.0)
            noise = np.abs(h) ** 2 * (1.0 - g) / (max(response.n_averages, 1) * g)
            after = np.sqrt(np.abs(h * biquad.response(f[band], sample_rate_hz)) ** 2 + noise)
            return float(20.0 * np.log10(np.abs(h).max() / max(after.max(), 1e-300)))
    ci = res.frequency_ci95_hz if np.isfinite(res.frequency_ci95_hz) else 0.0
    worst = np.inf
    for f0 in (res.frequency_hz - ci, res.frequency_hz, res.frequency_hz + ci):
        lo, hi = band_of(f0, zeta, bandwidths)
        f = np.linspace(max(lo, 1e-9), hi, 801)
        r = f / f0
        h = 1.0 / (1.0 - r * r + 2j * zeta * r)
        after = np.abs(h * biquad.response(f, sample_rate_hz))
        worst = min(worst, float(20.0 * np.log10(np.abs(h).max() / max(after.max(), 1e-300))))
    return worst


#: Margin over ``min_reduction_db`` the width search aims for: the verification repeats a noisy measurement.
PREDICTION_MARGIN_DB = 2.0


def design_notches(
    resonances, cfg: NotchConfig, filter_rate_hz: float, slots: list[int], response: FrequencyResponse | None = None
) -> list[NotchDesign]:
    """A notch per resonance (most prominent first), as many as there are free slots.

    The width starts at ``width_factor`` times the half-power bandwidth
    ``2 zeta f``, at least ``min_width_ratio * f``, so an identification error
    of a fraction of a percent in the centre frequency still leaves the
    resonance deep in the notch. It then grows (by 25 % a step, up to
    ``max_width_ratio * f``) until the predicted band figure
    (:func:`predicted_band_reduction_db`, ``verify_band_bandwidths``) reaches
    ``min_reduction_db`` plus a 2 dB margin; the depth is at least 6 dB more than that. When the
    widest notch still falls short, the design keeps it and says so in
    ``warning`` with the figure it achieves. With `response` (the measured
    loop the verification repeats) the prediction uses it.

    Before the search the width is made at least what the resonance's 95 %
    frequency interval needs: the designed (discrete) notch attenuates at
    least ``target_attenuation_db`` at ``f -+ frequency_ci95_hz``
    (:func:`~hilident.filters.notch.interval_width_hz`, closed form). Each
    design says which rule set its width (``width_reason``) and what it
    attenuates at the ends of the interval.
    """
    ordered = sorted(resonances, key=lambda r: -r.peak_magnitude_db)[: len(slots)]
    designs = []
    target = cfg.min_reduction_db
    depth = max(cfg.depth_db, target + 6.0, cfg.target_attenuation_db + 6.0)
    for slot, res in zip(slots, sorted(ordered, key=lambda r: r.frequency_hz), strict=False):
        zeta = res.damping_ratio if np.isfinite(res.damping_ratio) else 0.05
        spec = notch_from_resonance(
            res.frequency_hz,
            zeta,
            depth_db=depth,
            width_factor=cfg.width_factor,
            min_relative_width=cfg.min_width_ratio,
        )
        reason = (
            "resonance bandwidth" if cfg.width_factor * 2.0 * zeta >= cfg.min_width_ratio else "minimum width ratio"
        )
        ci = res.frequency_ci95_hz
        has_interval = bool(
            np.isfinite(ci) and 0.0 < ci < res.frequency_hz and res.frequency_hz + ci < 0.5 * filter_rate_hz
        )
        needed = (
            interval_width_hz(res.frequency_hz, ci, cfg.target_attenuation_db, depth, filter_rate_hz)
            if has_interval
            else 0.0
        )
        if needed > spec.width_hz:
            spec = NotchSpec(spec.center_hz, needed, spec.depth_db)
            reason = "frequency uncertainty"
        start_width = spec.width_hz
        widest = max(cfg.max_width_ratio * res.frequency_hz, spec.width_hz)
        while True:
            biquad = design_notch(spec, filter_rate_hz)
            predicted = predicted_band_reduction_db(res, biquad, filter_rate_hz, cfg.verify_band_bandwidths, response)
            if predicted >= target + PREDICTION_MARGIN_DB or spec.width_hz >= widest:
                break
            spec = NotchSpec(spec.center_hz, min(1.25 * spec.width_hz, widest), spec.depth_db)
        warning = ""
        if predicted < target:
            warning = (
                f"notch at {res.frequency_hz:.4g} Hz: even {spec.width_hz:.3g} Hz wide (notch.max_width_ratio = "
                f"{cfg.max_width_ratio:g}) it is predicted to reduce the band figure by only {predicted:.1f} dB "
                f"(notch.min_reduction_db = {target:g}): the response beside the mode stays above the notched "
                "peak; a finer frequency resolution (identification.segment_s, excitation.period_s) sharpens "
                "the measured peak"
            )
        if spec.width_hz > start_width:
            reason = "band figure"
        at_ci = float("nan")
        if has_interval:
            at_ci = min(attenuation_db(biquad, res.frequency_hz + side * ci, filter_rate_hz) for side in (-1.0, 1.0))
        designs.append(NotchDesign(spec, biquad, slot, filter_rate_hz, res, predicted, warning, reason, at_ci))
    return designs


def covering_design(map_entries, cfg: NotchConfig, filter_rate_hz: float, realise=None):
    """One notch for the mapped mode over the whole workspace, or a position-scheduled set.

    :func:`hilident.filters.covering.covering_notch` with the run's ``[notch]``
    keys: ``target_attenuation_db`` everywhere in ``[min(f - ci), max(f +
    ci)]`` over the map, a width of at most ``max_width_ratio`` of the centre.

    Parameters
    ----------
    map_entries : iterable
        The ``map`` records (``position_m``, ``frequency_hz``, ``frequency_ci95_hz``).
    cfg : NotchConfig
        The ``[notch]`` table.
    filter_rate_hz : float
        The drive's filter rate, Hz.
    realise : callable, optional
        ``realise(spec) -> Biquad``, the section the device stores for a notch;
        default the exact design.
    """
    from hilident.filters.covering import covering_notch

    return covering_notch(map_entries, filter_rate_hz, cfg.target_attenuation_db, cfg.max_width_ratio, realise=realise)


def peak_reductions(before: FrequencyResponse, after: FrequencyResponse, resonances, band_bandwidths: float = 2.0):
    """Measured reduction of each resonance between two runs with the same excitation.

    Both responses come from measurements; the notch design does not enter the
    numbers. For each resonance two figures are reported:

    * ``band_reduction_db`` (the headline): largest ``|before|`` over largest
      ``|after|`` within ``band_bandwidths`` half-power bandwidths
      (``2 zeta f``) either side of the resonance (:func:`band_of`). It counts
      the skirts a notch leaves and a peak that moved: it is what the Bode
      plot shows a person;
    * ``reduction_db`` (``peak_reduction_db`` in the summary): ``|before| /
      |after|`` at the identified resonance frequency (nearest line).

    Returns
    -------
    list of dict
        ``frequency_hz``, ``before_db``, ``after_db``, ``reduction_db``,
        ``band_hz``, ``band_before_db``, ``band_after_db``,
        ``band_reduction_db`` per resonance.
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
        lo, hi = band_of(res.frequency_hz, res.damping_ratio, band_bandwidths)
        band = np.flatnonzero((f >= lo) & (f <= hi))
        band = band if len(band) else np.array([i])
        b_db, a_db = 20 * np.log10(mag_before[i]), 20 * np.log10(mag_after[i])
        band_b, band_a = 20 * np.log10(mag_before[band].max()), 20 * np.log10(mag_after[band].max())
        out.append(
            {
                "frequency_hz": float(f[i]),
                "before_db": float(b_db),
                "after_db": float(a_db),
                "reduction_db": float(b_db - a_db),
                "band_hz": [float(lo), float(hi)],
                "band_before_db": float(band_b),
                "band_after_db": float(band_a),
                "band_reduction_db": float(band_b - band_a),
            }
        )
    return out


#: Attenuation reported for an exact zero of a stored section (-20 log10 1e-300), dB
_DEEPEST_DB = 6000.0


#: Euler's constant: ``sqrt(ln K + gamma)`` approximates the largest of ``K`` complex Gaussian errors over their rms.
_EULER_GAMMA = 0.5772156649015329


#: A band figure within this of its record's noise floor (:func:`band_floor_db`) is floor-limited, dB.
FLOOR_HEADROOM_DB = 6.0


def floor_limited(band_reduction_db: float, floor_db: float) -> bool:
    """Whether a band figure lies within :data:`FLOOR_HEADROOM_DB` of its record's noise floor: it then says more
    about the record than about the notch (a floor of -inf, a record without coherence, always is)."""
    return bool(floor_db < band_reduction_db + FLOOR_HEADROOM_DB)


def band_floor_db(
    before: FrequencyResponse, after: FrequencyResponse, resonance, band_bandwidths: float = 2.0
) -> float:
    """The largest band figure (:func:`peak_reductions`) the `after` measurement's own noise lets it show, dB.

    A notch takes the response near the mode down, but not what the output
    does that the excitation does not explain: noise, and forces that enter
    behind the filter slots (on the load, say) and drive the mode, which the
    notch may even leave less damped than before. `after` is measured through
    it. Its error per line (:func:`~hilident.ident.frfquality.estimate_error_std`)
    is pooled over the band (rms), and the largest of the band's ``K`` lines'
    errors is expected near ``rms * sqrt(ln K + 0.577)``; the floor is the
    largest ``|before|`` in the band over that. A measured band figure within a
    few dB of its floor says more about the measurement than about the notch:
    longer records lower the floor by 10 dB per tenfold the averages.

    Returns
    -------
    float
        dB; inf when `after` has no noise, NaN when its estimator gives no
        coherence or no line falls in the band.
    """
    lo, hi = band_of(resonance.frequency_hz, resonance.damping_ratio, band_bandwidths)
    in_band = (after.frequency_hz >= lo) & (after.frequency_hz <= hi)
    in_before = (before.frequency_hz >= lo) & (before.frequency_hz <= hi)
    if not in_band.any() or not in_before.any():
        return float("nan")
    errors = estimate_error_std(after)[in_band]
    if not np.all(np.isfinite(errors)):
        return float("nan") if np.isnan(errors).any() else float("-inf")
    rms = float(np.sqrt(np.mean(errors**2)))
    if rms == 0.0:
        return float("inf")
    expected_max = rms * np.sqrt(np.log(in_band.sum()) + _EULER_GAMMA)
    return float(20.0 * np.log10(np.abs(before.response[in_before]).max() / expected_max))


def achieved_notch(design: NotchDesign, stored: Biquad, planned: Biquad | None = None) -> dict:
    """What the section a device stores actually does, next to what was designed.

    A device rounds what it is sent: coefficients to REAL32, fixed point or
    scaled integers; physical notch parameters to its grid (a centre in 1 Hz
    steps, a width from a table). For a notch far below the filter rate that
    rounding can move the notch. This reports where the stored section's
    minimum lies and its attenuation at the designed centre, computed from the
    stored section.

    Parameters
    ----------
    design : NotchDesign
        The notch asked for (centre, width and depth) and its filter rate.
    stored : Biquad
        The section the device runs, from what it reads back.
    planned : Biquad, optional
        The section the host expected the device to store (the design after
        the device's quantisation, before anything was written).

    Returns
    -------
    dict
        ``center_hz`` (deepest point within half an octave, Hz), ``depth_db``
        (its attenuation), ``attenuation_at_design_center_db``,
        ``depth_error_db`` (that attenuation minus the designed depth, dB),
        ``dc_gain``, ``stable``; with ``planned`` also ``realisable_db`` (the
        planned section's attenuation at the designed centre: the design minus
        the device's quantisation), ``quantisation_loss_db`` (designed depth
        minus ``realisable_db``) and ``beyond_quantisation_db``
        (``realisable_db`` minus the stored attenuation: zero when the device
        holds what was planned).
    """
    f0, fs = design.spec.center_hz, design.sample_rate_hz

    def attenuation(section: Biquad) -> float:  # finite at an exact zero, for summary.json
        return min(attenuation_db(section, f0, fs), _DEEPEST_DB)

    grid = np.linspace(0.5 * f0, 1.5 * f0, 4001)
    mag = np.abs(stored.response(grid, fs))
    at_center = attenuation(stored)
    out = {
        "center_hz": float(grid[int(np.argmin(mag))]),
        "depth_db": float(-20 * np.log10(max(mag.min(), 1e-300))),
        "attenuation_at_design_center_db": at_center,
        "depth_error_db": at_center - float(design.spec.depth_db),
        "dc_gain": float(stored.dc_gain()),
        "stable": bool(stored.is_stable()),
    }
    if planned is not None:
        realisable = attenuation(planned)
        out.update(
            realisable_db=realisable,
            quantisation_loss_db=float(design.spec.depth_db) - realisable,
            beyond_quantisation_db=realisable - at_center,
        )
    return out


def resonance_records(resonances) -> list[dict]:
    """Resonances as plain records for ``summary.json``, with their uncertainty and whether they may be notched."""
    out = []
    for r in resonances:
        ok = notch_eligibility(r)
        out.append(
            {
                "frequency_hz": r.frequency_hz,
                "damping_ratio": r.damping_ratio,
                "peak_magnitude_db": r.peak_magnitude_db,
                "coherence": r.coherence,
                "method": r.method,
                "frequency_ci95_hz": r.frequency_ci95_hz,
                "damping_ci95": r.damping_ci95,
                "half_power_bandwidth_hz": r.bandwidth_hz,
                "local_fit_db_rms": r.local_fit_db_rms,
                "local_noise_db_rms": r.local_noise_db_rms,
                "local_fit_ratio": r.local_fit_ratio,
                "notchable": ok["notchable"],
                **({"not_notchable": ok["reason"]} if not ok["notchable"] else {}),
            }
        )
    return out


def rejected_peak_records(rejected) -> list[dict]:
    """Rejected peaks as plain records for ``summary.json`` (``rejected_peaks``)."""
    return [p.to_dict() for p in rejected]


def notch_records(designs: list[NotchDesign]) -> list[dict]:
    """Designed notches as plain records for ``summary.json`` (biquad ``b``, ``a`` in scipy convention)."""
    return [
        {
            "center_hz": d.spec.center_hz,
            "width_hz": d.spec.width_hz,
            "depth_db": d.spec.depth_db,
            "sample_rate_hz": d.sample_rate_hz,
            "slot": d.slot,
            "b": list(d.biquad.b),
            "a": list(d.biquad.a),
            "predicted_band_reduction_db": d.predicted_band_reduction_db,
            **(
                {"width_reason": d.width_reason, "attenuation_at_ci95_db": d.attenuation_at_ci95_db}
                if d.width_reason
                else {}
            ),
        }
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
        return greybox.mass_spring_damper_regression(
            force, position, sample_rate_hz, cutoff, decimate=cfg.decimate, input_hold=cfg.input_hold
        )
    return greybox.rigid_axis_regression(
        position,
        force,
        sample_rate_hz,
        cutoff,
        asymmetric=cfg.asymmetric,
        decimate=cfg.decimate,
        min_speed=cfg.min_speed or None,
        input_hold=cfg.input_hold,
    )


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


def residual_warnings(kind: str, name: str, check: dict) -> list[str]:
    """What failing residual tests of a grey-box fit (:func:`~hilident.ident.greybox.validate_fit`)
    mean and what to change.

    Tests that were not computed (None) say nothing.
    """
    out = []
    p = check.get("ljung_box_p")
    if check.get("residuals_white") is False:
        out.append(
            f"[model] {kind} on {name}: the residuals are not white (Ljung-Box p = "
            f"{'n/a' if p is None else format(p, '.3g')}): "
            "the model leaves dynamics unexplained; try the other input_hold, a lower cutoff_hz, or a model with "
            "more physics (a second mass, friction) before trusting its parameters' standard deviations"
        )
    if check.get("independent_of_input") is False:
        out.append(
            f"[model] {kind} on {name}: the residuals are correlated with the input: part of the input's effect is "
            "missing from the model (a delay, an unmodelled force such as friction, or a wrong kind)"
        )
    return out


def fit_greybox(
    cfg: ModelConfig, torque, position, sample_rate_hz: float, validation_records: dict | None = None
) -> GreyBoxResult:
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
        warnings.append(
            f"{cfg.kind}: {est.low_speed_rows} of {est.low_speed_rows + estimation['samples']} rows "
            f"slower than {est.min_speed:.3g} ({why}) left out of the fit"
        )
    checked = {}
    warnings += residual_warnings(cfg.kind, "the estimation data", estimation)
    for name, (tq, pos) in records.items():
        try:
            checked[name] = greybox.validate_fit(fit, greybox_regression(cfg, tq, pos, sample_rate_hz))
        except DataError as exc:
            warnings.append(f"{cfg.kind} validation on {name}: {exc}")
            continue
        warnings += residual_warnings(cfg.kind, name, checked[name])
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
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


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
        return {
            "rows": int(len(self.keep)),
            "used_rows": self.used_rows,
            "segments": len(self.segments),
            "gaps": self.gaps,
            "n_gaps": self.n_gaps,
            "missing_samples": self.missing_samples,
            "period_samples": self.period_samples,
        }


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
    gaps = [
        {"row": int(b + 1), "sample_index": int(index[b + 1]), "missing_samples": int(step[b] - 1)}
        for b in breaks[:MAX_LISTED_GAPS]
    ]
    missing = int(np.clip(step[breaks] - 1, 0, None).sum()) if len(breaks) else 0
    if period_samples:
        keep, warnings = _whole_periods(index, runs, int(period_samples), name)
    else:
        keep, warnings = _longest_run(len(index), runs, name)
    segments = _kept_segments(keep, step)
    return GapFreeSelection(
        keep, segments, gaps, len(breaks), missing, int(period_samples) if period_samples else None, warnings
    )


def _kept_segments(keep: np.ndarray, step: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` ranges of kept rows that follow each other on the sample clock."""
    joined = np.concatenate(([False], (step == 1) & keep[:-1] & keep[1:]))  # row r continues row r - 1
    starts = np.flatnonzero(keep & ~joined)
    stops = np.flatnonzero(keep & ~np.concatenate((joined[1:], [False]))) + 1
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=False)]


def _longest_run(n: int, runs, name: str) -> tuple[np.ndarray, list[str]]:
    a, b = max(runs, key=lambda r: r[1] - r[0])
    keep = np.zeros(n, dtype=bool)
    keep[a:b] = True
    warnings = []
    if len(runs) > 1:
        warnings.append(
            f"{name}: recording has {len(runs) - 1} gap(s); the longest contiguous stretch "
            f"({b - a} samples) was analysed"
        )
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
            keep[start : start + period] = True
    n_complete = len(taken)
    total = max(int(index.max()) // period, 0)
    warnings = []
    if n_complete < total:
        warnings.append(
            f"{name}: {total - n_complete} of {total} excitation periods had lost samples and were left out"
        )
    if n_complete < 2:
        raise DataError(
            f"{name}: only {n_complete} complete excitation period(s) recorded; at least 2 are needed "
            "(check the line: lost or corrupt frames)"
        )
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
