"""Several CANopen twins on one mechanism: their loops step one :class:`~hilident.emulator.coupled_plant.CoupledPlant`
on the same ticks, whatever their threads' timing.

A :class:`MechanismGroup` keeps the nodes' steps aligned on the mechanism's ticks:

* while SYNC comes, every node steps at each SYNC: a node in a SYNC-driven run
  its cycles, any other node (disabled, torque 0) the ticks the nodes' one
  SYNC clock (:meth:`MechanismGroup.verdict`) runs at that SYNC; each first
  catches up to where the steps of the earlier SYNCs ended
  (:meth:`MechanismGroup.start_of`), so the cycles of one SYNC on all nodes
  are the same ticks of the mechanism. A node producing the SYNC runs its cycle
  as it reads its own SYNC, as its partners do;
* while no SYNC comes and no node is in a SYNC-driven run, the nodes idle at
  the loop rate on the wall clock (``time_scale``), towards one target for all;
* a table run (or a vendor drive's generator) paces its node by the drive's
  clock; the others idle on the wall clock beside it.

Every run a node's loop makes is announced first (:class:`LockstepDrive`), so a
partner knows how far to step. :class:`NodeOnMechanism` is one node's part:
what its server's SYNC subscription and clock thread call.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from hilident.emulator.canopen.firmware import CanopenDriveFirmware
from hilident.emulator.canopen.production import SyncProducer
from hilident.emulator.canopen.sync import SyncMonitor, SyncVerdict
from hilident.emulator.coupled_plant import CoupledPlant, PlantPort
from hilident.emulator.drive import DriveLoop
from hilident.protocol import cia402

__all__ = ["NO_TAG", "LockstepDrive", "MechanismGroup", "NodeOnMechanism"]

NO_TAG = -math.inf
_QUIET_S = 0.02  # no SYNC for this long (at least three SYNC periods): the nodes idle on the wall clock
_MAX_LEAD_S = 0.05  # most wall time the idling nodes make up at once after a stall (no bursts)
_KEPT_RUNS = 64  # announced runs a MechanismGroup keeps by their tag


class LockstepDrive(DriveLoop):
    """A :class:`~hilident.emulator.drive.DriveLoop` on a port of a mechanism that announces every run.

    Before a run steps, its group hears where it will end (the mechanism's tick after its last), tagged with
    :attr:`tag`; a partner idling meanwhile steps as far (:class:`MechanismGroup`). While the group closes, each
    run ends by taking the port out of the lockstep.

    Attributes
    ----------
    group : MechanismGroup or None
        None until the node's server runs (the runs of its power-up are its own).
    tag : float
        The SYNC (its bus timestamp, s) the runs now belong to; :data:`NO_TAG` for none.
    """

    group: MechanismGroup | None = None
    tag: float = NO_TAG

    @property
    def port(self) -> PlantPort:
        """The node's port of the mechanism."""
        if not isinstance(self.plant, PlantPort):
            raise TypeError("a LockstepDrive runs on a PlantPort")
        return self.plant

    def run(self, excitation) -> np.ndarray:
        """:meth:`DriveLoop.run <hilident.emulator.drive.DriveLoop.run>`, announced to the group first."""
        group = self.group
        if group is None:
            return super().run(excitation)
        port = self.port
        group.announce(self.tag, port.plant.ticks + int(np.size(excitation)))
        try:
            return super().run(excitation)
        finally:
            if group.closing:
                port.detach()


def _self_paced(fw: CanopenDriveFirmware) -> bool:
    """A run the drive's own clock paces: a table playing, or a vendor drive's generator or recorder."""
    recorder = fw.recorder
    return fw.playback.running or (
        recorder is not None and recorder.active and fw.state is cia402.State.OPERATION_ENABLED
    )


def _in_sync_run(fw: CanopenDriveFirmware) -> bool:
    """A SYNC-driven run that has had its first SYNC (its cycles come with the SYNCs)."""
    return fw.pdo.running() and fw.pdo.last_sync_stamp is not None


class MechanismGroup:
    """The nodes on one mechanism: where their steps end, so that all of them step the same ticks.

    Parameters
    ----------
    plant : CoupledPlant
    loop_rate_hz : float
        The nodes' loop rate, Hz (the driver's).
    time_scale : float
        Simulated seconds per wall second while the nodes idle on the wall clock.

    Attributes
    ----------
    members : list of CanopenDriveFirmware
        The nodes, in node order.
    divider : int
        Loop ticks per SYNC period of the last SYNC-driven cycle a node ran (0: none yet).
    closing : bool
        Set by :meth:`CanopenBusServer.close`: nothing new steps, a run that ends leaves the lockstep.
    """

    def __init__(self, plant: CoupledPlant, loop_rate_hz: float, time_scale: float = 1.0):
        self.plant = plant
        self.loop_rate_hz = float(loop_rate_hz)
        self.rate = self.loop_rate_hz * float(time_scale)
        self.members: list[CanopenDriveFirmware] = []
        self.divider = 0
        self.closing = False
        self._lock = threading.Lock()
        self._runs: list[tuple[float, int]] = []  # (tag, the mechanism's tick it ends at) of the recent runs
        self._floor = plant.ticks  # where the runs before those ended
        self._heard = -math.inf  # monotonic time a node last heard a SYNC
        self._stamp = -math.inf  # bus timestamp of that SYNC
        self._interval = 0.0  # s between the last two SYNCs (their bus timestamps)
        self._anchor: tuple[float, int] | None = None  # (wall time, tick) the idling counts from
        self._clock: SyncMonitor | None = None  # the nodes' clock, locked to the SYNCs (as each drive's is)
        # what it made of the recent SYNCs, by bus timestamp, and its reference after each
        self._verdicts: dict[float, tuple[SyncVerdict, float | None]] = {}
        self._judged = -math.inf  # bus timestamp of the last SYNC it judged

    def announce(self, tag: float, end: int) -> None:
        """A run of the SYNC ``tag`` (:data:`NO_TAG`: of none) that ends at the mechanism's tick ``end``."""
        with self._lock:
            self._runs.append((tag, end))
            if len(self._runs) > _KEPT_RUNS:
                self._floor = max(self._floor, *(e for _, e in self._runs[: -_KEPT_RUNS // 2]))
                del self._runs[: -_KEPT_RUNS // 2]

    def start_of(self, tag: float) -> int:
        """The mechanism's tick where the steps of SYNC ``tag`` begin: where every run of an earlier SYNC (or of
        none) ends."""
        with self._lock:
            return max(self._floor, *(e for t, e in self._runs if t < tag), 0)

    def reached(self) -> int:
        """Where the last announced run ends."""
        with self._lock:
            return self._reached()

    def _reached(self) -> int:
        return max(self._floor, *(e for _, e in self._runs), 0)

    def heard_sync(self, now: float, timestamp: float) -> None:
        """A node heard the SYNC of bus timestamp ``timestamp`` (s) at monotonic time ``now`` (s)."""
        with self._lock:
            if timestamp > self._stamp:  # the first node to hear it
                if timestamp - self._stamp < 1.0:
                    self._interval = timestamp - self._stamp
                self._stamp = timestamp
            self._heard = now

    def verdict(self, timestamp: float, divider: int) -> SyncVerdict:
        """What the nodes' clock makes of the SYNC of bus timestamp ``timestamp`` (s), in cycles of ``divider`` loop
        ticks: the same verdict for every node that asks (:class:`~hilident.emulator.canopen.sync.SyncMonitor`, the
        clock each drive keeps, here one for all of them, locked to every SYNC since the nodes last idled on the
        wall clock)."""
        return self._judge(timestamp, divider)[0]

    def clock_reference(self, timestamp: float) -> float | None:
        """Bus time (s) of the cycle instant the nodes' clock counted from after the SYNC of bus timestamp
        ``timestamp`` (s) (None: not judged)."""
        with self._lock:
            found = self._verdicts.get(timestamp)
            return None if found is None else found[1]

    def _judge(self, timestamp: float, divider: int) -> tuple[SyncVerdict, float | None]:
        with self._lock:
            found = self._verdicts.get(timestamp)
            if found is not None:
                return found
            if self._clock is None:
                self._clock = SyncMonitor(self.members[0].desc.sync)
            if timestamp - self._judged > self.quiet_s:
                self._clock.restart()  # after a pause: the clock locks anew
            self._judged = max(self._judged, timestamp)
            verdict = self._clock.observe(timestamp, divider / self.loop_rate_hz)
            found = self._verdicts[timestamp] = (verdict, self._clock.reference)
            if len(self._verdicts) > _KEPT_RUNS:
                del self._verdicts[min(self._verdicts)]
            return found

    def divider_of(self, fw: CanopenDriveFirmware) -> int:
        """Loop ticks per SYNC period of node ``fw``: its own (0x1006, 0x60C2), else the nodes' last cycles'."""
        return fw.pdo.sync_divider or self.divider

    @property
    def quiet_s(self) -> float:
        """How long no SYNC must come before the nodes idle on the wall clock, s."""
        return max(_QUIET_S, 3.0 * self._interval)

    def idle_target(self, now: float) -> int | None:
        """The mechanism's tick the nodes idle to at monotonic time ``now`` (s); None while SYNC paces them.

        One target for all nodes, at the loop rate from where the last run ended (never more than
        ``_MAX_LEAD_S`` ahead of the mechanism: a stalled process resumes instead of bursting).
        """
        with self._lock:
            if now - self._heard < self.quiet_s or any(_in_sync_run(fw) for fw in self.members):
                self._anchor = None
                return None
            reached = max(self._reached(), self.plant.ticks)
            if self._anchor is None:
                self._anchor = (now, reached)
            wall, tick = self._anchor
            target = tick + int((now - wall) * self.rate)
            lead = int(_MAX_LEAD_S * self.rate)
            if target - reached > lead:
                self._anchor = (now, reached + lead)
                target = reached + lead
            return target


class NodeOnMechanism:
    """What one node's server does for the :class:`MechanismGroup`: steps at SYNCs and on the wall clock."""

    def __init__(self, firmware: CanopenDriveFirmware, drive: LockstepDrive, group: MechanismGroup):
        self.fw = firmware
        self.drive = drive
        self.group = group
        self.last_sync: float | None = None  # bus timestamp of the last SYNC this node heard
        firmware.clock.coast_s = 0.0  # the node never stops: no coast to count down

    def on_sync(self, can_id, data, timestamp) -> None:
        """Every SYNC, the node's own too: a SYNC-driven run's cycle, after catching up to where this SYNC's steps
        begin; else the ticks of the SYNC's period, disabled.

        A node producing the SYNC runs its cycle here too, as its partners do (not at its next SYNC instant, as a
        node alone does): the set-points stamped before the SYNC are latched, and the frames before it on the
        bus are read by now.
        """
        fw, group = self.fw, self.group
        if group.closing:
            return
        with fw.lock:
            group.heard_sync(time.monotonic(), timestamp)
            previous, self.last_sync = self.last_sync, timestamp
            producing = fw.pdo.producing
            if producing:
                fw.setpoints.latch(timestamp)
                fw.pdo.producing = False  # its cycle: the consumer's
            self.drive.tag = timestamp
            try:
                self._step(can_id, data, timestamp, previous)
            finally:
                self.drive.tag = NO_TAG
                fw.pdo.producing = producing

    def _step(self, can_id, data, timestamp: float, previous: float | None) -> None:
        """The node's steps for the SYNC of bus timestamp ``timestamp`` (s; ``previous``: the one before)."""
        fw, group = self.fw, self.group
        cycles = fw.pdo.running() and fw.node.nmt.state == "OPERATIONAL"
        divider = fw.pdo.sync_divider or group.divider
        if cycles:
            divider = group.divider = fw.divider()
        verdict = group.verdict(timestamp, divider) if divider else None
        first = cycles and fw.pdo.last_sync_stamp is None  # a run's first SYNC: its cycle 0
        if cycles:
            # a run's first SYNC: the cycles its partners ran on the nodes' clock before it are no cycles of its own
            self._catch_up(timestamp, verdict.held if first and verdict is not None else 0)
        fw.pdo.on_sync(can_id, data, timestamp)
        reference = group.clock_reference(timestamp) if first else None
        if reference is not None and fw.pdo.monitor.reference is not None:
            fw.pdo.monitor.reference = reference  # its clock is the nodes' clock as this SYNC left it
        if not cycles and not _self_paced(fw):
            self._idle_for_sync(timestamp, previous, verdict)

    def instant(self, producer: SyncProducer, late_s: float, due_wall_s: float) -> None:
        """The node's own SYNC instant (:meth:`SyncProducer.instant`): the SYNC goes out, its cycle runs when the
        node reads it (:meth:`on_sync`)."""
        fw = self.fw
        if self.group.closing:
            return
        with fw.lock:
            producer.cycle_open = False
            try:
                producer.instant(late_s, due_wall_s)
            finally:
                producer.cycle_open = False

    def idle(self, now: float) -> None:
        """The clock thread's turn: idle towards the group's target on the wall clock while no SYNC paces the
        nodes."""
        fw = self.fw
        with fw.lock:
            if self.group.closing or _self_paced(fw):
                return
            target = self.group.idle_target(now)
            if target is None:
                return
            n = target - self.drive.port.plant.ticks
            if n > 0:
                fw.last_row = self.drive.run(np.full(n, self._held_input()))[-1]

    def _held_input(self) -> float:
        """What the loop runs on between cycles: nothing while disabled, else the set-point it holds."""
        fw = self.fw
        if not fw.drive.enabled:
            return 0.0
        held = fw.pdo.held_input
        return fw.setpoints.drive_input() if held is None else held

    def _catch_up(self, tag: float, missed: int = 0) -> None:
        """Before a cycle of SYNC ``tag``: step (holding the set-point) to where the steps of that SYNC begin, and
        ``missed`` SYNC periods beyond (the cycles the nodes' clock ran before a run's first SYNC); a run's first
        cycle starts the run's tick count there."""
        fw = self.fw
        target = self.group.start_of(tag) + missed * fw.divider()
        n = target - self.drive.port.plant.ticks
        if n > 0:
            fw.last_row = self.drive.run(np.full(n, self._held_input()))[-1]
        if fw.sample_index == 0:
            fw.run_start_tick = self.drive.tick

    def _idle_for_sync(self, timestamp: float, previous: float | None, verdict: SyncVerdict | None) -> None:
        """A node without cycles steps the ticks the nodes' clock runs at this SYNC (the cycles it ran without a
        SYNC, and the one this SYNC starts), from where the steps of this SYNC begin."""
        fw, group = self.fw, self.group
        if verdict is not None:
            ticks = group.divider_of(fw) * (verdict.held + verdict.answer)
        else:  # no SYNC period known: the time since the SYNC before
            gap = timestamp - previous if previous is not None else math.inf
            if gap > group.quiet_s:
                return
            ticks = max(1, round(gap * fw.loop_rate))
        n = group.start_of(timestamp) + ticks - self.drive.port.plant.ticks
        if n > 0:
            fw.playback.idle(n)
