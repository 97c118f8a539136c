"""The host's side of a drive's interpolation data buffer (CiA 402 0x60C4): how far ahead its set-points go.

In interpolated position mode a drive with a buffer queues the set-points
(0x60C1:1) and takes one at each SYNC, so the host may send them several
cycles ahead: one held up for less than that costs nothing. The host sets it
up as a first-in first-out queue of as many records as the drive can hold,
at most :data:`MAX_RECORDS` (0x60C4:2 the size, 0x60C4:3 = 0 the FIFO, 0x60C4:6
cleared then enabled), keeps one record spare, and clears and disables it
when the run ends. The RPDO carrying the set-points is event-driven
(:data:`~hilident.protocol.canopen_pdo_plan.EVENT_DRIVEN`): a synchronous one
hands the drive only the newest record a cycle.

Only while the drive or the interface keeps the bus clock: on the host's own
clock a cycle it skips sends no SYNC, the drive takes no record, and the
queue would shift every later set-point by a cycle.
"""

from __future__ import annotations

from typing import Protocol

from hilident.errors import DeviceError
from hilident.protocol.canopen_pdo_plan import buffers_setpoints

__all__ = ["MAX_RECORDS", "close_buffer", "open_buffer"]

#: Records the host asks for at most (a drive may hold more).
MAX_RECORDS = 16


class _Sdo(Protocol):
    def read(self, role: str): ...

    def write(self, role: str, value) -> None: ...


class _Desc(Protocol):
    def has(self, role: str) -> bool: ...


def open_buffer(sdo: _Sdo, desc: _Desc, setpoint_role: str, port: str) -> int:
    """Set the buffer up as a FIFO; the set-points the host may send ahead of the drive's next SYNC (1: no buffer).

    Raises
    ------
    DeviceError
        The drive refused a write (naming the object, as the SDO layer does).
    """
    if not buffers_setpoints(desc, setpoint_role):
        return 1
    try:
        records = min(int(sdo.read("ip_buffer_max")), MAX_RECORDS)
    except DeviceError as exc:
        raise DeviceError(f"{port}: the interpolation data buffer: {exc}") from None
    sdo.write("ip_buffer_clear", 0)
    if records < 2:
        return 1
    sdo.write("ip_buffer_size", records)
    if desc.has("ip_buffer_organization"):
        sdo.write("ip_buffer_organization", 0)
    sdo.write("ip_buffer_clear", 1)
    return records - 1


def close_buffer(sdo: _Sdo, desc: _Desc, setpoint_role: str) -> None:
    """Clear and disable the buffer (never raises: every ending passes here)."""
    if buffers_setpoints(desc, setpoint_role):
        try:
            sdo.write("ip_buffer_clear", 0)
        except Exception:
            pass
