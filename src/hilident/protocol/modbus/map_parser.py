"""The ``[modbus]`` tables of a driver description, read and validated: the register map language.

A Modbus drive is described by data (``drivers/<name>/driver.toml``, tables
``[modbus]``, ``[modbus.registers]``, ``[modbus.control]``, ``[modbus.status]``,
``[modbus.fault_codes]``, ``[modbus.modes]``, ``[modbus.table]``,
``[modbus.capture]``, ``[modbus.filters]``, ``[filters]`` and ``[loop]``).
:func:`parse_map_tables` reads them into the parts of a
:class:`~hilident.protocol.modbus.register_map.RegisterMap`, or raises a
:class:`~hilident.errors.ConfigError` naming the key and the file.

Each ``[modbus.registers]`` entry goes through the typed schema of
:mod:`hilident.config.schema` (:class:`_RegisterSpec`): ``address`` or ``parameter``
(a vendor code such as ``"P08.02"`` resolved by the rule of
``[modbus.parameters]``, :class:`~hilident.protocol.modbus.registers.ParameterRule`),
``type``, ``access``, ``table`` (holding or input), ``scale``, ``offset``,
``unit``, ``min``, ``max``, ``word_order``, ``byte_order``,
``channel``/``channel_scale`` (the drive channel a feedback register shows),
plus ``bits`` (named masks) and ``default`` (the value at power-up).
Capabilities are tables of their own: hilident's excitation table and capture
(``[modbus.table]``, ``[modbus.capture]`` with the control/status registers
they need; a map without them describes a parameter drive), ``[modbus.filters]``
(hilident's four-register slots, or ``slots`` naming the drive's own notch
parameters, :mod:`~hilident.protocol.modbus.filter_slots`),
``[modbus.identity]``, ``[modbus.save]`` and ``[modbus.stop]``. ``[loop]`` names the registers
that hold the drive's cascade parameters (:mod:`~hilident.protocol.modbus.loop_registers`).

All pure: dicts in, dataclasses out.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import ClassVar, NoReturn

from hilident.config.schema import build_table
from hilident.config.schema import spec as _spec
from hilident.errors import ConfigError, DataError
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.protocol.loop_parameters import LoopDescription
from hilident.protocol.modbus.codecs import BYTE_ORDERS, TYPES, WORD_ORDERS
from hilident.protocol.modbus.filter_slots import FILTER_FIELDS, FieldSlots, FourRegisterSlots
from hilident.protocol.modbus.loop_registers import parse_loop_registers
from hilident.protocol.modbus.paging import CaptureChannel, Window
from hilident.protocol.modbus.registers import ParameterRule, Register

__all__ = ["ExcitationProtocol", "MapTables", "parse_map_tables"]

#: ``table`` of a register: holding registers (function 3, written by 6 and 16) or input registers (function 4).
REGISTER_TABLES = ("holding", "input")
#: types of the excitation table and capture channels (one or two registers)
WINDOW_TYPES = ("u16", "i16", "u32", "i32", "f32")
#: hilident modes an excitation map gives a ``[modbus.modes]`` code each.
MODES = ("torque", "torque_injection", "velocity", "position")
#: Registers every Modbus drive map must name, with the types allowed for each.
REQUIRED_REGISTERS: dict[str, tuple[str, ...]] = {
    "device_type": ("u16",),
    "map_version": ("u16",),
    "loop_rate_hz": ("u16", "u32", "f32"),
    "max_sample_rate_hz": ("u16", "u32", "f32"),
    "filter_slots": ("u16",),
    "table_capacity": ("u16", "u32"),
    "capture_capacity": ("u16", "u32"),
    "device_name": ("str",),
    "firmware": ("str",),
    "control_word": ("u16",),
    "status_word": ("u16",),
    "fault_code": ("u16",),
    "sample_count": ("u16", "u32"),
    "fault_sample": ("u16", "u32"),
    "fault_value": ("f32",),
    "mode": ("u16",),
    "sample_divider": ("u16",),
    "capture_mask": ("u16",),
    "table_length": ("u16", "u32"),
    "table_page": ("u16",),
    "capture_page": ("u16",),
    "table_crc": ("u16",),
    "torque_limit_nm": ("f32",),
    "velocity_limit_mps": ("f32",),
    "position_min_m": ("f32",),
    "position_max_m": ("f32",),
}
#: Registers of an excitation map the host writes: each must be ``access = "rw"``.
WRITABLE = (
    "control_word",
    "mode",
    "sample_divider",
    "capture_mask",
    "table_length",
    "table_page",
    "capture_page",
    "torque_limit_nm",
    "velocity_limit_mps",
    "position_min_m",
    "position_max_m",
)
#: The names of ``[modbus.control]`` and ``[modbus.status]`` (one bit each) and ``[modbus.fault_codes]``.
CONTROL_BITS = ("run", "fault_reset")
STATUS_BITS = ("enabled", "running", "done", "fault", "capture_stopped", "limits_loaded")
FAULT_NAMES = ("torque_limit", "velocity_limit", "position_limit", "drive_fault")
#: Registers a map may name, with the types allowed; the host uses each only when it is there.
#: ``comm_timeout_ms``: the drive's communication timeout (ms, 0 = off), the device-side stop for a host
#: that dies; a map that names it must also name ``[modbus.fault_codes] comm_timeout``.
OPTIONAL_REGISTERS: dict[str, tuple[str, ...]] = {"comm_timeout_ms": ("u16", "u32")}
OPTIONAL_FAULT_NAMES = {"comm_timeout": "comm_timeout_ms"}  # fault name -> the register it belongs to


#: ``fail(key, message)`` raises the :class:`ConfigError` naming ``key`` and the driver file.
_Fail = Callable[[str, str], NoReturn]


def _fail_in(source: str) -> _Fail:
    def fail(key: str, message: str) -> NoReturn:
        raise ConfigError(key, message, source or None)

    return fail


@dataclass(frozen=True)
class ExcitationProtocol:
    """hilident's table-and-capture protocol of a map (all empty for a parameter drive, which has none)."""

    control: dict[str, int] = field(default_factory=dict)
    status: dict[str, int] = field(default_factory=dict)
    fault_codes: dict[str, int] = field(default_factory=dict)
    modes: dict[str, int] = field(default_factory=dict)
    table: Window | None = None
    table_type: str = "f32"
    table_scale: float = 1.0
    capture: Window | None = None
    capture_channels: tuple[CaptureChannel, ...] = ()


