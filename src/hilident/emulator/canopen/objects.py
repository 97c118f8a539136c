"""The emulated CANopen drive's object dictionary as stored: values, defaults, scalings, unset objects.

:class:`ObjectStore` reads what the host wrote or the EDS declares, without the
live callbacks; it knows each role's SI scaling and how a sampled signal is
encoded in its object's type, and what a drive answers for an object that was
never written and has no default.
"""

from __future__ import annotations

import math

import numpy as np
from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.roles import COLUMN_OF_ROLE
from hilident.errors import ConfigError, DataError
from hilident.protocol.canopen_objects import (
    DOMAIN,
    REAL32,
    CanopenDescription,
    numpy_type,
)
from hilident.protocol.canopen_types import ObjectAddress, parse_address

__all__ = ["ObjectStore", "hold_values"]

_TEXT_TYPES = (0x09, 0x0B)  # VISIBLE_STRING, UNICODE_STRING: served from a str
_OCTET_TYPES = (0x0A, DOMAIN)  # OCTET_STRING, DOMAIN: served from bytes
_OBJECT_DOES_NOT_EXIST = 0x06020000


class ObjectStore:
    """Stored values and scalings of one drive's object dictionary.

    Parameters
    ----------
    node : canopen.LocalNode
        The node whose data store holds what the host wrote.
    desc : CanopenDescription
        The driver's object roles.
    name : str
        The driver's name (the device name of last resort).
    columns : dict
        ``DriveLoop.CHANNELS`` name -> row column.

    Attributes
    ----------
    rated_torque_nm, rated_current_a : float
        The references of per-thousand torque and current objects.
    scales : dict
        Role -> SI per object unit, for every role the drive can scale.
    """

    def __init__(self, node, desc: CanopenDescription, name: str, columns: dict[str, int]):
        self.node = node
        self.od = node.object_dictionary
        self.desc = desc
        self.name = name
        self.columns = columns
        self._codecs: dict = {}
        try:
            self.rated_torque_nm = desc.rated_torque(self._reference("rated_torque"))
        except DataError:
            self.rated_torque_nm = 0.0  # no torque objects to scale
        self.rated_current_a = desc.rated_current(self._reference("rated_current"))
        self.scales = {}
        for role in desc.objects:
            try:
                self.scales[role] = desc.scale(role, self.rated_torque_nm, self.rated_current_a)
            except DataError:
                pass  # a torque or current object without its reference: the drive cannot be asked for it

    def _reference(self, role: str) -> float | None:
        return float(self.default(self.desc.address(role))) if self.desc.has(role) else None

    def variable(self, addr: ObjectAddress):
        obj = self.od.get_variable(addr.index, addr.subindex)
        if obj is None:
            raise SdoAbortedError(_OBJECT_DOES_NOT_EXIST)
        return obj

    def stored(self, index: int, sub: int):
        """Value of an object as stored (written or EDS default), without live callbacks."""
        obj = self.variable(ObjectAddress(index, sub))
        try:
            raw = self.node.data_store[index][sub]
        except KeyError:
            value = obj.value if obj.value is not None else obj.default
            return 0 if value is None else value
        return obj.decode_raw(raw)

    def default(self, addr: ObjectAddress):
        return self.stored(addr.index, addr.subindex)

    def unset_value(self, index: int, subindex: int, od):
        """The answer for an object never written whose EDS entry has no default (None: canopen serves it).

        A drive answers every readable object: the identity from the EDS's
        [DeviceInfo], some text, one zero byte, or 0. An empty string or octet
        string cannot be uploaded (SDO abort 0x08000024); a drive says something.
        """
        declared = od.value if od.value is not None else od.default
        sized = od.data_type in _TEXT_TYPES or od.data_type in _OCTET_TYPES
        if subindex in self.node.data_store.get(index, {}) or (declared is not None and not (sized and not declared)):
            return None
        info = self.od.device_information
        identity = {(0x1018, 1): info.vendor_number, (0x1018, 2): info.product_number}.get((index, subindex))
        if identity:
            return int(identity)
        if (index, subindex) == (0x1008, 0):
            return info.product_name or self.name
        if od.data_type in _TEXT_TYPES:
            return "n/a"
        return b"\0" if od.data_type in _OCTET_TYPES else 0

    def sampled(self, role: str, addr: ObjectAddress, row) -> float | int:
        """Raw value of the sampled object ``addr`` (role ``role``) for the drive loop row ``row``."""
        column, scale, lo, hi = self._scalar_codec(role, addr)
        x = float(row[column])
        if scale is None:
            return x  # REAL32
        v = x / scale
        if not math.isfinite(v):
            return 0
        return min(max(round(v), lo), hi)  # as encode_si: half to even, clipped to the type

    def _scalar_codec(self, role: str, addr: ObjectAddress):
        """(row column, SI per unit or None for REAL32, type minimum, type maximum) of a sampled object."""
        codec = self._codecs.get(addr)
        if codec is None:
            obj = self.variable(addr)
            column = self.columns[COLUMN_OF_ROLE[role]]
            if obj.data_type == REAL32:
                codec = (column, None, 0, 0)
            else:
                info = np.iinfo(numpy_type(obj.data_type))
                codec = (column, self.scales[role], int(info.min), int(info.max))
            self._codecs[addr] = codec
        return codec


def hold_values(node, od, values, source: str) -> None:
    """The driver's ``[emulator] values``: what the twin's drive holds in objects whose EDS gives no default
    (``{ "0x6065" = 100000 }``), as if set in the drive before the host connects.

    Raises
    ------
    ConfigError
        Naming ``emulator.values`` and ``source``: not a table, an object the EDS does not have, or a value its
        type cannot hold.
    """
    if values is None:
        return
    if not isinstance(values, dict):
        raise ConfigError("emulator.values", 'must be a table of "0xIIII[:SS]" = value', source)
    for key, value in values.items():
        addr = parse_address(key, "emulator.values", source)
        var = od.get_variable(addr.index, addr.subindex)
        if var is None:
            raise ConfigError("emulator.values", f"{addr} is not in the EDS", source)
        try:
            raw = var.encode_raw(value)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ConfigError("emulator.values", f"{addr} ({var.name}) cannot hold {value!r}: {exc}", source) from None
        node.data_store.setdefault(addr.index, {})[addr.subindex] = raw
