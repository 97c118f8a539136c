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
``drivers/modbus-servo/README.md``); :mod:`hilident.protocol.modbus_registers`
encodes and decodes it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from hilident.adapters.base import AdapterBase, ConnectReport, FilterUpload, RunResult, StreamStats
from hilident.events import Kind, RunEvent
from hilident.config import DeviceConfig
from hilident.drivers import DriverDescription
from hilident.errors import ConfigError, DataError, DeviceError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol.modbus_registers import (
    STAMP_MODULUS, Chunk, FieldSlots, RegisterMap, Window, count_rtu_frames, exception_meaning, plan_chunks,
    table_crc,
)

logging.getLogger("pymodbus").addHandler(logging.NullHandler())  # no library chatter on stderr

_RETRIES = 3  # extra attempts of a request that is safe to repeat
_RETRY_LATER = (5, 6)  # acknowledge, busy: the drive asks to be asked again
_POLL_S = 0.01  # pause between status reads while the drive has nothing new
_CHUNKS_PER_POLL = 16  # capture chunks read between two status reads
_LIMIT_FAULTS = ("torque_limit", "velocity_limit", "position_limit")
_IDENTITY = ("device_type", "map_version", "loop_rate_hz", "max_sample_rate_hz", "filter_slots", "table_capacity",
             "capture_capacity", "device_name", "firmware")
_STATUS = ("status_word", "fault_code", "sample_count", "fault_sample", "fault_value")
_STOP_WAIT_S = 0.05  # longest wait for the answer to a safe stop (it is sent twice at most)
_ENABLED_WAIT = 0.4  # while enabled, wait at most this fraction of the communication timeout for an answer
_DRAIN_QUIET_S = 0.25  # RTU at connect: the line must stay quiet this long (at most timeout_s)
_DRAIN_MAX_S = 2.0  # ... but a line that never goes quiet is left after this long


class _StaleAnswer(ModbusIOException):
    """Only frames that answer another request came back (dropped and counted)."""


class _SerialClient(ModbusSerialClient):
    """pymodbus's RTU client, made safe for a line that may hold answers to earlier requests.

    pymodbus drops what is on the line before each request (counted here as
    ``stale_frames``) and skips frames from other device ids, but it takes
    any frame from the right device as the answer. An RTU frame carries no
    transaction id, so an answer that comes after its request timed out could
    pass for the answer to the next one. This client also checks the answer's
    function code and what it echoes (:func:`_answers`); a frame that does not
    answer the request is dropped and counted, and the client goes on waiting
    for the real answer (a second frame read together with the dropped one is
    lost with it: the request then times out and is asked again, never
    mistaken).
    """

    stale_frames = 0

    def send(self, request: bytes, addr=None) -> int:
        if request and self.socket is not None:
            try:
                if waiting := self.socket.in_waiting:
                    self.stale_frames += count_rtu_frames(self.socket.read(waiting))
            except (OSError, ValueError):
                pass  # pymodbus's own send reports a broken line
        return super().send(request, addr)

    def execute(self, no_response_expected: bool, request):
        response = super().execute(no_response_expected, request)
        while response is not None and not _answers(request, response):
            self.stale_frames += 1
            try:
                response = self.transaction.sync_get_response(request.dev_id, request.transaction_id)
            except asyncio.TimeoutError:
                raise _StaleAnswer("only answers to other requests came back") from None
        return response


def _answers(request, response) -> bool:
    """Whether ``response`` can be the answer to ``request`` (function code and echoed fields).

    An exception answer must carry the request's function code; a read must
    return the registers asked for; a write must echo its address (and value,
    or quantity).
    """
    function = request.function_code
    if response.function_code == function | 0x80:
        return True
    if response.function_code != function:
        return False
    if function in (3, 4):
        return len(response.registers) == request.count
    if function == 6:
        return response.address == request.address and list(response.registers) == list(request.registers)
    if function == 16:
        return response.address == request.address and response.count == len(request.registers)
    return True


class NoResponse(DeviceError):
    """A request went unanswered (after its retries, when it may be retried)."""


@dataclass(frozen=True)
class ModbusIdentity:
    """What the drive reports in its identity registers."""

    name: str
    firmware: str
    loop_rate_hz: float
    max_sample_rate_hz: float
    filter_slots: int
    table_capacity: int
    capture_capacity: int
    device_type: int
    map_version: int
    registers: dict = field(default_factory=dict)  # parameter drives: what the identity registers hold


