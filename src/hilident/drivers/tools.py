"""Bring up a vendor CANopen drive: write a driver folder from its EDS, check a folder against its EDS, describe one.

``hilident drivers new --eds FILE --out DIR`` copies the vendor's EDS/DCF into
a new folder, byte for byte, and writes a ``driver.toml`` with what the EDS
tells (cyclic modes, PDO limits, period object, torque reference, scaling
suggestions from the factor group). Every value it had to assume is listed in
``[driver] placeholders`` and marked ``# PLACEHOLDER: why``; vendor objects
that look like filters, recorders or generators are listed as comments for the
user to describe. When the EDS is of a documented family (its vendor ID and filter objects,
:mod:`hilident.drivers.filter_proposals`), ``drivers new`` proposes its
``[filters]`` table, every key a placeholder with the source of its value.
``hilident drivers check DIR`` validates a folder against its
EDS; ``hilident drivers -v`` describes each driver found.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import textwrap
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from hilident.drivers.description import (
    DriverDescription,
    declared_modes,
    load_driver,
    load_object_dictionary,
    valid_sample_rates,
)
from hilident.drivers.filter_check import filter_problems
from hilident.drivers.filter_proposals import FilterProposal, propose_filters
from hilident.drivers.loop_check import loop_problems
from hilident.drivers.loop_proposals import LoopProposal, propose_loop
from hilident.errors import ConfigError, UsageError
from hilident.protocol import eds as E
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.canopen_pdo_plan import (
    RunChannel,
    capture_problems,
    plan_streamed_run,
    recorder_problems,
)
from hilident.protocol.canopen_sync import parse_sync
from hilident.protocol.canopen_types import ObjectAddress, parse_address
from hilident.protocol.loop_parameters import FEEDFORWARD

DESCRIPTION_FILE = "driver.toml"
#: CAN bit rates (kbit/s) a [DeviceInfo] may declare, fastest first.
_BAUDRATES = (1000, 800, 500, 250, 125, 50, 20, 10)
#: Default loop rate when the EDS gives no period, Hz.
_DEFAULT_RATE_HZ = 1000.0


@dataclass(frozen=True)
class NewDriverReport:
    """What ``drivers new`` wrote.

    Attributes
    ----------
    folder : Path
    eds_file : str
        The EDS/DCF file name inside the folder.
    name : str
        The driver name.
    summary : EdsSummary
    warnings : tuple of str
        The EDS's quirks, as :func:`~hilident.protocol.eds.load_eds` reported them.
    placeholders : tuple of str
        Dotted keys of ``driver.toml`` whose values were assumed.
    proposal : FilterProposal or None
        The documented family whose ``[filters]`` table was proposed (its keys are placeholders), if any.
    """

    folder: Path
    eds_file: str
    name: str
    summary: E.EdsSummary
    warnings: tuple[str, ...]
    placeholders: tuple[str, ...]
    proposal: FilterProposal | None = None


@dataclass(frozen=True)
class CheckReport:
    """What ``drivers check`` found.

    Attributes
    ----------
    folder : Path
    errors : tuple of str
        What would make the driver fail; empty when the folder is usable.
    warnings : tuple of str
        The EDS's quirks and what may be wrong but need not be.
    placeholders : tuple of str
        ``[driver] placeholders``: values still to be confirmed (refused on a real port).
    summary : EdsSummary or None
        The EDS's summary, when it could be read.
    """

    folder: Path
    errors: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    placeholders: tuple[str, ...] = ()
    summary: E.EdsSummary | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        return not self.errors


# --- drivers new --------------------------------------------------------------------------------------------------


def new_driver_folder(eds_path, out_dir, name: str | None = None) -> NewDriverReport:
    """Write a driver folder for the drive an EDS/DCF describes.

    Parameters
    ----------
    eds_path : str or Path
        The vendor's EDS or DCF file.
    out_dir : str or Path
        The folder to write (created; it must not hold a ``driver.toml`` already).
    name : str, optional
        Driver name (default: the EDS file name, lower case, as a slug).

    Returns
    -------
    NewDriverReport

    Raises
    ------
    ConfigError
        The EDS cannot be read (naming the file).
    UsageError
        The output folder cannot be written or already holds a driver.
    """
    eds_path, out = Path(eds_path), Path(out_dir)
    od, warnings = E.load_eds(eds_path)
    summary = E.inspect_eds(od)
    name = name if name is not None else _slug(eds_path.stem)
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", name or ""):
        raise UsageError(f"--name {name!r}: a driver name is 1-64 letters, digits, '.', '_' or '-'")
    if (out / DESCRIPTION_FILE).exists():
        raise UsageError(f"--out {out}: already holds a {DESCRIPTION_FILE}; choose a new folder")
    # the folder is moved around with its EDS: name the file, not where it was read from
    notes = [w.replace(str(eds_path), eds_path.name, 1) for w in warnings]
    proposal = propose_filters(od, summary)
    text, placeholders = render_driver_toml(summary, eds_path.name, name, notes, proposal, propose_loop(od))
    try:
        out.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(eds_path, out / eds_path.name)
        (out / DESCRIPTION_FILE).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot write the driver folder ({exc.strerror or exc})") from None
    return NewDriverReport(out, eds_path.name, name, summary, tuple(warnings), tuple(placeholders), proposal)


def _slug(text: str) -> str:
    slug = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    return slug[:64] or "drive"


def _toml_str(text: str) -> str:
    return json.dumps(str(text))  # a JSON string is a TOML basic string


def _comment(text) -> str:
    """Text safe inside a TOML comment (no control characters, one line)."""
    return re.sub(r"[\x00-\x08\x0a-\x1f\x7f]", "?", str(text))


class _Toml:
    """Lines of a driver.toml, with placeholders recorded as they are written."""

    def __init__(self):
        self.lines: list[str] = []
        self.placeholders: list[str] = []
        self.table = ""

    def add(self, line: str = "") -> None:
        self.lines.append(line)

    def start(self, table: str) -> None:
        self.table = table
        self.add()
        self.add(f"[{table}]")

    def key(self, key: str, value: str, note: str = "", placeholder: str = "") -> None:
        line = f"{key} = {value}"
        if placeholder:
            self.placeholders.append(f"{self.table}.{key}")
            line += f"  # PLACEHOLDER: {_comment(placeholder)}"
        elif note:
            line += f"  # {_comment(note)}"
        self.add(line)


def render_driver_toml(
    s: E.EdsSummary,
    eds_file: str,
    name: str,
    warnings=(),
    proposal: FilterProposal | None = None,
    loop: LoopProposal | None = None,
) -> tuple[str, list[str]]:
    """The ``driver.toml`` text for a drive summarised by ``s``, and its placeholder keys. Pure.

    Parameters
    ----------
    s : EdsSummary
    eds_file : str
        EDS/DCF file name inside the driver folder.
    name : str
        Driver name.
    warnings : sequence of str
        The EDS's load warnings, written as comments.
    proposal : FilterProposal, optional
        A documented family's ``[filters]`` table to propose, every key a placeholder.
    loop : LoopProposal, optional
        The ``[loop]`` table the EDS's gain objects give, every key a placeholder.
    """
    body = _Toml()
    _board(body, s, proposal)
    _canopen(body, s, eds_file)
    _scaling(body, s)
    _extras(body, s, proposal)
    if loop is not None:
        _proposed_loop(body, loop)
    head = _Toml()
    product = " ".join(x for x in (s.vendor_name, s.product_name) if x) or eds_file
    head.add(
        f"# Driver description of {_comment(product)}, written by `hilident drivers new` from {_comment(eds_file)}."
    )
    head.add("# Values marked PLACEHOLDER were assumed: check each against the drive's manual, then remove its key")
    head.add("# from [driver] placeholders. Placeholders are accepted on the emulator and refused on a real port.")
    head.add("# `hilident drivers check <this folder>` validates the folder against its EDS.")
    if warnings:
        head.add("#")
        head.add("# Quirks of the EDS, read as follows:")
        for w in warnings:
            head.add(f"#   {_comment(w)}")
    head.start("driver")
    head.key("name", _toml_str(name))
    head.key("description", _toml_str(f"{product} (from its EDS)"))
    head.key("transport", '"canopen"')
    rate, note = _baudrate(s)
    head.key("default_baudrate", str(rate), f"CAN bit rate when the config gives none; {note}")
    head.add(
        "# keys whose values were guessed by `hilident drivers new`: accepted on the emulator, refused on a real port"
    )
    placeholders = body.placeholders
    head.key("placeholders", "[" + ", ".join(_toml_str(p) for p in placeholders) + "]")
    text = "\n".join(head.lines + body.lines) + "\n"
    tomllib.loads(text)  # what we write must parse; a failure here is a bug, not a user error
    return text, placeholders


def _baudrate(s: E.EdsSummary) -> tuple[int, str]:
    """The fastest bit rate [DeviceInfo] declares (1 Mbit/s when it declares none), and a note saying which."""
    if not s.baudrates:
        return 1_000_000, "[DeviceInfo] declares no bit rate: 1 Mbit/s"
    return s.baudrates[0], "the EDS declares " + ", ".join(f"{b // 1000}" for b in s.baudrates) + " kbit/s"


def _rate_hz(s: E.EdsSummary) -> tuple[float, str]:
    """Loop rate guess and why: 1 kHz (a common servo SYNC rate), or faster when the default period is shorter.

    The default cyclic period proves only that the drive takes that rate, not that it takes no faster one.
    """
    p = s.period
    if p.seconds and 1e-5 <= p.seconds < 1.0 / _DEFAULT_RATE_HZ:
        return (
            1.0 / p.seconds,
            f"from the default period of {p.object} ({p.seconds * 1e3:g} ms); the drive's "
            "filter rate and fastest SYNC rate may differ",
        )
    known = f"the default period of {p.object} is {p.seconds * 1e3:g} ms; " if p.seconds else ""
    return _DEFAULT_RATE_HZ, f"{known}the EDS does not tell the drive's loop rate; 1 kHz assumed"


def _board(t: _Toml, s: E.EdsSummary, proposal: FilterProposal | None) -> None:
    rate, why = _rate_hz(s)
    t.start("board")
    t.key("loop_rate_hz", f"{rate:.1f}", placeholder=why)
    t.key("max_sample_rate_hz", f"{rate:.1f}", placeholder="taken equal to loop_rate_hz")
    if proposal is not None:
        slots = proposal.family.filter_slots
        t.key("filter_slots", str(slots), placeholder=f"the slots of the [filters] table proposed at the end ({slots})")
    else:
        t.key("filter_slots", "0", "no filter capability described (see the vendor objects listed at the end)")


def _canopen(t: _Toml, s: E.EdsSummary, eds_file: str) -> None:
    t.start("canopen")
    t.key("eds", _toml_str(eds_file))
    t.add(
        f"# identity from the EDS [DeviceInfo]: vendor {_hex(s.vendor_number)}, product {_hex(s.product_number)},"
        f" revision {_hex(s.revision_number)}"
    )
    t.key("default_acquisition", '"streamed"', "host-streamed on standard objects")
    modes = ", ".join(_toml_str(m) for m in s.cyclic_modes)
    if s.cyclic_modes:
        known = (
            "0x6502 default" if s.supported_modes is not None else "set-point objects present (0x6502 has no default)"
        )
        t.key("cyclic_modes", f"[{modes}]", f"preference order; from the {known}")
    else:  # the key is left out: an empty preference is refused, and there is nothing to prefer
        t.add(
            "# cyclic_modes: the drive has no cyclic mode (CST/CSV/CSP/IP) with its set-point object: it cannot "
            "run a host-streamed session"
        )
    t.key(
        "heartbeat_ms",
        "100",
        "producer heartbeat asked of the drive (0x1017)"
        if "heartbeat_time" in s.roles
        else "the EDS has no 0x1017: not used",
    )
    t.key(
        "host_node_id",
        "127",
        "the host's heartbeat node id, watched by the drive's 0x1016"
        if s.heartbeat_consumers
        else "the EDS has no heartbeat consumer 0x1016: no device-side net",
    )
    supported = "unknown (no 0x6502 default)" if s.supported_modes is None else ", ".join(s.supported_modes) or "none"
    t.add(f"# modes 0x6502 lists: {supported}")
    t.add(
        f"# PDO limits from the EDS: {len(s.rpdo_entries)} RPDOs x up to {s.rpdo_max_entries} entries, "
        f"{len(s.tpdo_entries)} TPDOs x up to {s.tpdo_max_entries} entries (64 bits per PDO); mapping "
        + ("writable" if s.pdo_mapping_writable else "NOT writable: the host cannot map its own objects")
    )
    p = s.period
    if p.object == "0x60C2":
        t.add(
            f"# cyclic period written to 0x60C2 (value {p.value}, exponent {p.exponent}"
            + (f": {p.seconds * 1e3:g} ms by default)" if p.seconds else ": no default)")
        )
    elif p.object == "0x1006":
        t.add(f"# cyclic period written to 0x1006 in us (default {p.value})")
    else:
        t.add("# the EDS has neither 0x60C2 nor 0x1006: the drive's cycle period cannot be set by the host")
    if s.cyclic_modes:
        t.add()
        t.add("# [canopen.sync]: who keeps the bus clock, from the drive's manual (an EDS cannot tell):")
        t.add("#   producer = true     # the drive can produce SYNC itself (0x1005 bit 30): the best clock there is")
        t.add("#   window_us = 0       # how far a SYNC may stray before the drive counts a sync error (0: unknown)")


def _hex(value) -> str:
    return f"0x{value:08X}" if isinstance(value, int) else "not given"


def _scaling(t: _Toml, s: E.EdsSummary) -> None:
    t.start("canopen.scaling")
    unit, why = _position_unit(s)
    t.key("position_unit_m", f"{unit:.6g}", placeholder=why)
    t.key(
        "velocity_unit_mps",
        f"{unit:.6g}",
        placeholder="taken as one position unit per second; many drives use "
        "rpm or increments per second: check the manual",
    )
    ref = s.torque_reference
    rated = s.roles.get("rated_torque")
    if ref in ("rated_torque", "torque"):
        if rated is not None:
            t.key(
                "rated_torque_unit_nm",
                "1e-3",
                placeholder="unit of 0x6076 taken as mN*m (CiA 402); some drives use uN*m",
            )
        if rated is None or not (isinstance(rated.default, int) and rated.default > 0):
            why = "the EDS has no 0x6076" if rated is None else "0x6076 has no non-zero default"
            t.key(
                "rated_torque_nm",
                "1.0",
                placeholder=f"{why}: torque objects are per mille of the motor's rated torque, N*m",
            )
    elif ref == "current":
        t.add("# current only (no 0x6071/0x6077): torque = current * kt; current objects are per mille of 0x6075 (mA)")
        t.key("torque_constant_nm_per_a", "0.05", placeholder="the motor's torque constant kt, N*m/A")
        current = s.roles.get("rated_current")
        if current is None or not (isinstance(current.default, int) and current.default > 0):
            why = "the EDS has no 0x6075" if current is None else "0x6075 has no non-zero default"
            t.key(
                "rated_current_a",
                "10.0",
                placeholder=f"{why}: the motor's rated current, A (10 A assumed: current objects are "
                "per mille of it, so it also sets their range)",
            )
    elif s.vendor_torque:
        index, name, role = s.vendor_torque[0]
        t.add("# the EDS has neither torque nor current objects; a vendor object named like a torque stands in:")
        t.add(f"# torque_nm is 0x{index:04X} ({_comment(name)}), read as per mille of rated_torque_nm")
        t.key(
            "rated_torque_nm",
            "1.0",
            placeholder=f"the scaling of 0x{index:04X} {_comment(name)!r} is not in "
            "the EDS: per mille of 1 N*m assumed",
        )
        t.start("canopen.objects")
        what = "what the drive commands" if role == "torque_demand" else "what the drive measures"
        t.key(
            role,
            _toml_str(f"0x{index:04X}"),
            placeholder=f"vendor object {_comment(name)!r} taken as the torque ({what}); check the manual",
        )
    else:
        t.add("# the EDS has neither torque nor current objects: no torque can be measured or commanded")


def _position_unit(s: E.EdsSummary) -> tuple[float, str]:
    """SI value of one position unit, suggested from the factor group's defaults, and why."""
    f = s.factor_group

    def ok(*keys):
        return all(isinstance(f.get(k), int) and f[k] > 0 for k in keys)

    if ok("feed", "feed_shaft_revs") and ok("encoder_increments", "motor_revolutions") and f["feed"] > 1:
        unit = 2 * math.pi * f["feed_shaft_revs"] / f["feed"]
        return unit, (
            f"suggested from 0x6092 (feed {f['feed']} per {f['feed_shaft_revs']} shaft rev): rad of the "
            f"driving shaft per position unit; a linear axis needs m per unit"
        )
    if ok("encoder_increments", "motor_revolutions") and f["encoder_increments"] > 1:
        unit = 2 * math.pi * f["motor_revolutions"] / f["encoder_increments"]
        return unit, (
            f"suggested from 0x608F ({f['encoder_increments']} increments per {f['motor_revolutions']} motor "
            f"rev): rad of the motor shaft per increment; a linear axis needs m per increment"
        )
    return 1e-6, "the EDS does not tell the position unit; 1 um per increment assumed"


