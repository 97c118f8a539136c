"""The emulated CANopen drive's parameters: limits, filter slots, and storing them (0x1010).

Limit objects load the drive loop's limits once every one the drive has was
written (and a position range is a range). Writing a filter slot's enable
object (or its whole block, or a field of a slot that runs: one with no enable,
or one enabled) rebuilds the slot's biquad from its stored fields with
:meth:`FilterEncoding.applied` and loads it into ``drive.filters``: the same
chain the plant sees. A word block written with another size than the drive's
is refused (SDO abort 0x06070010), as a drive refuses it.
"""

from __future__ import annotations

from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.host import FirmwareHost
from hilident.emulator.canopen.roles import LIMIT_ROLES
from hilident.emulator.canopen.sdo import ABORT_LENGTH, ABORT_TOO_LOW, ABORT_VALUE
from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.protocol.canopen_filters import ENABLED, FilterObjects
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.protocol.filter_encoding.block import encode_block

__all__ = ["DriveParameters"]

_STORE_SIGNATURE = 0x65766173  # "save" (CiA 301, 0x1010)
_ABORT_NOT_STORED = 0x08000020  # data cannot be transferred or stored (CiA 301)


class DriveParameters:
    """Limits and filter slots of one drive.

    Parameters
    ----------
    firmware : CanopenDriveFirmware
        The drive it belongs to: description, scalings, stored values, drive loop.

    Attributes
    ----------
    limits_loaded : bool
        The drive may be enabled: every limit object it has holds a valid value.
    saves : int
        Times the host had the parameters stored (0x1010:1 "save").
    stored_parameters : dict
        The filter slots as they were when last stored.
    """

    def __init__(self, firmware: FirmwareHost):
        self.fw = firmware
        self.limits_raw: dict[str, int] = {}
        # a drive with no limit object of its own can be enabled without any (the host checks the limits)
        self.limits_loaded = not any(firmware.desc.has(r) and r in firmware.scales for r in LIMIT_ROLES)
        self.saves = 0
        self.stored_parameters: dict = {}

    def store(self, value: int) -> None:
        """0x1010:1: with the signature "save" the drive keeps its parameters (here: the filter slots) as stored."""
        if value != _STORE_SIGNATURE:
            raise SdoAbortedError(_ABORT_NOT_STORED)
        self.stored_parameters = {
            slot: self.fw.drive.filters.read(slot) for slot in range(len(self.fw.drive.filters.enabled))
        }
        self.saves += 1

    def write_limit(self, role: str, raw: int) -> None:
        if role in ("max_torque", "max_velocity") and raw <= 0:
            raise SdoAbortedError(ABORT_TOO_LOW)
        self.limits_raw[role] = raw
        held = [r for r in LIMIT_ROLES if self.fw.desc.has(r) and r in self.fw.scales]
        if not all(r in self.limits_raw for r in held):
            return
        si = {r: self.limits_raw[r] * self.fw.scales[r] if r in held else None for r in LIMIT_ROLES}
        if (
            si["position_limit_min"] is not None
            and si["position_limit_max"] is not None
            and si["position_limit_min"] >= si["position_limit_max"]
        ):
            self.limits_loaded = False  # one end written, the other still to come
            return
        try:
            self.fw.drive.set_limits(
                si["max_torque"], si["max_velocity"], si["position_limit_min"], si["position_limit_max"]
            )
        except (ConfigError, ValueError):
            raise SdoAbortedError(ABORT_VALUE) from None
        self.limits_loaded = True

    def _filter_slots(self) -> tuple[FilterObjects, FilterEncoding]:
        """The filter-slot objects of the drive's description and their encoding.

        Raises
        ------
        RuntimeError
            The drive has no filter slots (the firmware routes no write here then).
        """
        fo, encoding = self.fw.desc.filters, self.fw.encoding
        if fo is None or encoding is None:
            raise RuntimeError(f"{self.fw.driver.name}: the drive has no filter slots")
        return fo, encoding

    def power_up_slots(self) -> None:
        """The filter slots as the drive powers up: each runs what its objects hold (their EDS defaults, or
        the ``[emulator] values`` the twin holds), where its enable says so or where it has none.

        A word-block slot the EDS gives no default holds a bypassed identity block of its size, as a drive's
        block always holds its words. Stored values that give no valid section leave the slot bypassed.
        """
        fo, encoding = self.fw.desc.filters, self.fw.encoding
        if fo is None or encoding is None:
            return
        if fo.in_block:
            lay = encoding.layout
            neutral = encoding.disabled({"block": encode_block(lay, Biquad.identity(), None, encoding.feedback_sign)})
            for slot in range(fo.count):
                addr = fo.address(slot, "block")
                if self._declared_block(slot) is None:
                    self.fw.node.data_store.setdefault(addr.index, {})[addr.subindex] = neutral["block"]
        for slot in range(fo.count):
            enabled = None if fo.in_block else (not fo.has_enable or self._enable_reads_on(slot))
            try:
                self._apply_filter(slot, enabled)
            except SdoAbortedError:
                self.fw.drive.filters.write(slot, Biquad.identity(), False)

    def _enable_reads_on(self, slot: int) -> bool:
        fo, _ = self._filter_slots()
        addr = fo.address(slot, ENABLED)
        stored = self.fw.stored(addr.index, addr.subindex)
        return stored is not None and int(stored) == fo.enable_on

    def block_size(self, slot: int) -> int:
        """Bytes of a word-block slot: its EDS default's length where the EDS gives one, else the layout's."""
        _, encoding = self._filter_slots()
        declared = self._declared_block(slot)
        return len(declared) if declared is not None else 2 * encoding.layout.words

    def _declared_block(self, slot: int) -> bytes | None:
        """The EDS default of a word-block slot's object (None: none, or empty)."""
        fo, _ = self._filter_slots()
        addr = fo.address(slot, "block")
        var = self.fw.od.get_variable(addr.index, addr.subindex)
        declared = var.default if var is not None else None
        return declared if isinstance(declared, bytes) and declared else None

    def write_filter(self, slot: int, name: str, value) -> None:
        """The host wrote field ``name`` (or the enable) of filter slot ``slot``: the drive loads the slot's
        section when its enable or its block is written, and when a field of a running slot changes."""
        fo, _ = self._filter_slots()
        if fo.in_block:
            if len(bytes(value)) != self.block_size(slot):
                raise SdoAbortedError(ABORT_LENGTH)  # a drive's block has its size
            self._apply_filter(slot, None, {"block": bytes(value)})
        elif name == ENABLED:
            self._apply_filter(slot, int(value) == fo.enable_on)
        elif not fo.has_enable:  # the slot runs what it holds, each field as it arrives
            self._reload(slot, name, value)
        elif self.fw.drive.filters.read(slot)[1]:
            self._reload(slot, name, value)

    def _reload(self, slot: int, name: str, value) -> None:
        """A field of a running slot changed: the section follows; one the other fields still make invalid
        (mid-way through an update) leaves the last one running."""
        values = self._stored_fields(slot)
        values[name] = value
        try:
            self._apply_filter(slot, True, values)
        except SdoAbortedError:
            pass

    def _stored_fields(self, slot: int) -> dict:
        fo, _ = self._filter_slots()
        return {name: self.fw.stored(a.index, a.subindex) for name, a in fo.slots[slot].items()}

    def _apply_filter(self, slot: int, enabled: bool | None, values: dict | None = None) -> None:
        """Load a slot's section into the drive loop: from its stored fields when its enable is written, or
        from ``values`` (a block's state word says ``enabled`` when it is None)."""
        _, encoding = self._filter_slots()
        if values is None:
            values = self._stored_fields(slot)
        try:
            if enabled is None:
                enabled = bool(encoding.slot_enabled(values))
            biquad = encoding.applied(values, self.fw.loop_rate)
        except (DataError, ConfigError):
            raise SdoAbortedError(ABORT_VALUE) from None
        if enabled and not biquad.is_stable():
            raise SdoAbortedError(ABORT_VALUE)  # an unstable section is never switched in
        self.fw.drive.filters.write(slot, biquad, enabled)
