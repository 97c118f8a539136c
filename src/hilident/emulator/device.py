"""The twin's parts every transport shares: the physics built from a configuration, and the running device.

:func:`build_drive` assembles plant, friction, sensors, disturbances and drive
loop from ``[emulator]``; every transport's firmware wraps the
:class:`~hilident.emulator.drive.DriveLoop` it returns. A transport's ``start``
returns an :class:`EmulatedDevice`. The transports import this module;
:mod:`hilident.emulator.factory` imports the transports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol, TypeVar

import numpy as np

from hilident.config.tables import DeviceConfig, EmulatorConfig, PositionFunction
from hilident.drivers.description import DriverDescription
from hilident.emulator.coupled_plant import CoupledModel, CoupledPlant, PlantPort
from hilident.emulator.coupling import PositionCurve
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
from hilident.emulator.preset import Realism, realism
from hilident.emulator.sensors import SensorModel
from hilident.errors import ConfigError
from hilident.links import PipeEnd

__all__ = [
    "EmulatedDevice",
    "EmulatorServer",
    "build_drive",
    "build_port_drive",
    "coupling_curves",
    "friction_model",
    "mechanism_model",
    "plant_model",
    "true_modes",
]


_Loop = TypeVar("_Loop", bound=DriveLoop)


class EmulatorServer(Protocol):
    """What every transport's running twin offers its owner."""

    @property
    def error(self) -> BaseException | None:
        """The exception that stopped the twin, else None."""
        ...

    def close(self) -> None:
        """Stop the axis and the twin's threads, release its line or bus."""
        ...


def _curve(value: float | PositionFunction) -> PositionCurve | None:
    return PositionCurve.from_table(value) if isinstance(value, PositionFunction) else None


def _at(value: float | PositionFunction, position_m: float) -> float:
    return PositionCurve.from_table(value)(position_m) if isinstance(value, PositionFunction) else float(value)


def coupling_curves(cfg: EmulatorConfig) -> tuple[PositionCurve | None, PositionCurve | None]:
    """``[emulator.plant]`` k and d as functions of the cart position (m), each None where it is a number."""
    return _curve(cfg.plant.k), _curve(cfg.plant.d)


def plant_model(cfg: EmulatorConfig, position_m: float = 0.0) -> TwoMass | ThreeMass | MassSpringDamper:
    """The configured plant as an emulator model (TwoMass, ThreeMass or MassSpringDamper).

    A ``k`` or ``d`` that is a function of the cart position is taken at ``position_m`` (m).
    """
    p = cfg.plant
    k, d = _at(p.k, position_m), _at(p.d, position_m)
    if p.model == "two_mass":
        return TwoMass(m1=p.m1, m2=p.m2, k=k, d=d, c=p.c)
    if p.model == "three_mass":
        return ThreeMass(m1=p.m1, m2=p.m2, m3=p.m3, k=k, d=d, k2=p.k2, d2=p.d2, c=p.c)
    return MassSpringDamper(m=p.m, b=p.b, k=k, c=p.c)


def friction_model(cfg: EmulatorConfig) -> StribeckFriction | None:
    f = cfg.friction
    if f.model == "none":
        return None
    return StribeckFriction(Fc=f.Fc, Fs=f.Fs, Fv=f.Fv, vs=f.vs, delta_v=f.delta_v, delta_s=f.delta_s)


def true_modes(cfg: EmulatorConfig, position_m: float = 0.0) -> list[tuple[float, float]]:
    """(frequency_hz, damping_ratio) of the configured frictionless plant: the truth tests compare with.

    Parameters
    ----------
    cfg : EmulatorConfig
    position_m : float
        Cart position, m (the encoder's ``position_m`` axis), where ``k`` and ``d`` depend on it.
    """
    return modes(plant_model(cfg, position_m))