def _proposed_filters(t: _Toml, proposal: FilterProposal) -> None:
    """The ``[filters]`` table of a documented family, every key a placeholder naming the source of its value."""
    family = proposal.family
    t.add()
    t.add(f"# [filters] proposed by `hilident drivers new` for {_comment(family.name)},")
    t.add(f"# recognised by {_comment(proposal.how)}.")
    t.add(f"# Vendor ID {_comment(family.vendor_source)}.")
    t.add(f"# Objects and values: {_comment(family.source)}.")
    t.add("# Confirm each value against the drive's manual, then remove its PLACEHOLDER mark and its key from")
    t.add("# [driver] placeholders; `hilident drivers check` then tries slot 0 on the folder's twin.")
    for table, keys in family.tables:
        t.start(table)
        for key, value, source in keys:
            t.key(key, value, placeholder=source)


def _proposed_loop(t: _Toml, loop: LoopProposal) -> None:
    """The ``[loop]`` table the EDS's gain objects give, every key a placeholder, and what it leaves out."""
    t.add()
    t.add("# [loop] proposed by `hilident drivers new` from the names of the EDS's gain objects: the drive's")
    t.add("# cascade (hilident.control.Cascade, docs/drivers.md). An EDS gives no unit: confirm each object's")
    t.add("# scale (SI units per stored unit) and each value against the drive's manual, then remove its")
    t.add("# PLACEHOLDER mark and its key from [driver] placeholders.")
    for note in loop.notes:
        lines = textwrap.wrap(_comment(note), 108)
        t.add(f"#   {lines[0]}")
        t.lines += [f"#     {line}" for line in lines[1:]]
    t.start("loop")
    for key, value, why in loop.keys:
        t.key(key, value, placeholder=why)