@dataclass(frozen=True)
class MapTables:
    """The ``[modbus]`` tables of a driver description, each validated: what a
    :class:`~hilident.protocol.modbus.register_map.RegisterMap` is built of.

    Attributes
    ----------
    map_version, device_type : int
        What the map's ``map_version`` and ``device_type`` registers must hold (0 when a parameter drive's map
        gives none).
    word_order, byte_order : {"big", "little"}
        The map's defaults: order of the words of a multi-register value, and of the bytes inside a register.
    max_read, max_write : int
        Most registers one read request asks for, and one write request carries.
    registers : dict
        Name -> :class:`~hilident.protocol.modbus.registers.Register`.
    rule : ParameterRule or None
        ``[modbus.parameters]``: how parameter codes give addresses.
    protocol : ExcitationProtocol
        hilident's excitation table and capture (empty for a parameter drive).
    filters : FourRegisterSlots, FieldSlots or None
        ``[modbus.filters]``.
    filter_encoding : FilterEncoding or None
        ``[filters]``: how a slot stores a notch.
    identity : tuple of str
        Registers read at connect.
    expect : dict
        Register -> the value it must hold at connect.
    save : (str, float) or None
        Register and value that store the parameters.
    stop : dict
        Register -> value that brings the axis to a stop.
    loop : LoopDescription or None
        ``[loop]``: the registers that hold the drive's cascade parameters (None: not described).
    """

    map_version: int
    device_type: int
    word_order: str
    byte_order: str
    max_read: int
    max_write: int
    registers: dict[str, Register]
    rule: ParameterRule | None
    protocol: ExcitationProtocol
    filters: FourRegisterSlots | FieldSlots | None
    filter_encoding: FilterEncoding | None
    identity: tuple[str, ...]
    expect: dict
    save: tuple[str, float] | None
    stop: dict
    loop: LoopDescription | None = None


