"""Messages of the hilident serial board protocol, version 1.

Every payload starts with a four-byte header ``version:u8 type:u8 seq:u16``
(little-endian throughout). Each side numbers its own messages with ``seq``
(modulo 2**16) so the other side can spot lost or reordered frames. Message
bodies are fixed ``struct`` layouts, strings are ``len:u8 + UTF-8``. The
normative description is ``drivers/myrio-board/PROTOCOL.md``; this module and
that file must agree.

Host -> board messages have types below 0x80, board -> host at or above 0x80.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

import numpy as np

from hilident.errors import ProtocolError

PROTOCOL_VERSION = 1
#: Message types at or above this go from the board to the host (PROTOCOL.md section 3).
BOARD_TO_HOST = 0x80

_HEADER = struct.Struct("<BBH")


class MsgType(enum.IntEnum):
    """Message type codes."""

    IDENTIFY = 0x01
    CONFIGURE = 0x02
    SET_LIMITS = 0x03
    START = 0x04
    STOP = 0x05
    EXCITATION = 0x06
    STATUS_REQUEST = 0x07
    WRITE_FILTER = 0x08
    READ_FILTER = 0x09
    CLEAR_FAULT = 0x0A
    PING = 0x0B
    READ_LOOP = 0x0C
    WRITE_LOOP = 0x0D

    IDENTITY = 0x81
    ACK = 0x82
    NAK = 0x83
    SAMPLES = 0x84
    STATUS = 0x85
    FILTER = 0x86
    EVENT = 0x87
    LOOP = 0x88


class ErrorCode(enum.IntEnum):
    """Reasons a board refuses a request (in a NAK)."""

    BAD_VERSION = 1
    UNKNOWN_TYPE = 2
    BAD_LENGTH = 3
    BAD_STATE = 4
    BAD_ARGUMENT = 5
    BUFFER_OVERFLOW = 6
    FAULT_ACTIVE = 7


class Mode(enum.IntEnum):
    """What the excitation stream drives."""

    TORQUE = 0  #: excitation is the torque command, loops open
    TORQUE_INJECTION = 1  #: loops hold position, excitation is added to the torque command
    VELOCITY = 2  #: excitation is the velocity set-point
    POSITION = 3  #: excitation is the position set-point (offset from the start position)


class Format(enum.IntEnum):
    """On-wire encoding of one value: IEEE float32, or a scaled signed integer."""

    F32 = 0
    I16 = 1
    I32 = 2


class EventCode(enum.IntEnum):
    """Asynchronous board events."""

    LIMIT_TRIP = 1
    UNDERRUN = 2
    FAULT = 3
    FINISHED = 4
    STOPPED = 5
    WATCHDOG = 6


class FaultCode(enum.IntEnum):
    """Why a board left the running state on its own (``STATUS.fault``)."""

    NONE = 0
    TORQUE_LIMIT = 1
    VELOCITY_LIMIT = 2
    POSITION_LIMIT = 3
    WATCHDOG = 4


class State(enum.IntEnum):
    """Board state machine."""

    IDLE = 0
    CONFIGURED = 1
    RUNNING = 2
    FAULT = 3


_NUMPY_FORMAT = {Format.F32: "<f4", Format.I16: "<i2", Format.I32: "<i4"}


# --- message bodies -------------------------------------------------------------


@dataclass(frozen=True)
class ChannelInfo:
    """A channel the board can stream: name and SI unit."""

    name: str
    unit: str


@dataclass(frozen=True)
class Identity:
    """Board -> host answer to IDENTIFY."""

    protocol_version: int
    name: str
    firmware: str
    loop_rate_hz: float
    max_sample_rate_hz: float
    filter_slots: int
    excitation_buffer_samples: int
    channels: tuple[ChannelInfo, ...]


@dataclass(frozen=True)
class ChannelSelection:
    """One streamed channel: index into the board's channel list, format and scale (SI per LSB)."""

    channel: int
    format: Format = Format.F32
    scale: float = 1.0


