"""The register map of a Modbus drive: parsing, value encodings, paged windows.

A Modbus drive is described by data (``drivers/<name>/driver.toml``, tables
``[modbus]``, ``[modbus.registers]``, ``[modbus.control]``, ``[modbus.status]``,
``[modbus.fault_codes]``, ``[modbus.modes]``, ``[modbus.table]``,
``[modbus.capture]``, ``[modbus.filters]`` and ``[filters]``). This module
parses that description into a :class:`RegisterMap` and converts between
physical values and 16-bit registers. The host adapter and the emulated drive
both use it, so they agree on the wire by construction.

Value types
-----------
``u16``, ``i16``
    One register, unsigned or two's complement.
``u32``, ``i32``, ``f32``; ``u64``, ``i64``, ``f64``
    Two (four) registers (IEEE-754 for the floats). ``word_order`` ``"big"``
    puts the most significant word at the lowest address, ``"little"`` the
    least significant. ``byte_order`` ``"big"`` sends each register high byte
    first, as Modbus does; ``"little"`` swaps the two bytes. Both are set per
    register, defaulting to ``[modbus] word_order`` / ``byte_order``.
``str``
    ``length`` registers, two ASCII characters each (first character in the
    high byte), NUL padded.

A physical value is ``raw * scale + offset``; ``min``/``max`` bound it (a
write outside is refused before it is sent, naming the register).

The map language
----------------
Each ``[modbus.registers]`` entry goes through the typed schema of
:mod:`hilident.config.tables` (:class:`_RegisterSpec`): ``address`` or ``parameter``
(a vendor code such as ``"P08.02"`` resolved by the rule of
``[modbus.parameters]``, :class:`ParameterRule`), ``type``, ``access``,
``table`` (holding or input), ``scale``, ``offset``, ``unit``, ``min``,
``max``, ``word_order``, ``byte_order``, ``channel``/``channel_scale`` (the
drive channel a feedback register shows), plus ``bits`` (named masks) and
``default`` (the value at power-up). Capabilities are tables of their own:
hilident's excitation table and capture (``[modbus.table]``,
``[modbus.capture]`` with the control/status registers they need; a map
without them describes a parameter drive, :attr:`RegisterMap.excitation`),
``[modbus.filters]`` (hilident's four-register slots, or ``slots`` naming the
drive's own notch parameters, :class:`FieldSlots`), ``[modbus.identity]``,
``[modbus.save]`` and ``[modbus.stop]``.

Paged windows
-------------
The excitation table and the capture buffer are longer than the 16-bit address
space allows. Each is shown through a window of ``page_samples`` samples at
``base``; a page register (``table_page``, ``capture_page``) selects which page
the window shows. Sample ``k`` lies on page ``k // page_samples`` at window
offset ``(k % page_samples) * registers_per_sample``. A capture record is a
``u16`` stamp (sample index modulo 65536) followed by the selected channels,
so a host can prove that every record it read is the one it asked for.

All functions are pure: values in, values out.

Examples
--------
>>> regs = encode_values([1.5, -2.0], "f32", word_order="little")
>>> [hex(r) for r in regs]
['0x0', '0x3fc0', '0x0', '0xc000']
>>> decode_values(regs, "f32", word_order="little").tolist()
[1.5, -2.0]
>>> [c.samples for c in plan_chunks(0, 130, 2, 1024, 123)]
[61, 61, 8]
"""

from __future__ import annotations

import binascii
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import ClassVar, NoReturn

import numpy as np

from hilident.config.schema import build_table
from hilident.config.schema import spec as _spec
from hilident.errors import ConfigError, DataError
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = [
    "EXCEPTION_MEANINGS",
    "TYPES",
    "CaptureChannel",
    "Chunk",
    "FilterSlots",
    "Register",
    "RegisterMap",
    "Window",
    "count_rtu_frames",
    "decode_string",
    "decode_values",
    "encode_string",
    "encode_values",
    "exception_meaning",
    "plan_chunks",
    "rtu_crc",
    "table_crc",
]

#: Registers per value and numpy type code of the numeric types.
TYPES: dict[str, tuple[int, str]] = {
    "u16": (1, "u2"),
    "i16": (1, "i2"),
    "u32": (2, "u4"),
    "i32": (2, "i4"),
    "f32": (2, "f4"),
    "u64": (4, "u8"),
    "i64": (4, "i8"),
    "f64": (4, "f8"),
}
WORD_ORDERS = ("big", "little")
BYTE_ORDERS = ("big", "little")
REGISTER_TABLES = ("holding", "input")
#: types of the excitation table and capture channels (one or two registers)
WINDOW_TYPES = ("u16", "i16", "u32", "i32", "f32")
MODES = ("torque", "torque_injection", "velocity", "position")

#: Meaning of each Modbus exception code (Modbus Application Protocol V1.1b3, section 7).
EXCEPTION_MEANINGS: dict[int, str] = {
    1: "illegal function: the drive does not offer this request",
    2: "illegal data address: no such register, or it is not writable",
    3: "illegal data value: the value is out of range or not allowed in this state",
    4: "server device failure: the drive could not carry out the request",
    5: "acknowledge: accepted, still being processed",
    6: "server device busy: try again later",
    7: "negative acknowledge",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}

#: Registers every Modbus drive map must name, with the types allowed for each.
REQUIRED_REGISTERS: dict[str, tuple[str, ...]] = {
    "device_type": ("u16",),
    "map_version": ("u16",),
    "loop_rate_hz": ("u16", "u32", "f32"),
    "max_sample_rate_hz": ("u16", "u32", "f32"),
    "filter_slots": ("u16",),
    "table_capacity": ("u16", "u32"),
    "capture_capacity": ("u16", "u32"),
    "device_name": ("str",),
    "firmware": ("str",),
    "control_word": ("u16",),
    "status_word": ("u16",),
    "fault_code": ("u16",),
    "sample_count": ("u16", "u32"),
    "fault_sample": ("u16", "u32"),
    "fault_value": ("f32",),
    "mode": ("u16",),
    "sample_divider": ("u16",),
    "capture_mask": ("u16",),
    "table_length": ("u16", "u32"),
    "table_page": ("u16",),
    "capture_page": ("u16",),
    "table_crc": ("u16",),
    "torque_limit_nm": ("f32",),
    "velocity_limit_mps": ("f32",),
    "position_min_m": ("f32",),
    "position_max_m": ("f32",),
}
WRITABLE = (
    "control_word",
    "mode",
    "sample_divider",
    "capture_mask",
    "table_length",
    "table_page",
    "capture_page",
    "torque_limit_nm",
    "velocity_limit_mps",
    "position_min_m",
    "position_max_m",
)
CONTROL_BITS = ("run", "fault_reset")
STATUS_BITS = ("enabled", "running", "done", "fault", "capture_stopped", "limits_loaded")
FAULT_NAMES = ("torque_limit", "velocity_limit", "position_limit", "drive_fault")
#: Registers a map may name, with the types allowed; the host uses each only when it is there.
#: ``comm_timeout_ms``: the drive's communication timeout (ms, 0 = off), the device-side stop for a host
#: that dies; a map that names it must also name ``[modbus.fault_codes] comm_timeout``.
OPTIONAL_REGISTERS: dict[str, tuple[str, ...]] = {"comm_timeout_ms": ("u16", "u32")}
OPTIONAL_FAULT_NAMES = {"comm_timeout": "comm_timeout_ms"}  # fault name -> the register it belongs to
FILTER_FIELDS = ("center", "width", "depth", "enable")
STAMP_MODULUS = 1 << 16


#: ``fail(key, message)`` raises the :class:`ConfigError` naming ``key`` and the driver file.
_Fail = Callable[[str, str], NoReturn]


def _fail_in(source: str) -> _Fail:
    def fail(key: str, message: str) -> NoReturn:
        raise ConfigError(key, message, source or None)

    return fail


