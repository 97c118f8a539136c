"""Build an emulated device from a configuration: plant, drive loop, firmware, line.

This is the one place the session reaches into the emulator: it asks for a
device (:func:`start_emulator`) and gets back the device settings a host uses
to reach it (a pseudo-terminal path, a loopback address, a virtual CAN
channel) and, for the serial board, optionally the host end of an in-memory
pipe. Adapters never import the emulator. Every transport's emulator wraps the
same :class:`~hilident.emulator.drive.DriveLoop` built by :func:`build_drive`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from typing import Callable

from hilident.config import DeviceConfig, EmulatorConfig, device_table
from hilident.drivers import DriverDescription
from hilident.emulator.board import BoardFirmware
from hilident.emulator.disturbance import ProcessDisturbance
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import MassSpringDamper, Plant, StribeckFriction, ThreeMass, TwoMass, modes
from hilident.emulator.preset import realism
from hilident.emulator.sensors import SensorModel
from hilident.emulator.serial_server import BoardServer, LineFaults, PipeLink, PtyLink, TcpLink
from hilident.links import pipe_pair
from hilident.protocol import serial_board as sb


def plant_model(cfg: EmulatorConfig):
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
        current_loop_hz=r.current_loop_hz, delay_ticks=r.delay_ticks,
    )
    # The sensors' noise streams are children 0-2 of the seed; the disturbance is child 3.
    disturbance = ProcessDisturbance(
        period_s=1.0 / driver.loop_rate_hz, noise_nm=r.torque_noise_nm, noise_corner_hz=r.torque_noise_corner_hz,
        cogging_nm=r.cogging_nm, cogging_period_m=r.cogging_period_m, load_step_nm=r.load_step_nm,
        load_step_rate_hz=r.load_step_rate_hz, load_noise_n=r.load_noise_n, seed=np.random.SeedSequence(cfg.seed, spawn_key=(3,)),
    )
    # Integrate at least 4x the loop rate, and at least 40 steps per period of the fastest mode.
    fastest = max((f for f, _ in true_modes(cfg)), default=0.0)
    substep = min(1.0 / (4 * driver.loop_rate_hz), 1.0 / (40 * fastest) if fastest else math.inf)
    backlash = cfg.plant.backlash_m if cfg.plant.model != "mass_spring_damper" else 0.0
    plant = Plant(plant_model(cfg), friction_model(cfg), max_substep_s=substep, backlash_m=backlash)
    return DriveLoop(plant, tuning, sensors, n_filter_slots=driver.filter_slots, disturbance=disturbance)


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
    """A running emulated device and what a host connects to.

    Attributes
    ----------
    server : object
        The running emulator (``close()``; ``error`` holds an exception that
        stopped it, else None).
    device : DeviceConfig
        The ``[device]`` settings that reach it (port, interface, ids).
    drive : DriveLoop
        Its physics: plant, sensors and drive loop (tests compare with its truth).
    link : object or None
        Host end of an in-memory pipe (serial board only), else None.
    """

    server: object
    device: DeviceConfig
    drive: DriveLoop
    link: object | None = None

    @property
    def port(self) -> str:
        return self.device.port

    def close(self) -> None:
        self.server.close()


def start_emulator(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> EmulatedDevice:
    """Start the emulated twin of ``driver`` for a session configured with ``device``.

    Dispatches on ``driver.transport``; each transport's emulator module offers
    ``start(cfg, driver, device) -> EmulatedDevice``.
    """
    starters: dict[str, Callable[..., EmulatedDevice]] = {"serial": _start_serial_for_session}
    if driver.transport == "canopen":
        from hilident.emulator.canopen_drive import start as start_canopen

        starters["canopen"] = start_canopen
    elif driver.transport == "modbus":
        from hilident.emulator.modbus_drive import start as start_modbus

        starters["modbus"] = start_modbus
    return starters[driver.transport](cfg, driver, device)


def _start_serial_for_session(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> EmulatedDevice:
    return start_serial_board(cfg, driver, device.baudrate or driver.default_baudrate)


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
    device = replace(DeviceConfig(), driver=str(driver.folder), port=device_link.path, baudrate=baudrate)
    return EmulatedDevice(server=server, device=device, drive=firmware.drive, link=host_link)


#: Links a standalone twin can be served on, per transport (what a host in another process opens).
STANDALONE_LINKS = {"serial": ("pty", "tcp"), "modbus": ("tcp", "rtu"), "canopen": ("socketcand",)}


def start_standalone(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig,
                     link: str, port: int = 0) -> EmulatedDevice:
    """Serve the twin of ``driver`` on a real transport for a host in another process.

    Parameters
    ----------
    cfg : EmulatorConfig
    driver : DriverDescription
    device : DeviceConfig
        The ``[device]`` settings of the config (ids, baud rate, parity).
    link : str
        One of :data:`STANDALONE_LINKS` for the driver's transport: serial
        ``"pty"`` or ``"tcp"`` (a raw line, ``socket://``), Modbus ``"tcp"`` or
        ``"rtu"`` (on a pseudo-terminal), CANopen ``"socketcand"``.
    port : int
        TCP port of a socketcand server (0: any free one).

    Returns
    -------
    EmulatedDevice
        ``device`` holds what a host config needs in ``[device]``
        (:func:`host_device_table`).
    """
    links = STANDALONE_LINKS.get(driver.transport, ())
    if link not in links:
        from hilident.errors import ConfigError

        raise ConfigError("emulator.link", f"a standalone {driver.transport} twin is served on {list(links)}, "
                          f"not {link!r}")
    if driver.transport == "serial":
        return start_serial_board(cfg, driver, device.baudrate or driver.default_baudrate, link=link)
    if driver.transport == "modbus":
        from hilident.emulator.modbus_drive import start as start_modbus

        return start_modbus(cfg, driver, device, link="pty" if link == "rtu" else "tcp")
    from hilident.emulator.canopen_drive import start_socketcand

    return start_socketcand(cfg, driver, device, port=port)


def host_device_table(device: DeviceConfig) -> dict:
    """The ``[device]`` table (as a dict, ready for a TOML writer) a host in another process uses to reach a
    standalone twin."""
    keys = ("driver", "port", "baudrate", "timeout_s", "can_interface", "node_id", "device_id", "parity",
            "stopbits", "acquisition", "allow_fault_reset", "host_timeout_s")
    return device_table(device, keys)