@dataclass(frozen=True)
class Configure:
    """Host -> board: sample rate (as a divider of the loop rate), mode, channels, scaling."""

    sample_divider: int
    mode: Mode
    block_samples: int
    channels: tuple[ChannelSelection, ...]
    excitation_format: Format = Format.F32
    excitation_scale: float = 1.0


@dataclass(frozen=True)
class Limits:
    """Host -> board safety limits enforced by the board itself."""

    torque_nm: float
    velocity_mps: float
    position_min_m: float
    position_max_m: float


@dataclass(frozen=True)
class Start:
    """Host -> board: start a run of ``n_samples`` samples (0: until STOP)."""

    n_samples: int


@dataclass(frozen=True)
class Stop:
    """Host -> board: stop now, torque to zero."""

    reason: int = 0


@dataclass(frozen=True)
class Excitation:
    """Host -> board: excitation samples ``first_index .. first_index + len(values)``."""

    first_index: int
    values: np.ndarray


@dataclass(frozen=True)
class StatusRequest:
    pass


@dataclass(frozen=True)
class Identify:
    pass


@dataclass(frozen=True)
class ClearFault:
    pass


@dataclass(frozen=True)
class Ping:
    pass


@dataclass(frozen=True)
class FilterCoefficients:
    """Biquad slot contents: ``b = (b0, b1, b2)``, ``a = (1, a1, a2)``, float32 on the wire."""

    slot: int
    enabled: bool
    b: tuple[float, float, float]
    a: tuple[float, float, float]


@dataclass(frozen=True)
class WriteFilter:
    """Host -> board: store coefficients in a slot."""

    coefficients: FilterCoefficients


@dataclass(frozen=True)
class ReadFilter:
    """Host -> board: ask for a slot's contents (answered by FILTER)."""

    slot: int


@dataclass(frozen=True)
class ReadLoop:
    """Host -> board: ask for the cascade's parameters (answered by LOOP)."""


@dataclass(frozen=True)
class WriteLoop:
    """Host -> board: the cascade's tunable gains, SI units, binary32 on the wire (PROTOCOL.md section 4.16).

    Attributes
    ----------
    kv_nm_per_mps : float
        Velocity loop proportional gain, N·m per (m/s).
    ti_s : float
        Velocity loop integral time, s (``inf``: a P controller).
    kp_pos_per_s : float
        Position loop gain, (m/s) per m.
    velocity_filter_hz : float
        Cut-off of the velocity estimate's first-order low-pass, Hz.
    """

    kv_nm_per_mps: float
    ti_s: float
    kp_pos_per_s: float
    velocity_filter_hz: float


@dataclass(frozen=True)
class LoopParameters:
    """Board -> host (LOOP): the cascade the board runs, SI units, binary32 on the wire (PROTOCOL.md section 4.15).

    The four gains of :class:`WriteLoop`, then the board's own parts: ``current_loop_hz`` (bandwidth of the
    current loop, Hz; ``inf``: ideal) and ``delay_ticks`` (computation and transport delay, loop ticks).
    """

    kv_nm_per_mps: float
    ti_s: float
    kp_pos_per_s: float
    velocity_filter_hz: float
    current_loop_hz: float
    delay_ticks: float

    def values(self) -> dict[str, float]:
        """Parameter name (:data:`LOOP_FIELDS`) -> SI value."""
        return {name: float(getattr(self, name)) for name in LOOP_FIELDS}


#: The fields of LOOP, in wire order; WRITE_LOOP carries the first four (:data:`WRITE_LOOP_FIELDS`).
LOOP_FIELDS = ("kv_nm_per_mps", "ti_s", "kp_pos_per_s", "velocity_filter_hz", "current_loop_hz", "delay_ticks")
WRITE_LOOP_FIELDS = LOOP_FIELDS[:4]


@dataclass(frozen=True)
class Ack:
    """Board -> host: the request with ``seq`` (of ``type``) was carried out."""

    acked_seq: int
    acked_type: int