def _optional_fault_codes(table: dict, registers: dict, required: dict, fail: _Fail) -> dict[str, int]:
    """The codes of the optional faults in ``[modbus.fault_codes]``, each required when its register is named."""
    out = {}
    for name, register in OPTIONAL_FAULT_NAMES.items():
        value = table.get(name)
        if value is None:
            if register in registers:
                fail(f"modbus.fault_codes.{name}", f"is required: the map names register {register}")
            continue
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 0xFFFF:
            fail(f"modbus.fault_codes.{name}", f"must be an integer in 1..65535, got {value!r}")
        if value in required.values():
            fail("modbus.fault_codes", "values must be distinct")
        out[name] = value
    return out


def exception_meaning(code: int) -> str:
    """What Modbus exception ``code`` means."""
    return EXCEPTION_MEANINGS.get(int(code), "not a standard Modbus exception code")


# --- value encodings ---------------------------------------------------------------------


def encode_values(
    values,
    type_: str,
    scale: float = 1.0,
    word_order: str = "big",
    saturate: bool = False,
    byte_order: str = "big",
    offset: float = 0.0,
) -> np.ndarray:
    """Registers holding ``values`` (physical units) as ``type_``.

    Parameters
    ----------
    values : array_like
        Physical values; raw = (values - offset) / scale (rounded to the
        nearest integer for the integer types).
    type_ : {"u16", "i16", "u32", "i32", "f32", "u64", "i64", "f64"}
    scale : float
        Physical value per raw unit.
    word_order : {"big", "little"}
        Multi-register types: ``"big"`` puts the most significant word first,
        ``"little"`` the least significant.
    saturate : bool
        Clip values beyond the type's range (and NaN to 0) instead of raising.
    byte_order : {"big", "little"}
        Byte order inside each register (``"big"``: as Modbus sends them).
    offset : float
        Physical value of raw 0.

    Returns
    -------
    ndarray of uint16
        ``len(values) * registers`` register values.

    Raises
    ------
    DataError
        A value does not fit the type (unless ``saturate``).
    """
    n_regs, code = _numeric(type_)
    exact = _exact_integers(values, code, scale, offset)
    if exact is not None:  # whole numbers into an unscaled integer type: no detour through float64
        info = np.iinfo(code)
        beyond = [v for v in exact if not info.min <= v <= info.max]
        if beyond and not saturate:
            raise DataError(f"value {beyond[0]} is beyond the {type_} range {info.min}..{info.max}")
        raw = np.array([min(max(v, int(info.min)), int(info.max)) for v in exact], dtype=">" + code)
        return _order_words(raw.view(">u2").reshape(-1, n_regs), word_order, byte_order)
    x = (np.asarray(values, dtype=float).ravel() - offset) / scale
    if code.startswith("f"):
        top = np.finfo(code).max
        big = np.abs(x) > top
        if np.any(big & np.isfinite(x)):
            if not saturate:
                raise DataError(f"value {x[big][0] * scale + offset:g} does not fit a float{8 * int(code[1])}")
            x = np.clip(x, -top, top)
        raw = x.astype(">" + code)
    else:
        info = np.iinfo(code)
        bad = ~np.isfinite(x)
        if np.any(bad):
            if not saturate:
                raise DataError(f"value {x[bad][0] * scale!r} cannot be stored as {type_}")
            x = np.where(bad, 0.0, x)
        q = np.rint(x)
        # float64 cannot hold every 64-bit integer: compare against the limits as floats, clip below them
        out = (q < float(info.min)) | (q >= float(info.max) + 1.0)
        if np.any(out):
            if not saturate:
                raise DataError(
                    f"value {q[out][0] * scale + offset:g} is beyond the {type_} range "
                    f"{info.min * scale + offset:g}..{info.max * scale + offset:g} (scale {scale:g})"
                )
            q = np.clip(q, float(info.min), np.nextafter(float(info.max) + 1.0, 0.0))
        raw = q.astype(">" + code)
    return _order_words(raw.view(">u2").reshape(-1, n_regs), word_order, byte_order)


def _exact_integers(values, code: str, scale: float, offset: float) -> list[int] | None:
    """``values`` as Python ints when they are all integers going into an unscaled integer type, else None."""
    if (
        code.startswith("f")
        or scale != 1.0
        or offset != 0.0
        or (isinstance(values, np.ndarray) and values.dtype.kind not in "iuO")
    ):
        return None
    items = list(np.asarray(values, dtype=object).ravel())
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) for v in items):
        return None
    return [int(v) for v in items]


def _order_words(words: np.ndarray, word_order: str, byte_order: str) -> np.ndarray:
    """Big-endian words of each value (one row per value) in the register order and byte order asked for;
    the same operation undoes itself."""
    words = np.asarray(words, dtype=np.uint16)
    if word_order == "little" and words.shape[1] > 1:
        words = words[:, ::-1]
    if byte_order == "little":
        words = (words >> 8) | ((words & 0xFF) << 8)
    return words.astype(np.uint16).ravel()


def decode_values(
    registers, type_: str, scale: float = 1.0, word_order: str = "big", byte_order: str = "big", offset: float = 0.0
) -> np.ndarray:
    """Physical values held in ``registers`` as ``type_`` (inverse of :func:`encode_values`).

    Raises
    ------
    DataError
        The number of registers is not a multiple of the type's size.
    """
    n_regs, code = _numeric(type_)
    r = np.asarray(registers, dtype=np.int64).ravel()
    if len(r) % n_regs:
        raise DataError(f"{len(r)} registers do not hold whole {type_} values")
    if np.any((r < 0) | (r > 0xFFFF)):
        raise DataError("register values must lie in 0..65535")
    words = _order_words(r.reshape(-1, n_regs), word_order, byte_order).reshape(-1, n_regs)
    raw = np.ascontiguousarray(words).astype(">u2").view(">" + code).ravel()
    return raw.astype(float) * scale + offset


def encode_string(text: str, length: int) -> np.ndarray:
    """``length`` registers holding ASCII ``text`` (NUL padded; too long raises DataError)."""
    data = text.encode("ascii", errors="replace")
    if len(data) > 2 * length:
        raise DataError(f"{text!r} does not fit {length} registers ({2 * length} characters)")
    data = data.ljust(2 * length, b"\0")
    return np.frombuffer(data, dtype=">u2").astype(np.uint16)


def decode_string(registers) -> str:
    """The ASCII text in ``registers`` up to the first NUL."""
    data = np.asarray(registers, dtype=np.int64).astype(">u2").tobytes()
    return data.split(b"\0", 1)[0].decode("ascii", errors="replace")


def table_crc(registers) -> int:
    """CRC-16/CCITT-FALSE (polynomial 0x1021, initial value 0xFFFF) of ``registers`` sent big-endian.

    The drive reports it in ``table_crc`` so the host can prove the whole table
    arrived before it starts a run.
    """
    data = np.asarray(registers, dtype=np.int64).astype(">u2").tobytes()
    return binascii.crc_hqx(data, 0xFFFF)


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


def _numeric(type_: str) -> tuple[int, str]:
    try:
        return TYPES[type_]
    except KeyError:
        raise DataError(f"{type_!r} is not a numeric register type ({', '.join(TYPES)})") from None


# --- chunk planning ----------------------------------------------------------------------


@dataclass(frozen=True)
class Chunk:
    """One request of a paged transfer.

    Attributes
    ----------
    page : int
        Page to select before the request.
    offset : int
        Register offset of the request within the window.
    first_sample, samples : int
        Samples the request carries.
    count : int
        Registers the request carries.
    """

    page: int
    offset: int
    first_sample: int
    samples: int
    count: int


