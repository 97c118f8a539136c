"""Host-streamed runs on a CANopen drive: one set-point per cycle, one SYNC per cycle, TPDOs back.

The bus clock comes from the drive, the CAN interface or, last, the host's
Python loop (:mod:`~hilident.adapters.canopen.sync_source` chooses and
measures it). Set-point ``k`` must reach the drive before SYNC ``k``; the drive
applies it for the cycle that SYNC starts and answers with its TPDOs
(transmission type 1), carrying the state at the start of that cycle:

* **listening** (the drive or the interface produces SYNC): the host sends
  set-point ``k + 1`` as soon as it hears SYNC ``k``, if it is no more than
  0.9 of a period after it; otherwise it skips it (the drive holds the last
  set-point, or extrapolates a position at its last velocity as CSP and IP
  drives do, and the recorded set-point of that cycle is that one) and counts
  it in ``setpoints_skipped``. A drive with an interpolation data buffer
  (:mod:`~hilident.adapters.canopen.ip_buffer`) takes set-points up to 15
  cycles ahead, each sent only while it can reach the drive before its own
  SYNC. SYNCs, and so samples, never depend on the host's timing;
* **host** (the Python loop): SYNC ``k`` goes out at the cycle's instant, or
  within the host's window after it (three quarters of the drive's SYNC
  window, at most 0.4 of a period), from a thread that does nothing else, and
  set-point ``k + 1`` right after it (a drive applies an
  RPDO at the SYNC after it), so nothing but the SYNC waits on the deadline. A
  cycle whose window the loop missed is skipped: no SYNC, no sample (the
  drive's own clock runs it with the set-point it holds), counted in
  ``setpoints_skipped`` and marked by a ``sync_skipped`` event; the next cycle
  sent gets its own set-point again before its SYNC. Never sent late, one SYNC
  per pass: never a burst.

Which sample a TPDO belongs to is known in one of two ways:

* **counted**: on a drive with the hilident counters every TPDO is headed by
  the drive's sample counter (cycles since Operation Enabled), so each frame
  names its cycle;
* **ordered** (every other CiA 402 drive, standard objects only): CAN keeps
  the order of frames, and a drive answers each SYNC with its TPDOs in PDO
  number order, so the answers form consecutive sets; a frame whose PDO
  number is not above the previous frame's starts the next set, and the
  ``n``-th set answers the ``n``-th SYNC of the run (whose cycle the host
  knows). A set with a frame missing is a lost sample at a known index. A
  SYNC the drive did not answer at all (a whole set missing) shows only in the
  count: the samples after it shift by one, which the run reports
  (``sync_unanswered``) with the number of unanswered SYNCs; such samples are
  never filled in. Channels the drive does not report (the set-point, on
  drives without an applied-set-point object) are the host's own.

The host assembles a sample from its TPDOs:

* a sample whose TPDOs did not all arrive within ``lost_after`` cycles after
  its SYNC (at the end of the run: ``_GRACE_S`` after the last SYNC or the last
  new sample, whichever is later) is lost: counted (``lost_samples``,
  ``lost_blocks``, and ``lost_frames`` for the missing TPDOs), logged as a
  ``lost_blocks`` event, never filled in; a skipped cycle is not lost (it was
  never asked for);
* a TPDO arriving after its sample was given up is late: counted as
  ``out_of_order`` and discarded;
* set-points that reached the drive after their SYNC are the drive's
  ``underruns`` (read from its diagnostics at the end, where it has them).

The SYNC source, the measured period and jitter, the SYNCs outside the
drive's window and the skipped set-points are the run's ``clock`` report
(``RunResult.clock``, in ``summary.json``).

An emergency stops the run at once (the drive already switched its power
stage off); the samples up to the fault are delivered, then the run ends with
LimitTrip (a limit) or DeviceError. A lost heartbeat ends it with DeviceError,
and so do TPDOs lagging more than a second behind the SYNCs (the drive does not
keep up; flooding it further would only queue frames). A drive producing SYNC
is told to stop (0x1005 bit 30 cleared) on every ending.
"""

from __future__ import annotations

import collections
import struct
import threading
import time
from collections.abc import Callable
from typing import Protocol

import can
import numpy as np