@dataclass(frozen=True)
class Nak:
    """Board -> host: the request was refused, with a reason."""

    acked_seq: int
    acked_type: int
    error: ErrorCode
    detail: str


@dataclass(frozen=True)
class Samples:
    """Board -> host: one block of samples.

    ``block_index`` counts every block the board produced, including blocks it had
    to drop, so a gap tells the host how many blocks were lost.
    """

    block_index: int
    first_sample: int
    flags: int
    excitation_consumed: int
    excitation_level: int
    underruns: int
    data: np.ndarray  # (n, n_channels) float64, SI units


@dataclass(frozen=True)
class Status:
    """Board -> host answer to STATUS_REQUEST."""

    state: State
    fault: FaultCode
    excitation_level: int
    excitation_capacity: int
    underruns: int
    dropped_blocks: int
    samples_produced: int
    limit_trips: int
    rx_corrupt: int


@dataclass(frozen=True)
class Event:
    """Board -> host: something happened at ``sample_index``."""

    code: EventCode
    sample_index: int
    value: float
    message: str


#: Flags in a SAMPLES block.
FLAG_CLIPPED = 0x0001  #: a value did not fit its integer format and was clipped
FLAG_UNDERRUN = 0x0002  #: the excitation buffer ran dry during this block
FLAG_FAULT = 0x0004  #: the board is in fault (torque is zero)
FLAG_LAST = 0x0008  #: last block of the run


# --- codec ----------------------------------------------------------------------


class _Reader:
    def __init__(self, body: bytes, what: str):
        self.body = body
        self.pos = 0
        self.what = what

    def take(self, fmt: str):
        s = struct.Struct("<" + fmt)
        if self.pos + s.size > len(self.body):
            raise ProtocolError(f"{self.what}: body too short ({len(self.body)} bytes)")
        values = s.unpack_from(self.body, self.pos)
        self.pos += s.size
        return values

    def string(self) -> str:
        (n,) = self.take("B")
        raw = self.body[self.pos : self.pos + n]
        if len(raw) != n:
            raise ProtocolError(f"{self.what}: truncated string")
        self.pos += n
        return raw.decode("utf-8", errors="replace")

    def rest(self) -> bytes:
        return self.body[self.pos :]


def _string(s: str) -> bytes:
    raw = s.encode("utf-8")[:255]
    return bytes([len(raw)]) + raw


def sample_dtype(channels: tuple[ChannelSelection, ...]) -> np.dtype:
    """Packed numpy record type of one sample row on the wire."""
    return np.dtype([(f"c{i}", _NUMPY_FORMAT[Format(c.format)]) for i, c in enumerate(channels)])


def pack_values(values: np.ndarray, fmt: Format, scale: float) -> tuple[bytes, bool]:
    """Encode a 1-D array in ``fmt``; returns the bytes and whether anything was clipped."""
    return pack_rows(np.asarray(values, dtype=float)[:, None], (ChannelSelection(0, fmt, scale),))


def unpack_values(raw: bytes, fmt: Format, scale: float) -> np.ndarray:
    """Decode a 1-D array written by :func:`pack_values`."""
    return unpack_rows(raw, (ChannelSelection(0, fmt, scale),))[:, 0]


def pack_rows(rows: np.ndarray, channels: tuple[ChannelSelection, ...]) -> tuple[bytes, bool]:
    """Encode an ``(n, n_channels)`` float array as packed records; returns bytes and a clipped flag."""
    rows = np.asarray(rows, dtype=float)
    out = np.empty(rows.shape[0], dtype=sample_dtype(channels))
    clipped = False
    for i, c in enumerate(channels):
        column = rows[:, i]
        fmt = Format(c.format)
        if fmt == Format.F32:
            out[f"c{i}"] = column
            continue
        info = np.iinfo(_NUMPY_FORMAT[fmt])
        counts = np.round(np.nan_to_num(column / c.scale, nan=0.0))
        if np.any((counts < info.min) | (counts > info.max)):
            clipped = True
            counts = np.clip(counts, info.min, info.max)
        out[f"c{i}"] = counts
    return out.tobytes(), clipped