def plan_chunks(
    first_sample: int, n_samples: int, registers_per_sample: int, page_samples: int, max_registers: int
) -> list[Chunk]:
    """Requests that move samples ``first_sample .. first_sample + n_samples - 1`` through a paged window.

    Each request carries whole samples, at most ``max_registers`` registers,
    and stays on one page.

    Raises
    ------
    ConfigError
        One sample does not fit in one request.
    """
    per_request = max_registers // registers_per_sample
    if per_request < 1:
        raise ConfigError(
            "modbus.max_registers",
            f"a sample of {registers_per_sample} registers does not fit a request of {max_registers}",
        )
    chunks = []
    k, end = int(first_sample), int(first_sample) + int(n_samples)
    while k < end:
        page, within = divmod(k, page_samples)
        m = min(per_request, page_samples - within, end - k)
        chunks.append(Chunk(page, within * registers_per_sample, k, m, m * registers_per_sample))
        k += m
    return chunks


# --- the map -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Register:
    """One named value of the map.

    Attributes
    ----------
    name : str
    address : int
        First register (0-based protocol address).
    type : str
        One of :data:`TYPES` or ``str``.
    access : {"r", "rw"}
    scale, offset : float
        Physical value = raw value * scale + offset.
    count : int
        Registers it occupies.
    word_order, byte_order : {"big", "little"}
        Order of the words of a multi-register value, and of the bytes inside each register.
    table : {"holding", "input"}
        Input registers are read with function 4 and never written.
    unit : str
        Unit of the physical value (for messages and documents).
    minimum, maximum : float or None
        Range of the physical value; a write outside it is refused before it is sent.
    bits : dict
        Named bit fields: name to mask (for flags and small fields inside one register).
    parameter : str
        The vendor's parameter code (``"P08.02"``) when the address came from the parameter rule.
    channel : str
        The drive channel the register shows (feedback), with ``channel_scale`` SI units per physical unit.
    default : float, str or None
        Value at power-up (the vendor's default; the emulated drive starts with it).
    """

    name: str
    address: int
    type: str
    access: str = "r"
    scale: float = 1.0
    count: int = 1
    word_order: str = "big"
    byte_order: str = "big"
    table: str = "holding"
    offset: float = 0.0
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    bits: dict = field(default_factory=dict, compare=False, hash=False)
    parameter: str = ""
    channel: str = ""
    channel_scale: float = 1.0
    default: float | str | None = None

    @property
    def end(self) -> int:
        """One past the last register."""
        return self.address + self.count

    @property
    def writable(self) -> bool:
        return self.access == "rw" and self.table == "holding"

    @property
    def label(self) -> str:
        """``name`` with its parameter code, for messages."""
        return f"{self.name}, {self.parameter}" if self.parameter and self.parameter != self.name else self.name

    def check_range(self, value) -> None:
        """DataError when the physical ``value`` lies outside ``minimum .. maximum`` (naming the register)."""
        if self.type == "str" or (self.minimum is None and self.maximum is None):
            return
        x = float(value)
        low = -math.inf if self.minimum is None else self.minimum
        high = math.inf if self.maximum is None else self.maximum
        if not low <= x <= high:
            unit = f" {self.unit}" if self.unit else ""
            raise DataError(
                f"register {self.address:#06x} ({self.label}): {x:g}{unit} is outside its range {low:g}..{high:g}{unit}"
            )

    def encode(self, value) -> list[int]:
        """The registers holding the physical ``value`` (DataError naming the register when it does not fit)."""
        if self.type == "str":
            return encode_string(str(value), self.count).tolist()
        self.check_range(value)
        try:
            return encode_values(
                [value], self.type, self.scale, self.word_order, byte_order=self.byte_order, offset=self.offset
            ).tolist()
        except DataError as exc:
            raise DataError(f"register {self.address} ({self.label}): {exc}") from None

    def decode(self, registers) -> float | int | str:
        """The physical value ``registers`` hold (an int for unscaled integer types)."""
        if self.type == "str":
            return decode_string(registers)
        value = float(decode_values(registers, self.type, self.scale, self.word_order, self.byte_order, self.offset)[0])
        exact = not self.type.startswith("f") and self.scale == 1.0 and self.offset == 0.0
        if exact and self.type in ("u64", "i64"):  # beyond float64's 53 bits: from the words themselves
            data = (
                _order_words(np.asarray(registers, dtype=np.int64).reshape(1, -1), self.word_order, self.byte_order)
                .astype(">u2")
                .tobytes()
            )
            return int.from_bytes(data, "big", signed=self.type == "i64")
        return int(value) if exact else value

    def bit_field(self, name: str, registers) -> int:
        """The value of bit field ``name`` (shifted down to its lowest bit)."""
        mask = self.bits[name]
        word = int(self.decode(registers)) if self.type != "str" else 0
        return (word & mask) >> ((mask & -mask).bit_length() - 1)


@dataclass(frozen=True, kw_only=True)
class _RegisterSpec:
    """One ``[modbus.registers]`` entry, validated by the typed schema of :mod:`hilident.config.tables`."""

    address: int = _spec(-1, ge=-1, le=65535, doc="0-based protocol address; -1: from `parameter` and the rule")
    parameter: str = _spec("", doc='vendor parameter code resolved by [modbus.parameters] (e.g. "P08.02")')
    type: str = _spec(choices=(*TYPES, "str"))
    access: str = _spec("r", choices=("r", "rw"))
    table: str = _spec("holding", choices=REGISTER_TABLES)
    scale: float = _spec(1.0, doc="physical units per raw unit (non-zero)")
    offset: float = _spec(0.0, doc="physical value of raw 0")
    unit: str = _spec("")
    min: float | None = _spec(None, doc="smallest physical value (writes below it are refused)")
    max: float | None = _spec(None, doc="largest physical value")
    length: int = _spec(1, ge=1, le=125, doc="str: registers")
    word_order: str = _spec("", choices=("", *WORD_ORDERS), doc="default: [modbus] word_order")
    byte_order: str = _spec("", choices=("", *BYTE_ORDERS), doc="default: [modbus] byte_order")
    channel: str = _spec("", doc="drive channel the register shows")
    channel_scale: float = _spec(1.0, doc="SI units of the channel per physical unit")
    description: str = _spec("")


@dataclass(frozen=True)
class ParameterRule:
    """Parameter addressing: ``address = group * group_factor + index * index_factor + base``.

    A rule is written as in the vendor's manual, ``"group * 0x100 + index"`` or
    ``"group * 256 + 2 * index"``: a sum of terms, each an integer, ``group``,
    ``index``, or an integer times one of them (decimal or ``0x`` hex). It is
    parsed, never evaluated as code. Parameter codes are ``<prefix><group>.<index>``
    (``P08.02``: group 8, index 2), both decimal.

    >>> rule = ParameterRule.parse("group * 0x100 + index")
    >>> hex(rule.address_of("P08.02")), rule.code(0x1201)
    ('0x802', 'P18.01')
    """

    group_factor: int
    index_factor: int
    base: int = 0
    prefix: str = "P"
    text: str = ""

    @classmethod
    def parse(cls, text, prefix: str = "P", key: str = "modbus.parameters.address", source: str = "") -> ParameterRule:
        """Read a rule; ConfigError naming ``key`` when it is not a sum of the allowed terms."""

        def bad(why: str) -> NoReturn:
            raise ConfigError(
                key,
                f"{why} in {text!r}; write it as a sum of terms such as "
                '"group * 0x100 + index" or "group * 256 + 2 * index"',
                source or None,
            )

        if not isinstance(text, str) or not text.strip() or len(text) > 200:
            bad("a rule must be a short string")
        factors = {"group": 0, "index": 0, "": 0}
        number = r"(?:0[xX][0-9a-fA-F]+|\d+)"
        term = re.compile(
            rf"^(?:({number})\s*\*\s*(group|index)|(group|index)\s*\*\s*({number})|"
            rf"(group|index)|({number}))$"
        )
        for raw in text.split("+"):
            m = term.match(raw.strip())
            if not m:
                bad(f"{raw.strip()!r} is not a term (an integer, group, index, or an integer times one of them)")
            n1, v1, v2, n2, v3, n3 = m.groups()
            name = v1 or v2 or v3 or ""
            factors[name] += int(n1 or n2 or n3 or "1", 0)
        if not factors["group"] or not factors["index"]:
            bad("the rule must use both group and index")
        return cls(factors["group"], factors["index"], factors[""], prefix, text)

    def split(self, code: str) -> tuple[int, int]:
        """``(group, index)`` of a parameter code; DataError when it is not one."""
        m = re.fullmatch(rf"{re.escape(self.prefix)}(\d{{1,3}})\.(\d{{1,3}})", code or "")
        if not m:
            raise DataError(f"{code!r} is not a parameter code ({self.prefix}<group>.<index>, e.g. {self.prefix}08.02)")
        return int(m.group(1)), int(m.group(2))

    def address_of(self, code: str) -> int:
        """The protocol address of parameter ``code`` (DataError beyond the 16-bit address space)."""
        group, index = self.split(code)
        address = group * self.group_factor + index * self.index_factor + self.base
        if not 0 <= address <= 0xFFFF:
            raise DataError(f"parameter {code} gives address {address}, outside 0..65535 ({self.text})")
        return address

    def code(self, address: int) -> str | None:
        """The parameter code at ``address``, or None when the rule gives no parameter there."""
        rest = address - self.base
        group, rest = divmod(rest, self.group_factor)
        index, left = divmod(rest, self.index_factor)
        if left or group < 0 or index < 0 or index * self.index_factor >= self.group_factor:
            return None
        return f"{self.prefix}{group:02d}.{index:02d}"