def parse_map_tables(sections: dict, filter_slots: int, source: str = "") -> MapTables:
    """Validate the ``[modbus]`` tables (and the ``[filters]`` encoding) of a parsed driver description.

    Parameters
    ----------
    sections : dict
        The parsed ``driver.toml``.
    filter_slots : int
        The drive's filter slots (``board.filter_slots``).
    source : str
        Its path, for messages.

    Raises
    ------
    ConfigError
        A table or key is missing, has the wrong type, or registers overlap;
        the message names the dotted key and ``source``.
    """
    fail = _fail_in(source)
    mb = _subtable(sections, "modbus", "", fail)
    keys = build_table(_ModbusTable, mb, "modbus.", source)
    rule = _parse_rule(mb, source) if "parameters" in mb else None
    registers = _parse_registers(
        _subtable(mb, "registers", "modbus", fail), rule, keys.word_order, keys.byte_order, source
    )
    excitation = "table" in mb or "capture" in mb
    protocol = _parse_excitation(mb, registers, source) if excitation else ExcitationProtocol()
    filters, encoding = _parse_filters(sections, mb, registers, rule, filter_slots, excitation, source)
    identity, expect = _parse_identity(mb, registers, excitation, fail)
    save = _parse_save(mb, registers, rule, fail)
    stop = _parse_stop(mb, registers, fail)
    _check_overlaps(registers, protocol.table, protocol.capture, filters, filter_slots, fail)
    loop = parse_loop_registers(sections.get("loop"), registers, source)
    return MapTables(
        map_version=keys.identity_code("map_version", excitation, source),
        device_type=keys.identity_code("device_type", excitation, source),
        word_order=keys.word_order,
        byte_order=keys.byte_order,
        max_read=keys.max_read_registers,
        max_write=keys.max_write_registers,
        registers=registers,
        rule=rule,
        protocol=protocol,
        filters=filters,
        filter_encoding=encoding,
        identity=identity,
        expect=expect,
        save=save,
        stop=stop,
        loop=loop,
    )


# --- [modbus] and [modbus.registers] --------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class _ModbusTable:
    """The scalar keys of ``[modbus]``; its sub-tables are read by the functions below."""

    open_table: ClassVar[bool] = True  # registers, parameters, table, capture, filters, identity, save, stop, ...
    word_order: str = _spec("big", choices=WORD_ORDERS, doc="order of the words of a 32-bit value")
    byte_order: str = _spec("big", choices=BYTE_ORDERS, doc="order of the bytes in a word")
    max_read_registers: int = _spec(125, ge=1, le=125, doc="most registers one read request asks for")
    max_write_registers: int = _spec(123, ge=1, le=123, doc="most registers one write request carries")
    map_version: int | None = _spec(None, ge=0, le=0xFFFF, doc="excitation maps: the map version register's value")
    device_type: int | None = _spec(None, ge=0, le=0xFFFF, doc="excitation maps: the device type register's value")

    def identity_code(self, name: str, excitation: bool, source: str) -> int:
        """``map_version`` or ``device_type``: required by an excitation map, else 0 when not given."""
        value = getattr(self, name)
        if value is None and excitation:
            raise ConfigError(f"modbus.{name}", "is required", source or None)
        return 0 if value is None else value


def _subtable(parent: dict, key: str, prefix: str, fail: _Fail) -> dict:
    value = parent.get(key)
    if not isinstance(value, dict):
        fail(f"{prefix}.{key}" if prefix else key, "table is required")
    return value


def _parse_rule(mb: dict, source: str) -> ParameterRule:
    """``[modbus.parameters]``: ``address`` (the rule) and ``prefix`` of the parameter codes."""
    fail = _fail_in(source)
    table = mb["parameters"]
    if not isinstance(table, dict):
        fail("modbus.parameters", "must be a table {address, prefix}")
    unknown = set(table) - {"address", "prefix"}
    if unknown:
        fail(f"modbus.parameters.{sorted(unknown)[0]}", "unknown key (known here: address, prefix)")
    prefix = table.get("prefix", "P")
    if not isinstance(prefix, str) or not re.fullmatch(r"[A-Za-z]{0,8}", prefix):
        fail("modbus.parameters.prefix", f"must be up to 8 letters, got {prefix!r}")
    if "address" not in table:
        fail("modbus.parameters.address", 'is required (e.g. "group * 0x100 + index")')
    return ParameterRule.parse(table["address"], prefix, "modbus.parameters.address", source)


