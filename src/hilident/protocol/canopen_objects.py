"""A CANopen drive's objects as its driver description names them, and how their values are coded.

The ``[canopen]`` tables of a driver description (``drivers/<name>/driver.toml``)
say which object of the drive plays which role (controlword, actual position,
excitation table, ...), how integer objects scale to SI units, which mode of
operation serves each hilident mode and which object carries each recorded
channel. The host adapter and the emulated drive both read them through
:meth:`CanopenDescription.from_sections`, so they agree by the description, not
by sharing state.

Also here: the PDO/capture mapping entry format of CiA 301
(``index << 16 | subindex << 8 | bits``), the packing of several mapped objects
into one record, and SI <-> raw conversion with rounding and clipping. The
object addresses and mode specs it is built of are in
:mod:`~hilident.protocol.canopen_types`.

All pure: dicts and arrays in, dataclasses and arrays out.

Examples
--------
>>> entry = mapping_entry(ObjectAddress(0x6064, 0), 32)
>>> hex(entry), parse_mapping_entry(entry)
('0x60640020', (ObjectAddress(index=24676, subindex=0), 32))
>>> encode_si(np.array([0.1234567]), INTEGER32, 1e-7)
array([1234567], dtype=int32)
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from hilident.config.schema import build_table, spec
from hilident.errors import ConfigError, DataError
from hilident.protocol import canopen_profile as profile
from hilident.protocol.canopen_filters import FilterObjects, parse_filter_objects
from hilident.protocol.canopen_recorder import RecorderCapability, parse_recorder
from hilident.protocol.canopen_sync import SyncCapability, parse_sync
from hilident.protocol.canopen_types import ModeSpec, ObjectAddress, parse_address
from hilident.protocol.loop_parameters import LoopDescription, parse_loop

__all__ = [
    "CanopenDescription",
    "BOOLEAN",
    "INTEGER8",
    "INTEGER16",
    "INTEGER32",
    "UNSIGNED8",
    "UNSIGNED16",
    "UNSIGNED32",
    "REAL32",
    "DOMAIN",
    "NUMERIC_TYPES",
    "type_bits",
    "numpy_type",
    "record_dtype",
    "encode_si",
    "decode_raw",
    "mapping_entry",
    "parse_mapping_entry",
    "pack_frames",
    "TableState",
    "TABLE_START",
    "TABLE_STOP",
    "ROLE_SCALING",
    "ABORT_CONNECTION_OPTIONS",
    "HEARTBEAT_CONSUMER_INDEX",
    "ABORT_CONNECTION_INDEX",
    "consumer_entry",
    "parse_consumer_entry",
    "COUNTER_ROLES",
    "REQUIRED_ROLES",
    "default_supported_modes",
]

# CiA 301 data type codes
BOOLEAN, INTEGER8, INTEGER16, INTEGER32 = 0x01, 0x02, 0x03, 0x04
UNSIGNED8, UNSIGNED16, UNSIGNED32, REAL32 = 0x05, 0x06, 0x07, 0x08
DOMAIN, REAL64, INTEGER64, UNSIGNED64 = 0x0F, 0x11, 0x15, 0x1B

_NUMPY = {
    BOOLEAN: "u1",
    INTEGER8: "i1",
    INTEGER16: "<i2",
    INTEGER32: "<i4",
    UNSIGNED8: "u1",
    UNSIGNED16: "<u2",
    UNSIGNED32: "<u4",
    REAL32: "<f4",
    REAL64: "<f8",
    INTEGER64: "<i8",
    UNSIGNED64: "<u8",
}
NUMERIC_TYPES = frozenset(_NUMPY)


#: Table/capture states reported in the table-state object.
class TableState:
    IDLE = 0
    PLAYING = 1
    DONE = 2
    STOPPED = 3  # ended early: fault, limit trip, disabled by the host

    NAMES = {0: "idle", 1: "playing", 2: "done", 3: "stopped"}


TABLE_STOP = 0
TABLE_START = 1

#: How an object of each role scales to SI: "position" (position_unit_m per
#: increment), "velocity" (velocity_unit_mps per unit), "torque" (per mille of the
#: rated torque), "current" (per mille of the rated current, as torque through the
#: torque constant), "si" (REAL32 already in SI units).
ROLE_SCALING = {
    "position_actual": "position",
    "target_position": "position",
    "position_limit_min": "position",
    "position_limit_max": "position",
    "interpolation_data": "position",
    "velocity_actual": "velocity",
    "target_velocity": "velocity",
    "max_velocity": "velocity",
    "velocity_offset": "velocity",
    "target_torque": "torque",
    "torque_offset": "torque",
    "torque_demand": "torque",
    "torque_actual": "torque",
    "max_torque": "torque",
    "current_actual": "current",
    "applied_excitation": "si",
    "load_position": "si",
}

#: Roles every CANopen drive must have (in its EDS, or named by its driver description).
REQUIRED_ROLES = ("controlword", "statusword", "modes_of_operation")
#: The hilident counters: a drive that has them numbers its TPDOs and RPDOs, so a streamed run is matched
#: sample by sample; without them the host matches TPDOs to SYNCs by their order on the bus.
COUNTER_ROLES = ("sample_counter", "setpoint_counter", "setpoint_underruns", "sync_errors")
BUFFERED_ROLES = (
    "table",
    "table_length",
    "table_divider",
    "table_command",
    "table_state",
    "capture_count",
    "table_capacity",
    "capture_offset",
    "capture_mapping",
    "capture_data",
)
ACQUISITIONS = ("streamed", "buffered", "recorder")
#: CiA 402 abort connection option codes (0x6007) hilident arms: what the drive does when it loses the host.
ABORT_CONNECTION_OPTIONS = {1: "fault", 2: "disable voltage", 3: "quick stop"}
#: Standard objects of the device-side net (CiA 301 heartbeat consumer, CiA 402 abort connection option).
HEARTBEAT_CONSUMER_INDEX = 0x1016
ABORT_CONNECTION_INDEX = 0x6007


def _loop(table, od, source: str) -> LoopDescription | None:
    """The ``[loop]`` table, each object it names found in the EDS."""
    loop = parse_loop(table, source)
    for name, addr in (loop.objects if loop is not None and od is not None else {}).items():
        if od.get_variable(addr.index, addr.subindex) is None:
            raise ConfigError(f"loop.{name}.object", f"{addr} is not in the EDS", source)
    return loop


def _pdo_mappable(od, addr: ObjectAddress) -> bool:
    """Whether the EDS lets ``addr`` be mapped into a PDO (True when there is no EDS to ask)."""
    var = od.get_variable(addr.index, addr.subindex) if od is not None else None
    return var is None or bool(getattr(var, "pdo_mappable", True))


@dataclass(frozen=True)
class CanopenDescription:
    """The ``[canopen]`` part of a driver description, validated against the drive's EDS.

    Standard CiA 301/402 objects are found by their index in the EDS
    (:data:`~hilident.protocol.canopen_profile.STANDARD_OBJECTS`); the driver
    description names only what the EDS cannot say: vendor objects, units,
    the torque reference, mode preference and vendor capabilities.

    Attributes
    ----------
    eds : str
        EDS file name, relative to the driver folder.
    vendor_id, product_code : int or None
        Identity (0x1018:1, 0x1018:2) the device must report; None: not checked.
    default_acquisition : {"streamed", "buffered", "recorder"}
        Used when ``device.acquisition = "auto"``.
    heartbeat_ms : int
        Producer heartbeat time the host asks of the drive (0x1017).
    heartbeat_timeout_ms : int
        A heartbeat gap longer than this stops the run.
    block_transfer : bool
        SDO block transfer for the excitation table and the capture (else segmented).
    emcy_sample_index : bool
        Emergency messages carry the run's sample index in their first four
        manufacturer bytes (UNSIGNED32, 0xFFFFFFFF: none).
    position_unit_m, velocity_unit_mps : float
        SI value of one position increment (m, or rad on a rotary axis) and one velocity unit.
    rated_torque_unit_nm : float
        Unit of the rated torque object 0x6076, N·m (CiA 402: mN·m, 1e-3).
    rated_torque_nm : float
        Rated torque used when 0x6076 is absent or reads 0, N·m (0: none given).
    torque_constant_nm_per_a : float
        Torque per ampere, for drives that report current only (0: none given).
    rated_current_a : float
        Rated current used when 0x6075 is absent or reads 0, A (0: none given).
    cyclic_modes : tuple of str
        Cyclic modes (``"cst"``, ``"csv"``, ``"csp"``, ``"ip"``) in the order the driver prefers them.
    objects : dict
        Role -> ObjectAddress: the standard objects the EDS has, and the vendor objects the description names.
    modes : dict
        hilident mode -> ModeSpec.
    channels : dict
        Channel name -> role of the object that carries it; None: the host records it (the set-point it sent).
    filters : FilterObjects or None
    host_node_id : int
        Node id the host's heartbeat (COB-ID 0x700 + id) is produced under, and
        the drive's heartbeat consumer (0x1016) watches. Must differ from the
        drive's own node id.
    abort_connection_option : int
        Value written to the abort connection option code (0x6007) when the EDS
        has it: what the drive does when the host's heartbeat stops (CiA 402:
        1 fault, 2 disable voltage, 3 quick stop).
    explicit_modes : bool
        ``[canopen.modes]`` fixed the modes; otherwise they follow the drive's supported modes (0x6502).
    unmappable : tuple of str
        Roles whose object the EDS declares not PDO-mappable (a cyclic mode whose set-point is one of them
        cannot be streamed).
    recorder : RecorderCapability or None
        The drive's own generator and recorder (:mod:`hilident.protocol.canopen_recorder`).
    sync : SyncCapability
        Whether the drive can produce SYNC and how it monitors it (:mod:`hilident.protocol.canopen_sync`).
    loop : LoopDescription or None
        Where the drive keeps its cascade's parameters (``[loop]``, :mod:`hilident.protocol.loop_parameters`).
    """

    eds: str
    vendor_id: int | None
    product_code: int | None
    default_acquisition: str
    heartbeat_ms: int
    heartbeat_timeout_ms: int
    block_transfer: bool
    emcy_sample_index: bool
    position_unit_m: float
    velocity_unit_mps: float
    objects: dict[str, ObjectAddress] = field(default_factory=dict)
    modes: dict[str, ModeSpec] = field(default_factory=dict)
    channels: dict[str, str | None] = field(default_factory=dict)
    filters: FilterObjects | None = None
    host_node_id: int = 127
    abort_connection_option: int = 2
    rated_torque_unit_nm: float = 1e-3
    rated_torque_nm: float = 0.0
    torque_constant_nm_per_a: float = 0.0
    rated_current_a: float = 0.0
    cyclic_modes: tuple[str, ...] = ("cst", "csv", "csp", "ip")
    explicit_modes: bool = False
    unmappable: tuple[str, ...] = ()
    recorder: RecorderCapability | None = None
    sync: SyncCapability = field(default_factory=SyncCapability)
    loop: LoopDescription | None = None

    @classmethod
    def from_sections(cls, sections: dict, source: str = "", od=None) -> CanopenDescription:
        """Validate the ``[canopen]`` and ``[filters]`` tables of a parsed driver description.

        The scalar keys of ``[canopen]`` and ``[canopen.scaling]`` are typed
        tables of :mod:`hilident.config.schema`; objects, modes and channels are checked
        against the EDS.

        Parameters
        ----------
        sections : dict
            The parsed ``driver.toml``.
        source : str
            Its path, for messages.
        od : canopen.ObjectDictionary, optional
            The drive's object dictionary (its EDS): standard objects it has are
            added by their index, and every object named must exist in it.
            Without it only the description's own ``[canopen.objects]`` count.

        Raises
        ------
        ConfigError
            A table or key is missing or malformed; the message names the dotted key and ``source``.
        """
        co = sections.get("canopen")
        if not isinstance(co, dict):
            raise ConfigError("canopen", "a CANopen driver needs a [canopen] table", source)
        keys = build_table(_CanopenTable, co, "canopen.", source)
        objects = _objects(co, od, source)
        modes, explicit, unmappable = _modes(co, objects, keys.cyclic_modes, od, source)
        units = build_table(_ScalingTable, _table(co, "scaling", source), "canopen.scaling.", source)
        channels = _channels(co, objects, units.torque_constant_nm_per_a > 0, source)
        desc = cls(
            eds=keys.eds,
            vendor_id=keys.vendor_id,
            product_code=keys.product_code,
            default_acquisition=keys.default_acquisition,
            heartbeat_ms=keys.heartbeat_ms,
            heartbeat_timeout_ms=keys.heartbeat_timeout(source),
            block_transfer=keys.block_transfer,
            emcy_sample_index=keys.emcy_sample_index,
            position_unit_m=units.position_unit_m,
            velocity_unit_mps=units.velocity_unit_mps,
            objects=objects,
            modes=modes,
            channels=channels,
            filters=parse_filter_objects(sections.get("filters"), source),
            host_node_id=keys.host_node_id,
            abort_connection_option=keys.abort_connection_option,
            rated_torque_unit_nm=units.rated_torque_unit_nm,
            rated_torque_nm=units.rated_torque_nm,
            torque_constant_nm_per_a=units.torque_constant_nm_per_a,
            rated_current_a=units.rated_current_a,
            cyclic_modes=tuple(keys.cyclic_modes),
            explicit_modes=explicit,
            unmappable=unmappable,
            recorder=parse_recorder(sections, source, od),
            sync=parse_sync(co, source),
            loop=_loop(sections.get("loop"), od, source),
        )
        desc._check_default_acquisition(source)
        return desc

    def _check_default_acquisition(self, source: str) -> None:
        """The default acquisition needs the objects of its protocol, or a ``[canopen.recorder]``."""
        if self.default_acquisition == "buffered":
            self.require_buffered(source)
        if self.default_acquisition == "recorder" and self.recorder is None:
            raise ConfigError("canopen.default_acquisition", 'is "recorder" but there is no [canopen.recorder]', source)

    def address(self, role: str) -> ObjectAddress:
        """The object of ``role``; ConfigError when the drive does not have it."""
        try:
            return self.objects[role]
        except KeyError:
            raise ConfigError(
                f"canopen.objects.{role}",
                "is not an object of this drive (not in its EDS, not named by its driver description)",
            ) from None

    def has(self, role: str) -> bool:
        return role in self.objects

    @property
    def counted(self) -> bool:
        """The drive has the hilident counters: streamed runs match TPDOs to samples by their counter."""
        return all(r in self.objects for r in COUNTER_ROLES)

    def with_supported_modes(self, supported) -> CanopenDescription:
        """This description with its modes chosen from ``supported`` (mode names read from 0x6502).

        A description whose ``[canopen.modes]`` fixes the modes is returned unchanged.
        """
        if self.explicit_modes:
            return self
        return replace(self, modes=profile.standard_modes(self.objects, supported, self.cyclic_modes, self.unmappable))

    def require_buffered(self, source: str = "") -> None:
        """Raise ConfigError unless every object of the drive-buffered protocol is named."""
        missing = [r for r in BUFFERED_ROLES if r not in self.objects]
        if missing:
            raise ConfigError("canopen.objects", f"drive-buffered acquisition needs {', '.join(missing)}", source)

    def rated_torque(self, raw: float | None) -> float:
        """The rated torque in N·m: 0x6076 read as ``raw`` (None: absent), else ``rated_torque_nm``.

        Raises
        ------
        DataError
            Neither gives a positive torque.
        """
        if raw is not None and raw > 0:
            return float(raw) * self.rated_torque_unit_nm
        if self.rated_torque_nm > 0:
            return self.rated_torque_nm
        said = "is absent" if raw is None else f"reads {raw:g}"
        raise DataError(
            f"the rated torque 0x6076 {said} and [canopen.scaling] rated_torque_nm is not given: "
            "torque objects (per mille of it) cannot be scaled"
        )

    def rated_current(self, raw: float | None) -> float:
        """The rated current in A: 0x6075 (mA) read as ``raw`` (None: absent), else ``rated_current_a`` (0: none)."""
        if raw is not None and raw > 0:
            return float(raw) * 1e-3
        return self.rated_current_a

    def scale(self, role: str, rated_torque_nm: float, rated_current_a: float = 0.0) -> float:
        """SI value of one raw unit of the object of ``role`` (1.0 for unscaled objects).

        Torque objects are per mille of the rated torque; current objects per
        mille of the rated current, turned into torque by the torque constant.
        """
        kind = ROLE_SCALING.get(role)
        if kind == "position":
            return self.position_unit_m
        if kind == "velocity":
            return self.velocity_unit_mps
        if kind == "torque":
            if not rated_torque_nm > 0:
                raise DataError(f"rated torque {rated_torque_nm!r} N*m: torque objects cannot be scaled")
            return rated_torque_nm / 1000.0
        if kind == "current":
            if not (rated_current_a > 0 and self.torque_constant_nm_per_a > 0):
                raise DataError(
                    f"rated current {rated_current_a!r} A, torque constant "
                    f"{self.torque_constant_nm_per_a!r} N*m/A: current objects cannot be read as torque"
                )
            return rated_current_a / 1000.0 * self.torque_constant_nm_per_a
        return 1.0

    def mode_by_code(self, code: int) -> ModeSpec | None:
        """The mode spec whose mode-of-operation code is ``code``."""
        for m in self.modes.values():
            if m.code == code:
                return m
        return None


def default_supported_modes(od, objects: dict) -> tuple[str, ...] | None:
    """Mode names of 0x6502's EDS default, or None when the EDS gives none (the drive is asked at connect)."""
    addr = objects.get("supported_modes")
    if od is None or addr is None:
        return None
    var = od.get_variable(addr.index, addr.subindex)
    value = var.default if var is not None else None
    if not isinstance(value, int) or value <= 0:
        return None
    return profile.decode_supported_modes(value)


