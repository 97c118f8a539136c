"""Byte framing of the serial board protocol: COBS, CRC-32 and a zero delimiter.

A frame on the wire is ``COBS(payload + crc32_le(payload)) + b"\\x00"``. COBS
removes every zero byte from the encoded body, so a receiver that lost its place
(garbage, dropped bytes, a cable plugged in mid-stream) resynchronises at the
next zero byte. The CRC-32 (IEEE 802.3, as :func:`zlib.crc32`) rejects frames
whose bytes were corrupted. See ``drivers/myrio-board/PROTOCOL.md``.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from cobs import cobs

DELIMITER = b"\x00"
CRC_BYTES = 4
#: Longest encoded frame a receiver accepts (bytes, without the delimiter).
MAX_FRAME_BYTES = 65536

_CRC = struct.Struct("<I")


def encode_frame(payload: bytes) -> bytes:
    """Wrap ``payload`` into one delimited, checksummed wire frame."""
    return cobs.encode(payload + _CRC.pack(zlib.crc32(payload))) + DELIMITER


@dataclass
class FrameStats:
    """Counters of what a :class:`FrameDecoder` saw.

    Attributes
    ----------
    frames : int
        Frames that passed COBS decoding and the CRC check.
    corrupt : int
        Frames rejected by COBS decoding, length or CRC.
    oversize : int
        Runs of bytes longer than ``MAX_FRAME_BYTES`` without a delimiter (discarded).
    bytes_in : int
        Bytes fed to the decoder.
    """

    frames: int = 0
    corrupt: int = 0
    oversize: int = 0
    bytes_in: int = 0


class FrameDecoder:
    """Incremental decoder: feed arbitrary byte chunks, get whole payloads back.

    Examples
    --------
    >>> dec = FrameDecoder()
    >>> wire = encode_frame(b"abc") + b"\\x13\\x37\\x00" + encode_frame(b"def")
    >>> dec.feed(wire[:5]) + dec.feed(wire[5:])
    [b'abc', b'def']
    >>> dec.stats.corrupt
    1
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.stats = FrameStats()

    def feed(self, data: bytes) -> list[bytes]:
        """Add received bytes; return the payloads of the frames they completed."""
        self.stats.bytes_in += len(data)
        self._buffer += data
        if DELIMITER not in data:
            if len(self._buffer) > MAX_FRAME_BYTES:
                self._buffer.clear()
                self.stats.oversize += 1
            return []
        *frames, rest = bytes(self._buffer).split(DELIMITER)
        self._buffer = bytearray(rest)
        payloads = []
        for raw in frames:
            if not raw:
                continue  # back-to-back delimiters are idle filler, not an error
            payload = self._check(raw)
            if payload is None:
                self.stats.corrupt += 1
            else:
                self.stats.frames += 1
                payloads.append(payload)
        return payloads

    @staticmethod
    def _check(raw: bytes) -> bytes | None:
        if len(raw) > MAX_FRAME_BYTES:
            return None
        try:
            body = cobs.decode(raw)
        except cobs.DecodeError:
            return None
        if len(body) <= CRC_BYTES:
            return None
        payload, crc = body[:-CRC_BYTES], body[-CRC_BYTES:]
        if _CRC.unpack(crc)[0] != zlib.crc32(payload):
            return None
        return payload