def _parse_registers(
    table: dict, rule: ParameterRule | None, word_order: str, byte_order: str, source: str
) -> dict[str, Register]:
    """``[modbus.registers]``: each entry through the typed schema, plus ``bits`` and ``default``."""
    return {name: _parse_register(name, raw, rule, word_order, byte_order, source) for name, raw in table.items()}


@dataclass(frozen=True, kw_only=True)
class _RegisterSpec:
    """One ``[modbus.registers]`` entry, validated by the typed schema of :mod:`hilident.config.schema`."""

    address: int = _spec(-1, ge=-1, le=65535, doc="0-based protocol address; -1: from `parameter` and the rule")
    parameter: str = _spec("", doc='vendor parameter code resolved by [modbus.parameters] (e.g. "P08.02")')
    type: str = _spec(choices=(*TYPES, "str"))
    access: str = _spec("r", choices=("r", "rw"))
    table: str = _spec("holding", choices=REGISTER_TABLES)
    scale: float = _spec(1.0, doc="physical units per raw unit (non-zero)")
    offset: float = _spec(0.0, doc="physical value of raw 0")
    unit: str = _spec("")
    min: float | None = _spec(None, doc="smallest physical value (writes below it are refused)")
    max: float | None = _spec(None, doc="largest physical value")
    length: int = _spec(1, ge=1, le=125, doc="str: registers")
    word_order: str = _spec("", choices=("", *WORD_ORDERS), doc="default: [modbus] word_order")
    byte_order: str = _spec("", choices=("", *BYTE_ORDERS), doc="default: [modbus] byte_order")
    channel: str = _spec("", doc="drive channel the register shows")
    channel_scale: float = _spec(1.0, doc="SI units of the channel per physical unit")
    description: str = _spec("")


def _parse_register(
    name: str, raw, rule: ParameterRule | None, word_order: str, byte_order: str, source: str
) -> Register:
    """One ``[modbus.registers]`` entry; ``word_order`` and ``byte_order`` are the map's defaults."""
    fail = _fail_in(source)
    key = f"modbus.registers.{name}"
    if not isinstance(raw, dict):
        fail(key, "must be a table {address, type, access}")
    spec = build_table(_RegisterSpec, {k: v for k, v in raw.items() if k not in ("bits", "default")}, key + ".", source)
    if spec.scale == 0:
        fail(f"{key}.scale", "must be a non-zero finite number, got 0")
    count = spec.length if spec.type == "str" else TYPES[spec.type][0]
    code, address = _register_address(name, spec, rule, key, fail)
    if address + count > 65536:
        fail(f"{key}.address", f"{count} registers from {address} leave the 16-bit address space")
    if spec.table == "input" and spec.access == "rw":
        fail(f"{key}.access", 'an input register is read only: "r"')
    if spec.min is not None and spec.max is not None and spec.min > spec.max:
        fail(f"{key}.min", f"{spec.min:g} is above max {spec.max:g}")
    register = Register(
        name,
        address,
        spec.type,
        spec.access,
        spec.scale,
        count,
        spec.word_order or word_order,
        spec.byte_order or byte_order,
        spec.table,
        spec.offset,
        spec.unit,
        spec.min,
        spec.max,
        _parse_bits(raw.get("bits", {}), spec.type, count, f"{key}.bits", fail),
        code,
        spec.channel,
        spec.channel_scale,
        None,
    )
    if "default" in raw:
        register = replace(register, default=_register_default(register, raw["default"], key, fail))
    return register


def _register_address(
    name: str, spec: _RegisterSpec, rule: ParameterRule | None, key: str, fail: _Fail
) -> tuple[str, int]:
    """The parameter code and address of a register: ``address``, else its code through the rule (they must agree)."""
    code, address = spec.parameter, spec.address
    if address < 0:
        code = code or name
        if rule is None:
            fail(f"{key}.address", "is required (or a parameter code with a [modbus.parameters] rule)")
        try:
            return code, rule.address_of(code)
        except DataError as exc:
            fail(f"{key}.parameter" if spec.parameter else f"{key}.address", str(exc))
    if code and rule is not None:
        try:
            where = rule.address_of(code)
        except DataError as exc:
            fail(f"{key}.parameter", str(exc))
        if where != address:
            fail(f"{key}.address", f"{address:#06x} is not where {rule.text!r} puts {code}")
    return code, address