def unpack_rows(raw: bytes, channels: tuple[ChannelSelection, ...]) -> np.ndarray:
    """Decode packed records into an ``(n, n_channels)`` float64 array in SI units."""
    if not channels:
        raise ProtocolError("sample data cannot be decoded without a channel selection")
    dtype = sample_dtype(channels)
    if len(raw) % dtype.itemsize:
        raise ProtocolError(f"sample data of {len(raw)} bytes is not a whole number of {dtype.itemsize}-byte rows")
    records = np.frombuffer(raw, dtype=dtype)
    rows = np.empty((len(records), len(channels)))
    for i, c in enumerate(channels):
        column = records[f"c{i}"].astype(float)
        rows[:, i] = column if Format(c.format) == Format.F32 else column * c.scale
    return rows


def encode(msg, seq: int, *, sample_channels: tuple[ChannelSelection, ...] = (), excitation=(Format.F32, 1.0)) -> bytes:
    """Payload (header + body, without framing) of ``msg`` numbered ``seq``.

    ``sample_channels`` is the current channel selection (needed for SAMPLES) and
    ``excitation`` the excitation ``(format, scale)`` (needed for EXCITATION).
    """
    kind, body = _encode_body(msg, sample_channels, excitation)
    return _HEADER.pack(PROTOCOL_VERSION, kind, seq & 0xFFFF) + body


def _encode_body(msg, sample_channels, excitation) -> tuple[int, bytes]:
    encoded = _encode_host_body(msg, excitation) or _encode_board_body(msg, sample_channels)
    if encoded is None:
        raise TypeError(f"not a protocol message: {msg!r}")
    return encoded


def _encode_host_body(msg, excitation) -> tuple[int, bytes] | None:
    """Type and body of a host -> board message; None for any other."""
    if isinstance(msg, Identify):
        return MsgType.IDENTIFY, b""
    if isinstance(msg, StatusRequest):
        return MsgType.STATUS_REQUEST, b""
    if isinstance(msg, ClearFault):
        return MsgType.CLEAR_FAULT, b""
    if isinstance(msg, Ping):
        return MsgType.PING, b""
    if isinstance(msg, Configure):
        body = struct.pack(
            "<HBHBfB",
            msg.sample_divider,
            msg.mode,
            msg.block_samples,
            msg.excitation_format,
            msg.excitation_scale,
            len(msg.channels),
        )
        body += b"".join(struct.pack("<BBf", c.channel, c.format, c.scale) for c in msg.channels)
        return MsgType.CONFIGURE, body
    if isinstance(msg, Limits):
        return MsgType.SET_LIMITS, struct.pack(
            "<ffff", msg.torque_nm, msg.velocity_mps, msg.position_min_m, msg.position_max_m
        )
    if isinstance(msg, Start):
        return MsgType.START, struct.pack("<I", msg.n_samples)
    if isinstance(msg, Stop):
        return MsgType.STOP, struct.pack("<B", msg.reason)
    if isinstance(msg, Excitation):
        raw, _ = pack_values(msg.values, *excitation)
        return MsgType.EXCITATION, struct.pack("<IH", msg.first_index, len(msg.values)) + raw
    if isinstance(msg, WriteFilter):
        return MsgType.WRITE_FILTER, _filter_body(msg.coefficients)
    if isinstance(msg, ReadFilter):
        return MsgType.READ_FILTER, struct.pack("<B", msg.slot)
    if isinstance(msg, ReadLoop):
        return MsgType.READ_LOOP, b""
    if isinstance(msg, WriteLoop):
        return MsgType.WRITE_LOOP, struct.pack("<4f", *(getattr(msg, f) for f in WRITE_LOOP_FIELDS))
    return None