#: The following error window (position increments) ``drivers new`` proposes for the twin of a drive whose EDS
#: gives 0x6065 no default or 0.
TWIN_FOLLOWING_ERROR_WINDOW = 100_000


def _following_error_unset(s: E.EdsSummary, modes=None) -> str:
    """How the EDS leaves 0x6065 unset for a drive with position cyclic modes ``modes`` (default: the EDS's);
    "" when it does not."""
    info = s.roles.get("following_error_window")
    modes = s.cyclic_modes if modes is None else modes
    if info is None or not isinstance(modes, list | tuple) or not {"csp", "ip"} & set(modes):
        return ""
    return "has no default in the EDS" if info.default is None else "is 0 in the EDS" if info.default == 0 else ""


def _extras(t: _Toml, s: E.EdsSummary, proposal: FilterProposal | None = None) -> None:
    if s.store_parameters:
        t.start("canopen.save")
        t.key("object", '"0x1010:1"', 'store parameters ("save"), written only with --save')
    no_window = _following_error_unset(s)
    if (s.supported_modes is None and s.cyclic_modes) or no_window:
        t.start("emulator")
    if s.supported_modes is None and s.cyclic_modes:
        modes = ", ".join(_toml_str(m) for m in s.cyclic_modes)
        t.key(
            "supported_modes",
            f"[{modes}]",
            placeholder="0x6502 has no default: the twin runs the cyclic modes whose set-point objects the EDS has",
        )
    if no_window:
        t.key(
            "values",
            f'{{ "0x6065" = {TWIN_FOLLOWING_ERROR_WINDOW} }}',
            placeholder=f"0x6065 (following error window) {no_window}: the twin holds this many position increments "
            "(with 0 its position loop faults on the first sample); the real drive holds its own",
        )
    if proposal is not None:
        _proposed_filters(t, proposal)
    for title, items in (
        ("filters", () if proposal is not None else s.vendor_filters),
        ("recorders", s.vendor_recorders),
        ("generators", s.vendor_generators),
    ):
        if items:
            t.add()
            t.add(
                f"# Vendor objects that look like {title}: describe them here to use them "
                + (
                    "([filters], encodings in protocol/filter_encoding/)"
                    if title == "filters"
                    else "(a vendor capability)"
                )
            )
            for index, name in items:
                t.add(f"#   0x{index:04X} {_comment(name)}")


