"""Vendor EDS/DCF files as they are: a tolerant loader and a summary of what the drive offers.

Real files break strict parsers: duplicate keys in a section, lower-case keys
and sections, CRLF line ends, latin-1 bytes, ``Lines=0`` in ``[Comments]``,
``CompactSubObj`` arrays, odd ``$NODEID`` expressions, DCF ``ParameterValue``
entries, and data types or access rights that deviate from CiA 402.
:func:`load_eds` reads the text into a canonical form that
:func:`canopen.import_od` (python-canopen) accepts and reports every quirk it met
as one warning naming the file, the section or line, and what was done. Data
types and access rights are kept as the file declares them (that is what the
device does); a deviation from the profile is reported, not "fixed".

:func:`inspect_eds` then reads what a host needs to know from the object
dictionary alone: identity, which standard roles exist, the supported and
cyclic modes, PDO limits, the period object, torque or current objects, the
factor group, the device-side net, store parameters and vendor objects that
look like filters, recorders or generators.

Only :func:`load_eds` touches a file; everything after it is pure.

Examples
--------
>>> od, warnings = load_eds_text("[DeviceInfo]\\nVendorName=ACME\\n[6502]\\nParameterName=Supported drive modes\\n"
...                              "ObjectType=0x7\\nDataType=0x0007\\nAccessType=ro\\nDefaultValue=0x380\\n", "x.eds")
>>> inspect_eds(od).supported_modes
('csp', 'csv', 'cst')
"""

from __future__ import annotations

import io
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

from hilident.errors import ConfigError
from hilident.protocol import canopen_profile as profile

__all__ = [
    "load_eds",
    "load_eds_text",
    "inspect_eds",
    "EdsSummary",
    "ObjectInfo",
    "PeriodInfo",
    "ROLES",
    "MODE_BITS",
    "CYCLIC_MODES",
    "MODE_CODES",
    "MODE_SETPOINTS",
    "object_info",
    "type_name",
    "readable",
    "writable",
]

# CiA 301 data types (the subset a drive's profile uses)
BOOLEAN, INTEGER8, INTEGER16, INTEGER32 = 0x01, 0x02, 0x03, 0x04
UNSIGNED8, UNSIGNED16, UNSIGNED32, REAL32 = 0x05, 0x06, 0x07, 0x08
VISIBLE_STRING, OCTET_STRING, DOMAIN = 0x09, 0x0A, 0x0F
_TYPE_NAMES = {
    0x01: "BOOLEAN",
    0x02: "INTEGER8",
    0x03: "INTEGER16",
    0x04: "INTEGER32",
    0x05: "UNSIGNED8",
    0x06: "UNSIGNED16",
    0x07: "UNSIGNED32",
    0x08: "REAL32",
    0x09: "VISIBLE_STRING",
    0x0A: "OCTET_STRING",
    0x0B: "UNICODE_STRING",
    0x0C: "TIME_OF_DAY",
    0x0D: "TIME_DIFFERENCE",
    0x0F: "DOMAIN",
    0x10: "INTEGER24",
    0x11: "REAL64",
    0x12: "INTEGER40",
    0x13: "INTEGER48",
    0x14: "INTEGER56",
    0x15: "INTEGER64",
    0x16: "UNSIGNED24",
    0x18: "UNSIGNED40",
    0x19: "UNSIGNED48",
    0x1A: "UNSIGNED56",
    0x1B: "UNSIGNED64",
}

#: Standard roles (canopen_schema): role -> (index, sub-index, CiA data type, how the host uses it: "r"/"w"/"rw").
ROLES: dict[str, tuple[int, int, int, str]] = {
    "device_name": (0x1008, 0, VISIBLE_STRING, "r"),
    "hardware_version": (0x1009, 0, VISIBLE_STRING, "r"),
    "software_version": (0x100A, 0, VISIBLE_STRING, "r"),
    "vendor_id": (0x1018, 1, UNSIGNED32, "r"),
    "product_code": (0x1018, 2, UNSIGNED32, "r"),
    "error_register": (0x1001, 0, UNSIGNED8, "r"),
    "error_history": (0x1003, 0, UNSIGNED8, "r"),
    "cycle_period": (0x1006, 0, UNSIGNED32, "rw"),
    "sync_overflow": (0x1019, 0, UNSIGNED8, "rw"),
    "heartbeat_time": (0x1017, 0, UNSIGNED16, "rw"),
    "store_parameters": (0x1010, 1, UNSIGNED32, "w"),
    "abort_connection": (0x6007, 0, INTEGER16, "rw"),
    "error_code": (0x603F, 0, UNSIGNED16, "r"),
    "controlword": (0x6040, 0, UNSIGNED16, "w"),
    "statusword": (0x6041, 0, UNSIGNED16, "r"),
    "modes_of_operation": (0x6060, 0, INTEGER8, "w"),
    "modes_display": (0x6061, 0, INTEGER8, "r"),
    "supported_modes": (0x6502, 0, UNSIGNED32, "r"),
    "position_actual": (0x6064, 0, INTEGER32, "r"),
    "velocity_actual": (0x606C, 0, INTEGER32, "r"),
    "target_torque": (0x6071, 0, INTEGER16, "w"),
    "max_torque": (0x6072, 0, UNSIGNED16, "rw"),
    "rated_current": (0x6075, 0, UNSIGNED32, "r"),
    "rated_torque": (0x6076, 0, UNSIGNED32, "r"),
    "torque_demand": (0x6074, 0, INTEGER16, "r"),
    "torque_actual": (0x6077, 0, INTEGER16, "r"),
    "current_actual": (0x6078, 0, INTEGER16, "r"),
    "target_position": (0x607A, 0, INTEGER32, "w"),
    "position_limit_min": (0x607D, 1, INTEGER32, "rw"),
    "position_limit_max": (0x607D, 2, INTEGER32, "rw"),
    "max_velocity": (0x6080, 0, UNSIGNED32, "rw"),
    "velocity_offset": (0x60B1, 0, INTEGER32, "w"),
    "torque_offset": (0x60B2, 0, INTEGER16, "w"),
    "interpolation_data": (0x60C1, 1, INTEGER32, "w"),
    "interpolation_period": (0x60C2, 1, UNSIGNED8, "rw"),
    "following_error_window": (0x6065, 0, UNSIGNED32, "rw"),
    "ip_buffer_max": (0x60C4, 1, UNSIGNED32, "r"),
    "ip_buffer_size": (0x60C4, 2, UNSIGNED32, "rw"),
    "ip_buffer_organization": (0x60C4, 3, UNSIGNED8, "rw"),
    "ip_buffer_clear": (0x60C4, 6, UNSIGNED8, "w"),
    "target_velocity": (0x60FF, 0, INTEGER32, "w"),
    "encoder_increments": (0x608F, 1, UNSIGNED32, "r"),
    "motor_revolutions": (0x608F, 2, UNSIGNED32, "r"),
    "gear_motor_revs": (0x6091, 1, UNSIGNED32, "r"),
    "gear_shaft_revs": (0x6091, 2, UNSIGNED32, "r"),
    "feed": (0x6092, 1, UNSIGNED32, "r"),
    "feed_shaft_revs": (0x6092, 2, UNSIGNED32, "r"),
}
#: CiA 402 objects whose declared data type or access is checked against the profile at load time.
_PROFILE_CHECKED = (
    "modes_of_operation",
    "modes_display",
    "controlword",
    "statusword",
    "target_torque",
    "max_torque",
    "rated_torque",
    "target_position",
    "target_velocity",
    "position_actual",
    "velocity_actual",
    "torque_actual",
    "torque_offset",
)
_PROFILE_EXTRA = {0x6073: ("max_current", UNSIGNED16)}  # checked, but not a role the host uses

