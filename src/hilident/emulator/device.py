"""The twin's parts every transport shares: the physics built from a configuration, and the running device.

:func:`build_drive` assembles plant, friction, sensors, disturbances and drive
loop from ``[emulator]``; every transport's firmware wraps the
:class:`~hilident.emulator.drive.DriveLoop` it returns. A transport's ``start``
returns an :class:`EmulatedDevice`. The transports import this module;
:mod:`hilident.emulator.factory` imports the transports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hilident.config import DeviceConfig, EmulatorConfig
from hilident.drivers import DriverDescription
from hilident.emulator.disturbance import ProcessDisturbance
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import (
    MassSpringDamper,
    Plant,
    StribeckFriction,
    ThreeMass,
    TwoMass,
    modes,
)
from hilident.emulator.preset import realism
from hilident.emulator.sensors import SensorModel
from hilident.links import PipeEnd

__all__ = ["EmulatedDevice", "EmulatorServer", "build_drive", "friction_model", "plant_model", "true_modes"]


class EmulatorServer(Protocol):
    """What every transport's running twin offers its owner."""

    @property
    def error(self) -> BaseException | None:
        """The exception that stopped the twin, else None."""
        ...

    def close(self) -> None:
        """Stop the axis and the twin's threads, release its line or bus."""
        ...


def plant_model(cfg: EmulatorConfig) -> TwoMass | ThreeMass | MassSpringDamper:
    """The configured plant as an emulator model (TwoMass, ThreeMass or MassSpringDamper)."""
    p = cfg.plant
    if p.model == "two_mass":
        return TwoMass(m1=p.m1, m2=p.m2, k=p.k, d=p.d, c=p.c)
    if p.model == "three_mass":
        return ThreeMass(m1=p.m1, m2=p.m2, m3=p.m3, k=p.k, d=p.d, k2=p.k2, d2=p.d2, c=p.c)
    return MassSpringDamper(m=p.m, b=p.b, k=p.k, c=p.c)


def friction_model(cfg: EmulatorConfig) -> StribeckFriction | None:
    f = cfg.friction
    if f.model == "none":
        return None
    return StribeckFriction(Fc=f.Fc, Fs=f.Fs, Fv=f.Fv, vs=f.vs, delta_v=f.delta_v, delta_s=f.delta_s)


def true_modes(cfg: EmulatorConfig) -> list[tuple[float, float]]:
    """(frequency_hz, damping_ratio) of the configured frictionless plant: the truth tests compare with."""
    return modes(plant_model(cfg))


def build_drive(cfg: EmulatorConfig, driver: DriverDescription) -> DriveLoop:
    """Plant, sensors, disturbances and drive loop as configured (unset keys from ``cfg.preset``)."""
    s = cfg.sensors
    d = cfg.drive
    r = realism(cfg, driver.loop_rate_hz)
    sensors = SensorModel(
        encoder_resolution_m=s.encoder_resolution_m, torque_noise_nm=s.torque_noise_nm,
        laser_range_m=tuple(s.laser_range_m), laser_noise_m=s.laser_noise_m,
        laser_resolution_m=s.laser_resolution_m, encoder_noise_m=r.encoder_noise_m, seed=cfg.seed,
    )
    tuning = DriveTuning(
        loop_rate_hz=driver.loop_rate_hz, kp_pos_per_s=d.kp_pos_per_s, kv_nm_per_mps=d.kv_nm_per_mps,
        ti_s=d.ti_s, velocity_filter_hz=d.velocity_filter_hz, torque_max_nm=d.torque_max_nm,
        current_loop_hz=r.current_loop_hz, delay_ticks=r.delay_ticks, velocity_feedforward=d.velocity_feedforward,
        accel_feedforward_nm_per_mps2=d.accel_feedforward_nm_per_mps2,
    )
    # The sensors' noise streams are children 0-2 of the seed; the disturbance is child 3.
    disturbance = ProcessDisturbance(
        period_s=1.0 / driver.loop_rate_hz, noise_nm=r.torque_noise_nm, noise_corner_hz=r.torque_noise_corner_hz,
        cogging_nm=r.cogging_nm, cogging_period_m=r.cogging_period_m, load_step_nm=r.load_step_nm,
        load_step_rate_hz=r.load_step_rate_hz, load_noise_n=r.load_noise_n,
        seed=np.random.SeedSequence(cfg.seed, spawn_key=(3,)),
    )
    # Integrate at least 4x the loop rate, and at least 40 steps per period of the fastest mode.
    fastest = max((f for f, _ in true_modes(cfg)), default=0.0)
    substep = min(1.0 / (4 * driver.loop_rate_hz), 1.0 / (40 * fastest) if fastest else math.inf)
    backlash = cfg.plant.backlash_m if cfg.plant.model != "mass_spring_damper" else 0.0
    plant = Plant(plant_model(cfg), friction_model(cfg), max_substep_s=substep, backlash_m=backlash)
    return DriveLoop(plant, tuning, sensors, n_filter_slots=driver.filter_slots, disturbance=disturbance)


@dataclass
class EmulatedDevice:
    """A running emulated device and what a host connects to.

    Attributes
    ----------
    server : EmulatorServer
        The running emulator (``close()``; ``error`` holds an exception that
        stopped it, else None).
    device : DeviceConfig
        The ``[device]`` settings that reach it (port, interface, ids).
    drive : DriveLoop
        Its physics: plant, sensors and drive loop (tests compare with its truth).
    link : hilident.links.PipeEnd or None
        Host end of an in-memory pipe (serial board only), else None.
    """

    server: EmulatorServer
    device: DeviceConfig
    drive: DriveLoop
    link: PipeEnd | None = None

    @property
    def port(self) -> str:
        return self.device.port

    def close(self) -> None:
        self.server.close()
