"""Notch filters and the biquad sections a drive runs them as: pure numerics, no devices.

- ``biquad``: coefficients (:class:`Biquad`) and running sections stepped one sample at a time
- ``notch``: analog notch design, pre-warped Tustin discretisation, float32 and fixed-point quantisation
- ``parametric``: sections from zero/pole frequencies or a rejection band, and the notch a section achieves
- ``covering``: one notch over the range a mode moves through the workspace, or a position-scheduled set

May import ``errors`` and ``numbers`` only (pure).
"""

from hilident.filters.biquad import Biquad, BiquadChain, BiquadSection
from hilident.filters.covering import CoveringResult, covering_notch
from hilident.filters.notch import (
    NotchSpec,
    chain_response,
    design_notch,
    float32_biquad,
    interval_width_hz,
    notch_analog,
    notch_from_resonance,
    quantize_biquad,
    tustin_prewarped,
    width_for_attenuation_hz,
)
from hilident.filters.parametric import (
    achieved_notch,
    attenuation_db,
    notch_width_hz,
    rejection_band_section,
    two_frequency_section,
)

__all__ = [
    "Biquad",
    "BiquadChain",
    "BiquadSection",
    "CoveringResult",
    "NotchSpec",
    "achieved_notch",
    "attenuation_db",
    "chain_response",
    "covering_notch",
    "design_notch",
    "float32_biquad",
    "interval_width_hz",
    "notch_analog",
    "notch_from_resonance",
    "notch_width_hz",
    "quantize_biquad",
    "rejection_band_section",
    "tustin_prewarped",
    "two_frequency_section",
    "width_for_attenuation_hz",
]