#: 0x6502 bits (CiA 402) -> mode name (the profile's table, by bit).
MODE_BITS = {bit: name for name, bit in profile.MODE_BITS.items()}
#: Mode name -> mode of operation code written to 0x6060.
MODE_CODES = profile.MODE_CODES
#: Cyclic modes a host can stream set-points in, in hilident's preference order (torque excitation first).
CYCLIC_MODES = profile.CYCLIC_MODES
#: Cyclic mode -> standard role of its set-point object.
MODE_SETPOINTS = profile.SETPOINT_OF_MODE

_FILTER_WORDS = ("notch", "filt", "biquad", "anti-resonance", "antiresonance", "resonance")
_RECORDER_WORDS = ("recorder", "recording", "trace", "scope", "capture", "logging")
_GENERATOR_WORDS = ("generator", "excitation", "prbs", "sweep", "function gen")
#: Names of manufacturer objects that carry a torque (or current) where the standard objects are missing, and the
#: standard role each stands in for: what the drive commands, or what it measures.
_TORQUE_NAMES = (
    ("control effort", "torque_demand"),
    ("torque demand", "torque_demand"),
    ("current demand", "torque_demand"),
    ("torque actual", "torque_actual"),
    ("actual torque", "torque_actual"),
    ("current actual", "torque_actual"),
    ("actual current", "torque_actual"),
)
#: Words that make such a name a setting, not a signal ("Actual Current Limit").
_NOT_A_TORQUE = ("limit", "threshold", "max", "maximum", "offset", "protection", "setting", "parameter", "mode")


# --- reading ---------------------------------------------------------------------------------------------------


def load_eds(path, node_id: int | None = None):
    """Read a vendor EDS or DCF file as it is.

    Parameters
    ----------
    path : str or Path
        The ``.eds`` or ``.dcf`` file.
    node_id : int, optional
        Node id (1..127) that ``$NODEID`` stands for; default: a DCF's
        ``[DeviceComissioning] NodeID``, else unresolved.

    Returns
    -------
    od : canopen.ObjectDictionary
    warnings : list of str
        One per quirk met, each naming the file, the section or line and what was done.

    Raises
    ------
    ConfigError
        The file cannot be read or holds no object dictionary; the message names the file.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise ConfigError("canopen.eds", f"cannot read the EDS: {reason}", str(path)) from None
    return load_eds_bytes(data, path.name, node_id, source=str(path))


def load_eds_bytes(data: bytes, name: str, node_id: int | None = None, source: str | None = None):
    """:func:`load_eds` on the file's bytes; ``name`` is the file name (its suffix says EDS or DCF)."""
    source = source or name
    warnings: list[str] = []
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        text = data.decode("latin-1")
        warnings.append(f"{source}: line {line}: bytes that are not UTF-8; the file is read as latin-1")
    od, more = load_eds_text(text, name, node_id, source)
    return od, warnings + more


def load_eds_text(text: str, name: str, node_id: int | None = None, source: str | None = None):
    """:func:`load_eds` on the file's text. See there."""
    source = source or name
    if node_id is not None and not (isinstance(node_id, int) and 1 <= node_id <= 127):
        raise ConfigError("device.canopen.node_id", f"must be a node id 1..127, got {node_id!r}", source)
    if "\x00" in text:
        raise ConfigError("canopen.eds", "holds NUL bytes: not an EDS/DCF text file", source)
    warnings: list[str] = []
    sections = _parse_sections(text, source, warnings)
    if not any(_HEX_SECTION.match(s) for s in sections):
        raise ConfigError("canopen.eds", "holds no object sections ([1000], [6040], ...): not an EDS/DCF", source)
    _repair(sections, source, warnings)
    if node_id is None and "DeviceComissioning" in sections:
        stored = _int(sections["DeviceComissioning"].get("NodeID", ("", 0))[0])
        node_id = stored if stored is not None and 1 <= stored <= 127 else None
    od = _import(sections, name, node_id, source, warnings)
    _expand_compact(od, sections)
    _check_values(od, sections, source, warnings)
    _check_profile(od, source, warnings)
    return od, warnings


