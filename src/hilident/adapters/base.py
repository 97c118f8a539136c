"""What every device adapter offers the session, whatever its transport.

An adapter is the host side of one transport. The session only talks to this
interface, so a CANopen or Modbus adapter slots in beside the serial one. New
adapters register under the ``hilident.adapters`` entry point group.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable, Protocol

import numpy as np

from hilident.errors import ConfigError


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
        Sample blocks that arrived after a later one (discarded).
    underruns : int
        Samples the board played as zero because its excitation buffer was empty.
    board_dropped_blocks : int
        Sample blocks the board could not send (its transmit buffer was full).
    clipped_blocks : int
        Blocks in which a value did not fit its integer format.
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

    def add(self, other: "StreamStats") -> "StreamStats":
        """Field-wise sum (for the totals of a session)."""
        return StreamStats(**{k: getattr(self, k) + getattr(other, k) for k in self.__dataclass_fields__})


@dataclass
class RunResult:
    """Outcome of streaming one excitation."""

    requested_samples: int
    stats: StreamStats
    events: list[dict] = field(default_factory=list)
    fault: str | None = None
    completed: bool = False


class DeviceAdapter(Protocol):
    """The contract between the session and a transport's adapter.

    Attributes
    ----------
    port : str
        Where the device is (device path, URL, CAN channel); used in messages.
    identity
        What the device reported: ``name``, ``firmware``, ``loop_rate_hz`` (the
        rate its filters run at, Hz) and ``filter_slots``.
    sample_rate_hz : float
        Recorded sample rate chosen by :meth:`configure`, Hz.
    channel_units : list of str
        Units of the channels :meth:`configure` returned, in order.
    last_result : RunResult or None
        Outcome of the last :meth:`stream`, also when it raised.
    """

    port: str
    identity: Any
    sample_rate_hz: float
    channel_units: list[str]
    last_result: RunResult | None

    @classmethod
    def open_device(cls, device, driver, link=None) -> "DeviceAdapter":
        """Connect as the ``[device]`` config says and check the device matches ``driver``."""

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the limits the device itself enforces (crossing one stops the axis)."""

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Choose the recorded rate, the excitation mode and channels; returns the channel names."""

    def stream(self, excitation: np.ndarray, sink: Callable[[np.ndarray, np.ndarray], None],
               progress: Callable[[float], None] | None = None) -> RunResult:
        """Play ``excitation`` and pass ``(sample_index, rows)`` blocks to ``sink``; lost ones are counted."""

    def write_filter(self, slot: int, biquad, spec=None, *, enabled: bool) -> None:
        """Store a notch in a filter slot, in the device's own encoding (coefficients or parameters)."""

    def read_filter(self, slot: int) -> tuple[Any, bool]:
        """The biquad the slot now applies, and whether it is enabled."""

    def stored_form(self, biquad, spec=None):
        """The biquad the device will apply after its own rounding of ``biquad``/``spec``."""

    def save_filter(self, slot: int) -> Any:
        """The slot's contents, opaque, for :meth:`restore_filter`."""

    def restore_filter(self, slot: int, saved: Any) -> None:
        """Put back what :meth:`save_filter` returned."""

    def close(self) -> None:
        """Zero torque, drive disabled, connection released. Never raises."""


class AdapterBase:
    """What every adapter class shares: ``with`` support and identify-or-close on opening."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @staticmethod
    def _identified(adapter):
        """``adapter`` after a successful ``identify()``; closed again when that fails."""
        try:
            adapter.identify()
        except BaseException:
            adapter.close()
            raise
        return adapter


def adapter_class(transport: str):
    """The adapter class registered for ``transport`` under ``hilident.adapters``."""
    for ep in entry_points(group="hilident.adapters"):
        if ep.name == transport:
            return ep.load()
    if transport == "serial":  # running from a checkout that was never installed
        from hilident.adapters.serial_board import SerialBoardAdapter

        return SerialBoardAdapter
    known = sorted(ep.name for ep in entry_points(group="hilident.adapters"))
    raise ConfigError("driver.transport", f"no adapter for transport {transport!r} (installed: {known})")


def contiguous_runs(sample_index: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` row ranges over which ``sample_index`` increases by exactly 1."""
    if len(sample_index) == 0:
        return []
    breaks = np.flatnonzero(np.diff(sample_index) != 1) + 1
    edges = np.concatenate(([0], breaks, [len(sample_index)]))
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