@dataclass(frozen=True)
class DriveStatus:
    """One read of the status registers."""

    word: int
    flags: frozenset
    fault_code: int
    sample_count: int
    fault_sample: int
    fault_value: float


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
    """

    transport = "modbus"

    def __init__(self, client, driver: DriverDescription, regmap: RegisterMap, port: str, device_id: int = 1,
                 timeout_s: float = 2.0):
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
        self.missing_responses = 0  # requests never answered, since opening
        self.bad_responses = 0  # answers that were not the one asked for
        self.dropped_frames = 0  # late answers dropped from an RTU line after a lost or foreign answer
        self.connect_report = ConnectReport()
        self._run_counts = (0, 0)  # missing and bad answers when the run started
        self.comm_timeout_s = 0.0  # the drive's communication timeout as armed at connect (0: none), s
        self._mask = 0
        self._order: list[int] = []
        self._pages: dict[str, int | None] = {"table": None, "capture": None}

    # --- opening --------------------------------------------------------------------

    @classmethod
    def open_device(cls, device: DeviceConfig, driver: DriverDescription, link=None) -> "ModbusDriveAdapter":
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
            raise ConfigError("device.acquisition", "a Modbus drive runs drive-buffered experiments only "
                              '(use "buffered" or "auto")')
        regmap = RegisterMap.from_driver(driver)
        shown = regmap.capture_channel_names() if regmap.excitation else \
            [r.channel for r in regmap.registers.values() if r.channel]
        missing = [c.name for c in driver.channels if c.name not in shown]
        if missing:
            where = "[[modbus.capture.channels]]" if regmap.excitation else "registers (key channel) of [modbus.registers]"
            raise ConfigError("channels", f"driver {driver.name!r} lists channels {missing} that its "
                              f"{where} do not hold", str(driver.folder / "driver.toml"))
        port = device.port
        if port.startswith("tcp://"):
            host, _, number = port[len("tcp://"):].rpartition(":")
            if not host or not number.isdigit():
                raise ConfigError("device.port", f"{port!r} is not tcp://HOST:PORT")
            client = ModbusTcpClient(host, port=int(number), timeout=device.timeout_s, retries=0)
            if not client.connect():
                raise DeviceError(f"{port}: cannot connect to {host}:{number} (is the drive on and the port right?)")
        else:
            baudrate = device.baudrate or driver.default_baudrate
            client = _SerialClient(port, baudrate=baudrate, parity=device.parity, stopbits=device.stopbits,
                                   timeout=device.timeout_s, retries=0)
            if not client.connect():
                raise DeviceError(f"{port}: cannot open at {baudrate} baud, parity {device.parity}, "
                                  f"{device.stopbits} stop bit(s): {_serial_error(port, baudrate, device)}")
        adapter = cls(client, driver, regmap, port, device.device_id, device.timeout_s)
        adapter._drain_line()
        adapter = cls._identified(adapter)
        return cls._or_closed(adapter, lambda: adapter._bring_to_known_state(device.allow_fault_reset,
                                                                             device.host_timeout_s))

    def _drain_line(self) -> None:
        """RTU: drop the answers still on their way to an earlier host, until the line is quiet (counted)."""
        sock = self.client.socket if self.rtu else None
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
                self.write_names(**self.map.stop)  # no speed, no torque asked of the drive
            self._arm_comm_timeout(host_timeout_s)
            report.discarded_frames += getattr(self.client, "stale_frames", 0) + self.dropped_frames + self.bad_responses
            return
        self.write_names(control_word=0)  # stopped, disabled, zero torque, ready for a fresh 0 -> 1 edge
        st = self.status()
        if "fault" in st.flags:
            def clear() -> None:
                self.clear_fault()
                after = self.status()
                if "fault" in after.flags:
                    raise DeviceError(f"{self.port}: {self.map.describe(self.map.register('fault_code').address)} "
                                      f"still holds {self.map.fault_name(after.fault_code)} after a fault reset; the "
                                      "cause is still there (check the drive's display)")

            self._clear_latched_fault(self._describe_fault(st), allow_fault_reset, clear)
        self._arm_comm_timeout(host_timeout_s)
        client_stale = getattr(self.client, "stale_frames", 0)
        report.discarded_frames += client_stale + self.dropped_frames + self.bad_responses

    def _arm_comm_timeout(self, host_timeout_s: float) -> None:
        """Write ``comm_timeout_ms`` from ``host_timeout_s`` and read it back (when the map names it)."""
        if "comm_timeout_ms" not in self.map.registers:
            self.connect_report.device_net = ""
            return
        r = self.map.register("comm_timeout_ms")
        ms = max(1, math.ceil(host_timeout_s * 1000.0 - 1e-9))
        try:
            self.write_names(comm_timeout_ms=ms)
        except DataError as exc:
            raise ConfigError("device.host_timeout_s", f"{host_timeout_s:g} s does not fit "
                              f"{self.map.describe(r.address)}: {exc}") from None
        back = float(self.read_names("comm_timeout_ms")["comm_timeout_ms"])
        if not back or abs(back - ms) > max(r.scale, 1.0):
            raise DeviceError(f"{self.port}: {self.map.describe(r.address)} reads {back:g} ms after "
                              f"{ms} ms was written: the drive's communication timeout is not armed")
        self.comm_timeout_s = back / 1000.0
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

    # --- requests -------------------------------------------------------------------------

    def _request(self, what: str, address: int, count: int, call: Callable, check: Callable,
                 retry: bool, page: int | None = None, tries: int | None = None):
        """Run one request; retried after a lost answer only when ``retry`` (safe to repeat).

        ``tries`` overrides the number of attempts. A lost connection is a
        :class:`DeviceError` at once: whatever the drive did since, it was not
        this session's request. An exception answer is a :class:`DeviceError`
        that names the registers and says what the code means for them.
        """
        where = self.map.describe(address, count, page)
        attempts = tries or 1 + (_RETRIES if retry else 0)
        for attempt in range(attempts):
            try:
                response = call()
            except (ConnectionException, OSError) as exc:
                self.missing_responses += 1
                with contextlib.suppress(Exception):
                    self.client.close()  # a fresh connection next time, never half of this one
                raise DeviceError(f"{self.port}: {what} {where}: the connection to the drive was lost "
                                  f"({_reason(exc)}); was it switched off, or its cable or gateway "
                                  "disconnected?") from None
            except _StaleAnswer:
                self.bad_responses += 1
                self._resync()
                error = "only answers to earlier requests came back"
                continue
            except ModbusException:
                self.missing_responses += 1
                self._resync()
                error = f"no answer within {self.client.comm_params.timeout_connect:g} s"
                continue
            except ValueError as exc:  # pymodbus refused to build the request
                raise DeviceError(f"{self.port}: {what} {where}: {exc}") from None
            if response.isError():
                code = int(getattr(response, "exception_code", 0))
                if retry and code in _RETRY_LATER and attempt + 1 < attempts:
                    time.sleep(0.05)
                    error = f"exception {code}"
                    continue
                function = int(getattr(response, "function_code", 0x80)) & 0x7F
                raise DeviceError(f"{self.port}: {what} {where}: "
                                  f"{_exception_text(code, function, self.device_id)}")
            if not check(response):
                self.bad_responses += 1
                self._resync()
                error = "the answer did not match the request"
                continue
            return response
        tries = f" ({attempts} attempts)" if attempts > 1 else ""
        raise NoResponse(f"{self.port}: {what} {where}: {error}{tries}; device id {self.device_id}")

    def _resync(self) -> None:
        """After a lost or foreign answer on an RTU line, wait for a late answer and drop it (counted).

        An RTU answer carries no transaction id: one that comes after its
        request timed out would pass for the next request's answer. So the
        line is watched for up to one answer timeout (as libmodbus does after
        a timeout), and left as soon as a whole frame has come and the line
        has been quiet for a few characters since.
        """
        if not self.rtu or self.client.socket is None:
            return
        sock = self.client.socket
        params = self.client.comm_params
        quiet = max(0.002, 4 * 11 / (params.baudrate or 9600))
        deadline = time.monotonic() + params.timeout_connect
        data, last = b"", time.monotonic()
        try:
            while time.monotonic() < deadline:
                if waiting := sock.in_waiting:
                    data += sock.read(waiting)
                    last = time.monotonic()
                elif data and count_rtu_frames(data) and time.monotonic() - last >= quiet:
                    break
                else:
                    time.sleep(min(quiet, 0.005))
        except Exception:
            pass  # the next request reports a broken line
        if data:
            self.dropped_frames += count_rtu_frames(data)

    @contextlib.contextmanager
    def _answers_within(self, seconds: float):
        """Wait at most ``seconds`` (never more than ``timeout_s``) for each answer inside the block."""
        params = self.client.comm_params
        before = params.timeout_connect
        params.timeout_connect = min(before, seconds)
        try:
            yield
        finally:
            params.timeout_connect = before

    @property
    def _enabled_wait_s(self) -> float:
        """Longest wait for one answer while the drive is enabled: lost answers are asked again in time."""
        return _ENABLED_WAIT * self.comm_timeout_s if self.comm_timeout_s else self.timeout_s

    def read(self, address: int, count: int, what: str = "reading", retry: bool = True,
             page: int | None = None, input_registers: bool = False) -> list[int]:
        """Registers ``address .. address + count - 1`` (read holding registers, or input registers)."""
        reader = self.client.read_input_registers if input_registers else self.client.read_holding_registers
        response = self._request(
            what, address, count,
            lambda: reader(address, count=count, device_id=self.device_id),
            lambda r: len(r.registers) == count, retry, page,
        )
        return list(response.registers)

    def write(self, address: int, values, what: str = "writing", page: int | None = None) -> None:
        """Write registers from ``address`` (write multiple registers); repeated after a lost answer."""
        values = [int(v) for v in values]
        self._request(
            what, address, len(values),
            lambda: self.client.write_registers(address, values, device_id=self.device_id),
            lambda r: r.address == address and r.count == len(values), True, page,
        )

    def read_names(self, *names: str) -> dict:
        """Values of the named registers (neighbours share a request)."""
        out = {}
        for table, address, count in self.map.request_groups(names):
            regs = self.read(address, count, input_registers=table == "input")
            out.update(self.map.decode_span([n for n in names if self.map.register(n).table == table and
                                             address <= self.map.register(n).address < address + count],
                                            address, regs))
        return out

    def write_names(self, **values) -> None:
        """Write named registers; neighbours share one request."""
        regs = {}
        for name, value in values.items():
            r = self.map.register(name)
            if not r.writable:
                raise DeviceError(f"{self.port}: {self.map.describe(r.address, r.count, table=r.table)} is read-only "
                                  f"in driver {self.driver.name!r}")
            try:
                words = self.map.encode(name, value)
            except DataError as exc:
                raise DeviceError(f"{self.port}: not written: {exc}") from None
            for i, v in enumerate(words):
                regs[r.address + i] = v
        addresses = sorted(regs)
        start = addresses[0]
        for a, b in zip(addresses, addresses[1:] + [None]):
            if b != a + 1 or b - start >= self.map.max_write:
                self.write(start, [regs[x] for x in range(start, a + 1)])
                start = b

    # --- device operations ------------------------------------------------------------------

    def identify(self) -> ModbusIdentity:
        """Read the identity registers and check the drive is the one the driver describes."""
        if not self.map.excitation:
            return self._identify_parameters()
        v = self.read_names(*_IDENTITY)
        m, d = self.map, self.driver

        def mismatch(name, got, want, hint=""):
            raise DeviceError(f"{self.port}: {m.describe(m.register(name).address)} holds {got}; driver "
                              f"{d.name!r} expects {want}{hint}")

        if v["device_type"] != m.device_type:
            mismatch("device_type", f"{v['device_type']:#06x}", f"{m.device_type:#06x}",
                     f" (is device id {self.device_id} the drive?)")
        if v["map_version"] != m.map_version:
            mismatch("map_version", v["map_version"], m.map_version)
        if abs(v["loop_rate_hz"] - d.loop_rate_hz) > 1e-6 * d.loop_rate_hz:
            mismatch("loop_rate_hz", f"{v['loop_rate_hz']:g} Hz", f"{d.loop_rate_hz:g} Hz")
        if v["filter_slots"] != d.filter_slots:
            mismatch("filter_slots", v["filter_slots"], d.filter_slots)
        self.identity = ModbusIdentity(
            name=v["device_name"] or d.name, firmware=v["firmware"], loop_rate_hz=float(v["loop_rate_hz"]),
            max_sample_rate_hz=float(v["max_sample_rate_hz"]), filter_slots=int(v["filter_slots"]),
            table_capacity=int(v["table_capacity"]), capture_capacity=int(v["capture_capacity"]),
            device_type=int(v["device_type"]), map_version=int(v["map_version"]),
        )
        return self.identity

    def _identify_parameters(self) -> ModbusIdentity:
        """A parameter drive: the registers ``[modbus.identity]`` names, checked against ``expect``."""
        m, d = self.map, self.driver
        v = self.read_names(*m.identity)
        for name, want in m.expect.items():
            if v[name] != want:
                r = m.register(name)
                raise DeviceError(f"{self.port}: {m.describe(r.address, r.count, table=r.table)} holds {v[name]}; "
                                  f"driver {d.name!r} expects {want} (is device id {self.device_id} the drive?)")
        slots = m.filters.slots if m.filters is not None else 0
        firmware = ", ".join(f"{n} {v[n]}" for n in m.identity)
        self.identity = ModbusIdentity(
            name=d.name, firmware=firmware, loop_rate_hz=float(d.loop_rate_hz),
            max_sample_rate_hz=float(d.max_sample_rate_hz), filter_slots=slots, table_capacity=0,
            capture_capacity=0, device_type=int(m.device_type), map_version=int(m.map_version), registers=dict(v))
        return self.identity

    # --- a parameter drive ---------------------------------------------------------------------

    @classmethod
    def run_refusal(cls, driver: DriverDescription) -> ConfigError | None:
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
            str(driver.folder / "driver.toml"))

    def _refuse_run(self) -> None:
        refusal = self.run_refusal(self.driver)
        if refusal is not None:
            raise refusal

    def _prepare_run(self, x: np.ndarray) -> None:
        self._refuse_run()

    def read_parameter(self, code: str) -> float | int:
        """The physical value of vendor parameter ``code`` (``"P08.02"``), through the map's rule."""
        try:
            r = self.map.parameter(code)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {exc}") from None
        return r.decode(self.read(r.address, r.count, f"reading parameter {code}", input_registers=r.table == "input"))

    def write_parameter(self, code: str, value) -> None:
        """Write vendor parameter ``code``; refused before sending when it is read-only or out of its range."""
        try:
            r = self.map.parameter(code)
            words = r.encode(value)
        except DataError as exc:
            raise DeviceError(f"{self.port}: parameter {code} not written: {exc}") from None
        if not r.writable:
            raise DeviceError(f"{self.port}: parameter {code} ({self.map.describe(r.address, table=r.table)}) is "
                              "read-only")
        self.write(r.address, words, f"writing parameter {code}")

    def read_feedback(self) -> dict[str, float]:
        """Channels the drive shows in registers (``channel`` in the map), in SI units."""
        shown = {r.name: r for r in self.map.registers.values() if r.channel}
        values = self.read_names(*shown) if shown else {}
        return {r.channel: float(values[n]) * r.channel_scale for n, r in shown.items()}

    def save_parameters(self) -> str:
        """Store the drive's parameters in non-volatile memory (``[modbus.save]``); returns what was written.

        Raises
        ------
        DeviceError
            The map describes no save parameter, or the drive refuses it.
        """
        if self.map.save is None:
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no save parameter "
                              "([modbus.save] in its driver.toml)")
        name, value = self.map.save
        r = self.map.register(name)
        self.write(r.address, self.map.encode(name, value), "saving the parameters to non-volatile memory")
        return f"{self.map.describe(r.address, r.count)} = {value:g}"

    def status(self) -> DriveStatus:
        """The status registers, in one request."""
        v = self.read_names(*_STATUS)
        word = int(v["status_word"])
        return DriveStatus(word, self.map.status_flags(word), int(v["fault_code"]), int(v["sample_count"]),
                           int(v["fault_sample"]), float(v["fault_value"]))

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the limits the drive enforces on its own (crossing one stops the axis).

        A parameter drive's map holds no limit registers and hilident moves
        nothing on it (no experiment can run): there is nothing to load.
        """
        if not self.map.excitation:
            return
        self.write_names(torque_limit_nm=torque_nm, velocity_limit_mps=velocity_mps,
                         position_min_m=position_min_m, position_max_m=position_max_m)
        if "limits_loaded" not in self.status().flags:
            raise DeviceError(f"{self.port}: the drive does not report its limits loaded "
                              f"({self.map.describe(self.map.register('status_word').address)})")

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Choose the capture rate, excitation mode and captured channels; returns the channel names."""
        self._refuse_run()
        ident = self.identity
        divider = ident.loop_rate_hz / sample_rate_hz
        if abs(divider - round(divider)) > 1e-9 or round(divider) < 1:
            raise DeviceError(f"{self.port}: sample rate {sample_rate_hz:g} Hz does not divide the drive's loop "
                              f"rate {ident.loop_rate_hz:g} Hz")
        if sample_rate_hz > ident.max_sample_rate_hz * (1 + 1e-9):
            raise DeviceError(f"{self.port}: sample rate {sample_rate_hz:g} Hz exceeds the drive's "
                              f"{ident.max_sample_rate_hz:g} Hz")
        if mode not in self.map.modes:
            raise ConfigError("excitation.mode", f"the drive offers modes {sorted(self.map.modes)}, got {mode!r}")
        names = list(channels) if channels else [c.name for c in self.driver.streamed_channels]
        mask = self.map.mask_of(names)
        self.write_names(mode=self.map.modes[mode], sample_divider=int(round(divider)), capture_mask=mask)
        record = [c.name for c in self.map.selected(mask)]
        self._mask = mask
        self._order = [record.index(n) for n in names]
        units = {c.name: c.unit for c in self.driver.channels}
        self.channel_names = names
        self.channel_units = [units.get(n, "") for n in names]
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
            with self._answers_within(wait_s):
                self._request("stopping the drive", r.address, 1,
                              lambda: self.client.write_registers(r.address, [0], device_id=self.device_id),
                              lambda resp: resp.address == r.address, retry=True, tries=tries)
        except Exception:
            pass  # the drive's communication timeout stops it when the host cannot

    def _stop_parameters(self, wait_s: float) -> None:
        """A parameter drive: write ``[modbus.stop]`` (no speed, no torque), if the map gives it. Never raises."""
        if not self.map.stop:
            return
        try:
            with self._answers_within(wait_s):
                self.write_names(**self.map.stop)
        except Exception:
            pass

    def clear_fault(self) -> None:
        """Clear a latched fault (0 -> 1 edge of the fault_reset bit)."""
        self.write_names(control_word=0)
        self.write_names(control_word=self.map.control["fault_reset"])
        self.write_names(control_word=0)

    # --- filters ------------------------------------------------------------------------------

    def _slot(self, slot: int) -> int:
        try:
            return self.map.filters.address(slot)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {exc}") from None

    # Filter slots of named registers (a parameter drive's notch parameters): each field is one register
    # holding the encoding's stored integer; the slot is bypassed by its enable register or by the "off"
    # value of one field.

    @property
    def parameter_slots(self) -> bool:
        """Whether the filter slots are the drive's notch parameters (:meth:`filter_parameters` reports them)."""
        return isinstance(self.map.filters, FieldSlots)

    def _fields(self, slot: int) -> dict:
        if self.map.filters is None:
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no filter slots")
        try:
            return self.map.filters.fields(slot)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {exc}") from None

    def _read_fields(self, slot: int) -> dict[str, int]:
        """The stored integer of each field of ``slot`` (one request for neighbouring registers)."""
        regs = self._fields(slot)
        values = self.read_names(*(r.name for r in regs.values()))
        return {f: int(round((values[r.name] - r.offset) / r.scale)) for f, r in regs.items()}

    def _write_fields(self, slot: int, stored: dict[str, int]) -> None:
        regs = self._fields(slot)
        self.write_names(**{regs[f].name: v * regs[f].scale + regs[f].offset for f, v in stored.items()})

    def _slot_state(self, stored: dict[str, int]) -> tuple[dict, bool]:
        """``(encoding values, enabled)`` of a named slot's stored integers."""
        values = {k: v for k, v in stored.items() if k != "enable"}
        if "enable" in stored:
            return values, bool(stored["enable"])
        return values, not all(values.get(k) == v for k, v in self.map.filters.off.items())

    def _realise(self, spec: NotchSpec | None):
        if spec is None:
            raise DeviceError(f"{self.port}: the drive takes notch parameters; no notch specification was given")
        try:
            return self.map.filter_encoding.realise(spec, self.identity.loop_rate_hz)
        except DataError as exc:
            raise DeviceError(f"{self.port}: the drive's {self.map.filter_encoding.kind} filter parameters cannot "
                              f"hold the {spec.center_hz:.4g} Hz notch: {exc}") from None

    def filter_parameters(self, slot: int) -> dict:
        """What a parameter drive's slot holds, for a report: each field's register, parameter code and stored
        integer, whether it is enabled, and the notch (centre, width, depth) the values stand for."""
        regs = self._fields(slot)
        stored = self._read_fields(slot)
        values, enabled = self._slot_state(stored)
        out = {"slot": slot, "enabled": enabled,
               "fields": {f: {"register": regs[f].name, "parameter": regs[f].parameter, "address": regs[f].address,
                              "value": v} for f, v in stored.items()}}
        if enabled:
            try:
                spec = self.map.filter_encoding.parameters(values)
                out["notch"] = {"center_hz": spec.center_hz, "width_hz": spec.width_hz, "depth_db": spec.depth_db}
            except DataError as exc:
                out["notch_error"] = str(exc)
        return out

    def filter_notes(self, spec: NotchSpec) -> tuple[str, ...]:
        """Why a parameter drive's notch parameters cannot meet ``spec`` exactly, if they cannot."""
        return self._realise(spec).notes if self.parameter_slots else ()

    def upload_filter(self, slot: int, biquad, spec=None) -> FilterUpload:
        """As :meth:`AdapterBase.upload_filter`; a slot bypassed by the "off" value of one of its fields is
        written bypassed with the other fields, those read back and compared, then the off field written
        (the notch takes effect), the whole slot read back and compared; anything else puts the previous
        contents back."""
        fs = self.map.filters
        if not self.parameter_slots or fs.has_enable:
            return super().upload_filter(slot, biquad, spec)
        previous = self.save_filter(slot)
        values = self._realise(spec).fields
        expected = self.stored_form(biquad, spec)
        self._write_fields(slot, {**values, **fs.off})
        back, enabled = self._slot_state(self._read_fields(slot))
        same = not enabled and all(back[k] == v for k, v in values.items() if k not in fs.off)
        stored = Biquad.identity()
        if same:
            self._write_fields(slot, values)
            stored, enabled = self.read_filter(slot)
            same = enabled and stored == expected
        if not same:
            self.restore_filter(slot, previous)
        return FilterUpload(stored, expected, bool(same))

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None, *, enabled: bool) -> None:
        """Store a notch in a slot as the drive takes it: centre, width, depth (scaled integers), enable.

        A parameter drive's slot gets the stored values closest to ``spec``
        (:meth:`FilterEncoding.realise`), bypassed by its off value when not ``enabled``.
        """
        if self.parameter_slots:
            stored = dict(self._realise(spec).fields)
            if self.map.filters.has_enable:
                stored["enable"] = int(bool(enabled))
            elif not enabled:
                stored.update(self.map.filters.off)
            self._write_fields(slot, stored)
            return
        values = self.map.filter_encoding.encode(biquad, spec)
        self.write(self._slot(slot), self.map.encode_filter(values, enabled), f"writing filter slot {slot}")

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad the slot's registers make the drive run, and whether it is enabled.

        A parameter drive's slot bypassed by an off value runs the identity section.
        """
        if self.parameter_slots:
            values, enabled = self._slot_state(self._read_fields(slot))
            if not enabled and not self.map.filters.has_enable:
                return Biquad.identity(), False
            try:
                return self.map.filter_encoding.applied(values, self.identity.loop_rate_hz), enabled
            except DataError as exc:
                regs = self._fields(slot)
                raise DeviceError(f"{self.port}: filter slot {slot} ({', '.join(r.label for r in regs.values())}) "
                                  f"holds {values}: {exc}") from None
        address = self._slot(slot)
        values, enabled = self.map.decode_filter(self.read(address, self.map.filters.span, f"reading filter slot {slot}"))
        if not any(values.values()):
            return Biquad.identity(), enabled  # an empty slot passes the torque through
        try:
            return self.map.filter_encoding.applied(values, self.identity.loop_rate_hz), enabled
        except DataError as exc:
            raise DeviceError(f"{self.port}: filter slot {slot} "
                              f"({self.map.describe(address, self.map.filters.span)}) holds {values}: {exc}") from None

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None = None) -> Biquad:
        """The biquad the drive runs after its own rounding of ``spec`` (0.1 Hz, 0.1 dB steps), or what a
        parameter drive runs with the stored values closest to ``spec``."""
        if self.parameter_slots:
            return self._realise(spec).section
        return self.map.filter_encoding.stored_form(biquad, spec, self.identity.loop_rate_hz)

    def _read_raw_slot(self, slot: int) -> tuple[int, ...]:
        """The slot's registers as they are."""
        if self.parameter_slots:
            return tuple(sorted(self._read_fields(slot).items()))
        return tuple(self.read(self._slot(slot), self.map.filters.span, f"reading filter slot {slot}"))

    def _write_raw_slot(self, slot: int, saved: tuple) -> None:
        if self.parameter_slots:
            self._write_fields(slot, dict(saved))
            return
        self.write(self._slot(slot), list(saved), f"restoring filter slot {slot}")

    def disable_filter(self, slot: int) -> None:
        """Bypass a slot: its enable register to 0, centre, width and depth kept (:meth:`restore_filter` undoes it).

        A parameter drive's slot without an enable gets its off value, the other fields kept.
        """
        if self.parameter_slots:
            fs = self.map.filters
            self._write_fields(slot, {"enable": 0} if fs.has_enable else dict(fs.off))
            return
        self.write(self._slot(slot) + self.map.filters.offsets["enable"], [0], f"disabling filter slot {slot}")

    # --- buffered runs ------------------------------------------------------------------------

    def _select_page(self, window: Window, page: int) -> None:
        if self._pages[window.name] != page:
            self._pages[window.name] = None  # unknown until the drive confirms
            self.write_names(**{window.page_register: page})
            self._pages[window.name] = page

    def _upload(self, registers: np.ndarray, n: int) -> None:
        rps = self.map.table_registers_per_sample
        w = self.map.table
        for c in plan_chunks(0, n, rps, w.page_samples, self.map.max_write):
            self._select_page(w, c.page)
            try:
                self.write(w.base + c.offset, registers[c.first_sample * rps : (c.first_sample + c.samples) * rps],
                           f"writing excitation samples {c.first_sample}..{c.first_sample + c.samples - 1}", c.page)
            except DeviceError:
                self._pages["table"] = None
                raise

    def _read_chunk(self, c: Chunk, stats: StreamStats, sink) -> None:
        """Read one chunk of capture records; deliver it, or count it lost."""
        w = self.map.capture
        expected = (c.first_sample + np.arange(c.samples)) % STAMP_MODULUS
        for _ in range(1 + _RETRIES):
            try:
                self._select_page(w, c.page)
                regs = self.read(w.base + c.offset, c.count,
                                 f"reading capture samples {c.first_sample}..{c.first_sample + c.samples - 1}",
                                 retry=False, page=c.page)
            except NoResponse:
                self._pages["capture"] = None
                continue
            stamps, rows = self.map.decode_records(regs, self._mask)
            if np.array_equal(stamps, expected):
                sink(c.first_sample + np.arange(c.samples, dtype=np.int64), rows[:, self._order])
                stats.samples += c.samples
                return
            # not the records asked for: a repeated or misplaced chunk, or damaged data; read it again
            if np.all((np.diff(stamps) % STAMP_MODULUS) == 1):
                stats.out_of_order += 1
            else:
                stats.corrupt_frames += 1
            self._pages["capture"] = None
        stats.lost_blocks += 1
        stats.lost_samples += c.samples
        self.log_event(RunEvent(Kind.LOST_BLOCKS, f"capture samples {c.first_sample}..{c.first_sample + c.samples - 1} "
                                                  f"could not be read ({1 + _RETRIES} attempts); not filled",
                                c.first_sample, value=1.0))

    def _trigger(self) -> None:
        """Start the run: one write of the run bit, never repeated."""
        r = self.map.register("control_word")
        run = self.map.control["run"]
        try:
            self._request("starting the run", r.address, 1,
                          lambda: self.client.write_register(r.address, run, device_id=self.device_id),
                          lambda resp: resp.address == r.address, retry=False)
        except NoResponse as exc:
            # the command may have arrived: ask the drive instead of sending it again
            after = self.status()
            if not after.flags & {"running", "done"}:
                raise DeviceError(f"{exc}; the drive is not running (not repeated: a start is never sent twice)") from None
            self.log_event(RunEvent(Kind.MISSING_RESPONSE, "the answer to the start command was lost; the drive "
                                                           "reports the run started", 0, value=0.0))

    def load_table(self, excitation: np.ndarray) -> np.ndarray:
        """Stop the drive, arm a run of ``len(excitation)`` samples and write the table; returns its registers.

        The drive's CRC of the table is compared with the CRC of what was sent.

        Raises
        ------
        DeviceError
            The excitation exceeds the table or capture, a fault is latched, a
            request was refused or went unanswered, or the CRC differs.
        DataError
            The excitation is empty or a value does not fit the table's type.
        """
        x = np.asarray(excitation, dtype=float)
        n = len(x)
        if n < 1:
            raise DataError("the excitation is empty")
        ident = self.identity
        for cap, name in ((ident.table_capacity, "table_capacity"), (ident.capture_capacity, "capture_capacity")):
            if n > cap:
                raise DeviceError(f"{self.port}: {n} samples exceed the drive's {cap} "
                                  f"({self.map.describe(self.map.register(name).address)}); shorten the excitation "
                                  "or lower run.sample_rate_hz")
        table = self.map.encode_table(x)
        self.write_names(control_word=0)  # stopped, and ready for a fresh 0 -> 1 edge
        before = self.status()
        if "fault" in before.flags:
            raise DeviceError(
                f"{self.port}: the drive reports {self.map.fault_name(before.fault_code)} in "
                f"{self.map.describe(self.map.register('fault_code').address)}; clear the fault before a run")
        self.write_names(table_length=n)
        self._upload(table, n)
        crc = self.read_names("table_crc")["table_crc"]
        if crc != table_crc(table):
            raise DeviceError(f"{self.port}: {self.map.describe(self.map.register('table_crc').address)} is "
                              f"{crc:#06x}, the table sent has {table_crc(table):#06x}: the excitation table did "
                              "not arrive intact")
        return table

    def read_capture(self, first: int, count: int, sink, stats: StreamStats, max_chunks: int | None = None) -> int:
        """Read capture records ``first .. first + count - 1`` (or the first ``max_chunks`` requests of them).

        Each chunk is delivered to ``sink(sample_index, rows)`` or counted lost
        in ``stats``. Returns the index after the last record read.
        """
        width = self.map.record_registers(self._mask)
        chunks = plan_chunks(first, count, width, self.map.capture.page_samples, self.map.max_read)
        end = first
        for c in chunks[:max_chunks]:
            self._read_chunk(c, stats, sink)
            end = c.first_sample + c.samples
        return end

    def _play(self, x: np.ndarray, deliver, result: RunResult) -> None:
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
        self._run_counts = (self.missing_responses, self.bad_responses)
        self.load_table(x)
        with self._answers_within(self._enabled_wait_s):
            self._trigger()
            self._capture(len(x), result.stats, deliver)
        result.completed = self.run_fault is None

    def _end_run(self, result: RunResult) -> None:
        """The drive stopped and disabled; the run's unanswered and bad answers counted."""
        self.safe_stop()
        missing_before, bad_before = self._run_counts
        result.stats.lost_frames = self.missing_responses - missing_before
        result.stats.corrupt_frames += self.bad_responses - bad_before

    def _capture(self, n: int, stats: StreamStats, deliver) -> None:
        """Poll the status and read the capture as it fills, until the run has ended and all is read."""
        started = time.monotonic()
        deadline = started + 1.2 * n / self.sample_rate_hz + 2.0 + 2 * self.timeout_s
        read_to = 0
        while True:
            st = self.status()
            if "fault" in st.flags and self.run_fault is None:
                self._note_fault(st)  # known now: the first cause, whatever fails after it
            available = min(st.sample_count, n)
            before = read_to
            read_to = self.read_capture(read_to, available - read_to, deliver, stats, _CHUNKS_PER_POLL)
            ended = "running" not in st.flags
            if ended and read_to >= available:
                break
            if ended and not st.flags & {"done", "fault"}:
                raise DeviceError(f"{self.port}: the run ended without the drive reporting it done "
                                  f"({self.map.describe(self.map.register('status_word').address)} = {st.word:#06x})")
            if read_to == before:
                if time.monotonic() > deadline:
                    raise DeviceError(f"{self.port}: the run did not end within {deadline - started:.1f} s "
                                      f"({self.map.describe(self.map.register('status_word').address)} still shows "
                                      "running); stopped")
                time.sleep(_POLL_S)
        if self.run_fault is not None:
            return
        if available < n:
            stats.lost_samples += n - available
            self.log_event(RunEvent(Kind.CAPTURE_STOPPED, f"the drive's capture stopped at sample {available} of {n}; "
                                                          f"samples {available}..{n - 1} were not recorded (not filled)",
                                    available, value=float(n - available)))
        else:
            self.log_event(RunEvent(Kind.FINISHED, "run complete", n, value=0.0))

    def _describe_fault(self, st: DriveStatus) -> str:
        """A latched fault in words: name, register, sample and value."""
        name = self.map.fault_name(st.fault_code)
        where = self.map.describe(self.map.register("fault_code").address)
        if name == "comm_timeout":
            return (f"comm_timeout: the drive heard nothing from the host for {st.fault_value:.3g} s and stopped "
                    f"on its own ({where} = {st.fault_code}, at sample {st.fault_sample})")
        return f"{name} ({where} = {st.fault_code}, at sample {st.fault_sample}, value {st.fault_value:g})"

    def _note_fault(self, st: DriveStatus) -> None:
        """Log a fault the status shows as an event, at once, and note it as the run's cause."""
        name = self.map.fault_name(st.fault_code)
        message = self._describe_fault(st)
        if name != "comm_timeout":
            message = message.replace(" (", ": axis stopped, torque zero (", 1)
        kind = Kind.LIMIT_TRIP if name in _LIMIT_FAULTS else Kind.FAULT
        self.note_fault(self.log_event(RunEvent(kind, message, st.fault_sample, value=st.fault_value)))


