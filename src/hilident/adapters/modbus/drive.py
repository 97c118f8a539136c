"""Host side of a Modbus drive (Modbus TCP or Modbus RTU), over pymodbus.

Experiments run drive-buffered: the adapter writes the excitation table into
the drive through its paged table window (write-multiple requests of at most
``max_write_registers``), checks the drive's CRC of the table, triggers the
run, and reads the capture back through the paged capture window while the
drive plays the table (read requests of at most ``max_read_registers``). Every
capture record carries a stamp (its sample index modulo 65536): a record that
is not the one asked for is read again, and a chunk that cannot be read is
counted as lost, never filled.

Requests that are safe to repeat (reads, and writes of the same values to the
same registers) are retried after a timeout; the start command never is: when
its answer is lost, the adapter asks the drive whether it is running. Modbus
exception responses become :class:`~hilident.errors.DeviceError` naming the
register (address and name from the driver's map) and the exception's meaning.

At connect the adapter brings the drive to a known state, whatever the
previous session left behind: on an RTU line it drops (and counts) answers
still on their way to a host that is gone, writes the stop command, reads the
latched fault and clears it only when ``[device] allow_fault_reset`` says so
(else the drive is refused before anything moves), and writes the drive's
communication timeout (``comm_timeout_ms``, from ``[device] host_timeout_s``)
when the map names it: a host that dies while the drive is enabled leaves it
stopped by the drive itself. While the drive is enabled the adapter talks to
it far more often than that, and waits at most 40 % of the timeout for an
answer, so a lost answer is asked again before the drive gives up on the host.

A lost connection (the drive power-cycled, the gateway closed the socket, the
USB adapter unplugged) is a :class:`~hilident.errors.DeviceError` naming the
port, never repeated. The register map is the driver's (see
``drivers/modbus-servo/README.md``); :mod:`hilident.protocol.modbus.register_map`
encodes and decodes it.

The adapter owns its parts and hands each its share of the work, so a call
site says where the code lives: ``registers``
(:class:`~hilident.adapters.modbus.requests.RegisterAccess`: every request,
its retries, stale answers and exceptions, the status registers), ``capture``
(:class:`~hilident.adapters.modbus.capture.TableCapture`: the excitation table
through its page window, the trigger, the capture read back), ``slots``
(:class:`~hilident.adapters.modbus.slots.ModbusFilterSlots`) and ``cascade``
(:class:`~hilident.adapters.modbus.loop.ModbusLoop`: the ``[loop]`` registers). Each part gets
what it needs in its constructor; none of them sees the adapter. This module
keeps opening and the known state at connect, the RTU line, identity, the
parameter drive, the run that follows the drive's status, the stop, and the
hooks of :class:`~hilident.adapters.base.AdapterBase` (it overrides none of its
public methods).
"""

from __future__ import annotations

import math
import time
from typing import NoReturn

import numpy as np
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from hilident.adapters.base import AdapterBase, ConnectReport, Deliver, RunResult
from hilident.adapters.modbus.capture import TableCapture
from hilident.adapters.modbus.common import (
    _CHUNKS_PER_POLL,
    _DRAIN_MAX_S,
    _DRAIN_QUIET_S,
    _IDENTITY,
    _LIMIT_FAULTS,
    _POLL_S,
    _STOP_WAIT_S,
    CaptureLayout,
    DriveStatus,
    ModbusIdentity,
    _serial_error,
    _SerialClient,
)
from hilident.adapters.modbus.loop import ModbusLoop
from hilident.adapters.modbus.requests import RegisterAccess
from hilident.adapters.modbus.slots import ModbusFilterSlots, SavedSlot
from hilident.adapters.ports import open_failure
from hilident.config.tables import DeviceConfig
from hilident.drivers.description import DriverDescription
from hilident.errors import ConfigError, DataError, DeviceError
from hilident.events import Kind, RunEvent, StreamStats
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.protocol.modbus.rtu import count_rtu_frames
from hilident.units import units_in_mode


