"""The emulated Modbus drive against the Modbus specification: one raw probe per rule, one table.

Run by hand: ``python bench/modbus_conformance.py`` (``PYTHONPATH=src`` from a
checkout whose package is not the one installed). It starts the emulated
``modbus-servo`` drive (Modbus TCP on 127.0.0.1 and Modbus RTU on a
pseudo-terminal), sends each probe as raw bytes built here (MBAP header, or
address and CRC), and prints request -> expected -> got. The rows are the
violations listed in issue 12 and the rules that replace them (MODBUS
Application Protocol V1.1b3, TCP/IP Implementation Guide V1.0b, Modbus over
Serial Line V1.02). Exit code 1 when a row differs.
"""

from __future__ import annotations

import socket
import struct
import sys
import time

import serial

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.config.tables import DeviceConfig, parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.modbus.server import start
from hilident.protocol.modbus.rtu import rtu_crc

BAUD = 115200
CONFIG = """
[limits]
torque_nm = 5.0
velocity_mps = 1.0
position_min_m = -1.0
position_max_m = 1.0
[emulator]
preset = "clean"
"""


def pdu(function: int, *words: int, tail: bytes = b"") -> bytes:
    return bytes([function]) + struct.pack(f">{len(words)}H", *words) + tail


def rtu(address: int, body: bytes) -> bytes:
    crc = rtu_crc(bytes([address]) + body)
    return bytes([address]) + body + bytes([crc & 0xFF, crc >> 8])


def tcp_probe(sock: socket.socket, unit: int, body: bytes) -> str:
    """The PDU answered (hex), or "silence" when nothing comes within 0.3 s."""
    sock.sendall(struct.pack(">HHHB", 0x2A2A, 0, len(body) + 1, unit) + body)
    sock.settimeout(0.3)
    try:
        header = sock.recv(7)
        data = sock.recv(struct.unpack(">H", header[4:6])[0] - 1)
    except TimeoutError:
        return "silence"
    return f"{header[6]:02x}|" + data.hex(" ")


def rtu_probe(line: serial.Serial, frame: bytes) -> str:
    """The frame answered (hex), or "silence" when nothing comes within 50 ms."""
    line.reset_input_buffer()
    line.write(frame)
    line.flush()
    time.sleep(0.05)
    data = line.read(line.in_waiting)
    return data.hex(" ") if data else "silence"


def main() -> int:
    cfg = parse_config(CONFIG).emulator
    driver = find_driver("modbus-servo")
    rows = []
    tcp = start(cfg, driver, DeviceConfig(device_id=1), link="tcp")
    try:
        host, port = tcp.port[len("tcp://") :].rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=2.0) as sock:
            for what, unit, body, want in [
                ("TCP read 126 registers", 1, pdu(3, 1024, 126), "01|83 03"),
                ("TCP read 0 registers", 1, pdu(3, 1024, 0), "01|83 03"),
                ("TCP write 124 registers", 1, pdu(16, 1024, 124, tail=bytes([248]) + bytes(248)), "01|90 03"),
                ("TCP write, byte count != 2 x quantity", 1, pdu(16, 111, 1, tail=b"\x04\x00\x01\x00\x01"), "01|90 03"),
                ("TCP read unmapped register 7", 1, pdu(3, 7, 1), "01|83 02"),
                *[
                    (f"TCP function {fc}", 1, body, f"01|{0x80 | fc:02x} 01")
                    for fc, body in [
                        (1, pdu(1, 0, 8)),
                        (2, pdu(2, 0, 8)),
                        (4, pdu(4, 0, 1)),
                        (7, bytes([7])),
                        (8, pdu(8, 0, 0x1234)),
                        (11, bytes([11])),
                        (15, pdu(15, 100, 2, tail=b"\x01\x03")),
                        (17, bytes([17])),
                        (22, pdu(22, 111, 0xFFFF, 0)),
                        (23, pdu(23, 0, 1, 111, 1, tail=b"\x02\x00\x01")),
                        (24, pdu(24, 0)),
                        (43, bytes([43, 14, 1, 0])),
                    ]
                ],
                ("TCP write single coil 100 ON (control word)", 1, pdu(5, 100, 0xFF00), "01|85 01"),
                ("TCP write single coil 111 ON (divider)", 1, pdu(5, 111, 0xFF00), "01|85 01"),
                ("TCP control word after the coil writes", 1, pdu(3, 100, 1), "01|03 02 00 00"),
                ("TCP unit id 255", 255, pdu(3, 0, 1), "ff|03 02 4d 53"),
                ("TCP unit id 1 (configured)", 1, pdu(3, 0, 1), "01|03 02 4d 53"),
                ("TCP unit id 2", 2, pdu(3, 0, 1), "silence"),
                ("TCP unit id 0", 0, pdu(3, 0, 1), "silence"),
            ]:
                rows.append((what, body.hex(" "), want, tcp_probe(sock, unit, body)))
    finally:
        tcp.close()
    emu = start(cfg, driver, DeviceConfig(device_id=1, baudrate=BAUD), link="pty")
    try:
        line = serial.Serial(emu.port, baudrate=BAUD, parity="N", timeout=0.2)
        bad = rtu(1, pdu(6, 111, 5))
        for what, frame, want in [
            ("RTU read to own address 1", rtu(1, pdu(3, 0, 1)), rtu(1, b"\x03\x02\x4d\x53").hex(" ")),
            ("RTU read to slave 2", rtu(2, pdu(3, 0, 1)), "silence"),
            ("RTU read to slave 247", rtu(247, pdu(3, 0, 1)), "silence"),
            ("RTU broadcast read", rtu(0, pdu(3, 0, 1)), "silence"),
            ("RTU broadcast write divider = 2", rtu(0, pdu(6, 111, 2)), "silence"),
            ("RTU divider after the broadcast", rtu(1, pdu(3, 111, 1)), rtu(1, b"\x03\x02\x00\x02").hex(" ")),
            ("RTU bad CRC", bad[:-1] + bytes([bad[-1] ^ 1]), "silence"),
            ("RTU function 43 (read device id)", rtu(1, bytes([43, 14, 1, 0])), rtu(1, b"\xab\x01").hex(" ")),
            ("RTU read 126 registers", rtu(1, pdu(3, 1024, 126)), rtu(1, b"\x83\x03").hex(" ")),
            ("RTU divider back to 1", rtu(1, pdu(6, 111, 1)), rtu(1, pdu(6, 111, 1)).hex(" ")),
        ]:
            rows.append((what, frame.hex(" "), want, rtu_probe(line, frame)))
        line.close()
    finally:
        emu.close()
    width = max(len(r[0]) for r in rows)
    print(f"{'probe':{width}}  {'expected':24}  {'got':24}  request")
    for what, request, want, got in rows:
        mark = "" if got == want else "   <-- differs"
        print(f"{what:{width}}  {want:24}  {got:24}  {request[:40]}{mark}")
    return int(any(r[2] != r[3] for r in rows))


if __name__ == "__main__":
    sys.exit(main())