def _reason(exc: BaseException) -> str:
    """Why a connection failed, in a few words (pymodbus's messages repeat the client's repr)."""
    text = str(exc)
    if isinstance(exc, ConnectionResetError):
        return "connection reset by the drive"
    if isinstance(exc, BrokenPipeError) or "unexpectedly closed" in text:
        return "the drive closed the connection"
    if "cannot connect" in text.lower():
        return "it does not accept a connection"
    return text or type(exc).__name__


def _exception_text(code: int, function: int, device_id: int) -> str:
    """A Modbus exception answer in words: the code, its meaning, and what it says about this request."""
    head = f"Modbus exception {code} ({exception_meaning(code)})"
    why = {
        1: f"the drive does not support function {function}; its map does not declare it",
        2: "the address range is not in the drive's map, or not writable there",
        3: "the drive refused the value or the quantity of registers",
        4: "the drive failed while carrying out the request",
        5: "the drive accepted the request and is still working on it",
        6: "the drive is busy with an earlier request; try again later",
        10: f"the gateway has no path to device id {device_id} (check [device].device_id)",
        11: f"no device with id {device_id} answered behind the gateway (check [device].device_id and "
            "the line behind the gateway)",
    }.get(code)
    return f"{head}: {why}" if why else head


def _serial_error(port: str, baudrate: int, device: DeviceConfig) -> str:
    """Why pyserial cannot open ``port`` (pymodbus only says that it could not)."""
    try:
        serial.serial_for_url(port, baudrate=baudrate, parity=device.parity, stopbits=device.stopbits,
                              timeout=0).close()
    except Exception as exc:
        return str(exc) or type(exc).__name__
    return "the port opened on a second try; check it is not in use"