# --- the [canopen] tables ---------------------------------------------------------------------


def _within(lo: int, hi: int, what: str):
    """A schema ``check``: an integer in ``lo..hi``, the message saying ``what`` it is."""

    def check(value, key, source):
        if not lo <= value <= hi:
            raise ConfigError(key, f"must be {what}{lo}..{hi}, got {value}", source)

    return check


def _abort_option(value, key, source):
    if value not in ABORT_CONNECTION_OPTIONS:
        raise ConfigError(
            key,
            f"must be one of {sorted(ABORT_CONNECTION_OPTIONS)} "
            f"({', '.join(f'{k} {v}' for k, v in ABORT_CONNECTION_OPTIONS.items())}), "
            f"got {value}",
            source,
        )


def _cyclic_modes(value, key, source):
    if not value or any(m not in profile.CYCLIC_MODES for m in value):
        raise ConfigError(key, f"must be a list of {profile.CYCLIC_MODES}, got {value!r}", source)


def _unsigned32(value, key, source):
    if not 0 <= value <= 0xFFFFFFFF:
        raise ConfigError(key, f"must fit UNSIGNED32, got {value!r}", source)


@dataclass(frozen=True, kw_only=True)
class _CanopenTable:
    """The scalar keys of ``[canopen]``; its sub-tables are read by the functions below."""

    open_table: ClassVar[bool] = True  # objects, modes, channels, scaling, recorder, ...
    eds: str = spec(doc="EDS file name, relative to the driver folder")
    vendor_id: int | None = spec(None, check=_unsigned32, doc="0x1018:1 the device must report")
    product_code: int | None = spec(None, check=_unsigned32, doc="0x1018:2 the device must report")
    default_acquisition: str = spec("streamed", choices=ACQUISITIONS)
    heartbeat_ms: int = spec(100, check=_within(1, 65535, ""), doc="producer heartbeat time written to 0x1017")
    heartbeat_timeout_ms: int | None = spec(None, doc="a longer heartbeat gap stops the run; default 4 heartbeats")
    block_transfer: bool = spec(True)
    emcy_sample_index: bool = spec(False)
    host_node_id: int = spec(127, check=_within(1, 127, "a node id "))
    abort_connection_option: int = spec(2, check=_abort_option)
    cyclic_modes: list[str] = spec(["cst", "csv", "csp", "ip"], max_items=8, check=_cyclic_modes)

    def heartbeat_timeout(self, source: str) -> int:
        """``heartbeat_timeout_ms``, or four heartbeats; it must exceed one."""
        timeout = 4 * self.heartbeat_ms if self.heartbeat_timeout_ms is None else self.heartbeat_timeout_ms
        if timeout <= self.heartbeat_ms:
            raise ConfigError(
                "canopen.heartbeat_timeout_ms", f"must exceed heartbeat_ms = {self.heartbeat_ms}, got {timeout}", source
            )
        return timeout


