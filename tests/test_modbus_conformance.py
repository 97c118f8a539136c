"""The emulated Modbus drive against the Modbus specification, probed without pymodbus.

Every request is built byte by byte here (MBAP header for Modbus TCP, address
and CRC for Modbus RTU) and every answer compared byte by byte with what the
MODBUS Application Protocol V1.1b3, the TCP/IP Implementation Guide V1.0b and
Modbus over Serial Line V1.02 prescribe. Silence is checked by sending a good
request right after: the next bytes on the wire must be its answer, so a late
answer to the ignored frame cannot pass unnoticed.
"""

from __future__ import annotations

import socket
import struct
import time
from dataclasses import replace

import pytest
import serial

from hilident.adapters.modbus.common import NoResponse
from hilident.adapters.modbus.drive import ModbusDriveAdapter
from hilident.config.tables import DeviceConfig, ModbusDeviceConfig, parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.modbus.pdu import handle, request_length
from hilident.emulator.modbus.server import start
from hilident.errors import DeviceError
from hilident.protocol.modbus.register_map import RegisterMap

DRIVER = find_driver("modbus-servo")
MAP = RegisterMap.from_driver(DRIVER)
UNIT = 1
DEVICE_TYPE = struct.pack(">H", MAP.device_type)
DIVIDER = MAP.register("sample_divider").address  # a plain read/write register (111)
CONTROL = MAP.register("control_word").address  # 100
RTU_BAUD = 115200
SILENCE_TCP_S = 0.3


def twin_config(faults: str = ""):
    return parse_config(f"""
[limits]
torque_nm = 5.0
velocity_mps = 1.0
position_min_m = -1.0
position_max_m = 1.0

[emulator]
time_scale = 1.0
preset = "clean"

[emulator.faults]
{faults}
""").emulator


def pdu(function: int, *words: int, tail: bytes = b"") -> bytes:
    return bytes([function]) + struct.pack(f">{len(words)}H", *words) + tail


def crc16(data: bytes) -> bytes:
    """CRC-16/MODBUS written out here, low byte first (independent of the package's)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


def rtu(address: int, body: bytes) -> bytes:
    return bytes([address]) + body + crc16(bytes([address]) + body)


# --- Modbus TCP ---------------------------------------------------------------------------------


class Tcp:
    """A raw socket speaking MBAP."""

    def __init__(self, port: str):
        host, number = port[len("tcp://") :].rsplit(":", 1)
        self.sock = socket.create_connection((host, int(number)), timeout=2.0)
        self.tid = 0x1200

    def send(self, body: bytes, unit: int = UNIT, protocol: int = 0) -> int:
        self.tid += 1
        self.sock.sendall(struct.pack(">HHHB", self.tid, protocol, len(body) + 1, unit) + body)
        return self.tid

    def receive(self, timeout: float = 2.0) -> bytes | None:
        """One whole answer (MBAP header and PDU), or None when nothing comes within ``timeout``."""
        self.sock.settimeout(timeout)
        try:
            header = self._exactly(7)
        except TimeoutError:
            return None
        self.sock.settimeout(2.0)
        return header + self._exactly(struct.unpack(">H", header[4:6])[0] - 1)

    def _exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            assert chunk, "the server closed the connection"
            data += chunk
        return data

    def ask(self, body: bytes, unit: int = UNIT) -> bytes:
        """Send ``body``; the answer's PDU after checking its header echoes the transaction and unit."""
        tid = self.send(body, unit)
        answer = self.receive()
        assert answer is not None, f"no answer to {body.hex()}"
        assert answer[:4] == struct.pack(">HH", tid, 0) and answer[6] == unit
        return answer[7:]

    def close(self):
        self.sock.close()


@pytest.fixture(scope="module")
def tcp_twin():
    emu = start(twin_config(), DRIVER, DeviceConfig(modbus=ModbusDeviceConfig(device_id=UNIT)), link="tcp")
    yield emu
    emu.close()


