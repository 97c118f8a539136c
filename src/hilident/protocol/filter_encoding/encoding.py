""":class:`FilterEncoding`: one drive's filter-slot encoding, checked, and both ends of the wire.

The host encodes a notch into the values it writes (:meth:`FilterEncoding.encode`,
:meth:`FilterEncoding.realise`); the drive, real or emulated, runs the section
those values give (:meth:`FilterEncoding.applied`). The vocabulary is in the
docstring of :mod:`hilident.protocol.filter_encoding`.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, replace
from typing import ClassVar

from hilident.config.schema import build_table, spec
from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, quantize_biquad
from hilident.protocol.filter_encoding import fit, grid
from hilident.protocol.filter_encoding.block import PRESETS, BlockLayout, block_section, encode_block
from hilident.protocol.filter_encoding.fit import Realisation
from hilident.protocol.filter_encoding.vocabulary import (
    COEFFICIENT_FIELDS,
    DEPTH_UNITS,
    ENCODINGS,
    FLOAT32_MAX,
    PARAMETRIC,
    WIDTH_UNITS,
    checked_range,
    default_fields,
    fail,
    float32,
    float32_biquad,
    int_in,
    positive,
    stored_coefficients,
)

__all__ = ["FilterEncoding"]


def _steps_within(value: float, scale: float, lo: float, hi: float) -> int:
    """The whole number of ``scale`` steps nearest ``value`` that stays within ``[lo, hi]`` (physical units)."""
    n = round(value / scale)
    if n * scale < lo:
        n += 1
    if n * scale > hi:
        n -= 1
    return int(n)


#: (pole field, zero field) pairs of the encodings whose section is the identity when its zeros sit on its poles.
_NEUTRAL_PAIRS = {
    "pole_zero_q": (("pole_hz", "zero_hz"), ("pole_q", "zero_q")),
    "pole_zero_damping": (("den_hz", "num_hz"), ("den_damping", "num_damping")),
}
#: fields of the encodings whose section is the identity when they hold these physical values
_NEUTRAL_VALUES = {"center_ratio_damping": {"ratio": 1.0, "damping_ratio": 1.0}}
#: the default physical units per stored step of an encoding's fields (0.0: REAL32), where not 1
_DEFAULT_SCALES = {
    # vendors of these keep REAL32 parameters unless the table says otherwise
    "pole_zero_q": 0.0,
    "pole_zero_damping": 0.0,
    # Beckhoff AX2000: Integer32 with weighting 1000 on the bus
    "center_ratio_damping": 0.001,
}


@dataclass(frozen=True, kw_only=True)
class _FiltersTable:
    """The keys of ``[filters]`` that choose and shape the encoding, as
    :func:`~hilident.config.schema.build_table` reads them.

    The table is open: it also holds a word block's keys (:meth:`BlockLayout.from_table`) and where the
    transport keeps the slots. Lists and tables are checked entry by entry by :class:`FilterEncoding`
    (a depth table may hold ``inf``, a full cut, which the schema's numbers may not).
    """

    open_table: ClassVar[bool] = True
    encoding: str = spec(choices=ENCODINGS, doc="how a slot stores a notch (docs/filter_encodings.md)")
    fractional_bits: int = spec(29, ge=0, le=62, doc='"fixed": fractional bits of the Q format')
    total_bits: int = spec(32, ge=2, le=64, doc='"fixed": bits of a coefficient')
    center_scale: float = spec(0.1, gt=0.0, doc='"notch_parameters": Hz per stored step of the centre')
    width_scale: float = spec(0.1, gt=0.0, doc='"notch_parameters": Hz per stored step of the width')
    depth_scale: float = spec(0.1, gt=0.0, doc='"notch_parameters": dB per stored step of the depth')
    max_value: int = spec(65535, ge=1, le=2**32 - 1, doc='"notch_parameters": largest integer a field holds')
    order: list | None = spec(None, doc="the fields in the order the slot holds them")
    feedback_sign: str = spec(
        "", choices=("", "minus", "plus"), doc='sign of the stored feedback terms; "": the preset\'s, else "minus"'
    )
    scales: dict = spec({}, doc="physical units per stored step of each field (0: REAL32)")
    ranges: dict = spec({}, doc="[low, high] of each field, physical units")
    resolution: dict = spec({}, doc="step a REAL32 field is rounded to by the drive")
    width_table: list = spec([], doc="bandwidth/centre ratio of each width setting")
    depth_table: list = spec([], doc="depth in dB of each depth setting (inf: a full cut)")
    width_values: list | None = spec(None, doc="the integer stored for each width_table entry")
    depth_values: list | None = spec(None, doc="the integer stored for each depth_table entry")
    width_unit: str = spec("hz", choices=WIDTH_UNITS, doc='"notch_parameters": how the width is expressed')
    depth_unit: str = spec("db", choices=DEPTH_UNITS, doc='"notch_parameters": how the depth is expressed')


@dataclass(frozen=True)
class FilterEncoding:
    """One drive's filter-slot encoding.

    Parameters
    ----------
    kind : str
        One of :data:`ENCODINGS`.
    fractional_bits, total_bits : int
        ``"fixed"`` only: the Q format.
    center_scale, width_scale, depth_scale : float
        ``"notch_parameters"`` only: physical value per integer step (Hz, Hz, dB).
    max_value : int
        ``"notch_parameters"`` only: largest integer a field holds (65535 for
        16-bit registers, 4294967295 for UNSIGNED32 objects).
    order : tuple of str, optional
        Field order (the default order of the kind when omitted).
    feedback_sign : {"minus", "plus"}
        Coefficient encodings: sign of the stored feedback terms.
    scales, ranges, resolution : dict
        Physical-parameter encodings: per field, physical units per integer
        step (``0`` for a REAL32 field), ``(low, high)`` in physical units, and
        the step a REAL32 field is rounded to by the drive.
    width_table, depth_table : tuple of float
        ``"index_table"`` (and ``"notch_parameters"`` with an ``"index"`` unit):
        bandwidth/centre ratio and depth in dB (positive, ``inf`` = full cut)
        for each stored value.
    width_values, depth_values : tuple of int, optional
        The stored integer of each table entry (``0, 1, ...`` when omitted).
    block : BlockLayout, optional
        ``"word_block"`` only.
    width_unit : {"hz", "q", "ratio", "index"}
        ``"notch_parameters"``: the width field in Hz, as a Q (centre / width),
        as width / centre, or as an index into ``width_table``.
    depth_unit : {"db", "ratio", "percent", "index", "full"}
        ``"notch_parameters"``: the depth field in dB, or as the gain at the
        centre (0 = full cut), plain or in percent, or an index into
        ``depth_table``; ``"full"``: no depth field, the slot always cuts fully.
    """

    kind: str
    fractional_bits: int = 29
    total_bits: int = 32
    center_scale: float = 0.1
    width_scale: float = 0.1
    depth_scale: float = 0.1
    max_value: int = 65535
    order: tuple[str, ...] | None = None
    feedback_sign: str = "minus"
    scales: dict[str, float] = field(default_factory=dict)
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    resolution: dict[str, float] = field(default_factory=dict)
    width_table: tuple[float, ...] = ()
    depth_table: tuple[float, ...] = ()
    width_values: tuple[int, ...] | None = None
    depth_values: tuple[int, ...] | None = None
    block: BlockLayout | None = None
    width_unit: str = "hz"
    depth_unit: str = "db"

    def __post_init__(self):
        if self.kind not in ENCODINGS:
            fail("encoding", f"must be one of {ENCODINGS}, got {self.kind!r}")
        for key in ("center_scale", "width_scale", "depth_scale"):
            positive(key, getattr(self, key))
        int_in("fractional_bits", self.fractional_bits, 0, 62)
        int_in("total_bits", self.total_bits, 2, 64)
        int_in("max_value", self.max_value, 1, 2**32 - 1)
        if self.fractional_bits >= self.total_bits:
            fail("fractional_bits", f"must be below total_bits = {self.total_bits}, got {self.fractional_bits}")
        if self.feedback_sign not in ("minus", "plus"):
            fail("feedback_sign", f'must be "minus" or "plus", got {self.feedback_sign!r}')
        if self.width_unit not in WIDTH_UNITS:
            fail("width_unit", f"must be one of {WIDTH_UNITS}, got {self.width_unit!r}")
        if self.depth_unit not in DEPTH_UNITS:
            fail("depth_unit", f"must be one of {DEPTH_UNITS}, got {self.depth_unit!r}")
        if self.kind == "word_block" and self.block is None:
            object.__setattr__(self, "block", BlockLayout.from_table({"preset": "copley"}))
        default = (
            ("block",)
            if self.kind == "word_block"
            else default_fields(self.kind, self.depth_unit)
            if self.kind in PARAMETRIC
            else COEFFICIENT_FIELDS
        )
        order = (
            tuple(self.order)
            if isinstance(self.order, (list, tuple))
            else default
            if self.order is None
            else (self.order,)
        )
        if not all(isinstance(x, str) for x in order) or sorted(order) != sorted(default):
            fail("order", f"must list each of {default} once, got {list(order)}")
        object.__setattr__(self, "order", order)
        if self.kind in PARAMETRIC:
            self._check_parameters()

    def __hash__(self):
        return hash(
            (
                self.kind,
                self.order,
                self.feedback_sign,
                self.fractional_bits,
                self.total_bits,
                self.width_unit,
                self.depth_unit,
                tuple(sorted(self.scales.items())),
                tuple(sorted(self.ranges.items())),
                self.block,
            )
        )

    def _check_parameters(self) -> None:
        """Validate and complete ``scales``, ``ranges``, ``resolution`` and the index tables of a parametric kind."""
        names = default_fields(self.kind, self.depth_unit)
        for table_name in ("scales", "ranges", "resolution"):
            table = getattr(self, table_name)
            if not isinstance(table, dict) or not set(table) <= set(names):
                fail(table_name, f"must be a table with keys among {names}, got {table!r}")
        object.__setattr__(self, "scales", self._checked_scales(names))
        object.__setattr__(self, "ranges", {name: checked_range(name, r) for name, r in self.ranges.items()})
        object.__setattr__(self, "resolution", {k: positive(f"resolution.{k}", v) for k, v in self.resolution.items()})
        for name in ("width", "depth"):
            if grid.is_index(self, name):
                self._check_index_table(name)

    def _checked_scales(self, names) -> dict:
        """Scale of each field: the kind's default (0.0: REAL32), overridden by ``scales``."""
        scales = {name: _DEFAULT_SCALES.get(self.kind, 1.0) for name in names}
        if self.kind == "notch_parameters":
            given = {"center": self.center_scale, "width": self.width_scale, "depth": self.depth_scale}
            scales.update({name: given[name] for name in names})
        scales.update({k: positive(f"scales.{k}", v, zero_ok=True) for k, v in self.scales.items()})
        return scales

    def _check_index_table(self, name: str) -> None:
        """``<name>_table`` (the physical values) and ``<name>_values`` (what is stored for each)."""
        table = getattr(self, f"{name}_table")
        if not isinstance(table, (list, tuple)) or not table:
            fail(f"{name}_table", "must be a non-empty list of numbers")
        values = tuple(
            positive(f"{name}_table", v, zero_ok=name == "depth")
            if not (name == "depth" and v == math.inf)
            else math.inf
            for v in table
        )
        object.__setattr__(self, f"{name}_table", values)
        stored = getattr(self, f"{name}_values")
        if stored is None:
            return
        if not isinstance(stored, (list, tuple)) or len(stored) != len(values):
            fail(f"{name}_values", f"must list one stored integer per {name}_table entry")
        stored = tuple(int_in(f"{name}_values", v, 0, 2**32 - 1) for v in stored)
        if len(set(stored)) != len(stored):
            fail(f"{name}_values", "must not repeat a stored integer")
        object.__setattr__(self, f"{name}_values", stored)

    @classmethod
    def from_table(cls, table: dict, source: str = "") -> FilterEncoding:
        """Build from a driver description's ``[filters]`` table (keys of other layers are ignored).

        The keys go through the typed schema (:class:`_FiltersTable`,
        :func:`hilident.config.schema.build_table`), then through the checks of the
        encoding itself; a word block's keys through :meth:`BlockLayout.from_table`.

        Raises
        ------
        ConfigError
            A key is missing, of the wrong type or out of range; names the key and ``source``.
        """
        keys = build_table(_FiltersTable, table, "filters.", source)
        try:
            block = BlockLayout.from_table(table) if keys.encoding == "word_block" else None
            preset = (
                PRESETS.get(table["preset"], {}) if block is not None and isinstance(table.get("preset"), str) else {}
            )
            preset_sign = preset.get("feedback_sign")
            return cls(
                keys.encoding,
                fractional_bits=keys.fractional_bits,
                total_bits=keys.total_bits,
                center_scale=keys.center_scale,
                width_scale=keys.width_scale,
                depth_scale=keys.depth_scale,
                max_value=keys.max_value,
                order=None if keys.order is None else tuple(keys.order),
                feedback_sign=keys.feedback_sign or (preset_sign if isinstance(preset_sign, str) else "minus"),
                scales=keys.scales,
                ranges=keys.ranges,
                resolution=keys.resolution,
                width_table=tuple(keys.width_table),
                depth_table=tuple(keys.depth_table),
                width_values=None if keys.width_values is None else tuple(keys.width_values),
                depth_values=None if keys.depth_values is None else tuple(keys.depth_values),
                block=block,
                width_unit=keys.width_unit,
                depth_unit=keys.depth_unit,
            )
        except ConfigError as exc:
            raise ConfigError(exc.key, exc.message, source) from None

    @property
    def fields(self) -> tuple[str, ...]:
        """Names of the values one slot holds, in order (``("block",)`` for a word block)."""
        assert self.order is not None  # __post_init__ completes it
        return self.order

    @property
    def layout(self) -> BlockLayout:
        """``"word_block"``: the block layout (DataError for the encodings that have none)."""
        if self.block is None:
            raise DataError(f'the "{self.kind}" encoding stores no word block')
        return self.block

    def value_kind(self, name: str) -> str:
        """What field ``name`` holds on the wire: ``"float32"`` (a REAL32 object or register),
        ``"integer"`` (signed for ``"fixed"``, unsigned otherwise) or ``"octets"`` (a word block of
        ``2 * block.words`` bytes) -- for checking a driver description against its EDS.

        Raises
        ------
        DataError
            ``name`` is no field of this encoding.
        """
        if name not in self.fields:
            raise DataError(f'"{name}" is no field of the {self.kind} encoding (fields: {", ".join(self.fields)})')
        if self.kind == "word_block":
            return "octets"
        if self.kind == "real32" or (
            self.kind in PARAMETRIC and not grid.is_index(self, name) and self.scales[name] == 0.0
        ):
            return "float32"
        return "integer"

    def encode(self, biquad: Biquad, spec: NotchSpec | None = None) -> dict:
        """The values to write for a notch designed as ``biquad`` (coefficients) or ``spec``.

        Coefficient encodings round ``biquad``; physical-parameter encodings
        take the nearest stored value of each field (``"notch_parameters"``
        refuses values beyond its integer range, the others clamp into their
        ranges).  :meth:`realise` fits the notch instead and explains.

        Raises
        ------
        DataError
            A value does not fit the encoding (coefficient overflow, frequency
            beyond the integer range), or ``spec`` is missing for a
            physical-parameter encoding.
        """
        if self.kind in ("real32", "fixed"):
            return self._encode_coefficients(biquad)
        if self.kind == "word_block":
            return {"block": encode_block(self.layout, biquad, spec, self.feedback_sign)}
        if spec is None:
            raise DataError(f"this drive takes notch parameters ({', '.join(self.fields)}); no NotchSpec was given")
        if self.kind == "notch_parameters" and grid.legacy_units(self):
            return self._encode_notch_parameters(spec)
        ideal = grid.ideal(self, spec)
        return {name: grid.nearest(self, name, grid.clamp(self, name, ideal[name])) for name in self.fields}

    def _encode_coefficients(self, biquad: Biquad) -> dict:
        """``"real32"`` and ``"fixed"``: the five coefficients of ``biquad`` rounded to the format."""
        if self.kind == "real32":
            values = stored_coefficients((*biquad.b, biquad.a[1], biquad.a[2]), self.feedback_sign)
            out = dict(zip(COEFFICIENT_FIELDS, map(float32, values), strict=False))
        else:
            q = quantize_biquad(biquad, self.fractional_bits, self.total_bits)
            scale = 2.0**self.fractional_bits
            values = stored_coefficients((*q.b, q.a[1], q.a[2]), self.feedback_sign)
            out = {name: int(round(v * scale)) for name, v in zip(COEFFICIENT_FIELDS, values, strict=False)}
        return {name: out[name] for name in self.fields}

    def _encode_notch_parameters(self, spec: NotchSpec) -> dict:
        """``"notch_parameters"`` in Hz and dB: each value in whole steps, refused beyond 1..max_value."""
        out = {}
        for name, value in (("center", spec.center_hz), ("width", spec.width_hz), ("depth", spec.depth_db)):
            scale = self.scales[name]
            if not math.isfinite(value):
                raise DataError(f"notch {name} {value!r} cannot be encoded as an integer")
            n = int(round(value / scale))
            if not 1 <= n <= self.max_value:
                raise DataError(
                    f"notch {name} {value:g} is {n} steps of {scale:g}; the drive takes 1..{self.max_value}"
                )
            out[name] = n
        return {name: out[name] for name in self.fields}

    def slot_enabled(self, values: dict) -> bool | None:
        """``"word_block"``: whether the block's state word enables the slot; ``None`` for other
        encodings (their enable is a separate object or register)."""
        if self.kind != "word_block":
            return None
        return self.layout.is_enabled(self.layout.unpack(values.get("block")))

    def disabled(self, values: dict) -> dict:
        """``"word_block"``: the values with the state word set to bypass, coefficients kept.

        Writing the saved block back later restores the slot as it was.

        Raises
        ------
        DataError
            The encoding keeps its enable elsewhere, or the block is malformed.
        """
        return self._with_state(values, enabled=False)

    def enabled(self, values: dict) -> dict:
        """``"word_block"``: the values with the state word set to run the filter, coefficients kept
        (what a slot read back disabled would run once enabled)."""
        return self._with_state(values, enabled=True)

    def _with_state(self, values: dict, enabled: bool) -> dict:
        """``"word_block"``: ``values`` with the state word set to run (``enabled``) or bypass the filter."""
        if self.kind != "word_block":
            raise DataError(f'the "{self.kind}" encoding has no enable of its own; write the slot\'s enable object')
        lay = self.layout
        words = lay.unpack(values.get("block"))
        state = lay.enabled_value if enabled else lay.disabled_value
        words[lay.state_word] = (words[lay.state_word] & ~lay.state_mask & 0xFFFF) | (state & lay.state_mask)
        return {"block": lay.pack(words)}

    @property
    def bypassable(self) -> bool:
        """The encoding has values that run the identity section (:meth:`neutral`): a slot without an
        enable of its own can still be bypassed."""
        return self.kind in _NEUTRAL_PAIRS or self.kind in _NEUTRAL_VALUES

    def neutral(self, values: dict) -> dict:
        """Values that run the identity section: how a slot that has no enable of its own is bypassed.

        Pole/zero encodings put each zero field and its pole field on one
        value: the pole's, moved into the range both fields share.
        ``"center_ratio_damping"`` sets the frequency ratio and the damping
        ratio to 1.

        Raises
        ------
        DataError
            The encoding has no neutral setting (its slots need an enable), a pole's and its zero's
            ranges do not meet, or a ratio's range leaves out 1.
        """
        if self.kind in _NEUTRAL_VALUES:
            self._check_values(values)
            return {**values, **{name: self._stored_exactly(name, x) for name, x in _NEUTRAL_VALUES[self.kind].items()}}
        pairs = _NEUTRAL_PAIRS.get(self.kind)
        if pairs is None:
            raise DataError(f'the "{self.kind}" encoding has no setting that bypasses the slot; it needs an enable')
        self._check_values(values)
        out = dict(values)
        for pole, zero in pairs:
            (lo_p, hi_p), (lo_z, hi_z) = (self.ranges.get(n, (-math.inf, math.inf)) for n in (pole, zero))
            lo, hi = max(lo_p, lo_z), min(hi_p, hi_z)
            scale = self.scales.get(pole, 0.0)
            if lo > hi or scale != self.scales.get(zero, 0.0):
                raise DataError(f"{pole} and {zero} cannot hold one value: the slot cannot be bypassed")
            common = min(max(float(values[pole]) * (scale or 1.0), lo), hi)
            stored = float32(common) if not scale else _steps_within(common, scale, lo, hi)
            out[pole] = out[zero] = stored
        return out

    def _stored_exactly(self, name: str, x: float):
        """The stored value of field ``name`` that stands for ``x`` exactly (DataError when none does)."""
        stored = grid.nearest(self, name, x) if grid.in_range(self, name, x) else None
        if stored is None or grid.physical(self, name, stored) != x:
            low, high = self.ranges.get(name, (0.0, math.inf))
            raise DataError(f"{name} cannot hold {x:g} (range {low:g}..{high:g}): the slot cannot be bypassed")
        return stored

    def parameters(self, values: dict) -> NotchSpec:
        """Physical-parameter encodings: the notch the stored values stand for (rate independent).

        ``"center_band"`` reports the -3 dB width ``3 band / pi`` and an infinite
        depth (as does ``"notch_parameters"`` with ``depth_unit = "full"``); the
        pole/zero and centre/ratio encodings report the centre at the zero
        frequency, the width ``2 D_pole f_pole`` and the depth
        ``20 log10(D_pole / D_zero)``.

        Raises
        ------
        DataError
            A field is missing, out of range, or the values are no notch.
        """
        missing = [f for f in self.fields if f not in values]
        if missing or self.kind not in PARAMETRIC:
            raise DataError(
                f"filter slot values lack {', '.join(missing)}"
                if missing
                else f'the "{self.kind}" encoding stores coefficients, not notch parameters'
            )
        center, width, depth = grid.notch_triplet(self, grid.physical_values(self, values))
        try:
            return NotchSpec(center, width, depth)
        except ConfigError as exc:
            raise DataError(f"notch parameters {dict(values)}: {exc.message}") from None

    def applied(self, values: dict, filter_rate_hz: float) -> Biquad:
        """The biquad a drive runs after receiving ``values`` (its own arithmetic).

        A disabled word block applies the identity section.

        Raises
        ------
        DataError
            A field is missing, or the values give an unstable or invalid filter.
        """
        self._check_values(values)
        if self.kind == "real32":
            return float32_biquad(*stored_coefficients([values[f] for f in COEFFICIENT_FIELDS], self.feedback_sign))
        if self.kind == "fixed":
            scale = 2.0**self.fractional_bits
            c = stored_coefficients([int(values[f]) / scale for f in COEFFICIENT_FIELDS], self.feedback_sign)
            section = Biquad((c[0], c[1], c[2]), (1.0, c[3], c[4]))
            if not section.is_stable():
                raise DataError(f"fixed-point coefficients {dict(values)} give an unstable filter")
            return section
        if self.kind == "word_block":
            words = self.layout.unpack(values["block"])
            if not self.layout.is_enabled(words):
                return Biquad.identity()
            section = block_section(self.layout, words, self.feedback_sign)
            if not section.is_stable():
                raise DataError(f"filter block coefficients b = {section.b}, a = {section.a} give an unstable filter")
            return section
        return self._section_of(values, filter_rate_hz)

    def _check_values(self, values: dict) -> None:
        """Every field present and of a type the encoding stores (values come from a wire)."""
        if not isinstance(values, dict):
            raise DataError(f"filter slot values must be a mapping of {self.fields}, got {type(values).__name__}")
        missing = [f for f in self.fields if f not in values]
        if missing:
            raise DataError(f"filter slot values lack {', '.join(missing)}")
        if self.kind == "word_block":
            return
        for name in self.fields:
            v = values[name]
            integral = self.kind == "fixed" or (
                self.kind in PARAMETRIC and (grid.is_index(self, name) or self.scales[name] != 0.0)
            )
            kind = "an integer" if integral else "a finite REAL32 number"
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise DataError(f"filter field {name} must be {kind}, got {v!r}")
            x = float(v)
            if not math.isfinite(x) or (integral and int(x) != x) or (not integral and abs(x) > FLOAT32_MAX):
                raise DataError(f"filter field {name} must be {kind}, got {v!r}")

    def _section_of(self, values: dict, rate: float) -> Biquad:
        """Physical-parameter encodings: the section the drive builds from ``values`` at ``rate`` (Hz)."""
        if self.kind in ("notch_parameters", "index_table"):
            center, _, depth = grid.notch_triplet(self, grid.physical_values(self, values))
            if center >= rate / 2:
                raise DataError(f"notch centre {center:g} Hz is not below half the {rate:g} Hz filter rate")
            if depth <= 0.0:
                return Biquad.identity()
            spec = self.parameters(values)
            designed = design_notch(spec, rate)
            return float32_biquad(*designed.b, designed.a[1], designed.a[2])
        return grid.parametric_section(self, grid.physical_values(self, values), rate)

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None, filter_rate_hz: float) -> Biquad:
        """What the drive will run when the host writes the notch ``biquad``/``spec``."""
        return self.applied(self.encode(biquad, spec), filter_rate_hz)

    def realise(self, spec: NotchSpec, filter_rate_hz: float) -> Realisation:
        """Fit ``spec`` to what this encoding can store, and say what the drive will do.

        Coefficient encodings store the pre-warped Tustin design rounded to
        their format.  Physical-parameter encodings try the stored values
        around the ideal ones (two grid steps or table entries each side of
        every field, clamped into the ranges) and keep the candidate whose
        attenuation at ``spec.center_hz`` (the resonance) is closest to
        ``spec.depth_db`` without being less deep, ties going to the width
        closest to ``spec.width_hz``; when none is deep enough, the deepest.

        Parameters
        ----------
        spec : NotchSpec
            The notch asked for: centre (the resonance), width and depth.
        filter_rate_hz : float
            Rate the drive runs the filter at, Hz.

        Returns
        -------
        Realisation
            Values to write, the section the drive runs, its achieved notch,
            attenuation at the asked centre, and notes when the depth or width
            cannot be reached.

        Raises
        ------
        DataError
            No stored value gives a valid filter (a centre beyond half the rate,
            coefficients that overflow the format).

        Notes
        -----
        The fit is remembered per encoding, notch and rate: on a parameter
        grid it weighs hundreds of candidates (about 0.4 s), and one upload
        asks for the same fit when it plans, writes and reports.
        """
        realised = fit.remembered_fit(self, spec, float(filter_rate_hz))
        return replace(realised, fields=dict(realised.fields))  # the caller may change its copy