def _fastest_mode_hz(cfg: EmulatorConfig) -> float:
    """The highest mode frequency of the plant anywhere its coupling curves vary (Hz; 0 without a mode)."""
    positions = [0.0]
    for curve in coupling_curves(cfg):
        if curve is not None and curve.span_m is not None:
            positions += np.linspace(curve.span_m[0], curve.span_m[1], 65).tolist()
    return max((f for p in positions for f, _ in true_modes(cfg, p)), default=0.0)


def _sensors(cfg: EmulatorConfig, r: Realism, seed: int | np.random.SeedSequence) -> SensorModel:
    s = cfg.sensors
    return SensorModel(
        encoder_resolution_m=s.encoder_resolution_m,
        torque_noise_nm=s.torque_noise_nm,
        laser_range_m=tuple(s.laser_range_m),
        laser_noise_m=s.laser_noise_m,
        laser_resolution_m=s.laser_resolution_m,
        encoder_noise_m=r.encoder_noise_m,
        seed=seed,
    )


def _tuning(cfg: EmulatorConfig, driver: DriverDescription, r: Realism) -> DriveTuning:
    d = cfg.drive
    return DriveTuning(
        loop_rate_hz=driver.loop_rate_hz,
        kp_pos_per_s=d.kp_pos_per_s,
        ki_pos_per_s2=d.ki_pos_per_s2,
        kd_pos=d.kd_pos,
        kv_nm_per_mps=d.kv_nm_per_mps,
        ti_s=d.ti_s,
        velocity_filter_hz=d.velocity_filter_hz,
        torque_max_nm=d.torque_max_nm,
        current_loop_hz=r.current_loop_hz,
        delay_ticks=r.delay_ticks,
        velocity_feedforward=d.velocity_feedforward,
        accel_feedforward_nm_per_mps2=d.accel_feedforward_nm_per_mps2,
        viscous_feedforward_nm_per_mps=d.viscous_feedforward_nm_per_mps,
        friction_feedforward_nm=d.friction_feedforward_nm,
    )


def _disturbance(driver: DriverDescription, r: Realism, seed: np.random.SeedSequence) -> ProcessDisturbance:
    return ProcessDisturbance(
        period_s=1.0 / driver.loop_rate_hz,
        noise_nm=r.torque_noise_nm,
        noise_corner_hz=r.torque_noise_corner_hz,
        cogging_nm=r.cogging_nm,
        cogging_period_m=r.cogging_period_m,
        load_step_nm=r.load_step_nm,
        load_step_rate_hz=r.load_step_rate_hz,
        load_noise_n=r.load_noise_n,
        seed=seed,
    )


def build_drive(cfg: EmulatorConfig, driver: DriverDescription) -> DriveLoop:
    """Plant, sensors, disturbances and drive loop as configured (unset keys from ``cfg.preset``)."""
    r = realism(cfg, driver.loop_rate_hz)
    # The sensors' noise streams are children 0-2 of the seed; the disturbance is child 3.
    sensors = _sensors(cfg, r, cfg.seed)
    disturbance = _disturbance(driver, r, np.random.SeedSequence(cfg.seed, spawn_key=(3,)))
    # Integrate at least 4x the loop rate, and at least 40 steps per period of the fastest mode.
    fastest = _fastest_mode_hz(cfg)
    substep = min(1.0 / (4 * driver.loop_rate_hz), 1.0 / (40 * fastest) if fastest else math.inf)
    backlash = cfg.plant.backlash_m if cfg.plant.model != "mass_spring_damper" else 0.0
    k_of, d_of = coupling_curves(cfg)
    plant = Plant(
        plant_model(cfg), friction_model(cfg), max_substep_s=substep, backlash_m=backlash, stiffness=k_of, damping=d_of
    )
    return DriveLoop(
        plant, _tuning(cfg, driver, r), sensors, n_filter_slots=driver.filter_slots, disturbance=disturbance
    )


#: ``CoupledModel``'s names of its fields that ``[emulator.mechanism]`` spells with their unit.
_MECHANISM_KEYS = {"masses": "masses_kg", "k": "k_n_per_m", "d": "d_ns_per_m"}


