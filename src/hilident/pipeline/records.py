"""Resonances, rejected peaks and notches as the plain records ``summary.json`` holds."""

from __future__ import annotations

import numpy as np

from hilident.filters.notch import chain_response
from hilident.pipeline.eligibility import notch_eligibility
from hilident.pipeline.notches import NotchDesign


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
    f = np.asarray(frequency_hz, dtype=float)
    return f, chain_response([d.biquad for d in designs], f, designs[0].sample_rate_hz)