# --- drivers check ------------------------------------------------------------------------------------------------

#: Roles the host writes (the object must be writable); every other role is read.
_WRITTEN_ROLES = frozenset(r for r, (_, _, _, use) in E.ROLES.items() if "w" in use) | {
    "table",
    "table_divider",
    "table_command",
    "capture_mapping",
    "capture_offset",
    "setpoint_counter",
}
_READ_ROLES = frozenset(r for r, (_, _, _, use) in E.ROLES.items() if "r" in use)
_MODE_BIT = {code: bit for bit, name in E.MODE_BITS.items() for n, code in E.MODE_CODES.items() if n == name}
_INTEGER_TYPES = frozenset(
    {0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x10, 0x12, 0x13, 0x14, 0x15, 0x16, 0x18, 0x19, 0x1A, 0x1B}
)
_FLOAT_TYPES = frozenset({0x08, 0x11})


def _family(data_type: int) -> str:
    if data_type in _INTEGER_TYPES:
        return "integer"
    if data_type in _FLOAT_TYPES:
        return "float"
    return "bytes"


class _Checker:
    def __init__(self, folder: Path, data: dict, od, summary: E.EdsSummary, source: str):
        self.folder, self.data, self.od, self.s, self.source = folder, data, od, summary, source
        self.errors: list[str] = []
        self.warnings: list[str] = []
        co = data.get("canopen")
        self.co = co if isinstance(co, dict) else {}
        objects = self.co.get("objects", {})
        self.objects = objects if isinstance(objects, dict) else {}

    def error(self, key: str, text: str) -> None:
        self.errors.append(f"{self.source}: [{key}] {text}")

    def warn(self, key: str, text: str) -> None:
        self.warnings.append(f"{self.source}: [{key}] {text}")

    def address(self, key: str, text) -> E.ObjectInfo | None:
        """The EDS entry of an address string; an error naming ``key`` when it is malformed or absent."""
        m = re.fullmatch(r"\s*(?:0x)?([0-9A-Fa-f]{1,4})(?::(\w+))?\s*", text) if isinstance(text, str) else None
        sub = _parse_int(m.group(2)) if m and m.group(2) else 0
        if m is None or sub is None or not 0 <= sub <= 255:
            self.error(key, f'must be an object address like "0x6064" or "0x607D:2", got {text!r}')
            return None
        info = E.object_info(self.od, int(m.group(1), 16), sub)
        if info is None:
            self.error(key, f"object {text} is not in the EDS")
        return info

    def role(self, key: str, role) -> E.ObjectInfo | None:
        """The object of a role: [canopen.objects] first, else the standard index when the EDS has it."""
        if not isinstance(role, str):
            self.error(key, f"must name a role, got {role!r}")
            return None
        if role in self.objects:
            return self.address(key, self.objects[role])
        if role in E.ROLES:
            index, sub, _, _ = E.ROLES[role]
            info = E.object_info(self.od, index, sub)
            if info is None:
                self.error(
                    key,
                    f"role {role!r}: its standard object 0x{index:04X}"
                    + (f":{sub}" if sub else "")
                    + " is not in the EDS, and [canopen.objects] does not name another",
                )
            return info
        self.error(key, f"role {role!r} is neither a standard role nor named in [canopen.objects]")
        return None

    def access(self, key: str, role: str, info: E.ObjectInfo, write: bool | None = None) -> None:
        write = role in _WRITTEN_ROLES if write is None else write
        if write and not E.writable(info.access):
            self.error(key, f"{info.address} ({role}) is {info.access!r} in the EDS; the host must write it")
        if not write and not E.readable(info.access):
            self.error(key, f"{info.address} ({role}) is write-only in the EDS; the host must read it")

    def type(self, key: str, role: str, info: E.ObjectInfo) -> None:
        if role not in E.ROLES:
            return
        want = E.ROLES[role][2]
        if _family(want) != _family(info.data_type):
            self.error(
                key,
                f"{info.address} ({role}) is {E.type_name(info.data_type)} in the EDS; the role needs "
                f"a {_family(want)} like {E.type_name(want)}",
            )


def _parse_int(text):
    try:
        return int(text, 0)
    except (TypeError, ValueError):
        return None


