"""Which resonances get a notch, and the notches designed for them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilident.config.tables import NotchConfig
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, interval_width_hz, notch_from_resonance
from hilident.filters.parametric import attenuation_db
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.resonance import Resonance
from hilident.pipeline.eligibility import coherence_amplitude_factor, notch_eligibility
from hilident.pipeline.plant import PlantResult


@dataclass
class NotchDecision:
    """Which identified resonances get a notch, and why the others do not.

    Attributes
    ----------
    resonances : list of Resonance
        The resonances the evidence supports a notch for (:func:`~hilident.pipeline.eligibility.notch_eligibility`).
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
    resonance gets a notch only when :func:`~hilident.pipeline.eligibility.notch_eligibility` allows it;
    when none does (or none was identified) the reason is given, with the
    amplitude that would have reached the evidence when the measurement
    tells it (:func:`~hilident.pipeline.eligibility.coherence_amplitude_factor`).

    Parameters
    ----------
    plant : PlantResult
        What :func:`~hilident.pipeline.plant.identify_plant` returned.
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


@dataclass
class NotchDesign:
    """One notch, designed for one resonance and assigned to a filter slot.

    Attributes
    ----------
    predicted_band_reduction_db : float
        Band figure (see :func:`~hilident.pipeline.verification.peak_reductions`) the notch gives on the
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
    """Band figure (:func:`~hilident.pipeline.verification.peak_reductions`) predicted for a notch on a resonance, dB.

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
