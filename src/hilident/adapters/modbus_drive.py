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

The register map is the driver's (see ``drivers/modbus-servo/README.md``);
:mod:`hilident.protocol.modbus_registers` encodes and decodes it.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException

from hilident.adapters.base import AdapterBase, RunResult, StreamStats
from hilident.config import DeviceConfig
from hilident.drivers import DriverDescription
from hilident.errors import ConfigError, DataError, DeviceError, LimitTrip
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol.modbus_registers import (
    STAMP_MODULUS, Chunk, RegisterMap, Window, exception_meaning, plan_chunks, table_crc,
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
        self._mask = 0
        self._order: list[int] = []
        self._pages: dict[str, int | None] = {"table": None, "capture": None}

    # --- opening --------------------------------------------------------------------

    @classmethod
    def open_device(cls, device: DeviceConfig, driver: DriverDescription, link=None) -> "ModbusDriveAdapter":
        """Connect as ``[device]`` says (``tcp://HOST:PORT`` or a serial port) and identify the drive."""
        if device.acquisition == "streamed":
            raise ConfigError("device.acquisition", "a Modbus drive runs drive-buffered experiments only "
                              '(use "buffered" or "auto")')
        regmap = RegisterMap.from_driver(driver)
        missing = [c.name for c in driver.channels if c.name not in regmap.capture_channel_names()]
        if missing:
            raise ConfigError("channels", f"driver {driver.name!r} lists channels {missing} that its "
                              "[[modbus.capture.channels]] do not hold", str(driver.folder / "driver.toml"))
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
            client = ModbusSerialClient(port, baudrate=baudrate, parity=device.parity, stopbits=device.stopbits,
                                        timeout=device.timeout_s, retries=0)
            if not client.connect():
                raise DeviceError(f"{port}: cannot open at {baudrate} baud, parity {device.parity}, "
                                  f"{device.stopbits} stop bit(s): {_serial_error(port, baudrate, device)}")
        return cls._identified(cls(client, driver, regmap, port, device.device_id, device.timeout_s))

    def close(self) -> None:
        """Stop the axis (zero torque, drive disabled) and release the connection. Never raises."""
        try:
            self.stop()
        finally:
            try:
                self.client.close()
            except Exception:
                pass

    # --- requests -------------------------------------------------------------------------

    def _request(self, what: str, address: int, count: int, call: Callable, check: Callable,
                 retry: bool, page: int | None = None):
        """Run one request; retried after a lost answer only when ``retry`` (safe to repeat)."""
        where = self.map.describe(address, count, page)
        attempts = 1 + (_RETRIES if retry else 0)
        for attempt in range(attempts):
            try:
                response = call()
            except ConnectionException as exc:
                self.missing_responses += 1
                self._resync()
                error = f"connection lost ({exc})"
                continue
            except ModbusException:
                self.missing_responses += 1
                self._resync()
                error = f"no answer within {self.timeout_s:g} s"
                continue
            except ValueError as exc:  # pymodbus refused to build the request
                raise DeviceError(f"{self.port}: {what} {where}: {exc}") from None
            if response.isError():
                code = int(getattr(response, "exception_code", 0))
                if retry and code in _RETRY_LATER and attempt + 1 < attempts:
                    time.sleep(0.05)
                    error = f"exception {code}"
                    continue
                raise DeviceError(f"{self.port}: {what} {where}: Modbus exception {code} "
                                  f"({exception_meaning(code)})")
            if not check(response):
                self.bad_responses += 1
                self._resync()
                error = "the answer did not match the request"
                continue
            return response
        tries = f" ({attempts} attempts)" if attempts > 1 else ""
        raise NoResponse(f"{self.port}: {what} {where}: {error}{tries}; device id {self.device_id}")

    def _resync(self) -> None:
        """After a lost or foreign answer on an RTU line, let a late answer arrive and drop it."""
        if self.rtu and self.client.socket is not None:
            try:
                time.sleep(min(0.05, self.timeout_s))
                self.client.socket.reset_input_buffer()
            except Exception:
                pass

    def read(self, address: int, count: int, what: str = "reading", retry: bool = True,
             page: int | None = None) -> list[int]:
        """Registers ``address .. address + count - 1`` (read holding registers)."""
        response = self._request(
            what, address, count,
            lambda: self.client.read_holding_registers(address, count=count, device_id=self.device_id),
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
        for address, count in self.map.read_groups(names):
            regs = self.read(address, count)
            out.update(self.map.decode_span([n for n in names if address <= self.map.register(n).address
                                             < address + count], address, regs))
        return out

    def write_names(self, **values) -> None:
        """Write named registers; neighbours share one request."""
        regs = {}
        for name, value in values.items():
            r = self.map.register(name)
            for i, v in enumerate(self.map.encode(name, value)):
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

    def status(self) -> DriveStatus:
        """The status registers, in one request."""
        v = self.read_names(*_STATUS)
        word = int(v["status_word"])
        return DriveStatus(word, self.map.status_flags(word), int(v["fault_code"]), int(v["sample_count"]),
                           int(v["fault_sample"]), float(v["fault_value"]))

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the limits the drive enforces on its own (crossing one stops the axis)."""
        self.write_names(torque_limit_nm=torque_nm, velocity_limit_mps=velocity_mps,
                         position_min_m=position_min_m, position_max_m=position_max_m)
        if "limits_loaded" not in self.status().flags:
            raise DeviceError(f"{self.port}: the drive does not report its limits loaded "
                              f"({self.map.describe(self.map.register('status_word').address)})")

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Choose the capture rate, excitation mode and captured channels; returns the channel names."""
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
        try:
            r = self.map.register("control_word")
            self._request("stopping the drive", r.address, 1,
                          lambda: self.client.write_registers(r.address, [0], device_id=self.device_id),
                          lambda resp: True, retry=True)
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

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None, *, enabled: bool) -> None:
        """Store a notch in a slot as the drive takes it: centre, width, depth (scaled integers), enable."""
        values = self.map.filter_encoding.encode(biquad, spec)
        self.write(self._slot(slot), self.map.encode_filter(values, enabled), f"writing filter slot {slot}")

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad the slot's registers make the drive run, and whether it is enabled."""
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
        """The biquad the drive runs after its own rounding of ``spec`` (0.1 Hz, 0.1 dB steps)."""
        return self.map.filter_encoding.stored_form(biquad, spec, self.identity.loop_rate_hz)

    def save_filter(self, slot: int) -> tuple[int, ...]:
        """The slot's registers as they are, for :meth:`restore_filter`."""
        return tuple(self.read(self._slot(slot), self.map.filters.span, f"reading filter slot {slot}"))

    def restore_filter(self, slot: int, saved: tuple[int, ...]) -> None:
        self.write(self._slot(slot), list(saved), f"restoring filter slot {slot}")

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
        self.events.append({"kind": "lost_blocks", "sample_index": c.first_sample, "value": 1.0,
                            "message": f"capture samples {c.first_sample}..{c.first_sample + c.samples - 1} "
                                       f"could not be read ({1 + _RETRIES} attempts); not filled"})

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
            self.events.append({"kind": "missing_response", "sample_index": 0, "value": 0.0,
                                "message": "the answer to the start command was lost; the drive reports the run started"})

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

    def stream(self, excitation: np.ndarray, sink: Callable[[np.ndarray, np.ndarray], None],
               progress: Callable[[float], None] | None = None) -> RunResult:
        """Play ``excitation`` from the drive's table and hand the captured samples to ``sink``.

        ``excitation[k]`` is held over sample period ``k``; row ``k`` is the
        drive's state at the start of that period. Samples the capture lacks
        (chunks that could not be read, a capture that stopped early) are
        counted in the result's stats, never filled. The drive is left
        disabled, at zero torque, on every exit path.

        Raises
        ------
        LimitTrip
            The drive tripped a limit (the samples captured up to then were delivered).
        DeviceError
            The drive refused a request (the message names the register), stopped
            answering, faulted, or did not finish in time.
        """
        x = np.asarray(excitation, dtype=float)
        n = len(x)
        self.events = []
        stats = StreamStats()
        result = RunResult(requested_samples=n, stats=stats)
        missing_before = self.missing_responses
        bad_before = self.bad_responses
        try:
            self.load_table(x)
            self._trigger()
            result = self._capture(n, stats, result, sink, progress)
            result.completed = result.fault is None
        finally:
            self.stop()
            stats.lost_frames = self.missing_responses - missing_before
            stats.corrupt_frames += self.bad_responses - bad_before
            result.events = list(self.events)
            self.last_result = result
        if result.fault:
            error = LimitTrip if result.fault.split(":")[0] in _LIMIT_FAULTS else DeviceError
            raise error(f"{self.port}: {result.fault}")
        return result

    def _capture(self, n: int, stats: StreamStats, result: RunResult, sink, progress) -> RunResult:
        """Poll the status and read the capture as it fills, until the run has ended and all is read."""
        started = time.monotonic()
        deadline = started + 1.2 * n / self.sample_rate_hz + 2.0 + 2 * self.timeout_s
        read_to = 0
        while True:
            st = self.status()
            available = min(st.sample_count, n)
            before = read_to
            read_to = self.read_capture(read_to, available - read_to, sink, stats, _CHUNKS_PER_POLL)
            if progress:
                progress(min(1.0, read_to / n))
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
        if "fault" in st.flags:
            name = self.map.fault_name(st.fault_code)
            where = self.map.describe(self.map.register("fault_code").address)
            message = (f"{name}: axis stopped, torque zero ({where} = {st.fault_code}, at sample "
                       f"{st.fault_sample}, value {st.fault_value:g})")
            kind = "limit_trip" if name in _LIMIT_FAULTS else "fault"
            self.events.append({"kind": kind, "message": message, "sample_index": st.fault_sample,
                                "value": st.fault_value})
            result.fault = message
        elif available < n:
            stats.lost_samples += n - available
            self.events.append({
                "kind": "capture_stopped", "sample_index": available, "value": float(n - available),
                "message": f"the drive's capture stopped at sample {available} of {n}; samples {available}.."
                           f"{n - 1} were not recorded (not filled)",
            })
        else:
            self.events.append({"kind": "finished", "message": "run complete", "sample_index": n, "value": 0.0})
        return result


def _serial_error(port: str, baudrate: int, device: DeviceConfig) -> str:
    """Why pyserial cannot open ``port`` (pymodbus only says that it could not)."""
    try:
        serial.serial_for_url(port, baudrate=baudrate, parity=device.parity, stopbits=device.stopbits,
                              timeout=0).close()
    except Exception as exc:
        return str(exc) or type(exc).__name__
    return "the port opened on a second try; check it is not in use"