def check_driver_folder(folder) -> CheckReport:
    """Validate a CANopen driver folder against its EDS.

    Every object ``driver.toml`` references ([canopen.objects], the set-points of [canopen.modes],
    [canopen.channels], [filters] objects and fields, [canopen.save]) must exist in the EDS with a
    compatible type and access; the preferred cyclic modes must be supported (a warning when 0x6502 has no
    default); the streamed channels must fit the TPDOs; scaling values must be positive; the placeholders are
    listed.

    Returns
    -------
    CheckReport
        Errors, warnings and placeholders; ``ok`` when there is no error.
    """
    folder = Path(folder)
    path = folder / DESCRIPTION_FILE
    source = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        return CheckReport(folder, errors=(f"{source}: cannot be read as TOML: {getattr(exc, 'strerror', '') or exc}",))
    table = data.get("driver")
    driver = table if isinstance(table, dict) else {}
    placeholders = driver.get("placeholders", [])
    placeholders = tuple(str(p) for p in placeholders) if isinstance(placeholders, list) else ()
    if driver.get("transport") != "canopen":
        return CheckReport(
            folder,
            errors=(
                f"{source}: [driver.transport] is {driver.get('transport')!r}; "
                f"`drivers check` validates CANopen drivers against their EDS",
            ),
            placeholders=placeholders,
        )
    table = data.get("canopen")
    co = table if isinstance(table, dict) else {}
    eds_name = co.get("eds")
    if not isinstance(eds_name, str) or not eds_name:
        return CheckReport(
            folder,
            errors=(f"{source}: [canopen.eds] must name the EDS/DCF file in the folder",),
            placeholders=placeholders,
        )
    try:
        od, eds_warnings = E.load_eds(folder / eds_name)
    except ConfigError as exc:
        return CheckReport(folder, errors=(str(exc),), placeholders=placeholders)
    c = _Checker(folder, data, od, E.inspect_eds(od), source)
    c.warnings += eds_warnings
    _check_objects(c)
    _check_modes(c)
    _check_channels(c)
    _check_filters(c)
    for key, text in loop_problems(c.data, c.od, source):
        c.error(key, text)
    _check_save(c)
    _check_recorder(c)
    _check_sync(c)
    _check_following_error(c)
    _check_scaling(c)
    _check_keys(c)
    _check_identity(c)
    _check_placeholders(c, placeholders, path)
    if not c.errors:  # what the runs map, on a description whose objects are known to be there
        c.errors += _run_mapping_errors(folder, od, source)
    return CheckReport(folder, tuple(c.errors), tuple(c.warnings), placeholders, c.s)


#: The node id ``drivers check`` plans the PDOs' COB-IDs for (the default ``[device.canopen] node_id``).
_CHECK_NODE_ID = 1


def _run_mapping_errors(folder: Path, od, source: str) -> list[str]:
    """What a run would map or write that the EDS refuses, for every mode and acquisition the folder declares.

    Streamed runs (the default acquisition, or any on a streamed driver) are planned for every mode of the
    driver with its streamed channels; a drive-buffered run's capture and a recorder's channels are checked
    when the driver describes them.
    """
    try:
        driver = load_driver(folder)
        desc = CanopenDescription.from_sections(driver.sections, source, od)
    except ConfigError:
        return []  # a description the loader refuses cannot be planned; the checks above report on its tables
    errors = []
    for acquisition in _declared_acquisitions(desc):
        modes_of: dict[str, list[str]] = {}  # a problem shared by several modes is told once, naming them
        for spec in desc.modes.values():
            for problem in run_mapping_problems(od, desc, driver, acquisition, spec.setpoint, None, _CHECK_NODE_ID):
                modes_of.setdefault(problem, []).append(spec.name)
        errors += [
            f"{source}: [{acquisition} run, {'mode' if len(m) == 1 else 'modes'} {', '.join(m)}] {problem}"
            for problem, m in modes_of.items()
        ]
    return errors


def _declared_acquisitions(desc: CanopenDescription) -> list[str]:
    """The acquisitions a driver declares: its default, a capture when it names one, a recorder when it has one."""
    acquisitions = [desc.default_acquisition]
    if desc.has("capture_mapping") and "buffered" not in acquisitions:
        acquisitions.append("buffered")
    if desc.recorder is not None and "recorder" not in acquisitions:
        acquisitions.append("recorder")
    return acquisitions


def run_mapping_problems(
    od,
    desc: CanopenDescription,
    driver: DriverDescription,
    acquisition: str,
    setpoint: str,
    channels: Sequence[str] | None,
    node_id: int,
) -> list[str]:
    """What a run would map or write that the EDS refuses (empty: nothing), one message per object.

    Parameters
    ----------
    od : canopen.ObjectDictionary
        The drive's EDS.
    desc : CanopenDescription
    driver : DriverDescription
        The driver's channels (its streamed channels are recorded when ``channels`` is None).
    acquisition : {"streamed", "buffered", "recorder"}
    setpoint : str
        The role of the set-point object of the run's mode.
    channels : sequence of str or None
        The channels recorded (``run.channels``); None: the driver's streamed channels.
    node_id : int
        The drive's node id (the COB-IDs of PDOs 1-4).
    """
    names = list(channels or [c.name for c in driver.streamed_channels])
    run_channels = [
        RunChannel(name, desc.address(role) if (role := desc.channels[name]) is not None else None)
        for name in names
        if name in desc.channels
    ]
    if acquisition == "buffered":
        return capture_problems(od, desc, run_channels)
    if acquisition == "recorder":
        return recorder_problems(desc, run_channels)
    try:
        plan_streamed_run(od, desc, node_id, run_channels, setpoint)
    except ConfigError as exc:
        return [exc.message]
    return []


def check_run_mapping(cfg, driver: DriverDescription, modes: Sequence[str]) -> None:
    """Refuse, before anything moves, a CANopen run whose mapping the drive's EDS does not allow.

    The run's acquisition (``device.acquisition``, "auto": the driver's default), its channels
    (``run.channels``) and each of ``modes`` (the hilident modes the session runs) are planned as the adapter
    maps them (:func:`run_mapping_problems`). Nothing is done for another transport.

    Raises
    ------
    ConfigError
        Naming the driver file, the EDS objects the run cannot map or write, and what to change.
    """
    if driver.transport != "canopen":
        return
    source = str(driver.folder / DESCRIPTION_FILE)
    node_id = cfg.device.canopen.node_id
    od = load_object_dictionary(driver, node_id)
    desc = CanopenDescription.from_sections(driver.sections, source, od)
    acquisition = desc.default_acquisition if cfg.device.acquisition == "auto" else cfg.device.acquisition
    problems: list[str] = []
    for mode in dict.fromkeys(modes):
        if mode in desc.modes:
            problems += run_mapping_problems(
                od, desc, driver, acquisition, desc.modes[mode].setpoint, cfg.run.channels, node_id
            )
    if problems:
        raise ConfigError(
            "device.driver",
            f"a {acquisition} run of driver {driver.name!r} cannot be configured on its EDS {desc.eds}: "
            + "; ".join(dict.fromkeys(problems)),
            source,
        )