def _register_default(register: Register, default: float | str, key: str, fail: _Fail) -> float | str:
    """``default``: the register's value at power-up, of its kind and within what it encodes."""
    is_str = register.type == "str"
    if isinstance(default, bool) or not isinstance(default, (int, float, str)) or isinstance(default, str) != is_str:
        fail(f"{key}.default", f"must be a {'string' if is_str else 'number'}, got {default!r}")
    try:
        register.encode(default)
    except DataError as exc:
        fail(f"{key}.default", str(exc))
    return default


def _parse_bits(bits, type_: str, count: int, key: str, fail: _Fail) -> dict[str, int]:
    """``bits = { name = mask }``: masks of an integer register, non-zero, within its width."""
    if not isinstance(bits, dict):
        fail(key, f"must be a table {{name = mask}}, got {bits!r}")
    if bits and (type_ == "str" or type_.startswith("f")):
        fail(key, f"bit fields need an integer type, not {type_}")
    out = {}
    for name, mask in bits.items():
        if isinstance(mask, bool) or not isinstance(mask, int) or not 0 < mask < 1 << (16 * count):
            fail(f"{key}.{name}", f"must be a non-zero mask within {16 * count} bits, got {mask!r}")
        out[name] = mask
    return out


def _named_register(
    value, registers: dict[str, Register], rule: ParameterRule | None, key: str, fail: _Fail
) -> Register:
    """A register of the map by name, or by parameter code through the rule (a ``u16`` holding register)."""
    if not isinstance(value, str):
        fail(key, f"must name a register or a parameter code, got {value!r}")
    if value in registers:
        return registers[value]
    for r in registers.values():
        if r.parameter == value:
            return r
    if rule is None:
        fail(key, f"{value!r} is no register of [modbus.registers]")
    try:
        return Register(value, rule.address_of(value), "u16", "rw", parameter=value)
    except DataError as exc:
        fail(key, f"{value!r} is no register of [modbus.registers], nor a parameter: {exc}")


# --- hilident's excitation table and capture ------------------------------------------------------


def _parse_excitation(mb: dict, registers: dict[str, Register], source: str) -> ExcitationProtocol:
    """hilident's table-and-capture protocol: control/status/fault/mode codes, the table and the capture."""
    fail = _fail_in(source)
    _check_required(registers, fail)
    control = _codes(mb, "control", CONTROL_BITS, True, fail)
    status = _codes(mb, "status", STATUS_BITS, True, fail)
    fault_codes = _codes(mb, "fault_codes", FAULT_NAMES, False, fail)
    fault_codes.update(_optional_fault_codes(mb["fault_codes"], registers, fault_codes, fail))
    modes = _codes(mb, "modes", MODES, False, fail)
    tb = _subtable(mb, "table", "modbus", fail)
    kind = build_table(_TableType, tb, "modbus.table.", source)
    window = build_table(_WindowTable, tb, "modbus.table.", source)
    table = Window(
        "table",
        window.base,
        window.page_samples,
        window.capacity_samples,
        window.page_samples * TYPES[kind.type][0],
        "table_page",
    )
    capture, channels = _parse_capture(_subtable(mb, "capture", "modbus", fail), source)
    for w in (table, capture):
        if w.end > 65536:
            fail(f"modbus.{w.name}.base", f"the window {w.base}..{w.end - 1} leaves the 16-bit address space")
        if w.pages > 65536:
            fail(f"modbus.{w.name}.page_samples", f"{w.pages} pages do not fit the u16 {w.page_register}")
    return ExcitationProtocol(control, status, fault_codes, modes, table, kind.type, kind.scale, capture, channels)


def _check_required(registers: dict[str, Register], fail: _Fail) -> None:
    """A map with the excitation capability names every register of hilident's table-and-capture protocol."""
    for name, types in REQUIRED_REGISTERS.items():
        if name not in registers:
            fail(f"modbus.registers.{name}", "is required")
        if registers[name].type not in types:
            fail(f"modbus.registers.{name}.type", f"must be one of {types}, got {registers[name].type!r}")
    for name in WRITABLE:
        if not registers[name].writable:
            fail(f"modbus.registers.{name}.access", 'must be "rw": the host writes it')
    for name, types in OPTIONAL_REGISTERS.items():
        if name in registers and registers[name].type not in types:
            fail(f"modbus.registers.{name}.type", f"must be one of {types}, got {registers[name].type!r}")
        if name in registers and not registers[name].writable:
            fail(f"modbus.registers.{name}.access", 'must be "rw": the host writes it')


