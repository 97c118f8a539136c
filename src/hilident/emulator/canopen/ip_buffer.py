"""The emulated drive's interpolation data buffer (CiA 402 0x60C4), organised as a FIFO.

In interpolated position mode a drive with a buffer takes the host's
set-points (0x60C1:1, in an event-driven RPDO) into a first-in first-out
queue and takes the next one at each SYNC: a host may fill it several cycles
ahead, and one held up for less than the queue's depth costs nothing. An
empty queue at a SYNC is an underrun: the drive extrapolates, as without a
buffer. Set up by the host as CiA 402 describes: the size it uses
(0x60C4:2, up to the maximum 0x60C4:1), the organisation (0x60C4:3, 0 =
FIFO: the ring buffer of 1 is not modelled and refused), and the access
(0x60C4:6: 0 clears the buffer and disables it, 1 enables it).
"""

from __future__ import annotations

from collections import deque

from canopen.sdo.exceptions import SdoAbortedError

from hilident.emulator.canopen.sdo import ABORT_VALUE

__all__ = ["InterpolationBuffer"]


class InterpolationBuffer:
    """A FIFO of ``(set-point counter, interpolation data)`` records.

    Parameters
    ----------
    max_size : int
        0x60C4:1, the most records the drive can hold.

    Attributes
    ----------
    size : int
        0x60C4:2, the records the host uses (1: no buffer, each new set-point replaces the last).
    enabled : bool
        0x60C4:6 was last written 1.
    overflows : int
        Records refused because the buffer was full.
    """

    def __init__(self, max_size: int):
        self.max_size = max(1, int(max_size))
        self.size = 1
        self.enabled = False
        self.overflows = 0
        self.records: deque[tuple[int, int]] = deque()

    @property
    def active(self) -> bool:
        """Set-points go through the queue (enabled, and more than one record)."""
        return self.enabled and self.size > 1

    def write_size(self, value: int) -> None:
        """0x60C4:2; the queue is cleared."""
        if not 1 <= value <= self.max_size:
            raise SdoAbortedError(ABORT_VALUE)
        self.size = value
        self.records.clear()

    def write_organization(self, value: int) -> None:
        """0x60C4:3: only 0, the FIFO."""
        if value != 0:
            raise SdoAbortedError(ABORT_VALUE)

    def write_clear(self, value: int) -> None:
        """0x60C4:6: 0 clears the queue and disables access, 1 enables it."""
        if value not in (0, 1):
            raise SdoAbortedError(ABORT_VALUE)
        if value == 0:
            self.records.clear()
        self.enabled = value == 1

    def push(self, counter: int, value: int) -> bool:
        """A record from the host; False (and counted) when the queue is full."""
        if len(self.records) >= self.size:
            self.overflows += 1
            return False
        self.records.append((counter, value))
        return True

    def pop(self) -> tuple[int, int] | None:
        """The oldest record, taken at a SYNC; None when the queue is empty (an underrun)."""
        return self.records.popleft() if self.records else None
