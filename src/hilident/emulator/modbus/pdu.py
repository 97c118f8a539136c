"""Modbus Application Protocol requests answered by an emulated drive (MODBUS Application Protocol V1.1b3).

:func:`handle` takes one request PDU (function code and data, without the
MBAP header or the RTU address and CRC) and returns the response PDU. It
knows nothing of the wire: :mod:`hilident.emulator.modbus.server` frames it
for Modbus TCP and Modbus RTU. The drive behind it is a *firmware* object:

``functions`` : frozenset of int
    The function codes the drive declares. Every other code gets
    exception 01 (illegal function), whatever it is.
``read(address, count, input_registers=False) -> list[int] | int``
    Holding (FC 3) or input (FC 4) registers, or an exception code.
``write(address, values) -> int | None``
    FC 6 and FC 16; an exception code when the drive refuses.
``read_bits(address, count, discrete=False) -> list[bool] | int``
    Coils (FC 1) or discrete inputs (FC 2); needed only when declared.
``write_bits(address, values) -> int | None``
    FC 5 and FC 15; needed only when declared.

Each request is checked as the specification's state diagrams do, in this
order: function code declared (else 01), quantity within the function's range
and the PDU's length and byte count consistent with it (else 03), address
range within the 65536 of the table (else 02), then the firmware decides
(02 for an address it does not map, 03 for a value it refuses, 06 busy).
"""

from __future__ import annotations

import struct
from typing import Protocol, runtime_checkable

READ_COILS = 1
READ_DISCRETE_INPUTS = 2
READ_HOLDING_REGISTERS = 3
READ_INPUT_REGISTERS = 4
WRITE_SINGLE_COIL = 5
WRITE_SINGLE_REGISTER = 6
WRITE_MULTIPLE_COILS = 15
WRITE_MULTIPLE_REGISTERS = 16

ILLEGAL_FUNCTION = 1
ILLEGAL_DATA_ADDRESS = 2
ILLEGAL_DATA_VALUE = 3
SERVER_DEVICE_FAILURE = 4
GATEWAY_TARGET_FAILED = 11

#: Functions a broadcast (RTU address 0) may carry: writes only (Modbus over serial line V1.02, 2.1).
WRITE_FUNCTIONS = frozenset({WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS})

_MAX_READ_REGISTERS = 125  # 0x7D
_MAX_WRITE_REGISTERS = 123  # 0x7B
_MAX_READ_BITS = 2000  # 0x7D0
_MAX_WRITE_BITS = 1968  # 0x7B0
_ADDRESSES = 0x10000
_COIL_ON, _COIL_OFF = 0xFF00, 0x0000


class Firmware(Protocol):
    """What :func:`handle` needs from a drive (see the module's docstring)."""

    functions: frozenset

    def read(self, address: int, count: int, input_registers: bool = False) -> list[int] | int: ...

    def write(self, address: int, values) -> int | None: ...


@runtime_checkable
class BitFirmware(Protocol):
    """What :func:`handle` needs besides :class:`Firmware` from a drive that declares coils or discrete inputs."""

    def read_bits(self, address: int, count: int, discrete: bool = False) -> list[bool] | int: ...

    def write_bits(self, address: int, values) -> int | None: ...


def exception_response(function: int, code: int) -> bytes:
    """The exception response PDU: the function code with its high bit set, then ``code``.

    >>> exception_response(3, 2).hex()
    '8302'
    """
    return bytes([(function | 0x80) & 0xFF, code])


def handle(firmware: Firmware, pdu: bytes) -> bytes | None:
    """The response PDU to request ``pdu``, or None for an empty PDU (nothing to answer).

    Parameters
    ----------
    firmware : Firmware
        The drive (see the module's docstring).
    pdu : bytes
        Function code and request data.

    Returns
    -------
    bytes or None
        A normal response, or an exception response (2 bytes).

    Examples
    --------
    A drive that declares no coils refuses "write single coil":

    >>> class Registers:
    ...     functions = frozenset({3})
    ...     def read(self, address, count, input_registers=False):
    ...         return [address + i for i in range(count)]
    >>> handle(Registers(), bytes.fromhex("0500640000")).hex()
    '8501'
    >>> handle(Registers(), bytes.fromhex("0300070002")).hex()
    '030400070008'
    """
    if not pdu:
        return None
    function = pdu[0]
    handler = _HANDLERS.get(function)
    if function not in firmware.functions or handler is None:
        return exception_response(function, ILLEGAL_FUNCTION)
    return handler(firmware, function, pdu[1:])


def _outcome(function: int, result) -> bytes | None:
    """An exception response when the firmware answered with an exception code, else None."""
    if isinstance(result, int) and not isinstance(result, bool):
        return exception_response(function, result)
    return None


def _address_range(function: int, address: int, count: int) -> bytes | None:
    """Exception 02 when ``address .. address + count - 1`` leaves the 16-bit address space."""
    return exception_response(function, ILLEGAL_DATA_ADDRESS) if address + count > _ADDRESSES else None