def _mechanism_key(key: str) -> str:
    """A key of :class:`~hilident.emulator.coupled_plant.CoupledModel` (``links[1].k``) as the config names it."""
    head, dot, last = key.rpartition(".")
    if dot:
        return f"{head}.{_MECHANISM_KEYS.get(last, last)}"
    name, bracket, rest = key.partition("[")
    return _MECHANISM_KEYS.get(name, name) + bracket + rest


def _index(value: float):
    """A mass index the config holds as a number: an int when it is a whole one (else as given, for the model to
    refuse)."""
    return int(value) if isinstance(value, float) and value.is_integer() else value


def mechanism_model(cfg: EmulatorConfig) -> CoupledModel:
    """``[emulator.mechanism]`` as a :class:`~hilident.emulator.coupled_plant.CoupledModel`.

    Raises
    ------
    ConfigError
        The model refuses it: the key is ``emulator.mechanism.<key>`` (``links[1].k_n_per_m``, ...).
    """
    m = cfg.mechanism
    try:
        return CoupledModel(
            masses=tuple(m.masses_kg),
            links=tuple((_index(i), _index(j), k, d) for i, j, k, d in m.links),
            motors=tuple((_index(i), c) for i, c in m.motors),
            sensors=tuple(m.sensors),
        )
    except ConfigError as exc:
        raise ConfigError(f"emulator.mechanism.{_mechanism_key(exc.key)}", exc.message, exc.file) from None


def build_port_drive(cfg: EmulatorConfig, driver: DriverDescription, port: PlantPort, loop: type[_Loop]) -> _Loop:
    """Sensors, disturbances and drive loop of the node on ``port`` of a mechanism (``[emulator.mechanism]``).

    As :func:`build_drive`, on the port instead of a plant of its own (no friction: the mechanism is linear).
    Each port's node draws its own noise: its sensors' streams are child ``(4, i)`` of the seed, its disturbance
    child ``(5, i)`` (``i`` the port's index); a force on its load (``load_noise_n``) scales with its motor's
    ``c``.

    Parameters
    ----------
    cfg : EmulatorConfig
    driver : DriverDescription
    port : PlantPort
        The node's port of the :class:`~hilident.emulator.coupled_plant.CoupledPlant`.
    loop : type
        The :class:`~hilident.emulator.drive.DriveLoop` class to build (``DriveLoop``, or a subclass that
        watches its runs).
    """
    c = port.plant.model.motors[port.index][1]
    r = realism(replace(cfg, plant=replace(cfg.plant, c=c)), driver.loop_rate_hz)
    sensors = _sensors(cfg, r, np.random.SeedSequence(cfg.seed, spawn_key=(4, port.index)))
    disturbance = _disturbance(driver, r, np.random.SeedSequence(cfg.seed, spawn_key=(5, port.index)))
    return loop(port, _tuning(cfg, driver, r), sensors, n_filter_slots=driver.filter_slots, disturbance=disturbance)


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
        Its physics: plant, sensors and drive loop (tests compare with its truth); of several nodes on one
        mechanism, the first node's.
    link : hilident.links.PipeEnd or None
        Host end of an in-memory pipe (serial board only), else None.
    drives : tuple of DriveLoop
        Every node's drive loop, in node order (one node: ``(drive,)``).
    mechanism : CoupledPlant or None
        The mechanism the nodes drive together (``[emulator.mechanism]``), else None.
    """

    server: EmulatorServer
    device: DeviceConfig
    drive: DriveLoop
    link: PipeEnd | None = None
    drives: tuple[DriveLoop, ...] = ()
    mechanism: CoupledPlant | None = None

    def __post_init__(self):
        if not self.drives:
            self.drives = (self.drive,)

    @property
    def port(self) -> str:
        return self.device.port

    def close(self) -> None:
        self.server.close()
