"""What a serial line adds to Modbus: the CRC that ends each RTU frame, and counting the frames in stray bytes.

An RTU frame is the unit address, the request or answer, and this CRC (low
byte first); it is the same over every serial port, real or emulated.
"""

from __future__ import annotations

__all__ = ["count_rtu_frames", "rtu_crc"]


def rtu_crc(data: bytes) -> int:
    """CRC-16/MODBUS of ``data`` (polynomial 0xA001 reflected, initial 0xFFFF), as an RTU frame ends with it.

    >>> hex(rtu_crc(bytes.fromhex("0103006500")))
    '0xd432'
    """
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def count_rtu_frames(data: bytes) -> int:
    """How many Modbus RTU frames ``data`` holds (bytes read off a line and not asked for).

    Frames are found by their CRC (low byte first), shortest first; bytes
    that end no frame count as one damaged frame.

    >>> frame = bytes.fromhex("010302002a")
    >>> crc = rtu_crc(frame)
    >>> count_rtu_frames((frame + bytes([crc & 0xFF, crc >> 8])) * 2 + b"\\x00")
    3
    """
    frames, start = 0, 0
    while start < len(data):
        for end in range(start + 4, len(data) + 1):
            body, crc = data[start : end - 2], data[end - 2 : end]
            if rtu_crc(body) == crc[0] | crc[1] << 8:
                frames, start = frames + 1, end
                break
        else:
            return frames + 1
    return frames
