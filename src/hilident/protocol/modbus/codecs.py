"""How a Modbus drive's values sit in its 16-bit registers: numbers of one to four registers, and text.

Value types
-----------
``u16``, ``i16``
    One register, unsigned or two's complement.
``u32``, ``i32``, ``f32``; ``u64``, ``i64``, ``f64``
    Two (four) registers (IEEE-754 for the floats). ``word_order`` ``"big"``
    puts the most significant word at the lowest address, ``"little"`` the
    least significant. ``byte_order`` ``"big"`` sends each register high byte
    first, as Modbus does; ``"little"`` swaps the two bytes.
``str``
    ``length`` registers, two ASCII characters each (first character in the
    high byte), NUL padded.

A physical value is ``raw * scale + offset``.

All functions are pure: values in, registers out, and back.

Examples
--------
>>> regs = encode_values([1.5, -2.0], "f32", word_order="little")
>>> [hex(r) for r in regs]
['0x0', '0x3fc0', '0x0', '0xc000']
>>> decode_values(regs, "f32", word_order="little").tolist()
[1.5, -2.0]
"""

from __future__ import annotations

import numpy as np

from hilident.errors import DataError

__all__ = [
    "BYTE_ORDERS",
    "TYPES",
    "WORD_ORDERS",
    "decode_integer",
    "decode_string",
    "decode_values",
    "encode_string",
    "encode_values",
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
#: ``word_order``: the most (``"big"``) or least significant word of a multi-register value at its lowest address.
WORD_ORDERS = ("big", "little")
#: ``byte_order``: each register sent high byte first (``"big"``, as Modbus does) or swapped.
BYTE_ORDERS = ("big", "little")


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


def decode_integer(registers, type_: str, word_order: str = "big", byte_order: str = "big") -> int:
    """The exact integer ``registers`` hold as one value of integer type ``type_``.

    :func:`decode_values` returns float64, which keeps 53 bits: a ``u64`` or ``i64`` needs this.

    >>> decode_integer(encode_values([2**63 - 1], "i64"), "i64")
    9223372036854775807
    """
    data = _order_words(np.asarray(registers, dtype=np.int64).reshape(1, -1), word_order, byte_order)
    return int.from_bytes(data.astype(">u2").tobytes(), "big", signed=type_.startswith("i"))


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


def _numeric(type_: str) -> tuple[int, str]:
    try:
        return TYPES[type_]
    except KeyError:
        raise DataError(f"{type_!r} is not a numeric register type ({', '.join(TYPES)})") from None