@pytest.fixture
def tcp(tcp_twin):
    client = Tcp(tcp_twin.port)
    yield client
    client.close()


def test_a_read_is_answered_with_the_transaction_id_on_several_connections(tcp, tcp_twin):
    other = Tcp(tcp_twin.port)
    try:
        other.tid = 0xBEEF
        first = tcp.send(pdu(3, 0, 1))
        second = other.send(pdu(3, 0, 2))
        assert other.receive() == struct.pack(">HHHB", second, 0, 7, UNIT) + bytes([3, 4]) + DEVICE_TYPE + struct.pack(
            ">H", MAP.map_version
        )
        assert tcp.receive() == struct.pack(">HHHB", first, 0, 5, UNIT) + bytes([3, 2]) + DEVICE_TYPE
    finally:
        other.close()


# request PDUs of the functions the drive does not declare, each well formed
UNDECLARED = {
    1: pdu(1, 0, 8),
    2: pdu(2, 0, 8),
    4: pdu(4, 0, 1),
    5: pdu(5, CONTROL, 0xFF00),
    7: bytes([7]),
    8: pdu(8, 0, 0x1234),
    11: bytes([11]),
    15: pdu(15, CONTROL, 2, tail=b"\x01\x03"),
    17: bytes([17]),
    22: pdu(22, DIVIDER, 0xFFFF, 0x0000),
    23: pdu(23, 0, 1, DIVIDER, 1, tail=b"\x02\x00\x01"),
    24: pdu(24, 0),
    43: bytes([43, 14, 1, 0]),
}


@pytest.mark.parametrize("function", sorted(UNDECLARED))
def test_every_undeclared_function_gets_exception_01(tcp, function):
    assert tcp.ask(UNDECLARED[function]) == bytes([0x80 | function, 0x01])


def test_write_single_coil_does_not_reach_the_registers(tcp):
    assert tcp.ask(pdu(6, DIVIDER, 3)) == pdu(6, DIVIDER, 3)
    for address in (CONTROL, DIVIDER):  # coil 100 ON once set the control word to run
        assert tcp.ask(pdu(5, address, 0xFF00)) == b"\x85\x01"
    assert tcp.ask(pdu(3, CONTROL, 1)) == b"\x03\x02\x00\x00"
    assert tcp.ask(pdu(3, DIVIDER, 1)) == b"\x03\x02\x00\x03"


@pytest.mark.parametrize(
    "request_pdu,answer",
    [
        (pdu(3, MAP.table.base, 0), b"\x83\x03"),
        (pdu(3, MAP.table.base, 126), b"\x83\x03"),
        (pdu(3, MAP.table.base, 0x7D, tail=b"\x00"), b"\x83\x03"),  # one byte too many
        (pdu(16, MAP.table.base, 0, tail=b"\x00"), b"\x90\x03"),
        (pdu(16, MAP.table.base, 124, tail=bytes([248]) + bytes(248)), b"\x90\x03"),
        (pdu(16, DIVIDER, 1, tail=b"\x04\x00\x02\x00\x00"), b"\x90\x03"),  # byte count 4 for 1 register
        (pdu(16, DIVIDER, 2, tail=b"\x04\x00\x02"), b"\x90\x03"),  # fewer bytes than the byte count
        (pdu(6, DIVIDER, tail=b"\x00"), b"\x86\x03"),  # value cut short
    ],
    ids=["read-0", "read-126", "read-long-pdu", "write-0", "write-124", "byte-count", "short-data", "fc6-short"],
)
def test_quantities_and_lengths_out_of_range_get_exception_03(tcp, request_pdu, answer):
    assert tcp.ask(request_pdu) == answer


