"""Driver descriptions: what a device offers, read from ``drivers/<name>/driver.toml``.

A device is described by data, not code. A driver NAME (``"myrio-board"``) is
searched, in order, in the folders given by the caller (config
``device.driver_paths``), in the folders listed in the ``HILIDENT_DRIVER_PATH``
environment variable (``os.pathsep`` separated), in the ``drivers/`` folder of a
source checkout, and in the copy installed with the package
(``hilident/_drivers``) -- never in the current directory. A value that looks
like a path (``./x``, ``../x``, ``/x``, ``~/x``, or holding a path separator) is
the driver's folder itself.

``[driver]``, ``[board]`` and ``[[channels]]`` are validated by the same typed
schema as the run configuration (:func:`hilident.config.schema.build_table`); the
transport tables (``[canopen]``, ``[modbus]``, ``[filters]``) by their parsers in
:mod:`hilident.protocol`. Every error is a :class:`~hilident.errors.ConfigError`
naming the ``driver.toml`` and the ``[table.key]``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import ClassVar

from hilident.config.schema import build_table, spec
from hilident.config.tables import parse_toml, read_toml_text
from hilident.errors import ConfigError
from hilident.protocol.loop_parameters import LoopDescription, parse_loop
from hilident.signals._checks import show

DESCRIPTION_FILE = "driver.toml"
_FORMATS = ("f32", "i16", "i32")
TRANSPORTS = ("serial", "canopen", "modbus")


@dataclass(frozen=True)
class ChannelSpec:
    """One channel of a device: name, unit, default on-wire encoding and how a sample is taken.

    ``sampling`` is ``"instant"`` (the value at the sample instant, the first loop tick of the
    sample period) or ``"mean"`` (the mean over the period's loop ticks: the device averages
    before it decimates, so what changes within a period does not alias).

    ``filter_input`` marks the signal entering the filter slots (the torque command before the
    notches): with it recorded, a run in closed loop measures what the notches do to the plant.
    """

    name: str
    unit: str
    format: str = "f32"
    scale: float = 1.0
    stream: bool = True
    sampling: str = "instant"
    filter_input: bool = False


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
    placeholders : tuple of str
        Keys of the description whose values were guessed (``hilident drivers
        new``): accepted on the emulator, refused on a real port.
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
    placeholders: tuple[str, ...] = ()
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

    @property
    def filter_input_channel(self) -> str | None:
        """The channel that records the filter slots' input (``filter_input = true``), or None."""
        return next((c.name for c in self.channels if c.filter_input), None)

    @property
    def averaged_channels(self) -> tuple[str, ...]:
        """Names of the channels the device averages over each sample period (``sampling = "mean"``)."""
        return tuple(c.name for c in self.channels if c.sampling == "mean")


@dataclass(frozen=True, kw_only=True)
class _DriverTable:
    """``[driver]``: what the device is and which adapter talks to it."""

    name: str = spec(doc="driver name (the folder name by convention)")
    transport: str = spec(choices=TRANSPORTS)
    description: str = spec("")
    protocol: str = spec("", doc="serial: the protocol the board speaks")
    protocol_version: int = spec(0, ge=0, le=65535, doc="serial: protocol version the board must report")
    default_baudrate: int = spec(0, ge=0, le=100_000_000, doc="line or CAN bit rate when the config gives none")
    placeholders: list[str] = spec([], max_items=256, doc="keys whose values are guesses: refused on a real port")


@dataclass(frozen=True, kw_only=True)
class _BoardTable:
    """``[board]``: the device's loop, rates, filter slots and buffers."""

    firmware: str = spec("")
    loop_rate_hz: float = spec(gt=0, le=1e6, doc="control loop and filter rate, Hz")
    max_sample_rate_hz: float = spec(gt=0, le=1e6, doc="highest sample rate the device records, Hz")
    filter_slots: int = spec(ge=0, le=64, doc="biquad slots in series on the torque command")
    excitation_buffer_samples: int = spec(0, ge=0, le=2**24, doc="serial: board-side excitation FIFO, samples")
    block_samples: int = spec(0, ge=0, le=65535, doc="serial: samples per SAMPLES frame")


