"""How the emulated CANopen drive judges each SYNC it receives against its own clock.

A drive in a SYNC-driven run keeps a clock of its own, locked to the SYNCs it
takes: it expects each SYNC a whole number of communication cycle periods
after the last cycle instant. Each SYNC's bus timestamp is compared with that
clock (:meth:`SyncMonitor.observe`):

* on time or late, within the cycle (no more than the window early, and
  less than a period less the window late: a SYNC is taken for the cycle
  whose instant is at most the window ahead of it):
  the cycles that passed without a SYNC ran on the drive's clock with the
  set-point it held (missed cycles, no TPDOs), this SYNC starts its cycle
  with the newest set-point. The clock follows the SYNCs slowly (a tenth of
  each distance, as a phase-locked loop does), so one late SYNC does not make
  the next one on time look early;
* a SYNC too early for its cycle, above all a second SYNC inside one cycle (a
  burst): a sync error. The drive stays on its own clock (the cycles whose
  instants passed run with the held set-point), answers nothing, and adds 3 to
  its leaky sync-error counter (a good SYNC takes 1 off); above the driver's
  ``error_limit`` the drive reacts to sync errors (EMCY 0x8700 and Fault).
  SYNCs late beyond the window are counted (``late``) but taken: the drive's
  clock ran the cycle meanwhile, and a late SYNC is what a host that skips
  and never bursts sends.

A drive that does not monitor SYNC timing (``window_us = 0``) takes every
SYNC as the start of a cycle, running the cycles that passed since the last
one first. Pure: timestamps in, :class:`SyncVerdict` out; no bus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hilident.protocol.canopen_sync import SyncCapability

__all__ = ["ERROR_STEP", "SYNC_COB_ID_INDEX", "SyncMonitor", "SyncVerdict"]

#: COB-ID SYNC (CiA 301); bit 30 (``SYNC_GEN_BIT``) makes the node the SYNC producer.
SYNC_COB_ID_INDEX = 0x1005
#: What one sync error adds to the leaky counter (a good SYNC takes 1 off).
ERROR_STEP = 3
#: How much of a SYNC's distance from the drive's clock the clock takes over (a phase-locked loop's gain).
_LOCK_GAIN = 0.1


@dataclass(frozen=True)
class SyncVerdict:
    """What the drive does with one SYNC.

    Attributes
    ----------
    held : int
        Cycles its own clock runs first, with the set-point it holds (no TPDOs for them).
    answer : bool
        This SYNC starts a cycle: physics with the newest set-point, TPDOs sent.
    error : bool
        The SYNC is a sync error (a second one in a cycle, or outside the window).
    fault : bool
        The leaky counter went above the limit: the drive's sync-error reaction.
    """

    held: int = 0
    answer: bool = True
    error: bool = False
    fault: bool = False


class SyncMonitor:
    """The drive's clock in a SYNC-driven run, and its leaky sync-error counter.

    Parameters
    ----------
    capability : SyncCapability
        The driver's ``[canopen.sync]``: window (µs, 0: no monitoring) and error limit.

    Attributes
    ----------
    reference : float or None
        Bus time (s) of the cycle instant the clock counts from; None before the run's first SYNC.
    errors : int
        The leaky counter.
    late : int
        SYNCs taken later than the window after their cycle's instant.
    """

    def __init__(self, capability: SyncCapability):
        self.window_s = capability.window_us * 1e-6
        self.error_limit = capability.error_limit
        self.restart()

    def restart(self) -> None:
        """A run starts: its first SYNC starts cycle 0."""
        self.reference: float | None = None
        self.errors = 0
        self.late = 0

    def observe(self, stamp: float, period_s: float) -> SyncVerdict:
        """Judge a SYNC with bus timestamp ``stamp`` (s) in cycles of ``period_s`` (s)."""
        if self.reference is None:
            self.reference = stamp
            return SyncVerdict()
        dt = stamp - self.reference
        if not self.window_s:
            self.reference = stamp
            return SyncVerdict(held=max(1, math.floor(dt / period_s + 0.5)) - 1)
        # the cycle whose instant is at most the window ahead: a SYNC up to a period less the window late is late
        # for its own cycle, not early for the next one
        cycles = math.floor((dt + self.window_s) / period_s)
        offset = dt - cycles * period_s  # from the window early to a period less the window late
        if cycles >= 1 and offset >= -self.window_s:
            self.reference += cycles * period_s + _LOCK_GAIN * offset
            self.errors = max(0, self.errors - 1)
            if offset > self.window_s:
                self.late += 1
            return SyncVerdict(held=cycles - 1)
        # The own clock has run the cycles whose instants passed (floor: an early SYNC does not move the clock
        # ahead of time, so the next SYNC on time is on time).
        passed = max(0, math.floor(dt / period_s))
        self.reference += passed * period_s
        self.errors += ERROR_STEP
        return SyncVerdict(held=passed, answer=False, error=True, fault=self.errors > self.error_limit)
