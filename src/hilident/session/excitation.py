"""A run's excitation from its configuration: the samples the host plays, or the recipe a drive's generator plays.

The config-level step between ``[excitation]``/``[run]`` and
:func:`hilident.signals.excitation.build_excitation` (pure).
"""

from __future__ import annotations

from typing import Any

from hilident.config.tables import Config, amplitude_ceiling_nm
from hilident.signals.excitation import Excitation
from hilident.signals.excitation import build_excitation as excitation_signal

__all__ = ["Excitation", "build_excitation", "excitation_recipe"]


def build_excitation(cfg: Config, amplitude: Any = None) -> Excitation:
    """The identification excitation of ``cfg`` (:func:`hilident.signals.excitation.build_excitation`).

    Torque (N·m) for ``torque`` and ``torque_injection``; a velocity (m/s) or
    position (m, relative to where the axis holds) set-point perturbation for
    ``velocity`` and ``position``. ``amplitude`` overrides the configured one;
    ``amplitude_nm = "auto"`` builds it at the ceiling auto may choose (what
    the plan shows and the limits are checked against).
    """
    e = cfg.excitation
    if amplitude is None:
        amplitude = (amplitude_ceiling_nm(cfg) or 1.0) if e.amplitude_auto else e.amplitude
    return excitation_signal(e, cfg.run.sample_rate_hz, amplitude, seed=cfg.run.seed)


def excitation_recipe(cfg: Config, amplitude: float | None = None, duration_s: float | None = None) -> dict:
    """``[excitation]`` as parameters, for a drive whose own generator plays it (``device.acquisition = "recorder"``).

    ``amplitude`` and ``duration_s`` override the configured ones (the trials of an automatic amplitude).
    """
    e = cfg.excitation
    return {
        "kind": e.kind,
        "mode": e.mode,
        "amplitude": e.amplitude if amplitude is None else amplitude,
        "amplitude_key": f"excitation.{e.amplitude_key}",
        "f_min_hz": e.f_min_hz,
        "f_max_hz": e.f_max_hz,
        "frequency_hz": e.frequency_hz,
        "duration_s": e.duration_s if duration_s is None else duration_s,
        "period_s": e.period_s,
        "register_length": e.register_length,
        "clock_divider": e.clock_divider,
        "chirp_method": e.chirp_method,
        "sample_rate_hz": cfg.run.sample_rate_hz,
    }