@dataclass(frozen=True, kw_only=True)
class _ScalingTable:
    """``[canopen.scaling]``: SI values of the drive's units."""

    open_table: ClassVar[bool] = True
    position_unit_m: float = spec(gt=0, doc="one increment of 0x6064, 0x607A, 0x607D")
    velocity_unit_mps: float = spec(gt=0, doc="one unit of 0x606C, 0x60FF, 0x6080")
    rated_torque_unit_nm: float = spec(1e-3, gt=0, doc="unit of the rated torque 0x6076")
    rated_torque_nm: float = spec(0.0, ge=0, doc="when 0x6076 is absent or reads 0; 0: none given")
    torque_constant_nm_per_a: float = spec(0.0, ge=0, doc="for drives that report current only; 0: none given")
    rated_current_a: float = spec(0.0, ge=0, doc="when 0x6075 is absent or reads 0; 0: none given")


def _objects(co: dict, od, source: str) -> dict[str, ObjectAddress]:
    """The standard objects the EDS has, and the vendor objects ``[canopen.objects]`` names."""

    def present(addr: ObjectAddress) -> bool:
        return od is not None and od.get_variable(addr.index, addr.subindex) is not None

    objects = profile.standard_objects(present)
    table = co.get("objects", {})
    if not isinstance(table, dict):
        raise ConfigError("canopen.objects", 'must be a table of role = "0xIIII[:sub]"', source)
    for role, text in table.items():
        objects[role] = parse_address(text, f"canopen.objects.{role}", source)
        if od is not None and not present(objects[role]):
            raise ConfigError(f"canopen.objects.{role}", f"object {objects[role]} is not in the EDS", source)
    missing = [r for r in REQUIRED_ROLES if r not in objects]
    if missing:
        where = "the EDS has no" if od is not None else "names no"
        raise ConfigError("canopen.objects", f"{where} {', '.join(missing)}: not a CiA 402 drive", source)
    return objects