@dataclass(frozen=True, kw_only=True)
class _ChannelTable:
    """One ``[[channels]]`` entry."""

    name: str = spec()
    unit: str = spec("")
    format: str = spec("f32", choices=_FORMATS)
    scale: float = spec(1.0, doc="SI units per LSB (i16/i32); non-zero, negative for a reversed sign")
    stream: bool = spec(True)
    sampling: str = spec(
        "instant",
        choices=("instant", "mean"),
        doc="instant: the value at the sample instant; mean: the mean over the sample period's "
        "loop ticks (the device averages before it decimates)",
    )
    filter_input: bool = spec(
        False, doc="the signal entering the filter slots (the torque command before the notches); one channel at most"
    )


@dataclass(frozen=True, kw_only=True)
class _DriverFile:
    """A whole ``driver.toml``; the transport tables are validated by their own parsers."""

    open_table: ClassVar[bool] = True  # [canopen], [modbus], [filters]: protocol/*.py
    driver: _DriverTable = spec()
    board: _BoardTable = spec()
    channels: list[_ChannelTable] = spec([], max_items=64)


#: Keys a serial driver must give (they are the serial protocol's own figures).
_SERIAL_REQUIRED = (
    ("driver", "protocol_version"),
    ("driver", "default_baudrate"),
    ("board", "excitation_buffer_samples"),
    ("board", "block_samples"),
)


def looks_like_path(value: str) -> bool:
    """A ``device.driver`` value names a folder when it looks like a path: ``./x``, ``../x``, ``/x``, ``~/x``,
    ``a/b``."""
    separators = {"/", os.sep} | ({os.altsep} if os.altsep else set())
    return value in (".", "..") or value.startswith("~") or any(c in value for c in separators)


def _expand(path) -> Path:
    """``path`` with ``~`` expanded when there is a home to expand it to."""
    try:
        return Path(path).expanduser()
    except (RuntimeError, ValueError):  # "~user" of no user (or with a NUL byte), or no home directory at all
        return Path(path)


def _is_dir(path: Path) -> bool:
    """``path.is_dir()`` that is False for names the file system refuses (too long, NUL bytes)."""
    try:
        return path.is_dir()
    except (OSError, ValueError):
        return False


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def search_path(extra: list[str | os.PathLike] | tuple = ()) -> list[Path]:
    """Folders searched for driver descriptions, in order."""
    folders = [_expand(p) for p in extra]
    env = os.environ.get("HILIDENT_DRIVER_PATH", "")
    folders += [_expand(p) for p in env.split(os.pathsep) if p]
    checkout = Path(__file__).resolve().parents[3] / "drivers"
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
        if _is_dir(folder):
            names += [p.parent.name for p in sorted(folder.glob(f"*/{DESCRIPTION_FILE}"))]
    return sorted(set(names))


def find_driver(name_or_path: str, extra=()) -> DriverDescription:
    """Load a driver by folder path or by name on the search path.

    A value that looks like a path (``./x``, ``../x``, ``/x``, ``~/x``, or with a
    path separator) is the driver's folder (or its ``driver.toml``); any other
    value is a driver name, looked up only in :func:`search_path` (``driver_paths``,
    ``$HILIDENT_DRIVER_PATH``, a checkout's ``drivers/``, the installed package),
    never in the current directory.

    Raises
    ------
    ConfigError
        The driver is not found (the message lists the folders searched) or its
        description is invalid (the message names the key and file).
    """
    if not isinstance(name_or_path, str) or not name_or_path.strip():
        raise ConfigError("device.driver", f"must name a driver or a driver folder, got {show(name_or_path)}")
    if looks_like_path(name_or_path):
        candidate = _expand(name_or_path)
        if _is_file(candidate / DESCRIPTION_FILE):
            return load_driver(candidate)
        if candidate.name == DESCRIPTION_FILE and _is_file(candidate):
            return load_driver(candidate.parent)
        raise ConfigError(
            "device.driver",
            f"{show(name_or_path)} is taken as a path (it looks like one) but holds no {DESCRIPTION_FILE}",
        )
    for folder in search_path(extra):
        if _is_file(folder / name_or_path / DESCRIPTION_FILE):
            return load_driver(folder / name_or_path)
    searched = ", ".join(str(f) for f in search_path(extra)) or "(nothing)"
    raise ConfigError(
        "device.driver",
        f"no driver {show(name_or_path)} found; searched {searched}; known drivers: "
        f"{', '.join(available_drivers(extra)) or 'none'} (a folder of your own: give its path, e.g. ./{name_or_path})",
    )


