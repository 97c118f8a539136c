"""Register requests of the Modbus adapter: read and write by name or address, retries, stale answers,
exceptions named, and the status registers.

:class:`RegisterAccess` is a part :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter` owns (its
``registers``); the other parts (the table and capture, the filter slots) send their requests through it.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np
import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException
from pymodbus.pdu import ModbusPDU

from hilident.adapters.modbus.common import (
    _ENABLED_WAIT,
    _RETRIES,
    _RETRY_LATER,
    _STATUS,
    DriveStatus,
    NoResponse,
    _exception_text,
    _reason,
    _StaleAnswer,
)
from hilident.drivers.description import DriverDescription
from hilident.errors import DataError, DeviceError
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.protocol.modbus.rtu import count_rtu_frames


class RegisterAccess:
    """The request part of :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter` (its ``registers``).

    Every request goes through :meth:`request`: what is safe to repeat is retried after a
    timeout, answers to another request are dropped and counted, and an exception answer or a
    lost connection becomes a :class:`~hilident.errors.DeviceError` naming the register.

    Parameters
    ----------
    client : pymodbus ModbusTcpClient or ModbusSerialClient
        Connected, with ``retries=0`` (this part decides what is repeated); the adapter owns and closes it.
    regmap : RegisterMap
        The driver's register map.
    driver : DriverDescription
        The driver (its name, for messages).
    port : str
        ``tcp://host:port`` or the serial port; used in messages.
    device_id : int
        Modbus device (unit) id.
    timeout_s : float
        Longest wait for one answer, s.

    Attributes
    ----------
    comm_timeout_s : float
        The drive's communication timeout as armed at connect (0: none), s.
    missing_responses, bad_responses, dropped_frames : int
        Requests never answered, answers that were not the one asked for, and late answers dropped from an
        RTU line after a lost or foreign answer, since opening.
    """

    def __init__(
        self,
        client: ModbusTcpClient | ModbusSerialClient,
        regmap: RegisterMap,
        driver: DriverDescription,
        port: str,
        device_id: int,
        timeout_s: float,
    ):
        self.client = client
        self.map = regmap
        self.driver = driver
        self.port = port
        self.device_id = device_id
        self.timeout_s = timeout_s
        self.comm_timeout_s = 0.0
        self.missing_responses = 0
        self.bad_responses = 0
        self.dropped_frames = 0

    def rtu_line(self) -> serial.Serial | None:
        """The RTU client's serial line while it is open, else None (Modbus TCP, or a closed line)."""
        return self.client.socket if isinstance(self.client, ModbusSerialClient) else None

    # --- requests -------------------------------------------------------------------------

    def request(
        self,
        what: str,
        address: int,
        count: int,
        call: Callable[[], ModbusPDU],
        check: Callable[[ModbusPDU], bool],
        retry: bool,
        page: int | None = None,
        tries: int | None = None,
    ) -> ModbusPDU:
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
                raise DeviceError(
                    f"{self.port}: {what} {where}: the connection to the drive was lost "
                    f"({_reason(exc)}); was it switched off, or its cable or gateway "
                    "disconnected?"
                ) from None
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
                raise DeviceError(f"{self.port}: {what} {where}: {_exception_text(code, function, self.device_id)}")
            if not check(response):
                self.bad_responses += 1
                self._resync()
                error = "the answer did not match the request"
                continue
            return response
        counted = f" ({attempts} attempts)" if attempts > 1 else ""
        raise NoResponse(f"{self.port}: {what} {where}: {error}{counted}; device id {self.device_id}")

    def _resync(self) -> None:
        """After a lost or foreign answer on an RTU line, wait for a late answer and drop it (counted).

        An RTU answer carries no transaction id: one that comes after its
        request timed out would pass for the next request's answer. So the
        line is watched for up to one answer timeout (as libmodbus does after
        a timeout), and left as soon as a whole frame has come and the line
        has been quiet for a few characters since.
        """
        sock = self.rtu_line()
        if sock is None:
            return
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
    def answers_within(self, seconds: float) -> Iterator[None]:
        """Wait at most ``seconds`` (never more than ``timeout_s``) for each answer inside the block."""
        params = self.client.comm_params
        before = params.timeout_connect
        params.timeout_connect = min(before, seconds)
        try:
            yield
        finally:
            params.timeout_connect = before

    @property
    def enabled_wait_s(self) -> float:
        """Longest wait for one answer while the drive is enabled: lost answers are asked again in time."""
        return _ENABLED_WAIT * self.comm_timeout_s if self.comm_timeout_s else self.timeout_s

    def read(
        self,
        address: int,
        count: int,
        what: str = "reading",
        retry: bool = True,
        page: int | None = None,
        input_registers: bool = False,
    ) -> list[int]:
        """Registers ``address .. address + count - 1`` (read holding registers, or input registers)."""
        reader = self.client.read_input_registers if input_registers else self.client.read_holding_registers
        response = self.request(
            what,
            address,
            count,
            lambda: reader(address, count=count, device_id=self.device_id),
            lambda r: len(r.registers) == count,
            retry,
            page,
        )
        return list(response.registers)

    def write(
        self, address: int, values: Sequence[int] | np.ndarray, what: str = "writing", page: int | None = None
    ) -> None:
        """Write registers from ``address`` (write multiple registers); repeated after a lost answer."""
        words = [int(v) for v in values]
        self.request(
            what,
            address,
            len(words),
            lambda: self.client.write_registers(address, words, device_id=self.device_id),
            lambda r: r.address == address and r.count == len(words),
            True,
            page,
        )

    def read_names(self, *names: str) -> dict[str, float | int | str]:
        """Values of the named registers (neighbours share a request)."""
        out: dict[str, float | int | str] = {}
        for table, address, count in self.map.request_groups(names):
            regs = self.read(address, count, input_registers=table == "input")
            out.update(
                self.map.decode_span(
                    [
                        n
                        for n in names
                        if self.map.register(n).table == table
                        and address <= self.map.register(n).address < address + count
                    ],
                    address,
                    regs,
                )
            )
        return out

    def write_names(self, **values: float | int | str) -> None:
        """Write named registers; neighbours share one request."""
        regs: dict[int, int] = {}
        for name, value in values.items():
            r = self.map.register(name)
            if not r.writable:
                raise DeviceError(
                    f"{self.port}: {self.map.describe(r.address, r.count, table=r.table)} is read-only "
                    f"in driver {self.driver.name!r}"
                )
            try:
                words = self.map.encode(name, value)
            except DataError as exc:
                raise DeviceError(f"{self.port}: not written: {exc}") from None
            for i, v in enumerate(words):
                regs[r.address + i] = v
        addresses = sorted(regs)
        start = addresses[0]
        for a, b in zip(addresses, [*addresses[1:], None], strict=True):
            if b is not None and b == a + 1 and b - start < self.map.max_write:
                continue  # register b joins this request
            self.write(start, [regs[x] for x in range(start, a + 1)])
            if b is not None:
                start = b

    def status(self) -> DriveStatus:
        """The status registers, in one request."""
        v = self.read_names(*_STATUS)
        word = int(v["status_word"])
        return DriveStatus(
            word,
            self.map.status_flags(word),
            int(v["fault_code"]),
            int(v["sample_count"]),
            int(v["fault_sample"]),
            float(v["fault_value"]),
        )
