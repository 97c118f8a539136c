"""Who keeps the bus clock of a streamed CANopen run, and how well it kept it.

A drive in a cyclic mode expects one SYNC per communication cycle, on time to
within its window (:class:`~hilident.protocol.canopen_sync.SyncCapability`).
The SYNC comes, best first, from:

* ``drive``: the drive itself, as SYNC producer (0x1005 bit 30, the period
  in 0x1006), where its ``[canopen.sync]`` says it can. Its clock is the
  drive's own hardware: nothing the host does delays it;
* ``interface``: the CAN interface's cyclic transmit (python-can's
  ``send_periodic``), but only where that is the interface's own (SocketCAN's
  broadcast manager in the kernel, or hardware). python-can's fallback for
  other interfaces is a Python thread that sends every overdue message at
  once after a stall, a burst: it is refused, never used;
* ``host``: the host's Python loop, last. It never bursts: a cycle whose
  instant it missed by more than its window is skipped and counted, the drive
  holds the last set-point, and the sample of that cycle is not recorded.

With the drive or the interface producing SYNC, the host listens to the SYNC
frames and sends each cycle's set-point after the previous SYNC, in time for
the next; one it cannot send in time is skipped (the drive holds the last one)
and counted, never sent late.

:class:`SyncTiming` measures the clock from the SYNC instants (the frames'
timestamps when the host hears them, its own send times when it sends them):
the period, the jitter (p50, p99, max) and the SYNCs outside the drive's
window; the run's summary reports them with the source and why it was chosen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from can.broadcastmanager import ThreadBasedCyclicSendTask

from hilident.errors import ConfigError
from hilident.protocol.canopen_sync import SyncCapability

__all__ = ["SOURCES", "SyncChoice", "SyncTiming", "choose_sync_source", "interface_clock_is_native"]

#: SYNC sources, best first.
SOURCES = ("drive", "interface", "host")


@dataclass(frozen=True)
class SyncChoice:
    """The SYNC source of a run and why it was chosen."""

    source: str
    why: str


def interface_clock_is_native(task) -> bool:
    """Whether a python-can cyclic task is the interface's own (kernel or hardware), not a Python thread."""
    return not isinstance(task, ThreadBasedCyclicSendTask)


def choose_sync_source(
    requested: str,
    capability: SyncCapability,
    can_write_sync_object: bool,
    interface_native: bool | None,
    key: str = "device.canopen.sync_source",
) -> SyncChoice:
    """The SYNC source for ``requested`` (``"auto"`` or one of :data:`SOURCES`).

    Parameters
    ----------
    capability : SyncCapability
        The driver's ``[canopen.sync]``.
    can_write_sync_object : bool
        The EDS has 0x1005 writable (the drive can be told to produce SYNC).
    interface_native : bool or None
        The interface's cyclic transmit is its own (None: not tried).

    Raises
    ------
    ConfigError
        A source was asked for that the drive or the interface does not offer (naming ``key``).
    """
    drive_ok = capability.producer and can_write_sync_object
    if requested in ("auto", "drive") and drive_ok:
        return SyncChoice("drive", "the drive produces SYNC ([canopen.sync] producer = true, 0x1005 bit 30)")
    if requested == "drive":
        why = "its [canopen.sync] does not say producer = true" if not capability.producer else "0x1005 is read-only"
        raise ConfigError(key, f'is "drive" but the drive cannot produce SYNC: {why}')
    if requested in ("auto", "interface") and interface_native:
        return SyncChoice("interface", "the CAN interface's own cyclic transmit (kernel or hardware)")
    if requested == "interface":
        raise ConfigError(
            key,
            'is "interface" but this interface\'s cyclic transmit is a Python thread of python-can (it bursts '
            "after a stall): use SocketCAN, a drive that produces SYNC, or host",
        )
    if requested == "host":
        return SyncChoice("host", "asked for (device.canopen.sync_source = host)")
    return SyncChoice(
        "host",
        "the Python loop: the drive cannot produce SYNC and the interface has no cyclic transmit of its own; "
        "late cycles are skipped, not sent late",
    )


class SyncTiming:
    """SYNC instants of one run and what they say about its clock.

    Parameters
    ----------
    period_s : float
        The nominal period (0x1006).
    window_s : float
        How far a SYNC may stray from its cycle's instant (the drive's window; 0: not monitored).
    capacity : int
        The most SYNCs the run will record.
    """

    def __init__(self, period_s: float, window_s: float, capacity: int):
        self.period_s = float(period_s)
        self.window_s = float(window_s)
        self.cycles = np.zeros(capacity, dtype=np.int64)
        self.instants = np.zeros(capacity)
        self.count = 0

    def add(self, cycle: int, instant_s: float) -> None:
        """Cycle ``cycle``'s SYNC went out (or was heard) at ``instant_s`` (s, any fixed origin)."""
        if self.count < len(self.cycles):
            self.cycles[self.count] = cycle
            self.instants[self.count] = instant_s
            self.count += 1

    def report(self) -> dict:
        """Measured period, jitter about the fitted clock, SYNCs outside the window (JSON-ready)."""
        k, t = self.cycles[: self.count], self.instants[: self.count]
        out: dict = {"syncs": int(self.count), "nominal_period_s": self.period_s, "window_s": self.window_s}
        if self.count < 3:
            return out
        slope, offset = np.polyfit(k - k[0], t - t[0], 1)
        jitter = np.abs((t - t[0]) - (offset + slope * (k - k[0])))
        steps = np.diff(k)
        spread = np.abs(np.diff(t) - steps * self.period_s)
        outside = int(np.count_nonzero(spread > self.window_s)) if self.window_s else 0
        out.update(
            period_s=float(slope),
            jitter_p50_s=float(np.percentile(jitter, 50)),
            jitter_p99_s=float(np.percentile(jitter, 99)),
            jitter_max_s=float(jitter.max()),
            outside_window=outside,
            histogram_us=_histogram_us(jitter),
        )
        return out


def _histogram_us(jitter_s: np.ndarray) -> dict:
    """Counts of |jitter| in decade-and-a-half bins, µs (for the report's histogram)."""
    edges = np.array([0, 10, 30, 100, 300, 1000, 3000, 10000, np.inf])
    counts, _ = np.histogram(jitter_s * 1e6, bins=edges)
    return {"edges_us": [float(e) for e in edges[:-1]], "counts": [int(c) for c in counts]}
