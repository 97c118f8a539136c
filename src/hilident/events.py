"""One vocabulary for what happens during a run, whatever the transport (pure: no I/O).

Every adapter makes its run events as :class:`RunEvent` and logs them with
:meth:`~hilident.adapters.base.AdapterBase.log_event`, which appends
:meth:`RunEvent.to_dict` to ``adapter.events``. The recording's event log
takes the same typed events (:meth:`hilident.io.recording.RunWriter.log`):
``kind``, ``message`` and ``sample_index`` go to their columns of the
``/events`` table, every other field to the ``data`` column.

:class:`StreamStats` counts what the line delivered and lost in a run; the
session sums them and ``summary.json["stream"]`` reports them.

Examples
--------
>>> RunEvent(Kind.LOST_BLOCKS, "2 sample block(s) lost", 100, value=2.0).to_dict()
{'kind': 'lost_blocks', 'message': '2 sample block(s) lost', 'sample_index': 100, 'value': 2.0}
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

__all__ = ["Kind", "RunEvent", "StreamStats"]


class Kind(str, enum.Enum):  # noqa: UP042 - StrEnum would change str()/format() of members in messages
    """The kinds of run event; the value is what the recording stores."""

    # the run ended, or stopped early
    FINISHED = "finished"  # the device says the run is complete
    STOPPED = "stopped"  # the serial board stopped the run on a STOP
    CAPTURE_END = "capture_end"  # a drive-buffered run's capture is home
    CAPTURE_SHORT = "capture_short"  # the drive's capture ended before the table (CANopen)
    CAPTURE_STOPPED = "capture_stopped"  # the drive's capture stopped before the table (Modbus)
    # faults: the first one is the run's cause
    LIMIT_TRIP = "limit_trip"  # a safety limit tripped (the device's, or the host's check)
    FAULT = "fault"  # the device faulted for another reason
    WATCHDOG = "watchdog"  # the serial board's watchdog stopped a run whose host went silent
    EMERGENCY = "emergency"  # a CANopen EMCY other than a limit trip
    EMERGENCY_RESET = "emergency_reset"  # a CANopen EMCY 0x0000 (error reset): no fault
    # what the line lost or mangled (counted, never filled)
    LOST_BLOCKS = "lost_blocks"
    OUT_OF_ORDER = "out_of_order"
    PROTOCOL_ERROR = "protocol_error"
    REFUSED = "refused"  # the device refused a frame
    MISSING_RESPONSE = "missing_response"  # an answer was lost; the device's state says what happened
    UNDERRUN = "underrun"  # the serial board played without a fresh set-point
    CLIPPED = "clipped"  # a value reached the range of its integer object (CANopen): saturated, not measured
    # host-produced SYNC (CANopen streamed runs)
    SYNC_LATE = "sync_late"  # recordings of earlier releases: a SYNC the host sent more than a period late
    SYNC_SKIPPED = "sync_skipped"  # cycles (host clock) or set-points (drive clock) skipped, never sent late
    SYNC_UNANSWERED = "sync_unanswered"
    SYNC_ERRORS = "sync_errors"
    # a drive's own generator (CANopen recorder runs)
    EXCITATION_DIFFERS = "excitation_differs"  # it plays another signal than the host's excitation
    EXCITATION_COMPUTED = "excitation_computed"  # no output object: the excitation column is computed


#: Kinds that end a run with an error (the first of them is the cause).
FAULT_KINDS = frozenset({Kind.LIMIT_TRIP, Kind.FAULT, Kind.WATCHDOG, Kind.EMERGENCY})


@dataclass(frozen=True)
class RunEvent:
    """One event of a run.

    Parameters
    ----------
    kind : Kind
        What happened.
    message : str
        The event in words, for the user.
    sample_index : int
        The sample it refers to (``-1``: none known, the recording puts it at
        the sample being written).
    value : float, optional
        The kind's number: samples or blocks lost, SYNCs late or unanswered,
        the value that crossed a limit (in its channel's SI unit), the
        device's fault value.
    worst_s : float, optional
        ``sync_late``: the latest SYNC's lateness, s.
    host_check : bool
        ``limit_trip``: the host found the sample outside a limit (not the device).
    code, register : int, optional
        ``emergency``, ``emergency_reset``, ``limit_trip`` from an EMCY: the
        emergency error code and the error register (0x1001).
    data : str, optional
        The EMCY's manufacturer-specific bytes, hex.

    Fields left at their default are not in :meth:`to_dict`.
    """

    kind: Kind
    message: str
    sample_index: int = -1
    value: float | None = None
    worst_s: float | None = None
    host_check: bool = False
    code: int | None = None
    register: int | None = None
    data: str | None = None

    @classmethod
    def from_dict(cls, entry: dict) -> RunEvent:
        """The event :meth:`to_dict` made ``entry`` of (the inverse: ``RunEvent.from_dict(e.to_dict()) == e``).

        >>> RunEvent.from_dict({"kind": "underrun", "message": "3 samples", "sample_index": 7, "value": 3.0})
        RunEvent(kind=<Kind.UNDERRUN: 'underrun'>, message='3 samples', sample_index=7, value=3.0, worst_s=None, \
host_check=False, code=None, register=None, data=None)
        """
        fields = {k: v for k, v in entry.items() if k not in ("kind", "message", "sample_index")}
        return cls(Kind(entry["kind"]), str(entry.get("message", "")), int(entry.get("sample_index", -1)), **fields)

    @property
    def extra(self) -> dict:
        """The fields beyond ``kind``, ``message`` and ``sample_index`` that are set (the recording's ``data``)."""
        return {k: v for k, v in self.to_dict().items() if k not in ("kind", "message", "sample_index")}

    @property
    def is_fault(self) -> bool:
        """Whether the event ends the run with an error."""
        return self.kind in FAULT_KINDS

    def to_dict(self) -> dict:
        """The event as the recording and the session take it: ``kind``, ``message``, ``sample_index``,
        then the fields that are set, in declaration order."""
        out: dict[str, Any] = {
            "kind": Kind(self.kind).value,
            "message": self.message,
            "sample_index": int(self.sample_index),
        }
        if self.value is not None:
            out["value"] = float(self.value)
        if self.worst_s is not None:
            out["worst_s"] = float(self.worst_s)
        if self.host_check:
            out["host_check"] = True
        for name in ("code", "register"):
            if getattr(self, name) is not None:
                out[name] = int(getattr(self, name))
        if self.data is not None:
            out["data"] = self.data
        return out


@dataclass
class StreamStats:
    """What happened on the line during one run.

    Attributes
    ----------
    samples : int
        Samples received and recorded.
    lost_frames : int
        Frames of any kind missing from the board's sequence numbers.
    lost_blocks : int
        Sample blocks missing from the block counter.
    lost_samples : int
        Samples in the missing blocks (never filled in the recording).
    corrupt_frames : int
        Frames rejected by COBS decoding or CRC.
    out_of_order : int
        Sample blocks that arrived after a later one (discarded; counted here
        and not as lost).
    underruns : int
        Samples the device played without a fresh set-point because its
        excitation buffer was empty (it holds the last set-point, PROTOCOL.md
        section 6).
    board_dropped_blocks : int
        Sample blocks the board could not send (its transmit buffer was full).
    clipped_blocks : int
        Blocks in which a value did not fit its integer format.
    setpoints_skipped : int
        CANopen streamed runs: set-points not sent because their cycle's time
        had passed (the drive held the last one); on the host's clock the
        cycle's SYNC and sample were skipped with it.
    """

    samples: int = 0
    lost_frames: int = 0
    lost_blocks: int = 0
    lost_samples: int = 0
    corrupt_frames: int = 0
    out_of_order: int = 0
    underruns: int = 0
    board_dropped_blocks: int = 0
    clipped_blocks: int = 0
    setpoints_skipped: int = 0

    def add(self, other: StreamStats) -> StreamStats:
        """Field-wise sum (for the totals of a session)."""
        return StreamStats(**{k: getattr(self, k) + getattr(other, k) for k in self.__dataclass_fields__})

    def to_summary(self) -> dict[str, int]:
        """``summary.json["stream"]``: every count but ``clipped_blocks`` (reported as a warning instead)."""
        return {k: v for k, v in self.__dict__.items() if k != "clipped_blocks"}