def _codes(mb: dict, key: str, names, bits: bool, fail: _Fail) -> dict[str, int]:
    """``[modbus.<key>]``: a distinct 16-bit code (a single bit when ``bits``) for each of ``names``."""
    table = _subtable(mb, key, "modbus", fail)
    out = {}
    for name in names:
        value = table.get(name)
        if value is None:
            fail(f"modbus.{key}.{name}", "is required")
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 0xFFFF:
            fail(f"modbus.{key}.{name}", f"must be an integer in 1..65535, got {value!r}")
        if bits and value & (value - 1):
            fail(f"modbus.{key}.{name}", f"must be a single bit, got {value:#x}")
        out[name] = value
    if len(set(out.values())) != len(out):
        fail(f"modbus.{key}", "values must be distinct")
    return out


def _optional_fault_codes(table: dict, registers: dict, required: dict, fail: _Fail) -> dict[str, int]:
    """The codes of the optional faults in ``[modbus.fault_codes]``, each required when its register is named."""
    out = {}
    for name, register in OPTIONAL_FAULT_NAMES.items():
        value = table.get(name)
        if value is None:
            if register in registers:
                fail(f"modbus.fault_codes.{name}", f"is required: the map names register {register}")
            continue
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 0xFFFF:
            fail(f"modbus.fault_codes.{name}", f"must be an integer in 1..65535, got {value!r}")
        if value in required.values():
            fail("modbus.fault_codes", "values must be distinct")
        out[name] = value
    return out


def _non_zero(value, key, source):
    if value == 0:
        raise ConfigError(key, f"must be a non-zero finite number, got {value!r}", source or None)


@dataclass(frozen=True, kw_only=True)
class _WindowTable:
    """``[modbus.table]`` and ``[modbus.capture]``: a paged window onto a buffer."""

    open_table: ClassVar[bool] = True  # [modbus.table] type and scale, [[modbus.capture.channels]]
    base: int = _spec(ge=0, le=65535, doc="address of the window")
    page_samples: int = _spec(ge=1, le=65535, doc="samples the window shows")
    capacity_samples: int = _spec(65536, ge=1, le=2**32 - 1, doc="length of the buffer, samples")


@dataclass(frozen=True, kw_only=True)
class _TableType:
    """``[modbus.table]`` type and scale of the excitation samples."""

    open_table: ClassVar[bool] = True
    type: str = _spec("f32", choices=WINDOW_TYPES)
    scale: float = _spec(1.0, check=_non_zero, doc="physical units per raw unit")


@dataclass(frozen=True, kw_only=True)
class _CaptureChannelTable:
    """One ``[[modbus.capture.channels]]`` entry."""

    open_table: ClassVar[bool] = True
    name: str = _spec()
    type: str = _spec(choices=WINDOW_TYPES)
    scale: float = _spec(1.0, check=_non_zero)


def _parse_capture(cp: dict, source: str) -> tuple[Window, tuple[CaptureChannel, ...]]:
    """``[modbus.capture]``: its window and channels (at most 16: the bits of ``capture_mask``)."""
    fail = _fail_in(source)
    raw = cp.get("channels")
    if not isinstance(raw, list) or not raw:
        fail("modbus.capture.channels", "needs at least one [[modbus.capture.channels]] entry")
    if len(raw) > 16:
        fail("modbus.capture.channels", f"capture_mask has 16 bits; {len(raw)} channels given")
    channels = []
    for i, ch in enumerate(raw):
        if not isinstance(ch, dict):
            fail(f"modbus.capture.channels[{i}].name", "is required")
        c = build_table(_CaptureChannelTable, ch, f"modbus.capture.channels[{i}].", source)
        channels.append(CaptureChannel(c.name, c.type, c.scale, i))
    if len({c.name for c in channels}) != len(channels):
        fail("modbus.capture.channels", "channel names must be distinct")
    window = build_table(_WindowTable, cp, "modbus.capture.", source)
    record_max = 1 + sum(c.count for c in channels)
    capture = Window(
        "capture",
        window.base,
        window.page_samples,
        window.capacity_samples,
        window.page_samples * record_max,
        "capture_page",
    )
    return capture, tuple(channels)


# --- filter slots ---------------------------------------------------------------------------------