def _modes(co: dict, objects: dict, preference: list[str], od, source: str):
    """``[canopen.modes]`` (explicit), else the standard modes of the drive; and the roles no PDO can map."""
    modes = {}
    for name, spec_ in _table(co, "modes", source).items():
        modes[name] = _mode(name, spec_, objects, source)
    unmappable = tuple(role for role, addr in objects.items() if not _pdo_mappable(od, addr))
    if modes:
        return modes, True, unmappable
    return (
        profile.standard_modes(objects, default_supported_modes(od, objects), preference, unmappable),
        False,
        unmappable,
    )


def _mode(name: str, spec_, objects: dict, source: str) -> ModeSpec:
    """One ``[canopen.modes]`` entry: ``{ code = <int>, setpoint = "<role>" }``."""
    if not isinstance(spec_, dict) or not _is_int(spec_.get("code")) or not isinstance(spec_.get("setpoint"), str):
        raise ConfigError(f"canopen.modes.{name}", 'must be { code = <int>, setpoint = "<role>" }', source)
    if spec_["setpoint"] not in objects:
        raise ConfigError(
            f"canopen.modes.{name}.setpoint", f"role {spec_['setpoint']!r} is not an object of this drive", source
        )
    if not -128 <= spec_["code"] <= 127:
        raise ConfigError(f"canopen.modes.{name}.code", f"must fit INTEGER8, got {spec_['code']}", source)
    return ModeSpec(name, spec_["code"], spec_["setpoint"], str(spec_.get("hold", "")))


