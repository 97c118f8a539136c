"""What every device adapter offers the session, whatever its transport.

An adapter is the host side of one transport. The session only talks to this
interface, so a CANopen or Modbus adapter slots in beside the serial one. The
built-in adapters are listed in :mod:`hilident.adapters.backends`; new ones
register under the ``hilident.adapters`` entry point group.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, Protocol, Self, TypeVar

import numpy as np
import numpy.typing as npt

from hilident.adapters.host_timing import timely_host
from hilident.errors import ConfigError, DataError, DeviceError, LimitTrip, UsageError
from hilident.events import Kind, RunEvent, StreamStats
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec

if TYPE_CHECKING:
    from hilident.config.tables import DeviceConfig
    from hilident.drivers.description import DriverDescription

_PROGRESS_S = 0.1  # progress is reported at most this often, and at the end

#: A block handed on by a run: ``(sample_index, rows)``.
Deliver = Callable[[np.ndarray, np.ndarray], None]


class _CanClose(Protocol):
    def close(self) -> None: ...


class _CanIdentify(_CanClose, Protocol):
    def identify(self) -> object: ...


_Closable = TypeVar("_Closable", bound=_CanClose)
_Identifiable = TypeVar("_Identifiable", bound=_CanIdentify)


class RunHost(Protocol):
    """What :class:`RunStrategy` itself uses of its adapter."""

    port: str

    def log_event(self, event: RunEvent) -> dict: ...


_Host = TypeVar("_Host", bound=RunHost)


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
        return {
            "discarded_frames": self.discarded_frames,
            "found_state": self.found_state,
            "faults": list(self.faults),
            "faults_cleared": self.faults_cleared,
            "device_net": self.device_net,
            "warnings": list(self.warnings),
        }


def refuse_latched_faults(port: str, faults: list[str]) -> DeviceError:
    """The :class:`DeviceError` for a device found with latched ``faults`` and no permission to clear them."""
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
    clock: dict | None = None  # who kept the bus clock and how well (CANopen streamed runs)


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
    connect_report: ConnectReport
    sample_rate_hz: float
    channel_units: list[str]
    last_result: RunResult | None

    @classmethod
    def open_device(cls, device: DeviceConfig, driver: DriverDescription, link: object = None) -> DeviceAdapter:
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

    def stream(
        self,
        excitation: np.ndarray,
        sink: Callable[[np.ndarray, np.ndarray], None],
        progress: Callable[[float], None] | None = None,
    ) -> RunResult:
        """Play ``excitation`` and pass ``(sample_index, rows)`` blocks to ``sink``; lost ones are counted.

        The first cause wins: once the device reported a limit trip,
        :class:`LimitTrip` is raised whatever fails after it. Anything raised
        by ``sink`` (a full disk) or by a signal propagates after the device
        was commanded safe.
        """

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None, *, enabled: bool) -> None:
        """Store a notch in a filter slot, in the device's own encoding (coefficients or parameters)."""

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad the slot now applies, and whether it is enabled."""

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None = None) -> Biquad:
        """The biquad the device will apply after its own rounding of ``biquad``/``spec``."""

    def read_loop(self) -> dict[str, float] | None:
        """The device's cascade parameters in SI units; None when its loop is not described."""

    def write_loop(self, values: Mapping[str, float]) -> None:
        """Write tunable cascade parameters, SI units."""

    def stored_loop(self, values: Mapping[str, float]) -> dict[str, float]:
        """What the device will hold for ``values`` after its own rounding, SI units."""

    def save_filter(self, slot: int) -> Any:
        """The slot's contents, opaque, for :meth:`restore_filter`."""

    def restore_filter(self, slot: int, saved: Any) -> None:
        """Put back what :meth:`save_filter` returned."""

    def disable_filter(self, slot: int) -> None:
        """Bypass a filter slot (its contents stay stored; :meth:`restore_filter` brings it back)."""

    @classmethod
    def run_refusal(cls, driver: DriverDescription) -> ConfigError | None:
        """Why ``hilident run`` cannot play an excitation on a device ``driver`` describes, or None."""

    def set_trace(self, path: str | os.PathLike[str]) -> None:
        """Write a wire trace of the next run to ``path`` where the transport keeps one."""

    def set_excitation_recipe(self, recipe: dict | None) -> None:
        """The next run's excitation as parameters, for a device whose own generator plays it."""

    def safe_stop(self) -> None:
        """Command the axis safe now: serial STOP (zero torque); CiA 402 out of
        Operation Enabled to Switch On Disabled; Modbus stop and disable.

        Never raises, returns quickly (it runs first on every ending, a signal
        included) and keeps the connection open so filter slots can still be
        restored afterwards.
        """

    def close(self) -> None:
        """Zero torque, drive disabled, connection released. Never raises."""


