"""A board's serial line reached as a byte stream (``socket://127.0.0.1:PORT``), spoken to frame by frame.

:class:`Wire` is the host end the conformance checks use. It sends requests framed by the host's codec
(:mod:`hilident.protocol.framing`, :mod:`hilident.protocol.serial_board`), or bytes a check built itself,
and reads the board's frames with timeouts. Every frame the board sends is unpacked here with
:func:`unframe`, written from ``drivers/myrio-board/PROTOCOL.md`` section 2 and not from the host's
decoder, so a framing bug shared by the host and a board cannot hide. Frames are then sorted:

* replies (IDENTITY, ACK, NAK, STATUS, FILTER, LOOP) are handed out one by one in arrival order
  (:meth:`Wire.reply`); the board answers requests in the order they came (PROTOCOL.md section 4);
* sample blocks and events (SAMPLES, EVENT) are kept in :attr:`Wire.stream`. A SAMPLES block that
  arrives before this connection's own CONFIGURE is not decoded (its row layout is another host's,
  PROTOCOL.md section 5.1): it is kept undecoded and counted in :attr:`Wire.stale`.

What no conforming board sends raises :class:`AssertionError` as soon as it arrives: a frame that fails
its COBS decoding or its CRC or is longer than 65 536 bytes, a payload the host codec cannot decode, a
host -> board type, SAMPLES flags in the reserved bits, an EVENT FAULT (reserved in version 1) or an end
event with a value other than 0 (section 11.2). Gaps in the board's message numbers are counted in
:attr:`Wire.seq_gaps` instead (a board may drop sample blocks it cannot send); the checks that expect
none say so.
"""

from __future__ import annotations

import select
import socket
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hilident.errors import ProtocolError
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import encode_frame

#: Longest stuffed frame, delimiter excluded (PROTOCOL.md section 2).
MAX_FRAME_BYTES = 65536
#: Board -> host types that answer a request; SAMPLES and EVENT form the stream.
REPLY_TYPES = frozenset(
    {sb.MsgType.IDENTITY, sb.MsgType.ACK, sb.MsgType.NAK, sb.MsgType.STATUS, sb.MsgType.FILTER, sb.MsgType.LOOP}
)
STREAM_TYPES = frozenset({sb.MsgType.SAMPLES, sb.MsgType.EVENT})
#: SAMPLES flag bits 4-15 are reserved and sent as 0 (PROTOCOL.md section 7).
RESERVED_FLAGS = 0xFFF0
#: SAMPLES header after the payload header: block_index, first_sample, n_rows, flags, consumed, level, underruns.
_BLOCK_HEADER = struct.Struct("<IIHHIII")


# --- framing written out from PROTOCOL.md section 2 ------------------------------------------------------


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xEDB88320 if crc & 1 else crc >> 1  # 0x04C11DB7, bit-reflected
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc32_ieee(data: bytes) -> int:
    """CRC-32 IEEE 802.3: reflected polynomial 0x04C11DB7, init and final XOR 0xFFFFFFFF."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ byte) & 0xFF]
    return crc ^ 0xFFFFFFFF


def crc_le(payload: bytes) -> bytes:
    """The 4 checksum bytes a frame carries after ``payload``: the CRC-32, little-endian."""
    return crc32_ieee(payload).to_bytes(4, "little")


def cobs_stuff(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing as PROTOCOL.md section 2 words it.

    Each run of non-zero bytes follows a code byte equal to its length + 1, the code standing for the
    zero that ended the run; a run of 254 non-zero bytes is cut with code 0xFF, which implies no zero;
    data that ends right after such a full run gets no further empty block.
    """
    out = bytearray()
    run = bytearray()
    ended_by_full_run = False
    for byte in data:
        ended_by_full_run = False
        if byte == 0:
            out += bytes([len(run) + 1]) + run
            run.clear()
            continue
        run.append(byte)
        if len(run) == 254:
            out += b"\xff" + run
            run.clear()
            ended_by_full_run = True
    if not ended_by_full_run:
        out += bytes([len(run) + 1]) + run
    return bytes(out)