_SECTION = re.compile(r"^\[([^\]]*)\]\s*(?:;.*)?$")
_HEX_SECTION = re.compile(r"^([0-9A-Fa-f]{4})$")
_SUB_SECTION = re.compile(r"^([0-9A-Fa-f]{4})sub([0-9A-Fa-f]{1,2})$", re.IGNORECASE)
_NAME_SECTION = re.compile(r"^([0-9A-Fa-f]{4})name$", re.IGNORECASE)
_KNOWN_SECTIONS = (
    "FileInfo",
    "DeviceInfo",
    "DummyUsage",
    "Comments",
    "MandatoryObjects",
    "OptionalObjects",
    "ManufacturerObjects",
    "DeviceComissioning",
    "DynamicChannels",
    "Tools",
    "SupportedModules",
)
_KNOWN_KEYS = (
    (
        "ParameterName",
        "ObjectType",
        "DataType",
        "AccessType",
        "DefaultValue",
        "ParameterValue",
        "PDOMapping",
        "LowLimit",
        "HighLimit",
        "SubNumber",
        "CompactSubObj",
        "StorageLocation",
        "Factor",
        "Description",
        "Unit",
        "ObjFlags",
        "Denotation",
        "UploadFile",
        "DownloadFile",
        "NrOfEntries",
        "SupportedObjects",
        "Lines",
        "VendorName",
        "VendorNumber",
        "ProductName",
        "ProductNumber",
        "RevisionNumber",
        "OrderCode",
        "SimpleBootUpMaster",
        "SimpleBootUpSlave",
        "Granularity",
        "DynamicChannelsSupported",
        "GroupMessaging",
        "NrOfRXPDO",
        "NrOfTXPDO",
        "LSS_Supported",
        "CompactPDO",
        "FileName",
        "FileVersion",
        "FileRevision",
        "EDSVersion",
        "CreationTime",
        "CreationDate",
        "CreatedBy",
        "ModificationTime",
        "ModificationDate",
        "ModifiedBy",
        "NodeID",
        "NodeName",
        "Baudrate",
        "NetNumber",
        "NetworkName",
        "CANopenManager",
        "LSS_SerialNumber",
    )
    + tuple(f"BaudRate_{r}" for r in (10, 20, 50, 125, 250, 500, 800, 1000))
    + tuple(f"Dummy{i:04d}" for i in range(1, 8))
)
_CANONICAL_KEYS = {k.lower(): k for k in _KNOWN_KEYS}
_CANONICAL_SECTIONS = {s.lower(): s for s in _KNOWN_SECTIONS}


def _canonical_section(name: str) -> str:
    m = _SUB_SECTION.match(name)
    if m:
        return f"{m.group(1).upper()}sub{int(m.group(2), 16):X}"
    if _HEX_SECTION.match(name):
        return name.upper()
    m = _NAME_SECTION.match(name)
    if m:
        return f"{m.group(1).upper()}Name"
    return _CANONICAL_SECTIONS.get(name.lower(), name)


def _canonical_key(key: str) -> str:
    if re.fullmatch(r"line\d+", key, re.IGNORECASE):
        return "Line" + key[4:]
    return _CANONICAL_KEYS.get(key.lower(), key)


class _Tally:
    """Counts one kind of repeated quirk and reports it once, naming the first place met."""

    def __init__(self, what: str):
        self.what, self.count, self.first = what, 0, ""

    def add(self, where: str) -> None:
        self.count += 1
        self.first = self.first or where

    def report(self, source: str, warnings: list[str]) -> None:
        if self.count:
            more = f" ({self.count} in all)" if self.count > 1 else ""
            warnings.append(f"{source}: {self.first}: {self.what}{more}")


def _parse_sections(text: str, source: str, warnings: list[str]) -> dict[str, dict[str, tuple[str, int]]]:
    """Sections -> {key: (value, line number)}, canonical names, first of duplicates kept."""
    reader = _SectionReader(source, warnings)
    for no, raw in enumerate(text.split("\n"), 1):
        reader.line(no, raw)
    reader.crlf.report(source, warnings)
    reader.case.report(source, warnings)
    return reader.sections


class _SectionReader:
    """Reads an EDS line by line into sections, warning of what it skips or reads leniently."""

    def __init__(self, source: str, warnings: list[str]):
        self.source, self.warnings = source, warnings
        self.crlf = _Tally("CRLF line ends; read as plain line ends")
        self.case = _Tally("section or key names not in the EDS spelling (e.g. lower case); read case-insensitively")
        self.sections: dict[str, dict[str, tuple[str, int]]] = {}
        self.current: dict[str, tuple[str, int]] | None = None
        self.name = ""

    def line(self, no: int, raw: str) -> None:
        if raw.endswith("\r"):
            self.crlf.add(f"line {no}")
        line = raw.replace("\r", "").strip()
        if not line or line[0] in ";#":
            return
        m = _SECTION.match(line)
        if m:
            self.header(no, m.group(1).strip())
        elif self.current is None:
            if not self.name:
                self.warnings.append(f"{self.source}: line {no}: text before the first section; skipped")
                self.name = "?"
        else:
            self.entry(no, line, self.current)

    def header(self, no: int, given: str) -> None:
        """A ``[section]`` line: the sections that follow go into it, unless it is unreadable or repeated."""
        name = self.name = _canonical_section(given)
        if (
            name != given
            and name.lower() == given.lower()
            and not _SUB_SECTION.match(given)
            and not _HEX_SECTION.match(given)
        ):
            self.case.add(f"line {no} [{given}]")
        self.current = None
        if not name or name.upper() == "DEFAULT" or any(c in name for c in "[]\n"):
            self.warnings.append(f"{self.source}: line {no}: section [{given}] cannot be read; skipped with its keys")
        elif name in self.sections:
            self.warnings.append(
                f"{self.source}: line {no}: section [{given}] appears again; the first one is kept, this one skipped"
            )
        else:
            self.current = self.sections[name] = {}

    def entry(self, no: int, line: str, section: dict[str, tuple[str, int]]) -> None:
        """A ``key=value`` line of the current section ``section`` (comments after `` ;`` dropped)."""
        key, eq, value = line.partition("=")
        key = key.strip()
        value = re.split(r"\s;", value, maxsplit=1)[0].strip()
        if not eq or not key or any(c in key for c in ":[]") or key.upper() == "DEFAULT":
            self.warnings.append(
                f"{self.source}: line {no} [{self.name}]: {line[:60]!r} is not a key=value line; skipped"
            )
            return
        canon = _canonical_key(key)
        if canon != key:
            self.case.add(f"line {no} [{self.name}] {key!r}")
        if canon in section:
            self.warnings.append(
                f"{self.source}: line {no} [{self.name}]: duplicate key {key!r}; the first (line "
                f"{section[canon][1]}) is kept"
            )
            return
        section[canon] = (value, no)


def _int(text) -> int | None:
    """An EDS integer (``0x1F``, ``31``, ``-3``, ``007``), or None."""
    text = str(text).strip()
    try:
        return int(text, 0)
    except ValueError:
        pass
    if re.fullmatch(r"[+-]?0+\d*", text):
        return int(text, 10)
    return None


_NODEID = re.compile(r"\$nodeid", re.IGNORECASE)


