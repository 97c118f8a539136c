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
class ConnectReport:
    """What an adapter found when it connected, and what it did about it.

    Attributes
    ----------
    discarded_frames : int
        Frames (or answers) that arrived before the host had configured
        anything, left over from an earlier session; dropped, never used.
    faults : list of str
        Faults the device had latched, as it described them.
    faults_cleared : bool
        Whether those faults were cleared (only with ``allow_fault_reset``).
    found_state : str
        The device's state before the host stopped it (e.g. ``"RUNNING"`` when
        a killed session's run was still playing, ``"FAULT"``), or ``""``.
    device_net : str
        The device-side stop the host armed for when it dies (e.g.
        ``"heartbeat consumer 0x1016: 500 ms, 0x6007 = 2 (disable voltage)"``,
        ``"board watchdog 1 s"``), or ``""``.
    warnings : list of str
        What the host noticed about the device's description (e.g. the quirks
        of a vendor EDS it repaired while reading it).
    """

    discarded_frames: int = 0
    faults: list[str] = field(default_factory=list)
    faults_cleared: bool = False
    found_state: str = ""
    device_net: str = ""
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"discarded_frames": self.discarded_frames, "found_state": self.found_state,
                "faults": list(self.faults), "faults_cleared": self.faults_cleared, "device_net": self.device_net,
                "warnings": list(self.warnings)}


def refuse_latched_faults(port: str, faults: list[str]):
    """The :class:`DeviceError` for a device found with latched ``faults`` and no permission to clear them."""
    from hilident.errors import DeviceError

    return DeviceError(
        f"{port}: the device has a latched fault: {'; '.join(faults)}. Check the axis, then clear it with "
        "[device] allow_fault_reset = true or hilident run --clear-fault"
    )


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
    events : list of dict
        Events of the current (or last) :meth:`stream`, each ``{kind, message,
        sample_index, ...}``. Emptied when a stream starts and appended **as
        soon as an event is known**, so the session writes them to the
        recording while the run goes on; ``RunResult.events`` is a copy at the
        end.
    connect_report : ConnectReport
        What :meth:`open_device` found and did to bring the device to a known
        state.
    """

    port: str
    identity: Any
    events: list[dict]
    connect_report: "ConnectReport"
    sample_rate_hz: float
    channel_units: list[str]
    last_result: RunResult | None

    @classmethod
    def open_device(cls, device, driver, link=None) -> "DeviceAdapter":
        """Connect as the ``[device]`` config says, check the device matches ``driver``
        and bring it to a known state.

        Whatever the previous session left behind (it may have been killed):
        frames that arrive before the host has configured anything are
        discarded and counted, the axis is commanded stopped, latched faults
        are read and reported in :attr:`connect_report`; they are cleared only
        when ``device.allow_fault_reset`` is true, else :class:`DeviceError`
        names the port and the fault and says how to clear it
        (``[device] allow_fault_reset = true`` or ``hilident run --clear-fault``).
        The device-side net is armed (``device.host_timeout_s``: a CANopen
        heartbeat consumer, a Modbus communication timeout) where the driver
        declares it.
        """

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the limits the device itself enforces (crossing one stops the axis)."""

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Choose the recorded rate, the excitation mode and channels; returns the channel names."""

    def stream(self, excitation: np.ndarray, sink: Callable[[np.ndarray, np.ndarray], None],
               progress: Callable[[float], None] | None = None) -> RunResult:
        """Play ``excitation`` and pass ``(sample_index, rows)`` blocks to ``sink``; lost ones are counted.

        The first cause wins: once the device reported a limit trip,
        :class:`LimitTrip` is raised whatever fails after it. Anything raised
        by ``sink`` (a full disk) or by a signal propagates after the device
        was commanded safe.
        """

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

    def disable_filter(self, slot: int) -> None:
        """Bypass a filter slot (its contents stay stored; :meth:`restore_filter` brings it back)."""

    def safe_stop(self) -> None:
        """Command the axis safe now: serial STOP (zero torque); CiA 402 out of
        Operation Enabled to Switch On Disabled; Modbus stop and disable.

        Never raises, returns quickly (it runs first on every ending, a signal
        included) and keeps the connection open so filter slots can still be
        restored afterwards.
        """

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
