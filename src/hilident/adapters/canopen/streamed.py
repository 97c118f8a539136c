"""Host-streamed runs on a CANopen drive: an RPDO set-point and a SYNC every sample period.

For sample ``k`` the host sends the RPDO with the set-point and then SYNC; the
drive applies the set-point for the sample period that SYNC starts and answers
with its TPDOs (transmission type 1), carrying the state at the start of that
period. Which sample a TPDO belongs to is known in one of two ways:

* **counted**: on a drive with the hilident counters every TPDO is headed by
  the sample counter ``k`` (and the RPDO by the set-point counter), so each
  frame names its sample;
* **ordered** (every other CiA 402 drive, standard objects only): CAN keeps
  the order of frames, and a drive answers each SYNC with its TPDOs in PDO
  number order, so the answers form consecutive sets; a frame whose PDO
  number is not above the previous frame's starts the next set, and the
  ``n``-th set answers the ``n``-th SYNC. A set with a frame missing is a lost
  sample at a known index. A SYNC the drive did not answer at all (a whole set
  missing) shows only in the count: the samples after it shift by one, which the
  run reports (``sync_unanswered``) with the number of unanswered SYNCs; such
  samples are never filled in. Channels the drive does not report (the
  set-point, on drives without an applied-set-point object) are the host's own.

The host assembles a sample from its TPDOs:

* a sample whose TPDOs did not all arrive within ``window`` sample periods
  after its SYNC (at the end of the run: ``_GRACE_S`` after the last SYNC or
  the last new sample, whichever is later) is lost: counted (``lost_samples``, ``lost_blocks``, and
  ``lost_frames`` for the missing TPDOs), logged as a ``lost_blocks`` event,
  never filled in;
* a TPDO arriving after its sample was given up is late: counted as
  ``out_of_order`` and discarded;
* a SYNC the host sent more than one period late is counted in a
  ``sync_late`` event; set-points that reached the drive after their SYNC are
  the drive's ``underruns`` (read from its diagnostics at the end).

An emergency stops the SYNCs at once (the drive already switched its power
stage off); the samples up to the fault are delivered, then the run ends with
LimitTrip (a limit) or DeviceError. A lost heartbeat ends it with DeviceError,
and so do TPDOs lagging more than a second behind the SYNCs (the drive does not
keep up; flooding it further would only queue frames).
"""

from __future__ import annotations

import collections
import struct
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from hilident.adapters.base import RunResult, RunStrategy
from hilident.adapters.canopen.common import DriveIdentity, DriveRatings, RunLayout
from hilident.adapters.canopen.net import NetWatch
from hilident.adapters.canopen.sdo import SdoAccess
from hilident.adapters.canopen.trace import TracingNetwork
from hilident.drivers.description import DriverDescription
from hilident.errors import DeviceError
from hilident.events import Kind, RunEvent
from hilident.protocol.canopen_objects import CanopenDescription, numpy_type, type_bits

__all__ = ["StreamedRun", "DriveHost", "Deliver", "POSITION_SETPOINTS"]

#: Set-point roles that are positions (targets relative to where the axis holds at enable).
POSITION_SETPOINTS = ("target_position", "interpolation_data")

#: Where a strategy hands ``(sample indices, rows)`` blocks (the template's ``deliver``).
Deliver = Callable[[np.ndarray, np.ndarray], None]

_GRACE_S = 0.25  # after the last SYNC (or an emergency), wait this long for the TPDOs in flight