def load_driver(folder: str | os.PathLike) -> DriverDescription:
    """Parse and validate ``folder/driver.toml`` (its ``[driver]``, ``[board]`` and ``[[channels]]`` tables).

    Raises
    ------
    ConfigError
        The file cannot be read, is not UTF-8 TOML, or a key is missing, unknown
        (in ``[[channels]]``), of the wrong type or out of range; the message names
        the file and the ``[table.key]``.
    """
    folder = Path(folder)
    path = folder / DESCRIPTION_FILE
    source = str(path)
    text = read_toml_text(path, "driver description")
    data = parse_toml(text, source)
    parsed = build_table(_DriverFile, data, "", source)
    if parsed.driver.transport == "serial":
        _check_serial_keys(data, source)
        _serial_loop(data, source)
    _check_board_rates(parsed.board, source)
    channels = _described_channels(parsed, folder, data, source)
    _check_channel_scales(channels, source)
    _check_channel_names(channels, source)
    _check_filter_input(channels, source)
    return _driver_description(parsed, folder, channels, data, text)


def _check_serial_keys(data: dict, source: str) -> None:
    """Refuse a serial driver that leaves out one of the serial protocol's own figures (:data:`_SERIAL_REQUIRED`)."""
    for table, key in _SERIAL_REQUIRED:
        if key not in data[table]:
            raise ConfigError(f"{table}.{key}", "is required for a serial driver", source)


def _serial_loop(data: dict, source: str) -> LoopDescription | None:
    """A serial driver's ``[loop]``: each parameter in the board's LOOP message (PROTOCOL.md section 4.15) or a
    fixed value; None without one. ConfigError naming the key and ``source`` when it is malformed."""
    return parse_loop(data.get("loop"), source, kinds=("message",))


def serial_loop(driver: DriverDescription) -> LoopDescription | None:
    """The ``[loop]`` of the serial driver ``driver`` (checked when it was loaded); None when it has none."""
    return _serial_loop(driver.sections, str(driver.folder / DESCRIPTION_FILE))


def _check_board_rates(board: _BoardTable, source: str) -> None:
    """Refuse a board whose highest sample rate (Hz) exceeds its loop rate (Hz)."""
    if board.max_sample_rate_hz > board.loop_rate_hz:
        raise ConfigError(
            "board.max_sample_rate_hz",
            f"{board.max_sample_rate_hz:g} Hz exceeds board.loop_rate_hz = {board.loop_rate_hz:g} Hz",
            source,
        )


def _described_channels(parsed: _DriverFile, folder: Path, data: dict, source: str) -> tuple[ChannelSpec, ...]:
    """The ``[[channels]]`` of the file; for a CANopen drive that lists none, those its EDS has.

    Raises
    ------
    ConfigError
        The driver ends up with no channel.
    """
    channels = tuple(
        ChannelSpec(c.name, c.unit, c.format, c.scale, c.stream, c.sampling, c.filter_input) for c in parsed.channels
    )
    if not channels and parsed.driver.transport == "canopen":
        channels = _canopen_channels(folder, data, source)
    if not channels:
        raise ConfigError("channels", "a driver needs at least one [[channels]] entry", source)
    return channels


def _check_channel_scales(channels: tuple[ChannelSpec, ...], source: str) -> None:
    """Refuse a channel whose scale (SI units per LSB) is zero."""
    zero = next((i for i, c in enumerate(channels) if c.scale == 0), None)
    if zero is not None:
        raise ConfigError(f"channels[{zero}].scale", "must not be zero", source)


def _check_channel_names(channels: tuple[ChannelSpec, ...], source: str) -> None:
    """Refuse channel names that repeat or are empty."""
    names = [c.name for c in channels]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate is not None or "" in names:
        raise ConfigError("channels", f"channel names must be distinct and non-empty, got {show(names)}", source)


def _check_filter_input(channels: tuple[ChannelSpec, ...], source: str) -> None:
    """Refuse more than one channel marked as the signal entering the filter slots."""
    inputs = [i for i, c in enumerate(channels) if c.filter_input]
    if len(inputs) > 1:
        raise ConfigError(
            f"channels[{inputs[1]}].filter_input",
            f"only one channel enters the filter slots; {channels[inputs[0]].name!r} already does",
            source,
        )