def _check_objects(c: _Checker) -> None:
    if "objects" in c.co and not isinstance(c.co["objects"], dict):
        c.error("canopen.objects", 'must be a table of role = "0xIIII[:sub]"')
    for role, text in c.objects.items():
        key = f"canopen.objects.{role}"
        info = c.address(key, text)
        if info is None:
            continue
        c.type(key, role, info)
        c.access(key, role, info)


def _check_modes(c: _Checker) -> None:
    """``[canopen.modes]`` against the EDS, then ``cyclic_modes``."""
    modes = c.co.get("modes", {})
    if not isinstance(modes, dict):
        c.error("canopen.modes", 'must be a table of mode = { code = <int>, setpoint = "<role>" }')
        modes = {}
    for name, spec in modes.items():
        key = f"canopen.modes.{name}"
        if not isinstance(spec, dict) or not isinstance(spec.get("code"), int) or "setpoint" not in spec:
            c.error(key, 'must be { code = <int>, setpoint = "<role>" }')
            continue
        _check_mode_setpoint(c, key, spec["setpoint"])
        _check_mode_code(c, key, spec["code"])
    _check_cyclic_modes(c)


def _check_mode_setpoint(c: _Checker, key: str, role: str) -> None:
    """The set-point object of a mode: of its type, writable, PDO-mappable."""
    info = c.role(f"{key}.setpoint", role)
    if info is None:
        return
    if role not in c.objects:  # else _check_objects has checked its type already
        c.type(f"{key}.setpoint", role, info)
    if role not in c.objects or role not in _WRITTEN_ROLES:
        c.access(f"{key}.setpoint", role, info, write=True)
    if not info.pdo_mappable:
        c.warn(f"{key}.setpoint", f"{info.address} is not PDO-mappable: it cannot be streamed")


def _check_mode_code(c: _Checker, key: str, code: int) -> None:
    """A mode code fits 0x6060 and is one 0x6502 lists."""
    s = c.s
    mode_object = s.roles.get("modes_of_operation")
    if code < 0 and mode_object is not None and mode_object.data_type != E.INTEGER8:
        c.warn(
            f"{key}.code",
            f"negative mode {code}, but 0x6060 is {E.type_name(mode_object.data_type)}: written as {code & 0xFF}",
        )
    bit = _MODE_BIT.get(code)
    if s.supported_modes is not None and bit is not None and E.MODE_BITS[bit] not in s.supported_modes:
        c.error(
            f"{key}.code",
            f"mode {code} ({E.MODE_BITS[bit].upper()}) is not in 0x6502 ({', '.join(s.supported_modes) or 'none'})",
        )
    elif bit is None:
        c.warn(f"{key}.code", f"mode {code} is not a CiA 402 mode 0x6502 lists; not checked")


def _check_cyclic_modes(c: _Checker) -> None:
    """``cyclic_modes``: known modes, at least one the drive supports; say when 0x6502 cannot tell."""
    s = c.s
    preferred = c.co.get("cyclic_modes", [])
    if not isinstance(preferred, list) or any(m not in E.CYCLIC_MODES for m in preferred):
        c.error("canopen.cyclic_modes", f"must be a list of {', '.join(E.CYCLIC_MODES)}, got {preferred!r}")
        return
    usable = []
    for mode in preferred:
        role = E.MODE_SETPOINTS[mode]
        if role not in s.roles and role not in c.objects:
            c.warn("canopen.cyclic_modes", f"{mode}: its set-point object ({role}) is not in the EDS")
        elif s.supported_modes is not None and mode not in s.supported_modes:
            c.warn("canopen.cyclic_modes", f"{mode} is not in 0x6502 ({', '.join(s.supported_modes) or 'none'})")
        else:
            usable.append(mode)
    if preferred and not usable:
        c.error("canopen.cyclic_modes", f"none of {', '.join(preferred)} is supported by the drive")
    if not preferred and not s.cyclic_modes:
        c.warn(
            "canopen.cyclic_modes",
            "the drive has no cyclic mode (CST/CSV/CSP/IP) with its set-point object in the EDS: hilident run "
            "cannot excite it; hilident identify reads its recordings",
        )
    if preferred and s.supported_modes is None:
        emulator = c.data.get("emulator")
        emu = emulator.get("supported_modes") if isinstance(emulator, dict) else None
        c.warn(
            "canopen.cyclic_modes",
            "0x6502 has no default: the modes are read from the drive at connect"
            + ("" if emu else "; the twin needs [emulator] supported_modes"),
        )


def _check_sync(c: _Checker) -> None:
    """``[canopen.sync]``: its keys, and a SYNC producer needs 0x1005 writable and 0x1006 in the EDS."""
    try:
        sync = parse_sync(c.co, c.source)
    except ConfigError as exc:
        c.errors.append(str(exc))
        return
    if not sync.producer:
        if c.s.cyclic_modes or c.co.get("cyclic_modes"):
            c.warn(
                "canopen.sync.producer",
                "not set: in streamed runs the SYNC comes from the CAN interface's own cyclic transmit where "
                "there is one (SocketCAN), else from the host's Python loop (late cycles skipped); set "
                "producer = true if the drive's manual says it can produce SYNC (0x1005 bit 30)",
            )
        return
    for index, name, write in ((0x1005, "COB-ID SYNC", True), (0x1006, "communication cycle period", True)):
        info = E.object_info(c.od, index, 0)
        if info is None:
            c.error("canopen.sync.producer", f"is true but 0x{index:04X} ({name}) is not in the EDS")
        elif write and not E.writable(info.access):
            c.error(
                "canopen.sync.producer",
                f"is true but 0x{index:04X} ({name}) is {info.access!r} in the EDS: the host cannot ask for SYNC",
            )