def _encode_board_body(msg, sample_channels) -> tuple[int, bytes] | None:
    """Type and body of a board -> host message; None for any other."""
    if isinstance(msg, Identity):
        body = struct.pack(
            "<BffBI",
            msg.protocol_version,
            msg.loop_rate_hz,
            msg.max_sample_rate_hz,
            msg.filter_slots,
            msg.excitation_buffer_samples,
        )
        body += _string(msg.name) + _string(msg.firmware) + bytes([len(msg.channels)])
        body += b"".join(_string(c.name) + _string(c.unit) for c in msg.channels)
        return MsgType.IDENTITY, body
    if isinstance(msg, Ack):
        return MsgType.ACK, struct.pack("<HB", msg.acked_seq, msg.acked_type)
    if isinstance(msg, Nak):
        return MsgType.NAK, struct.pack("<HBB", msg.acked_seq, msg.acked_type, msg.error) + _string(msg.detail)
    if isinstance(msg, Samples):
        raw, _ = pack_rows(msg.data, sample_channels)
        head = struct.pack(
            "<IIHHIII",
            msg.block_index,
            msg.first_sample,
            len(msg.data),
            msg.flags,
            msg.excitation_consumed,
            msg.excitation_level,
            msg.underruns,
        )
        return MsgType.SAMPLES, head + raw
    if isinstance(msg, Status):
        return MsgType.STATUS, struct.pack(
            "<BHIIIIIII",
            msg.state,
            msg.fault,
            msg.excitation_level,
            msg.excitation_capacity,
            msg.underruns,
            msg.dropped_blocks,
            msg.samples_produced,
            msg.limit_trips,
            msg.rx_corrupt,
        )
    if isinstance(msg, FilterCoefficients):
        return MsgType.FILTER, _filter_body(msg)
    if isinstance(msg, Event):
        return MsgType.EVENT, struct.pack("<BIf", msg.code, msg.sample_index, msg.value) + _string(msg.message)
    if isinstance(msg, LoopParameters):
        return MsgType.LOOP, struct.pack("<6f", *(getattr(msg, f) for f in LOOP_FIELDS))
    return None


def _filter_body(c: FilterCoefficients) -> bytes:
    return struct.pack("<BB5f", c.slot, int(c.enabled), c.b[0], c.b[1], c.b[2], c.a[1], c.a[2])


def _decode_filter(r: _Reader) -> FilterCoefficients:
    slot, enabled, b0, b1, b2, a1, a2 = r.take("BB5f")
    return FilterCoefficients(slot, bool(enabled), (b0, b1, b2), (1.0, a1, a2))


@dataclass
class Header:
    """Decoded payload header."""

    version: int
    type: int
    seq: int


def decode(payload: bytes, *, sample_channels: tuple[ChannelSelection, ...] = (), excitation=(Format.F32, 1.0)):
    """Split a payload into its :class:`Header` and message object.

    Raises
    ------
    ProtocolError
        Unknown version or type, or a body of the wrong length.
    """
    if len(payload) < _HEADER.size:
        raise ProtocolError(f"payload of {len(payload)} bytes is shorter than the header")
    version, kind, seq = _HEADER.unpack_from(payload)
    header = Header(version, kind, seq)
    if version != PROTOCOL_VERSION:
        raise ProtocolError(f"protocol version {version} (this host speaks {PROTOCOL_VERSION})")
    try:
        mtype = MsgType(kind)
    except ValueError:
        raise ProtocolError(f"unknown message type 0x{kind:02x}") from None
    r = _Reader(payload[_HEADER.size :], mtype.name)
    msg = _decode_body(mtype, r, sample_channels, excitation)
    return header, msg


def _decode_body(mtype: MsgType, r: _Reader, sample_channels, excitation):
    msg = _decode_host_body(mtype, r, excitation)
    if msg is None:
        msg = _decode_board_body(mtype, r, sample_channels)
    if msg is None:  # pragma: no cover - every type is handled
        raise ProtocolError(f"no decoder for {mtype.name}")
    return msg


