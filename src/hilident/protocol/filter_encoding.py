"""How a drive stores a notch in one filter slot: the values a host writes.

Drives differ in what their filter objects or registers hold. A driver
description names one of these encodings (``[filters] encoding = ...``) and
where each field lives; the adapter encodes with it and the emulated drive
decodes with it, so both sides agree by construction of the wire, not by
sharing state.

``"real32"``
    Five IEEE-754 single-precision coefficients ``b0, b1, b2, a1, a2``
    (``a0 = 1``); the drive runs exactly those values.
``"fixed"``
    Five signed integers, coefficient times ``2**fractional_bits``, in
    ``total_bits`` two's complement; DC gain kept at 1 (see
    :func:`~hilident.filters.notch.quantize_biquad`).
``"notch_parameters"``
    Three unsigned integers: centre frequency, width and depth in the drive's
    units (for example 0.1 Hz, 0.1 Hz, 0.1 dB). The drive designs the biquad
    itself, at its loop rate, by the pre-warped Tustin transform of the
    standard notch (:func:`~hilident.filters.notch.design_notch`) and stores it
    in single precision; this is the drive's documented formula.

All functions are pure: values in, values out.

Examples
--------
>>> from hilident.filters.notch import NotchSpec, design_notch
>>> enc = FilterEncoding("notch_parameters", center_scale=0.1, width_scale=0.1, depth_scale=0.1)
>>> spec = NotchSpec(center_hz=21.7849, width_hz=6.53, depth_db=40.0)
>>> fields = enc.encode(design_notch(spec, 4000.0), spec)
>>> fields
{'center': 218, 'width': 65, 'depth': 400}
>>> enc.applied(fields, 4000.0) == enc.stored_form(design_notch(spec, 4000.0), spec, 4000.0)
True
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, quantize_biquad

ENCODINGS = ("real32", "fixed", "notch_parameters")
COEFFICIENT_FIELDS = ("b0", "b1", "b2", "a1", "a2")
PARAMETER_FIELDS = ("center", "width", "depth")


def float32(x: float) -> float:
    """``x`` rounded to IEEE-754 single precision (what a REAL32 object holds)."""
    return struct.unpack("<f", struct.pack("<f", float(x)))[0]


def _float32_biquad(b0, b1, b2, a1, a2) -> Biquad:
    return Biquad((float32(b0), float32(b1), float32(b2)), (1.0, float32(a1), float32(a2)))


@dataclass(frozen=True)
class FilterEncoding:
    """One drive's filter-slot encoding.

    Parameters
    ----------
    kind : {"real32", "fixed", "notch_parameters"}
    fractional_bits, total_bits : int
        ``"fixed"`` only: the Q format.
    center_scale, width_scale, depth_scale : float
        ``"notch_parameters"`` only: physical value per integer step (Hz, Hz, dB).
    max_value : int
        ``"notch_parameters"`` only: largest integer a field holds (65535 for
        16-bit registers, 4294967295 for UNSIGNED32 objects).
    """

    kind: str
    fractional_bits: int = 29
    total_bits: int = 32
    center_scale: float = 0.1
    width_scale: float = 0.1
    depth_scale: float = 0.1
    max_value: int = 65535

    def __post_init__(self):
        if self.kind not in ENCODINGS:
            raise ConfigError("filters.encoding", f"must be one of {ENCODINGS}, got {self.kind!r}")
        for key in ("center_scale", "width_scale", "depth_scale"):
            v = getattr(self, key)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"filters.{key}", f"must be a positive number, got {v!r}")
        for key, low, high in (("fractional_bits", 0, 62), ("total_bits", 2, 64), ("max_value", 1, 2**32 - 1)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
                raise ConfigError(f"filters.{key}", f"must be an integer in {low}..{high}, got {v!r}")
        if self.fractional_bits >= self.total_bits:
            raise ConfigError("filters.fractional_bits", f"must be below total_bits = {self.total_bits}, "
                                                         f"got {self.fractional_bits}")

    @classmethod
    def from_table(cls, table: dict, source: str = "") -> "FilterEncoding":
        """Build from a driver description's ``[filters]`` table (unknown keys are ignored)."""
        if not isinstance(table, dict):
            raise ConfigError("filters", f"must be a table, got {type(table).__name__}", source)
        if "encoding" not in table:
            raise ConfigError("filters.encoding", "is required", source)
        keys = ("fractional_bits", "total_bits", "center_scale", "width_scale", "depth_scale", "max_value")
        try:
            return cls(table["encoding"], **{k: table[k] for k in keys if k in table})
        except ConfigError as exc:
            raise ConfigError(exc.key, exc.message, source) from None

    @property
    def fields(self) -> tuple[str, ...]:
        """Names of the values one slot holds, in order."""
        return PARAMETER_FIELDS if self.kind == "notch_parameters" else COEFFICIENT_FIELDS

    # --- host side -------------------------------------------------------------------

    def encode(self, biquad: Biquad, spec: NotchSpec | None = None) -> dict[str, float | int]:
        """The values to write for a notch designed as ``biquad`` (coefficients) or ``spec``.

        Raises
        ------
        DataError
            A value does not fit the encoding (coefficient overflow, frequency
            beyond the integer range), or ``spec`` is missing for
            ``"notch_parameters"``.
        """
        if self.kind == "real32":
            values = (*biquad.b, biquad.a[1], biquad.a[2])
            return {name: float32(v) for name, v in zip(COEFFICIENT_FIELDS, values)}
        if self.kind == "fixed":
            q = quantize_biquad(biquad, self.fractional_bits, self.total_bits)
            scale = 2.0**self.fractional_bits
            values = (*q.b, q.a[1], q.a[2])
            return {name: int(round(v * scale)) for name, v in zip(COEFFICIENT_FIELDS, values)}
        if spec is None:
            raise DataError("this drive takes notch parameters (centre, width, depth); no NotchSpec was given")
        out = {}
        for name, value, scale in (("center", spec.center_hz, self.center_scale),
                                   ("width", spec.width_hz, self.width_scale),
                                   ("depth", spec.depth_db, self.depth_scale)):
            if not math.isfinite(value):
                raise DataError(f"notch {name} {value!r} cannot be encoded as an integer")
            n = int(round(value / scale))
            if not 1 <= n <= self.max_value:
                raise DataError(
                    f"notch {name} {value:g} is {n} steps of {scale:g}; the drive takes 1..{self.max_value}"
                )
            out[name] = n
        return out

    # --- what the drive applies ------------------------------------------------------

    def applied(self, values: dict[str, float | int], filter_rate_hz: float) -> Biquad:
        """The biquad a drive runs after receiving ``values`` (its own arithmetic).

        Raises
        ------
        DataError
            A field is missing, or the values give an unstable or invalid filter.
        """
        missing = [f for f in self.fields if f not in values]
        if missing:
            raise DataError(f"filter slot values lack {', '.join(missing)}")
        if self.kind == "real32":
            return _float32_biquad(*(values[f] for f in COEFFICIENT_FIELDS))
        if self.kind == "fixed":
            scale = 2.0**self.fractional_bits
            c = [int(values[f]) / scale for f in COEFFICIENT_FIELDS]
            section = Biquad(tuple(c[:3]), (1.0, c[3], c[4]))
            if not section.is_stable():
                raise DataError(f"fixed-point coefficients {dict(values)} give an unstable filter")
            return section
        spec = self.parameters(values)
        if spec.center_hz >= filter_rate_hz / 2:
            raise DataError(f"notch centre {spec.center_hz:g} Hz is not below half the {filter_rate_hz:g} Hz filter rate")
        designed = design_notch(spec, filter_rate_hz)
        return _float32_biquad(*designed.b, designed.a[1], designed.a[2])

    def parameters(self, values: dict[str, float | int]) -> NotchSpec:
        """``"notch_parameters"``: the physical notch the integers stand for."""
        try:
            return NotchSpec(int(values["center"]) * self.center_scale, int(values["width"]) * self.width_scale,
                             int(values["depth"]) * self.depth_scale)
        except ConfigError as exc:
            raise DataError(f"notch parameters {dict(values)}: {exc.message}") from None

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None, filter_rate_hz: float) -> Biquad:
        """What the drive will run when the host writes the notch ``biquad``/``spec``."""
        return self.applied(self.encode(biquad, spec), filter_rate_hz)
