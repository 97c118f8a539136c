"""Excitation signals: sine, square, chirp, step, band-limited noise, PRBS, multisine,
velocity ramps for friction tests, fades and crest factor.

All generators are pure functions returning float64 arrays (or small frozen
dataclasses holding them); see :mod:`hilident.signals.generators`.

The names are loaded from :mod:`~hilident.signals.generators` on first use, so
the argument checks in :mod:`~hilident.signals._checks` (which the config
loader uses) come without numpy.

May import ``errors`` only (pure).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("hilident.signals.generators"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
