"""One named register of a Modbus drive's map, and the rule that turns vendor parameter codes into addresses.

A :class:`Register` is a value at an address: its type (the value types of
:mod:`~hilident.protocol.modbus.codecs`), its scale and offset (a physical
value is ``raw * scale + offset``), its range (``min``/``max`` bound it: a
write outside is refused before it is sent, naming the register) and its named
bit fields. A :class:`ParameterRule` turns a vendor's parameter code
(``"P08.02"``) into the address of its register, as the vendor's manual does.

Examples
--------
>>> speed = Register("speed", 0x0802, "i32", "rw", scale=0.001, unit="m/s", minimum=-2.0, maximum=2.0, count=2)
>>> speed.encode(1.5), speed.decode([0, 1500])
([0, 1500], 1.5)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import NoReturn

from hilident.errors import ConfigError, DataError
from hilident.protocol.modbus.codecs import decode_integer, decode_string, decode_values, encode_string, encode_values

__all__ = ["ParameterRule", "Register"]


@dataclass(frozen=True)
class Register:
    """One named value of the map.

    Attributes
    ----------
    name : str
    address : int
        First register (0-based protocol address).
    type : str
        One of :data:`~hilident.protocol.modbus.codecs.TYPES` or ``str``.
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
            return decode_integer(registers, self.type, self.word_order, self.byte_order)
        return int(value) if exact else value

    def bit_field(self, name: str, registers) -> int:
        """The value of bit field ``name`` (shifted down to its lowest bit)."""
        mask = self.bits[name]
        word = int(self.decode(registers)) if self.type != "str" else 0
        return (word & mask) >> ((mask & -mask).bit_length() - 1)


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