def _read_registers(firmware, function: int, data: bytes) -> bytes:
    if len(data) != 4:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    address, count = struct.unpack(">HH", data)
    if not 1 <= count <= _MAX_READ_REGISTERS:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    if refused := _address_range(function, address, count):
        return refused
    result = firmware.read(address, count, input_registers=function == READ_INPUT_REGISTERS)
    if refused := _outcome(function, result):
        return refused
    values = [int(v) for v in result]
    if len(values) != count or any(not 0 <= v <= 0xFFFF for v in values):
        return exception_response(function, SERVER_DEVICE_FAILURE)
    return bytes([function, 2 * count]) + struct.pack(f">{count}H", *values)


def _write_single_register(firmware, function: int, data: bytes) -> bytes:
    if len(data) != 4:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    address, value = struct.unpack(">HH", data)
    if refused := _outcome(function, firmware.write(address, [value])):
        return refused
    return bytes([function]) + data  # the echo of the request


def _write_multiple_registers(firmware, function: int, data: bytes) -> bytes:
    if len(data) < 5:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    address, count, byte_count = struct.unpack(">HHB", data[:5])
    values = data[5:]
    if not 1 <= count <= _MAX_WRITE_REGISTERS or byte_count != 2 * count or len(values) != byte_count:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    if refused := _address_range(function, address, count):
        return refused
    if refused := _outcome(function, firmware.write(address, list(struct.unpack(f">{count}H", values)))):
        return refused
    return bytes([function]) + data[:4]  # starting address and quantity


def _read_bits(firmware, function: int, data: bytes) -> bytes:
    if len(data) != 4:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    address, count = struct.unpack(">HH", data)
    if not 1 <= count <= _MAX_READ_BITS:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    if refused := _address_range(function, address, count):
        return refused
    result = firmware.read_bits(address, count, discrete=function == READ_DISCRETE_INPUTS)
    if refused := _outcome(function, result):
        return refused
    bits = [bool(b) for b in result]
    if len(bits) != count:
        return exception_response(function, SERVER_DEVICE_FAILURE)
    return bytes([function, len(_pack_bits(bits))]) + _pack_bits(bits)


def _write_single_coil(firmware, function: int, data: bytes) -> bytes:
    if len(data) != 4:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    address, value = struct.unpack(">HH", data)
    if value not in (_COIL_ON, _COIL_OFF):
        return exception_response(function, ILLEGAL_DATA_VALUE)
    if refused := _outcome(function, firmware.write_bits(address, [value == _COIL_ON])):
        return refused
    return bytes([function]) + data  # the echo of the request, FF 00 for ON


def _write_multiple_coils(firmware, function: int, data: bytes) -> bytes:
    if len(data) < 5:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    address, count, byte_count = struct.unpack(">HHB", data[:5])
    packed = data[5:]
    if not 1 <= count <= _MAX_WRITE_BITS or byte_count != -(-count // 8) or len(packed) != byte_count:
        return exception_response(function, ILLEGAL_DATA_VALUE)
    if refused := _address_range(function, address, count):
        return refused
    if refused := _outcome(function, firmware.write_bits(address, _unpack_bits(packed, count))):
        return refused
    return bytes([function]) + data[:4]  # starting address and quantity


def _pack_bits(bits: list[bool]) -> bytes:
    """Bits packed eight to a byte, the first bit in the lowest bit of the first byte."""
    out = bytearray(-(-len(bits) // 8))
    for i, bit in enumerate(bits):
        if bit:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def _unpack_bits(packed: bytes, count: int) -> list[bool]:
    return [bool(packed[i // 8] >> (i % 8) & 1) for i in range(count)]


_HANDLERS = {
    READ_COILS: _read_bits,
    READ_DISCRETE_INPUTS: _read_bits,
    READ_HOLDING_REGISTERS: _read_registers,
    READ_INPUT_REGISTERS: _read_registers,
    WRITE_SINGLE_COIL: _write_single_coil,
    WRITE_SINGLE_REGISTER: _write_single_register,
    WRITE_MULTIPLE_COILS: _write_multiple_coils,
    WRITE_MULTIPLE_REGISTERS: _write_multiple_registers,
}


def request_length(frame: bytes) -> int | None:
    """Length of the RTU request frame starting at ``frame[0]`` (address, PDU, CRC), or None when unknown yet.

    Known from the function code for every public function of the
    specification, with the byte count for the variable ones; None when the
    frame is too short to tell, or the function has no fixed layout (the
    end is then found by the line's silence).

    >>> request_length(bytes.fromhex("0110006400020400"))
    13
    """
    if len(frame) < 2:
        return None
    function = frame[1]
    if function in _FIXED_REQUEST:
        return _FIXED_REQUEST[function]
    if function in _COUNTED_REQUEST:
        at = _COUNTED_REQUEST[function]
        return at + 1 + frame[at] + 2 if len(frame) > at else None
    return None


# address + PDU + CRC of the requests whose length the function code fixes
_FIXED_REQUEST = {1: 8, 2: 8, 3: 8, 4: 8, 5: 8, 6: 8, 7: 4, 8: 8, 11: 4, 12: 4, 17: 4, 22: 10, 24: 6}
# index of the byte count in the requests that carry one (the frame ends 2 CRC bytes after the data)
_COUNTED_REQUEST = {15: 6, 16: 6, 23: 10}
