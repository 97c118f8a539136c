"""A transfer function fitted to the measured plant response, and the resonances it confirms."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilident.errors import DataError
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.resonance import RejectedPeak, Resonance
from hilident.ident.tffit import ModalModel, RootReport, TfFit, classify_roots, modal_form, select_structure
from hilident.pipeline.eligibility import notch_eligibility
from hilident.pipeline.findings import Finding


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
        ``reason``. Set by :func:`~hilident.pipeline.plant.identify_plant`.
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


#: A resonance kept on its local evidence while the model misses the data (``{subjects}``: the resonances).
_LOCAL_FIT_ALONE = (
    "the resonance(s) at {subjects} rest on their local fit alone: the fitted model misses the measured response "
    "as a whole"
)
#: A resonance kept without a mode in a model of the highest order allowed (``{subjects}``: the resonances).
_NO_MODE_AT_ORDER_LIMIT = (
    "the resonance(s) at {{subjects}} have no mode in the fitted model, which uses all "
    "identification.model_max_order = {max_order} poles: raise it to let the model hold them"
)


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
    on local evidence good enough for a notch (:func:`~hilident.pipeline.eligibility.notch_eligibility`)
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
    kept, rejected = [], list(rejected)
    warnings: list[str] = []
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
                warnings.append(Finding(_LOCAL_FIT_ALONE, f"{r.frequency_hz:.4g} Hz"))
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
            warnings.append(Finding(_NO_MODE_AT_ORDER_LIMIT.format(max_order=max_order), f"{r.frequency_hz:.4g} Hz"))
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


def model_warnings(model: PlantModel) -> list[str]:
    """What the user should act on or weigh about a fitted model: flagged poles, right-half-plane zeros no delay
    explains, instability, a misfit."""
    roots = model.roots
    out: list[str] = []
    if roots.flagged_poles:
        out.append(
            "transfer-function fit: "
            + "; ".join(
                f"pole at {p['frequency_hz']:.4g} Hz not reported as a mode ({p['reason']})"
                for p in roots.flagged_poles
            )
        )
    out += [
        Finding(_UNEXPLAINED_RHP_ZERO, f"{z['frequency_hz']:.4g} Hz")
        for z in roots.rhp_zeros
        if "equivalent_delay_s" not in z
    ]
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


def model_notes(model: PlantModel) -> list[str]:
    """What is worth knowing about a fitted model and needs no action: right-half-plane zeros a delay explains."""
    return [
        Finding(_DELAY_RHP_ZERO, f"{z['frequency_hz']:.4g} Hz (a {1e3 * z['equivalent_delay_s']:.3g} ms delay)")
        for z in model.roots.rhp_zeros
        if "equivalent_delay_s" in z
    ]


#: A real right-half-plane zero: the phase lag of a delay (``{subjects}``: the zeros and their delays).
_DELAY_RHP_ZERO = (
    "transfer-function fit: right-half-plane zero(s) at {subjects}: the phase lag of a delay (the drive's "
    "computation, transport or current loop), non-minimum phase, not anti-resonances"
)
#: A complex right-half-plane zero pair: no delay explains it (``{subjects}``: the zeros).
_UNEXPLAINED_RHP_ZERO = (
    "transfer-function fit: right-half-plane zero(s) at {subjects} (non-minimum phase, usually a delay or a "
    "non-collocated sensor; not anti-resonances)"
)


#: Weighted cost (about 1 when the model explains the data to within the noise) above which a fit is called a
#: misfit, when it also misses by more than _MISFIT_DB rms (a fit within a dB is useful however small the noise).
_MISFIT_RATIO = 10.0
_MISFIT_DB = 1.0


def _misfits(fit: TfFit) -> bool:
    """The coherence-weighted fit misses the data by far more than their scatter, and by more than a dB."""
    return fit.weighting == "coherence" and fit.weighted_cost > _MISFIT_RATIO and fit.fit_db_rms > _MISFIT_DB
