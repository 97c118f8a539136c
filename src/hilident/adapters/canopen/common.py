"""What the parts of the CANopen adapter share: CANopen constants, the identity, channel and PDO records,
and :class:`CanopenState`, the attributes and methods the parts see of the adapter they are composed into.

Split from :mod:`hilident.adapters.canopen.drive` so that its parts
(:mod:`~hilident.adapters.canopen.sdo`, :mod:`~hilident.adapters.canopen.net`,
:mod:`~hilident.adapters.canopen.mapping`, :mod:`~hilident.adapters.canopen.slots`)
import them without importing the adapter.
"""

from __future__ import annotations

import collections
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import can
from canopen.sdo import SdoAbortedError, SdoCommunicationError

import canopen
from hilident.protocol.canopen_objects import (
    ObjectAddress,
    type_bits,
)

if TYPE_CHECKING:
    from hilident.adapters.base import ConnectReport, RunResult
    from hilident.adapters.canopen.trace import TracingNetwork
    from hilident.config.tables import DeviceConfig
    from hilident.drivers.description import DriverDescription
    from hilident.events import RunEvent
    from hilident.protocol import cia402
    from hilident.protocol.canopen_objects import CanopenDescription
    from hilident.protocol.filter_encoding import FilterEncoding

#: A value as an object's EDS data type decodes it (canopen's ``ODVariable.decode_raw``).
ObjectValue = int | float | str | bytes | bytearray

#: Emergency codes that mean a safety limit tripped (they raise LimitTrip).
LIMIT_TRIP_CODES = {0x8311: "torque_limit", 0x8400: "velocity_limit", 0x8612: "position_limit"}
_NMT_OPERATIONAL = 5
_TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
_ABORT_GENERAL = 0x08000000  # SDO abort code: general error (a transfer the host broke off)
_TRANSFER_ERRORS = (SdoAbortedError, SdoCommunicationError, can.CanError, OSError)
_STATE_POLL_S = 0.002
#: CiA 301 store parameters (0x1010): writing "save" (ASCII, little-endian) stores them in non-volatile memory.
STORE_SIGNATURE = 0x65766173
_GUARD_TIME, _LIFE_TIME_FACTOR = 0x100C, 0x100D  # CiA 301 node guarding


def _transfer_error(exc: BaseException) -> Exception | None:
    """The SDO or bus error behind ``exc``, or None when ``exc`` is something else.

    canopen 2.4.1's ``BlockUploadStream._end_upload`` calls a method it does not
    have (``self.abort``) when the end-of-upload response times out, so a drive
    that vanishes at the end of a capture surfaces as an ``AttributeError``
    raised while handling the ``SdoCommunicationError``: that one is the cause.
    """
    link: BaseException | None = exc
    while link is not None:
        if isinstance(link, _TRANSFER_ERRORS):
            return link
        if not isinstance(link, AttributeError):
            return None
        link = link.__context__
    return None


@dataclass(frozen=True)
class DriveIdentity:
    """What the drive reported (0x1008, 0x100A, 0x1018) and what its driver description adds."""

    name: str
    firmware: str
    loop_rate_hz: float
    filter_slots: int
    vendor_id: int
    product_code: int


@dataclass(frozen=True)
class ChannelCodec:
    """A recorded channel: the object carrying it, its CANopen data type and SI value per unit.

    ``role`` and ``address`` are None for a channel the host records itself
    (the set-point it sent, on a drive that does not report the one it applied).
    """

    name: str
    unit: str
    role: str | None
    address: ObjectAddress | None
    datatype: int
    scale: float

    @property
    def bits(self) -> int:
        return type_bits(self.datatype)

    @property
    def on_host(self) -> bool:
        return self.address is None


@dataclass(frozen=True)
class PdoSlot:
    """One PDO the drive's EDS declares: its number, how many objects it maps at most, its COB-ID."""

    number: int
    max_entries: int
    cob_id: int


@dataclass
class Emergency:
    """One EMCY message as received."""

    code: int
    register: int
    data: bytes
    received_s: float