def test_the_largest_quantities_are_served(tcp):
    answer = tcp.ask(pdu(3, MAP.table.base, 125))
    assert answer[:2] == bytes([3, 250]) and len(answer) == 252
    values = list(range(123))
    assert tcp.ask(pdu(16, MAP.table.base, 123, tail=bytes([246]) + struct.pack(">123H", *values))) == pdu(
        16, MAP.table.base, 123
    )
    assert struct.unpack(">123H", tcp.ask(pdu(3, MAP.table.base, 123))[2:]) == tuple(values)


@pytest.mark.parametrize(
    "request_pdu,answer",
    [
        (pdu(3, 5, 4), b"\x83\x02"),  # crosses the gap after filter_slots
        (pdu(3, 7, 1), b"\x83\x02"),
        (pdu(3, 0xFFFF, 2), b"\x83\x02"),  # beyond the last address
        (pdu(6, 7, 1), b"\x86\x02"),
        (pdu(6, MAP.register("status_word").address, 1), b"\x86\x02"),  # read-only
        (pdu(16, 129, 2, tail=b"\x04\x00\x01\x00\x01"), b"\x90\x02"),
    ],
    ids=["read-gap", "read-unmapped", "read-wraps", "write-unmapped", "write-read-only", "write-multiple-unmapped"],
)
def test_unmapped_addresses_get_exception_02(tcp, request_pdu, answer):
    assert tcp.ask(request_pdu) == answer


def test_only_a_failing_drive_answers_exception_04(tcp, tcp_twin, monkeypatch):
    def broken(address, count, input_registers=False):
        raise RuntimeError("register image lost")

    assert tcp.ask(pdu(3, 0, 1)) == b"\x03\x02" + DEVICE_TYPE
    monkeypatch.setattr(tcp_twin.server.firmware, "read", broken)
    failures = tcp_twin.server.device_failures
    assert tcp.ask(pdu(3, 0, 1)) == b"\x83\x04"
    assert tcp_twin.server.device_failures == failures + 1 and isinstance(tcp_twin.server.last_failure, RuntimeError)


@pytest.mark.parametrize("unit", [UNIT, 0xFF])
def test_the_configured_unit_id_and_255_are_answered(tcp, unit):
    assert tcp.ask(pdu(3, 0, 1), unit=unit) == b"\x03\x02" + DEVICE_TYPE


@pytest.mark.parametrize("unit", [0, 2, 247, 254])
def test_other_unit_ids_are_ignored(tcp, unit):
    tcp.send(pdu(3, 0, 1), unit=unit)
    assert tcp.receive(timeout=SILENCE_TCP_S) is None
    assert tcp.ask(pdu(3, 0, 1)) == b"\x03\x02" + DEVICE_TYPE  # the connection is still good


def test_another_protocol_id_is_not_answered(tcp):
    tcp.send(pdu(3, 0, 1), protocol=1)
    assert tcp.receive(timeout=SILENCE_TCP_S) is None
    assert tcp.ask(pdu(3, 0, 1)) == b"\x03\x02" + DEVICE_TYPE


def test_other_unit_ids_get_exception_11_when_the_twin_acts_as_a_gateway():
    gateway = twin_config('[emulator.faults.modbus]\nunknown_unit_id = "gateway_exception"')
    emu = start(gateway, DRIVER, DeviceConfig(modbus=ModbusDeviceConfig(device_id=UNIT)), link="tcp")
    client = Tcp(emu.port)
    try:
        assert client.ask(pdu(3, 0, 1), unit=2) == b"\x83\x0b"
        assert client.ask(pdu(6, DIVIDER, 2), unit=0) == b"\x86\x0b"
        assert client.ask(pdu(3, DIVIDER, 1)) == b"\x03\x02\x00\x01"  # the write to unit 0 was not carried out
    finally:
        client.close()
        emu.close()


# --- Modbus RTU ---------------------------------------------------------------------------------


