"""How messy the twin is: the ``[emulator] preset`` and the values it gives unset keys.

A real axis is never as clean as its equations. The ``"bench"`` preset (the
default) gives every emulated axis what a lab bench has: a process torque the
drive does not measure (coloured noise, cogging, load steps), a current loop
of finite bandwidth behind a computation delay, and an encoder whose
interpolation noise dithers its counts. The ``"clean"`` preset gives none of
it: the physics of the first twins, exact, for tests that compare with theory.

Torques scale with the drive's ``torque_max_nm``, because a motor's ripple and a
bench's disturbances grow with the motor: a 20 N·m drive gets 0.06 N·m of noise,
a 2 N·m drive 0.006 N·m (forces on the load: the same fraction of ``c * torque_max_nm``).
A key set in the config always wins over its preset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hilident.config.tables import EmulatorConfig

__all__ = ["Realism", "BENCH", "realism"]

#: Bench-preset levels: torques as fractions of the drive's torque_max_nm, the
#: current loop in Hz, the delay in loop ticks, the encoder noise in counts.
BENCH = {
    "torque_noise_of_max": 0.003,
    "cogging_of_max": 0.005,
    "load_step_of_max": 0.002,
    "load_noise_of_max": 0.003,
    "current_loop_hz": 1000.0,
    "delay_ticks": 1,
    "encoder_noise_counts": 0.5,
}


@dataclass(frozen=True)
class Realism:
    """The effective disturbance, current-loop and encoder settings of a twin.

    Attributes
    ----------
    preset : str
        ``"bench"`` or ``"clean"``.
    torque_noise_nm, torque_noise_corner_hz : float
        Coloured process torque noise: rms (N·m) and low-pass corner (Hz).
    cogging_nm, cogging_period_m : float
        Position-periodic ripple: amplitude (N·m) and period (m).
    load_step_nm, load_step_rate_hz : float
        Random load steps: largest level (N·m) and mean rate (1/s).
    load_noise_n : float
        Coloured force noise on the load, N rms (same corner as the torque noise).
    current_loop_hz : float
        Current-loop bandwidth, Hz (``math.inf``: ideal).
    delay_ticks : int
        Computation delay, loop ticks.
    encoder_noise_m : float
        Encoder interpolation noise, m rms.
    """

    preset: str
    torque_noise_nm: float
    torque_noise_corner_hz: float
    cogging_nm: float
    cogging_period_m: float
    load_step_nm: float
    load_step_rate_hz: float
    load_noise_n: float
    current_loop_hz: float
    delay_ticks: int
    encoder_noise_m: float


def _given(value, bench: float, clean: float, preset: str) -> float:
    if value is not None:
        return value
    return bench if preset == "bench" else clean


def realism(cfg: EmulatorConfig, loop_rate_hz: float) -> Realism:
    """The settings of ``cfg``'s twin: each key as set, else its preset's value.

    Parameters
    ----------
    cfg : EmulatorConfig
    loop_rate_hz : float
        The drive's control loop rate, Hz (the delay is whole ticks of it).

    Examples
    --------
    >>> from hilident.config.tables import parse_config
    >>> r = realism(parse_config("[emulator.drive]\\ntorque_max_nm = 20.0\\n").emulator, 4000.0)
    >>> r.preset, round(r.torque_noise_nm, 6), r.current_loop_hz, r.delay_ticks
    ('bench', 0.06, 1000.0, 1)
    >>> realism(parse_config("[emulator]\\npreset = 'clean'\\n").emulator, 4000.0).current_loop_hz
    inf
    """
    preset = cfg.preset
    d, drive, sensors = cfg.disturbance, cfg.drive, cfg.sensors
    tmax = drive.torque_max_nm
    if drive.delay_s is None:
        delay_ticks = int(BENCH["delay_ticks"]) if preset == "bench" else 0
    else:
        delay_ticks = int(round(drive.delay_s * loop_rate_hz))
    return Realism(
        preset=preset,
        torque_noise_nm=_given(d.torque_noise_nm, BENCH["torque_noise_of_max"] * tmax, 0.0, preset),
        torque_noise_corner_hz=d.torque_noise_corner_hz,
        cogging_nm=_given(d.cogging_nm, BENCH["cogging_of_max"] * tmax, 0.0, preset),
        cogging_period_m=d.cogging_period_m,
        load_step_nm=_given(d.load_step_nm, BENCH["load_step_of_max"] * tmax, 0.0, preset),
        load_step_rate_hz=d.load_step_rate_hz,
        load_noise_n=_given(d.load_noise_n, BENCH["load_noise_of_max"] * cfg.plant.c * tmax, 0.0, preset),
        current_loop_hz=_given(drive.current_loop_hz, BENCH["current_loop_hz"], math.inf, preset),
        delay_ticks=delay_ticks,
        encoder_noise_m=_given(
            sensors.encoder_noise_m, BENCH["encoder_noise_counts"] * sensors.encoder_resolution_m, 0.0, preset
        ),
    )
