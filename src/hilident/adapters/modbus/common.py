"""What the parts of the Modbus adapter share: timing constants, the RTU client, small frozen values (the
identity, a status read, the capture's record layout) and the words for a failed request.

Split from :mod:`hilident.adapters.modbus.drive` so that its parts
(:mod:`~hilident.adapters.modbus.requests`, :mod:`~hilident.adapters.modbus.slots`,
:mod:`~hilident.adapters.modbus.capture`) import them without importing the adapter.
"""

from __future__ import annotations

import errno
import logging
from dataclasses import dataclass, field

import serial
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusIOException
from pymodbus.pdu import ModbusPDU

from hilident.config.tables import DeviceConfig
from hilident.errors import DeviceError
from hilident.protocol.modbus.exception_codes import exception_meaning
from hilident.protocol.modbus.rtu import count_rtu_frames

logging.getLogger("pymodbus").addHandler(logging.NullHandler())  # no library chatter on stderr

_RETRIES = 3  # extra attempts of a request that is safe to repeat
_RETRY_LATER = (5, 6)  # acknowledge, busy: the drive asks to be asked again
_POLL_S = 0.01  # pause between status reads while the drive has nothing new
_CHUNKS_PER_POLL = 16  # capture chunks read between two status reads
_LIMIT_FAULTS = ("torque_limit", "velocity_limit", "position_limit")
_IDENTITY = (
    "device_type",
    "map_version",
    "loop_rate_hz",
    "max_sample_rate_hz",
    "filter_slots",
    "table_capacity",
    "capture_capacity",
    "device_name",
    "firmware",
)
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

    def send(self, request: bytes, addr: tuple | None = None) -> int:
        if request and self.socket is not None:
            try:
                if waiting := self.socket.in_waiting:
                    self.stale_frames += count_rtu_frames(self.socket.read(waiting))
            except (OSError, ValueError):
                pass  # pymodbus's own send reports a broken line
        return super().send(request, addr)

    def execute(self, no_response_expected: bool, request: ModbusPDU) -> ModbusPDU:
        response = super().execute(no_response_expected, request)
        while response is not None and not _answers(request, response):
            self.stale_frames += 1
            try:
                response = self.transaction.sync_get_response(request.dev_id, request.transaction_id)
            except TimeoutError:
                raise _StaleAnswer("only answers to other requests came back") from None
        return response


def _answers(request: ModbusPDU, response: ModbusPDU) -> bool:
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


@dataclass(frozen=True)
class CaptureLayout:
    """Which channels ``configure()`` chose for the capture, and where each sits in a capture record.

    Attributes
    ----------
    mask : int
        The capture mask written to the drive (one bit per channel of its map).
    columns : tuple of int
        The column of each configured channel (in the configured order) in a decoded record.
    """

    mask: int = 0
    columns: tuple[int, ...] = ()


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
        10: f"the gateway has no path to device id {device_id} (check [device.modbus] device_id)",
        11: f"no device with id {device_id} answered behind the gateway (check [device.modbus] device_id and "
        "the line behind the gateway)",
    }.get(code)
    return f"{head}: {why}" if why else head


def _serial_error(port: str, baudrate: int, device: DeviceConfig) -> Exception:
    """Why pyserial cannot open ``port`` (pymodbus only says that it could not), as the error it raises."""
    try:
        serial.serial_for_url(
            port, baudrate=baudrate, parity=device.modbus.parity, stopbits=device.modbus.stopbits, timeout=0
        ).close()
    except Exception as exc:
        return exc
    return OSError(errno.EBUSY, "the port opened on a second try; check it is not in use")