from hilident.adapters.base import RunResult, RunStrategy
from hilident.adapters.canopen.common import DriveIdentity, DriveRatings, RunLayout
from hilident.adapters.canopen.ip_buffer import close_buffer, open_buffer
from hilident.adapters.canopen.net import NetWatch
from hilident.adapters.canopen.sdo import SdoAccess
from hilident.adapters.canopen.sync_source import SyncChoice, SyncTiming, choose_sync_source, interface_clock_is_native
from hilident.adapters.canopen.trace import TracingNetwork
from hilident.config.tables import DeviceConfig
from hilident.drivers.description import DriverDescription
from hilident.errors import DeviceError
from hilident.events import Kind, RunEvent
from hilident.protocol.canopen_objects import CanopenDescription, numpy_type, type_bits
from hilident.protocol.canopen_sync import SYNC_GEN_BIT

__all__ = ["StreamedRun", "DriveHost", "Deliver", "POSITION_SETPOINTS"]

#: Set-point roles that are positions (targets relative to where the axis holds at enable).
POSITION_SETPOINTS = ("target_position", "interpolation_data")

#: Where a strategy hands ``(sample indices, rows)`` blocks (the template's ``deliver``).
Deliver = Callable[[np.ndarray, np.ndarray], None]

_GRACE_S = 0.25  # after the last SYNC (or an emergency), wait this long for the TPDOs in flight
_SPIN_S = 2e-4  # host clock: the last this many seconds before a cycle's instant are spun, not slept
_SETTLE_S = 0.02  # after the clock stopped, the answers to its last SYNCs are awaited this long
_LEAD = 0.9  # listening: a set-point goes out only within this share of a period after the SYNC before it


class DriveHost(Protocol):
    """What a CANopen acquisition strategy uses of its adapter
    (:class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`).

    The parts the adapter owns: ``sdo`` (the drive's objects,
    :class:`~hilident.adapters.canopen.sdo.SdoAccess`) and ``net`` (the link
    check, the host's heartbeat, the emergency queue to wait on,
    :class:`~hilident.adapters.canopen.net.NetWatch`); the run's ``layout`` as
    ``configure()`` left it (mode, rate, channels, PDOs); ``desc`` (the
    driver's objects and modes), ``driver``, ``device`` (its config: the SYNC
    source asked for), ``sync_overflow``, ``excitation_recipe`` (recorder), the ``ratings``,
    ``timeout_s``, ``port``; the bus ``network`` (``send_message``,
    ``subscribe``, ``unsubscribe``); the run: ``events`` (read only: log with
    :meth:`log_event`) and ``run_fault`` (read only: note with
    :meth:`take_emergency_fault`). The adapter's ``ACQUISITIONS`` table is
    typed with this protocol, so the type checker holds the adapter to it.
    """

    port: str
    timeout_s: float
    network: TracingNetwork
    sdo: SdoAccess
    net: NetWatch
    driver: DriverDescription
    desc: CanopenDescription
    layout: RunLayout
    device: DeviceConfig
    sync_overflow: int
    excitation_recipe: dict | None
    ratings: DriveRatings
    events: list[dict]
    run_fault: dict | None

    def drive_identity(self) -> DriveIdentity: ...

    def scale(self, role: str) -> float: ...

    def enable(self) -> None:
        """CiA 402 state machine to Operation Enabled."""

    def safe_stop(self) -> None:
        """Power stage off now; never raises."""

    def take_emergency_fault(self, sample_index: int) -> dict | None:
        """Log the queued emergencies up to the first fault; that fault (noted as the run's), or None."""

    def log_event(self, event: RunEvent) -> dict: ...

    def encode_setpoints(self, x: np.ndarray, datatype: int, role: str, origin_raw: int = 0) -> np.ndarray: ...

    def decode_rows(self, raw_columns: list[np.ndarray], first_index: int = 0) -> np.ndarray: ...

    def count_saturated(self, raw: np.ndarray, first_index: int) -> None: ...


def choose_clock(ad: DriveHost, period_s: float) -> tuple[SyncChoice, can.broadcastmanager.CyclicSendTaskABC | None]:
    """The SYNC source for a streamed run on ``ad`` (see :mod:`~hilident.adapters.canopen.sync_source`).

    Returns the choice and, when it is the interface, its cyclic SYNC task set
    up but not started. A SYNC counter (0x1019) changes every frame, which no
    interface's own cyclic transmit does: then the interface is not tried.

    Raises
    ------
    ConfigError
        ``device.canopen.sync_source`` asks for a source the drive or the interface does not offer.
    """
    requested = ad.device.canopen.sync_source
    writable = ad.desc.has("sync_cob_id") and ad.sdo.eds_variable(ad.desc.address("sync_cob_id")).writable
    task = None
    drive_first = requested == "auto" and ad.desc.sync.producer and writable
    bus = getattr(ad.network, "bus", None)
    if requested in ("auto", "interface") and not drive_first and bus is not None and ad.sync_overflow <= 1:
        try:
            task = bus.send_periodic(
                can.Message(arbitration_id=0x80, data=b"", is_extended_id=False), period_s, autostart=False
            )
        except (can.CanError, NotImplementedError, TypeError, ValueError):
            task = None
        if task is not None and not interface_clock_is_native(task):
            task.stop()
            task = None
    choice = choose_sync_source(
        requested, ad.desc.sync, writable, None if task is None and drive_first else task is not None
    )
    if choice.source != "interface" and task is not None:
        task.stop()
        task = None
    return choice, task


