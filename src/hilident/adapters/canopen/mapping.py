"""Configuration of a CANopen run: the limits the drive holds, the sample period, the channel codecs and the
PDO or capture mapping of the channels, ending in the run's :class:`~hilident.adapters.canopen.common.RunLayout`.

:class:`ChannelMapping` is a part :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` owns (its
``mapping``): the adapter's ``configure()`` takes its steps in order and keeps the layout :meth:`map_run`
returns, which the acquisition strategies play the run by.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

from hilident.adapters.canopen.common import ChannelCodec, RpdoMap, RunLayout, TpdoMap
from hilident.adapters.canopen.net import NetWatch
from hilident.adapters.canopen.recorder import check_recorder_channels
from hilident.adapters.canopen.sdo import SdoAccess
from hilident.drivers.description import DriverDescription
from hilident.errors import ConfigError, DeviceError
from hilident.protocol.canopen_objects import (
    REAL32,
    CanopenDescription,
    mapping_entry,
    numpy_type,
)
from hilident.protocol.canopen_pdo_plan import (
    SYNCHRONOUS,
    PdoPlan,
    PlannedPdo,
    RunChannel,
    pdo_slots,
    plan_streamed_run,
)
from hilident.protocol.canopen_profile import period_fields
from hilident.protocol.canopen_types import ModeSpec, ObjectAddress

#: SI value of one raw unit of the object of a role (the adapter's ``scale``; DeviceError when it cannot be scaled).
Scale = Callable[[str], float]


class ChannelMapping:
    """The configuration part of :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` (its ``mapping``).

    The limits the drive holds, the sample period, channel codecs, and the TPDO/RPDO
    (streamed) or capture (buffered) mapping within what the EDS allows. It never looks
    at the drive's modes: the adapter picks the mode's :class:`ModeSpec`.

    Parameters
    ----------
    sdo : SdoAccess
        The drive's objects.
    net : NetWatch
        NMT commands around the mapping (PDOs are mapped in Pre-operational).
    desc : CanopenDescription
        The drive's objects by role, its channels, whether it has the hilident counters, its EDS file name.
    driver : DriverDescription
        The driver's channels and units, its highest sample rate, its name (for messages).
    node_id : int
        The drive's node id (the COB-IDs of PDOs 1-4).
    port : str
        Where the drive is; used in messages.
    """

    def __init__(
        self,
        sdo: SdoAccess,
        net: NetWatch,
        desc: CanopenDescription,
        driver: DriverDescription,
        node_id: int,
        port: str,
    ):
        self.sdo = sdo
        self.net = net
        self.desc = desc
        self.driver = driver
        self.node_id = node_id
        self.port = port

    # --- limits, rate, channels ------------------------------------------------------------------

    def load_limits(
        self, limits: tuple[float, float, float, float], scale: Scale, torque_scaled: bool
    ) -> tuple[str, ...]:
        """Write the trip limits into the objects the drive has, read each back; the roles written.

        ``limits`` are the torque (N·m), velocity (m/s), position minimum and
        maximum (m); max torque 0x6072 is written only when torque objects can
        be scaled (``torque_scaled``).

        Raises
        ------
        ConfigError
            A limit does not fit its object's type.
        DeviceError
            The drive stores another value than the one written.
        """
        torque_nm, velocity_mps, position_min_m, position_max_m = limits
        d = self.desc
        wanted = {
            "max_torque": lambda: math.floor(torque_nm / scale("max_torque")),
            "max_velocity": lambda: math.floor(velocity_mps / scale("max_velocity")),
            "position_limit_min": lambda: math.ceil(position_min_m / scale("position_limit_min")),
            "position_limit_max": lambda: math.floor(position_max_m / scale("position_limit_max")),
        }
        values: dict[str, int] = {}
        for role, compute in wanted.items():
            if not d.has(role) or (role == "max_torque" and not torque_scaled):
                continue
            values[role] = compute()
            info = np.iinfo(numpy_type(self.sdo.data_type(d.address(role))))
            if not info.min <= values[role] <= info.max:
                raise ConfigError(
                    f"limits ({role})", f"{values[role]} units do not fit {self.sdo.describe(d.address(role))}"
                )
        for role, raw in values.items():
            self.sdo.write(role, raw)
            back = int(self.sdo.read(role))
            if back != raw:
                raise DeviceError(
                    f"{self.port}: wrote {raw} to {self.sdo.describe(d.address(role))}, the drive holds {back}"
                )
        return tuple(values)

    def divider_for(self, sample_rate_hz: float, loop_rate_hz: float) -> tuple[int, float]:
        """(loop periods per sample, sample rate in Hz); DeviceError when the rate does not fit the drive."""
        divider = loop_rate_hz / sample_rate_hz
        if abs(divider - round(divider)) > 1e-9 or round(divider) < 1:
            raise DeviceError(
                f"{self.port}: sample rate {sample_rate_hz:g} Hz does not divide the drive's loop rate "
                f"{loop_rate_hz:g} Hz"
            )
        divider = int(round(divider))
        rate = loop_rate_hz / divider
        if rate > self.driver.max_sample_rate_hz * (1 + 1e-9):
            raise DeviceError(
                f"{self.port}: sample rate {rate:g} Hz exceeds the drive's {self.driver.max_sample_rate_hz:g} Hz"
            )
        return divider, rate

    def channel_codecs(self, channels: list[str] | None, scale: Scale) -> list[ChannelCodec]:
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
            codecs.append(ChannelCodec(name, units[name], role, addr, self.sdo.data_type(addr), scale(role)))
        return codecs

    def prepare_recorder(self, codecs: Sequence[ChannelCodec]) -> None:
        """A recorder run: the drive's recorder takes the channels (ConfigError otherwise), NMT Operational for
        the heartbeat's check, no stale TPDOs beside the recorder (no PDO runs)."""
        check_recorder_channels(self.desc, self.driver, codecs)
        self.net.nmt("OPERATIONAL")
        self._disable_tpdos()

    def write_period(self, divider: int, loop_rate_hz: float) -> None:
        """The sample period to whichever of 0x1006 (us), 0x60C2 (value and exponent) and the table divider
        the drive has."""
        period_s = divider / loop_rate_hz
        if self.desc.has("cycle_period"):
            self.sdo.write("cycle_period", int(round(1e6 * period_s)))
        if self.desc.has("interpolation_period"):
            try:
                value, exponent = period_fields(period_s)
            except ValueError as exc:
                raise DeviceError(
                    f"{self.port}: {self.sdo.describe(self.desc.address('interpolation_period'))}: {exc}"
                ) from None
            self.sdo.write("interpolation_period", value)
            if self.desc.has("interpolation_exponent"):
                self.sdo.write("interpolation_exponent", exponent)
        if self.desc.has("table_divider"):
            self.sdo.write("table_divider", divider)

    # --- the mapping ---------------------------------------------------------------------------

    def map_run(self, layout: RunLayout, spec: ModeSpec) -> RunLayout:
        """Map ``layout``'s channels for its acquisition (``spec``: the mode's set-point); the layout the run
        is played by, with its PDOs for a streamed run.

        A recorder run maps nothing here (:meth:`prepare_recorder` did its part).
        """
        if layout.acquisition == "streamed":
            tpdos, rpdo, plan = self._map_pdos(layout.channels, spec)
            return dataclasses.replace(layout, tpdos=tpdos, rpdo=rpdo, pdo_plan=plan)
        if layout.acquisition == "buffered":
            self._map_capture(layout.channels)
        return layout

    def _write_mapping(
        self, pdo: tuple[int, int] | None, map_index: int, entries: list[int], transmission: int = SYNCHRONOUS
    ) -> None:
        """CiA 301 order: invalidate, clear the count, write entries, set the count, validate.

        ``pdo`` is the PDO's (communication object index, COB-ID), None for a mapping that is no PDO's
        (the capture's); ``transmission`` its transmission type.
        """
        write = self.sdo.write_object
        if pdo is not None:
            write(ObjectAddress(pdo[0], 1), pdo[1] | 0x80000000)
        write(ObjectAddress(map_index, 0), 0)
        for i, entry in enumerate(entries, start=1):
            write(ObjectAddress(map_index, i), entry)
        write(ObjectAddress(map_index, 0), len(entries))
        if pdo is not None and entries:
            write(ObjectAddress(pdo[0], 2), transmission)
            write(ObjectAddress(pdo[0], 1), pdo[1])

    def _map_pdos(self, codecs: Sequence[ChannelCodec], spec: ModeSpec) -> tuple[tuple[TpdoMap, ...], RpdoMap, PdoPlan]:
        """Map the channels into TPDOs and the set-point into an RPDO, as
        :func:`~hilident.protocol.canopen_pdo_plan.plan_streamed_run` plans them.

        On a drive with the hilident counters every PDO is headed by one (the
        sample counter, the set-point counter); otherwise the TPDOs carry the
        channels only and the host matches them to SYNCs by their order. The plan
        is checked against the EDS before anything is written.
        """
        od = self.sdo.node.object_dictionary
        channels = [RunChannel(c.name, c.address) for c in codecs]
        plan = plan_streamed_run(od, self.desc, self.node_id, channels, spec.setpoint)
        self.net.nmt("PRE-OPERATIONAL")
        for pdo in plan.tpdos + plan.rpdos:
            self._write_mapping((pdo.comm_index, pdo.slot.cob_id), pdo.map_index, pdo.mapping_entries, pdo.transmission)
        self.net.nmt("OPERATIONAL")
        tpdo_maps = tuple(TpdoMap(pdo.slot.cob_id, pdo.columns) for pdo in plan.carrying)
        return tpdo_maps, self._rpdo_map(plan.setpoint_pdo, spec), plan

    def _rpdo_map(self, pdo: PlannedPdo, spec: ModeSpec) -> RpdoMap:
        """The set-point RPDO as the streamed run encodes it: the counter's type (None: none), the set-point's."""
        counter_type = self.sdo.data_type(self.desc.address("setpoint_counter")) if self.desc.counted else None
        return RpdoMap(
            pdo.slot.cob_id, counter_type, self.sdo.data_type(self.desc.address(spec.setpoint)), spec.setpoint
        )

    def _drive_object(self, codec: ChannelCodec) -> ObjectAddress:
        """The object carrying ``codec``'s channel; DeviceError for a channel the host records itself."""
        if codec.address is None:
            raise DeviceError(
                f"{self.port}: channel {codec.name!r} is recorded by the host: no drive object carries it"
            )
        return codec.address

    def _map_capture(self, codecs: Sequence[ChannelCodec]) -> None:
        index = self.desc.address("capture_mapping").index
        self._write_mapping(None, index, [mapping_entry(self._drive_object(c), c.bits) for c in codecs])
        self.net.nmt("OPERATIONAL")  # for the heartbeat's NMT check; no PDOs are mapped
        self._disable_tpdos()  # no stale TPDOs beside the capture

    def _disable_tpdos(self) -> None:
        """Every TPDO the EDS declares marked invalid (its COB-ID's bit 31)."""
        for slot in pdo_slots(self.sdo.node.object_dictionary, "tpdo", self.node_id):
            self.sdo.write_object(ObjectAddress(0x1800 + slot.number, 1), slot.cob_id | 0x80000000)