def cobs_unstuff(stuffed: bytes) -> bytes:
    """The data :func:`cobs_stuff` made ``stuffed`` from; ValueError for bytes no stuffing produces."""
    out = bytearray()
    i = 0
    while i < len(stuffed):
        code = stuffed[i]
        if code == 0:
            raise ValueError(f"zero byte at {i} inside a stuffed frame")
        block = stuffed[i + 1 : i + code]
        if len(block) != code - 1 or 0 in block:
            raise ValueError(f"code byte {code} at {i} runs past the frame or over a zero")
        out += block
        i += code
        if code != 0xFF and i < len(stuffed):
            out.append(0)
    return bytes(out)


def hand_frame(payload: bytes, crc: bytes | None = None) -> bytes:
    """``COBS(payload ‖ CRC32_LE(payload)) ‖ 0x00`` built here, or with the checksum bytes ``crc`` instead."""
    return cobs_stuff(payload + (crc_le(payload) if crc is None else crc)) + b"\x00"


def unframe(raw: bytes) -> bytes:
    """The payload of one received frame (``raw``: the bytes before its delimiter).

    Raises
    ------
    AssertionError
        The frame is longer than 65 536 bytes, is not COBS, is too short or fails its CRC.
    """
    assert len(raw) <= MAX_FRAME_BYTES, f"the board sent a frame of {len(raw)} bytes (limit {MAX_FRAME_BYTES})"
    try:
        body = cobs_unstuff(raw)
    except ValueError as exc:
        raise AssertionError(f"the board sent a frame that is not COBS ({exc}): {raw[:64].hex(' ')}") from None
    assert len(body) > 4, f"the board sent a frame of {len(body)} bytes after unstuffing: {raw.hex(' ')}"
    payload, crc = body[:-4], body[-4:]
    assert crc == crc_le(payload), (
        f"the board sent a frame whose CRC bytes {crc.hex(' ')} are not CRC32_LE(payload) = "
        f"{crc_le(payload).hex(' ')}: {raw[:64].hex(' ')}"
    )
    return payload


def header(version: int, kind: int, seq: int) -> bytes:
    """The 4-byte payload header (PROTOCOL.md section 3)."""
    return struct.pack("<BBH", version, kind, seq & 0xFFFF)


def block_fields(payload: bytes) -> tuple[int, int, int, int, int, int, int]:
    """A SAMPLES payload's fixed fields, readable without the channel selection: ``(block_index,
    first_sample, n_rows, flags, excitation_consumed, excitation_level, underruns)``."""
    return _BLOCK_HEADER.unpack_from(payload, 4)


# --- the host end ------------------------------------------------------------------------------------------


@dataclass
class Frame:
    """One frame the board sent, as it arrived."""

    order: int  #: arrival position on this connection, from 0
    at: float  #: time.monotonic() when it was read
    type: int
    seq: int
    payload: bytes
    raw: bytes  #: the stuffed bytes before the delimiter
    msg: object | None  #: the decoded message; None for a sample block of another host's configuration

    @property
    def is_block(self) -> bool:
        return self.type == sb.MsgType.SAMPLES

    @property
    def flags(self) -> int:
        """A SAMPLES block's flags (also for one that was not decoded)."""
        return block_fields(self.payload)[3]