def _channels(co: dict, objects: dict, current_as_torque: bool, source: str) -> dict[str, str | None]:
    """``[canopen.channels]``: channel -> role; without the table the standard channels of the objects."""
    channels: dict[str, str | None] = {}
    if "channels" not in co:
        channels = profile.standard_channels(objects, current_as_torque)
    for name, role in _table(co, "channels", source).items():
        if not isinstance(role, str) or role not in objects:
            raise ConfigError(f"canopen.channels.{name}", f"role {role!r} is not an object of this drive", source)
        channels[name] = role
    if not channels:
        raise ConfigError("canopen.channels", "needs at least one channel", source)
    return channels


def _table(parent: dict, key: str, source: str) -> dict:
    """``parent[key]`` (a table, empty when absent); ConfigError naming ``canopen.<key>`` otherwise."""
    value = parent.get(key, {})
    if not isinstance(value, dict):
        raise ConfigError(f"canopen.{key}", f"must be a table, got {value!r}"[:200], source)
    return value


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


# --- values -----------------------------------------------------------------------------------


def type_bits(datatype: int) -> int:
    """Width in bits of a numeric CiA 301 data type."""
    try:
        return np.dtype(_NUMPY[datatype]).itemsize * 8
    except KeyError:
        raise DataError(f"data type 0x{datatype:02X} is not a numeric CANopen type") from None


