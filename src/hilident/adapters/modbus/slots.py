"""Filter slots of a Modbus drive: a notch written as registers or parameters, read back, saved, restored.

:class:`ModbusFilterSlots` is a part :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter` owns (its
``slots``); its requests go through the request part (:class:`~hilident.adapters.modbus.requests.RegisterAccess`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from hilident.adapters.modbus.common import ModbusIdentity
from hilident.adapters.modbus.requests import RegisterAccess
from hilident.errors import DataError, DeviceError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol.filter_encoding import FilterEncoding, Realisation
from hilident.protocol.modbus.filter_slots import FieldSlots
from hilident.protocol.modbus.filter_slots import FourRegisterSlots as RegisterSlots
from hilident.protocol.modbus.registers import Register

#: A slot's contents as :meth:`ModbusFilterSlots.read_raw` keeps them: the register block's words, or a parameter
#: drive's ``(field, stored integer)`` pairs.
SavedSlot = tuple[int, ...] | tuple[tuple[str, int], ...]


def _saved_words(saved: SavedSlot) -> list[int]:
    """The words of a register block's saved slot."""
    words = [w for w in saved if isinstance(w, int)]
    if len(words) != len(saved):
        raise DataError("a saved filter slot of a register block holds its registers' words")
    return words


def _saved_fields(saved: SavedSlot) -> dict[str, int]:
    """The stored integer of each field of a parameter drive's saved slot."""
    pairs = [pair for pair in saved if isinstance(pair, tuple)]
    if len(pairs) != len(saved):
        raise DataError("a saved filter slot of a parameter drive holds (field, stored integer) pairs")
    return dict(pairs)


