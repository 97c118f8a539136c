"""Host-streamed runs of several nodes on one SYNC: every node's set-points per cycle, every node's TPDOs back.

Each node has its own :class:`~hilident.adapters.canopen.streamed.StreamedRun` (its RPDO, its TPDOs, their
matching to samples, its counters, its events), and one clock runs them all:

* **the host's clock**: the first node's run keeps the cycle; at each cycle's instant every node's set-point
  that must be re-sent goes out, then one SYNC, then every node's next set-point ahead. A cycle the host missed
  is skipped on every node at once (no SYNC, no sample anywhere);
* **a drive's or the interface's clock**: the first node's run starts it (0x1005 bit 30 on that node, or the
  interface's cyclic task) and stops it; every node's run hears the same SYNCs and sends its set-points.

Every node is enabled, and its first set-point is on the bus, before the first SYNC, so the drives'
sample counters (cycles since Operation Enabled) all count the same cycles.

A sample of the run is a row of every node's channels; it is delivered once every node has its part, and a
part one node lost loses the whole row (counted by that node, never filled). A fault on one node (its
emergency, a limit the host checks, a lost heartbeat) switches every node off at once and stops the SYNCs; the
run then ends with that node's fault.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from hilident.adapters.base import Deliver
from hilident.adapters.canopen.ip_buffer import close_buffer
from hilident.adapters.canopen.streamed import StreamedRun
from hilident.events import StreamStats

if TYPE_CHECKING:
    from hilident.adapters.canopen.drive import CanopenDriveAdapter

__all__ = ["GroupStreamedRun"]

_POLL_S = 0.002  # the run's thread sleeps this long between passes


class GroupStreamedRun:
    """One run of every node's column of ``x`` on one SYNC; see the module docstring.

    Parameters
    ----------
    adapters : sequence of CanopenDriveAdapter
        One per node, on one bus, each configured for a streamed run and its run opened
        (:meth:`~hilident.adapters.base.AdapterBase.open_run`: its ``last_result`` is this run's). The first keeps
        the clock.
    x : ndarray, shape (N, n_nodes)
        Each node's set-points, one column per node, in its mode's SI unit.
    sink : callable
        ``sink(sample_index, rows)``: the joint rows, every node's channels side by side in node order.
    from_sink : list
        Where what ``sink`` raised is noted (:meth:`~hilident.adapters.base.AdapterBase.run_deliver`).
    progress : callable, optional
        ``progress(fraction)`` as joint rows are delivered.
    """

    def __init__(
        self,
        adapters: Sequence[CanopenDriveAdapter],
        x: np.ndarray,
        sink: Deliver,
        from_sink: list[BaseException],
        progress: Callable[[float], None] | None = None,
    ):
        self.n = len(x)
        self.members = []
        for i, ad in enumerate(adapters):
            assert ad.last_result is not None, "open_run() before the group's run"
            deliver = ad.run_deliver(self.collector(i), self.n, None, from_sink)  # the node's host limit check
            self.members.append(StreamedRun(ad, np.ascontiguousarray(x[:, i]), deliver, ad.last_result))
        lead = self.members[0]
        for member in self.members[1:]:
            member.clock_stop = lead.clock_stop  # one clock: any node's fault stops it for all
            member.owns_clock = False
        lead.cycle_members = self.members
        self.sink = sink
        self.progress = progress
        self.tables = [np.zeros((self.n, len(m.ad.layout.channels))) for m in self.members]
        self.got = np.zeros((len(self.members), self.n), dtype=bool)
        self.flushed = 0  # joint rows below are delivered or dropped
        self.cap = self.n  # no joint row at or beyond it is delivered (a node's fault: the sample after it)
        self.samples = 0  # joint rows delivered
        self.stopped = False  # every node switched off, the clock told to stop

    def collector(self, i: int) -> Deliver:
        """Where node ``i``'s run delivers: its part of each joint row."""

        def collect(index: np.ndarray, rows: np.ndarray) -> None:
            self.tables[i][index] = rows
            self.got[i, index] = True

        return collect

    def flush(self, limit: int) -> None:
        """Deliver the joint rows below ``limit`` every node has; drop the others (a node lost its part). Nothing
        after a node's fault is delivered."""
        limit = min(limit, self.cap)
        a = self.flushed
        if limit <= a:
            return
        idx = np.flatnonzero(self.got[:, a:limit].all(axis=0)) + a
        self.flushed = limit
        if len(idx):
            self.samples += len(idx)
            self.sink(idx.astype(np.int64), np.hstack([t[idx] for t in self.tables]))
            if self.progress is not None:
                self.progress(min(1.0, (int(idx[-1]) + 1) / max(self.n, 1)))

    @property
    def final(self) -> int:
        """The sample index below which every node's samples are final."""
        return min(m.final for m in self.members)

    def stop_all(self) -> None:
        """Every node's power stage off, then the clock told to stop (never raises; once)."""
        if self.stopped:
            return
        self.stopped = True
        for member in self.members:
            with contextlib.suppress(Exception):
                member.ad.safe_stop()
        self.members[0].clock_stop.set()

    def run(self) -> None:
        """Play the run on every node; each node's result filled, the joint rows delivered to ``sink``."""
        lead = self.members[0]
        for member in self.members:
            for cob in member.frames:
                member.ad.network.subscribe(cob, member.on_tpdo)
        lead.choice = lead.choose_source()
        for member in self.members[1:]:
            member.choice = lead.choice
        try:
            for member in self.members:
                member.begin()  # enabled, harmless set-point; with the host's clock, set-point 0 ahead
            if lead.choice.source == "host":
                lead.start_host_clock(lead._host_clock)
            else:
                for member in self.members:
                    member.arm_listening()
                lead.start_listening_clock()
            self._loop()
            self._stop_clock()
            for member in self.members:
                member._settle()
            self.flush(self.final)
            for member in self.members:
                self._close_member(member)
        except BaseException:
            self.stop_all()
            for member in self.members:
                member.note_skipped()
                with contextlib.suppress(Exception):
                    member.drain()
                    member.finalize(member.sent - member.lost_after)
                    member.finalize(member.sent, count_lost=False)
            with contextlib.suppress(Exception):
                self.flush(self.final)
            raise
        finally:
            self._stop_clock()
            for member in self.members:
                with contextlib.suppress(Exception):
                    close_buffer(member.ad.sdo, member.ad.desc, member.rpdo.setpoint_role)
                member.result.clock = member.clock_report()
                for cob in [*member.frames, 0x80]:
                    with contextlib.suppress(KeyError, ValueError):
                        member.ad.network.unsubscribe(cob, member.on_tpdo if cob != 0x80 else member.on_sync)

    def _close_member(self, member: StreamedRun) -> None:
        """A node's run after the clock stopped: its skipped set-points, unanswered SYNCs or drive counters."""
        member.note_skipped()
        if member.ad.run_fault is None and not member.counted:
            member.note_unanswered()
        if member.ad.run_fault is None and member.counted:
            member.read_drive_counters()
        member.result.completed = member.ad.run_fault is None and not self.stopped

    def _loop(self) -> None:
        """Every node's run polled until all are over, or a node's fault ended it for all."""
        done = [False] * len(self.members)
        while True:
            now = time.perf_counter()
            for i, member in enumerate(self.members):
                if not done[i]:
                    done[i] = member.poll(now, beat=i == 0)
            faulted = [i for i, m in enumerate(self.members) if m.fault is not None]
            if faulted:
                self.stop_all()
                first = faulted[0]
                if done[first]:
                    fault = self.members[first].fault
                    assert fault is not None
                    last = min(self.members[first].sent, int(fault["sample_index"]) + 1)
                    self.cap = last
                    for i, member in enumerate(self.members):
                        if not done[i]:
                            member.end_early(last)
                    self.flush(last)
                    return
            elif all(done):
                return
            self.flush(self.final)
            time.sleep(_POLL_S)

    def _stop_clock(self) -> None:
        """The SYNCs stop, every node switched off first where they come from the host or the interface (a
        drive that consumes SYNC faults when they stop in a cyclic mode). Never raises."""
        lead = self.members[0]
        if not lead.clock_stopped and (lead.sender is not None or lead.periodic_task is not None):
            for member in self.members[1:]:
                with contextlib.suppress(Exception):
                    member.ad.safe_stop()
        for member in self.members:
            member._stop_clock()

    def stats(self) -> StreamStats:
        """The run's counters: every node's added, with the joint rows delivered as its samples."""
        total = StreamStats()
        for member in self.members:
            total = total.add(member.stats)
        total.samples = self.samples
        return total
