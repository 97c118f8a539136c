"""Configuration of a CANopen run: mode, sample period, limits, and the PDO or capture mapping of the channels.

One part of :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`, which composes the parts
(see that module); a part uses only the attributes and methods
:class:`~hilident.adapters.canopen.common.CanopenState` declares.
"""

from __future__ import annotations

import math

import numpy as np

from hilident.adapters.canopen.common import (
    CanopenState,
    ChannelCodec,
    PdoSlot,
)
from hilident.adapters.canopen.recorder import configure_recorder
from hilident.errors import ConfigError, DataError, DeviceError
from hilident.protocol.canopen_objects import (
    REAL32,
    ObjectAddress,
    mapping_entry,
    numpy_type,
    pack_frames,
    type_bits,
)
from hilident.protocol.canopen_profile import (
    mapping_capacity,
    period_fields,
)
from hilident.units import units_in_mode


class ChannelMapping(CanopenState):
    """The configuration part of :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`.

    Mode of operation and sample period, the limits the drive holds, channel codecs,
    and the TPDO/RPDO (streamed) or capture (buffered) mapping within what the EDS allows.
    """

    # --- configuration ---------------------------------------------------------------------------

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the trip limits into the drive where it has them, and read each back.

        Max torque 0x6072, max motor speed 0x6080, software position limits
        0x607D. Whatever the drive has, the host also checks every sample it
        receives against the limits (see :meth:`stream`).

        Raises
        ------
        ConfigError
            A limit does not fit its object's type.
        DeviceError
            The drive stores another value than the one written.
        """
        d = self.desc
        wanted = {
            "max_torque": lambda: math.floor(torque_nm / self.scale("max_torque")),
            "max_velocity": lambda: math.floor(velocity_mps / self.scale("max_velocity")),
            "position_limit_min": lambda: math.ceil(position_min_m / self.scale("position_limit_min")),
            "position_limit_max": lambda: math.floor(position_max_m / self.scale("position_limit_max")),
        }
        values: dict[str, int] = {}
        for role, compute in wanted.items():
            if not d.has(role) or (role == "max_torque" and not self.rated_torque_nm > 0):
                continue
            values[role] = compute()
            info = np.iinfo(numpy_type(self.data_type(d.address(role))))
            if not info.min <= values[role] <= info.max:
                raise ConfigError(
                    f"limits ({role})", f"{values[role]} units do not fit {self.describe(d.address(role))}"
                )
        for role, raw in values.items():
            self.write(role, raw)
            back = int(self.read(role))
            if back != raw:
                raise DeviceError(
                    f"{self.port}: wrote {raw} to {self.describe(d.address(role))}, the drive holds {back}"
                )
        self.device_limits = tuple(values)
        self._limits = (torque_nm, velocity_mps, position_min_m, position_max_m)

    def scale(self, role: str) -> float:
        """SI value of one raw unit of the object of ``role``; DeviceError when it cannot be scaled."""
        try:
            return self.desc.scale(role, self.rated_torque_nm, self.rated_current_a)
        except DataError as exc:
            raise DeviceError(
                f"{self.port}: {self.describe(self.desc.address(role))}: {self.torque_problem or exc}"
            ) from None

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Mode of operation, sample period and the PDO (or capture) mapping of the channels.

        The period goes to whichever of 0x1006 (us) and 0x60C2 (value and
        exponent) the drive has.
        """
        divider, rate = self._divider_for(sample_rate_hz)
        self._check_mode(mode)
        codecs = self._channel_codecs(channels)
        if self.acquisition == "recorder":
            configure_recorder(self, codecs)
        elif self.acquisition == "buffered" and any(c.on_host for c in codecs):
            raise DeviceError(
                f"{self.port}: a drive-buffered run records only drive objects; channel "
                f"{next(c.name for c in codecs if c.on_host)!r} has none"
            )
        spec = self.desc.modes[mode]
        for role in (spec.setpoint, spec.hold):
            if role:
                self.scale(role)  # a set-point that cannot be scaled stops here, before anything moves
        self.safe_stop()
        self.write("modes_of_operation", spec.code)
        self._write_period(divider)
        if self.acquisition == "streamed":
            self._map_pdos(codecs, mode)
        elif self.acquisition == "buffered":
            self._map_capture(codecs)
        self.divider, self.sample_rate_hz, self.mode = divider, rate, mode
        self._configured_for = self.acquisition
        self.channels = codecs
        self.channel_names = [c.name for c in codecs]
        self.channel_units = units_in_mode(self.channel_names, [c.unit for c in codecs], mode)
        return self.channel_names

    def _divider_for(self, sample_rate_hz: float) -> tuple[int, float]:
        """(loop periods per sample, sample rate in Hz); DeviceError when the rate does not fit the drive."""
        ident = self.drive_identity()
        divider = ident.loop_rate_hz / sample_rate_hz
        if abs(divider - round(divider)) > 1e-9 or round(divider) < 1:
            raise DeviceError(
                f"{self.port}: sample rate {sample_rate_hz:g} Hz does not divide the drive's loop rate "
                f"{ident.loop_rate_hz:g} Hz"
            )
        divider = int(round(divider))
        rate = ident.loop_rate_hz / divider
        if rate > self.driver.max_sample_rate_hz * (1 + 1e-9):
            raise DeviceError(
                f"{self.port}: sample rate {rate:g} Hz exceeds the drive's {self.driver.max_sample_rate_hz:g} Hz"
            )
        return divider, rate

    def _check_mode(self, mode: str) -> None:
        """DeviceError naming the modes the driver has (and 0x6502's) when it has none for ``mode``."""
        if mode not in self.desc.modes:
            supported = (
                f"; 0x6502 says it supports {', '.join(self.supported_modes) or 'no mode'}"
                if self.supported_modes is not None
                else ""
            )
            raise DeviceError(
                f"{self.port}: driver {self.driver.name!r} has no mode for {mode!r} "
                f"(it has {', '.join(self.desc.modes) or 'none'}{supported})"
            )

    def _channel_codecs(self, channels: list[str] | None) -> list[ChannelCodec]:
        """The codec of each channel (the driver's streamed channels by default); DeviceError for an unknown one."""
        names = channels or [c.name for c in self.driver.streamed_channels]
        units = {c.name: c.unit for c in self.driver.channels}
        codecs = []
        for name in names:
            if name not in self.desc.channels or name not in units:
                raise DeviceError(
                    f"{self.port}: driver {self.driver.name!r} has no channel {name!r} "
                    f"(it has {', '.join(self.desc.channels)})"
                )
            role = self.desc.channels[name]
            if role is None:
                codecs.append(ChannelCodec(name, units[name], None, None, REAL32, 1.0))
                continue
            addr = self.desc.address(role)
            codecs.append(ChannelCodec(name, units[name], role, addr, self.data_type(addr), self.scale(role)))
        return codecs

    def _write_period(self, divider: int) -> None:
        """The sample period to whichever of 0x1006, 0x60C2 and the table divider the drive has."""
        period_s = divider / self.drive_identity().loop_rate_hz
        if self.desc.has("cycle_period"):
            self.write("cycle_period", int(round(1e6 * period_s)))
        if self.desc.has("interpolation_period"):
            try:
                value, exponent = period_fields(period_s)
            except ValueError as exc:
                raise DeviceError(
                    f"{self.port}: {self.describe(self.desc.address('interpolation_period'))}: {exc}"
                ) from None
            self.write("interpolation_period", value)
            if self.desc.has("interpolation_exponent"):
                self.write("interpolation_exponent", exponent)
        if self.desc.has("table_divider"):
            self.write("table_divider", divider)

    def _write_mapping(self, pdo: tuple[int, int] | None, map_index: int, entries: list[int]) -> None:
        """CiA 301 order: invalidate, clear the count, write entries, set the count, validate.

        ``pdo`` is the PDO's (communication object index, COB-ID), None for a mapping that is no PDO's
        (the capture's).
        """
        if pdo is not None:
            self.write_object(ObjectAddress(pdo[0], 1), pdo[1] | 0x80000000)
        self.write_object(ObjectAddress(map_index, 0), 0)
        for i, entry in enumerate(entries, start=1):
            self.write_object(ObjectAddress(map_index, i), entry)
        self.write_object(ObjectAddress(map_index, 0), len(entries))
        if pdo is not None and entries:
            self.write_object(ObjectAddress(pdo[0], 2), 1)  # synchronous, every SYNC
            self.write_object(ObjectAddress(pdo[0], 1), pdo[1])

    def pdo_slots(self, kind: str) -> list[PdoSlot]:
        """The RPDOs (``kind = "rpdo"``) or TPDOs the EDS declares, with their mapping capacity.

        A PDO counts when both its communication and its mapping object exist;
        its capacity is :func:`~hilident.protocol.canopen_profile.mapping_capacity`.
        The COB-ID is the predefined connection set's for PDOs 1-4 and the
        EDS default for the others.
        """
        od = self.node.object_dictionary
        comm_base, map_base, cob_base = (0x1400, 0x1600, 0x200) if kind == "rpdo" else (0x1800, 0x1A00, 0x180)
        slots = []
        for n in range(512):
            if comm_base + n not in od or map_base + n not in od:
                continue
            capacity = mapping_capacity(od[map_base + n])
            if n < 4:
                cob = cob_base + 0x100 * n + self.node_id
            else:
                var = od.get_variable(comm_base + n, 1)
                cob = int(var.default or 0) & 0x7FF if var is not None else 0
            if capacity and cob:
                slots.append(PdoSlot(n, capacity, cob))
        return slots

    def _map_pdos(self, codecs: list[ChannelCodec], mode: str) -> None:
        """Map the channels into TPDOs and the set-point into an RPDO, within what the EDS allows.

        On a drive with the hilident counters every PDO is headed by one (the
        sample counter, the set-point counter); otherwise the TPDOs carry the
        channels only and the host matches them to SYNCs by their order.
        """
        counted = self.desc.counted
        mapped = [c for c in codecs if not c.on_host]
        tpdos, rpdos = self.pdo_slots("tpdo"), self.pdo_slots("rpdo")
        header = []
        if counted:
            counter = self.desc.address("sample_counter")
            header = [(counter, type_bits(self.data_type(counter)))]
        per_frame = min((s.max_entries for s in tpdos[:4]), default=0) - len(header)
        try:
            frames = pack_frames(
                [(c.name, c.bits) for c in mapped],
                header_bits=sum(b for _, b in header),
                max_frames=len(tpdos),
                max_entries=per_frame,
            )
        except DataError as exc:
            raise DeviceError(
                f"{self.port}: {exc} ({self.desc.eds}: {len(tpdos)} TPDOs of "
                f"{', '.join(str(s.max_entries) for s in tpdos)} entries)"
            ) from None
        self.nmt("PRE-OPERATIONAL")
        layout = []
        for i, slot in enumerate(tpdos):
            members = frames[i] if i < len(frames) else []
            idx = [self.channel_index(codecs, m) for m in members]
            entries = (
                (
                    [mapping_entry(a, b) for a, b in header]
                    + [mapping_entry(self._drive_object(codecs[j]), codecs[j].bits) for j in idx]
                )
                if members
                else []
            )
            self._write_mapping((0x1800 + slot.number, slot.cob_id), 0x1A00 + slot.number, entries)
            if members:
                layout.append((slot.cob_id, idx))
        spec = self.desc.modes[mode]
        sp = self.desc.address(spec.setpoint)
        sp_type = self.data_type(sp)
        if not rpdos:
            raise DeviceError(f"{self.port}: the EDS {self.desc.eds} declares no RPDO: set-points cannot be streamed")
        rx_type = None
        entries = []
        if counted:
            rx_counter = self.desc.address("setpoint_counter")
            rx_type = self.data_type(rx_counter)
            entries.append(mapping_entry(rx_counter, type_bits(rx_type)))
        entries.append(mapping_entry(sp, type_bits(sp_type)))
        self._write_mapping((0x1400 + rpdos[0].number, rpdos[0].cob_id), 0x1600 + rpdos[0].number, entries)
        for slot in rpdos[1:4]:
            self._write_mapping((0x1400 + slot.number, slot.cob_id), 0x1600 + slot.number, [])
        self.tpdo_layout = layout
        self.rpdo = (rpdos[0].cob_id, rx_type, sp_type, spec.setpoint)
        self.nmt("OPERATIONAL")

    @staticmethod
    def channel_index(codecs: list[ChannelCodec], name: str) -> int:
        return [c.name for c in codecs].index(name)

    def _drive_object(self, codec: ChannelCodec) -> ObjectAddress:
        """The object carrying ``codec``'s channel; DeviceError for a channel the host records itself."""
        if codec.address is None:
            raise DeviceError(
                f"{self.port}: channel {codec.name!r} is recorded by the host: no drive object carries it"
            )
        return codec.address

    def _map_capture(self, codecs: list[ChannelCodec]) -> None:
        index = self.desc.address("capture_mapping").index
        self._write_mapping(None, index, [mapping_entry(self._drive_object(c), c.bits) for c in codecs])
        self.nmt("OPERATIONAL")  # for the heartbeat's NMT check; no PDOs are mapped
        for slot in self.pdo_slots("tpdo"):  # no stale TPDOs beside the capture
            self.write_object(ObjectAddress(0x1800 + slot.number, 1), slot.cob_id | 0x80000000)
