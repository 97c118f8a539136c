"""Filter slots of a CANopen drive: notch coefficients written, read back, saved and restored by SDO.

:class:`CanopenFilterSlots` is a part :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` owns (its
``slots``); the adapter's filter-slot hooks and ``save_parameters`` hand their work to it.
"""

from __future__ import annotations

from collections.abc import Callable

from hilident.adapters.canopen.common import (
    STORE_SIGNATURE,
    DriveIdentity,
)
from hilident.adapters.canopen.sdo import SdoAccess
from hilident.drivers.description import DriverDescription
from hilident.errors import DataError, DeviceError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol.canopen_filters import ENABLED, FilterObjects
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.canopen_types import parse_address
from hilident.protocol.filter_encoding import FilterEncoding, Realisation


class CanopenFilterSlots:
    """The filter slots of a CANopen drive (the ``slots`` of
    :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`).

    Slots are described by the driver's filter objects and encoding; :meth:`save_parameters`
    stores them in non-volatile memory where the drive has 0x1010.

    Parameters
    ----------
    sdo : SdoAccess
        The drive's objects.
    desc : CanopenDescription
        The drive's filter objects (``filters``), its objects by role and its EDS file name.
    driver : DriverDescription
        The driver (its name and folder for messages, its ``[canopen.save]`` table).
    encoding : FilterEncoding or None
        How the drive stores a notch; None: the driver describes no filter objects.
    identity : callable
        The drive's identity as read at connect (its filter slots, its loop rate); DeviceError before.
    port : str
        Where the drive is; used in messages.
    """

    def __init__(
        self,
        sdo: SdoAccess,
        desc: CanopenDescription,
        driver: DriverDescription,
        encoding: FilterEncoding | None,
        identity: Callable[[], DriveIdentity],
        port: str,
    ):
        self.sdo = sdo
        self.desc = desc
        self.driver = driver
        self.encoding = encoding
        self.identity = identity
        self.port = port

    def _slot_objects(self) -> tuple[FilterObjects, FilterEncoding]:
        """The driver's filter objects and their encoding; DeviceError when it describes none."""
        fo, encoding = self.desc.filters, self.encoding
        if fo is None or encoding is None:
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no filter objects")
        return fo, encoding

    def _filter_slot(self, slot: int) -> tuple[FilterObjects, FilterEncoding]:
        """The filter objects and encoding of ``slot``; DeviceError for a slot the drive does not have."""
        fo, encoding = self._slot_objects()
        slots = self.identity().filter_slots
        if not 0 <= slot < fo.count or slot >= slots:
            raise DeviceError(f"{self.port}: filter slot {slot} (the drive has {slots})")
        return fo, encoding

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None, enabled: bool) -> None:
        """Store a notch in a slot, fitted to what the drive's encoding can hold; it takes effect when enabled.

        With ``spec`` the notch is realised in the encoding (the stored values
        closest to it, :meth:`FilterEncoding.realise`); without, ``biquad`` is
        rounded to the encoding.
        """
        fo, encoding = self._filter_slot(slot)
        values = self._realise(spec).fields if spec is not None else encoding.encode(biquad, spec)
        self._write_slot(fo, encoding, slot, values, enabled)

    def _realise(self, spec: NotchSpec) -> Realisation:
        """``spec`` realised in the drive's encoding at its filter rate; DeviceError when the slots cannot hold it."""
        _, encoding = self._slot_objects()
        try:
            return encoding.realise(spec, self.identity().loop_rate_hz)
        except DataError as exc:
            raise DeviceError(
                f"{self.port}: the drive's {encoding.kind} filter slots cannot hold the "
                f"{spec.center_hz:.4g} Hz notch: {exc}"
            ) from None

    def filter_notes(self, spec: NotchSpec) -> tuple[str, ...]:
        """Why the drive's encoding cannot meet ``spec`` exactly (depth or width out of reach), if it cannot."""
        return self._realise(spec).notes

    def _write_slot(self, fo: FilterObjects, encoding: FilterEncoding, slot: int, values: dict, enabled: bool) -> None:
        """Write a slot's values and its enable (a block: its state word; no enable: the values run at once)."""
        if fo.in_block:
            block = values if enabled else self._slot_call(fo, slot, encoding.disabled, values)
            self.sdo.write_object(fo.address(slot, "block"), block["block"])
            return
        for name, value in values.items():
            self.sdo.write_object(fo.address(slot, name), value)
        if fo.has_enable:
            self.sdo.write_object(fo.address(slot, ENABLED), fo.enable_on if enabled else fo.enable_off)

    def _read_fields(self, fo: FilterObjects, encoding: FilterEncoding, slot: int) -> tuple[dict, object]:
        """A slot's field values, and what its enable object holds (None: it has none of its own)."""
        values = {name: self.sdo.read_object(fo.address(slot, name)) for name in encoding.fields}
        found = self.sdo.read_object(fo.address(slot, ENABLED)) if fo.has_enable else None
        return values, found

    def _read_slot(self, fo: FilterObjects, encoding: FilterEncoding, slot: int) -> tuple[dict, bool]:
        """A slot's values and whether it runs (a slot without an enable always runs what it holds)."""
        values, found = self._read_fields(fo, encoding, slot)
        if fo.in_block:
            return values, bool(self._slot_call(fo, slot, encoding.slot_enabled, values))
        return values, found is None or found == fo.enable_on

    def _slot_call(self, fo: FilterObjects, slot: int, call, *args):
        """``call(*args)`` on the slot's values; a DataError becomes a DeviceError naming the port and objects."""
        try:
            return call(*args)
        except DataError as exc:
            raise DeviceError(f"{self.port}: filter slot {slot} ({fo.where(slot)}): {exc}") from None

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad the slot applies, rebuilt from the values read from the drive."""
        fo, encoding = self._filter_slot(slot)
        values, enabled = self._read_slot(fo, encoding, slot)
        if fo.in_block:  # a block read back disabled: what it holds, as it would run
            values = self._slot_call(fo, slot, encoding.enabled, values)
        return self._slot_call(fo, slot, encoding.applied, values, self.identity().loop_rate_hz), enabled

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None) -> Biquad:
        """What the drive will run once :meth:`write_filter` stored ``biquad``/``spec``."""
        if spec is not None:
            return self._realise(spec).section
        _, encoding = self._slot_objects()
        return encoding.stored_form(biquad, spec, self.identity().loop_rate_hz)

    def read_raw(self, slot: int) -> tuple[dict, bool]:
        """The slot's raw field values and whether it runs; a slot with an enable object of its own also keeps
        the enable's value under :data:`ENABLED` (a mode such as the PID-T2 of a BQMODE is neither on nor off,
        and a restore puts it back as it was)."""
        fo, encoding = self._filter_slot(slot)
        if not fo.has_enable:
            return self._read_slot(fo, encoding, slot)
        values, found = self._read_fields(fo, encoding, slot)
        return {**values, ENABLED: found}, found == fo.enable_on

    def bypass(self, slot: int) -> None:
        """Bypass a slot: its enable off, or its block's state word to bypass (the coefficients stay stored); a
        slot without an enable gets the encoding's neutral values (:meth:`FilterEncoding.neutral`)."""
        fo, encoding = self._filter_slot(slot)
        if fo.in_block:
            values, _ = self._read_slot(fo, encoding, slot)
            self._write_slot(fo, encoding, slot, values, False)
        elif fo.has_enable:
            self.sdo.write_object(fo.address(slot, ENABLED), fo.enable_off)
        else:  # no enable: the values that run the identity section
            values, _ = self._read_slot(fo, encoding, slot)
            self._write_slot(fo, encoding, slot, self._slot_call(fo, slot, encoding.neutral, values), True)

    def save_parameters(self) -> str:
        """Have the drive store its parameters in non-volatile memory (CiA 301 0x1010:1, signature "save").

        ``[canopen.save]`` in the driver description may name another object
        and value (``object = "0x2F00"``, ``value = 1``) for drives that store
        by a vendor command.

        Returns
        -------
        str
            What was written, e.g. ``"0x1010:1 (Save all parameters) = 0x65766173"``.

        Raises
        ------
        DeviceError
            The drive has no store object, or refuses the command.
        """
        table = self.driver.sections.get("canopen", {}).get("save")
        if isinstance(table, dict) and "object" in table:
            addr = parse_address(table["object"], "canopen.save.object", str(self.driver.folder / "driver.toml"))
            value = table.get("value", STORE_SIGNATURE)
        elif self.desc.has("store_parameters"):
            addr, value = self.desc.address("store_parameters"), STORE_SIGNATURE
        else:
            raise DeviceError(
                f"{self.port}: the EDS {self.desc.eds} has no store parameters object (0x1010) and the "
                "driver names none ([canopen.save] object): the drive cannot be asked to save"
            )
        self.sdo.write_object(addr, value)
        return f"{self.sdo.describe(addr)} = 0x{int(value):08X}"

    def write_raw(self, slot: int, saved: tuple[dict, bool]) -> None:
        """Put back what :meth:`read_raw` returned (a block as found; else the fields disabled, then the enable;
        a slot without an enable runs its fields as written)."""
        values, enabled = saved
        fo, encoding = self._filter_slot(slot)
        if fo.in_block:
            self.sdo.write_object(fo.address(slot, "block"), values["block"])  # the block as found, enable and all
            return
        fields = {name: value for name, value in values.items() if name != ENABLED}
        self._write_slot(fo, encoding, slot, fields, False)
        if fo.has_enable:
            found = values.get(ENABLED, fo.enable_on if enabled else fo.enable_off)
            if found != fo.enable_off:
                self.sdo.write_object(fo.address(slot, ENABLED), found)
