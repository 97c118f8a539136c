"""``drivers check`` of a CANopen driver's ``[filters]`` table: every slot's objects against the EDS.

The table is read as ``hilident run`` reads it (the encoding with
:meth:`FilterEncoding.from_table`, the objects with
:func:`~hilident.protocol.canopen_filters.parse_filter_objects`); then each
object the host writes is looked up in the EDS: it exists, the host may write
and read it, its type holds what the encoding writes there (a REAL32 field, an
integer field, a word block in an OCTET_STRING or DOMAIN of ``2 * words`` bytes
where the EDS gives a default) and an enable object takes the values the table
switches it with. Nothing is asked that the encoding does not use: a word
block carries its own enable. A refusal names the ``[filters]`` key and the
object.
"""

from __future__ import annotations

from hilident.errors import ConfigError
from hilident.protocol import eds as E
from hilident.protocol.canopen_filters import ENABLED, FilterObjects, parse_filter_objects
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = ["filter_key", "filter_problems", "show_address"]

_OCTETS = (0x0A, 0x0F)  # OCTET_STRING, DOMAIN
_FLOATS = (0x08, 0x11)  # REAL32, REAL64
#: CiA 301 integer types an enable or an integer field may be, and the values each holds.
_INTEGERS = {
    0x01: (0, 1),
    0x02: (-(2**7), 2**7 - 1),
    0x03: (-(2**15), 2**15 - 1),
    0x04: (-(2**31), 2**31 - 1),
    0x15: (-(2**63), 2**63 - 1),
    0x05: (0, 2**8 - 1),
    0x06: (0, 2**16 - 1),
    0x07: (0, 2**32 - 1),
    0x1B: (0, 2**64 - 1),
}


def filter_problems(data: dict, od) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """Errors and warnings of the ``[filters]`` table of a parsed ``driver.toml`` against its EDS.

    Parameters
    ----------
    data : dict
        The parsed ``driver.toml``.
    od : canopen.ObjectDictionary
        Its EDS.

    Returns
    -------
    errors, warnings : list of (key, text)
        ``key`` is the dotted ``filters.`` key at fault.
    """
    table = data.get("filters")
    if not isinstance(table, dict) or "encoding" not in table:
        return [], []
    try:
        encoding = FilterEncoding.from_table(table)
        fo = parse_filter_objects(table)
    except ConfigError as exc:
        return [(exc.key, exc.message)], []
    if fo is None:
        return [], []
    errors: list[tuple[str, str]] = []
    errors += _slot_count_problems(data, fo)
    for slot in range(fo.count):
        for name in encoding.fields:
            if name not in fo.slots[slot]:
                errors.append((f"filters.fields.{name}", f"is not given: the {encoding.kind} encoding writes it"))
                continue
            errors += _field_problems(table, fo, slot, name, encoding, od)
        errors += _enable_problems(table, fo, slot, encoding, od)
    extra = sorted(set(fo.slots[0]) - set(encoding.fields))
    warnings = [(f"filters.fields.{n}", f"is no field of the {encoding.kind} encoding; not written") for n in extra]
    return _unique(errors), warnings


def _unique(items: list) -> list:
    return list(dict.fromkeys(items))


def _slot_count_problems(data: dict, fo: FilterObjects) -> list[tuple[str, str]]:
    board = data.get("board")
    slots = board.get("filter_slots", 0) if isinstance(board, dict) else 0
    if isinstance(slots, int) and slots > fo.count:
        return [("board.filter_slots", f"is {slots}, but [filters] describes the objects of {fo.count} slot(s)")]
    return []


def filter_key(table: dict, fo: FilterObjects, name: str) -> str:
    """The ``[filters]`` key that placed field ``name`` (or :data:`~hilident.protocol.canopen_filters.ENABLED`),
    for messages: ``"filters.fields.band"``, ``"filters.objects"`` (a word block), ``"filters.enable"``."""
    if name == ENABLED:
        return "filters.enable" if "enable" in table else "filters.enable_subindex"
    return "filters.objects" if fo.in_block else f"filters.fields.{name}"


def _lookup(key: str, addr, od, errors: list, write: bool = True) -> E.ObjectInfo | None:
    info = E.object_info(od, addr.index, addr.subindex)
    if info is None:
        errors.append((key, f"{show_address(addr)} is not in the EDS"))
        return None
    if write and not E.writable(info.access):
        errors.append((key, f"{show_address(addr)} ({info.name}) is {info.access!r} in the EDS; the host writes it"))
    if not E.readable(info.access):
        errors.append((key, f"{show_address(addr)} ({info.name}) is write-only in the EDS; the host reads it back"))
    return info


def show_address(addr) -> str:
    """An object as ``drivers check`` names it: ``"0x2106"``, ``"0x3406:10"``."""
    return f"0x{addr.index:04X}" + (f":{addr.subindex}" if addr.subindex else "")


def _field_problems(table: dict, fo: FilterObjects, slot: int, name: str, encoding: FilterEncoding, od) -> list:
    errors: list[tuple[str, str]] = []
    key, addr = filter_key(table, fo, name), fo.address(slot, name)
    info = _lookup(key, addr, od, errors)
    if info is None:
        return errors
    kind, what = encoding.value_kind(name), f"{show_address(addr)} ({info.name}) is {E.type_name(info.data_type)}"
    if kind == "octets":
        size = 2 * encoding.layout.words
        if info.data_type not in _OCTETS:
            errors.append((key, f"{what}; a word block of {size} bytes needs an OCTET_STRING or a DOMAIN"))
        elif isinstance(info.default, bytes) and info.default and len(info.default) != size:
            errors.append(
                (
                    key,
                    f"{what} of {len(info.default)} bytes (its EDS default); the {encoding.layout.words}-word block "
                    f"of this table is {size} bytes: check words (or preset) against the drive's manual",
                )
            )
    elif kind == "float32" and info.data_type not in _FLOATS:
        errors.append((key, f"{what}; the {encoding.kind} encoding writes a REAL32 there"))
    elif kind == "integer" and info.data_type not in _INTEGERS:
        errors.append((key, f"{what}; the {encoding.kind} encoding writes an integer there"))
    return errors


def _enable_problems(table: dict, fo: FilterObjects, slot: int, encoding: FilterEncoding, od) -> list:
    if fo.in_block:
        return []  # the block's state word is its enable
    if not fo.has_enable:
        if encoding.bypassable:
            return []
        return [("filters.enable", f'is "none", but a {encoding.kind} slot cannot be bypassed without an enable')]
    errors: list[tuple[str, str]] = []
    key, addr = filter_key(table, fo, ENABLED), fo.address(slot, ENABLED)
    info = _lookup(key, addr, od, errors)
    if info is None:
        return errors
    bounds = _INTEGERS.get(info.data_type)
    if bounds is None:
        errors.append(
            (key, f"{show_address(addr)} ({info.name}) is {E.type_name(info.data_type)}; an enable is an integer")
        )
    elif not all(bounds[0] <= v <= bounds[1] for v in (fo.enable_on, fo.enable_off)):
        errors.append(
            (
                "filters.enable_values",
                f"on = {fo.enable_on}, off = {fo.enable_off} do not fit {show_address(addr)} "
                f"({info.name}, {E.type_name(info.data_type)})",
            )
        )
    return errors
