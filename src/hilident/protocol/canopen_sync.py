"""How a CANopen drive keeps its cycle: SYNC production and SYNC monitoring, as its ``[canopen.sync]`` says.

A drive in a cyclic synchronous mode (CST, CSV, CSP) or interpolated position
runs one cycle per communication cycle period (0x1006) and expects one SYNC
per cycle. Two facts about a drive decide how a host may run it, and neither
is in an EDS (0x1005 is writable on drives that cannot produce SYNC too):

* **production**: whether the drive can be the SYNC producer (CiA 301: 0x1005
  bit 30 "gen" set, the period in 0x1006). A drive producing SYNC keeps the
  bus clock itself; the host only listens and fills set-points ahead;
* **monitoring**: how much earlier than its cycle's instant a SYNC may come
  before the drive counts a sync error (``window_us``; a second SYNC inside one
  cycle, a burst, always is one), how many such errors it forgives
  (``error_limit``, a leaky counter: +3 per error, -1 per good SYNC, the drive
  faults above the limit, as EtherCAT's sync error counter 0x10F1:2 works),
  and how long a SYNC may be missing before the drive faults
  (``loss_timeout_ms``). A SYNC missing for whole cycles is no error: the
  drive's own clock runs the cycle with the set-point it holds, and counts it.

:class:`SyncCapability` is that table; the twin monitors and produces SYNC by
it, and the host picks its SYNC source and its own sending window from it.

Pure data: no bus, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass

from hilident.config.schema import build_table, spec
from hilident.errors import ConfigError

__all__ = ["SYNC_GEN_BIT", "SyncCapability", "parse_sync"]

#: 0x1005 bit 30 (CiA 301 "gen"): the node produces SYNC with the COB-ID in bits 0-10.
SYNC_GEN_BIT = 0x40000000


@dataclass(frozen=True, kw_only=True)
class SyncCapability:
    """``[canopen.sync]``: whether the drive can produce SYNC, and how strictly it monitors it."""

    producer: bool = spec(False, doc="the drive can produce SYNC itself (0x1005 bit 30, period from 0x1006)")
    window_us: int = spec(
        0,
        ge=0,
        le=1_000_000,
        doc="how much earlier (µs) than its cycle's instant a SYNC may come before the drive counts a sync error "
        "(a second SYNC in one cycle always is one); 0: the drive does not monitor SYNC timing",
    )
    error_limit: int = spec(
        4, ge=0, le=1000, doc="leaky sync-error counter (+3 per error, -1 per good SYNC): the drive faults above it"
    )
    loss_timeout_ms: int = spec(
        100, ge=1, le=60_000, doc="the drive faults when no SYNC arrives for this long in a cyclic mode, ms"
    )

    def host_window_s(self, period_s: float) -> float:
        """How late (s) a host may send a cycle's SYNC.

        A drive takes a late SYNC (its own clock ran the cycle meanwhile) and
        counts an early one as a sync error. Its clock follows the SYNCs
        slowly, so a host that is often late drags it late, and the next SYNC
        on time then looks early: the host keeps its lateness within three
        quarters of the drive's window, and below 0.4 of a period so that the
        drive counts whole cycles between SYNCs without doubt.
        """
        cap = 0.4 * period_s
        return min(cap, 0.75e-6 * self.window_us) if self.window_us else cap


def parse_sync(canopen_table: dict, source: str) -> SyncCapability:
    """``[canopen.sync]`` of a ``[canopen]`` table (the defaults when absent).

    Raises
    ------
    ConfigError
        Naming ``canopen.sync.<key>`` and ``source``.
    """
    raw = canopen_table.get("sync", {})
    if not isinstance(raw, dict):
        raise ConfigError("canopen.sync", f"must be a table, got {raw!r}"[:200], source)
    return build_table(SyncCapability, raw, "canopen.sync.", source)