class Rtu:
    """A raw serial line speaking RTU frames."""

    def __init__(self, port: str):
        self.line = serial.Serial(port, baudrate=RTU_BAUD, parity="N", timeout=0.5)
        self.char_s = 11 / RTU_BAUD

    def send(self, frame: bytes) -> None:
        self.line.reset_input_buffer()
        self.line.write(frame)
        self.line.flush()

    def receive(self, n: int, timeout: float = 2.0) -> bytes:
        deadline = time.monotonic() + timeout
        data = b""
        while len(data) < n and time.monotonic() < deadline:
            data += self.line.read(n - len(data))
        return data

    def ask(self, address: int, body: bytes, answer: bytes) -> None:
        """Send a request; the next bytes on the line are exactly ``answer`` (address and CRC added), then quiet."""
        want = rtu(address, answer)
        self.send(rtu(address, body))
        assert self.receive(len(want)) == want
        time.sleep(20 * self.char_s)
        assert self.line.in_waiting == 0

    def silent(self, frame: bytes) -> None:
        """No answer to ``frame``: the answer to a good request that follows is the first thing on the line."""
        self.line.write(frame)
        self.line.flush()
        time.sleep(max(0.02, 40 * self.char_s))  # the line's silence before the next frame (well over 3.5 chars)
        assert self.line.in_waiting == 0
        want = rtu(UNIT, b"\x03\x02" + DEVICE_TYPE)
        self.line.write(rtu(UNIT, pdu(3, 0, 1)))
        assert self.receive(len(want)) == want

    def close(self):
        self.line.close()


@pytest.fixture(scope="module")
def rtu_twin():
    device = DeviceConfig(baudrate=RTU_BAUD, modbus=ModbusDeviceConfig(device_id=UNIT))
    emu = start(twin_config(), DRIVER, device, link="pty")
    yield emu
    emu.close()


@pytest.fixture
def line(rtu_twin):
    client = Rtu(rtu_twin.port)
    yield client
    client.close()


def test_rtu_own_address_is_answered_with_its_crc(line):
    line.ask(UNIT, pdu(3, 0, 1), b"\x03\x02" + DEVICE_TYPE)
    line.ask(UNIT, pdu(6, DIVIDER, 1), pdu(6, DIVIDER, 1))


@pytest.mark.parametrize("function", [5, 8, 43])
def test_rtu_undeclared_functions_get_exception_01(line, function):
    line.ask(UNIT, UNDECLARED[function], bytes([0x80 | function, 0x01]))


def test_rtu_quantity_and_address_exceptions(line):
    line.ask(UNIT, pdu(3, MAP.table.base, 126), b"\x83\x03")
    line.ask(UNIT, pdu(16, DIVIDER, 1, tail=b"\x04\x00\x02\x00\x00"), b"\x90\x03")
    line.ask(UNIT, pdu(3, 7, 1), b"\x83\x02")


@pytest.mark.parametrize("address", [2, 247])
def test_rtu_frames_to_other_slaves_get_no_answer(line, rtu_twin, address):
    line.ask(UNIT, pdu(6, DIVIDER, 1), pdu(6, DIVIDER, 1))
    for body in (pdu(3, 0, 1), pdu(6, DIVIDER, 5), UNDECLARED[5]):
        line.silent(rtu(address, body))
    line.ask(UNIT, pdu(3, DIVIDER, 1), b"\x03\x02\x00\x01")  # the write to the other slave was not carried out


def test_rtu_broadcast_writes_are_carried_out_without_an_answer(line):
    line.ask(UNIT, pdu(6, DIVIDER, 1), pdu(6, DIVIDER, 1))
    line.silent(rtu(0, pdu(6, DIVIDER, 2)))
    line.ask(UNIT, pdu(3, DIVIDER, 1), b"\x03\x02\x00\x02")
    line.silent(rtu(0, pdu(16, DIVIDER, 1, tail=b"\x02\x00\x04")))
    line.ask(UNIT, pdu(3, DIVIDER, 1), b"\x03\x02\x00\x04")
    line.silent(rtu(0, pdu(3, 0, 1)))  # a broadcast read: nothing to answer
    line.silent(rtu(0, pdu(6, 7, 1)))  # a broadcast the drive refuses: still no answer
    line.ask(UNIT, pdu(6, DIVIDER, 1), pdu(6, DIVIDER, 1))