def numpy_type(datatype: int) -> np.dtype:
    """Little-endian numpy type of a numeric CiA 301 data type."""
    try:
        return np.dtype(_NUMPY[datatype])
    except KeyError:
        raise DataError(f"data type 0x{datatype:02X} is not a numeric CANopen type") from None


def record_dtype(datatypes) -> np.dtype:
    """Packed structure of several objects one after another (a PDO or a capture record)."""
    return np.dtype([(f"f{i}", numpy_type(t)) for i, t in enumerate(datatypes)])


def encode_si(values, datatype: int, scale: float) -> np.ndarray:
    """SI values as raw object values: ``round(value / scale)`` clipped to the type, or REAL32.

    NaN goes to 0 for integer types (REAL32 keeps it).
    """
    t = numpy_type(datatype)
    x = np.asarray(values, dtype=float) / scale
    if t.kind == "f":
        return x.astype(t)
    info = np.iinfo(t)
    x = np.where(np.isfinite(x), x, 0.0)
    return np.clip(np.rint(x), info.min, info.max).astype(t)


def decode_raw(raw, scale: float) -> np.ndarray:
    """Raw object values to SI (float64)."""
    return np.asarray(raw, dtype=float) * scale


def consumer_entry(node_id: int, time_ms: int) -> int:
    """A CiA 301 heartbeat consumer entry (0x1016:n): ``node_id << 16 | time_ms`` (0: not used)."""
    if not (0 <= node_id <= 127 and 0 <= time_ms <= 0xFFFF):
        raise DataError(f"heartbeat consumer entry: node {node_id}, {time_ms} ms out of range")
    return (node_id << 16) | time_ms


