"""A bare CANopen host's cycles on a twin's bus: PDO mapping, and frames sent at their cycle instants, as a real
host's clock sends them (a strict drive counts a SYNC sent off its period as a sync error)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable


def map_pdo(write: Callable[[int, int, int], None], comm: int, mapping: int, cob: int, entries: list[int]) -> None:
    """Map a PDO in the CiA 301 order: invalidate, count 0, entries, count, valid again."""
    write(comm, 1, cob | 0x80000000)
    write(mapping, 0, 0)
    for i, entry in enumerate(entries, 1):
        write(mapping, i, entry)
    write(mapping, 0, len(entries))
    write(comm, 1, cob)


class CycleClock:
    """Cycle instants ``start + j * period_s`` (perf_counter), kept as a real host keeps them.

    The clock starts with the first cycle sent (at once). A cycle whose instant
    the host missed by more than ``skip_late_s`` is skipped, never sent late (a
    strict drive counts a late SYNC as a sync error and a burst of overdue ones
    faults it); the drive runs it on its own clock.

    Parameters
    ----------
    period_s : float
        The communication cycle period, s.
    skip_late_s : float
        How late (s) a cycle may still be sent: half a 400 µs drive window.

    Attributes
    ----------
    sent, skipped : list of int
        The cycles sent, and those skipped.
    worst_late_s : float
        The latest (s) a cycle's frames were all out after its instant.
    """

    def __init__(self, period_s: float, skip_late_s: float = 200e-6):
        self.period_s = period_s
        self.skip_late_s = skip_late_s
        self.start: float | None = None
        self.sent: list[int] = []
        self.skipped: list[int] = []
        self.worst_late_s = 0.0

    def at(self, cycles: Iterable[int], send: Callable[[int], None]) -> None:
        """Call ``send(j)`` at the instant of each cycle ``j``, in order; skip the cycles reached too late."""
        for j in cycles:
            if self.start is None:
                self.start = time.perf_counter() - j * self.period_s
            due = self.start + j * self.period_s
            wait = due - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            if time.perf_counter() - due > self.skip_late_s:
                self.skipped.append(j)
                continue
            send(j)
            self.sent.append(j)
            self.worst_late_s = max(self.worst_late_s, time.perf_counter() - due)
