"""Where a CANopen drive keeps its filter slots: the object of every field and of the enable, slot by slot.

Vendors lay a slot out in three ways, and the ``[filters]`` table of a driver
description says which, as the drive's manual shows it:

* **one record per slot** (``objects``, one index a slot, and ``fields``, the
  sub-index of each field; the enable at ``enable_subindex``): Synapticon's
  0x2023 (sub 1 enabled, sub 2 centre, sub 3 rejection band);
* **one octet string per slot** holding the whole section and its enable
  (``encoding = "word_block"`` and ``objects``): Copley's 0x2106, 0x2108;
* **field-major**: each field an object of its own, or a sub-index chosen per
  slot (``fields`` maps a field to a list of addresses, one a slot; the enable
  is a list of addresses too, or ``"none"``): Kollmorgen AKD's 0x3406 (ARPQ1..4
  at sub 5..8, ARZF1..4 at 9..0xC), Beckhoff AX2000's 0x3662..0x3666.

An enable may be a value of a mode or type field (Beckhoff BQMODE 2 = bi-quad,
0 = none; Ingenia TYPE 5 = notch, 0 = disabled): ``enable_values = { on = 2,
off = 0 }``. A slot with no enable (``enable = "none"``, Kollmorgen's AR
filters) runs whatever it holds.

Pure: the parsed table in, :class:`FilterObjects` out.

Examples
--------
>>> fo = parse_filter_objects({"encoding": "center_band", "objects": ["0x2023"], "fields": {"center": 2, "band": 3}})
>>> str(fo.address(0, "band")), str(fo.address(0, "enabled"))
('0x2023:3', '0x2023:1')
>>> fo = parse_filter_objects(
...     {"fields": {"pole_q": ["0x3406:5", "0x3406:6"], "zero_hz": ["0x3406:9", "0x3406:0xA"]}, "enable": "none"}
... )
>>> fo.count, fo.owner(parse_address("0x3406:0xA")), fo.has_enable
(2, (1, 'zero_hz'), False)
"""

from __future__ import annotations

from dataclasses import dataclass

from hilident.errors import ConfigError
from hilident.protocol.canopen_types import ObjectAddress, parse_address

__all__ = ["ENABLED", "FilterObjects", "parse_filter_objects"]

#: The name :meth:`FilterObjects.address` and :meth:`FilterObjects.owner` give a slot's enable.
ENABLED = "enabled"


@dataclass(frozen=True)
class FilterObjects:
    """The objects of a drive's filter slots.

    Attributes
    ----------
    slots : tuple of dict
        Per slot, field name -> the object holding it.
    enables : tuple of ObjectAddress or None
        Per slot, the object that switches it on and off; None when the slot
        keeps its enable inside its one block (``in_block``) or has none.
    in_block : bool
        The enable is the state word of a ``word_block`` (the field ``block``).
    enable_on, enable_off : int
        The values of the enable object that run and bypass the slot.
    """

    slots: tuple[dict[str, ObjectAddress], ...]
    enables: tuple[ObjectAddress, ...] | None = None
    in_block: bool = False
    enable_on: int = 1
    enable_off: int = 0

    @property
    def count(self) -> int:
        """Slots described."""
        return len(self.slots)

    @property
    def has_enable(self) -> bool:
        """The slot has an enable object of its own (not inside a block, not none)."""
        return self.enables is not None

    def address(self, slot: int, name: str) -> ObjectAddress:
        """The object of field ``name`` (or :data:`ENABLED`) of filter slot ``slot``.

        Raises
        ------
        ConfigError
            ``name`` is the enable of a slot that has no enable object.
        """
        if name != ENABLED:
            return self.slots[slot][name]
        if self.enables is None:
            raise ConfigError("filters.enable", "this drive's slots have no enable object of their own")
        return self.enables[slot]

    def owner(self, addr: ObjectAddress) -> tuple[int, str] | None:
        """(slot, field name or :data:`ENABLED`) of the object ``addr``; None when it is no filter object."""
        for slot, fields in enumerate(self.slots):
            for name, a in fields.items():
                if a == addr:
                    return slot, name
            if self.enables is not None and self.enables[slot] == addr:
                return slot, ENABLED
        return None

    def where(self, slot: int) -> str:
        """The objects of ``slot``, for messages (``"0x2106"``, ``"0x3406:5, 0x3406:9, ..."``)."""
        addrs = list(self.slots[slot].values()) + ([self.enables[slot]] if self.enables is not None else [])
        indices = {a.index for a in addrs}
        if len(indices) == 1 and all(a.subindex == 0 for a in addrs):
            return f"object 0x{addrs[0].index:04X}"
        return "objects " + ", ".join(str(a) for a in addrs)