def _decode_host_body(mtype: MsgType, r: _Reader, excitation):
    """A host -> board message of type ``mtype``; None for a board -> host type."""
    simple = {
        MsgType.IDENTIFY: Identify,
        MsgType.STATUS_REQUEST: StatusRequest,
        MsgType.CLEAR_FAULT: ClearFault,
        MsgType.PING: Ping,
        MsgType.READ_LOOP: ReadLoop,
    }
    if mtype in simple:
        return simple[mtype]()
    if mtype == MsgType.CONFIGURE:
        divider, mode, block, exc_fmt, exc_scale, n = r.take("HBHBfB")
        channels = tuple(
            ChannelSelection(ch, _enum(Format, fmt, "format"), scale)
            for ch, fmt, scale in (r.take("BBf") for _ in range(n))
        )
        return Configure(
            divider, _enum(Mode, mode, "mode"), block, channels, _enum(Format, exc_fmt, "format"), exc_scale
        )
    if mtype == MsgType.SET_LIMITS:
        return Limits(*r.take("ffff"))
    if mtype == MsgType.START:
        return Start(*r.take("I"))
    if mtype == MsgType.STOP:
        return Stop(*r.take("B"))
    if mtype == MsgType.EXCITATION:
        first, n = r.take("IH")
        values = unpack_values(r.rest(), *excitation)
        if len(values) != n:
            raise ProtocolError(f"EXCITATION announces {n} values but carries {len(values)}")
        return Excitation(first, values)
    if mtype == MsgType.WRITE_FILTER:
        return WriteFilter(_decode_filter(r))
    if mtype == MsgType.READ_FILTER:
        return ReadFilter(*r.take("B"))
    if mtype == MsgType.WRITE_LOOP:
        return WriteLoop(*r.take("4f"))
    return None


def _decode_board_body(mtype: MsgType, r: _Reader, sample_channels):
    """A board -> host message of type ``mtype``; None for any other type."""
    if mtype == MsgType.IDENTITY:
        version, loop_rate, max_rate, slots, buffer_samples = r.take("BffBI")
        name, firmware = r.string(), r.string()
        (n,) = r.take("B")
        channels = tuple(ChannelInfo(r.string(), r.string()) for _ in range(n))
        return Identity(version, name, firmware, loop_rate, max_rate, slots, buffer_samples, channels)
    if mtype == MsgType.ACK:
        return Ack(*r.take("HB"))
    if mtype == MsgType.NAK:
        seq, kind, err = r.take("HBB")
        return Nak(seq, kind, _enum(ErrorCode, err, "error code"), r.string())
    if mtype == MsgType.SAMPLES:
        block, first, n, flags, consumed, level, underruns = r.take("IIHHIII")
        if not sample_channels:
            raise ProtocolError(f"SAMPLES block {block} arrived before any channel selection (no CONFIGURE yet)")
        data = unpack_rows(r.rest(), sample_channels)
        if len(data) != n:
            raise ProtocolError(f"SAMPLES block {block} announces {n} rows but carries {len(data)}")
        return Samples(block, first, flags, consumed, level, underruns, data)
    if mtype == MsgType.STATUS:
        state, fault, *rest = r.take("BHIIIIIII")
        return Status(_enum(State, state, "state"), _enum(FaultCode, fault, "fault"), *rest)
    if mtype == MsgType.FILTER:
        return _decode_filter(r)
    if mtype == MsgType.EVENT:
        code, index, value = r.take("BIf")
        return Event(_enum(EventCode, code, "event code"), index, value, r.string())
    if mtype == MsgType.LOOP:
        return LoopParameters(*r.take("6f"))
    return None


def _enum(cls, value, what):
    try:
        return cls(value)
    except ValueError:
        raise ProtocolError(f"unknown {what} {value}") from None


def float32(x: float) -> float:
    """``x`` rounded to IEEE single precision, as the board stores it."""
    return float(np.float32(x))