class StreamedRun(RunStrategy):
    """One host-streamed run: the set-points, SYNCs, received TPDOs and their matching to samples.

    See the module docstring. State: the raw sample table and the mask of
    the TPDOs received per sample, the index below which samples are final
    (delivered or counted lost), the cycles started (``sent``), the SYNCs of
    the run and their cycles, the cycles skipped.
    """

    ad: DriveHost

    def __init__(self, adapter: DriveHost, x: np.ndarray, deliver: Deliver, result: RunResult):
        super().__init__(adapter, x, deliver, result)
        ad = adapter
        n = self.n
        layout = ad.layout
        if layout.rpdo is None:
            raise DeviceError(f"{ad.port}: configure() for streamed acquisition before stream(): no RPDO is mapped")
        self.rpdo = layout.rpdo  # the RPDO configure() mapped
        self.counted = ad.desc.counted
        counter_char, self.counter_mod = "", 0
        if self.counted:
            counter_type = ad.sdo.data_type(ad.desc.address("sample_counter"))
            counter_char, self.counter_mod = numpy_type(counter_type).char, 1 << type_bits(counter_type)
        #: COB-ID -> (its bit in the mask, its layout, the channel columns it carries, its rank in PDO order)
        self.frames: dict[int, tuple[int, struct.Struct, np.ndarray, int]] = {}
        for rank, tpdo in enumerate(layout.tpdos):
            fmt = "<" + counter_char + "".join(numpy_type(layout.channels[i].datatype).char for i in tpdo.columns)
            self.frames[tpdo.cob_id] = (1 << rank, struct.Struct(fmt), np.asarray(tpdo.columns, dtype=np.intp), rank)
        self.full = (1 << len(self.frames)) - 1
        self.scales = np.array([c.scale for c in layout.channels])
        self.host_columns = [j for j, c in enumerate(layout.channels) if c.on_host]
        self.raw = np.zeros((n, len(layout.channels)))
        for j in self.host_columns:
            self.raw[:, j] = x  # the set-point the host sends, in SI units (scale 1)
        self.mask = np.zeros(n, dtype=np.uint32)
        self.skipped = np.zeros(n, dtype=bool)  # host clock: cycles without a SYNC (no sample asked for)
        self.answered_set, self.answered_rank = -1, len(self.frames)  # ordered matching: the set, its last PDO
        self.rx: collections.deque[tuple[int, bytes]] = collections.deque()  # (COB-ID, data) as received
        self.period = 1.0 / layout.sample_rate_hz
        self.lost_after = max(16, int(round(0.1 / self.period)))
        self.final = 0  # samples below are delivered or counted lost
        self.sent = 0  # cycles started: every sample index of the run is below it
        self.sync_cycle = np.zeros(n, dtype=np.int64)  # the cycle of each SYNC of the run, in order
        self.syncs = 0  # SYNCs of the run (sent or heard)
        self.tail = 0  # host clock: SYNCs sent after the run's last cycle, until it is over
        self.next_cycle = 0  # host clock: the next cycle to send (beyond the run's last, in its tail)
        self.heard = 0  # listening: SYNCs heard since the drive or the interface began
        self.ahead = 1  # listening: set-points the drive holds ahead of its next SYNC (more with a buffer)
        self.pushed = 0  # listening: set-points sent (each before its SYNC) or given up as held
        self.applied = 0  # listening: set-points sent: the drive holds set-point applied - 1 when it runs out
        self.setpoints: list = []
        self.choice = SyncChoice("host", "")
        capability = ad.desc.sync
        self.timing = SyncTiming(self.period, 1e-6 * capability.window_us, n)
        self.host_window = capability.host_window_s(self.period)
        self.periodic_task: can.broadcastmanager.CyclicSendTaskABC | None = None  # the interface's cyclic SYNC
        self.clock_stopped = False
        self.clock_stop = threading.Event()  # host clock: its thread stops
        self.sender: threading.Thread | None = None  # host clock: the thread that sends the SYNCs
        self.sender_error: BaseException | None = None
        self.t0 = 0.0  # host clock: the instant of cycle 0, perf_counter s
        self.fault: dict | None = None  # the drive's fault, once taken
        self.fault_s = 0.0  # when the fault was taken, perf_counter s
        self.ended: float | None = None  # when the last cycle started, perf_counter s
        self.top = -1  # the newest sample heard
        self.heard_s = 0.0  # when the newest sample arrived (the start until one did), perf_counter s
        self.owns_clock = True  # False for a node of a group whose SYNC another node's run starts and stops
        self.cycle_members: list[StreamedRun] = [self]  # host clock: the runs whose set-points share each SYNC
        self._pack = self.rpdo_packer()

    # --- receiving ---------------------------------------------------------------------------------

    def on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.rx.append((can_id, bytes(data)))

    def finalize(self, limit: int, count_lost: bool = True) -> None:
        """Deliver complete samples below ``limit``; count the others as lost (or drop them silently).

        Skipped cycles are neither: no sample was asked for them.
        """
        a, stats, mask = self.final, self.stats, self.mask
        if limit <= a:
            return
        seg = mask[a:limit]
        complete = seg == self.full
        idx = np.flatnonzero(complete) + a
        if len(idx):
            self.ad.count_saturated(self.raw[idx], int(idx[0]))
            self.deliver(idx.astype(np.int64), self.raw[idx] * self.scales)
            stats.samples += len(idx)
        missing = np.flatnonzero(~complete & ~self.skipped[a:limit]) + a
        if count_lost and len(missing):
            stats.lost_samples += len(missing)
            stats.lost_blocks += len(missing)
            stats.lost_frames += int(sum(bin(self.full & ~int(m)).count("1") for m in mask[missing]))
            breaks = np.flatnonzero(np.diff(missing) != 1) + 1
            for run in np.split(missing, breaks):
                self.ad.log_event(
                    RunEvent(
                        Kind.LOST_BLOCKS,
                        f"{len(run)} sample(s) lost on the bus: samples {run[0]}..{run[-1]}",
                        int(run[0]),
                        value=float(len(run)),
                    )
                )
        self.final = limit

    def drain(self) -> int:
        """Sort received TPDOs into samples; returns the highest sample index seen."""
        top = -1
        final, rx, stats, n = self.final, self.rx, self.stats, self.n
        while rx:
            cob, data = rx.popleft()
            spec = self.frames.get(cob)
            if spec is None:
                continue
            bit, packer, idx, rank = spec
            if not self.counted:  # a PDO number not above the last one's starts the answer to the next SYNC
                if rank <= self.answered_rank:
                    self.answered_set += 1
                self.answered_rank = rank
            if len(data) < packer.size:
                stats.corrupt_frames += 1
                continue
            values = packer.unpack_from(data)
            if self.counted:
                # the newest cycle begun, the run's tail included; read per frame: the SYNCs are counted in another
                # thread
                ref = max(self.next_cycle, self.heard) - 1
                k = ref - ((ref - values[0]) % self.counter_mod)
                values = values[1:]
            elif self.answered_set < self.syncs:
                k = int(self.sync_cycle[self.answered_set])
            else:  # after the run's last SYNC (the clock goes on until the run is over), else not ours
                k = n if self.heard > n or self.answered_set < self.syncs + self.tail else -1
            if k >= n:
                continue  # a cycle after the run's last: the drive clocks on until it is told to stop
            if k < 0:
                stats.corrupt_frames += 1  # an answer to a SYNC of no cycle of this run
                continue
            if k < final:
                stats.out_of_order += 1  # arrived after its sample was given up: late
                continue
            self.raw[k, idx] = values
            self.mask[k] |= bit
            top = max(top, k)
        return top

    def complete_from_final(self, end: int | None = None) -> bool:
        """Whether every sample from the final index to ``end`` has all its TPDOs (or was skipped)."""
        seg = slice(self.final, end)
        return bool(np.all((self.mask[seg] == self.full) | self.skipped[seg]))

    # --- events --------------------------------------------------------------------------------------

    def note_skipped(self) -> None:
        """Listening: the ``sync_skipped`` event (once) for the set-points not sent in time (the drive held)."""
        skipped = self.stats.setpoints_skipped
        if skipped and self.choice.source != "host":
            if not any(e["kind"] == Kind.SYNC_SKIPPED.value for e in self.ad.events):
                self.ad.log_event(
                    RunEvent(
                        Kind.SYNC_SKIPPED,
                        f"{skipped} set-point(s) skipped: not sent in time for their cycle, the drive held the "
                        "last one (the recorded set-point is the held one)",
                        0,
                        value=float(skipped),
                    )
                )

    def note_unanswered(self) -> None:
        """Ordered matching: SYNCs no TPDO answered show only in the count of answer sets.

        Counted over every SYNC of the run and after it (the clock runs on until
        the run is over), once the clock stopped and the last answers came in.
        The last SYNC a drive produced before it stopped may go unanswered (a
        drive may answer a cycle at its end): it is not counted.
        """
        if self.choice.source == "host":
            syncs = self.syncs + self.tail
        else:
            syncs = self.heard - 1
        unanswered = syncs - 1 - self.answered_set
        if unanswered > 0:
            self.ad.log_event(
                RunEvent(
                    Kind.SYNC_UNANSWERED,
                    f"{unanswered} SYNC(s) got no TPDO at all: the drive skipped them or their "
                    "answers were lost; matched by order, the samples after such a SYNC are shifted, "
                    "so the run's last samples are counted lost",
                    int(self.answered_set + 1),
                    value=float(unanswered),
                )
            )

    def read_drive_counters(self) -> None:
        """The hilident counters at the end of a counted run: underruns and SYNC counter jumps."""
        ad = self.ad
        self.stats.underruns = int(ad.sdo.read("setpoint_underruns"))
        sync_errors = int(ad.sdo.read("sync_errors"))
        if sync_errors:
            ad.log_event(
                RunEvent(
                    Kind.SYNC_ERRORS, f"the drive saw {sync_errors} SYNC counter jump(s)", 0, value=float(sync_errors)
                )
            )

    def clock_report(self) -> dict:
        """The run's clock: source and why, measured period and jitter, set-points skipped."""
        report = {"source": self.choice.source, "why": self.choice.why, **self.timing.report()}
        report["setpoints_skipped"] = int(self.stats.setpoints_skipped)
        report["host_window_s"] = self.host_window if self.choice.source == "host" else None
        return report

    # --- the run -----------------------------------------------------------------------------------

    def rpdo_packer(self) -> Callable[[int, int | float], bytes]:
        """``pack(k, value)``: the RPDO of sample ``k`` (headed by the set-point counter where there is one)."""
        rx_type, sp_type = self.rpdo.counter_type, self.rpdo.setpoint_type
        if rx_type is not None:
            rx_mod = 1 << type_bits(rx_type)
            rpdo_struct = struct.Struct("<" + numpy_type(rx_type).char + numpy_type(sp_type).char)
            return lambda k, value: rpdo_struct.pack(k % rx_mod, value)
        rpdo_struct = struct.Struct("<" + numpy_type(sp_type).char)
        return lambda k, value: rpdo_struct.pack(value)

    def start(self) -> list:
        """Harmless set-points first, then Operation Enabled; the run's raw set-points.

        Zero torque/speed/offset, or the present position in CSP and IP; a
        torque offset injected in CSP or CSV is held by the present position or
        zero speed. Position set-points are relative to where the axis holds.
        """
        ad, sdo = self.ad, self.ad.sdo
        sp_type, sp_role = self.rpdo.setpoint_type, self.rpdo.setpoint_role
        position = sp_role in POSITION_SETPOINTS
        sdo.write(sp_role, int(sdo.read("position_actual")) if position else 0)
        hold = ad.desc.modes[ad.layout.mode].hold
        if hold:
            sdo.write(hold, int(sdo.read("position_actual")) if hold in POSITION_SETPOINTS else 0)
        ad.enable()
        origin = int(sdo.read("position_actual")) if position else 0
        return ad.encode_setpoints(self.x, sp_type, sp_role, origin).tolist()

    def choose_source(self) -> SyncChoice:
        """The SYNC source of this run; the interface's cyclic task, when it is the one, is kept to start."""
        choice, self.periodic_task = choose_clock(self.ad, self.period)
        return choice

    def run(self) -> None:
        """Play the run; see the module docstring."""
        ad = self.ad
        for cob in self.frames:
            ad.network.subscribe(cob, self.on_tpdo)
        self.choice = self.choose_source()
        try:
            self._loop()
            self._stop_clock()
            self._settle()
            self.note_skipped()
            if ad.run_fault is None and not self.counted:
                self.note_unanswered()
            if ad.run_fault is None and self.counted:
                self.read_drive_counters()
            self.result.completed = ad.run_fault is None
        except BaseException:
            self.note_skipped()  # a run that broke off says what it skipped too
            try:
                self.drain()
                self.finalize(self.sent - self.lost_after)  # long overdue: lost
                self.finalize(self.sent, count_lost=False)  # still in flight when the run broke off
            except Exception:
                pass
            raise
        finally:
            self._stop_clock()
            close_buffer(ad.sdo, ad.desc, self.rpdo.setpoint_role)
            self.result.clock = self.clock_report()
            for cob in [*self.frames, 0x80]:
                try:
                    ad.network.unsubscribe(cob, self.on_tpdo if cob != 0x80 else self.on_sync)
                except (KeyError, ValueError):
                    pass

    # --- the clocks --------------------------------------------------------------------------------

    def _start_clock(self) -> None:
        """Listening: set-point 0 out, then the drive (0x1005 bit 30) or the interface starts the SYNCs."""
        self.arm_listening()
        self.start_listening_clock()

    def arm_listening(self) -> None:
        """Listening: set-point 0 (and more where the drive buffers them) out, and SYNC heard from now on."""
        ad = self.ad
        self.ahead = open_buffer(ad.sdo, ad.desc, self.rpdo.setpoint_role, ad.port)
        self.pushed = self.applied = min(self.ahead, self.n)
        for j in range(self.pushed):
            ad.network.send_message(self.rpdo.cob_id, self._pack(j, self.setpoints[j]))
        ad.network.subscribe(0x80, self.on_sync)

    def start_listening_clock(self) -> None:
        """Listening: the drive (0x1005 bit 30) or the interface starts producing SYNC."""
        ad = self.ad
        if self.choice.source == "drive":
            cob = int(ad.sdo.read("sync_cob_id")) & 0x7FF
            ad.sdo.write("sync_cob_id", SYNC_GEN_BIT | cob)
        elif isinstance(self.periodic_task, can.broadcastmanager.RestartableCyclicTaskABC):
            self.periodic_task.start()

    def _settle(self) -> None:
        """After the clock stopped: the answers to its last SYNCs, still on their way, are drained."""
        end = time.perf_counter() + _SETTLE_S + 2 * self.period
        while time.perf_counter() < end:
            time.sleep(0.002)
            self.drain()

    def _stop_clock(self) -> None:
        """The SYNCs stop (never raises: every ending passes here; once).

        A drive that consumes SYNC faults when they stop while it is in a
        cyclic mode (its loss timeout, CiA 301 0x8250): with the host's or the
        interface's clock, the drive is commanded safe first, the SYNCs still
        coming. A drive that produces SYNC stops producing when bit 30 of
        0x1005 is cleared.
        """
        ad = self.ad
        if not self.clock_stopped and (self.sender is not None or self.periodic_task is not None):
            ad.safe_stop()
        self.clock_stop.set()
        if self.sender is not None:
            self.sender.join(timeout=1.0)
        if self.clock_stopped:
            return
        self.clock_stopped = True
        if self.periodic_task is not None:
            try:
                self.periodic_task.stop()
            except Exception:
                pass
        if self.choice.source == "drive" and self.owns_clock:
            try:
                ad.sdo.write("sync_cob_id", int(ad.sdo.read("sync_cob_id")) & ~SYNC_GEN_BIT & 0xFFFFFFFF)
            except Exception:
                pass

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Listening: SYNC ``k`` heard; the set-points up to ``k + ahead`` out, each if it reaches the drive before
        its own SYNC, else given up (held) with every one after it until the next SYNC."""
        k = self.heard
        self.heard += 1
        n = self.n
        if k >= n:
            return
        self.timing.add(k, timestamp)
        self.sync_cycle[self.syncs] = k
        self.syncs += 1
        self.sent = k + 1
        if self.pushed <= k:  # set-points not sent before their SYNCs: the drive held (its buffer ran empty)
            self._held(self.pushed, k + 1)
        age = time.time() - timestamp
        if not -0.1 < age < 1.0:  # an interface whose timestamps are not wall-clock time: the SYNC is taken as now
            age = 0.0
        send = self.ad.network.send_message
        while self.pushed < min(n, k + 1 + self.ahead):
            j = self.pushed
            if age > (j - k - 1 + _LEAD) * self.period:
                break  # too late for SYNC j: none after it may go either, or the drive would take it for j
            send(self.rpdo.cob_id, self._pack(j, self.setpoints[j]))
            self.pushed = self.applied = j + 1

    def _held(self, first: int, stop: int) -> None:
        """Listening: set-points ``first .. stop - 1`` reached the drive too late; it held the one before (a
        position it extrapolates at the last set-point velocity, as CSP and IP drives do), and so does the
        recording."""
        self.stats.setpoints_skipped += stop - first
        a, x = self.applied - 1, self.x  # the last set-point the drive took
        for j in range(first, stop):
            held = x[a]
            if self.rpdo.setpoint_role in POSITION_SETPOINTS and a > 0:
                held = x[a] + (j - a) * (x[a] - x[a - 1])
            self.raw[j, self.host_columns] = held
        self.pushed = stop

    def _send_due(self, now: float) -> None:
        """Host clock: the SYNC of the cycle whose instant passed last, if within the window; one per call.

        After the run's last cycle the SYNCs go on (without set-points: the
        drive holds the last one) until the run is over, so the drive's clock
        does not stop while its last samples are still on their way.
        """
        k = self.due_cycle(now)
        if k is None:
            return
        for member in self.cycle_members:
            member.before_sync(k)
        overflow = self.ad.sync_overflow
        self.ad.network.send_message(0x80, bytes([(self.syncs + self.tail) % overflow + 1]) if overflow > 1 else b"")
        sent_s = time.perf_counter()
        for member in self.cycle_members:
            member.after_sync(k, sent_s)

    def due_cycle(self, now: float) -> int | None:
        """Host clock: the cycle whose instant passed last, if its SYNC is due now (within the host's window, not
        sent yet); else None."""
        k = int((now - self.t0) / self.period)
        if k < self.next_cycle:
            return None
        now = time.perf_counter()  # the loop may have been held up since ``now`` was taken
        if now - (self.t0 + k * self.period) > self.host_window:
            return None  # sent already, or this cycle's window passed: wait for the next one, never send late
        return k

    def before_sync(self, k: int) -> None:
        """Host clock, before SYNC ``k``: the cycles skipped since the last SYNC counted, and set-point ``k`` sent
        if the one sent ahead was another cycle's (after a skip)."""
        n = self.n
        if self.sent < min(k, n):
            self._skip(self.sent, min(k, n))
        if k != self.next_cycle and k < n:
            self.ad.network.send_message(self.rpdo.cob_id, self._pack(k, self.setpoints[k]))

    def after_sync(self, k: int, sent_s: float) -> None:
        """Host clock, after SYNC ``k`` went out at ``sent_s`` (perf_counter s): the cycle noted, and the next
        cycle's set-point sent ahead (a drive applies an RPDO at the SYNC after it)."""
        n = self.n
        if k < n:
            self.timing.add(k, sent_s)
            self.sync_cycle[self.syncs] = k
            self.syncs += 1
        else:
            self.tail += 1
        self.next_cycle = k + 1
        self.sent = min(k + 1, n)
        if k + 1 < n:
            self.ad.network.send_message(self.rpdo.cob_id, self._pack(k + 1, self.setpoints[k + 1]))

    def _skip(self, first: int, stop: int) -> None:
        """Host clock: cycles ``first .. stop - 1`` are skipped (no SYNC, no sample); an event marks the gap."""
        self.skipped[first:stop] = True
        self.stats.setpoints_skipped += stop - first
        self.ad.log_event(
            RunEvent(
                Kind.SYNC_SKIPPED,
                f"{stop - first} cycle(s) skipped: the host's loop missed their window (no SYNC, no sample): "
                f"samples {first}..{stop - 1}",
                first,
                value=float(stop - first),
            )
        )

    def _loop(self) -> None:
        """The clock runs, TPDOs are matched, samples delivered, until the run ends or a fault stops it."""
        self.begin()
        if self.choice.source == "host":
            self.start_host_clock(self._host_clock)
        else:
            self._start_clock()
        while not self.poll(time.perf_counter()):
            time.sleep(0.002)

    def begin(self) -> None:
        """Harmless set-points, Operation Enabled (:meth:`start`); with the host's clock, set-point 0 sent ahead
        of SYNC 0. The clock is started next, by the caller."""
        self.setpoints = self.start()
        if self.choice.source == "host":
            close_buffer(self.ad.sdo, self.ad.desc, self.rpdo.setpoint_role)  # a skipped cycle would shift a queue
            self.ad.network.send_message(self.rpdo.cob_id, self._pack(0, self.setpoints[0]))
        self.heard_s = time.perf_counter()  # when the newest sample so far arrived (the start: none yet)

    def start_host_clock(self, target: Callable[[], None]) -> None:
        """Host clock: ``target`` sends the SYNCs from a thread that does nothing else (cycle 0 when it begins)."""
        self.sender = threading.Thread(target=target, name="hilident-sync", daemon=True)
        self.sender.start()

    def poll(self, now: float, beat: bool = True) -> bool:
        """One pass of the run's thread at ``now`` (perf_counter s): the host's heartbeat (with ``beat``), the
        TPDOs received matched, a fault taken, the samples final delivered or counted lost. True once the run is
        over (every sample final, or the fault's samples in).

        Raises
        ------
        DeviceError
            The link failed, the drive does not keep up with the SYNCs, or no SYNC came.
        """
        ad, period = self.ad, self.period
        if self.sender_error is not None:
            raise self.sender_error
        if beat:
            ad.net.heartbeat.beat_if_due()
        newest = self.drain()
        if newest > self.top:
            self.top, self.heard_s = newest, now
        if self.fault is None:
            self.fault = ad.take_emergency_fault(max(self.top, 0))
            if self.fault is not None:
                self.fault_s = now
                self.clock_stop.set()  # the drive switched off: no more SYNCs
        if self.fault is not None:
            last = min(self.sent, self.fault["sample_index"] + 1)
            if now - self.fault_s > _GRACE_S or self.complete_from_final(last):
                self.finalize(last)
                self.finalize(min(self.sent, self.top + 1), count_lost=False)
                return True
            return False
        ad.net.check_link()
        lag_limit = max(10 * self.lost_after, int(round(1.0 / period)))  # the drive is not keeping up
        if self.sent - 1 - self.top > lag_limit:
            raise DeviceError(
                f"{ad.port}: the drive's TPDOs lag {self.sent - 1 - self.top} samples behind the "
                f"SYNCs (more than {lag_limit * period:.2g} s): it does not keep up with "
                f"{1 / period:g} SYNC/s"
            )
        if self.choice.source != "host" and self.heard == 0 and now - self.heard_s > max(_GRACE_S, 20 * period):
            raise DeviceError(
                f"{ad.port}: no SYNC on the bus {now - self.heard_s:.2g} s after the "
                f"{self.choice.source} was told to produce it (0x1005, 0x1006)"
            )
        if self.sent >= self.n:
            self.ended = self.ended or now
            # the grace runs from the last SYNC or the last new sample, whichever is later: a drive
            # still answering the last SYNCs is slow, not silent
            if now - max(self.ended, self.heard_s) > _GRACE_S or self.complete_from_final(self.n):
                self.finalize(self.n)
                return True
        else:
            self.finalize(self.sent - self.lost_after)
        return False

    def end_early(self, last: int) -> None:
        """The run stops before its end at sample ``last`` (another node of the same SYNC faulted there): the
        samples in are delivered, the ones up to ``last`` not in counted lost, the later ones left (in flight when
        the clock stopped), none filled."""
        self.drain()
        self.finalize(min(self.sent, last))
        self.finalize(min(self.sent, self.top + 1), count_lost=False)

    def _host_clock(self) -> None:
        """Host clock, in a thread of its own that does nothing else: each cycle's SYNC at its instant.

        It sleeps until shortly before the next cycle's instant and spins the
        last ``_SPIN_S`` (a sleep overshoots by tens of µs); the receiving,
        matching and recording stay in the run's thread. It stops when the run
        ends or the drive faults.

        Cycle 0 is the instant the thread begins, never earlier: its SYNC is
        the drive's first, and the drive counts its cycles from it (its
        sample counter, and its own clock through SYNCs that do not come). A
        cycle 0 set before a thread that started late would be skipped, and
        every sample of the run named one cycle early.
        """
        self.t0 = time.perf_counter()
        try:
            while not self.clock_stop.is_set():
                instant = self.t0 + self.next_cycle * self.period
                wait = instant - time.perf_counter()
                if wait > _SPIN_S:
                    self.clock_stop.wait(min(wait - _SPIN_S, 0.005))
                    continue
                while time.perf_counter() < instant:
                    pass
                self._send_due(time.perf_counter())
        except BaseException as exc:  # a failed send: the run's thread raises it
            self.sender_error = exc