def test_rtu_a_bad_crc_is_dropped_in_silence(line):
    good = rtu(UNIT, pdu(6, DIVIDER, 1))
    line.ask(UNIT, pdu(6, DIVIDER, 1), pdu(6, DIVIDER, 1))
    bad = rtu(UNIT, pdu(6, DIVIDER, 6))
    line.silent(bad[:-1] + bytes([bad[-1] ^ 0x01]))
    line.silent(good[:3] + bytes([good[3] ^ 0x10]) + good[4:])  # a flipped data bit
    line.silent(b"\x01\x2b\x0e\x01\x00\xde\xad")  # a function of unknown length, bad CRC
    line.ask(UNIT, pdu(3, DIVIDER, 1), b"\x03\x02\x00\x01")


# --- the PDU handler with coils (no shipped map declares them) ----------------------------------


class CoilDrive:
    """A drive that declares coils and discrete inputs next to its registers."""

    functions = frozenset({1, 2, 3, 5, 15})

    def __init__(self):
        self.coils = [False] * 32
        self.registers = [0] * 8

    def read(self, address, count, input_registers=False):
        return self.registers[address : address + count] if address + count <= 8 else 2

    def write(self, address, values):
        return 1

    def read_bits(self, address, count, discrete=False):
        if address + count > 32:
            return 2
        return (
            [not b for b in self.coils[address : address + count]]
            if discrete
            else self.coils[address : address + count]
        )

    def write_bits(self, address, values):
        if address + len(values) > 32:
            return 2
        self.coils[address : address + len(values)] = values
        return None


@pytest.mark.parametrize(
    "request_pdu,answer,coils",
    [
        (pdu(5, 3, 0xFF00), pdu(5, 3, 0xFF00), {3}),  # the echo, FF 00 for ON
        (pdu(5, 3, 0x0000), pdu(5, 3, 0x0000), set()),
        (pdu(5, 3, 0x1234), b"\x85\x03", set()),
        (pdu(5, 40, 0xFF00), b"\x85\x02", set()),
        (pdu(15, 1, 10, tail=b"\x02\xcd\x01"), pdu(15, 1, 10), {1, 3, 4, 7, 8, 9}),  # address and quantity
        (pdu(15, 1, 10, tail=b"\x01\xcd"), b"\x8f\x03", set()),  # 10 coils take 2 bytes
        (pdu(15, 1, 0, tail=b"\x00"), b"\x8f\x03", set()),
        (pdu(6, 1, 1), b"\x86\x01", set()),  # declared no FC 6
        (pdu(16, 1, 1, tail=b"\x02\x00\x01"), b"\x90\x01", set()),
    ],
)
def test_coil_writes_answer_as_the_specification_says(request_pdu, answer, coils):
    drive = CoilDrive()
    assert handle(drive, request_pdu) == answer
    assert {i for i, on in enumerate(drive.coils) if on} == coils


def test_coil_reads_pack_the_first_coil_into_the_lowest_bit():
    drive = CoilDrive()
    for i in (0, 2, 9):
        drive.coils[i] = True
    assert handle(drive, pdu(1, 0, 10)) == b"\x01\x02\x05\x02"
    assert handle(drive, pdu(2, 0, 3)) == b"\x02\x01\x02"
    assert handle(drive, pdu(1, 0, 2001)) == b"\x81\x03"
    assert handle(drive, pdu(4, 0, 1)) == b"\x84\x01"
    assert handle(drive, b"") is None