def _check_following_error(c: _Checker) -> None:
    """A drive with position cyclic modes whose EDS gives its following error window (0x6065) as 0, or gives
    none (its twin then holds 0): position runs are refused unless the drive holds another value."""
    unset = _following_error_unset(c.s, c.co.get("cyclic_modes"))
    if unset:
        emulator = c.data.get("emulator")
        values = emulator.get("values") if isinstance(emulator, dict) else None
        held = isinstance(values, dict) and any(_is_6065(k) for k in values)
        name = c.s.roles["following_error_window"].name
        c.warn(
            "canopen.cyclic_modes",
            f"0x6065 ({name}) {unset}: a drive holding 0 faults on the first sample with its position loop "
            "closed (CSP, IP, a torque offset held in CSP), so such runs are refused until the drive holds the "
            "distance from the set-point it may tolerate "
            + (
                "(this folder's twin holds the one [emulator] values gives)"
                if held
                else '(this folder\'s twin holds 0: give it one in [emulator] values = { "0x6065" = ... })'
            ),
        )


def _is_6065(key) -> bool:
    try:
        return parse_address(key, "emulator.values") == ObjectAddress(0x6065, 0)
    except ConfigError:
        return False


def _check_channels(c: _Checker) -> None:
    channels = c.co.get("channels", {})
    if not isinstance(channels, dict):
        c.error("canopen.channels", 'must be a table of channel = "<role>"')
        return
    bits = []
    for name, role in channels.items():
        key = f"canopen.channels.{name}"
        info = c.role(key, role)
        if info is None:
            continue
        c.access(key, role, info, write=False)
        if not info.pdo_mappable:
            c.warn(key, f"{info.address} is not PDO-mappable: it cannot be streamed")
        elif info.data_type in _INTEGER_TYPES | _FLOAT_TYPES:
            bits.append(_bits(info.data_type))
    capacity = len(c.s.tpdo_entries)
    if bits and c.s.tpdo_entries and _pdos_needed(bits, c.s.tpdo_max_entries) > capacity:
        c.error(
            "canopen.channels",
            f"{len(bits)} streamed channels ({sum(bits)} bits) do not fit the drive's "
            f"{capacity} TPDOs of up to {c.s.tpdo_max_entries} entries (64 bits each)",
        )


def _bits(data_type: int) -> int:
    return {0x01: 8, 0x02: 8, 0x05: 8, 0x03: 16, 0x06: 16, 0x10: 24, 0x16: 24, 0x11: 64, 0x15: 64, 0x1B: 64}.get(
        data_type, 32
    )


def _pdos_needed(bits: list[int], max_entries: int) -> int:
    """PDOs first-fit packing needs for objects of these widths (64 bits and ``max_entries`` entries per PDO)."""
    frames: list[list[int]] = []
    for b in sorted(bits, reverse=True):
        for f in frames:
            if sum(f) + b <= 64 and len(f) < max_entries:
                f.append(b)
                break
        else:
            frames.append([b])
    return len(frames)


def _check_filters(c: _Checker) -> None:
    """[filters]: every slot's objects against the EDS (:mod:`hilident.drivers.filter_check`)."""
    errors, warnings = filter_problems(c.data, c.od)
    for key, text in errors:
        c.error(key, text)
    for key, text in warnings:
        c.warn(key, text)


def _check_save(c: _Checker) -> None:
    save = c.co.get("save")
    if save is None:
        return
    if not isinstance(save, dict) or "object" not in save:
        c.error("canopen.save", 'must be { object = "0x1010:1" }')
        return
    info = c.address("canopen.save.object", save["object"])
    if info is not None:
        c.access("canopen.save.object", "store_parameters", info, write=True)


def _check_scaling(c: _Checker) -> None:
    scaling = c.co.get("scaling", {})
    if not isinstance(scaling, dict):
        c.error("canopen.scaling", "must be a table")
        return
    for key, value in scaling.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            c.error(f"canopen.scaling.{key}", f"must be a positive number, got {value!r}")
    ref = c.s.torque_reference
    if ref == "current" and "torque_constant_nm_per_a" not in scaling:
        c.warn("canopen.scaling", "current-only drive without torque_constant_nm_per_a: no torque in N*m")
    if ref == "torque" and "rated_torque_nm" not in scaling:
        c.warn("canopen.scaling", "the EDS has no 0x6076 and rated_torque_nm is not given: no torque in N*m")


def _check_recorder(c: _Checker) -> None:
    """[canopen.recorder] and [canopen.generator]: their vocabulary, and every object they name in the EDS."""
    from hilident.protocol.canopen_recorder import parse_recorder

    try:
        parse_recorder(c.data, c.source, c.od)
    except ConfigError as exc:
        c.errors.append(str(exc))


def _check_keys(c: _Checker) -> None:
    """[canopen] values that are written to the drive fit their objects."""
    hb = c.co.get("heartbeat_ms", 100)
    if not isinstance(hb, int) or isinstance(hb, bool) or not 1 <= hb <= 65535:
        c.error("canopen.heartbeat_ms", f"must fit 0x1017 (UNSIGNED16 ms, 1..65535), got {hb!r}")
    node = c.co.get("host_node_id", 127)
    if not isinstance(node, int) or isinstance(node, bool) or not 1 <= node <= 127:
        c.error("canopen.host_node_id", f"must be a node id 1..127, got {node!r}")
    option = c.co.get("abort_connection_option")
    if option is not None and not c.s.abort_connection:
        c.warn("canopen.abort_connection_option", "the EDS has no 0x6007: the value is not written")


def _check_identity(c: _Checker) -> None:
    for key, value in (("vendor_id", c.s.vendor_number), ("product_code", c.s.product_number)):
        given = c.co.get(key)
        if given is not None and value is not None and given != value:
            c.warn(
                f"canopen.{key}",
                f"0x{given:08X} differs from the EDS [DeviceInfo] (0x{value:08X})"
                if isinstance(given, int)
                else f"must be an integer, got {given!r}",
            )


def _check_placeholders(c: _Checker, placeholders: tuple[str, ...], path: Path) -> None:
    for p in placeholders:
        node: object = c.data
        for part in p.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if node is None:
            c.warn("driver.placeholders", f"{p!r} is not a key of the file")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError:
        return
    table = ""
    for line in lines:
        m = re.match(r"\s*\[+\s*([^\]]+?)\s*\]", line)
        if m:
            table = m.group(1)
        m = re.match(r"\s*([A-Za-z0-9_-]+)\s*=.*#\s*PLACEHOLDER", line)
        if m and f"{table}.{m.group(1)}" not in placeholders:
            c.warn("driver.placeholders", f"{table}.{m.group(1)} is marked PLACEHOLDER but not listed")


# --- drivers -v ---------------------------------------------------------------------------------------------------