def _driver_description(
    parsed: _DriverFile, folder: Path, channels: tuple[ChannelSpec, ...], data: dict, text: str
) -> DriverDescription:
    """The checked tables of a ``driver.toml`` as a :class:`DriverDescription` (the serial-only figures 0 for
    other transports)."""
    d, board = parsed.driver, parsed.board
    serial = d.transport == "serial"
    return DriverDescription(
        name=d.name,
        folder=folder,
        transport=d.transport,
        protocol_version=d.protocol_version if serial else 0,
        default_baudrate=d.default_baudrate,
        description=d.description,
        firmware=board.firmware,
        loop_rate_hz=board.loop_rate_hz,
        max_sample_rate_hz=board.max_sample_rate_hz,
        filter_slots=board.filter_slots,
        excitation_buffer_samples=board.excitation_buffer_samples if serial else 0,
        block_samples=board.block_samples if serial else 0,
        channels=channels,
        placeholders=tuple(d.placeholders),
        sections=data,
        text=text,
    )


def load_object_dictionary(
    driver: DriverDescription | Path, node_id: int | None = None, warnings: list[str] | None = None
):
    """The object dictionary of a CANopen driver folder's EDS (``[canopen] eds``), read as vendors write them.

    Parameters
    ----------
    driver : DriverDescription or Path
        The driver, or its folder.
    node_id : int, optional
        Node id that ``$NODEID`` in the EDS stands for.
    warnings : list, optional
        Receives one line per quirk of the file that was repaired (see
        :func:`hilident.protocol.eds.load_eds`).

    Raises
    ------
    ConfigError
        No ``[canopen] eds``, the file is missing, or it cannot be read; the message names the file.
    """
    from hilident.protocol.eds import load_eds

    folder = driver.folder if isinstance(driver, DriverDescription) else Path(driver)
    source = str(folder / DESCRIPTION_FILE)
    sections = (
        driver.sections
        if isinstance(driver, DriverDescription)
        else parse_toml(read_toml_text(folder / DESCRIPTION_FILE, "driver description"), source)
    )
    co = sections.get("canopen")
    name = co.get("eds") if isinstance(co, dict) else None
    if not isinstance(name, str) or not name:
        raise ConfigError("canopen.eds", "a CANopen driver names its EDS file", source)
    path = folder / name
    if not _is_file(path):
        raise ConfigError("canopen.eds", f"EDS file {path} not found", source)
    od, found = load_eds(path, node_id)
    if warnings is not None:
        warnings.extend(found)
    return od


def _canopen_channels(folder: Path, data: dict, source: str) -> tuple[ChannelSpec, ...]:
    """The channels of a CANopen drive whose description lists none: from the objects its EDS has."""
    from hilident.protocol.canopen_objects import CanopenDescription
    from hilident.protocol.canopen_profile import CHANNEL_UNITS

    desc = CanopenDescription.from_sections(data, source, load_object_dictionary(folder))
    return tuple(ChannelSpec(name, CHANNEL_UNITS.get(name, "1")) for name in desc.channels)


# --- checks of a run against its driver, before connecting ----------------------------------

#: Largest loop-rate divider a device takes (a 16-bit field on every transport).
MAX_DIVIDER = 65535
#: hilident modes every serial board offers (PROTOCOL.md: the CONFIGURE mode byte).
SERIAL_MODES = ("torque", "torque_injection", "velocity", "position")


def declared_modes(driver: DriverDescription) -> tuple[str, ...]:
    """hilident modes the device runs: ``[canopen.modes]`` or those its EDS offers, ``[modbus.modes]``, or every
    serial mode."""
    if driver.transport == "serial":
        return SERIAL_MODES
    if driver.transport == "canopen":
        from hilident.protocol.canopen_objects import CanopenDescription

        desc = CanopenDescription.from_sections(
            driver.sections, str(driver.folder / DESCRIPTION_FILE), load_object_dictionary(driver)
        )
        return tuple(desc.modes)
    table = driver.sections.get(driver.transport, {})
    modes = table.get("modes", {}) if isinstance(table, dict) else {}
    return tuple(modes) if isinstance(modes, dict) else ()