@dataclass
class FilterUpload:
    """What :meth:`AdapterBase.upload_filter` left in a slot.

    Attributes
    ----------
    stored : Biquad
        The biquad the slot applies, read back from the device.
    expected : Biquad
        What the device should hold after its own rounding (:meth:`~DeviceAdapter.stored_form`).
    matches : bool
        Read back as written and enabled; when not, the slot's previous contents were put back.
    """

    stored: Biquad
    expected: Biquad
    matches: bool


def checked_excitation(excitation: npt.ArrayLike) -> np.ndarray:
    """``excitation`` as a float array; DataError unless it is finite and one-dimensional."""
    x = np.asarray(excitation, dtype=float)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise DataError("excitation must be a finite one-dimensional array")
    return x


class AdapterBase:
    """The public run, upload and stop logic of every adapter, once; transports supply protected hooks.

    In the style of python-can's ``BusABC``: the public methods (:meth:`stream`,
    :meth:`upload_filter`, the other filter-slot methods, :meth:`safe_stop`,
    :meth:`close`, ...) hold what every transport must do the same way (the
    excitation checked, the events emptied, ``last_result`` set also when the
    run raises, the first cause winning, the axis commanded safe on every
    ending) and are never overridden; a transport's adapter supplies

    ``_play(x, deliver, result)`` (required)
        play ``x``, pass ``(sample_index, rows)`` blocks to ``deliver``, fill
        ``result.stats``, set ``result.completed``; log events with
        :meth:`log_event` and a fault with :meth:`note_fault` as soon as known;
    ``_prepare_run(x)``
        refuse a run before anything was cleared or moved (not configured, ...);
    ``_end_run(result)``
        after every ending, a signal included: at least the safe stop (the default);
    ``_host_limit_columns()``
        ``(column, low, high, limit name)`` the host checks on every sample
        (default: none, the device enforces its limits);
    ``_fault_text(event)``, ``_collect_faults()``, ``_as_device_error(exc)``
        how a fault is worded, faults still queued at the device, transport
        exceptions that are device errors;
    ``_command_safe()``, ``_stop_for_close()``, ``_release()``
        the one command that makes the axis safe (for :meth:`safe_stop`), the
        stop before closing (default: the same) and releasing the connection
        (for :meth:`close`);
    ``_write_filter(slot, biquad, spec, enabled)``, ``_read_filter(slot)``, ``_stored_form(biquad, spec)`` (required)
        a notch stored in the device's encoding, read back, and as the device
        rounds it (for :meth:`write_filter`, :meth:`read_filter`,
        :meth:`stored_form`, which :meth:`upload_filter` builds on);
    ``_read_raw_slot(slot)``, ``_write_raw_slot(slot, saved)``
        a filter slot's contents, opaque (for :meth:`save_filter` / :meth:`restore_filter`);
    ``_bypass_slot(slot)``, ``_read_back_bypassed(slot, biquad, spec, expected)``
        bypassing a slot with its contents kept (for :meth:`disable_filter`),
        and checking a notch written bypassed (for :meth:`upload_filter`);
        both default to the generic way over the three required filter hooks;
    ``_run_refusal(driver)``, ``_set_trace(path)``, ``_set_excitation_recipe(recipe)``
        why a described device cannot play runs, a wire trace of the next run,
        the next run's excitation as parameters (defaults: none refused,
        nothing kept).

    Attributes
    ----------
    run_fault : dict or None
        The first fault event of the current run (its cause), or None.

    A transport's adapter sets :attr:`connect_report` and :attr:`channel_names`
    (and the other attributes of :class:`DeviceAdapter`) in its ``__init__``;
    they are declared here, without a value, because the template reads them.
    """

    port: str = ""
    events: list[dict]
    connect_report: ConnectReport
    channel_names: list[str]  # of the configured channels, in column order
    last_result: RunResult | None = None
    run_fault: dict | None = None
    # (column, low, high, limit name) of the run, from _host_limit_columns()
    _host_checks: Sequence[tuple[int, float, float, str]] = ()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @staticmethod
    def _or_closed(adapter: _Closable, step: Callable[[], object]) -> _Closable:
        """``adapter`` after ``step()`` succeeded; closed again (connection released) when it raised."""
        try:
            step()
        except BaseException:
            adapter.close()
            raise
        return adapter

    @classmethod
    def _identified(cls, adapter: _Identifiable) -> _Identifiable:
        """``adapter`` after a successful ``identify()``; closed again when that fails."""
        return cls._or_closed(adapter, adapter.identify)

    def _clear_latched_fault(self, fault: str, allowed: bool, clear: Callable[[], None]) -> None:
        """A fault found at connect: reported in :attr:`connect_report`, refused unless ``allowed``, else cleared.

        ``clear()`` resets the device and raises :class:`DeviceError` when the fault stays.
        """
        self.connect_report.faults.append(fault)
        if not allowed:
            raise refuse_latched_faults(self.port, self.connect_report.faults)
        clear()
        self.connect_report.faults_cleared = True

    # --- the run template -------------------------------------------------------------------

    def stream(
        self,
        excitation: np.ndarray,
        sink: Callable[[np.ndarray, np.ndarray], None],
        progress: Callable[[float], None] | None = None,
    ) -> RunResult:
        """Play ``excitation`` and pass ``(sample_index, rows)`` blocks to ``sink``; see :class:`DeviceAdapter`.

        ``progress(fraction)`` is called as samples arrive. The axis is
        commanded safe on every ending; events are appended to
        :attr:`events` as soon as known; :attr:`last_result` is set also when
        this raises.

        Raises
        ------
        DataError
            ``excitation`` is not a finite one-dimensional array.
        LimitTrip
            A limit tripped (the device's, or the host's check); the samples
            up to it were delivered. The first cause wins: whatever fails
            after a fault, the run ends with the fault.
        DeviceError
            The device faulted, the line or bus failed, the device did not
            keep up, ... (the transport's adapter names the object or register).
        Exception
            Whatever ``sink`` raised (a full disk, a signal), after the axis
            was commanded safe.
        """
        x = checked_excitation(excitation)
        result = self.open_run(x)
        from_sink: list[BaseException] = []
        deliver = self.run_deliver(sink, len(x), progress, from_sink)
        try:
            with timely_host():
                self._play(x, deliver, result)
        except BaseException as exc:
            if any(exc is e for e in from_sink):
                raise  # a full disk, a signal in the session's writer: its own error, after the axis is safe
            first = self.first_cause(exc)
            if first is not exc:
                raise first from None
            raise
        finally:
            self.close_run(result)
        if self.run_fault is not None:
            raise self.fault_error(self.run_fault) from None
        return result

    def open_run(self, x: np.ndarray) -> RunResult:
        """A run of ``x`` begins: refused before anything moves where it cannot play (:meth:`_prepare_run`), the
        events and the fault of the last run cleared; its fresh :class:`RunResult` (also :attr:`last_result`)."""
        self.last_result = None
        self._prepare_run(x)
        self.events = []
        self.run_fault = None
        result = self.last_result = RunResult(requested_samples=len(x), stats=StreamStats())
        self._host_checks = self._host_limit_columns()
        return result

    def run_deliver(
        self,
        sink: Callable[[np.ndarray, np.ndarray], None],
        n: int,
        progress: Callable[[float], None] | None,
        from_sink: list[BaseException],
    ) -> Deliver:
        """The ``deliver`` a run of ``n`` samples hands its blocks to: the host's limit check on every sample
        (a trip ends the run at that sample), then ``sink``, then ``progress``. What ``sink`` raises is appended
        to ``from_sink`` (so the caller tells it from the device's errors) and raised."""
        shown = [0.0]  # when progress was last called (monotonic s)

        def deliver(index: np.ndarray, rows: np.ndarray) -> None:
            if self.run_fault is not None and self.run_fault.get("host_check"):
                return  # nothing after the sample the host stopped the axis at
            tripped = self._host_limit_trip(index, rows)
            if tripped is not None:
                index, rows = index[: tripped + 1], rows[: tripped + 1]
            try:
                sink(index, rows)
            except BaseException as exc:
                from_sink.append(exc)
                raise
            if progress is not None and len(index):
                done = min(1.0, (int(index[-1]) + 1) / max(n, 1))
                now = time.monotonic()
                if done == 1.0 or now - shown[0] > _PROGRESS_S:
                    shown[0] = now
                    progress(done)
            if tripped is not None:
                assert self.run_fault is not None  # _host_limit_trip noted the trip (or an earlier fault) as the cause
                raise self.fault_error(self.run_fault)

        return deliver

    def close_run(self, result: RunResult) -> None:
        """After every ending of a run: the axis commanded safe (:meth:`_end_run`), the run's events in
        ``result``."""
        try:
            self._end_run(result)
        finally:
            result.events = list(self.events)

    @classmethod
    def run_refusal(cls, driver: DriverDescription) -> ConfigError | None:
        """Why ``hilident run`` cannot play experiments on a device described by ``driver`` (a ConfigError
        naming the driver file, to raise or report), or None when it can."""
        return cls._run_refusal(driver)

    @classmethod
    def _run_refusal(cls, driver: DriverDescription) -> ConfigError | None:
        """Why a device ``driver`` describes cannot play runs (hook); default None: every device with an
        excitation path can."""
        return None

    def set_trace(self, path: str | os.PathLike[str]) -> None:
        """Write a wire trace of the next run to ``path`` where the transport keeps one (CANopen: ``.asc`` or
        ``.blf``), so a session may ask every adapter."""
        self._set_trace(path)

    def _set_trace(self, path: str | os.PathLike[str]) -> None:
        """Keep ``path`` for the next run's wire trace (hook; default: the transport keeps no trace)."""

    def set_excitation_recipe(self, recipe: dict | None) -> None:
        """The next run's excitation as parameters (``kind``, ``amplitude``, band, ...), or None.

        Only a device whose own generator plays the excitation needs it (a
        CANopen drive's recorder runs); every other run plays the samples it
        is given.
        """
        self._set_excitation_recipe(recipe)

    def _set_excitation_recipe(self, recipe: dict | None) -> None:
        """Keep the next run's excitation recipe (hook; default: nothing kept, the run plays its samples)."""

    def _prepare_run(self, x: np.ndarray) -> None:
        """Refuse a run of ``x`` before anything is cleared or moved (hook; default: nothing to check)."""

    def _play(self, x: np.ndarray, deliver: Deliver, result: RunResult) -> None:
        """Play ``x`` on the device and pass what comes back to ``deliver`` (hook, required)."""
        raise NotImplementedError

    def _end_run(self, result: RunResult) -> None:
        """After every ending of a run (hook): the axis commanded safe."""
        self.safe_stop()

    def log_event(self, event: RunEvent) -> dict:
        """Append ``event`` to :attr:`events` now (the session records it while the run goes on); its dict."""
        entry = event.to_dict()
        self.events.append(entry)
        return entry

    def note_fault(self, event: dict) -> None:
        """Record ``event`` as the run's fault; the first one stays the cause."""
        if self.run_fault is None:
            self.run_fault = event
            if self.last_result is not None:
                self.last_result.fault = event["message"]

    def fault_error(self, event: dict, then: BaseException | None = None) -> DeviceError:
        """The exception a run ends with after fault ``event`` (LimitTrip for a limit);
        ``then``: what failed after it."""
        cls = LimitTrip if event["kind"] == Kind.LIMIT_TRIP.value else DeviceError
        text = f"{self.port}: {self._fault_text(event)}"
        if then is not None:
            text += f" (then: {then})"
        error = cls(text)
        error.event = event  # the run's first cause, for first_cause()
        return error

    def _fault_text(self, event: dict) -> str:
        """A fault event in the words its run ends with (hook)."""
        return event["message"]

    def _collect_faults(self) -> None:
        """Note faults the device reported that are still queued (hook; default: none are)."""

    def _as_device_error(self, exc: BaseException) -> BaseException:
        """A transport exception that means the device or its line failed, as a DeviceError (hook)."""
        return exc

    def first_cause(self, exc: BaseException) -> BaseException:
        """The error a run that raised ``exc`` ends with: the first fault the device reported, else ``exc``.

        A lost line or a refused request is often only the consequence of a
        fault (a limit trip) the device just reported: the fault is the cause.
        """
        exc = self._as_device_error(exc)
        if not isinstance(exc, DeviceError):
            return exc
        self._collect_faults()
        if self.run_fault is None or exc.event is self.run_fault:
            return exc
        return self.fault_error(self.run_fault, then=exc)

    # --- the host's limit check -------------------------------------------------------------------

    def _host_limit_columns(self) -> list[tuple[int, float, float, str]]:
        """(channel column, low, high, limit name) checked by the host on every sample (hook; default none)."""
        return []

    def _host_limit_trip(self, index: np.ndarray, rows: np.ndarray) -> int | None:
        """Row of the first sample outside a host-checked limit (logged and noted as the run's fault), or None."""
        first: tuple[int, int, str, float, float] | None = None
        for j, low, high, name in self._host_checks:
            out = np.flatnonzero((rows[:, j] < low) | (rows[:, j] > high))
            if len(out) and (first is None or out[0] < first[0]):
                first = (int(out[0]), j, name, low, high)
        if first is None:
            return None
        row, j, name, low, high = first
        value = float(rows[row, j])
        event = self.log_event(
            RunEvent(
                Kind.LIMIT_TRIP,
                f"{name}: {self.channel_names[j]} = {value:.4g} outside [{low:.4g}, {high:.4g}] "
                "(checked by the host): axis stopped, torque zero",
                int(index[row]),
                value=value,
                host_check=True,
            )
        )
        self.note_fault(event)
        self.safe_stop()
        return row

    # --- stopping -------------------------------------------------------------------------------

    def close(self) -> None:
        """The axis stopped, the connection released. Never raises."""
        try:
            self._stop_for_close()
        finally:
            try:
                self._release()
            except Exception:
                pass  # closing a connection that is already gone

    def _stop_for_close(self) -> None:
        """The stop before the connection is released (hook; default :meth:`safe_stop`)."""
        self.safe_stop()

    def _release(self) -> None:
        """Release the connection (hook)."""
        raise NotImplementedError

    def safe_stop(self) -> None:
        """Command the axis safe now; never raises (see :class:`DeviceAdapter`)."""
        try:
            self._command_safe()
        except Exception:
            pass  # the device-side net (watchdog, timeout, heartbeat consumer) stops a device that is gone

    def _command_safe(self) -> None:
        """Send the transport's one stop command (hook)."""
        raise NotImplementedError

    # --- filter slots -----------------------------------------------------------------------------

    def upload_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None) -> FilterUpload:
        """Store a notch in ``slot`` so that it is either applied as written or not changed at all.

        The slot's contents are kept, the notch written disabled, read back and
        compared with :meth:`stored_form`; only a notch that came back as
        written is enabled (and read back again). Otherwise the previous
        contents are restored.
        """
        previous = self.save_filter(slot)
        self.write_filter(slot, biquad, spec, enabled=False)
        expected = self.stored_form(biquad, spec)
        stored, same = self._read_back_bypassed(slot, biquad, spec, expected)
        if same:
            self.write_filter(slot, biquad, spec, enabled=True)
            stored, enabled = self.read_filter(slot)
            same = enabled and stored == expected
        if not same:
            self.restore_filter(slot, previous)
        return FilterUpload(stored, expected, bool(same))

    def save_filter(self, slot: int) -> Any:
        """The slot's contents, opaque, for :meth:`restore_filter`."""
        return self._read_raw_slot(slot)

    def restore_filter(self, slot: int, saved: Any) -> None:
        """Put back what :meth:`save_filter` returned."""
        self._write_raw_slot(slot, saved)

    def disable_filter(self, slot: int) -> None:
        """Bypass ``slot``, its contents kept (:meth:`restore_filter` brings it back)."""
        self._bypass_slot(slot)

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None, *, enabled: bool) -> None:
        """Store a notch in ``slot`` in the device's own encoding, enabled or bypassed."""
        self._write_filter(slot, biquad, spec, enabled)

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad ``slot`` now applies, and whether it is enabled."""
        return self._read_filter(slot)

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None = None) -> Biquad:
        """The biquad the device applies after its own rounding of ``biquad``/``spec``."""
        return self._stored_form(biquad, spec)

    def _write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None, enabled: bool) -> None:
        """Store a notch in ``slot`` in the device's own encoding, enabled or bypassed (hook, required)."""
        raise NotImplementedError

    def _read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad ``slot`` now applies, and whether it is enabled (hook, required)."""
        raise NotImplementedError

    def read_loop(self) -> dict[str, float] | None:
        """The device's cascade parameters in SI units (:data:`hilident.protocol.loop_parameters.PARAMETERS`);
        None when its driver description does not describe its loop. A drive that keeps the velocity integral as
        a gain is read in the cascade's form (``ti_s``: :meth:`LoopDescription.to_cascade
        <hilident.protocol.loop_parameters.LoopDescription.to_cascade>`)."""
        values = self._read_loop()
        loop = self._loop_description()
        return values if values is None or loop is None else loop.to_cascade(values)

    def _loop_description(self):
        """The driver's ``[loop]`` (:class:`~hilident.protocol.loop_parameters.LoopDescription`; hook; default:
        none)."""
        return None

    def _read_loop(self) -> dict[str, float] | None:
        """The cascade's parameters as the device keeps them (hook; default: no loop described, None)."""
        return None

    def write_loop(self, values: Mapping[str, float]) -> None:
        """Write cascade parameters, SI units, into the device (only the tunable ones:
        :data:`hilident.protocol.loop_parameters.TUNABLE`).

        Raises
        ------
        DeviceError
            The device refused one or the line failed; the message names the object, register or message.
        UsageError
            A parameter is not tunable, or the device's description keeps it as a fixed value.
        """
        from hilident.protocol.loop_parameters import TUNABLE

        fixed = sorted(set(values) - set(TUNABLE))
        if fixed:
            raise UsageError(f"{fixed[0]} is no gain a tuner may change (they are {list(TUNABLE)})")
        loop = self._loop_description()
        self._write_loop(dict(values) if loop is None else loop.to_device(values, self._present_loop))

    def stored_loop(self, values: Mapping[str, float]) -> dict[str, float]:
        """What the device will hold for ``values`` after its own rounding (its objects' or registers' types and
        scales), SI units: what :meth:`read_loop` reads back after :meth:`write_loop`."""
        loop = self._loop_description()
        if loop is None:
            return self._stored_loop(dict(values))
        present = functools.cache(self._present_loop)  # read from the device once, if at all
        stored = loop.to_cascade(self._stored_loop(loop.to_device(values, present)), present)
        return {name: stored[name] for name in values}

    def _present_loop(self) -> dict[str, float]:
        """The present cascade parameters (for a write of ``kv`` or ``ti`` alone to a drive that keeps ``ki``)."""
        present = self.read_loop()
        if present is None:
            raise UsageError(f"{self.port}: the device does not report its loop")
        return present

    def _write_loop(self, values: dict[str, float]) -> None:
        """Write the tunable parameters ``values`` (hook; default: the device describes no loop)."""
        raise UsageError(f"{self.port}: the driver describes no loop parameters ([loop]) to write")

    def _stored_loop(self, values: dict[str, float]) -> dict[str, float]:
        """``values`` as the device stores them (hook; default: unchanged)."""
        return dict(values)

    def _stored_form(self, biquad: Biquad, spec: NotchSpec | None) -> Biquad:
        """The biquad the device applies after its own rounding of ``biquad``/``spec`` (hook, required)."""
        raise NotImplementedError

    def _bypass_slot(self, slot: int) -> None:
        """Bypass ``slot``, its contents kept (hook; default: read back, rewritten disabled when enabled)."""
        biquad, enabled = self.read_filter(slot)
        if enabled:
            self.write_filter(slot, biquad, enabled=False)

    def _read_back_bypassed(
        self, slot: int, biquad: Biquad, spec: NotchSpec | None, expected: Biquad
    ) -> tuple[Biquad, bool]:
        """What ``slot`` holds after ``biquad``/``spec`` was written to it bypassed, and whether that is the
        notch as written (hook; default: the slot's biquad read back and compared with ``expected``, the
        :meth:`stored_form`)."""
        stored, _ = self.read_filter(slot)
        return stored, stored == expected

    def _read_raw_slot(self, slot: int) -> Any:
        """A filter slot's contents as the device holds them (hook)."""
        raise NotImplementedError

    def _write_raw_slot(self, slot: int, saved: Any) -> None:
        """Write back what :meth:`_read_raw_slot` returned (hook)."""
        raise NotImplementedError


class RunStrategy(Generic[_Host]):
    """One acquisition strategy's run: it owns the run's state and talks to its adapter through hooks.

    A transport with several ways of playing a run (CANopen: host-streamed,
    drive-buffered, ...) keeps a table ``{acquisition name: strategy}``; its
    ``_play`` looks the strategy up and calls :meth:`play`. A strategy is any
    callable ``(adapter, x, deliver, result)``; subclasses of this class take
    their arguments in ``__init__`` and do the work in :meth:`run`. ``RunStrategy[SomeAdapter]`` types
    :attr:`ad` as that adapter.
    """

    def __init__(self, adapter: _Host, x: np.ndarray, deliver: Deliver, result: RunResult):
        self.ad = adapter
        self.x = x
        self.n = len(x)
        self.deliver = deliver
        self.result = result
        self.stats = result.stats

    @classmethod
    def play(cls, adapter: _Host, x: np.ndarray, deliver: Deliver, result: RunResult) -> None:
        """Run ``x`` on ``adapter`` with a fresh instance (the strategy-table entry)."""
        cls(adapter, x, deliver, result).run()

    def run(self) -> None:
        """Play the run; fill ``self.result`` (hook, required)."""
        raise NotImplementedError

    def finish_capture(self, got: int, short_message: str, done_message: str) -> None:
        """End a run the device captured on its own: ``got`` of the run's samples came home.

        All of them: the ``capture_end`` event and the run complete. Fewer:
        the rest counted lost (never filled), the ``capture_short`` event,
        and DeviceError with ``short_message`` (which names the object or
        register that told).
        """
        n, ad = self.n, self.ad
        if got < n:
            self.stats.lost_samples += n - got
            self.stats.lost_blocks += 1
            ad.log_event(RunEvent(Kind.CAPTURE_SHORT, short_message, got, value=float(n - got)))
            self.result.fault = short_message
            raise DeviceError(f"{ad.port}: {short_message}")
        ad.log_event(RunEvent(Kind.CAPTURE_END, done_message, n, value=float(n)))
        self.result.completed = True