def _nodeid_expression(value: str) -> str | None:
    """A ``$NODEID`` expression in canonical form ``$NODEID+0xNNN``, or None when it is not a sum."""
    terms = [t for t in value.replace(" ", "").split("+")]
    if sum(1 for t in terms if _NODEID.fullmatch(t)) != 1:
        return None
    rest = [_int(t) for t in terms if not _NODEID.fullmatch(t)]
    numbers = [r for r in rest if r is not None]
    if len(numbers) != len(rest):
        return None
    return f"$NODEID+0x{sum(numbers):X}"


def _repair(sections: dict, source: str, warnings: list[str]) -> None:
    """Make what python-canopen reads strictly (keys it requires, integers it parses) readable, warning once each."""
    _repair_info(sections, source, warnings)
    zeros = _Tally("decimal numbers with leading zeros; read as decimal")
    nodeid = _Tally("$NODEID expression not in the form $NODEID+0xNNN; rewritten as one")
    for name in list(sections):
        if name in sections and _keep_section(name, sections, source, warnings):  # not gone with its object
            sec = sections[name]
            _repair_custom_type(name, sec, sections, source, warnings)
            _repair_values(name, sec, zeros, nodeid, source, warnings)
    zeros.report(source, warnings)
    nodeid.report(source, warnings)
    _repair_heartbeat_consumer_limits(sections, source, warnings)
    _repair_names(sections, source, warnings)
    _drop_orphan_subs(sections, source, warnings)


#: A consumer heartbeat entry of 0x1016 (CiA 301): the producer's node id in bits 16-23, its time (ms) in 0-15.
_CONSUMER_ENTRY = re.compile(r"1016sub0*([1-9a-f][0-9a-f]*)", re.IGNORECASE)
_CONSUMER_NODE_BITS = 0x7F << 16


def _repair_heartbeat_consumer_limits(sections: dict, source: str, warnings: list[str]) -> None:
    """A 0x1016 entry whose HighLimit leaves no room for the node id: the limit read as the time's.

    Some vendor files give the heartbeat time's range (``HighLimit=65535``) as
    the whole entry's; taken as written, no producer could ever be watched. A
    drive checks the time against it; so does the twin, after this repair.
    """
    tally = _Tally(
        "0x1016 consumer heartbeat HighLimit leaves no room for the node id (bits 16-23, CiA 301); "
        "read as the limit of its time (bits 0-15)"
    )
    for name, sec in sections.items():
        high = _int(sec["HighLimit"][0]) if _CONSUMER_ENTRY.fullmatch(name) and "HighLimit" in sec else None
        if high is not None and 0 <= high <= 0xFFFF:
            sec["HighLimit"] = (hex(_CONSUMER_NODE_BITS | high), sec["HighLimit"][1])
            tally.add(f"[{name}] (line {_first_line(sec)})")
    tally.report(source, warnings)


def _keep_section(name: str, sections: dict, source: str, warnings: list[str]) -> bool:
    """Whether ``name`` is a usable object or sub-index section (repaired); unusable ones are deleted."""
    sec = sections[name]
    m_obj, m_sub = _HEX_SECTION.match(name), _SUB_SECTION.match(name)
    if m_sub and m_sub.group(1) not in sections:
        warnings.append(
            f"{source}: [{name}] (line {_first_line(sec)}): sub-index of an object the file does not declare; skipped"
        )
        del sections[name]
        return False
    if _NAME_SECTION.match(name):
        return False  # after the objects: see _repair_names
    if not (m_obj or m_sub or name in _KNOWN_SECTIONS) and re.match(r"[0-9A-Fa-f]{4}", name):
        warnings.append(
            f"{source}: [{name}] (line {_first_line(sec)}): neither an object, a sub-index nor a names section; skipped"
        )
        del sections[name]
        return False
    if not (m_obj or m_sub):
        return False
    has_subs = bool(m_obj) and any(s.startswith(name + "sub") for s in sections)
    if _repair_object(name, sec, source, warnings, bool(m_sub), has_subs):
        return True
    del sections[name]
    if m_obj:  # its sub-index sections go with it
        for sub in [s for s in sections if s.startswith(name + "sub")]:
            del sections[sub]
    return False


#: CiA 301 types whose value is text or bytes, never a number: VISIBLE_STRING, OCTET_STRING, UNICODE_STRING, DOMAIN
_UNNUMBERED_TYPES = (0x09, 0x0A, 0x0B, 0x0F)
_HEX_BYTES = re.compile(r"(?:0x)?((?:[0-9A-Fa-f]{2})*)")


def _repair_values(name: str, sec: dict, zeros: _Tally, nodeid: _Tally, source: str, warnings: list[str]) -> None:
    """Values with a ``$NODEID`` expression in canonical form, decimals with leading zeros read as decimal.

    The value of an octet string or a DOMAIN is hex digits, two a byte (``0x``
    and spaces dropped); a string's is text: neither is read as a number.
    """
    dtype = _int(sec.get("DataType", ("", 0))[0])
    if dtype in _UNNUMBERED_TYPES:
        for key in ("DefaultValue", "ParameterValue"):
            m = _HEX_BYTES.fullmatch(sec[key][0].replace(" ", "")) if key in sec and dtype in (0x0A, 0x0F) else None
            if m is not None:
                sec[key] = (m.group(1), sec[key][1])
        return
    for key in ("DefaultValue", "ParameterValue", "LowLimit", "HighLimit"):
        if key not in sec:
            continue
        value, no = sec[key]
        if "$" in value:
            canon = _nodeid_expression(value)
            if canon is None:
                warnings.append(
                    f"{source}: line {no} [{name}]: {key}={value!r} is not a $NODEID+offset expression; dropped"
                )
                del sec[key]
            elif canon != value:
                nodeid.add(f"line {no} [{name}] {value!r}")
                sec[key] = (canon, no)
        elif re.fullmatch(r"[+-]?0+\d+", value):
            zeros.add(f"line {no} [{name}] {key}={value}")
            sec[key] = (str(int(value, 10)), no)


def _drop_orphan_subs(sections: dict, source: str, warnings: list[str]) -> None:
    """Sub-index sections of an object that is no array or record are skipped."""
    for name in [n for n in sections if _SUB_SECTION.match(n)]:
        parent = sections.get(name[:4])
        if parent is None or _int(parent.get("ObjectType", ("7", 0))[0]) not in (0x8, 0x9):
            warnings.append(
                f"{source}: [{name}] (line {_first_line(sections[name])}): sub-index of an object that is "
                f"not an array or record; skipped"
            )
            del sections[name]