def parse_filter_objects(table, source: str = "") -> FilterObjects | None:
    """The slots' objects of a ``[filters]`` table; None when it names none (no filter objects described).

    Parameters
    ----------
    table : dict or None
        The parsed ``[filters]`` table.
    source : str
        The driver description's path, for messages.

    Raises
    ------
    ConfigError
        ``objects``, ``fields``, ``enable``, ``enable_subindex`` or ``enable_values`` is malformed; the
        message names the key.
    """
    if not isinstance(table, dict) or not _describes_objects(table):
        return None
    indices = _indices(table, source)
    block = table.get("encoding") == "word_block"
    fields = table.get("fields", {"block": 0} if block else None)
    if not isinstance(fields, dict) or not fields:
        raise ConfigError(
            "filters.fields",
            "must map each field to its sub-index ({ b0 = 2, ... }) or to its objects, one a slot "
            '({ pole_q = ["0x3406:5", "0x3406:6"], ... })',
            source,
        )
    count = _slot_count(fields, indices, source)
    slots = tuple(
        {name: _field_address(name, where, indices, slot, source) for name, where in fields.items()}
        for slot in range(count)
    )
    if block:
        if set(fields) != {"block"}:
            raise ConfigError("filters.fields", f"a word_block slot is one field, block, got {sorted(fields)}", source)
        return FilterObjects(slots, None, in_block=True)
    on, off = _enable_values(table.get("enable_values", {"on": 1, "off": 0}), source)
    enables = _enables(table, fields, indices, count, source)
    _distinct(slots, enables, source)
    return FilterObjects(slots, enables, enable_on=on, enable_off=off)


def _distinct(slots: tuple[dict[str, ObjectAddress], ...], enables, source: str) -> None:
    """No object holds two fields, or a field and an enable (a slot written there would lose one of them)."""
    seen: dict[ObjectAddress, str] = {}
    for slot, fields in enumerate(slots):
        named = [(f"fields.{n}", a) for n, a in fields.items()] + ([("enable", enables[slot])] if enables else [])
        for key, addr in named:
            if addr in seen:
                raise ConfigError(
                    f"filters.{key}",
                    f"{addr} holds {seen[addr]} already (slot {slot}): every field and enable needs its own object",
                    source,
                )
            seen[addr] = key


def _describes_objects(table: dict) -> bool:
    """``objects``, or a field given as a list of addresses (field-major)."""
    fields = table.get("fields")
    return "objects" in table or (isinstance(fields, dict) and any(isinstance(v, list) for v in fields.values()))


def _indices(table: dict, source: str) -> tuple[int, ...] | None:
    if "objects" not in table:
        return None
    objects = table["objects"]
    if not isinstance(objects, list) or not objects:
        raise ConfigError("filters.objects", "must be a list of object indices, one a slot", source)
    return tuple(parse_address(x, "filters.objects", source).index for x in objects)


def _slot_count(fields: dict, indices: tuple[int, ...] | None, source: str) -> int:
    """Slots the table describes: ``objects``' length, else the length of the fields' address lists."""
    lengths = {len(v) for v in fields.values() if isinstance(v, list)}
    if indices is not None:
        lengths.add(len(indices))
    if len(lengths) != 1 or 0 in lengths:
        raise ConfigError(
            "filters.fields",
            "every field needs one object a slot: the lists of addresses (and objects) must have one length, "
            f"got lengths {sorted(lengths)}",
            source,
        )
    return lengths.pop()


def _field_address(name: str, where, indices, slot: int, source: str) -> ObjectAddress:
    """Field ``name`` of ``slot``: a sub-index of ``objects[slot]``, or the slot's entry of its address list."""
    key = f"filters.fields.{name}"
    if isinstance(where, list):
        return parse_address(where[slot], key, source)
    if not (isinstance(where, int) and not isinstance(where, bool) and 0 <= where < 256):
        raise ConfigError(
            key, f'must be a sub-index 0..255 or a list of addresses like "0x3406:5", got {where!r}', source
        )
    if indices is None:
        raise ConfigError(
            key, f"sub-index {where} of which object? give objects = [...] or a list of addresses", source
        )
    return ObjectAddress(indices[slot], where)


def _enables(table: dict, fields: dict, indices, count: int, source: str) -> tuple[ObjectAddress, ...] | None:
    """The slots' enable objects: ``enable`` (a list of addresses, or "none"), else ``enable_subindex``."""
    if "enable" in table:
        enable = table["enable"]
        if enable == "none":
            return None
        if not isinstance(enable, list) or len(enable) != count:
            raise ConfigError(
                "filters.enable", f'must be "none" or a list of {count} addresses (one a slot), got {enable!r}', source
            )
        return tuple(parse_address(x, "filters.enable", source) for x in enable)
    sub = table.get("enable_subindex", 1)
    taken = {v for v in fields.values() if isinstance(v, int)}
    if not (isinstance(sub, int) and not isinstance(sub, bool)) or not 0 < sub < 256 or sub in taken:
        raise ConfigError("filters.enable_subindex", f"must be a free sub-index 1..255, got {sub!r}", source)
    if indices is None:
        raise ConfigError(
            "filters.enable", 'field-major slots need enable = ["0x....", ...] or enable = "none"', source
        )
    return tuple(ObjectAddress(i, sub) for i in indices)


def _enable_values(values, source: str) -> tuple[int, int]:
    ok = isinstance(values, dict) and set(values) == {"on", "off"}
    ok = ok and all(isinstance(v, int) and not isinstance(v, bool) for v in values.values())
    if not ok or values["on"] == values["off"]:
        raise ConfigError(
            "filters.enable_values", f"must be {{ on = <int>, off = <int> }}, two values, got {values!r}", source
        )
    return values["on"], values["off"]
