"""Where a Modbus drive keeps its filter slots: hilident's four-register slots, or a vendor's notch parameters.

:class:`FourRegisterSlots` (``[modbus.filters] base``, ``stride`` and offsets)
are blocks of four registers, center, width, depth and enable, one block per
slot. :class:`FieldSlots` (``[modbus.filters] slots``) name, per slot, the
registers of the map that hold each field of the drive's own notch parameters.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hilident.errors import DataError

__all__ = ["FILTER_FIELDS", "FieldSlots", "FourRegisterSlots"]

#: The fields of a four-register slot, each one register.
FILTER_FIELDS = ("center", "width", "depth", "enable")


@dataclass(frozen=True)
class FourRegisterSlots:
    """hilident's four-register filter slots: field ``f`` of slot ``i`` at register ``base + i * stride + offsets[f]``.

    The fields are center, width, depth and enable (:data:`FILTER_FIELDS`), contiguous in some order.
    """

    base: int
    stride: int
    slots: int
    offsets: dict[str, int] = field(default_factory=dict)

    @property
    def span(self) -> int:
        """Registers read or written per slot (the four fields, contiguous)."""
        return len(FILTER_FIELDS)

    def address(self, slot: int) -> int:
        if not 0 <= slot < self.slots:
            raise DataError(f"filter slot {slot} does not exist (the drive has {self.slots})")
        return self.base + slot * self.stride

    def slot_at(self, address: int) -> int | None:
        """Slot whose field registers contain ``address``, else None."""
        if address < self.base:
            return None
        slot, offset = divmod(address - self.base, self.stride)
        return slot if slot < self.slots and offset < self.span else None

    @property
    def end(self) -> int:
        return self.base + (self.slots - 1) * self.stride + self.span if self.slots else self.base


@dataclass(frozen=True)
class FieldSlots:
    """Filter slots whose fields are named registers of the map (a vendor's notch parameters).

    Attributes
    ----------
    registers : tuple of dict
        Per slot, field name (``center``, ``width``, ``depth``, ... of the
        encoding, and ``enable`` when the drive has one) to its
        :class:`~hilident.protocol.modbus.registers.Register`.
    off : dict
        Drives without an enable register: the field and stored integer that
        bypass the slot (``{"center": 4000}``); the other fields keep their values.
    """

    registers: tuple
    off: dict = field(default_factory=dict, hash=False, compare=False)

    @property
    def slots(self) -> int:
        return len(self.registers)

    @property
    def has_enable(self) -> bool:
        return bool(self.registers) and "enable" in self.registers[0]

    def fields(self, slot: int) -> dict:
        """Field name to :class:`~hilident.protocol.modbus.registers.Register` of ``slot``.

        Raises
        ------
        DataError
            There is no such slot.
        """
        if not 0 <= slot < self.slots:
            raise DataError(f"filter slot {slot} does not exist (the drive has {self.slots})")
        return self.registers[slot]

    def address(self, slot: int) -> int:
        """The lowest address of the slot's fields."""
        return min(r.address for r in self.fields(slot).values())

    def slot_at(self, address: int) -> int | None:
        for i, regs in enumerate(self.registers):
            if any(r.address <= address < r.end for r in regs.values()):
                return i
        return None