def _repair_custom_type(name: str, sec: dict, sections: dict, source: str, warnings: list[str]) -> None:
    """A data type beyond 0x1B names a type-definition section whose sub-index 1 holds the base type."""
    dtype = _int(sec.get("DataType", ("", 0))[0])
    if dtype is None or dtype <= 0x1B:
        return
    definition = sections.get(f"{dtype:X}sub1")
    if definition is not None and _int(definition.get("DefaultValue", ("", 0))[0]) is None:
        warnings.append(
            f"{source}: [{name}]: DataType=0x{dtype:04X} has no readable definition in [{dtype:X}sub1]; read as DOMAIN"
        )
        sec["DataType"] = ("0x000F", sec["DataType"][1])


def _repair_names(sections: dict, source: str, warnings: list[str]) -> None:
    """[IIIIName] sections: names of a compact array's entries, NrOfEntries of them, numbered 1..N."""
    for name in [n for n in sections if _NAME_SECTION.match(n)]:
        sec, index = sections[name], name[:4]
        count = _int(sec.get("NrOfEntries", ("", 0))[0])
        if (
            index not in sections
            or "CompactSubObj" not in sections[index]
            or count is None
            or _int(sections[index].get("ObjectType", ("7", 0))[0]) != 0x8
        ):
            warnings.append(
                f"{source}: [{name}] (line {_first_line(sec)}): names of a compact array that the file "
                f"does not declare as one (or without NrOfEntries); skipped"
            )
            del sections[name]
            continue
        present = 0
        while str(present + 1) in sec and present < 255:
            present += 1
        if present != count:
            warnings.append(
                f"{source}: [{name}] (line {_first_line(sec)}): NrOfEntries={count} but {present} names "
                f"follow in order; read {present}"
            )
        sec["NrOfEntries"] = (str(present), 0)


def _first_line(sec: dict) -> int:
    return min((no for _, no in sec.values()), default=0)


_ACCESS = ("ro", "wo", "rw", "rwr", "rww", "const")


def _repair_object(name: str, sec: dict, source: str, warnings: list[str], is_sub: bool, has_subs: bool) -> bool:
    """Fill or fix one object section's keys; False when it cannot be used at all."""
    where = f"[{name}] (line {_first_line(sec)})"
    if "ParameterName" not in sec or not sec["ParameterName"][0]:
        warnings.append(f"{source}: {where}: no ParameterName; named 'Object {name}'")
        sec["ParameterName"] = (f"Object {name}", 0)
    otype = _repair_object_type(sec, where, has_subs, source, warnings)
    if otype in (0x8, 0x9) and not is_sub and not _compact(sec, otype, where, source, warnings):
        return True
    if otype in (0x0, 0x5, 0x6) and not is_sub:  # NULL, DEFTYPE, DEFSTRUCT: type definitions, not objects
        return True
    dtype = _int(sec.get("DataType", ("", 0))[0])
    if dtype is None or not 0 < dtype <= 0xFFFF:
        warnings.append(
            f"{source}: {where}: DataType={sec.get('DataType', ('(missing)', 0))[0]!r} unreadable; object skipped"
        )
        return False
    sec["DataType"] = (f"0x{dtype:04X}", sec.get("DataType", ("", 0))[1])
    _repair_access(sec, where, source, warnings)
    return True


def _repair_object_type(sec: dict, where: str, has_subs: bool, source: str, warnings: list[str]) -> int:
    """The object type, in canonical form (a section with sub-indices and no type of its own: a record)."""
    if "ObjectType" not in sec and has_subs and "DataType" not in sec:
        warnings.append(f"{source}: {where}: no ObjectType, but sub-index sections follow; read as a record (0x9)")
        sec["ObjectType"] = ("0x9", 0)
    otype = _int(sec.get("ObjectType", ("0x7", 0))[0])
    if otype is None or otype not in (0x0, 0x2, 0x5, 0x6, 0x7, 0x8, 0x9):
        warnings.append(f"{source}: {where}: ObjectType={sec['ObjectType'][0]!r} unknown; read as a variable (0x7)")
        sec["ObjectType"], otype = ("0x7", 0), 0x7
    sec["ObjectType"] = (f"0x{otype:X}", sec.get("ObjectType", ("", 0))[1])
    return otype


def _compact(sec: dict, otype: int, where: str, source: str, warnings: list[str]) -> bool:
    """Whether an array or record is compact (``CompactSubObj``: arrays only; 0 means not compact)."""
    compact = _int(sec.get("CompactSubObj", ("0", 0))[0])
    if "CompactSubObj" in sec and not compact:
        del sec["CompactSubObj"]  # 0 means "not compact"; python-canopen only asks whether the key is there
    elif compact and otype == 0x9:
        warnings.append(f"{source}: {where}: CompactSubObj on a record (only arrays may be compact); ignored")
        del sec["CompactSubObj"]
    return "CompactSubObj" in sec


def _repair_access(sec: dict, where: str, source: str, warnings: list[str]) -> None:
    """AccessType in lower case (unknown: read only); PDOMapping 0 or 1 (unreadable: 0)."""
    access = sec.get("AccessType", ("", 0))[0].strip().lower()
    if access not in _ACCESS:
        warnings.append(f"{source}: {where}: AccessType={access or '(missing)'!r} unknown; read as 'ro'")
        access = "ro"
    sec["AccessType"] = (access, sec.get("AccessType", ("", 0))[1])
    if "PDOMapping" in sec and _int(sec["PDOMapping"][0]) not in (0, 1):
        warnings.append(f"{source}: {where}: PDOMapping={sec['PDOMapping'][0]!r} unreadable; read as 0 (not mappable)")
        sec["PDOMapping"] = ("0", sec["PDOMapping"][1])


_DEVICE_INFO_NUMBERS = (
    "VendorNumber",
    "ProductNumber",
    "RevisionNumber",
    "SimpleBootUpMaster",
    "SimpleBootUpSlave",
    "Granularity",
    "DynamicChannelsSupported",
    "GroupMessaging",
    "NrOfRXPDO",
    "NrOfTXPDO",
    "LSS_Supported",
) + tuple(k for k in _KNOWN_KEYS if k.startswith("BaudRate_"))