class Wire:
    """One host connection to a board.

    Parameters
    ----------
    url : str
        ``socket://HOST:PORT``.
    timeout_s : float
        How long :meth:`reply` and :meth:`wait_for` wait by default.
    first_seq : int
        The host numbers its first message ``first_seq + 1`` (a receiver must not assume a start value,
        PROTOCOL.md section 3).
    loop_rate_hz, capacity : float, int
        The board's loop rate and excitation buffer (IDENTITY), for :meth:`play`.
    """

    def __init__(
        self,
        url: str,
        timeout_s: float = 2.0,
        first_seq: int = 0x7FF0,
        loop_rate_hz: float = 4000.0,
        capacity: int = 4096,
    ):
        assert url.startswith("socket://"), url
        host, port = url[len("socket://") :].rsplit(":", 1)
        self.url = url
        self.timeout_s = timeout_s
        self.loop_rate_hz = loop_rate_hz
        self.capacity = capacity
        self.sock = socket.create_connection((host, int(port)), timeout=timeout_s)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.seq = first_seq & 0xFFFF
        self.channels: tuple[sb.ChannelSelection, ...] = ()
        self.block_samples = 0
        self.sample_divider = 0
        self.excitation: tuple[sb.Format, float] = (sb.Format.F32, 1.0)
        self.frames: list[Frame] = []  #: every frame received, in order
        self.stream: list[Frame] = []  #: SAMPLES and EVENT frames, in order
        self.stale = 0  #: SAMPLES blocks dropped undecoded (no CONFIGURE of this connection yet)
        self.seq_gaps = 0  #: board messages missing by their numbers
        self._replies: deque[Frame] = deque()
        self.last_reply: Frame | None = None  #: the reply :meth:`reply` handed out last
        self._rx = bytearray()
        self._last_board_seq: int | None = None
        self.closed = False

    # --- sending ---------------------------------------------------------------------------------------

    def next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        return self.seq

    def payload(self, msg, seq: int | None = None) -> bytes:
        """``msg`` encoded by the host codec, numbered ``seq`` (the next number when None)."""
        return sb.encode(msg, self.next_seq() if seq is None else seq, excitation=self.excitation)

    def send(self, msg, seq: int | None = None) -> bytes:
        """Send ``msg`` as one frame; returns its payload."""
        payload = self.payload(msg, seq)
        self.send_raw(encode_frame(payload))
        return payload

    def send_payload(self, payload: bytes) -> None:
        """Send a payload built by a check, framed by the host codec."""
        self.send_raw(encode_frame(payload))

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    # --- receiving -------------------------------------------------------------------------------------

    def pump(self, timeout: float) -> bool:
        """Read what arrives within ``timeout`` seconds (at most one read); True when bytes came."""
        try:
            ready, _, _ = select.select([self.sock], [], [], max(timeout, 0.0))
            if not ready:
                return False
            data = self.sock.recv(1 << 16)
        except OSError as exc:
            raise AssertionError(f"{self.url}: the line failed: {exc}") from None
        assert data, f"{self.url}: the board closed the connection"
        now = time.monotonic()
        self._rx += data
        *complete, rest = bytes(self._rx).split(b"\x00")
        self._rx = bytearray(rest)
        assert len(self._rx) <= MAX_FRAME_BYTES, f"the board sent {len(self._rx)} bytes without a delimiter"
        for raw in complete:
            if raw:  # back-to-back delimiters are idle filler
                self._accept(raw, now)
        return True

    def _accept(self, raw: bytes, now: float) -> None:
        payload = unframe(raw)
        assert len(payload) >= 4, f"the board sent a payload of {len(payload)} bytes: {payload.hex(' ')}"
        version, kind, seq = struct.unpack_from("<BBH", payload)
        assert version == sb.PROTOCOL_VERSION, f"the board sent protocol version {version}"
        assert kind in REPLY_TYPES | STREAM_TYPES, f"the board sent message type 0x{kind:02x}"
        if self._last_board_seq is not None:
            missing = (seq - self._last_board_seq - 1) & 0xFFFF
            if missing < 0x8000:
                self.seq_gaps += missing
        self._last_board_seq = seq
        frame = Frame(len(self.frames), now, kind, seq, payload, raw, self._decode(kind, payload))
        self.frames.append(frame)
        if kind in STREAM_TYPES:
            self.stream.append(frame)
        else:
            self._replies.append(frame)

    def _decode(self, kind: int, payload: bytes):
        if kind == sb.MsgType.SAMPLES:
            fields = block_fields(payload)
            assert not fields[3] & RESERVED_FLAGS, f"SAMPLES block {fields[0]} has reserved flags {fields[3]:#06x}"
            if not self.channels:
                self.stale += 1
                return None
            assert fields[2] <= self.block_samples, f"SAMPLES block {fields[0]} holds {fields[2]} rows"
        try:
            msg = sb.decode(payload, sample_channels=self.channels)[1]
        except ProtocolError as exc:
            raise AssertionError(f"the board sent an undecodable {sb.MsgType(kind).name}: {exc}") from None
        if isinstance(msg, sb.Event):
            assert msg.code != sb.EventCode.FAULT, f"EVENT FAULT is not sent by a version-1 board: {msg}"
            if msg.code in (sb.EventCode.FINISHED, sb.EventCode.STOPPED, sb.EventCode.WATCHDOG):
                assert msg.value == 0.0, f"{msg.code.name} carries value {msg.value}, not 0"
        return msg

    def reply(self, timeout: float | None = None) -> Frame:
        """The next reply frame (IDENTITY, ACK, NAK, STATUS, FILTER or LOOP); stream frames are kept meanwhile."""
        self.wait_for(lambda: bool(self._replies), "reply", timeout)
        self.last_reply = self._replies.popleft()
        return self.last_reply

    def wait_for(self, condition: Callable[[], bool], what: str, timeout: float | None = None) -> None:
        """Read until ``condition()`` holds; AssertionError naming ``what`` when it does not within ``timeout``."""
        deadline = time.monotonic() + (self.timeout_s if timeout is None else timeout)
        while not condition():
            left = deadline - time.monotonic()
            assert left > 0, f"{self.url}: no {what} within {self.timeout_s if timeout is None else timeout:g} s"
            self.pump(left)

    def listen(self, seconds: float) -> None:
        """Read whatever arrives for ``seconds``."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            self.pump(left)

    # --- requests --------------------------------------------------------------------------------------

    def ask(self, msg, seq: int | None = None):
        """Send ``msg`` and return the next reply's message; an ACK or NAK must name this request."""
        payload = self.send(msg, seq)
        return self.answer_to(payload)

    def answer_to(self, payload: bytes):
        """The next reply, checked to answer the request ``payload`` when it is an ACK or NAK."""
        frame = self.reply()
        msg = frame.msg
        if isinstance(msg, sb.Ack | sb.Nak):
            _, kind, seq = struct.unpack_from("<BBH", payload)
            assert (msg.acked_seq, msg.acked_type) == (seq, kind), (
                f"answer {msg} names request (seq {msg.acked_seq}, type 0x{msg.acked_type:02x}); "
                f"the next request waiting for one was (seq {seq}, type 0x{kind:02x})"
            )
        return msg

    def ok(self, msg, seq: int | None = None) -> sb.Ack:
        """Send ``msg``; its answer must be an ACK of it."""
        answer = self.ask(msg, seq)
        assert isinstance(answer, sb.Ack), f"{type(msg).__name__} was answered with {answer}"
        return answer

    def refused(self, msg, error: sb.ErrorCode) -> sb.Nak:
        """Send ``msg``; its answer must be a NAK of it with ``error``."""
        return self.refused_payload(self.payload(msg), error)

    def refused_payload(self, payload: bytes, error: sb.ErrorCode) -> sb.Nak:
        """Send ``payload`` (framed by the host codec); its answer must be a NAK of it with ``error``."""
        self.send_payload(payload)
        answer = self.answer_to(payload)
        assert isinstance(answer, sb.Nak), f"request {payload[:24].hex(' ')} was answered with {answer}, not a NAK"
        assert answer.error == error, f"NAK {answer.error.name} ({answer.detail!r}), expected {error.name}"
        return answer

    def status(self) -> sb.Status:
        answer = self.ask(sb.StatusRequest())
        assert isinstance(answer, sb.Status), f"STATUS_REQUEST was answered with {answer}"
        return answer

    def identify(self) -> sb.Identity:
        answer = self.ask(sb.Identify())
        assert isinstance(answer, sb.Identity), f"IDENTIFY was answered with {answer}"
        return answer

    def read_filter(self, slot: int) -> tuple[sb.FilterCoefficients, bytes]:
        """A slot's contents: the decoded FILTER and its raw body (22 bytes)."""
        self.send(sb.ReadFilter(slot))
        frame = self.reply()
        assert isinstance(frame.msg, sb.FilterCoefficients), f"READ_FILTER {slot} was answered with {frame.msg}"
        assert frame.msg.slot == slot, f"READ_FILTER {slot} was answered with slot {frame.msg.slot}"
        return frame.msg, frame.payload[4:]

    def read_loop(self) -> tuple[sb.LoopParameters, bytes]:
        """The cascade the board runs: the decoded LOOP and its raw body (24 bytes)."""
        self.send(sb.ReadLoop())
        frame = self.reply()
        assert isinstance(frame.msg, sb.LoopParameters), f"READ_LOOP was answered with {frame.msg}"
        return frame.msg, frame.payload[4:]

    def configure(self, config: sb.Configure) -> None:
        """CONFIGURE (must be ACKed); sample blocks from here on are decoded with its channels."""
        self.ok(config)
        self.channels = config.channels
        self.block_samples = config.block_samples
        self.sample_divider = config.sample_divider
        self.excitation = (config.excitation_format, config.excitation_scale)

    def excite(self, first: int, values) -> bytes:
        """EXCITATION of ``values`` from ``first`` (not acknowledged on success); returns its payload."""
        return self.send(sb.Excitation(first, np.asarray(values, dtype=float)))

    # --- the stream --------------------------------------------------------------------------------------

    def blocks(self, since: int = 0) -> list[Frame]:
        """SAMPLES frames that arrived at or after arrival position ``since``."""
        return [f for f in self.stream if f.is_block and f.order >= since]

    def events(self, since: int = 0) -> list[sb.Event]:
        return [f.msg for f in self.stream if f.type == sb.MsgType.EVENT and f.order >= since]

    def last_block(self, since: int = 0) -> Frame | None:
        return next((f for f in self.blocks(since) if f.flags & sb.FLAG_LAST), None)

    def wait_for_last_block(self, since: int = 0, timeout: float | None = None) -> Frame:
        """Read until the run's FLAG_LAST block arrived."""
        self.wait_for(lambda: self.last_block(since) is not None, "SAMPLES block with FLAG_LAST", timeout)
        last = self.last_block(since)
        assert last is not None
        return last

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.sock.close()

    # --- a run ------------------------------------------------------------------------------------------

    def play(self, values, n_samples: int | None = None, chunk: int = 256) -> Run:
        """START a run of ``n_samples`` (default: one per value) and stream ``values`` with flow control.

        As the reference host does (PROTOCOL.md sections 6, 8 and 13): pre-fill the excitation buffer up
        to its capacity less one chunk, START, keep ``sent - excitation_consumed <= capacity`` with the
        latest block, PING after 0.2 s without sending, and read until the run's FLAG_LAST block and its
        end event arrived. Every PING must be ACKed; any other answer during the run fails the check.
        """
        values = np.asarray(values, dtype=float)
        n = len(values) if n_samples is None else n_samples
        sent = 0
        while sent < len(values) and sent + chunk <= self.capacity - chunk:
            sent = self._send_chunk(values, sent, chunk)
        since = len(self.frames)
        start = self.send(sb.Start(n))
        started = time.monotonic()
        start_ack = self.reply()
        assert start_ack.msg == sb.Ack(struct.unpack_from("<H", start, 2)[0], sb.MsgType.START), (
            f"START was answered with {start_ack.msg}"
        )
        pings: list[bytes] = []
        last_send = started
        max_outstanding = sent
        deadline = started + self.timeout_s + 2.0 * n * self.sample_divider / self.loop_rate_hz
        while self.last_block(since) is None:
            assert time.monotonic() < deadline, f"{self.url}: the run of {n} samples did not end in time"
            blocks = [f.msg for f in self.blocks(since) if f.msg is not None]
            consumed = blocks[-1].excitation_consumed if blocks else 0
            while sent < len(values) and sent + min(chunk, len(values) - sent) - consumed <= self.capacity:
                sent = self._send_chunk(values, sent, chunk)
                last_send = time.monotonic()
            max_outstanding = max(max_outstanding, sent - consumed)
            if time.monotonic() - last_send > 0.2:
                pings.append(self.send(sb.Ping()))
                last_send = time.monotonic()
            self.pump(0.01)
        self.wait_for(lambda: any(e.code in END_EVENTS for e in self.events(since)), "event ending the run")
        for ping in pings:
            assert isinstance(self.answer_to(ping), sb.Ack)
        return Run(since, start_ack, started, self.blocks(since), self.events(since), sent, max_outstanding)

    def _send_chunk(self, values: np.ndarray, first: int, chunk: int) -> int:
        end = min(first + chunk, len(values))
        self.excite(first, values[first:end])
        return end


#: Events that end a run (PROTOCOL.md section 11.2).
END_EVENTS = frozenset({sb.EventCode.FINISHED, sb.EventCode.STOPPED, sb.EventCode.LIMIT_TRIP, sb.EventCode.WATCHDOG})


@dataclass
class Run:
    """What :meth:`Wire.play` saw of one run."""

    since: int  #: arrival position of the first frame after START was sent
    start_ack: Frame
    started: float  #: time.monotonic() when START was sent
    blocks: list[Frame]
    events: list[sb.Event]
    sent: int  #: excitation values sent
    max_outstanding: int  #: largest ``sent - excitation_consumed`` the host allowed itself

    @property
    def samples(self) -> list[sb.Samples]:
        return [f.msg for f in self.blocks if isinstance(f.msg, sb.Samples)]

    def rows(self) -> np.ndarray:
        """Every row of the run, in SI units, one column per selected channel."""
        return np.concatenate([s.data for s in self.samples])

    @property
    def last(self) -> Frame:
        return self.blocks[-1]