def valid_sample_rates(driver: DriverDescription, count: int | None = None) -> list[float]:
    """Sample rates the device records: its loop rate divided by a whole number, at most its maximum, Hz.

    Parameters
    ----------
    driver : DriverDescription
    count : int, optional
        Return only the ``count`` highest rates.
    """
    rates: list[float] = []
    first = max(1, math.ceil(driver.loop_rate_hz / driver.max_sample_rate_hz - 1e-9))
    for divider in range(first, MAX_DIVIDER + 1):
        if count is not None and len(rates) >= count:
            break
        rates.append(driver.loop_rate_hz / divider)
    return rates


def check_run_against_driver(cfg, driver: DriverDescription) -> tuple[str, ...]:
    """Refuse, before connecting, what a run of ``cfg`` would only fail at on the device.

    Refuses a driver with placeholders on a real port. Checks the sample rate
    against the loop rate (the message lists valid rates),
    the channels the session records and analyses, the modes of the excitation
    and of the friction test, and the filter slots the notches need.
    Returns the modes the device runs (:func:`declared_modes`), read once here.

    Parameters
    ----------
    cfg : hilident.config.tables.Config
    driver : DriverDescription

    Raises
    ------
    ConfigError
        Naming the configuration key, the configuration file and the driver.
    """
    src, what = cfg.source, f"driver {driver.name!r} ({driver.folder / DESCRIPTION_FILE})"
    if driver.placeholders and cfg.device.port != "emulator":
        raise ConfigError(
            "driver.placeholders",
            f"{what} still has guessed values for "
            f"{', '.join(driver.placeholders)}: set them to the drive's real "
            "values (and remove them from the list) before a real port",
            str(driver.folder / DESCRIPTION_FILE),
        )
    _check_sample_rate(cfg, driver, what)
    names = [c.name for c in driver.channels]
    for i, name in enumerate(cfg.run.channels):
        if name not in names:
            raise ConfigError(
                f"run.channels[{i}]", f"{what} has no channel {show(name)} (it has: {', '.join(names)})", src
            )
    recorded = cfg.run.channels or [c.name for c in driver.streamed_channels]
    needed = (
        ("identification.output", cfg.identification.output),
        ("run.channels", "excitation"),
        ("run.channels", "torque_nm"),
        ("run.channels", "velocity_mps"),
    )
    for key, name in needed:
        if name not in names:
            raise ConfigError(key, f"{what} has no channel {show(name)} (it has: {', '.join(names)})", src)
        if name not in recorded:
            raise ConfigError(
                key, f"channel {name!r} is not recorded by default by {what}; list it in run.channels", src
            )
    modes = declared_modes(driver)
    if cfg.excitation.mode not in modes:
        raise ConfigError(
            "excitation.mode",
            f"{what} runs no {cfg.excitation.mode!r} mode (it has: {', '.join(modes) or 'none'})",
            src,
        )
    if cfg.friction_test.enabled and not {"velocity", "position"} & set(modes):
        raise ConfigError(
            "friction_test.enabled",
            f"the friction test runs in velocity (or position) mode, which "
            f"{what} does not have (it has: {', '.join(modes) or 'none'})",
            src,
        )
    # a device without filter slots is no error: the session designs the notch, reports it and says why it was
    # not uploaded
    return modes


def _check_sample_rate(cfg, driver: DriverDescription, what: str) -> None:
    fs = cfg.run.sample_rate_hz
    divider = driver.loop_rate_hz / fs
    rate = driver.loop_rate_hz / round(divider) if round(divider) >= 1 else math.inf
    if (
        abs(divider - round(divider)) <= 1e-9 * divider
        and 1 <= round(divider) <= MAX_DIVIDER
        and rate <= driver.max_sample_rate_hz * (1 + 1e-9)
    ):
        return
    valid = ", ".join(f"{r:g}" for r in valid_sample_rates(driver, 8))
    raise ConfigError(
        "run.sample_rate_hz",
        f"{fs:g} Hz is not a rate {what} records; valid: {valid}, ... Hz "
        f"(the loop rate {driver.loop_rate_hz:g} Hz divided by a whole number "
        f"up to {MAX_DIVIDER}, at most {driver.max_sample_rate_hz:g} Hz)",
        cfg.source,
    )