def _repair_info(sections: dict, source: str, warnings: list[str]) -> None:
    """[DeviceInfo], [Comments], [DummyUsage], [DeviceComissioning]: integers python-canopen parses strictly."""
    info = sections.get("DeviceInfo")
    if info is None:
        warnings.append(f"{source}: no [DeviceInfo] section; identity unknown")
        sections["DeviceInfo"] = {}  # python-canopen would say so once more
    else:
        _repair_numbers(info, "DeviceInfo", _DEVICE_INFO_NUMBERS, source, warnings)
    if "Comments" in sections:
        _repair_comments(sections["Comments"], source, warnings)
    dummy = sections.get("DummyUsage")
    if dummy is not None:
        for i in range(1, 8):
            key = f"Dummy{i:04d}"
            dummy[key] = (str(_int(dummy.get(key, ("", 0))[0]) or 0), 0)  # python-canopen reads base 10
    if "DeviceComissioning" in sections:
        _repair_numbers(sections["DeviceComissioning"], "DeviceComissioning", ("NodeID", "Baudrate"), source, warnings)


def _repair_numbers(sec: dict, name: str, keys, source: str, warnings: list[str]) -> None:
    """``keys`` of section ``name`` as decimal integers; one that is no number is dropped with a warning."""
    for key in keys:
        if key in sec and _int(sec[key][0]) is None:
            warnings.append(f"{source}: line {sec[key][1]} [{name}]: {key}={sec[key][0]!r} is not a number; ignored")
            del sec[key]
        elif key in sec:
            sec[key] = (str(_int(sec[key][0])), sec[key][1])


def _repair_comments(comments: dict, source: str, warnings: list[str]) -> None:
    """``Lines`` is the number of ``LineN`` keys that follow in order."""
    present = sorted(int(k[4:]) for k in comments if re.fullmatch(r"Line\d+", k))
    lines = _int(comments.get("Lines", ("", 0))[0])
    count = 0
    while count + 1 in present:
        count += 1
    if lines != count:
        warnings.append(
            f"{source}: [Comments]: Lines={comments.get('Lines', ('(missing)', 0))[0]} but "
            f"{count} comment lines follow in order; read {count}"
        )
    comments["Lines"] = (str(count), comments.get("Lines", ("", 0))[1])


