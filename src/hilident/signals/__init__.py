"""Excitation signals: sine, square, chirp, step, band-limited noise, PRBS, multisine,
velocity ramps for friction tests, fades and crest factor.

All generators are pure functions returning float64 arrays (or small frozen
dataclasses holding them); see :mod:`hilident.signals.generators`.
"""

from hilident.signals.generators import (
    Multisine,
    RampProfile,
    band_limited_noise,
    chirp,
    crest_factor,
    fade,
    multisine,
    prbs,
    ramp_extent,
    sine,
    square,
    step,
    velocity_ramps,
)

__all__ = [
    "Multisine",
    "RampProfile",
    "band_limited_noise",
    "chirp",
    "crest_factor",
    "fade",
    "multisine",
    "prbs",
    "ramp_extent",
    "sine",
    "square",
    "step",
    "velocity_ramps",
]