def _describe_modbus(mb: dict) -> list[str]:
    """A Modbus map's capabilities for ``drivers -v``: parameter rule, excitation, save."""
    caps = []
    rule = mb.get("parameters")
    if isinstance(rule, dict) and rule.get("address"):
        caps.append(f"parameters {rule.get('prefix', '')}XX.YY at {rule['address']}")
    if isinstance(mb.get("table"), dict) and isinstance(mb.get("capture"), dict):
        caps.append("excitation (table and capture)")
    else:
        caps.append("no excitation: identify a recording, then upload")
    save = mb.get("save")
    if isinstance(save, dict):
        caps.append(f"save ({save.get('register', '?')} = {save.get('value', '?')}, with --save)")
    return caps


def describe_driver(folder) -> str:
    """Several lines for ``hilident drivers -v``: channels, rates, modes, filter slots and capabilities."""
    folder = Path(folder)
    try:
        data = tomllib.loads((folder / DESCRIPTION_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        return f"  unreadable {DESCRIPTION_FILE}: {exc}"
    board, driver = _table_of(data, "board"), _table_of(data, "driver")
    out = [f"  {driver['description']}"] if driver.get("description") else []
    out.append(
        f"  rates: loop {board.get('loop_rate_hz', '?')} Hz, samples up to "
        f"{board.get('max_sample_rate_hz', '?')} Hz; filter slots: {board.get('filter_slots', 0)}"
    )
    channels, modes, caps = _transport_features(folder, data, driver.get("transport", "?"))
    out.append(f"  channels: {', '.join(channels) or 'none'}")
    out += _loaded_figures(folder)
    out.append(f"  modes: {', '.join(modes) or 'none'}")
    out += _loop_lines(_table_of(data, "loop"))
    if _table_of(data, "filters").get("encoding"):
        caps.append(f"filters ({data['filters']['encoding']})")
    placeholders = driver.get("placeholders") or []
    out.append(f"  capabilities: {', '.join(caps) or 'none beyond the transport'}")
    if placeholders:
        out.append(f"  placeholders (refused on a real port): {', '.join(map(str, placeholders))}")
    return "\n".join(out)


def _loop_lines(loop: dict) -> list[str]:
    """The cascade ``[loop]`` describes: its controllers' forms, its feed-forward terms, what the drive holds."""
    if not loop:
        return []
    integral = "its integral as a gain" if "ki_nm_per_m" in loop else "its integral as a time"
    position = {(False, False): "P", (True, False): "PI", (False, True): "PD", (True, True): "PID"}[
        ("ki_pos_per_s2" in loop, "kd_pos" in loop)
    ]
    held = [name for name, entry in loop.items() if isinstance(entry, dict) and "value" not in entry]
    feedforward = [name for name in FEEDFORWARD if name in loop]
    return [
        f"  loop: velocity PI ({integral}), position {position}; feed-forward: {', '.join(feedforward) or 'none'}",
        f"  loop parameters the drive holds: {', '.join(held) or 'none'}",
    ]


def _loaded_figures(folder: Path) -> list[str]:
    """The channels' units and the sample rates a session may record at, as the driver loader reads them."""
    try:
        d = load_driver(folder)
        rates = valid_sample_rates(d, 6)
    except (ConfigError, ValueError, ZeroDivisionError):  # a broken description is described, not refused
        return []
    units = ", ".join(f"{c.name} [{c.unit}]" for c in d.channels)
    return [
        f"  channel units: {units or 'none'}",
        f"  sample rates: {', '.join(f'{r:g}' for r in rates)}, ... Hz (the loop rate over a whole number)",
    ]


def _table_of(data: dict, key: str) -> dict:
    """``data[key]`` when it is a table, else an empty one (a description being described may be broken)."""
    value = data.get(key)
    return value if isinstance(value, dict) else {}


def _transport_features(folder: Path, data: dict, transport: str) -> tuple[list, list, list]:
    """Channels, modes and capabilities as the transport's description gives them."""
    channels = [c.get("name", "?") for c in data.get("channels", []) if isinstance(c, dict)]
    if transport == "canopen":
        caps, modes, more = _describe_canopen(folder, data, _table_of(data, "canopen"))
        channels = channels or more
        try:  # what a session would use: the channels and hilident modes the driver loader derives
            loaded = load_driver(folder)
            channels, modes = [c.name for c in loaded.channels], list(declared_modes(loaded))
        except ConfigError as exc:
            caps.append(f"not loadable: {exc}")
        return channels, modes, caps
    if transport == "modbus":
        mb = _table_of(data, "modbus")
        return channels, list(_table_of(mb, "modes")), _describe_modbus(mb)
    return channels, ["torque", "torque_injection", "velocity", "position"], []


def _describe_canopen(folder: Path, data: dict, co: dict):
    caps: list[str] = []
    channels: list[str] = []
    modes = list(co.get("modes", {})) if isinstance(co.get("modes"), dict) else []
    if isinstance(co.get("cyclic_modes"), list):
        modes += [m.upper() for m in co["cyclic_modes"] if isinstance(m, str)]
    eds_name = co.get("eds")
    try:
        od, _ = E.load_eds(folder / str(eds_name))
    except ConfigError as exc:
        return [f"EDS unreadable ({exc})"], modes, channels
    s = E.inspect_eds(od)
    standard = (
        ("position_m", "position_actual"),
        ("velocity_mps", "velocity_actual"),
        ("torque_nm", "torque_actual"),
        ("torque_cmd_nm", "torque_demand"),
        ("current_a", "current_actual"),
    )
    channels = [name for name, role in standard if role in s.roles]
    if s.supported_modes is not None:
        caps.append(f"0x6502: {', '.join(s.supported_modes) or 'none'}")
    caps.append(f"{len(s.rpdo_entries)} RPDO x {s.rpdo_max_entries}, {len(s.tpdo_entries)} TPDO x {s.tpdo_max_entries}")
    if s.period.object:
        caps.append(f"period {s.period.object}")
    if s.heartbeat_consumers:
        caps.append("heartbeat consumer 0x1016" + (" + 0x6007" if s.abort_connection else ""))
    if "sync_overflow" in s.roles:
        caps.append("SYNC counter 0x1019")
    if isinstance(co.get("save"), dict):
        caps.append(f"save {co['save'].get('object')}")
    objects = co.get("objects", {}) if isinstance(co.get("objects"), dict) else {}
    if "table" in objects:
        caps.append("drive-buffered table/capture")
    if "sample_counter" in objects:
        caps.append("hilident counters")
    return caps, modes, channels