class _Collect(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def _import(sections: dict, name: str, node_id, source: str, warnings: list[str]):
    """The canonical text through :func:`canopen.import_od`; python-canopen's own warnings become ours."""
    import canopen

    out = io.StringIO()
    for sec, keys in sections.items():
        out.write(f"[{sec}]\n")
        for key, (value, _) in keys.items():
            out.write(f"{key}={value}\n")
    out.seek(0)
    out.name = name if name.lower().endswith((".eds", ".dcf")) else name + ".eds"
    handler = _Collect()
    log = logging.getLogger("canopen.objectdictionary")
    log.addHandler(handler)
    try:
        od = canopen.import_od(out, node_id)
    except Exception as exc:  # a file python-canopen still cannot read: say which, never a traceback
        raise ConfigError(
            "canopen.eds", f"cannot be read as an EDS/DCF ({type(exc).__name__}: {exc})"[:300], source
        ) from None
    finally:
        log.removeHandler(handler)
    warnings += [f"{source}: {m}" for m in handler.messages]
    return od


def _expand_compact(od, sections: dict) -> None:
    """A CompactSubObj array declares N equal entries; python-canopen builds only the first: add the rest."""
    import copy

    from canopen.objectdictionary import ODArray

    for name, sec in sections.items():
        if not (_HEX_SECTION.match(name) and "CompactSubObj" in sec):
            continue
        obj = od.indices.get(int(name, 16))
        n = _int(sec["CompactSubObj"][0]) or 0
        if not isinstance(obj, ODArray) or 1 not in obj.subindices or not 0 < n < 255:
            continue
        first = obj.subindices[1]
        for sub in range(2, n + 1):
            if sub not in obj.subindices:
                var = copy.copy(first)
                var.subindex, var.name = sub, f"{first.name}_{sub:x}"
                obj.add_member(var)
        count = obj.subindices.get(0)
        if count is not None:
            count.access_type, count.default = "ro", n


def _check_values(od, sections: dict, source: str, warnings: list[str]) -> None:
    """Values python-canopen could not parse (it drops them silently), and a DCF's configured values."""
    dropped = _Tally("DefaultValue that is not a value of its data type; taken as no default")
    configured = _Tally("DCF ParameterValue entries; taken as the objects' values (they override DefaultValue)")
    for var in _variables(od):
        raw = getattr(var, "default_raw", None)
        if raw not in (None, "") and var.default is None and "$NODEID" not in raw:
            dropped.add(f"{var.index:04X}sub{var.subindex:X} DefaultValue={raw!r}")
        if getattr(var, "value", None) is not None:
            configured.add(f"[{var.index:04X}" + (f"sub{var.subindex:X}]" if var.parent is not od else "]"))
    dropped.report(source, warnings)
    configured.report(source, warnings)


def _check_profile(od, source: str, warnings: list[str]) -> None:
    """Standard objects whose data type or access deviates from CiA 301/402: kept as declared, reported."""
    if 0x1005 not in od:
        warnings.append(f"{source}: no 0x1005 (COB-ID SYNC): the drive is taken to consume SYNC at the default 0x080")
    checks = [(role, *ROLES[role][:3], ROLES[role][3]) for role in _PROFILE_CHECKED]
    checks += [(role, index, 0, dtype, "r") for index, (role, dtype) in _PROFILE_EXTRA.items()]
    for role, index, sub, dtype, use in checks:
        use = "rw" if index == 0x6060 else use  # CiA 402: rw; a host may read back what it wrote
        var = object_info(od, index, sub)
        if var is None:
            continue
        where = f"0x{index:04X}" + (f":{sub}" if sub else "")
        if var.data_type != dtype:
            warnings.append(
                f"{source}: [{index:04X}]: {where} ({role}) is declared {type_name(var.data_type)} where "
                f"CiA 402 says {type_name(dtype)}; kept as declared"
            )
        if "w" in use and not writable(var.access):
            warnings.append(
                f"{source}: [{index:04X}]: {where} ({role}) is declared {var.access!r}, the host must "
                f"write it; kept as declared"
            )
        if "r" in use and not readable(var.access):
            warnings.append(
                f"{source}: [{index:04X}]: {where} ({role}) is declared write-only; kept as declared"
                + (" (the mode in effect is read from 0x6061)" if index == 0x6060 else "")
            )


def _variables(od):
    from canopen.objectdictionary import ODVariable

    for obj in od.values():
        if isinstance(obj, ODVariable):
            yield obj
        else:
            yield from obj.subindices.values()


# --- what the drive offers ---------------------------------------------------------------------------------------


def type_name(data_type: int) -> str:
    """CiA 301 name of a data type code (``0x0007`` -> ``"UNSIGNED32"``)."""
    return _TYPE_NAMES.get(data_type, f"type 0x{data_type:04X}")


def readable(access: str) -> bool:
    return access in ("ro", "rw", "rwr", "rww", "const")


def writable(access: str) -> bool:
    return access in ("wo", "rw", "rwr", "rww")


@dataclass(frozen=True)
class ObjectInfo:
    """One object (or sub-index) as the EDS declares it.

    Attributes
    ----------
    index, subindex : int
    name : str
    data_type : int
        CiA 301 data type code.
    access : str
        ``ro``, ``wo``, ``rw``, ``rwr``, ``rww`` or ``const``.
    pdo_mappable : bool
    default : int, float, str, bytes or None
        The DCF's ParameterValue when there is one, else the DefaultValue (None: none declared).
    high_limit : int or None
        HighLimit when declared.
    """

    index: int
    subindex: int
    name: str
    data_type: int
    access: str
    pdo_mappable: bool
    default: object = None
    high_limit: int | None = None

    @property
    def address(self) -> str:
        return f"0x{self.index:04X}" + (f":{self.subindex}" if self.subindex else "")


def object_info(od, index: int, subindex: int = 0) -> ObjectInfo | None:
    """The entry at ``index:subindex`` (a variable at sub-index 0 for a plain object), or None when absent."""
    from canopen.objectdictionary import ODVariable

    obj = od.indices.get(index) if hasattr(od, "indices") else None
    if obj is None:
        return None
    if isinstance(obj, ODVariable):
        var = obj if subindex == 0 else None
    else:
        var = obj.subindices.get(subindex)
    if var is None:
        return None
    value = getattr(var, "value", None)
    return ObjectInfo(
        index,
        subindex,
        var.name,
        int(var.data_type or 0),
        var.access_type or "ro",
        bool(var.pdo_mappable),
        value if value is not None else var.default,
        var.max,
    )


@dataclass(frozen=True)
class PeriodInfo:
    """The object the cyclic period is written to.

    Attributes
    ----------
    object : str
        ``"0x60C2"`` (interpolation time period: value and exponent), ``"0x1006"`` (communication cycle period, us)
        or ``""`` when the drive has neither.
    seconds : float or None
        The period its defaults give, s (None: no default).
    value, exponent : int or None
        0x60C2:1 and 0x60C2:2 defaults (value * 10**exponent s), or 0x1006's default in us and None.
    """

    object: str
    seconds: float | None = None
    value: int | None = None
    exponent: int | None = None


@dataclass(frozen=True)
class EdsSummary:
    """What a host needs to know of a drive, read from its object dictionary.

    Attributes
    ----------
    vendor_name, product_name : str
    vendor_number, product_number, revision_number : int or None
        From [DeviceInfo].
    roles : dict
        Standard role (canopen_schema) -> ObjectInfo, for the roles whose object exists.
    supported_modes : tuple of str or None
        0x6502's default decoded (``"pp"``, ``"csp"``, ...); None when it has no default (read it from the device).
    cyclic_modes : tuple of str
        Cyclic modes available, in hilident's preference order: supported (or 0x6502 unknown) and with the
        set-point object present.
    rpdo_entries, tpdo_entries : tuple of int
        Per RPDO/TPDO with both its communication and mapping object: the most entries its mapping object takes.
    pdo_mapping_writable : bool
        Every mapping object's sub-index 0 is writable (the host may map its own objects).
    period : PeriodInfo
    torque_objects, current_objects : tuple of str
        Present among 0x6071/0x6072/0x6074/0x6076/0x6077 and 0x6075/0x6078.
    factor_group : dict
        Present factor-group roles (encoder_increments, motor_revolutions, gear_motor_revs, gear_shaft_revs,
        feed, feed_shaft_revs) -> default (None when none declared).
    heartbeat_consumers : int
        Entries of 0x1016 (0: no heartbeat consumer).
    abort_connection : bool
        0x6007 exists.
    store_parameters : bool
        0x1010:1 exists.
    vendor_filters, vendor_recorders, vendor_generators : tuple of (int, str)
        Manufacturer objects (0x2000-0x5FFF) whose names look like filters, recorders or generators.
    vendor_torque : tuple of (int, str, str)
        Manufacturer objects (plain, readable, PDO-mappable integers) named like a torque or current demand or
        actual value: ``(index, name, role)`` with the standard role each could stand in for
        (``torque_demand`` or ``torque_actual``).
    baudrates : tuple of int
        CAN bit rates [DeviceInfo] declares (BaudRate_xxx = 1), bit/s, fastest first.
    """

    vendor_name: str
    vendor_number: int | None
    product_name: str
    product_number: int | None
    revision_number: int | None
    roles: dict = field(hash=False)
    supported_modes: tuple[str, ...] | None
    cyclic_modes: tuple[str, ...]
    rpdo_entries: tuple[int, ...]
    tpdo_entries: tuple[int, ...]
    pdo_mapping_writable: bool
    period: PeriodInfo
    torque_objects: tuple[str, ...]
    current_objects: tuple[str, ...]
    factor_group: dict = field(default_factory=dict, hash=False)
    heartbeat_consumers: int = 0
    abort_connection: bool = False
    store_parameters: bool = False
    vendor_filters: tuple[tuple[int, str], ...] = ()
    vendor_recorders: tuple[tuple[int, str], ...] = ()
    vendor_generators: tuple[tuple[int, str], ...] = ()
    vendor_torque: tuple[tuple[int, str, str], ...] = ()
    baudrates: tuple[int, ...] = ()

    @property
    def rpdo_max_entries(self) -> int:
        return max(self.rpdo_entries, default=0)

    @property
    def tpdo_max_entries(self) -> int:
        return max(self.tpdo_entries, default=0)

    @property
    def torque_reference(self) -> str:
        """``"rated_torque"`` (torque objects per mille of 0x6076), ``"torque"`` (torque objects, no 0x6076),
        ``"current"`` (current objects only) or ``"none"``."""
        if {"0x6071", "0x6077", "0x6074"} & set(self.torque_objects):
            return "rated_torque" if "0x6076" in self.torque_objects else "torque"
        return "current" if self.current_objects else "none"


def inspect_eds(od) -> EdsSummary:
    """Summarise a loaded object dictionary (see :class:`EdsSummary`). Pure."""
    roles = {role: o for role, (i, s, _, _) in ROLES.items() if (o := object_info(od, i, s)) is not None}
    supported = _supported_modes(roles.get("supported_modes"))
    cyclic = tuple(m for m in CYCLIC_MODES if MODE_SETPOINTS[m] in roles and (supported is None or m in supported))
    rpdo, rpdo_w = _pdo_entries(od, 0x1400, 0x1600)
    tpdo, tpdo_w = _pdo_entries(od, 0x1800, 0x1A00)
    filters, recorders, generators = _vendor_objects(od)
    return EdsSummary(
        **_identity(od.device_information),
        roles=roles,
        supported_modes=supported,
        cyclic_modes=cyclic,
        rpdo_entries=rpdo,
        tpdo_entries=tpdo,
        pdo_mapping_writable=bool(rpdo or tpdo) and rpdo_w and tpdo_w,
        period=_period(od, roles),
        torque_objects=tuple(f"0x{i:04X}" for i in (0x6071, 0x6072, 0x6074, 0x6076, 0x6077) if i in od.indices),
        current_objects=tuple(f"0x{i:04X}" for i in (0x6075, 0x6078) if i in od.indices),
        factor_group=_factor_group(roles),
        heartbeat_consumers=_heartbeat_consumers(od),
        abort_connection=0x6007 in od.indices,
        store_parameters="store_parameters" in roles,
        vendor_filters=filters,
        vendor_recorders=recorders,
        vendor_generators=generators,
        vendor_torque=_vendor_torque(od),
        baudrates=tuple(sorted(od.device_information.allowed_baudrates, reverse=True)),
    )


def _identity(info) -> dict:
    """Vendor and product of ``[DeviceInfo]``."""
    return {
        "vendor_name": str(info.vendor_name or ""),
        "vendor_number": info.vendor_number,
        "product_name": str(info.product_name or ""),
        "product_number": info.product_number,
        "revision_number": info.revision_number,
    }


def _factor_group(roles: dict) -> dict:
    """Default values of the CiA 402 factor group objects the EDS has."""
    return {
        r: roles[r].default
        for r in (
            "encoder_increments",
            "motor_revolutions",
            "gear_motor_revs",
            "gear_shaft_revs",
            "feed",
            "feed_shaft_revs",
        )
        if r in roles
    }


def _heartbeat_consumers(od) -> int:
    """Entries of the heartbeat consumer 0x1016 (a variable: one); 0 without it."""
    hb = od.indices.get(0x1016)
    if hb is None:
        return 0
    return len([s for s in getattr(hb, "subindices", {}) if s > 0]) or 1


def _supported_modes(var: ObjectInfo | None) -> tuple[str, ...] | None:
    if var is None or not isinstance(var.default, int) or isinstance(var.default, bool):
        return None
    return profile.decode_supported_modes(var.default)


def _pdo_entries(od, comm_base: int, map_base: int) -> tuple[tuple[int, ...], bool]:
    """Most entries of each PDO whose communication and mapping objects both exist; all mappings writable?"""
    counts, writable_all = [], True
    for n in range(512):
        comm, mapping = od.indices.get(comm_base + n), od.indices.get(map_base + n)
        if comm is None or mapping is None:
            continue
        counts.append(profile.mapping_capacity(mapping))
        head = getattr(mapping, "subindices", {}).get(0)
        writable_all = writable_all and head is not None and writable(head.access_type or "ro")
    return tuple(counts), writable_all


def _period(od, roles: dict) -> PeriodInfo:
    if "interpolation_period" in roles:
        value = roles["interpolation_period"].default
        exp_var = object_info(od, 0x60C2, 2)
        exponent = exp_var.default if exp_var is not None else None
        if isinstance(exponent, int) and exponent > 127:  # declared UNSIGNED8 by some: -3 reads as 253
            exponent -= 256
        seconds = value * 10.0**exponent if isinstance(value, int) and isinstance(exponent, int) else None
        return PeriodInfo(
            "0x60C2",
            seconds,
            value if isinstance(value, int) else None,
            exponent if isinstance(exponent, int) else None,
        )
    if "cycle_period" in roles:
        value = roles["cycle_period"].default
        ok = isinstance(value, int) and value > 0
        return PeriodInfo("0x1006", value * 1e-6 if ok else None, value if isinstance(value, int) else None)
    return PeriodInfo("")


def _vendor_torque(od) -> tuple[tuple[int, str, str], ...]:
    """Manufacturer objects named like a torque or current, that a host could map and read (see EdsSummary)."""
    from canopen.objectdictionary import datatypes

    found = []
    for index in sorted(od.indices):
        obj = od.indices[index]
        if not 0x2000 <= index <= 0x5FFF or getattr(obj, "subindices", None) is not None:
            continue
        text = " " + re.sub(r"[^a-z0-9]+", " ", obj.name.lower()) + " "
        role = next((r for words, r in _TORQUE_NAMES if f" {words} " in text), None)
        if any(f" {w} " in text for w in _NOT_A_TORQUE):
            continue
        integer = obj.data_type in datatypes.INTEGER_TYPES
        if role and integer and getattr(obj, "pdo_mappable", False) and "r" in (obj.access_type or "ro"):
            found.append((index, obj.name, role))
    return tuple(found)


def _vendor_objects(od):
    """Manufacturer objects named like a filter, a recorder or a generator (whole words of the object's name)."""
    found: dict[str, list[tuple[int, str]]] = {"f": [], "r": [], "g": []}
    for index in sorted(od.indices):
        if not 0x2000 <= index <= 0x5FFF:
            continue
        name = od.indices[index].name
        spaced = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", name)  # "DataRecorder" -> "Data Recorder"
        text = " " + re.sub(r"[^a-z0-9-]+", " ", spaced.lower().replace("_", " ")) + " "
        if "acceptance filter" in text:  # a CAN identifier filter, not a signal filter
            continue
        for kind, words in (("f", _FILTER_WORDS), ("r", _RECORDER_WORDS), ("g", _GENERATOR_WORDS)):
            if any(re.search(rf"\b{re.escape(w)}", text) for w in words):
                found[kind].append((index, name))
    return tuple(found["f"]), tuple(found["r"]), tuple(found["g"])