def _parse_filters(
    sections: dict,
    mb: dict,
    registers: dict[str, Register],
    rule: ParameterRule | None,
    filter_slots: int,
    excitation: bool,
    source: str,
) -> tuple[FourRegisterSlots | FieldSlots | None, FilterEncoding | None]:
    """``[modbus.filters]`` with the ``[filters]`` encoding: hilident's slots or the drive's named registers."""
    fail = _fail_in(source)
    if not (excitation or "filters" in mb):
        if filter_slots:
            fail("modbus.filters", f"is required: board.filter_slots = {filter_slots}")
        return None, None
    encoding = FilterEncoding.from_table(sections.get("filters", {}), source)
    ft = _subtable(mb, "filters", "modbus", fail)
    if "slots" in ft:
        return _parse_field_slots(ft, encoding, registers, rule, filter_slots, fail), encoding
    if encoding.kind != "notch_parameters":
        fail("filters.encoding", f'a Modbus drive map holds "notch_parameters", got {encoding.kind!r}')
    keys = build_table(_FourRegisterSlotsTable, ft, "modbus.filters.", source)
    offsets = {f: getattr(keys, f) for f in FILTER_FIELDS}
    if sorted(offsets.values()) != [0, 1, 2, 3]:
        fail("modbus.filters", "center, width, depth and enable must be the offsets 0, 1, 2, 3 in some order")
    filters = FourRegisterSlots(keys.base, keys.stride, filter_slots, offsets)
    if filters.end > 65536:
        fail("modbus.filters.base", "the filter slots leave the 16-bit address space")
    return filters, encoding


@dataclass(frozen=True, kw_only=True)
class _FourRegisterSlotsTable:
    """``[modbus.filters]`` of hilident's four-register slots: base, stride and each field's offset."""

    open_table: ClassVar[bool] = True
    base: int = _spec(ge=0, le=65535, doc="address of slot 0")
    stride: int = _spec(4, ge=4, le=65535, doc="registers from one slot to the next")
    center: int = _spec(ge=0, le=3)
    width: int = _spec(ge=0, le=3)
    depth: int = _spec(ge=0, le=3)
    enable: int = _spec(ge=0, le=3)


def _parse_field_slots(
    ft: dict,
    encoding: FilterEncoding,
    registers: dict[str, Register],
    rule: ParameterRule | None,
    filter_slots: int,
    fail: _Fail,
) -> FieldSlots:
    """``[modbus.filters]`` with ``slots = [{center = ..., width = ..., depth = ...}]`` and ``off`` or ``enable``."""
    if encoding.kind == "word_block" or encoding.kind not in (
        "notch_parameters",
        "index_table",
        "pole_zero_q",
        "pole_zero_damping",
        "center_band",
        "center_ratio_damping",
    ):
        fail("filters.encoding", f"filter slots of named registers hold notch parameters, not {encoding.kind!r}")
    unknown = set(ft) - {"slots", "off"}
    if unknown:
        fail(f"modbus.filters.{sorted(unknown)[0]}", "unknown key (known with slots: slots, off)")
    raw = ft["slots"]
    if not isinstance(raw, list) or len(raw) != filter_slots:
        fail(
            "modbus.filters.slots",
            f"must list board.filter_slots = {filter_slots} slot(s), got "
            f"{len(raw) if isinstance(raw, list) else raw!r}",
        )
    slots = [
        _field_slot(f"modbus.filters.slots[{i}]", entry, encoding, registers, rule, fail) for i, entry in enumerate(raw)
    ]
    off = ft.get("off", {})
    has_enable = bool(slots) and "enable" in slots[0]
    if not isinstance(off, dict) or (not has_enable and len(off) != 1) or set(off) - set(encoding.fields):
        fail(
            "modbus.filters.off",
            "slots without an enable register need off = {field = stored value} "
            f"for one of {', '.join(encoding.fields)}: the value that bypasses the slot",
        )
    for name, value in off.items():
        if isinstance(value, bool) or not isinstance(value, int):
            fail(f"modbus.filters.off.{name}", f"must be the stored integer, got {value!r}")
    return FieldSlots(tuple(slots), dict(off))


