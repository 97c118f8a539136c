"""What the parts of the CANopen adapter share: CANopen constants and small frozen values (the identity,
the ratings, a channel's codec, an emergency, the layout of a configured run).

Split from :mod:`hilident.adapters.canopen.drive` so that its parts
(:mod:`~hilident.adapters.canopen.sdo`, :mod:`~hilident.adapters.canopen.net`,
:mod:`~hilident.adapters.canopen.mapping`, :mod:`~hilident.adapters.canopen.slots`)
and the acquisition strategies import them without importing the adapter.
"""

from __future__ import annotations

from dataclasses import dataclass

import can
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from hilident.protocol.canopen_objects import (
    type_bits,
)
from hilident.protocol.canopen_pdo_plan import PdoPlan
from hilident.protocol.canopen_types import ObjectAddress

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


@dataclass
class Emergency:
    """One EMCY message as received."""

    code: int
    register: int
    data: bytes
    received_s: float


@dataclass(frozen=True)
class DriveRatings:
    """The ratings torque and current objects are scaled by, found at connect.

    Attributes
    ----------
    torque_nm : float
        Rated torque, N·m (0x6076, else the driver's ``rated_torque_nm``); 0 when neither gives one.
    current_a : float
        Rated current, A (0x6075, else the driver's ``rated_current_a``); 0: none.
    torque_problem : str
        Why torque objects cannot be scaled, when they cannot; "" otherwise.
    """

    torque_nm: float = 0.0
    current_a: float = 0.0
    torque_problem: str = ""


@dataclass(frozen=True)
class TpdoMap:
    """A TPDO of a streamed run: its COB-ID and the channel columns it carries (after the sample counter)."""

    cob_id: int
    columns: tuple[int, ...]


@dataclass(frozen=True)
class RpdoMap:
    """The RPDO of a streamed run: its COB-ID, the CiA 301 data types of the set-point counter (None: the
    drive has none) and of the set-point, and the set-point's role."""

    cob_id: int
    counter_type: int | None
    setpoint_type: int
    setpoint_role: str


@dataclass(frozen=True)
class RunLayout:
    """What ``configure()`` set the drive up for: the acquisition strategies play a run by it.

    The default value stands for a drive not configured yet.

    Attributes
    ----------
    acquisition : str
        The acquisition the objects were mapped for (``"streamed"``, ``"buffered"``, ``"recorder"``); "": none.
    mode : str
        The hilident mode of the run (``"torque"``, ``"velocity"``, ...).
    divider : int
        Loop periods per sample.
    sample_rate_hz : float
        The recorded sample rate, Hz.
    channels : tuple of ChannelCodec
        The recorded channels, in column order.
    tpdos : tuple of TpdoMap
        The TPDOs a streamed run receives, in PDO number order (empty for the other acquisitions).
    rpdo : RpdoMap or None
        The RPDO a streamed run sends its set-points in (None for the other acquisitions).
    pdo_plan : PdoPlan or None
        Every PDO a streamed run mapped or emptied, as planned and written (None for the other acquisitions).
    """

    acquisition: str = ""
    mode: str = ""
    divider: int = 0
    sample_rate_hz: float = 0.0
    channels: tuple[ChannelCodec, ...] = ()
    tpdos: tuple[TpdoMap, ...] = ()
    rpdo: RpdoMap | None = None
    pdo_plan: PdoPlan | None = None
