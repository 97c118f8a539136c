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
``u32``, ``i32``, ``f32``
    Two registers (IEEE-754 single precision for ``f32``). ``word_order``
    ``"big"`` puts the high word at the lower address, ``"little"`` the low
    word. Within a register the bytes are big-endian (Modbus).
``str``
    ``length`` registers, two ASCII characters each (first character in the
    high byte), NUL padded.

A physical value is ``raw * scale``.

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
from dataclasses import dataclass, field

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = [
    "EXCEPTION_MEANINGS", "TYPES", "CaptureChannel", "Chunk", "FilterSlots", "Register", "RegisterMap", "Window",
    "count_rtu_frames", "decode_string", "decode_values", "encode_string", "encode_values", "exception_meaning",
    "plan_chunks", "rtu_crc", "table_crc",
]

#: Registers per value and numpy type code of the numeric types.
TYPES: dict[str, tuple[int, str]] = {"u16": (1, "u2"), "i16": (1, "i2"), "u32": (2, "u4"), "i32": (2, "i4"),
                                     "f32": (2, "f4"), "u64": (4, "u8"), "i64": (4, "i8"), "f64": (4, "f8")}
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
    "device_type": ("u16",), "map_version": ("u16",), "loop_rate_hz": ("u16", "u32", "f32"),
    "max_sample_rate_hz": ("u16", "u32", "f32"), "filter_slots": ("u16",), "table_capacity": ("u16", "u32"),
    "capture_capacity": ("u16", "u32"), "device_name": ("str",), "firmware": ("str",),
    "control_word": ("u16",), "status_word": ("u16",), "fault_code": ("u16",), "sample_count": ("u16", "u32"),
    "fault_sample": ("u16", "u32"), "fault_value": ("f32",), "mode": ("u16",), "sample_divider": ("u16",),
    "capture_mask": ("u16",), "table_length": ("u16", "u32"), "table_page": ("u16",), "capture_page": ("u16",),
    "table_crc": ("u16",), "torque_limit_nm": ("f32",), "velocity_limit_mps": ("f32",),
    "position_min_m": ("f32",), "position_max_m": ("f32",),
}
WRITABLE = ("control_word", "mode", "sample_divider", "capture_mask", "table_length", "table_page", "capture_page",
            "torque_limit_nm", "velocity_limit_mps", "position_min_m", "position_max_m")
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


def _optional_fault_codes(table: dict, registers: dict, required: dict, fail) -> dict[str, int]:
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


def encode_values(values, type_: str, scale: float = 1.0, word_order: str = "big",
                  saturate: bool = False, byte_order: str = "big", offset: float = 0.0) -> np.ndarray:
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


def _order_words(words: np.ndarray, word_order: str, byte_order: str) -> np.ndarray:
    """Big-endian words of each value (one row per value) in the register order and byte order asked for;
    the same operation undoes itself."""
    words = np.asarray(words, dtype=np.uint16)
    if word_order == "little" and words.shape[1] > 1:
        words = words[:, ::-1]
    if byte_order == "little":
        words = (words >> 8) | ((words & 0xFF) << 8)
    return words.astype(np.uint16).ravel()


def decode_values(registers, type_: str, scale: float = 1.0, word_order: str = "big", byte_order: str = "big",
                  offset: float = 0.0) -> np.ndarray:
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