class CanopenState:
    """The attributes and cross-part methods of :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`, as
    its parts see them.

    Every part (:class:`~hilident.adapters.canopen.sdo.SdoAccess`, :class:`~hilident.adapters.canopen.net.NetWatch`,
    :class:`~hilident.adapters.canopen.mapping.ChannelMapping`, :class:`~hilident.adapters.canopen.slots.FilterSlots`)
    derives from this class. It holds bare annotations only (no values) and, for type checking only, the
    signatures of the methods one part calls that another part, the adapter or
    :class:`~hilident.adapters.base.AdapterBase` defines: at run time it is empty, and the composed adapter sets
    the attributes in its ``__init__``. See :mod:`hilident.adapters.canopen.drive` for the pattern.
    """

    # --- set at construction (CanopenDriveAdapter.__init__) ---------------------------------------
    network: TracingNetwork
    node: canopen.RemoteNode
    driver: DriverDescription
    desc: CanopenDescription
    device: DeviceConfig
    port: str
    node_id: int  # the drive's node id ([device.canopen] node_id)
    timeout_s: float
    encoding: FilterEncoding | None  # None: the driver describes no filter objects
    acquisition: str
    connect_report: ConnectReport

    # --- found at connect -------------------------------------------------------------------------
    identity: DriveIdentity | None  # set by open_device (the drive's identity objects)
    rated_torque_nm: float
    rated_current_a: float
    torque_problem: str
    supported_modes: tuple[str, ...] | None
    sync_overflow: int

    # --- configuration (configure(), set_limits(), set_excitation_recipe()) ------------------------
    sample_rate_hz: float
    divider: int
    mode: str
    channels: list[ChannelCodec]
    channel_names: list[str]
    channel_units: list[str]
    sync_rate_hz: float | None
    tpdo_layout: list[tuple[int, list[int]]]
    #: (COB-ID, set-point counter type or None, set-point type, set-point role) of the streamed RPDO
    rpdo: tuple[int, int | None, int, str] | None
    _configured_for: str
    excitation_recipe: dict | None
    _limits: tuple[float, float, float, float] | None  # torque N·m, velocity m/s, position min and max m
    device_limits: tuple[str, ...]

    # --- the run ----------------------------------------------------------------------------------
    last_result: RunResult | None
    events: list[dict]
    run_fault: dict | None
    emergencies: collections.deque[Emergency]
    _trace_path: Path | None

    # --- the link: heartbeats, guarding, the device-side net ---------------------------------------
    _host_heartbeat: can.broadcastmanager.ThreadBasedCyclicSendTask | None
    _guarding: bool
    _consumer: ObjectAddress | None
    _in_block_transfer: bool
    answered: bool
    _beat: tuple[int, float]
    _beat_s: float
    heartbeat_s: float | None
    heartbeat_state: int | None
    _nmt_settled_s: float

    if TYPE_CHECKING:
        # Defined by a part (canopen_sdo, canopen_net, canopen_mapping), by CanopenDriveAdapter or by AdapterBase;
        # declared here so that another part may call them. The definitions are checked against these.
        def read_object(self, addr: ObjectAddress) -> ObjectValue: ...
        def write_object(self, addr: ObjectAddress, value: ObjectValue) -> None: ...
        def read(self, role: str) -> ObjectValue: ...
        def write(self, role: str, value: ObjectValue) -> None: ...
        def describe(self, addr: ObjectAddress) -> str: ...
        def data_type(self, addr: ObjectAddress) -> int: ...
        def beat_if_due(self) -> None: ...
        def nmt(self, state: str) -> None: ...
        def pdo_slots(self, kind: str) -> list[PdoSlot]: ...
        def drive_identity(self) -> DriveIdentity: ...
        def drive_state(self) -> cia402.State: ...
        def _follow(self, state: cia402.State, commands: Iterable[int]) -> cia402.State: ...
        def last_error_text(self) -> str: ...
        def safe_stop(self) -> None: ...
        def log_event(self, event: RunEvent) -> dict: ...
        def note_fault(self, event: dict) -> None: ...