def parse_consumer_entry(value: int) -> tuple[int, int]:
    """Inverse of :func:`consumer_entry`: (producer node id, consumer time in ms)."""
    return (int(value) >> 16) & 0x7F, int(value) & 0xFFFF


def mapping_entry(address: ObjectAddress, bits: int) -> int:
    """A CiA 301 PDO (and capture) mapping entry: ``index << 16 | subindex << 8 | bits``."""
    if not 0 < bits <= 64:
        raise DataError(f"mapping of {address}: {bits} bits")
    return (address.index << 16) | (address.subindex << 8) | bits


def parse_mapping_entry(value: int) -> tuple[ObjectAddress, int]:
    """Inverse of :func:`mapping_entry`."""
    return ObjectAddress((value >> 16) & 0xFFFF, (value >> 8) & 0xFF), value & 0xFF


def pack_frames(
    items: list[tuple[str, int]],
    header_bits: int = 16,
    frame_bits: int = 64,
    max_frames: int = 4,
    max_entries: int = 64,
) -> list[list[str]]:
    """Put mapped objects into PDO frames, each headed by a ``header_bits`` counter (0: none).

    First fit in the given order: an object goes into the first frame with room
    (bits, and fewer than ``max_entries`` objects: the drive's mapping capacity).

    Parameters
    ----------
    items : list of (name, bits)
    header_bits, frame_bits, max_frames, max_entries : int

    Returns
    -------
    list of lists of names, one list per frame

    Raises
    ------
    DataError
        They do not fit ``max_frames`` frames.

    Examples
    --------
    >>> pack_frames([("a", 32), ("b", 16), ("c", 32), ("d", 16), ("e", 32)])
    [['a', 'b'], ['c', 'd'], ['e']]
    """
    frames: list[list[str]] = []
    used: list[int] = []
    for name, bits in items:
        if header_bits + bits > frame_bits:
            raise DataError(f"{name} ({bits} bits) does not fit a PDO beside the {header_bits}-bit counter")
        if max_entries < 1:
            raise DataError(f"{name}: the drive's PDOs map no object beside the counter")
        for i, u in enumerate(used):
            if u + bits <= frame_bits and len(frames[i]) < max_entries:
                frames[i].append(name)
                used[i] += bits
                break
        else:
            frames.append([name])
            used.append(header_bits + bits)
    if len(frames) > max_frames:
        raise DataError(f"{len(items)} channels need {len(frames)} PDOs; the drive has {max_frames}")
    return frames