class ModbusFilterSlots:
    """The filter slots of a Modbus drive (the ``slots`` of
    :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter`).

    A slot is either a register block of the map or a set of parameters (a parameter
    drive); both are written disabled, read back and compared before they are enabled.

    Parameters
    ----------
    registers : RegisterAccess
        The requests (and the map, port and driver they name).
    identity : callable
        The drive's identity as read at connect (its loop rate); DeviceError before.
    """

    def __init__(self, registers: RegisterAccess, identity: Callable[[], ModbusIdentity]):
        self.registers = registers
        self.map = registers.map
        self.port = registers.port
        self.driver = registers.driver
        self.identity = identity

    def _register_slots(self) -> RegisterSlots:
        """The slots as a block of registers; DeviceError when the map describes no such block."""
        fs = self.map.filters
        if not isinstance(fs, RegisterSlots):
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no filter slots in registers")
        return fs

    def _slot(self, slot: int) -> int:
        try:
            return self._register_slots().address(slot)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {exc}") from None

    def _encoding(self) -> FilterEncoding:
        """How the drive stores a notch; DeviceError when the driver describes no filter encoding."""
        if self.map.filter_encoding is None:
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no filter encoding")
        return self.map.filter_encoding

    # Filter slots of named registers (a parameter drive's notch parameters): each field is one register
    # holding the encoding's stored integer; the slot is bypassed by its enable register or by the "off"
    # value of one field.

    @property
    def parameter_slots(self) -> bool:
        """Whether the filter slots are the drive's notch parameters (:meth:`filter_parameters` reports them)."""
        return self._field_slots() is not None

    def _field_slots(self) -> FieldSlots | None:
        """The slots when they are named registers (a parameter drive's notch parameters), else None."""
        fs = self.map.filters
        return fs if isinstance(fs, FieldSlots) else None

    def _named_slots(self) -> FieldSlots:
        """The slots as named registers; DeviceError when the map describes them otherwise, or none."""
        fs = self._field_slots()
        if fs is None:
            raise DeviceError(
                f"{self.port}: driver {self.driver.name!r} describes no filter slots of named "
                "registers (notch parameters)"
            )
        return fs

    def _fields(self, slot: int) -> dict[str, Register]:
        fs = self._named_slots()
        try:
            return fs.fields(slot)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {exc}") from None

    def _read_fields(self, slot: int) -> dict[str, int]:
        """The stored integer of each field of ``slot`` (one request for neighbouring registers)."""
        regs = self._fields(slot)
        values = self.registers.read_names(*(r.name for r in regs.values()))
        return {f: int(round((float(values[r.name]) - r.offset) / r.scale)) for f, r in regs.items()}

    def _write_fields(self, slot: int, stored: Mapping[str, int | float | bytes]) -> None:
        regs = self._fields(slot)
        physical = {}
        for name, value in stored.items():
            if isinstance(value, bytes):  # a word block's raw words: no register of a named slot holds one
                raise DataError(
                    f"{self.port}: filter slot {slot} field {name!r} is raw words; a parameter "
                    "drive's slot holds numbers"
                )
            physical[regs[name].name] = value * regs[name].scale + regs[name].offset
        self.registers.write_names(**physical)

    def _slot_state(self, stored: dict[str, int]) -> tuple[dict[str, int], bool]:
        """``(encoding values, enabled)`` of a named slot's stored integers."""
        values = {k: v for k, v in stored.items() if k != "enable"}
        if "enable" in stored:
            return values, bool(stored["enable"])
        return values, not all(values.get(k) == v for k, v in self._named_slots().off.items())

    def _realise(self, spec: NotchSpec | None) -> Realisation:
        if spec is None:
            raise DeviceError(f"{self.port}: the drive takes notch parameters; no notch specification was given")
        encoding = self._encoding()
        try:
            return encoding.realise(spec, self.identity().loop_rate_hz)
        except DataError as exc:
            raise DeviceError(
                f"{self.port}: the drive's {encoding.kind} filter parameters cannot "
                f"hold the {spec.center_hz:.4g} Hz notch: {exc}"
            ) from None

    def filter_parameters(self, slot: int) -> dict:
        """What a parameter drive's slot holds, for a report: each field's register, parameter code and stored
        integer, whether it is enabled, and the notch (centre, width, depth) the values stand for."""
        regs = self._fields(slot)
        stored = self._read_fields(slot)
        values, enabled = self._slot_state(stored)
        out: dict[str, object] = {
            "slot": slot,
            "enabled": enabled,
            "fields": {
                f: {"register": regs[f].name, "parameter": regs[f].parameter, "address": regs[f].address, "value": v}
                for f, v in stored.items()
            },
        }
        if enabled:
            try:
                spec = self._encoding().parameters(values)
                out["notch"] = {"center_hz": spec.center_hz, "width_hz": spec.width_hz, "depth_db": spec.depth_db}
            except DataError as exc:
                out["notch_error"] = str(exc)
        return out

    def planned_parameters(self, slot: int, spec: NotchSpec) -> dict:
        """What a parameter drive's ``slot`` will hold for ``spec``: each field's register, parameter code and
        the integer the drive's steps give (what ``hilident upload --dry-run`` shows)."""
        regs = self._fields(slot)
        return {
            f: {"register": regs[f].name, "parameter": regs[f].parameter, "value": v}
            for f, v in self._realise(spec).fields.items()
        }

    def filter_notes(self, spec: NotchSpec) -> tuple[str, ...]:
        """Why a parameter drive's notch parameters cannot meet ``spec`` exactly, if they cannot."""
        return self._realise(spec).notes if self.parameter_slots else ()

    @property
    def bypassed_by_a_field(self) -> bool:
        """Whether a slot is bypassed by the "off" value of one of its fields (a parameter drive's notch without
        an enable): :meth:`read_back_bypassed` checks such a slot written bypassed."""
        fs = self._field_slots()
        return fs is not None and not fs.has_enable

    def read_back_bypassed(self, slot: int, spec: NotchSpec | None) -> tuple[Biquad, bool]:
        """A slot bypassed by the "off" value of a field, after the notch ``spec`` was written bypassed: the
        identity section it applies, and whether its other fields read back as written."""
        fs = self._named_slots()
        values = self._realise(spec).fields
        back, enabled = self._slot_state(self._read_fields(slot))
        same = not enabled and all(back[k] == v for k, v in values.items() if k not in fs.off)
        return Biquad.identity(), same

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None, enabled: bool) -> None:
        """Store a notch in a slot as the drive takes it: centre, width, depth (scaled integers), enable.

        A parameter drive's slot gets the stored values closest to ``spec``
        (:meth:`FilterEncoding.realise`), bypassed by its off value when not ``enabled``.
        """
        fs = self._field_slots()
        if fs is not None:
            stored: dict[str, int | float | bytes] = dict(self._realise(spec).fields)
            if fs.has_enable:
                stored["enable"] = int(bool(enabled))
            elif not enabled:
                stored.update(fs.off)
            self._write_fields(slot, stored)
            return
        values = self._encoding().encode(biquad, spec)
        self.registers.write(self._slot(slot), self.map.encode_filter(values, enabled), f"writing filter slot {slot}")

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad the slot's registers make the drive run, and whether it is enabled.

        A parameter drive's slot bypassed by an off value runs the identity section.
        """
        fs = self._field_slots()
        if fs is not None:
            values, enabled = self._slot_state(self._read_fields(slot))
            if not enabled and not fs.has_enable:
                return Biquad.identity(), False
            try:
                return self._encoding().applied(values, self.identity().loop_rate_hz), enabled
            except DataError as exc:
                regs = self._fields(slot)
                raise DeviceError(
                    f"{self.port}: filter slot {slot} ({', '.join(r.label for r in regs.values())}) "
                    f"holds {values}: {exc}"
                ) from None
        address = self._slot(slot)
        span = self._register_slots().span
        words, enabled = self.map.decode_filter(self.registers.read(address, span, f"reading filter slot {slot}"))
        if not any(words.values()):
            return Biquad.identity(), enabled  # an empty slot passes the torque through
        try:
            return self._encoding().applied(words, self.identity().loop_rate_hz), enabled
        except DataError as exc:
            raise DeviceError(
                f"{self.port}: filter slot {slot} ({self.map.describe(address, span)}) holds {words}: {exc}"
            ) from None

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None) -> Biquad:
        """The biquad the drive runs after its own rounding of ``spec`` (0.1 Hz, 0.1 dB steps), or what a
        parameter drive runs with the stored values closest to ``spec``."""
        if self.parameter_slots:
            return self._realise(spec).section
        return self._encoding().stored_form(biquad, spec, self.identity().loop_rate_hz)

    def read_raw(self, slot: int) -> SavedSlot:
        """The slot's registers as they are (a parameter drive: its fields' stored integers, by name)."""
        if self.parameter_slots:
            return tuple(sorted(self._read_fields(slot).items()))
        return tuple(self.registers.read(self._slot(slot), self._register_slots().span, f"reading filter slot {slot}"))

    def write_raw(self, slot: int, saved: SavedSlot) -> None:
        """Put back what :meth:`read_raw` returned."""
        if self.parameter_slots:
            self._write_fields(slot, _saved_fields(saved))
            return
        self.registers.write(self._slot(slot), _saved_words(saved), f"restoring filter slot {slot}")

    def bypass(self, slot: int) -> None:
        """Bypass a slot: its enable register to 0, centre, width and depth kept (:meth:`write_raw` undoes it).

        A parameter drive's slot without an enable gets its off value, the other fields kept.
        """
        fs = self._field_slots()
        if fs is not None:
            self._write_fields(slot, {"enable": 0} if fs.has_enable else dict(fs.off))
            return
        self.registers.write(
            self._slot(slot) + self._register_slots().offsets["enable"], [0], f"disabling filter slot {slot}"
        )
