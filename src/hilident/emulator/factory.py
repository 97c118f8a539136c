"""Build an emulated device from a configuration: plant, drive loop, firmware, line.

This is the one place the session reaches into the emulator: it asks for a
device and gets back something to connect to (a serial device path, or the
host end of an in-memory pipe). Adapters never import the emulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hilident.config import EmulatorConfig
from hilident.drivers import DriverDescription
from hilident.emulator.board import BoardFirmware
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import MassSpringDamper, Plant, StribeckFriction, TwoMass, modes
from hilident.emulator.sensors import SensorModel
from hilident.emulator.serial_server import BoardServer, LineFaults, PipeLink, PtyLink, TcpLink
from hilident.links import pipe_pair
from hilident.protocol import serial_board as sb


def plant_model(cfg: EmulatorConfig):
    """The configured plant as an emulator model (TwoMass or MassSpringDamper)."""
    p = cfg.plant
    if p.model == "two_mass":
        return TwoMass(m1=p.m1, m2=p.m2, k=p.k, d=p.d, c=p.c)
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
    """Plant, sensors and drive loop as configured."""
    s = cfg.sensors
    d = cfg.drive
    sensors = SensorModel(
        encoder_resolution_m=s.encoder_resolution_m, torque_noise_nm=s.torque_noise_nm,
        laser_range_m=tuple(s.laser_range_m), laser_noise_m=s.laser_noise_m,
        laser_resolution_m=s.laser_resolution_m, seed=cfg.seed,
    )
    tuning = DriveTuning(
        loop_rate_hz=driver.loop_rate_hz, kp_pos_per_s=d.kp_pos_per_s, kv_nm_per_mps=d.kv_nm_per_mps,
        ti_s=d.ti_s, velocity_filter_hz=d.velocity_filter_hz, torque_max_nm=d.torque_max_nm,
    )
    # Integrate at least 4x the loop rate, and at least 40 steps per period of the fastest mode.
    fastest = max((f for f, _ in true_modes(cfg)), default=0.0)
    substep = min(1.0 / (4 * driver.loop_rate_hz), 1.0 / (40 * fastest) if fastest else math.inf)
    plant = Plant(plant_model(cfg), friction_model(cfg), max_substep_s=substep)
    return DriveLoop(plant, tuning, sensors, n_filter_slots=driver.filter_slots)


def identity_from_driver(driver: DriverDescription) -> sb.Identity:
    """What the emulated board answers to IDENTIFY: the driver description's board."""
    return sb.Identity(
        protocol_version=sb.PROTOCOL_VERSION,
        name=driver.name,
        firmware=driver.firmware,
        loop_rate_hz=driver.loop_rate_hz,
        max_sample_rate_hz=driver.max_sample_rate_hz,
        filter_slots=driver.filter_slots,
        excitation_buffer_samples=driver.excitation_buffer_samples,
        channels=tuple(sb.ChannelInfo(c.name, c.unit) for c in driver.channels),
    )


@dataclass
class EmulatedDevice:
    """A running emulated board and what a host connects to."""

    server: BoardServer
    port: str  # device path of the pseudo-terminal, or a pipe name
    link: object | None = None  # host end of the pipe (None for a pseudo-terminal)

    @property
    def drive(self) -> DriveLoop:
        return self.server.firmware.drive

    def close(self) -> None:
        self.server.close()


def start_serial_board(cfg: EmulatorConfig, driver: DriverDescription, baudrate: int,
                       link: str | None = None) -> EmulatedDevice:
    """Start an emulated serial board on a pseudo-terminal or an in-memory pipe.

    Parameters
    ----------
    cfg : EmulatorConfig
        Plant, friction, drive, sensors, faults, time scale.
    driver : DriverDescription
        The board to emulate.
    baudrate : int
        Line rate the board paces its output to (0: unpaced).
    link : {"pty", "tcp", "pipe"}, optional
        Overrides ``cfg.link``: a pseudo-terminal, a raw TCP line on 127.0.0.1
        (``socket://`` for pyserial), or an in-memory pipe.
    """
    kind = link or cfg.link
    firmware = BoardFirmware(build_drive(cfg, driver), identity_from_driver(driver))
    faults = LineFaults(cfg.faults.corrupt_frame_rate, cfg.faults.drop_frame_rate, seed=cfg.seed + 1)
    if kind == "pty":
        device_link, host_link = PtyLink(), None
    elif kind == "tcp":
        device_link, host_link = TcpLink(), None
    else:
        host_link, device_end = pipe_pair()
        device_link = PipeLink(device_end)
    server = BoardServer(
        firmware, device_link, baudrate=baudrate, time_scale=cfg.time_scale,
        faults=faults, close_after_s=cfg.faults.close_after_s,
    ).start()
    return EmulatedDevice(server=server, port=device_link.path, link=host_link)