def plan_chunks(first_sample: int, n_samples: int, registers_per_sample: int, page_samples: int,
                max_registers: int) -> list[Chunk]:
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
        raise ConfigError("modbus.max_registers",
                          f"a sample of {registers_per_sample} registers does not fit a request of {max_registers}")
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
        ``u16``, ``i16``, ``u32``, ``i32``, ``f32`` or ``str``.
    access : {"r", "rw"}
    scale : float
        Physical value per raw unit.
    count : int
        Registers it occupies.
    """

    name: str
    address: int
    type: str
    access: str = "r"
    scale: float = 1.0
    count: int = 1

    @property
    def end(self) -> int:
        """One past the last register."""
        return self.address + self.count

    @property
    def writable(self) -> bool:
        return self.access == "rw"


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
    offsets: dict = field(default_factory=dict)

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


class RegisterMap:
    """A parsed Modbus register map (see the module docstring and ``drivers/modbus-servo/README.md``).

    Build it with :meth:`from_driver` or :meth:`parse`.
    """

    def __init__(self, *, map_version: int, device_type: int, word_order: str, max_read: int, max_write: int,
                 registers: dict[str, Register], control: dict[str, int], status: dict[str, int],
                 fault_codes: dict[str, int], modes: dict[str, int], table: Window, table_type: str,
                 table_scale: float, capture: Window, capture_channels: tuple[CaptureChannel, ...],
                 filters: FilterSlots, filter_encoding: FilterEncoding):
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
    def from_driver(cls, driver) -> "RegisterMap":
        """The map of a :class:`~hilident.drivers.DriverDescription` (its ``sections``)."""
        return cls.parse(driver.sections, driver.filter_slots, str(driver.folder / "driver.toml"))

    @classmethod
    def parse(cls, sections: dict, filter_slots: int, source: str = "") -> "RegisterMap":
        """Validate the ``[modbus]`` tables of a parsed driver description.

        Raises
        ------
        ConfigError
            A table or key is missing, has the wrong type, or registers overlap;
            the message names the dotted key and ``source``.
        """
        def fail(key, message):
            raise ConfigError(key, message, source or None)

        def integer(table, key, prefix, lo=0, hi=None, default=None):
            value = table.get(key, default)
            if value is None:
                fail(f"{prefix}.{key}", "is required")
            if isinstance(value, bool) or not isinstance(value, int) or value < lo or (hi is not None and value > hi):
                fail(f"{prefix}.{key}", f"must be an integer in {lo}..{hi if hi is not None else 'inf'}, got {value!r}")
            return value

        def number(table, key, prefix, default):
            value = table.get(key, default)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value == 0:
                fail(f"{prefix}.{key}", f"must be a non-zero finite number, got {value!r}")
            return float(value)

        def subtable(parent, key, prefix):
            value = parent.get(key)
            if not isinstance(value, dict):
                fail(f"{prefix}.{key}" if prefix else key, "table is required")
            return value

        mb = subtable(sections, "modbus", "")
        word_order = mb.get("word_order", "big")
        if word_order not in WORD_ORDERS:
            fail("modbus.word_order", f"must be one of {WORD_ORDERS}, got {word_order!r}")
        max_read = integer(mb, "max_read_registers", "modbus", 1, 125, 125)
        max_write = integer(mb, "max_write_registers", "modbus", 1, 123, 123)

        registers: dict[str, Register] = {}
        for name, spec in subtable(mb, "registers", "modbus").items():
            key = f"modbus.registers.{name}"
            if not isinstance(spec, dict):
                fail(key, "must be a table {address, type, access}")
            unknown = set(spec) - {"address", "type", "access", "scale", "length"}
            if unknown:
                fail(f"{key}.{sorted(unknown)[0]}", "unknown key (known: address, type, access, scale, length)")
            type_ = spec.get("type")
            if type_ not in (*TYPES, "str"):
                fail(f"{key}.type", f"must be one of {(*TYPES, 'str')}, got {type_!r}")
            access = spec.get("access", "r")
            if access not in ("r", "rw"):
                fail(f"{key}.access", f'must be "r" or "rw", got {access!r}')
            count = integer(spec, "length", key, 1, 125) if type_ == "str" else TYPES[type_][0]
            address = integer(spec, "address", key, 0, 65536 - count)
            registers[name] = Register(name, address, type_, access, number(spec, "scale", key, 1.0), count)
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

        def codes(key, names, bits):
            table = subtable(mb, key, "modbus")
            out = {}
            for name in names:
                value = integer(table, name, f"modbus.{key}", 1, 0xFFFF)
                if bits and value & (value - 1):
                    fail(f"modbus.{key}.{name}", f"must be a single bit, got {value:#x}")
                out[name] = value
            if len(set(out.values())) != len(out):
                fail(f"modbus.{key}", "values must be distinct")
            return out

        control = codes("control", CONTROL_BITS, True)
        status = codes("status", STATUS_BITS, True)
        fault_codes = codes("fault_codes", FAULT_NAMES, False)
        fault_codes.update(_optional_fault_codes(mb["fault_codes"], registers, fault_codes, fail))
        modes = codes("modes", MODES, False)

        tb = subtable(mb, "table", "modbus")
        table_type = tb.get("type", "f32")
        if table_type not in WINDOW_TYPES:
            fail("modbus.table.type", f"must be one of {WINDOW_TYPES}, got {table_type!r}")
        table_scale = number(tb, "scale", "modbus.table", 1.0)
        table_page = integer(tb, "page_samples", "modbus.table", 1, 65535)
        table = Window("table", integer(tb, "base", "modbus.table", 0, 65535), table_page,
                       integer(tb, "capacity_samples", "modbus.table", 1, 2**32 - 1, 65536),
                       table_page * TYPES[table_type][0], "table_page")

        cp = subtable(mb, "capture", "modbus")
        channels = []
        raw_channels = cp.get("channels")
        if not isinstance(raw_channels, list) or not raw_channels:
            fail("modbus.capture.channels", "needs at least one [[modbus.capture.channels]] entry")
        if len(raw_channels) > 16:
            fail("modbus.capture.channels", f"capture_mask has 16 bits; {len(raw_channels)} channels given")
        for i, ch in enumerate(raw_channels):
            key = f"modbus.capture.channels[{i}]"
            if not isinstance(ch, dict) or not isinstance(ch.get("name"), str):
                fail(f"{key}.name", "is required")
            if ch.get("type") not in WINDOW_TYPES:
                fail(f"{key}.type", f"must be one of {WINDOW_TYPES}, got {ch.get('type')!r}")
            channels.append(CaptureChannel(ch["name"], ch["type"], number(ch, "scale", key, 1.0), i))
        if len({c.name for c in channels}) != len(channels):
            fail("modbus.capture.channels", "channel names must be distinct")
        capture_page = integer(cp, "page_samples", "modbus.capture", 1, 65535)
        record_max = 1 + sum(c.count for c in channels)
        capture = Window("capture", integer(cp, "base", "modbus.capture", 0, 65535), capture_page,
                         integer(cp, "capacity_samples", "modbus.capture", 1, 2**32 - 1, 65536),
                         capture_page * record_max, "capture_page")

        ft = subtable(mb, "filters", "modbus")
        offsets = {f: integer(ft, f, "modbus.filters", 0, 3) for f in FILTER_FIELDS}
        if sorted(offsets.values()) != [0, 1, 2, 3]:
            fail("modbus.filters", "center, width, depth and enable must be the offsets 0, 1, 2, 3 in some order")
        filters = FilterSlots(integer(ft, "base", "modbus.filters", 0, 65535),
                              integer(ft, "stride", "modbus.filters", 4, 65535, 4), filter_slots, offsets)
        encoding = FilterEncoding.from_table(sections.get("filters", {}), source)
        if encoding.kind != "notch_parameters":
            fail("filters.encoding", f'a Modbus drive map holds "notch_parameters", got {encoding.kind!r}')

        for w in (table, capture):
            if w.end > 65536:
                fail(f"modbus.{w.name}.base", f"the window {w.base}..{w.end - 1} leaves the 16-bit address space")
            if w.pages > 65536:
                fail(f"modbus.{w.name}.page_samples", f"{w.pages} pages do not fit the u16 {w.page_register}")
        if filters.end > 65536:
            fail("modbus.filters.base", "the filter slots leave the 16-bit address space")

        # nothing may overlap: registers, windows, filter slots
        spans = [(r.address, r.end, f"modbus.registers.{r.name}") for r in registers.values()]
        spans += [(w.base, w.end, f"modbus.{w.name}") for w in (table, capture)]
        spans += [(filters.base + i * filters.stride, filters.base + i * filters.stride + filters.span,
                   f"modbus.filters (slot {i})") for i in range(filter_slots)]
        spans.sort()
        for (a0, a1, k0), (b0, b1, k1) in zip(spans, spans[1:]):
            if b0 < a1:
                fail(k1, f"registers {b0}..{b1 - 1} overlap {k0} ({a0}..{a1 - 1})")

        return cls(
            map_version=integer(mb, "map_version", "modbus", 0, 0xFFFF),
            device_type=integer(mb, "device_type", "modbus", 0, 0xFFFF),
            word_order=word_order, max_read=max_read, max_write=max_write, registers=registers,
            control=control, status=status, fault_codes=fault_codes, modes=modes,
            table=table, table_type=table_type, table_scale=table_scale,
            capture=capture, capture_channels=tuple(channels), filters=filters, filter_encoding=encoding,
        )

    # --- single registers ----------------------------------------------------------------

    def register(self, name: str) -> Register:
        return self.registers[name]

    def encode(self, name: str, value) -> list[int]:
        """Registers holding ``value`` in register ``name`` (DataError when it does not fit)."""
        r = self.registers[name]
        if r.type == "str":
            return encode_string(str(value), r.count).tolist()
        try:
            return encode_values([value], r.type, r.scale, self.word_order).tolist()
        except DataError as exc:
            raise DataError(f"register {r.address} ({name}): {exc}") from None

    def decode(self, name: str, registers) -> float | int | str:
        """The value ``registers`` hold in register ``name`` (ints for unscaled integer types)."""
        r = self.registers[name]
        if r.type == "str":
            return decode_string(registers)
        value = float(decode_values(registers, r.type, r.scale, self.word_order)[0])
        return int(value) if r.type != "f32" and r.scale == 1.0 else value

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
        regs = sorted((self.registers[n] for n in names), key=lambda r: r.address)
        groups: list[list[int]] = []
        for r in regs:
            if groups and r.address == groups[-1][1] and r.end - groups[-1][0] <= self.max_read:
                groups[-1][1] = r.end
            else:
                groups.append([r.address, r.end])
        return [(a, b - a) for a, b in groups]

    def decode_span(self, names, address: int, registers) -> dict:
        """Values of ``names`` from ``registers`` read starting at ``address``."""
        out = {}
        for n in names:
            r = self.registers[n]
            out[n] = self.decode(n, registers[r.address - address : r.end - address])
        return out

    def describe(self, address: int, count: int = 1, page: int | None = None) -> str:
        """Human-readable name of registers ``address .. address + count - 1`` (for messages)."""
        last = address + max(count, 1) - 1
        where = f"register {address}" if last == address else f"registers {address}..{last}"
        names = [r.name for r in sorted(self.registers.values(), key=lambda r: r.address)
                 if r.address <= last and r.end > address]
        for w, label in ((self.table, "excitation table window"), (self.capture, "capture window")):
            if w.base <= last and w.end > address:
                names.append(label + (f", page {page}" if page is not None else ""))
        slots = sorted({s for a in range(address, last + 1) if (s := self.filters.slot_at(a)) is not None})
        names += [f"filter slot {s}" for s in slots]
        return f"{where} ({', '.join(names) or 'not in the driver map'})"

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

    def encode_filter(self, values: dict, enabled: bool) -> list[int]:
        """The four registers of a filter slot, in address order."""
        fields = {**{k: int(values[k]) for k in ("center", "width", "depth")}, "enable": int(bool(enabled))}
        for k, v in fields.items():
            if not 0 <= v <= 0xFFFF:
                raise DataError(f"filter field {k} = {v} does not fit a 16-bit register")
        out = [0] * self.filters.span
        for k, v in fields.items():
            out[self.filters.offsets[k]] = v
        return out

    def decode_filter(self, registers) -> tuple[dict, bool]:
        """``({center, width, depth}, enabled)`` from a slot's four registers."""
        regs = [int(x) for x in registers]
        values = {k: regs[self.filters.offsets[k]] for k in ("center", "width", "depth")}
        return values, bool(regs[self.filters.offsets["enable"]])