@pytest.mark.parametrize(
    "frame,length",
    [
        (rtu(1, pdu(3, 0, 1)), 8),
        (rtu(1, pdu(16, 0, 2, tail=b"\x04\x00\x01\x00\x02")), 13),
        (rtu(1, bytes([7])), 4),
        (rtu(1, pdu(15, 1, 10, tail=b"\x02\xcd\x01")), 11),
        (rtu(1, bytes([43, 14, 1, 0])), None),
    ],
)
def test_rtu_frame_lengths_come_from_the_function_code(frame, length):
    assert request_length(frame) == length
    if length is not None:
        assert length == len(frame)


# --- the host side: a late answer on an RTU line is never taken for a fresh one -----------------


@pytest.fixture
def late_answers(rtu_twin):
    """The RTU twin's answers delayed by the seconds ``set(delay)`` says (as the switch of the next answer)."""
    server = rtu_twin.server
    before = server.faults

    def set_delay(seconds: float) -> None:
        server.faults = replace(before, modbus=replace(before.modbus, response_delay_s=seconds))

    yield set_delay
    server.faults = before


def rtu_adapter(emu, timeout_s: float) -> ModbusDriveAdapter:
    device = DeviceConfig(
        driver="modbus-servo",
        port=emu.port,
        baudrate=RTU_BAUD,
        timeout_s=timeout_s,
        modbus=ModbusDeviceConfig(parity="N"),
    )
    return ModbusDriveAdapter.open_device(device, DRIVER)


def discarded(ad: ModbusDriveAdapter) -> int:
    return ad.client.stale_frames + ad.registers.dropped_frames + ad.registers.bad_responses


@pytest.mark.parametrize(
    "delay_s,timeout_s,first_count",
    [
        (0.3, 0.2, 1),  # the late answer comes while the adapter waits for it after the timeout
        (0.4, 0.15, 2),  # it comes while the next request waits: another length, dropped there
    ],
    ids=["after-timeout", "during-next-request"],
)
def test_a_late_rtu_answer_is_dropped_and_the_next_request_gets_its_own(
    rtu_twin, late_answers, delay_s, timeout_s, first_count
):
    ad = rtu_adapter(rtu_twin, timeout_s)
    try:
        assert ad.registers.read(DIVIDER, 1) == [1]
        assert ad.registers.read(0, 1) == [MAP.device_type]
        before = discarded(ad)
        late_answers(delay_s)
        with pytest.raises(NoResponse, match="no answer within"):
            ad.registers.read(0, first_count, retry=False)  # device_type (and map_version): its answer comes late
        late_answers(0.0)
        assert ad.registers.read(DIVIDER, 1) == [1]  # the same length as the late answer, another value
        assert discarded(ad) > before
        assert ad.registers.read(0, 1) == [MAP.device_type]
    finally:
        ad.close()


def test_an_exception_answer_names_the_register_and_what_the_code_means(tcp_twin):
    device = DeviceConfig(driver="modbus-servo", port=tcp_twin.port, timeout_s=1.0)
    ad = ModbusDriveAdapter.open_device(device, DRIVER)
    try:
        with pytest.raises(
            DeviceError,
            match=r"register 7 \(not in the driver map\): Modbus exception 2 "
            r"\(illegal data address.*not in the drive's map",
        ):
            ad.registers.read(7, 1)
        with pytest.raises(
            DeviceError,
            match=r"register 110 \(mode\): Modbus exception 3 \(illegal data value.*"
            r"refused the value or the quantity",
        ):
            ad.registers.write(MAP.register("mode").address, [77])
        with pytest.raises(DeviceError, match=r"Modbus exception 1 \(illegal function.*does not support function 4"):
            ad.registers.request(
                "reading input registers",
                0,
                1,
                lambda: ad.client.read_input_registers(0, count=1, device_id=UNIT),
                lambda r: True,
                retry=False,
            )
    finally:
        ad.close()