@dataclass(frozen=True)
class Window:
    """A paged window onto a buffer longer than the address space.

    Attributes
    ----------
    name : {"table", "capture"}
    base : int
        Address of the window's first register.
    page_samples : int
        Samples per page.
    capacity_samples : int
        Samples the drive's buffer holds (the emulated drive's size; a host
        reads the ``*_capacity`` register).
    registers : int
        Size of the window in registers.
    page_register : str
        Register that selects the page.
    """

    name: str
    base: int
    page_samples: int
    capacity_samples: int
    registers: int
    page_register: str

    @property
    def end(self) -> int:
        return self.base + self.registers

    @property
    def pages(self) -> int:
        return -(-self.capacity_samples // self.page_samples)


@dataclass(frozen=True)
class CaptureChannel:
    """One channel of a capture record: name, on-wire type and scale; ``bit`` in ``capture_mask``."""

    name: str
    type: str
    scale: float
    bit: int

    @property
    def count(self) -> int:
        return TYPES[self.type][0]


@dataclass(frozen=True)
class FilterSlots:
    """Where filter slot ``i`` lives: registers ``base + i * stride + offsets[field]``."""

    base: int
    stride: int
    slots: int
    offsets: dict[str, int] = field(default_factory=dict)

    @property
    def span(self) -> int:
        """Registers read or written per slot (the four fields, contiguous)."""
        return len(FILTER_FIELDS)

    def address(self, slot: int) -> int:
        if not 0 <= slot < self.slots:
            raise DataError(f"filter slot {slot} does not exist (the drive has {self.slots})")
        return self.base + slot * self.stride

    def slot_at(self, address: int) -> int | None:
        """Slot whose field registers contain ``address``, else None."""
        if address < self.base:
            return None
        slot, offset = divmod(address - self.base, self.stride)
        return slot if slot < self.slots and offset < self.span else None

    @property
    def end(self) -> int:
        return self.base + (self.slots - 1) * self.stride + self.span if self.slots else self.base


@dataclass(frozen=True)
class FieldSlots:
    """Filter slots whose fields are named registers of the map (a vendor's notch parameters).

    Attributes
    ----------
    registers : tuple of dict
        Per slot, field name (``center``, ``width``, ``depth``, ... of the
        encoding, and ``enable`` when the drive has one) to its :class:`Register`.
    off : dict
        Drives without an enable register: the field and stored integer that
        bypass the slot (``{"center": 4000}``); the other fields keep their values.
    """

    registers: tuple
    off: dict = field(default_factory=dict, hash=False, compare=False)

    @property
    def slots(self) -> int:
        return len(self.registers)

    @property
    def has_enable(self) -> bool:
        return bool(self.registers) and "enable" in self.registers[0]

    def fields(self, slot: int) -> dict:
        """Field name to :class:`Register` of ``slot`` (DataError when there is no such slot)."""
        if not 0 <= slot < self.slots:
            raise DataError(f"filter slot {slot} does not exist (the drive has {self.slots})")
        return self.registers[slot]

    def address(self, slot: int) -> int:
        """The lowest address of the slot's fields."""
        return min(r.address for r in self.fields(slot).values())

    def slot_at(self, address: int) -> int | None:
        for i, regs in enumerate(self.registers):
            if any(r.address <= address < r.end for r in regs.values()):
                return i
        return None


def _parse_rule(mb: dict, source: str) -> ParameterRule:
    """``[modbus.parameters]``: ``address`` (the rule) and ``prefix`` of the parameter codes."""
    fail = _fail_in(source)
    table = mb["parameters"]
    if not isinstance(table, dict):
        fail("modbus.parameters", "must be a table {address, prefix}")
    unknown = set(table) - {"address", "prefix"}
    if unknown:
        fail(f"modbus.parameters.{sorted(unknown)[0]}", "unknown key (known here: address, prefix)")
    prefix = table.get("prefix", "P")
    if not isinstance(prefix, str) or not re.fullmatch(r"[A-Za-z]{0,8}", prefix):
        fail("modbus.parameters.prefix", f"must be up to 8 letters, got {prefix!r}")
    if "address" not in table:
        fail("modbus.parameters.address", 'is required (e.g. "group * 0x100 + index")')
    return ParameterRule.parse(table["address"], prefix, "modbus.parameters.address", source)


def _parse_registers(
    table: dict, rule: ParameterRule | None, word_order: str, byte_order: str, source: str
) -> dict[str, Register]:
    """``[modbus.registers]``: each entry through the typed schema, plus ``bits`` and ``default``."""
    return {name: _parse_register(name, raw, rule, word_order, byte_order, source) for name, raw in table.items()}


def _parse_register(
    name: str, raw, rule: ParameterRule | None, word_order: str, byte_order: str, source: str
) -> Register:
    """One ``[modbus.registers]`` entry; ``word_order`` and ``byte_order`` are the map's defaults."""
    fail = _fail_in(source)
    key = f"modbus.registers.{name}"
    if not isinstance(raw, dict):
        fail(key, "must be a table {address, type, access}")
    spec = build_table(_RegisterSpec, {k: v for k, v in raw.items() if k not in ("bits", "default")}, key + ".", source)
    if spec.scale == 0:
        fail(f"{key}.scale", "must be a non-zero finite number, got 0")
    count = spec.length if spec.type == "str" else TYPES[spec.type][0]
    code, address = _register_address(name, spec, rule, key, fail)
    if address + count > 65536:
        fail(f"{key}.address", f"{count} registers from {address} leave the 16-bit address space")
    if spec.table == "input" and spec.access == "rw":
        fail(f"{key}.access", 'an input register is read only: "r"')
    if spec.min is not None and spec.max is not None and spec.min > spec.max:
        fail(f"{key}.min", f"{spec.min:g} is above max {spec.max:g}")
    register = Register(
        name,
        address,
        spec.type,
        spec.access,
        spec.scale,
        count,
        spec.word_order or word_order,
        spec.byte_order or byte_order,
        spec.table,
        spec.offset,
        spec.unit,
        spec.min,
        spec.max,
        _parse_bits(raw.get("bits", {}), spec.type, count, f"{key}.bits", fail),
        code,
        spec.channel,
        spec.channel_scale,
        None,
    )
    if "default" in raw:
        register = replace(register, default=_register_default(register, raw["default"], key, fail))
    return register


def _register_address(
    name: str, spec: _RegisterSpec, rule: ParameterRule | None, key: str, fail: _Fail
) -> tuple[str, int]:
    """The parameter code and address of a register: ``address``, else its code through the rule (they must agree)."""
    code, address = spec.parameter, spec.address
    if address < 0:
        code = code or name
        if rule is None:
            fail(f"{key}.address", "is required (or a parameter code with a [modbus.parameters] rule)")
        try:
            return code, rule.address_of(code)
        except DataError as exc:
            fail(f"{key}.parameter" if spec.parameter else f"{key}.address", str(exc))
    if code and rule is not None:
        try:
            where = rule.address_of(code)
        except DataError as exc:
            fail(f"{key}.parameter", str(exc))
        if where != address:
            fail(f"{key}.address", f"{address:#06x} is not where {rule.text!r} puts {code}")
    return code, address


def _register_default(register: Register, default: float | str, key: str, fail: _Fail) -> float | str:
    """``default``: the register's value at power-up, of its kind and within what it encodes."""
    is_str = register.type == "str"
    if isinstance(default, bool) or not isinstance(default, (int, float, str)) or isinstance(default, str) != is_str:
        fail(f"{key}.default", f"must be a {'string' if is_str else 'number'}, got {default!r}")
    try:
        register.encode(default)
    except DataError as exc:
        fail(f"{key}.default", str(exc))
    return default


def _parse_bits(bits, type_: str, count: int, key: str, fail: _Fail) -> dict[str, int]:
    """``bits = { name = mask }``: masks of an integer register, non-zero, within its width."""
    if not isinstance(bits, dict):
        fail(key, f"must be a table {{name = mask}}, got {bits!r}")
    if bits and (type_ == "str" or type_.startswith("f")):
        fail(key, f"bit fields need an integer type, not {type_}")
    out = {}
    for name, mask in bits.items():
        if isinstance(mask, bool) or not isinstance(mask, int) or not 0 < mask < 1 << (16 * count):
            fail(f"{key}.{name}", f"must be a non-zero mask within {16 * count} bits, got {mask!r}")
        out[name] = mask
    return out


def _check_required(registers: dict[str, Register], fail: _Fail) -> None:
    """A map with the excitation capability names every register of hilident's table-and-capture protocol."""
    for name, types in REQUIRED_REGISTERS.items():
        if name not in registers:
            fail(f"modbus.registers.{name}", "is required")
        if registers[name].type not in types:
            fail(f"modbus.registers.{name}.type", f"must be one of {types}, got {registers[name].type!r}")
    for name in WRITABLE:
        if not registers[name].writable:
            fail(f"modbus.registers.{name}.access", 'must be "rw": the host writes it')
    for name, types in OPTIONAL_REGISTERS.items():
        if name in registers and registers[name].type not in types:
            fail(f"modbus.registers.{name}.type", f"must be one of {types}, got {registers[name].type!r}")
        if name in registers and not registers[name].writable:
            fail(f"modbus.registers.{name}.access", 'must be "rw": the host writes it')


def _named_register(
    value, registers: dict[str, Register], rule: ParameterRule | None, key: str, fail: _Fail
) -> Register:
    """A register of the map by name, or by parameter code through the rule (a ``u16`` holding register)."""
    if not isinstance(value, str):
        fail(key, f"must name a register or a parameter code, got {value!r}")
    if value in registers:
        return registers[value]
    for r in registers.values():
        if r.parameter == value:
            return r
    if rule is None:
        fail(key, f"{value!r} is no register of [modbus.registers]")
    try:
        return Register(value, rule.address_of(value), "u16", "rw", parameter=value)
    except DataError as exc:
        fail(key, f"{value!r} is no register of [modbus.registers], nor a parameter: {exc}")


def _parse_field_slots(
    ft: dict,
    encoding: FilterEncoding,
    registers: dict[str, Register],
    rule: ParameterRule | None,
    filter_slots: int,
    fail: _Fail,
) -> FieldSlots:
    """``[modbus.filters]`` with ``slots = [{center = ..., width = ..., depth = ...}]`` and ``off`` or ``enable``."""
    if encoding.kind == "word_block" or encoding.kind not in (
        "notch_parameters",
        "index_table",
        "pole_zero_q",
        "pole_zero_damping",
        "center_band",
    ):
        fail("filters.encoding", f"filter slots of named registers hold notch parameters, not {encoding.kind!r}")
    unknown = set(ft) - {"slots", "off"}
    if unknown:
        fail(f"modbus.filters.{sorted(unknown)[0]}", "unknown key (known with slots: slots, off)")
    raw = ft["slots"]
    if not isinstance(raw, list) or len(raw) != filter_slots:
        fail(
            "modbus.filters.slots",
            f"must list board.filter_slots = {filter_slots} slot(s), got "
            f"{len(raw) if isinstance(raw, list) else raw!r}",
        )
    slots = [
        _field_slot(f"modbus.filters.slots[{i}]", entry, encoding, registers, rule, fail) for i, entry in enumerate(raw)
    ]
    off = ft.get("off", {})
    has_enable = bool(slots) and "enable" in slots[0]
    if not isinstance(off, dict) or (not has_enable and len(off) != 1) or set(off) - set(encoding.fields):
        fail(
            "modbus.filters.off",
            "slots without an enable register need off = {field = stored value} "
            f"for one of {', '.join(encoding.fields)}: the value that bypasses the slot",
        )
    for name, value in off.items():
        if isinstance(value, bool) or not isinstance(value, int):
            fail(f"modbus.filters.off.{name}", f"must be the stored integer, got {value!r}")
    return FieldSlots(tuple(slots), dict(off))


def _field_slot(
    key: str, entry, encoding: FilterEncoding, registers: dict[str, Register], rule: ParameterRule | None, fail: _Fail
) -> dict[str, Register]:
    """One slot: the numeric read-write holding register of each field of the encoding (and optionally enable)."""
    names = (*encoding.fields, "enable")
    if not isinstance(entry, dict) or set(entry) - set(names) or not set(encoding.fields) <= set(entry):
        fail(key, f"must name the register of each of {', '.join(encoding.fields)} (and optionally enable)")
    regs = {}
    for name in entry:
        r = _named_register(entry[name], registers, rule, f"{key}.{name}", fail)
        if r.type == "str" or r.table != "holding" or r.access != "rw":
            fail(f"{key}.{name}", f"{r.label} must be a numeric read-write holding register")
        regs[name] = r
    return regs


def _parse_identity(mb: dict, registers: dict, excitation: bool, fail: _Fail) -> tuple[tuple[str, ...], dict]:
    """``[modbus.identity]``: registers read at connect (``registers``) and values they must hold (``expect``)."""
    table = mb.get("identity")
    if table is None:
        if not excitation:
            fail(
                "modbus.identity",
                "table is required: the registers that identify the drive "
                '(registers = ["motor_model", "software_version"])',
            )
        return (), {}
    if not isinstance(table, dict) or set(table) - {"registers", "expect"}:
        fail("modbus.identity", "must be a table {registers, expect}")
    names = table.get("registers", [])
    if not isinstance(names, list) or not names or any(n not in registers for n in names):
        fail("modbus.identity.registers", f"must list registers of [modbus.registers], got {names!r}")
    expect = table.get("expect", {})
    if not isinstance(expect, dict):
        fail("modbus.identity.expect", "must be a table {register = value}")
    for name, value in expect.items():
        if name not in names:
            fail(f"modbus.identity.expect.{name}", "must be one of modbus.identity.registers")
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            fail(f"modbus.identity.expect.{name}", f"must be a number or a string, got {value!r}")
    return tuple(names), dict(expect)


def _parse_save(
    mb: dict, registers: dict[str, Register], rule: ParameterRule | None, fail: _Fail
) -> tuple[str, float] | None:
    """``[modbus.save]``: the register (or parameter) written to store the parameters, and the value."""
    table = mb.get("save")
    if table is None:
        return None
    if not isinstance(table, dict) or set(table) != {"register", "value"}:
        fail("modbus.save", "must be a table {register, value}")
    r = _named_register(table["register"], registers, rule, "modbus.save.register", fail)
    if r.name not in registers:
        registers[r.name] = r
    if not r.writable:
        fail("modbus.save.register", f"{r.label} must be a read-write holding register")
    value = table["value"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        fail("modbus.save.value", f"must be a number, got {value!r}")
    return r.name, value


def _parse_stop(mb: dict, registers: dict, fail: _Fail) -> dict:
    """``[modbus.stop]``: register values that bring the axis to a stop (written at connect and on every ending)."""
    table = mb.get("stop", {})
    if not isinstance(table, dict):
        fail("modbus.stop", "must be a table {register = value}")
    for name, value in table.items():
        if name not in registers or not registers[name].writable:
            fail(f"modbus.stop.{name}", "must name a read-write holding register of [modbus.registers]")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            fail(f"modbus.stop.{name}", f"must be a number, got {value!r}")
    return dict(table)


# --- the [modbus] tables ----------------------------------------------------------------------


def _non_zero(value, key, source):
    if value == 0:
        raise ConfigError(key, f"must be a non-zero finite number, got {value!r}", source or None)


@dataclass(frozen=True, kw_only=True)
class _ModbusTable:
    """The scalar keys of ``[modbus]``; its sub-tables are read by the functions below."""

    open_table: ClassVar[bool] = True  # registers, parameters, table, capture, filters, identity, save, stop, ...
    word_order: str = _spec("big", choices=WORD_ORDERS, doc="order of the words of a 32-bit value")
    byte_order: str = _spec("big", choices=BYTE_ORDERS, doc="order of the bytes in a word")
    max_read_registers: int = _spec(125, ge=1, le=125, doc="most registers one read request asks for")
    max_write_registers: int = _spec(123, ge=1, le=123, doc="most registers one write request carries")
    map_version: int | None = _spec(None, ge=0, le=0xFFFF, doc="excitation maps: the map version register's value")
    device_type: int | None = _spec(None, ge=0, le=0xFFFF, doc="excitation maps: the device type register's value")

    def identity_code(self, name: str, excitation: bool, source: str) -> int:
        """``map_version`` or ``device_type``: required by an excitation map, else 0 when not given."""
        value = getattr(self, name)
        if value is None and excitation:
            raise ConfigError(f"modbus.{name}", "is required", source or None)
        return 0 if value is None else value


@dataclass(frozen=True, kw_only=True)
class _WindowTable:
    """``[modbus.table]`` and ``[modbus.capture]``: a paged window onto a buffer."""

    open_table: ClassVar[bool] = True  # [modbus.table] type and scale, [[modbus.capture.channels]]
    base: int = _spec(ge=0, le=65535, doc="address of the window")
    page_samples: int = _spec(ge=1, le=65535, doc="samples the window shows")
    capacity_samples: int = _spec(65536, ge=1, le=2**32 - 1, doc="length of the buffer, samples")


@dataclass(frozen=True, kw_only=True)
class _TableType:
    """``[modbus.table]`` type and scale of the excitation samples."""

    open_table: ClassVar[bool] = True
    type: str = _spec("f32", choices=WINDOW_TYPES)
    scale: float = _spec(1.0, check=_non_zero, doc="physical units per raw unit")


@dataclass(frozen=True, kw_only=True)
class _CaptureChannelTable:
    """One ``[[modbus.capture.channels]]`` entry."""

    open_table: ClassVar[bool] = True
    name: str = _spec()
    type: str = _spec(choices=WINDOW_TYPES)
    scale: float = _spec(1.0, check=_non_zero)


@dataclass(frozen=True)
class _ExcitationProtocol:
    """hilident's table-and-capture protocol of a map (all empty for a parameter drive, which has none)."""

    control: dict[str, int] = field(default_factory=dict)
    status: dict[str, int] = field(default_factory=dict)
    fault_codes: dict[str, int] = field(default_factory=dict)
    modes: dict[str, int] = field(default_factory=dict)
    table: Window | None = None
    table_type: str = "f32"
    table_scale: float = 1.0
    capture: Window | None = None
    capture_channels: tuple[CaptureChannel, ...] = ()


def _subtable(parent: dict, key: str, prefix: str, fail: _Fail) -> dict:
    value = parent.get(key)
    if not isinstance(value, dict):
        fail(f"{prefix}.{key}" if prefix else key, "table is required")
    return value


def _codes(mb: dict, key: str, names, bits: bool, fail: _Fail) -> dict[str, int]:
    """``[modbus.<key>]``: a distinct 16-bit code (a single bit when ``bits``) for each of ``names``."""
    table = _subtable(mb, key, "modbus", fail)
    out = {}
    for name in names:
        value = table.get(name)
        if value is None:
            fail(f"modbus.{key}.{name}", "is required")
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 0xFFFF:
            fail(f"modbus.{key}.{name}", f"must be an integer in 1..65535, got {value!r}")
        if bits and value & (value - 1):
            fail(f"modbus.{key}.{name}", f"must be a single bit, got {value:#x}")
        out[name] = value
    if len(set(out.values())) != len(out):
        fail(f"modbus.{key}", "values must be distinct")
    return out


def _parse_excitation(mb: dict, registers: dict[str, Register], source: str) -> _ExcitationProtocol:
    """hilident's table-and-capture protocol: control/status/fault/mode codes, the table and the capture."""
    fail = _fail_in(source)
    _check_required(registers, fail)
    control = _codes(mb, "control", CONTROL_BITS, True, fail)
    status = _codes(mb, "status", STATUS_BITS, True, fail)
    fault_codes = _codes(mb, "fault_codes", FAULT_NAMES, False, fail)
    fault_codes.update(_optional_fault_codes(mb["fault_codes"], registers, fault_codes, fail))
    modes = _codes(mb, "modes", MODES, False, fail)
    tb = _subtable(mb, "table", "modbus", fail)
    kind = build_table(_TableType, tb, "modbus.table.", source)
    window = build_table(_WindowTable, tb, "modbus.table.", source)
    table = Window(
        "table",
        window.base,
        window.page_samples,
        window.capacity_samples,
        window.page_samples * TYPES[kind.type][0],
        "table_page",
    )
    capture, channels = _parse_capture(_subtable(mb, "capture", "modbus", fail), source)
    for w in (table, capture):
        if w.end > 65536:
            fail(f"modbus.{w.name}.base", f"the window {w.base}..{w.end - 1} leaves the 16-bit address space")
        if w.pages > 65536:
            fail(f"modbus.{w.name}.page_samples", f"{w.pages} pages do not fit the u16 {w.page_register}")
    return _ExcitationProtocol(control, status, fault_codes, modes, table, kind.type, kind.scale, capture, channels)


def _parse_capture(cp: dict, source: str) -> tuple[Window, tuple[CaptureChannel, ...]]:
    """``[modbus.capture]``: its window and channels (at most 16: the bits of ``capture_mask``)."""
    fail = _fail_in(source)
    raw = cp.get("channels")
    if not isinstance(raw, list) or not raw:
        fail("modbus.capture.channels", "needs at least one [[modbus.capture.channels]] entry")
    if len(raw) > 16:
        fail("modbus.capture.channels", f"capture_mask has 16 bits; {len(raw)} channels given")
    channels = []
    for i, ch in enumerate(raw):
        if not isinstance(ch, dict):
            fail(f"modbus.capture.channels[{i}].name", "is required")
        c = build_table(_CaptureChannelTable, ch, f"modbus.capture.channels[{i}].", source)
        channels.append(CaptureChannel(c.name, c.type, c.scale, i))
    if len({c.name for c in channels}) != len(channels):
        fail("modbus.capture.channels", "channel names must be distinct")
    window = build_table(_WindowTable, cp, "modbus.capture.", source)
    record_max = 1 + sum(c.count for c in channels)
    capture = Window(
        "capture",
        window.base,
        window.page_samples,
        window.capacity_samples,
        window.page_samples * record_max,
        "capture_page",
    )
    return capture, tuple(channels)


def _parse_filters(
    sections: dict,
    mb: dict,
    registers: dict[str, Register],
    rule: ParameterRule | None,
    filter_slots: int,
    excitation: bool,
    source: str,
) -> tuple[FilterSlots | FieldSlots | None, FilterEncoding | None]:
    """``[modbus.filters]`` with the ``[filters]`` encoding: hilident's slots or the drive's named registers."""
    fail = _fail_in(source)
    if not (excitation or "filters" in mb):
        if filter_slots:
            fail("modbus.filters", f"is required: board.filter_slots = {filter_slots}")
        return None, None
    encoding = FilterEncoding.from_table(sections.get("filters", {}), source)
    ft = _subtable(mb, "filters", "modbus", fail)
    if "slots" in ft:
        return _parse_field_slots(ft, encoding, registers, rule, filter_slots, fail), encoding
    if encoding.kind != "notch_parameters":
        fail("filters.encoding", f'a Modbus drive map holds "notch_parameters", got {encoding.kind!r}')
    keys = build_table(_FilterSlotsTable, ft, "modbus.filters.", source)
    offsets = {f: getattr(keys, f) for f in FILTER_FIELDS}
    if sorted(offsets.values()) != [0, 1, 2, 3]:
        fail("modbus.filters", "center, width, depth and enable must be the offsets 0, 1, 2, 3 in some order")
    filters = FilterSlots(keys.base, keys.stride, filter_slots, offsets)
    if filters.end > 65536:
        fail("modbus.filters.base", "the filter slots leave the 16-bit address space")
    return filters, encoding


@dataclass(frozen=True, kw_only=True)
class _FilterSlotsTable:
    """``[modbus.filters]`` of hilident's four-register slots: base, stride and each field's offset."""

    open_table: ClassVar[bool] = True
    base: int = _spec(ge=0, le=65535, doc="address of slot 0")
    stride: int = _spec(4, ge=4, le=65535, doc="registers from one slot to the next")
    center: int = _spec(ge=0, le=3)
    width: int = _spec(ge=0, le=3)
    depth: int = _spec(ge=0, le=3)
    enable: int = _spec(ge=0, le=3)


def _check_overlaps(
    registers: dict[str, Register],
    table: Window | None,
    capture: Window | None,
    filters: FilterSlots | FieldSlots | None,
    filter_slots: int,
    fail: _Fail,
) -> None:
    """Nothing may overlap: registers (holding and input apart), windows, filter slots."""
    spans = [(r.table, r.address, r.end, f"modbus.registers.{r.name}") for r in registers.values()]
    spans += [("holding", w.base, w.end, f"modbus.{w.name}") for w in (table, capture) if w is not None]
    if isinstance(filters, FilterSlots):
        spans += [
            (
                "holding",
                filters.base + i * filters.stride,
                filters.base + i * filters.stride + filters.span,
                f"modbus.filters (slot {i})",
            )
            for i in range(filter_slots)
        ]
    spans.sort()
    for (t0, a0, a1, k0), (t1, b0, b1, k1) in zip(spans, spans[1:], strict=False):
        if t0 == t1 and b0 < a1:
            fail(k1, f"registers {b0}..{b1 - 1} overlap {k0} ({a0}..{a1 - 1})")


class RegisterMap:
    """A parsed Modbus register map (see the module docstring and ``drivers/modbus-servo/README.md``).

    Build it with :meth:`from_driver` or :meth:`parse`.
    """

    def __init__(
        self,
        *,
        map_version: int,
        device_type: int,
        word_order: str,
        max_read: int,
        max_write: int,
        registers: dict[str, Register],
        control: dict[str, int],
        status: dict[str, int],
        fault_codes: dict[str, int],
        modes: dict[str, int],
        table: Window | None,
        table_type: str,
        table_scale: float,
        capture: Window | None,
        capture_channels: tuple[CaptureChannel, ...],
        filters: FilterSlots | FieldSlots | None,
        filter_encoding: FilterEncoding | None,
        byte_order: str = "big",
        rule: ParameterRule | None = None,
        identity: tuple[str, ...] = (),
        expect: dict | None = None,
        save: tuple[str, float] | None = None,
        stop: dict | None = None,
    ):
        self.byte_order = byte_order
        self.rule = rule
        self.identity = identity
        self.expect = dict(expect or {})
        self.save = save
        self.stop = dict(stop or {})
        self.map_version = map_version
        self.device_type = device_type
        self.word_order = word_order
        self.max_read = max_read
        self.max_write = max_write
        self.registers = registers
        self.control = control
        self.status = status
        self.fault_codes = fault_codes
        self.modes = modes
        self.table = table
        self.table_type = table_type
        self.table_scale = table_scale
        self.capture = capture
        self.capture_channels = capture_channels
        self.filters = filters
        self.filter_encoding = filter_encoding

    # --- parsing -----------------------------------------------------------------------

    @classmethod
    def from_driver(cls, driver) -> RegisterMap:
        """The map of a :class:`~hilident.drivers.description.DriverDescription` (its ``sections``)."""
        return cls.parse(driver.sections, driver.filter_slots, str(driver.folder / "driver.toml"))

    @classmethod
    def parse(cls, sections: dict, filter_slots: int, source: str = "") -> RegisterMap:
        """Validate the ``[modbus]`` tables of a parsed driver description.

        Raises
        ------
        ConfigError
            A table or key is missing, has the wrong type, or registers overlap;
            the message names the dotted key and ``source``.
        """
        fail = _fail_in(source)
        mb = _subtable(sections, "modbus", "", fail)
        keys = build_table(_ModbusTable, mb, "modbus.", source)
        rule = _parse_rule(mb, source) if "parameters" in mb else None
        registers = _parse_registers(
            _subtable(mb, "registers", "modbus", fail), rule, keys.word_order, keys.byte_order, source
        )
        excitation = "table" in mb or "capture" in mb
        protocol = _parse_excitation(mb, registers, source) if excitation else _ExcitationProtocol()
        filters, encoding = _parse_filters(sections, mb, registers, rule, filter_slots, excitation, source)
        identity, expect = _parse_identity(mb, registers, excitation, fail)
        save = _parse_save(mb, registers, rule, fail)
        stop = _parse_stop(mb, registers, fail)
        _check_overlaps(registers, protocol.table, protocol.capture, filters, filter_slots, fail)
        return cls(
            map_version=keys.identity_code("map_version", excitation, source),
            device_type=keys.identity_code("device_type", excitation, source),
            word_order=keys.word_order,
            max_read=keys.max_read_registers,
            max_write=keys.max_write_registers,
            registers=registers,
            control=protocol.control,
            status=protocol.status,
            fault_codes=protocol.fault_codes,
            modes=protocol.modes,
            table=protocol.table,
            table_type=protocol.table_type,
            table_scale=protocol.table_scale,
            capture=protocol.capture,
            capture_channels=protocol.capture_channels,
            filters=filters,
            filter_encoding=encoding,
            byte_order=keys.byte_order,
            rule=rule,
            identity=identity,
            expect=expect,
            save=save,
            stop=stop,
        )

    @property
    def excitation(self) -> bool:
        """Whether the drive offers hilident's excitation-table and capture capability."""
        return self.table is not None

    def parameter(self, code: str) -> Register:
        """The register of vendor parameter ``code`` (``"P08.02"``): the map's own entry, else a ``u16``
        holding register at the rule's address.

        Raises
        ------
        DataError
            The map has no parameter rule, or ``code`` is not a parameter code.
        """
        for r in self.registers.values():
            if r.parameter == code or r.name == code:
                return r
        if self.rule is None:
            raise DataError(f"the map has no [modbus.parameters] rule to find parameter {code!r}")
        return Register(code, self.rule.address_of(code), "u16", "rw", parameter=code)

    # --- single registers ----------------------------------------------------------------

    def register(self, name: str) -> Register:
        return self.registers[name]

    def encode(self, name: str, value) -> list[int]:
        """Registers holding ``value`` in register ``name`` (DataError naming the register when it does not fit
        or lies outside the register's range)."""
        return self.registers[name].encode(value)

    def decode(self, name: str, registers) -> float | int | str:
        """The value ``registers`` hold in register ``name`` (ints for unscaled integer types)."""
        return self.registers[name].decode(registers)

    def span(self, *names: str) -> tuple[int, int]:
        """``(address, count)`` of one request covering registers ``names``."""
        regs = [self.registers[n] for n in names]
        first = min(r.address for r in regs)
        return first, max(r.end for r in regs) - first

    def read_groups(self, names) -> list[tuple[int, int]]:
        """``(address, count)`` read requests covering registers ``names``.

        Neighbouring registers without a gap between them share a request (a
        drive answers a read across a gap with exception 2); each request holds
        at most ``max_read`` registers.
        """
        return [(a, n) for _, a, n in self.request_groups(names)]

    def request_groups(self, names) -> list[tuple[str, int, int]]:
        """``(table, address, count)`` read requests covering registers ``names``: as :meth:`read_groups`,
        holding and input registers apart."""
        regs = sorted((self.registers[n] for n in names), key=lambda r: (r.table, r.address))
        groups: list[list] = []
        for r in regs:
            if (
                groups
                and r.table == groups[-1][0]
                and r.address == groups[-1][2]
                and r.end - groups[-1][1] <= self.max_read
            ):
                groups[-1][2] = r.end
            else:
                groups.append([r.table, r.address, r.end])
        return [(t, a, b - a) for t, a, b in groups]

    def decode_span(self, names, address: int, registers) -> dict:
        """Values of ``names`` from ``registers`` read starting at ``address``."""
        out = {}
        for n in names:
            r = self.registers[n]
            out[n] = self.decode(n, registers[r.address - address : r.end - address])
        return out

    def describe(self, address: int, count: int = 1, page: int | None = None, table: str = "holding") -> str:
        """Human-readable name of registers ``address .. address + count - 1`` (for messages)."""
        last = address + max(count, 1) - 1
        fmt = "#06x" if self.rule is not None else "d"
        where = f"register {address:{fmt}}" if last == address else f"registers {address:{fmt}}..{last:{fmt}}"
        names = [
            r.label
            for r in sorted(self.registers.values(), key=lambda r: r.address)
            if r.address <= last and r.end > address and r.table == table
        ]
        if table == "holding":
            names += self._holding_names(address, last, page, bool(names))
        if table == "input":
            where = "input " + where
        return f"{where} ({', '.join(names) or 'not in the driver map'})"

    def _holding_names(self, address: int, last: int, page: int | None, named: bool) -> list[str]:
        """What else holding registers ``address..last`` are: windows, filter slots, else a parameter code."""
        names = [
            label + (f", page {page}" if page is not None else "")
            for w, label in ((self.table, "excitation table window"), (self.capture, "capture window"))
            if w is not None and w.base <= last and w.end > address
        ]
        if self.filters is not None:
            slots = sorted({s for a in range(address, last + 1) if (s := self.filters.slot_at(a)) is not None})
            names += [f"filter slot {s}" for s in slots]
        if not names and not named and self.rule is not None and (code := self.rule.code(address)):
            names.append(f"parameter {code}")
        return names

    # --- codes and bits --------------------------------------------------------------------

    def status_flags(self, word: int) -> frozenset[str]:
        """Names of the bits set in a status word."""
        return frozenset(n for n, bit in self.status.items() if word & bit)

    def fault_name(self, code: int) -> str:
        for name, value in self.fault_codes.items():
            if value == code:
                return name
        return f"fault {code}"

    # --- excitation table ------------------------------------------------------------------

    @property
    def table_registers_per_sample(self) -> int:
        return TYPES[self.table_type][0]

    def encode_table(self, values) -> np.ndarray:
        """Registers of the excitation table (DataError when a value does not fit)."""
        return encode_values(values, self.table_type, self.table_scale, self.word_order)

    def decode_table(self, registers) -> np.ndarray:
        return decode_values(registers, self.table_type, self.table_scale, self.word_order)

    # --- capture records ----------------------------------------------------------------------

    def capture_channel_names(self) -> list[str]:
        return [c.name for c in self.capture_channels]

    def mask_of(self, names) -> int:
        """``capture_mask`` selecting channels ``names`` (ConfigError naming an unknown one)."""
        known = {c.name: c for c in self.capture_channels}
        mask = 0
        for n in names:
            if n not in known:
                raise ConfigError("run.channels", f"the drive captures no channel {n!r} (it has: {', '.join(known)})")
            mask |= 1 << known[n].bit
        return mask

    def selected(self, mask: int) -> tuple[CaptureChannel, ...]:
        """Channels selected by ``mask``, in record order."""
        return tuple(c for c in self.capture_channels if mask >> c.bit & 1)

    def record_registers(self, mask: int) -> int:
        """Registers per capture record: the stamp plus the selected channels."""
        return 1 + sum(c.count for c in self.selected(mask))

    def encode_records(self, stamps, rows, mask: int) -> np.ndarray:
        """Registers of capture records (integer channels saturate, as a drive's would).

        Parameters
        ----------
        stamps : array_like of int, shape (n,)
        rows : array_like, shape (n, channels selected by ``mask``)
        """
        chans = self.selected(mask)
        stamps = np.asarray(stamps, dtype=np.int64) % STAMP_MODULUS
        rows = np.asarray(rows, dtype=float).reshape(len(stamps), len(chans))
        columns = [stamps.astype(np.uint16).reshape(-1, 1)]
        for j, c in enumerate(chans):
            regs = encode_values(rows[:, j], c.type, c.scale, self.word_order, saturate=True)
            columns.append(regs.reshape(len(stamps), c.count))
        return np.hstack(columns).ravel()

    def decode_records(self, registers, mask: int) -> tuple[np.ndarray, np.ndarray]:
        """``(stamps, rows)`` of whole capture records read back.

        Raises
        ------
        DataError
            The registers do not hold whole records.
        """
        chans = self.selected(mask)
        width = self.record_registers(mask)
        r = np.asarray(registers, dtype=np.int64)
        if len(r) % width:
            raise DataError(f"{len(r)} registers are not whole capture records of {width}")
        r = r.reshape(-1, width)
        rows = np.empty((len(r), len(chans)))
        col = 1
        for j, c in enumerate(chans):
            rows[:, j] = decode_values(r[:, col : col + c.count], c.type, c.scale, self.word_order)
            col += c.count
        return r[:, 0].copy(), rows

    # --- filter slots ---------------------------------------------------------------------

    def _four_register_slots(self) -> FilterSlots:
        """The map's filter slots when they are hilident's four-register slots (DataError otherwise)."""
        if not isinstance(self.filters, FilterSlots):
            held = "no filter slots" if self.filters is None else "filter slots of named registers"
            raise DataError(f"the map has {held}, not hilident's four-register slots ([modbus.filters] base)")
        return self.filters

    def encode_filter(self, values: dict, enabled: bool) -> list[int]:
        """The four registers of a filter slot, in address order."""
        slots = self._four_register_slots()
        fields = {**{k: int(values[k]) for k in ("center", "width", "depth")}, "enable": int(bool(enabled))}
        for k, v in fields.items():
            if not 0 <= v <= 0xFFFF:
                raise DataError(f"filter field {k} = {v} does not fit a 16-bit register")
        out = [0] * slots.span
        for k, v in fields.items():
            out[slots.offsets[k]] = v
        return out

    def decode_filter(self, registers) -> tuple[dict, bool]:
        """``({center, width, depth}, enabled)`` from a slot's four registers."""
        offsets = self._four_register_slots().offsets
        regs = [int(x) for x in registers]
        values = {k: regs[offsets[k]] for k in ("center", "width", "depth")}
        return values, bool(regs[offsets["enable"]])
