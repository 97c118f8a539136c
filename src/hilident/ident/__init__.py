"""Identification numerics: friction, signal conditioning, frequency responses, resonances.

Pure functions on numpy arrays; no files, devices or clocks.
"""

from hilident.ident.frequency import (
    FrequencyResponse,
    etfe,
    frf_from_reference,
    h1_estimate,
    periodic_frf,
)
from hilident.ident.friction import (
    FrictionFit,
    SteadyStatePoints,
    StribeckParams,
    compensate,
    fit_coulomb_viscous,
    fit_stribeck,
    steady_state_points,
    stribeck,
)
from hilident.ident.preprocess import (
    bandpass,
    central_difference,
    check_signals,
    detrend,
    highpass,
    lowpass,
)
from hilident.ident.resonance import Resonance, find_resonances, fit_local_mode

__all__ = [
    "FrequencyResponse",
    "etfe",
    "frf_from_reference",
    "h1_estimate",
    "periodic_frf",
    "FrictionFit",
    "SteadyStatePoints",
    "StribeckParams",
    "compensate",
    "fit_coulomb_viscous",
    "fit_stribeck",
    "steady_state_points",
    "stribeck",
    "bandpass",
    "central_difference",
    "check_signals",
    "detrend",
    "highpass",
    "lowpass",
    "Resonance",
    "find_resonances",
    "fit_local_mode",
]
