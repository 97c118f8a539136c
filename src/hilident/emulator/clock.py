"""The twins' simulated clock and table player: one of each, for every transport.

A twin runs its physics in simulated time, ``time_scale`` simulated seconds per
wall second. Its server's clock thread asks :class:`SimClock` how much work is
due at the wall time it woke up:

* :meth:`SimClock.samples_due` paces a run: samples due since the run started,
  at the sample rate. A process that was not scheduled for a while (a loaded
  machine) never bursts to catch up: beyond ``max_catch_up_s`` of samples the
  run resumes from now.
* :meth:`SimClock.coast_ticks` lets the axis coast to rest for ``coast_s``
  simulated seconds after a run ends (drive disabled, the plant keeps moving).
* :meth:`SimClock.step` does both for a firmware that offers the
  :class:`PacedFirmware` methods (the serial board, the Modbus drive, the
  CANopen drive's table playback).

:class:`TablePlayer` plays excitation samples through the
:class:`~hilident.emulator.drive.DriveLoop`, each held for ``divider`` loop
ticks, and says where a run must be cut: at an injected fault's time, at the
sample in which the drive faulted, after a capture that stopped.

What the three transports keep of their own: the CANopen drive's synchronous
runs are paced by the host's SYNC frames, not by this clock (one SYNC, one
sample); the serial board paces its line (the UART's baud rate) in its
transmit thread.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from hilident.emulator.drive import DriveLoop

__all__ = ["COAST_S", "PacedFirmware", "Played", "SimClock", "TablePlayer", "cut_at"]

#: Simulated seconds the axis coasts, drive disabled, after a run.
COAST_S = 2.0


class PacedFirmware(Protocol):
    """What :meth:`SimClock.step` needs of a firmware."""

    @property
    def running(self) -> bool: ...

    @property
    def produced(self) -> int: ...

    @property
    def sample_rate_hz(self) -> float: ...

    def advance(self, n_samples: int) -> None: ...

    def idle(self, n_ticks: int) -> None: ...


class SimClock:
    """Simulated time against the wall clock: run pacing without bursts, and coasting after a run.

    Parameters
    ----------
    loop_rate_hz : float
        Drive loop rate, Hz (coasting runs in loop ticks).
    time_scale : float
        Simulated seconds per wall-clock second.
    max_catch_up_s : float
        Most simulated time, s, one call may make up after the clock thread
        ran late; beyond it the run resumes from now.
    coast_s : float
        Simulated time, s, the axis coasts after :meth:`start_coast`.
    """

    def __init__(
        self, loop_rate_hz: float, time_scale: float = 1.0, max_catch_up_s: float = 0.05, coast_s: float = COAST_S
    ):
        self.loop_rate_hz = float(loop_rate_hz)
        self.time_scale = float(time_scale)
        self.max_catch_up_s = float(max_catch_up_s)
        self.coast_s = float(coast_s)
        self._origin = 0.0  # wall time (s) the pacing counts from
        self._done_at_origin = 0  # samples done at that time
        self._coast_left = 0  # loop ticks still to coast
        self._coast_clock = 0.0  # wall time (s) coasting was last advanced

    # --- pacing a run ---------------------------------------------------------------------

    def start_run(self, now: float, done: int = 0) -> None:
        """A run starts at wall time ``now`` (s) with ``done`` samples already played; coasting ends."""
        self._origin, self._done_at_origin = now, done
        self._coast_left = 0

    def samples_due(self, now: float, done: int, rate_hz: float) -> int:
        """Samples to play at wall time ``now`` (s) when ``done`` were played, at ``rate_hz`` simulated.

        Never more than ``max_catch_up_s`` worth (at least one): a clock that
        ran late resumes from now instead of bursting.
        """
        rate = rate_hz * self.time_scale
        due = int((now - self._origin) * rate) - (done - self._done_at_origin)
        cap = max(1, int(self.max_catch_up_s * rate))
        if due > cap:
            self._origin, self._done_at_origin = now, done
            return cap
        return due

    # --- coasting after a run ---------------------------------------------------------------

    def start_coast(self, now: float) -> None:
        """The power stage went off at wall time ``now`` (s): coast for ``coast_s`` simulated seconds."""
        self._coast_left = int(self.coast_s * self.loop_rate_hz)
        self._coast_clock = now

    def stop_coast(self) -> None:
        self._coast_left = 0

    @property
    def coasting(self) -> bool:
        return self._coast_left > 0

    def coast_ticks(self, now: float) -> int:
        """Loop ticks to coast at wall time ``now`` (s); 0 once the coast is over."""
        if self._coast_left <= 0:
            return 0
        n = min(self._coast_left, int((now - self._coast_clock) * self.loop_rate_hz * self.time_scale))
        if n <= 0:
            return 0
        self._coast_left -= n
        self._coast_clock = now
        return n

    # --- both, for a firmware ------------------------------------------------------------------

    def step(self, firmware: PacedFirmware, now: float) -> None:
        """Advance ``firmware`` to wall time ``now`` (s): play a running run's due samples, else coast.

        A run that ends in this step starts the coast.
        """
        if firmware.running:
            firmware.advance(self.samples_due(now, firmware.produced, firmware.sample_rate_hz))
            if not firmware.running:
                self.start_coast(now)
            return
        n = self.coast_ticks(now)
        if n:
            firmware.idle(n)


def cut_at(first: int, n: int, times_s: Iterable[float], rate_hz: float) -> int:
    """How many of ``n`` samples (at ``rate_hz``) from run index ``first`` to play before the first of
    ``times_s`` (run time, s) falls due: a fault injected at a time starts exactly at its sample."""
    for t in times_s:
        k = math.ceil(t * rate_hz - 1e-9)
        if first < k < first + n:
            n = k - first
    return n


@dataclass(frozen=True)
class Played:
    """Samples a :class:`TablePlayer` played.

    Attributes
    ----------
    first : int
        Run index of the first sample.
    rows : numpy.ndarray
        One ``DriveLoop.CHANNELS`` row per sample: the state at the start of
        its sample period, when its excitation begins.
    kept : int
        How many of ``rows`` belong to the run: up to and including the sample
        in which the drive faulted, all of them without a fault.
    fault_sample : int or None
        Run index of the sample in which the drive faulted (None: no fault).
    """

    first: int
    rows: np.ndarray
    kept: int
    fault_sample: int | None = None

    @property
    def faulted(self) -> bool:
        return self.fault_sample is not None

    @property
    def end(self) -> int:
        """Run index after the last kept sample."""
        return self.first + self.kept


class TablePlayer:
    """Play excitation samples through a drive loop, one sample every ``divider`` loop ticks.

    Parameters
    ----------
    drive : DriveLoop
    divider : int
        Loop ticks per sample.
    loop_rate_hz : float
    averaged : iterable of str
        Columns of ``drive.CHANNELS`` recorded as the mean over each sample period's ticks (the
        driver's ``sampling = "mean"`` channels); the others at the period's first tick.

    Attributes
    ----------
    start_tick : int
        The drive's tick when the run started (:meth:`restart`).
    """

    def __init__(self, drive: DriveLoop, divider: int, loop_rate_hz: float, averaged: Iterable[str] = ()):
        self.drive = drive
        self.divider = int(divider)
        self.loop_rate_hz = float(loop_rate_hz)
        self.start_tick = drive.tick
        self.averaged = drive.columns_of([n for n in averaged if n in drive.CHANNELS], "averaged channel")

    @property
    def sample_rate_hz(self) -> float:
        return self.loop_rate_hz / self.divider

    def restart(self, divider: int | None = None) -> None:
        """A run starts now (at the drive's present tick), optionally at another divider."""
        if divider is not None:
            self.divider = int(divider)
        self.start_tick = self.drive.tick

    def cut_at(self, first: int, n: int, times_s: Iterable[float]) -> int:
        """:func:`cut_at` at this player's sample rate."""
        return cut_at(first, n, times_s, self.sample_rate_hz)

    def samples_before(self, seconds: float) -> int:
        """Samples of a run whose period starts before run time ``seconds``."""
        return max(0, math.ceil(seconds * self.sample_rate_hz - 1e-9))

    def fault_sample(self) -> int | None:
        """Run index of the sample in which the drive faulted (None: no fault)."""
        if self.drive.fault is None or self.drive.fault_tick is None:
            return None
        return (int(self.drive.fault_tick) - self.start_tick) // self.divider

    def play(self, values: np.ndarray, first: int) -> Played:
        """Play ``values`` (one per sample, run index ``first`` on) and return what the run keeps."""
        d = self.divider
        self.drive.setpoint_ticks = d
        ticks = self.drive.run(np.repeat(np.asarray(values, dtype=float), d))
        rows = ticks[::d]
        if self.averaged and d > 1:
            cols = self.averaged
            rows[:, cols] = ticks[:, cols].reshape(len(rows), d, len(cols)).mean(axis=1)
        kept = len(rows)
        fault = self.fault_sample()
        if fault is not None:
            kept = max(0, min(kept, fault - first + 1))
        return Played(first, rows, kept, fault)