class ModbusDriveAdapter(AdapterBase):
    """A servo drive with a Modbus register map, experiments played from its own table.

    Parameters
    ----------
    client : pymodbus ModbusTcpClient or ModbusSerialClient
        Connected, with ``retries=0`` (the adapter decides what is repeated).
    driver : DriverDescription
    regmap : RegisterMap
    port : str
        ``tcp://host:port`` or the serial port; used in messages.
    device_id : int
        Modbus device (unit) id.
    timeout_s : float
        Longest wait for one answer.

    Attributes
    ----------
    registers, capture, slots, cascade
        The parts (see the module docstring).
    """

    transport = "modbus"

    def __init__(
        self,
        client: ModbusTcpClient | ModbusSerialClient,
        driver: DriverDescription,
        regmap: RegisterMap,
        port: str,
        device_id: int = 1,
        timeout_s: float = 2.0,
    ):
        self.client = client
        self.driver = driver
        self.map = regmap
        self.port = port
        self.device_id = device_id
        self.timeout_s = timeout_s
        self.rtu = isinstance(client, ModbusSerialClient)
        self.identity: ModbusIdentity | None = None
        self.sample_rate_hz = 0.0
        self.channel_names: list[str] = []
        self.channel_units: list[str] = []
        self.last_result: RunResult | None = None
        self.events: list[dict] = []
        self.connect_report = ConnectReport()
        self._run_counts = (0, 0)  # missing and bad answers when the run started
        self.registers = RegisterAccess(client, regmap, driver, port, device_id, timeout_s)
        self.capture = TableCapture(self.registers, self._known_identity, self.log_event)
        self.slots = ModbusFilterSlots(self.registers, self._known_identity)
        self.cascade = ModbusLoop(self.registers)

    # --- opening --------------------------------------------------------------------

    @classmethod
    def open_device(cls, device: DeviceConfig, driver: DriverDescription, link=None) -> ModbusDriveAdapter:
        """Connect as ``[device]`` says (``tcp://HOST:PORT`` or a serial port), identify the drive and
        bring it to a known state.

        On an RTU line, answers still on their way to an earlier host are
        dropped and counted (``connect_report.discarded_frames``); the drive
        is stopped and disabled; a latched fault is reported in
        ``connect_report.faults`` and cleared only with
        ``device.allow_fault_reset``; the communication timeout is set from
        ``device.host_timeout_s`` when the map names ``comm_timeout_ms``
        (``connect_report.device_net``).

        Raises
        ------
        ConfigError
            A ``[device]`` value or the driver's map does not fit.
        DeviceError
            Nothing answers at ``port``, the drive is not the one the driver
            describes, it has a latched fault and no permission to clear it,
            or it refuses a request at connect (the message names the register).
        """
        if device.acquisition == "streamed":
            raise ConfigError(
                "device.acquisition", 'a Modbus drive runs drive-buffered experiments only (use "buffered" or "auto")'
            )
        regmap = RegisterMap.from_driver(driver)
        shown = (
            regmap.capture_channel_names()
            if regmap.excitation
            else [r.channel for r in regmap.registers.values() if r.channel]
        )
        missing = [c.name for c in driver.channels if c.name not in shown]
        if missing:
            where = (
                "[[modbus.capture.channels]]" if regmap.excitation else "registers (key channel) of [modbus.registers]"
            )
            raise ConfigError(
                "channels",
                f"driver {driver.name!r} lists channels {missing} that its {where} do not hold",
                str(driver.folder / "driver.toml"),
            )
        port = device.port
        client: ModbusTcpClient | ModbusSerialClient
        if port.startswith("tcp://"):
            host, _, number = port[len("tcp://") :].rpartition(":")
            if not host or not number.isdigit():
                raise ConfigError("device.port", f"{port!r} is not tcp://HOST:PORT")
            client = ModbusTcpClient(host, port=int(number), timeout=device.timeout_s, retries=0)
            if not client.connect():
                raise DeviceError(f"{port}: cannot connect to {host}:{number} (is the drive on and the port right?)")
        else:
            baudrate = device.baudrate or driver.default_baudrate
            line = device.modbus
            client = _SerialClient(
                port, baudrate=baudrate, parity=line.parity, stopbits=line.stopbits, timeout=device.timeout_s, retries=0
            )
            if not client.connect():
                raise open_failure(
                    port,
                    _serial_error(port, baudrate, device),
                    f"cannot open at {baudrate} baud, parity {line.parity}, {line.stopbits} stop bit(s)",
                )
        adapter = cls(client, driver, regmap, port, device.modbus.device_id, device.timeout_s)
        adapter._drain_line()
        adapter = cls._identified(adapter)
        return cls._or_closed(
            adapter, lambda: adapter._bring_to_known_state(device.allow_fault_reset, device.host_timeout_s)
        )

    def _drain_line(self) -> None:
        """RTU: drop the answers still on their way to an earlier host, until the line is quiet (counted)."""
        sock = self.registers.rtu_line()
        if sock is None:
            return
        quiet = min(self.timeout_s, _DRAIN_QUIET_S)
        data = b""
        start = last = time.monotonic()
        try:
            while time.monotonic() - last < quiet and time.monotonic() - start < _DRAIN_MAX_S:
                if waiting := sock.in_waiting:
                    data += sock.read(waiting)
                    last = time.monotonic()
                else:
                    time.sleep(0.005)
        except (OSError, ValueError):
            pass  # the first request reports a broken line, naming the register
        self.connect_report.discarded_frames += count_rtu_frames(data)

    def _bring_to_known_state(self, allow_fault_reset: bool, host_timeout_s: float) -> None:
        """Stop the drive, report (and, when allowed, clear) a latched fault, arm the communication timeout.

        Raises
        ------
        DeviceError
            The drive has a latched fault and ``allow_fault_reset`` is false
            (the message says how to clear it), the fault does not clear, or
            the timeout does not read back as written.
        """
        report = self.connect_report
        if not self.map.excitation:
            if self.map.stop:
                self.registers.write_names(**self.map.stop)  # no speed, no torque asked of the drive
            self._arm_comm_timeout(host_timeout_s)
            report.discarded_frames += (
                getattr(self.client, "stale_frames", 0) + self.registers.dropped_frames + self.registers.bad_responses
            )
            return
        self.registers.write_names(control_word=0)  # stopped, disabled, zero torque, ready for a fresh 0 -> 1 edge
        st = self.registers.status()
        if "fault" in st.flags:

            def clear() -> None:
                self.clear_fault()
                after = self.registers.status()
                if "fault" in after.flags:
                    raise DeviceError(
                        f"{self.port}: {self.map.describe(self.map.register('fault_code').address)} "
                        f"still holds {self.map.fault_name(after.fault_code)} after a fault reset; the "
                        "cause is still there (check the drive's display)"
                    )

            self._clear_latched_fault(self._describe_fault(st), allow_fault_reset, clear)
        self._arm_comm_timeout(host_timeout_s)
        client_stale = getattr(self.client, "stale_frames", 0)
        report.discarded_frames += client_stale + self.registers.dropped_frames + self.registers.bad_responses

    def _arm_comm_timeout(self, host_timeout_s: float) -> None:
        """Write ``comm_timeout_ms`` from ``host_timeout_s`` and read it back (when the map names it)."""
        if "comm_timeout_ms" not in self.map.registers:
            self.connect_report.device_net = ""
            return
        r = self.map.register("comm_timeout_ms")
        ms = max(1, math.ceil(host_timeout_s * 1000.0 - 1e-9))
        try:
            self.registers.write_names(comm_timeout_ms=ms)
        except DataError as exc:
            raise ConfigError(
                "device.host_timeout_s", f"{host_timeout_s:g} s does not fit {self.map.describe(r.address)}: {exc}"
            ) from None
        back = float(self.registers.read_names("comm_timeout_ms")["comm_timeout_ms"])
        if not back or abs(back - ms) > max(r.scale, 1.0):
            raise DeviceError(
                f"{self.port}: {self.map.describe(r.address)} reads {back:g} ms after "
                f"{ms} ms was written: the drive's communication timeout is not armed"
            )
        self.registers.comm_timeout_s = back / 1000.0
        self.connect_report.device_net = f"communication timeout {self.map.describe(r.address)}: {back:g} ms"

    def _stop_for_close(self) -> None:
        """Zero torque, drive disabled, waiting as long as any answer (not the quick :meth:`safe_stop`)."""
        self.stop()

    def _release(self) -> None:
        self.client.close()

    def _command_safe(self) -> None:
        """Write 0 to the control word now (run stopped, drive disabled, zero torque).

        Quick: the answer is waited for at most 50 ms, and the write sent at
        most twice. The connection stays open.
        """
        self._stop(tries=2, wait_s=_STOP_WAIT_S)

    # --- device operations ------------------------------------------------------------------

    def identify(self) -> ModbusIdentity:
        """Read the identity registers and check the drive is the one the driver describes."""
        if not self.map.excitation:
            return self._identify_parameters()
        v = self.registers.read_names(*_IDENTITY)
        m, d = self.map, self.driver

        def mismatch(name: str, got: object, want: object, hint: str = "") -> NoReturn:
            raise DeviceError(
                f"{self.port}: {m.describe(m.register(name).address)} holds {got}; driver "
                f"{d.name!r} expects {want}{hint}"
            )

        if v["device_type"] != m.device_type:
            mismatch(
                "device_type",
                f"{v['device_type']:#06x}",
                f"{m.device_type:#06x}",
                f" (is device id {self.device_id} the drive?)",
            )
        if v["map_version"] != m.map_version:
            mismatch("map_version", v["map_version"], m.map_version)
        if abs(float(v["loop_rate_hz"]) - d.loop_rate_hz) > 1e-6 * d.loop_rate_hz:
            mismatch("loop_rate_hz", f"{v['loop_rate_hz']:g} Hz", f"{d.loop_rate_hz:g} Hz")
        if v["filter_slots"] != d.filter_slots:
            mismatch("filter_slots", v["filter_slots"], d.filter_slots)
        self.identity = ModbusIdentity(
            name=str(v["device_name"] or d.name),
            firmware=str(v["firmware"]),
            loop_rate_hz=float(v["loop_rate_hz"]),
            max_sample_rate_hz=float(v["max_sample_rate_hz"]),
            filter_slots=int(v["filter_slots"]),
            table_capacity=int(v["table_capacity"]),
            capture_capacity=int(v["capture_capacity"]),
            device_type=int(v["device_type"]),
            map_version=int(v["map_version"]),
        )
        return self.identity

    def _identify_parameters(self) -> ModbusIdentity:
        """A parameter drive: the registers ``[modbus.identity]`` names, checked against ``expect``."""
        m, d = self.map, self.driver
        v = self.registers.read_names(*m.identity)
        for name, want in m.expect.items():
            if v[name] != want:
                r = m.register(name)
                raise DeviceError(
                    f"{self.port}: {m.describe(r.address, r.count, table=r.table)} holds {v[name]}; "
                    f"driver {d.name!r} expects {want} (is device id {self.device_id} the drive?)"
                )
        slots = m.filters.slots if m.filters is not None else 0
        firmware = ", ".join(f"{n} {v[n]}" for n in m.identity)
        self.identity = ModbusIdentity(
            name=d.name,
            firmware=firmware,
            loop_rate_hz=float(d.loop_rate_hz),
            max_sample_rate_hz=float(d.max_sample_rate_hz),
            filter_slots=slots,
            table_capacity=0,
            capture_capacity=0,
            device_type=int(m.device_type),
            map_version=int(m.map_version),
            registers=dict(v),
        )
        return self.identity

    # --- a parameter drive ---------------------------------------------------------------------

    @classmethod
    def _run_refusal(cls, driver: DriverDescription) -> ConfigError | None:
        """Why ``hilident run`` cannot run on ``driver`` (a drive without the excitation capability), or None."""
        regmap = RegisterMap.from_driver(driver)
        if regmap.excitation:
            return None
        return ConfigError(
            "device.driver",
            f"driver {driver.name!r} describes a drive without an excitation capability (no [modbus.table] "
            f"and [modbus.capture] in {driver.folder / 'driver.toml'}): hilident cannot play an experiment on it. "
            "Record the axis "
            "another way (the drive vendor's scope exported to CSV, or a serial board on the same axis), run "
            "`hilident identify RECORDING`, then `hilident upload --from RUN_DIR --config CONFIG` to write the notch",
            str(driver.folder / "driver.toml"),
        )

    def _refuse_run(self) -> None:
        refusal = self.run_refusal(self.driver)
        if refusal is not None:
            raise refusal

    def _known_identity(self) -> ModbusIdentity:
        """What :meth:`identify` read; DeviceError when the drive was not identified (never opened)."""
        if self.identity is None:
            raise DeviceError(f"{self.port}: the drive has not been identified (open it first)")
        return self.identity

    def read_parameter(self, code: str) -> float | int | str:
        """The physical value of vendor parameter ``code`` (``"P08.02"``), through the map's rule (a string for a
        text parameter)."""
        try:
            r = self.map.parameter(code)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {exc}") from None
        return r.decode(
            self.registers.read(r.address, r.count, f"reading parameter {code}", input_registers=r.table == "input")
        )

    def write_parameter(self, code: str, value: float | int | str) -> None:
        """Write vendor parameter ``code``; refused before sending when it is read-only or out of its range."""
        try:
            r = self.map.parameter(code)
            words = r.encode(value)
        except DataError as exc:
            raise DeviceError(f"{self.port}: parameter {code} not written: {exc}") from None
        if not r.writable:
            raise DeviceError(
                f"{self.port}: parameter {code} ({self.map.describe(r.address, table=r.table)}) is read-only"
            )
        self.registers.write(r.address, words, f"writing parameter {code}")

    def read_feedback(self) -> dict[str, float]:
        """Channels the drive shows in registers (``channel`` in the map), in SI units."""
        shown = {r.name: r for r in self.map.registers.values() if r.channel}
        values = self.registers.read_names(*shown) if shown else {}
        return {r.channel: float(values[n]) * r.channel_scale for n, r in shown.items()}

    def save_parameters(self) -> str:
        """Store the drive's parameters in non-volatile memory (``[modbus.save]``); returns what was written.

        Raises
        ------
        DeviceError
            The map describes no save parameter, or the drive refuses it.
        """
        if self.map.save is None:
            raise DeviceError(
                f"{self.port}: driver {self.driver.name!r} describes no save parameter "
                "([modbus.save] in its driver.toml)"
            )
        name, value = self.map.save
        r = self.map.register(name)
        self.registers.write(r.address, self.map.encode(name, value), "saving the parameters to non-volatile memory")
        return f"{self.map.describe(r.address, r.count)} = {value:g}"

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the limits the drive enforces on its own (crossing one stops the axis).

        A parameter drive's map holds no limit registers and hilident moves
        nothing on it (no experiment can run): there is nothing to load.
        """
        if not self.map.excitation:
            return
        self.registers.write_names(
            torque_limit_nm=torque_nm,
            velocity_limit_mps=velocity_mps,
            position_min_m=position_min_m,
            position_max_m=position_max_m,
        )
        if "limits_loaded" not in self.registers.status().flags:
            raise DeviceError(
                f"{self.port}: the drive does not report its limits loaded "
                f"({self.map.describe(self.map.register('status_word').address)})"
            )

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Choose the capture rate, excitation mode and captured channels; returns the channel names."""
        self._refuse_run()
        ident = self._known_identity()
        divider = ident.loop_rate_hz / sample_rate_hz
        if abs(divider - round(divider)) > 1e-9 or round(divider) < 1:
            raise DeviceError(
                f"{self.port}: sample rate {sample_rate_hz:g} Hz does not divide the drive's loop "
                f"rate {ident.loop_rate_hz:g} Hz"
            )
        if sample_rate_hz > ident.max_sample_rate_hz * (1 + 1e-9):
            raise DeviceError(
                f"{self.port}: sample rate {sample_rate_hz:g} Hz exceeds the drive's {ident.max_sample_rate_hz:g} Hz"
            )
        if mode not in self.map.modes:
            raise ConfigError("excitation.mode", f"the drive offers modes {sorted(self.map.modes)}, got {mode!r}")
        names = list(channels) if channels else [c.name for c in self.driver.streamed_channels]
        mask = self.map.mask_of(names)
        self.registers.write_names(mode=self.map.modes[mode], sample_divider=int(round(divider)), capture_mask=mask)
        record = [c.name for c in self.map.selected(mask)]
        self.capture.layout = CaptureLayout(mask, tuple(record.index(n) for n in names))
        units = {c.name: c.unit for c in self.driver.channels}
        self.channel_names = names
        self.channel_units = units_in_mode(names, [units.get(n, "") for n in names], mode)
        self.sample_rate_hz = ident.loop_rate_hz / round(divider)
        return self.channel_names

    def stop(self) -> None:
        """Write 0 to the control word: run stopped, drive disabled, zero torque. Never raises."""
        self._stop(tries=2, wait_s=self.timeout_s)

    def _stop(self, tries: int, wait_s: float) -> None:
        if not self.map.excitation:
            self._stop_parameters(wait_s)
            return
        r = self.map.register("control_word")
        try:
            with self.registers.answers_within(wait_s):
                self.registers.request(
                    "stopping the drive",
                    r.address,
                    1,
                    lambda: self.client.write_registers(r.address, [0], device_id=self.device_id),
                    lambda resp: resp.address == r.address,
                    retry=True,
                    tries=tries,
                )
        except Exception:
            pass  # the drive's communication timeout stops it when the host cannot

    def _stop_parameters(self, wait_s: float) -> None:
        """A parameter drive: write ``[modbus.stop]`` (no speed, no torque), if the map gives it. Never raises."""
        if not self.map.stop:
            return
        try:
            with self.registers.answers_within(wait_s):
                self.registers.write_names(**self.map.stop)
        except Exception:
            pass

    def clear_fault(self) -> None:
        """Clear a latched fault (0 -> 1 edge of the fault_reset bit)."""
        self.registers.write_names(control_word=0)
        self.registers.write_names(control_word=self.map.control["fault_reset"])
        self.registers.write_names(control_word=0)

    # --- runs (hooks of AdapterBase.stream) ---------------------------------------------------------

    def _prepare_run(self, x: np.ndarray) -> None:
        self._refuse_run()

    def _play(self, x: np.ndarray, deliver: Deliver, result: RunResult) -> None:
        """Play ``x`` from the drive's table and hand the captured samples to ``deliver``.

        ``x[k]`` is held over sample period ``k``; row ``k`` is the drive's
        state at the start of that period. Samples the capture lacks (chunks
        that could not be read, a capture that stopped early) are counted in
        the result's stats, never filled. A fault is logged as soon as a status
        read shows it. While the drive is enabled each answer is waited for at
        most 40 % of the communication timeout.

        Raises
        ------
        DeviceError
            The drive refused a request (the message names the register),
            stopped answering, lost the connection, or did not finish in time.
        DataError
            The excitation is empty or a value does not fit the table's type.
        """
        registers = self.registers
        self._run_counts = (registers.missing_responses, registers.bad_responses)
        self.capture.load_table(x)
        with registers.answers_within(registers.enabled_wait_s):
            self.capture.trigger()
            self._follow_capture(len(x), result.stats, deliver)
        result.completed = self.run_fault is None

    def _end_run(self, result: RunResult) -> None:
        """The drive stopped and disabled; the run's unanswered and bad answers counted."""
        self.safe_stop()
        missing_before, bad_before = self._run_counts
        result.stats.lost_frames = self.registers.missing_responses - missing_before
        result.stats.corrupt_frames += self.registers.bad_responses - bad_before

    def _follow_capture(self, n: int, stats: StreamStats, deliver: Deliver) -> None:
        """Poll the status and read the capture as it fills, until the run has ended and all is read."""
        started = time.monotonic()
        deadline = started + 1.2 * n / self.sample_rate_hz + 2.0 + 2 * self.timeout_s
        status_word = self.map.describe(self.map.register("status_word").address)
        read_to = 0
        while True:
            st = self.registers.status()
            if "fault" in st.flags and self.run_fault is None:
                self._note_status_fault(st)  # known now: the first cause, whatever fails after it
            available = min(st.sample_count, n)
            before = read_to
            read_to = self.capture.read_capture(read_to, available - read_to, deliver, stats, _CHUNKS_PER_POLL)
            ended = "running" not in st.flags
            if ended and read_to >= available:
                break
            if ended and not st.flags & {"done", "fault"}:
                raise DeviceError(
                    f"{self.port}: the run ended without the drive reporting it done ({status_word} = {st.word:#06x})"
                )
            if read_to == before:
                if time.monotonic() > deadline:
                    raise DeviceError(
                        f"{self.port}: the run did not end within {deadline - started:.1f} s "
                        f"({status_word} still shows running); stopped"
                    )
                time.sleep(_POLL_S)
        if self.run_fault is None:
            self._log_capture_end(available, n, stats)

    def _log_capture_end(self, available: int, n: int, stats: StreamStats) -> None:
        """The run's last event: the capture complete, or stopped at sample ``available`` (the rest counted lost)."""
        if available < n:
            stats.lost_samples += n - available
            self.log_event(
                RunEvent(
                    Kind.CAPTURE_STOPPED,
                    f"the drive's capture stopped at sample {available} of {n}; "
                    f"samples {available}..{n - 1} were not recorded "
                    "(not filled)",
                    available,
                    value=float(n - available),
                )
            )
        else:
            self.log_event(RunEvent(Kind.FINISHED, "run complete", n, value=0.0))

    def _describe_fault(self, st: DriveStatus) -> str:
        """A latched fault in words: name, register, sample and value."""
        name = self.map.fault_name(st.fault_code)
        where = self.map.describe(self.map.register("fault_code").address)
        if name == "comm_timeout":
            return (
                f"comm_timeout: the drive heard nothing from the host for {st.fault_value:.3g} s and stopped "
                f"on its own ({where} = {st.fault_code}, at sample {st.fault_sample})"
            )
        return f"{name} ({where} = {st.fault_code}, at sample {st.fault_sample}, value {st.fault_value:g})"

    def _note_status_fault(self, st: DriveStatus) -> None:
        """Log a fault the status shows as an event, at once, and note it as the run's cause."""
        name = self.map.fault_name(st.fault_code)
        message = self._describe_fault(st)
        if name != "comm_timeout":
            message = message.replace(" (", ": axis stopped, torque zero (", 1)
        kind = Kind.LIMIT_TRIP if name in _LIMIT_FAULTS else Kind.FAULT
        self.note_fault(self.log_event(RunEvent(kind, message, st.fault_sample, value=st.fault_value)))

    # --- filter slots (hooks of AdapterBase's filter-slot methods) ----------------------------------

    def _write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None, enabled: bool) -> None:
        self.slots.write_filter(slot, biquad, spec, enabled)

    def _read_filter(self, slot: int) -> tuple[Biquad, bool]:
        return self.slots.read_filter(slot)

    def _stored_form(self, biquad: Biquad, spec: NotchSpec | None) -> Biquad:
        return self.slots.stored_form(biquad, spec)

    def _read_raw_slot(self, slot: int) -> SavedSlot:
        return self.slots.read_raw(slot)

    def _write_raw_slot(self, slot: int, saved: SavedSlot) -> None:
        self.slots.write_raw(slot, saved)

    def _bypass_slot(self, slot: int) -> None:
        self.slots.bypass(slot)

    def _read_back_bypassed(
        self, slot: int, biquad: Biquad, spec: NotchSpec | None, expected: Biquad
    ) -> tuple[Biquad, bool]:
        """A slot bypassed by the "off" value of one of its fields applies no notch: its other fields are
        compared with what was written; any other slot as the template does."""
        if self.slots.bypassed_by_a_field:
            return self.slots.read_back_bypassed(slot, spec)
        return super()._read_back_bypassed(slot, biquad, spec, expected)

    @property
    def parameter_slots(self) -> bool:
        """Whether the filter slots are the drive's notch parameters (:meth:`filter_parameters` reports them)."""
        return self.slots.parameter_slots

    def filter_parameters(self, slot: int) -> dict:
        """What a parameter drive's slot holds, for a report (see :meth:`ModbusFilterSlots.filter_parameters
        <hilident.adapters.modbus.slots.ModbusFilterSlots.filter_parameters>`)."""
        return self.slots.filter_parameters(slot)

    def planned_parameters(self, slot: int, spec: NotchSpec) -> dict:
        """What a parameter drive's ``slot`` will hold for ``spec`` (what ``hilident upload --dry-run`` shows)."""
        return self.slots.planned_parameters(slot, spec)

    def filter_notes(self, spec: NotchSpec) -> tuple[str, ...]:
        """Why a parameter drive's notch parameters cannot meet ``spec`` exactly, if they cannot."""
        return self.slots.filter_notes(spec)

    # --- the drive's loop (hooks of AdapterBase's read_loop, write_loop, stored_loop) ----------------

    def _loop_description(self):
        return self.map.loop

    def _read_loop(self) -> dict[str, float] | None:
        return self.cascade.read()

    def _write_loop(self, values: dict[str, float]) -> None:
        self.cascade.write(values)

    def _stored_loop(self, values: dict[str, float]) -> dict[str, float]:
        return self.cascade.stored(values)
