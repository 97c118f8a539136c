"""Driver descriptions: what a device offers, read from ``drivers/<name>/driver.toml``.

A device is described by data, not code. Descriptions are searched, in order, in
the folders given by the caller (config ``device.driver_paths``), in the folders
listed in the ``HILIDENT_DRIVER_PATH`` environment variable (``os.pathsep``
separated), in the ``drivers/`` folder of a source checkout, and in the copy
installed with the package (``hilident/_drivers``).
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from hilident.errors import ConfigError

DESCRIPTION_FILE = "driver.toml"
_FORMATS = ("f32", "i16", "i32")
TRANSPORTS = ("serial", "canopen", "modbus")


@dataclass(frozen=True)
class ChannelSpec:
    """One channel of a device: name, unit and default on-wire encoding."""

    name: str
    unit: str
    format: str = "f32"
    scale: float = 1.0
    stream: bool = True


@dataclass(frozen=True)
class DriverDescription:
    """A parsed driver description.

    Attributes
    ----------
    name : str
        Driver name (the folder name by convention).
    folder : Path
        Folder the description was read from (protocol specs, EDS files live there).
    transport : str
        ``"serial"``, ``"canopen"`` or ``"modbus"``: which adapter talks to it.
    loop_rate_hz : float
        Rate of the device's control loop, Hz; notch biquads are discretised at it.
    filter_slots : int
        Biquad slots in series on the torque command.
    protocol_version, default_baudrate, firmware, excitation_buffer_samples, block_samples
        The serial board's protocol figures (required for ``transport = "serial"``,
        zero or empty for other transports). ``default_baudrate`` is the line rate
        (serial, Modbus RTU) or CAN bit rate used when the config gives none.
    sections : dict
        The whole parsed description. Each adapter reads its own tables from it
        (``[canopen]``, ``[modbus]``, ...).
    text : str
        The description file verbatim, stored in every recording.
    """

    name: str
    folder: Path
    transport: str
    protocol_version: int
    default_baudrate: int
    firmware: str
    loop_rate_hz: float
    max_sample_rate_hz: float
    filter_slots: int
    excitation_buffer_samples: int
    block_samples: int
    channels: tuple[ChannelSpec, ...]
    description: str = ""
    sections: dict = field(default_factory=dict, repr=False, compare=False)
    text: str = field(default="", repr=False)

    def channel_index(self, name: str) -> int:
        """Board index of channel ``name``."""
        for i, c in enumerate(self.channels):
            if c.name == name:
                return i
        known = ", ".join(c.name for c in self.channels)
        raise ConfigError("channels", f"driver {self.name!r} has no channel {name!r} (it has: {known})")

    @property
    def streamed_channels(self) -> tuple[ChannelSpec, ...]:
        """Channels streamed by default."""
        return tuple(c for c in self.channels if c.stream)


def search_path(extra: list[str | os.PathLike] | tuple = ()) -> list[Path]:
    """Folders searched for driver descriptions, in order."""
    folders = [Path(p).expanduser() for p in extra]
    env = os.environ.get("HILIDENT_DRIVER_PATH", "")
    folders += [Path(p).expanduser() for p in env.split(os.pathsep) if p]
    checkout = Path(__file__).resolve().parents[2] / "drivers"
    if checkout.is_dir():
        folders.append(checkout)
    installed = resources.files("hilident") / "_drivers"
    if installed.is_dir():
        folders.append(Path(str(installed)))
    return folders


def available_drivers(extra=()) -> list[str]:
    """Names of every driver found on the search path."""
    names = []
    for folder in search_path(extra):
        if folder.is_dir():
            names += [p.parent.name for p in sorted(folder.glob(f"*/{DESCRIPTION_FILE}"))]
    return sorted(set(names))


def find_driver(name_or_path: str, extra=()) -> DriverDescription:
    """Load a driver by folder path or by name on the search path.

    Raises
    ------
    ConfigError
        The driver is not found (the message lists the folders searched) or its
        description is invalid (the message names the key and file).
    """
    candidate = Path(name_or_path).expanduser()
    if candidate.is_dir() and (candidate / DESCRIPTION_FILE).is_file():
        return load_driver(candidate)
    if candidate.is_file() and candidate.name == DESCRIPTION_FILE:
        return load_driver(candidate.parent)
    for folder in search_path(extra):
        if (folder / name_or_path / DESCRIPTION_FILE).is_file():
            return load_driver(folder / name_or_path)
    searched = ", ".join(str(f) for f in search_path(extra)) or "(nothing)"
    raise ConfigError(
        "device.driver",
        f"no driver {name_or_path!r} found; searched {searched}; known drivers: "
        f"{', '.join(available_drivers(extra)) or 'none'}",
    )


def load_driver(folder: str | os.PathLike) -> DriverDescription:
    """Parse ``folder/driver.toml``."""
    folder = Path(folder)
    path = folder / DESCRIPTION_FILE
    text = path.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("driver.toml", f"not valid TOML: {exc}", str(path)) from None

    def get(section: str, key: str, kind, default=None):
        value = data.get(section, {}).get(key, default)
        if value is None:
            raise ConfigError(f"{section}.{key}", "is required", str(path))
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
            raise ConfigError(f"{section}.{key}", f"must be {kind.__name__}, got {value!r}", str(path))
        return value

    transport = get("driver", "transport", str)
    if transport not in TRANSPORTS:
        raise ConfigError("driver.transport", f"must be one of {TRANSPORTS}, got {transport!r}", str(path))
    serial_only = transport == "serial"

    def serial_figure(section: str, key: str, kind):
        # the serial protocol's own figures: required there, meaningless elsewhere
        return get(section, key, kind, None if serial_only else kind())

    channels = []
    for i, c in enumerate(data.get("channels", [])):
        fmt = c.get("format", "f32")
        if fmt not in _FORMATS:
            raise ConfigError(f"channels[{i}].format", f"must be one of {_FORMATS}, got {fmt!r}", str(path))
        channels.append(
            ChannelSpec(
                name=str(c["name"]), unit=str(c.get("unit", "")), format=fmt,
                scale=float(c.get("scale", 1.0)), stream=bool(c.get("stream", True)),
            )
        )
    if not channels:
        raise ConfigError("channels", "a driver needs at least one [[channels]] entry", str(path))
    return DriverDescription(
        name=get("driver", "name", str),
        folder=folder,
        transport=transport,
        protocol_version=serial_figure("driver", "protocol_version", int),
        default_baudrate=serial_figure("driver", "default_baudrate", int),
        description=get("driver", "description", str, ""),
        firmware=get("board", "firmware", str, ""),
        loop_rate_hz=get("board", "loop_rate_hz", float),
        max_sample_rate_hz=get("board", "max_sample_rate_hz", float),
        filter_slots=get("board", "filter_slots", int),
        excitation_buffer_samples=serial_figure("board", "excitation_buffer_samples", int),
        block_samples=serial_figure("board", "block_samples", int),
        channels=tuple(channels),
        sections=data,
        text=text,
    )
