"""What the parts of the CANopen adapter share: CANopen constants, the identity, channel and PDO records.

Split from :mod:`hilident.adapters.canopen_drive` so that its parts
(:mod:`~hilident.adapters.canopen_sdo`, :mod:`~hilident.adapters.canopen_net`,
:mod:`~hilident.adapters.canopen_mapping`, :mod:`~hilident.adapters.canopen_slots`)
import them without importing the adapter.
"""

from __future__ import annotations

from dataclasses import dataclass

import can
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from hilident.protocol.canopen_objects import (
    ObjectAddress,
    type_bits,
)

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


def _transfer_error(exc: BaseException) -> BaseException | None:
    """The SDO or bus error behind ``exc``, or None when ``exc`` is something else.

    canopen 2.4.1's ``BlockUploadStream._end_upload`` calls a method it does not
    have (``self.abort``) when the end-of-upload response times out, so a drive
    that vanishes at the end of a capture surfaces as an ``AttributeError``
    raised while handling the ``SdoCommunicationError``: that one is the cause.
    """
    while exc is not None:
        if isinstance(exc, _TRANSFER_ERRORS):
            return exc
        if not isinstance(exc, AttributeError):
            return None
        exc = exc.__context__
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
