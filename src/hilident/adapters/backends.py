"""Which adapter class serves which transport.

The transports hilident ships are listed in :data:`BACKENDS` (transport name
to ``"module:Class"``), so a source tree that was never installed resolves
them too. Third-party adapters register under the ``hilident.adapters`` entry
point group, as python-can's interfaces do under ``can.interface``; a built-in
name always wins over an entry point of the same name.
"""

from __future__ import annotations

from importlib import import_module
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING

from hilident.errors import ConfigError

if TYPE_CHECKING:
    from hilident.adapters.base import DeviceAdapter

ENTRY_POINT_GROUP = "hilident.adapters"

BACKENDS: dict[str, str] = {
    "serial": "hilident.adapters.serial.board:SerialBoardAdapter",
    "canopen": "hilident.adapters.canopen.drive:CanopenDriveAdapter",
    "modbus": "hilident.adapters.modbus.drive:ModbusDriveAdapter",
}


def _load(target: str) -> type[DeviceAdapter]:
    """The class named by ``"module:Class"``."""
    module_name, _, class_name = target.partition(":")
    return getattr(import_module(module_name), class_name)


def _registered() -> dict[str, EntryPoint]:
    """Entry points of the ``hilident.adapters`` group, by transport name."""
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def known_transports() -> list[str]:
    """Every transport an adapter can be found for: built-ins and entry points, sorted."""
    return sorted(set(BACKENDS) | set(_registered()))


def adapter_class(transport: str) -> type[DeviceAdapter]:
    """The adapter class for ``transport``.

    Parameters
    ----------
    transport : str
        The ``transport`` of a driver description (``"serial"``, ``"canopen"``,
        ``"modbus"`` or a name a third-party package registers).

    Raises
    ------
    ConfigError
        No built-in backend and no entry point has that name (key
        ``driver.transport``; the message lists the known transports).
    """
    if transport in BACKENDS:
        return _load(BACKENDS[transport])
    registered = _registered()
    if transport in registered:
        return registered[transport].load()
    raise ConfigError("driver.transport", f"no adapter for transport {transport!r} (known: {known_transports()})")