def _field_slot(
    key: str, entry, encoding: FilterEncoding, registers: dict[str, Register], rule: ParameterRule | None, fail: _Fail
) -> dict[str, Register]:
    """One slot: the numeric read-write holding register of each field of the encoding (and optionally enable)."""
    names = (*encoding.fields, "enable")
    if not isinstance(entry, dict) or set(entry) - set(names) or not set(encoding.fields) <= set(entry):
        fail(key, f"must name the register of each of {', '.join(encoding.fields)} (and optionally enable)")
    regs = {}
    for name in entry:
        r = _named_register(entry[name], registers, rule, f"{key}.{name}", fail)
        if r.type == "str" or r.table != "holding" or r.access != "rw":
            fail(f"{key}.{name}", f"{r.label} must be a numeric read-write holding register")
        regs[name] = r
    return regs


# --- identity, save, stop; overlaps ---------------------------------------------------------------


def _parse_identity(mb: dict, registers: dict, excitation: bool, fail: _Fail) -> tuple[tuple[str, ...], dict]:
    """``[modbus.identity]``: registers read at connect (``registers``) and values they must hold (``expect``)."""
    table = mb.get("identity")
    if table is None:
        if not excitation:
            fail(
                "modbus.identity",
                "table is required: the registers that identify the drive "
                '(registers = ["motor_model", "software_version"])',
            )
        return (), {}
    if not isinstance(table, dict) or set(table) - {"registers", "expect"}:
        fail("modbus.identity", "must be a table {registers, expect}")
    names = table.get("registers", [])
    if not isinstance(names, list) or not names or any(n not in registers for n in names):
        fail("modbus.identity.registers", f"must list registers of [modbus.registers], got {names!r}")
    expect = table.get("expect", {})
    if not isinstance(expect, dict):
        fail("modbus.identity.expect", "must be a table {register = value}")
    for name, value in expect.items():
        if name not in names:
            fail(f"modbus.identity.expect.{name}", "must be one of modbus.identity.registers")
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            fail(f"modbus.identity.expect.{name}", f"must be a number or a string, got {value!r}")
    return tuple(names), dict(expect)


def _parse_save(
    mb: dict, registers: dict[str, Register], rule: ParameterRule | None, fail: _Fail
) -> tuple[str, float] | None:
    """``[modbus.save]``: the register (or parameter) written to store the parameters, and the value."""
    table = mb.get("save")
    if table is None:
        return None
    if not isinstance(table, dict) or set(table) != {"register", "value"}:
        fail("modbus.save", "must be a table {register, value}")
    r = _named_register(table["register"], registers, rule, "modbus.save.register", fail)
    if r.name not in registers:
        registers[r.name] = r
    if not r.writable:
        fail("modbus.save.register", f"{r.label} must be a read-write holding register")
    value = table["value"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        fail("modbus.save.value", f"must be a number, got {value!r}")
    return r.name, value


def _parse_stop(mb: dict, registers: dict, fail: _Fail) -> dict:
    """``[modbus.stop]``: register values that bring the axis to a stop (written at connect and on every ending)."""
    table = mb.get("stop", {})
    if not isinstance(table, dict):
        fail("modbus.stop", "must be a table {register = value}")
    for name, value in table.items():
        if name not in registers or not registers[name].writable:
            fail(f"modbus.stop.{name}", "must name a read-write holding register of [modbus.registers]")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            fail(f"modbus.stop.{name}", f"must be a number, got {value!r}")
    return dict(table)


def _check_overlaps(
    registers: dict[str, Register],
    table: Window | None,
    capture: Window | None,
    filters: FourRegisterSlots | FieldSlots | None,
    filter_slots: int,
    fail: _Fail,
) -> None:
    """Nothing may overlap: registers (holding and input apart), windows, filter slots."""
    spans = [(r.table, r.address, r.end, f"modbus.registers.{r.name}") for r in registers.values()]
    spans += [("holding", w.base, w.end, f"modbus.{w.name}") for w in (table, capture) if w is not None]
    if isinstance(filters, FourRegisterSlots):
        spans += [
            (
                "holding",
                filters.base + i * filters.stride,
                filters.base + i * filters.stride + filters.span,
                f"modbus.filters (slot {i})",
            )
            for i in range(filter_slots)
        ]
    spans.sort()
    for (t0, a0, a1, k0), (t1, b0, b1, k1) in zip(spans, spans[1:], strict=False):
        if t0 == t1 and b0 < a1:
            fail(k1, f"registers {b0}..{b1 - 1} overlap {k0} ({a0}..{a1 - 1})")