class DriveHost(Protocol):
    """What a CANopen acquisition strategy uses of its adapter
    (:class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`).

    The parts the adapter owns: ``sdo`` (the drive's objects,
    :class:`~hilident.adapters.canopen.sdo.SdoAccess`) and ``net`` (the link
    check, the host's heartbeat, the emergency queue to wait on,
    :class:`~hilident.adapters.canopen.net.NetWatch`); the run's ``layout`` as
    ``configure()`` left it (mode, rate, channels, PDOs); ``desc`` (the
    driver's objects and modes), ``driver``, ``sync_rate_hz``,
    ``sync_overflow``, ``excitation_recipe`` (recorder), the ``ratings``,
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
    sync_rate_hz: float | None
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


class StreamedRun(RunStrategy):
    """One host-streamed run: the set-points, SYNCs, received TPDOs and their matching to samples.

    See the module docstring. State: the raw sample table and the mask of
    the TPDOs received per sample, the index below which samples are final
    (delivered or counted lost), the SYNCs sent, late and unanswered.
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
        self.raw = np.zeros((n, len(layout.channels)))
        for j, c in enumerate(layout.channels):
            if c.on_host:
                self.raw[:, j] = x  # the set-point the host sends, in SI units (scale 1)
        self.mask = np.zeros(n, dtype=np.uint32)
        self.answered_set, self.answered_rank = -1, len(self.frames)  # ordered matching: the set, its last PDO
        self.rx: collections.deque[tuple[int, bytes]] = collections.deque()  # (COB-ID, data) as received
        self.period = 1.0 / (ad.sync_rate_hz or layout.sample_rate_hz)
        self.window = max(16, int(round(0.1 / self.period)))
        self.final = 0  # samples below are delivered or counted lost
        self.sent = 0  # SYNCs sent
        self.late_syncs, self.worst_late = 0, 0.0

    # --- receiving ---------------------------------------------------------------------------------

    def on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.rx.append((can_id, bytes(data)))

    def finalize(self, limit: int, count_lost: bool = True) -> None:
        """Deliver complete samples below ``limit``; count the others as lost (or drop them silently)."""
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
        if count_lost and not complete.all():
            missing = np.flatnonzero(~complete) + a
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
        sent, final, rx, stats = self.sent, self.final, self.rx, self.stats
        ref = sent - 1
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
                k = ref - ((ref - values[0]) % self.counter_mod)
                values = values[1:]
            else:
                k = self.answered_set
                if k >= sent:
                    stats.corrupt_frames += 1  # an answer to a SYNC the host never sent: not this run's
                    continue
            if k < final or k < 0:
                stats.out_of_order += 1  # arrived after its sample was given up: late
                continue
            self.raw[k, idx] = values
            self.mask[k] |= bit
            top = max(top, k)
        return top

    def complete_from_final(self, end: int | None = None) -> bool:
        """Whether every sample from the final index to ``end`` has all its TPDOs."""
        return self.mask[self.final : end].min(initial=self.full) == self.full

    # --- events --------------------------------------------------------------------------------------

    def note_late_syncs(self) -> None:
        """The ``sync_late`` event (once): how many SYNCs went out more than a period late, the worst in s."""
        if self.late_syncs and not any(e["kind"] == Kind.SYNC_LATE.value for e in self.ad.events):
            self.ad.log_event(
                RunEvent(
                    Kind.SYNC_LATE,
                    f"{self.late_syncs} SYNC(s) sent more than one period late (worst {self.worst_late * 1e3:.2f} ms)",
                    0,
                    value=float(self.late_syncs),
                    worst_s=float(self.worst_late),
                )
            )

    def note_unanswered(self) -> None:
        """Ordered matching: SYNCs no TPDO answered show only in the count of answer sets."""
        unanswered = self.sent - 1 - self.answered_set
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

    def run(self) -> None:
        """Play the run; see the module docstring."""
        ad = self.ad
        for cob in self.frames:
            ad.network.subscribe(cob, self.on_tpdo)
        try:
            self._loop()
            self.note_late_syncs()
            if ad.run_fault is None and not self.counted:
                self.note_unanswered()
            if ad.run_fault is None and self.counted:
                self.read_drive_counters()
            self.result.completed = ad.run_fault is None
        except BaseException:
            self.note_late_syncs()  # a run that broke off says how late its SYNCs went out too
            try:
                self.drain()
                self.finalize(self.sent - self.window)  # long overdue: lost
                self.finalize(self.sent, count_lost=False)  # still in flight when the run broke off
            except Exception:
                pass
            raise
        finally:
            for cob in self.frames:
                try:
                    ad.network.unsubscribe(cob, self.on_tpdo)
                except (KeyError, ValueError):
                    pass

    def _loop(self) -> None:
        """SYNCs on time, TPDOs matched, samples delivered, until the run ends or a fault stops it."""
        ad, n, period, window = self.ad, self.n, self.period, self.window
        lag_limit = max(10 * window, int(round(1.0 / period)))  # the drive is not keeping up: stop flooding it
        overflow = ad.sync_overflow
        send = ad.network.send_message
        rpdo_cob, pack = self.rpdo.cob_id, self.rpdo_packer()
        setpoints = self.start()
        fault = None
        t0 = time.perf_counter() + 0.001
        ended: float | None = None  # when the last SYNC went out
        fault_s = 0.0  # when the fault was taken
        top = -1
        heard_s = 0.0  # when the newest sample so far arrived
        while True:
            now = time.perf_counter()
            if fault is None:
                while self.sent < n and now >= t0 + self.sent * period:
                    late = now - (t0 + self.sent * period)
                    if late > period:
                        self.late_syncs += 1
                        self.worst_late = max(self.worst_late, late)
                    send(rpdo_cob, pack(self.sent, setpoints[self.sent]))
                    send(0x80, bytes([self.sent % overflow + 1]) if overflow > 1 else b"")
                    self.sent += 1
            ad.net.heartbeat.beat_if_due()
            newest = self.drain()
            if newest > top:
                top, heard_s = newest, now
            if fault is None:
                fault = ad.take_emergency_fault(max(top, 0))
                if fault is not None:
                    fault_s = now
            if fault is not None:
                last = min(self.sent, fault["sample_index"] + 1)
                if now - fault_s > _GRACE_S or self.complete_from_final(last):
                    self.finalize(last)
                    self.finalize(min(self.sent, top + 1), count_lost=False)
                    return
            else:
                ad.net.check_link()
                if self.sent - 1 - top > lag_limit:
                    raise DeviceError(
                        f"{ad.port}: the drive's TPDOs lag {self.sent - 1 - top} samples behind the "
                        f"SYNCs (more than {lag_limit * period:.2g} s): it does not keep up with "
                        f"{1 / period:g} SYNC/s"
                    )
                if self.sent == n:
                    ended = ended or now
                    # the grace runs from the last SYNC or the last new sample, whichever is later: a drive
                    # still answering the last SYNCs is slow, not silent
                    if now - max(ended, heard_s) > _GRACE_S or self.complete_from_final():
                        self.finalize(n)
                        return
                else:
                    self.finalize(self.sent - window)
            wait = t0 + self.sent * period - time.perf_counter()
            time.sleep(min(max(wait, 0.0), 0.005) if self.sent < n and fault is None else 0.002)
