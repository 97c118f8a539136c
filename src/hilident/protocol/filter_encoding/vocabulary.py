"""The names, limits and checks the parts of :mod:`hilident.protocol.filter_encoding` share."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import NoReturn

from hilident.errors import ConfigError
from hilident.filters.biquad import Biquad

__all__ = [
    "COEFFICIENT_FIELDS",
    "DEEPER",
    "DEPTH_MARGINS_DB",
    "DEPTH_TOLERANCE_DB",
    "DEPTH_UNITS",
    "ENCODINGS",
    "FLOAT32_MAX",
    "FULL_DEPTH_DB",
    "MIN_ATTENUATION_DB",
    "PARAMETER_FIELDS",
    "PARAMETRIC",
    "REFINE_STEPS",
    "SAME_FREQUENCY",
    "SCALER_CHOICES",
    "WIDTH_TOLERANCE",
    "WIDTH_UNITS",
    "float32",
]

COEFFICIENT_FIELDS = ("b0", "b1", "b2", "a1", "a2")
PARAMETER_FIELDS = ("center", "width", "depth")
#: the fields of each physical-parameter encoding, in their default order
PARAMETRIC = {
    "notch_parameters": PARAMETER_FIELDS,
    "pole_zero_q": ("pole_hz", "pole_q", "zero_hz", "zero_q"),
    "pole_zero_damping": ("num_hz", "num_damping", "den_hz", "den_damping"),
    "index_table": PARAMETER_FIELDS,
    "center_band": ("center", "band"),
    "center_ratio_damping": ("center_hz", "ratio", "center_damping", "damping_ratio"),
}
ENCODINGS = ("real32", "fixed", "word_block", *PARAMETRIC)
#: a realised notch this much shallower than asked at the resonance is noted (float32 rounding is far less)
DEPTH_TOLERANCE_DB = 0.1
#: a realised width off by more than this factor from the asked one is noted
WIDTH_TOLERANCE = 1.25
#: INT16 blocks: how many of the best scalings realise() weighs against the asked depth
SCALER_CHOICES = 48
#: coefficient encodings: extra design depth tried, in order, while rounding leaves the notch short (dB)
DEPTH_MARGINS_DB = (0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
#: attenuations at or beyond this count as a full cut when candidates are compared (dB)
FULL_DEPTH_DB = 150.0
#: a candidate attenuating the resonance by less than this is no notch (dB)
MIN_ATTENUATION_DB = 1.0
#: most single steps realise() takes from the best neighbour
REFINE_STEPS = 40
#: fields that set a notch's depth, and which way is deeper (+1: a larger value)
DEEPER = {"depth": 1, "zero_q": 1, "num_damping": -1, "damping_ratio": 1}
#: ``"notch_parameters"``: how the width and depth fields are expressed
WIDTH_UNITS = ("hz", "q", "ratio", "index")
DEPTH_UNITS = ("db", "ratio", "percent", "index", "full")
#: pairs of fields that must hold the same frequency for the section to be a notch
SAME_FREQUENCY = {"pole_zero_q": ("pole_hz", "zero_hz"), "pole_zero_damping": ("num_hz", "den_hz")}
#: fields the fit keeps at their ideal value, never walked (a ratio of 1: the zeros' and poles' frequencies meet)
HELD = {"center_ratio_damping": ("ratio",)}
FLOAT32_MAX = 3.4028234663852886e38


def default_fields(kind: str, depth_unit: str = "db") -> tuple[str, ...]:
    """The fields of a physical-parameter encoding in their default order (``"notch_parameters"`` with
    ``depth_unit = "full"`` has no depth field: the slot always cuts fully)."""
    fields = PARAMETRIC[kind]
    if kind == "notch_parameters" and depth_unit == "full":
        return tuple(f for f in fields if f != "depth")
    return fields


def float32(x: float) -> float:
    """``x`` rounded to IEEE-754 single precision (what a REAL32 object holds)."""
    return struct.unpack("<f", struct.pack("<f", float(x)))[0]


def float32_biquad(b0: float, b1: float, b2: float, a1: float, a2: float) -> Biquad:
    """The section of five coefficients each rounded to single precision (what REAL32 objects hold)."""
    return Biquad((float32(b0), float32(b1), float32(b2)), (1.0, float32(a1), float32(a2)))


def stored_coefficients(values: Sequence[float], feedback_sign: str) -> tuple[float, float, float, float, float]:
    """scipy ``(b0, b1, b2, a1, a2)`` <-> stored ``b0 .. a2`` (the feedback terms negated for ``"plus"``)."""
    sign = -1.0 if feedback_sign == "plus" else 1.0
    return (values[0], values[1], values[2], sign * values[3], sign * values[4])


def fail(key: str, message: str) -> NoReturn:
    """Raise the :class:`ConfigError` of ``[filters] <key>``."""
    raise ConfigError(f"filters.{key}", message)


def int_in(key: str, v, low: int, high: int) -> int:
    """``v`` when it is an integer in ``low..high``; else the ConfigError of ``[filters] <key>``."""
    if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
        fail(key, f"must be an integer in {low}..{high}, got {v!r}")
    return v


def positive(key: str, v, zero_ok: bool = False) -> float:
    """``v`` as a float when it is a finite positive (or, ``zero_ok``, non-negative) number; else ConfigError."""
    what = "non-negative" if zero_ok else "positive"
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        fail(key, f"must be a {what} number, got {v!r}")
    try:
        x = float(v)
    except OverflowError:  # an integer beyond any float
        fail(key, f"must be a {what} number, got an integer of {int(v).bit_length()} bits")
    if not math.isfinite(x) or x < 0 or (x == 0 and not zero_ok):
        fail(key, f"must be a {what} number, got {v!r}")
    return x


def checked_range(name: str, r) -> tuple[float, float]:
    """``ranges.<name> = [low, high]``: non-negative, low not above high."""
    if not isinstance(r, (list, tuple)) or len(r) != 2:
        fail(f"ranges.{name}", f"must be [low, high], got {r!r}")
    low, high = positive(f"ranges.{name}", r[0], zero_ok=True), positive(f"ranges.{name}", r[1])
    if low > high:
        fail(f"ranges.{name}", f"low {low:g} is above high {high:g}")
    return low, high
