"""Start an emulated device from a configuration: the one place the session reaches into the emulator.

The session asks for a device (:func:`start_emulator`) and gets back the device
settings a host uses to reach it (a pseudo-terminal path, a loopback address, a
virtual CAN channel) and, for the serial board, optionally the host end of an
in-memory pipe. Adapters never import the emulator. Each transport package
(:mod:`~hilident.emulator.serial`, :mod:`~hilident.emulator.modbus`,
:mod:`~hilident.emulator.canopen`) offers ``start(cfg, driver, device)``; every
one wraps the same :class:`~hilident.emulator.drive.DriveLoop` built by
:func:`~hilident.emulator.device.build_drive`.
"""

from __future__ import annotations

from collections.abc import Callable

from hilident.config.tables import DeviceConfig, EmulatorConfig, device_table
from hilident.drivers.description import DriverDescription
from hilident.emulator.canopen.server import start as start_canopen
from hilident.emulator.canopen.server import start_socketcand
from hilident.emulator.device import (
    EmulatedDevice,
    build_drive,
    coupling_curves,
    plant_model,
    true_modes,
)
from hilident.emulator.modbus.server import start as start_modbus
from hilident.emulator.serial.server import start as start_serial
from hilident.emulator.serial.server import start_serial_board
from hilident.errors import ConfigError

__all__ = [
    "EmulatedDevice",
    "STANDALONE_LINKS",
    "build_drive",
    "coupling_curves",
    "host_device_table",
    "plant_model",
    "start_emulator",
    "start_standalone",
    "true_modes",
]

#: Each transport's twin: ``start(cfg, driver, device) -> EmulatedDevice``.
_STARTERS: dict[str, Callable[..., EmulatedDevice]] = {
    "serial": start_serial,
    "modbus": start_modbus,
    "canopen": start_canopen,
}


def _check_mechanism(cfg: EmulatorConfig, driver: DriverDescription) -> None:
    """``[emulator.mechanism]`` is driven by the nodes of one CANopen bus; no other transport's twin runs on it."""
    if cfg.mechanism.defined and driver.transport != "canopen":
        raise ConfigError(
            "emulator.mechanism",
            f"is driven by the nodes of one CANopen bus (device.canopen.node_ids); driver {driver.name!r} is a "
            f"{driver.transport} device: leave [emulator.mechanism] out, its twin runs on [emulator.plant]",
        )


def start_emulator(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> EmulatedDevice:
    """Start the emulated twin of ``driver`` for a session configured with ``device``.

    Dispatches on ``driver.transport``; each transport's server module offers
    ``start(cfg, driver, device) -> EmulatedDevice``. A CANopen twin of several
    nodes (``[device.canopen] node_ids``) runs them all on one bus, driving
    ``[emulator.mechanism]`` together.
    """
    _check_mechanism(cfg, driver)
    return _STARTERS[driver.transport](cfg, driver, device)


#: Links a standalone twin can be served on, per transport (what a host in another process opens).
STANDALONE_LINKS = {"serial": ("pty", "tcp"), "modbus": ("tcp", "rtu"), "canopen": ("socketcand",)}


def start_standalone(
    cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig, link: str, port: int = 0
) -> EmulatedDevice:
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
    _check_mechanism(cfg, driver)
    links = STANDALONE_LINKS.get(driver.transport, ())
    if link not in links:
        raise ConfigError(
            "emulator.link", f"a standalone {driver.transport} twin is served on {list(links)}, not {link!r}"
        )
    if driver.transport == "serial":
        return start_serial_board(cfg, driver, device.baudrate or driver.default_baudrate, link=link)
    if driver.transport == "modbus":
        return start_modbus(cfg, driver, device, link="pty" if link == "rtu" else "tcp")
    return start_socketcand(cfg, driver, device, port=port)


def host_device_table(device: DeviceConfig) -> dict:
    """The ``[device]`` table (as a dict, ready for a TOML writer) a host in another process uses to reach a
    standalone twin (a CANopen twin of several nodes: with their ``node_ids``)."""
    keys = (
        "driver",
        "port",
        "baudrate",
        "timeout_s",
        "can_interface",
        "node_id",
        "device_id",
        "parity",
        "stopbits",
        "acquisition",
        "allow_fault_reset",
        "host_timeout_s",
    )
    table = device_table(device, keys)
    if device.canopen.node_ids:
        table.setdefault("canopen", {})["node_ids"] = list(device.canopen.node_ids)
    return table
