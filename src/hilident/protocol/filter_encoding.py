"""How a drive stores a notch in one filter slot: the values a host writes.

Drives differ in what their filter objects or registers hold. A driver
description names one of these encodings (``[filters] encoding = ...``, the
vocabulary is in ``docs/filter_encodings.md``) and where each field lives; the
adapter encodes with it and the emulated drive decodes with it, so both sides
agree by construction of the wire, not by sharing state.

Coefficient encodings (the host designs the biquad, the drive runs it):

``"real32"``
    Five IEEE-754 single-precision coefficients (``a0 = 1``); the drive runs
    exactly those values.
``"fixed"``
    Five signed integers, coefficient times ``2**fractional_bits``, in
    ``total_bits`` two's complement; DC gain kept at 1 (see
    :func:`~hilident.filters.notch.quantize_biquad`).
``"word_block"``
    One octet string holding the whole slot as 16-bit words: INT16
    coefficients with a common unsigned scaler ``K`` (``c = n K / 2**scaler_bits``,
    Copley's first generation: ``y = K (...) / 32768 / 4096``), or float32
    coefficients split over two words.  Its only field is ``"block"`` whose
    value is ``bytes``.  The slot's enable lives in the block itself: a state
    word whose bits under ``state_mask`` equal ``disabled_value`` means
    bypassed (Copley: word 1 = 0xFFFF; Copley plus family: type bits 13-15 = 7).
    :meth:`FilterEncoding.slot_enabled` reads it, :meth:`FilterEncoding.disabled`
    gives the block to write to bypass the slot while keeping its
    coefficients, and writing back the saved block restores it.

For ``"real32"``, ``"fixed"`` and ``"word_block"``, ``order`` gives the
field order and ``feedback_sign`` the sign convention of the stored feedback
terms: ``"minus"`` (scipy, ``y = b0 x + ... - a1 y[-1] - a2 y[-2]``) or
``"plus"`` (``y = b0 x + ... + a1 y[-1] + a2 y[-2]``, Copley), in which case
the stored ``a1, a2`` are the negated scipy ones.

Physical-parameter encodings (the drive builds the biquad itself; each field
has a ``scale`` -- physical units per integer step, or ``0`` for a REAL32 field
-- a ``range`` in physical units and an optional ``resolution``):

``"notch_parameters"``
    ``center``, ``width``, ``depth`` (Hz, Hz, dB -- or the width as a Q, a
    ratio to the centre or an index into ``width_table`` of bandwidth/centre
    ratios, the depth as a gain ratio, percent or an index into ``depth_table``
    of dB, see ``width_unit`` and ``depth_unit``); pre-warped Tustin notch
    (:func:`~hilident.filters.notch.design_notch`).
``"pole_zero_q"``
    ``pole_hz``, ``pole_q``, ``zero_hz``, ``zero_q`` (Kollmorgen-style
    anti-resonance filter ``(s^2/wz^2 + s/(Qz wz) + 1) / (s^2/wp^2 + s/(Qp wp) + 1)``);
    depth at the centre ``Qz / Qp``.
``"pole_zero_damping"``
    ``num_hz``, ``num_damping``, ``den_hz``, ``den_damping`` (Siemens-style
    general second-order filter; band-stop: ``D_N = f_BB / (2 f)``,
    ``D_Z = 10**(-depth/20) D_N``).
``"index_table"``
    ``center`` (Hz), ``width`` and ``depth`` as indices into tables of
    bandwidth/centre ratios and depths in dB (Panasonic-style).
``"center_band"``
    ``center`` and ``band`` in Hz, full depth (Synapticon-style, the vendor's
    discrete formula, :func:`~hilident.filters.parametric.rejection_band_section`).

The two pole/zero encodings are discretised by the bilinear transform with the
numerator pre-warped at its natural frequency and the denominator at its own
(:func:`~hilident.filters.parametric.two_frequency_section`), so the zeros and
poles sit at the stored frequencies; Kollmorgen documents a backward-Euler form
pre-warped the same way, which differs from this one only far above the notch.

:meth:`FilterEncoding.realise` fits a :class:`~hilident.filters.notch.NotchSpec`
to what the encoding can store and says what it achieves.

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
>>> r = FilterEncoding("center_band", ranges={"center": (10, 2000), "band": (1, 4000)}).realise(spec, 4000.0)
>>> r.fields, round(r.attenuation_db, 1)
({'center': 22, 'band': 8}, 24.8)
>>> r.notes
('the center_band encoding reaches 24.8 dB at 21.7849 Hz, not the 40 dB asked',)
"""

from __future__ import annotations

import functools
import itertools
import math
import numbers
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal, NoReturn

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, quantize_biquad
from hilident.filters.parametric import (
    achieved_notch,
    attenuation_db,
    notch_width_hz,
    rejection_band_section,
    two_frequency_section,
)

COEFFICIENT_FIELDS = ("b0", "b1", "b2", "a1", "a2")
PARAMETER_FIELDS = ("center", "width", "depth")
#: the fields of each physical-parameter encoding, in their default order
PARAMETRIC = {
    "notch_parameters": PARAMETER_FIELDS,
    "pole_zero_q": ("pole_hz", "pole_q", "zero_hz", "zero_q"),
    "pole_zero_damping": ("num_hz", "num_damping", "den_hz", "den_damping"),
    "index_table": PARAMETER_FIELDS,
    "center_band": ("center", "band"),
}
ENCODINGS = ("real32", "fixed", "word_block", *PARAMETRIC)

#: Copley first generation: 9 INT16 words [info, info, info, b2, b1, b0, a2, a1, K], word 1 = 0xFFFF disabled
COPLEY = {"words": 9, "coefficient_format": "int16", "coefficient_words": {"b2": 3, "b1": 4, "b0": 5, "a2": 6, "a1": 7},
          "scaler_word": 8, "scaler_bits": 27, "feedback_sign": "plus", "state_word": 0, "state_mask": 0xFFFF,
          "disabled_value": 0xFFFF, "enabled_value": 0x0000, "frequency_words": [], "byte_order": "little"}
#: Copley plus family: 14 words, word 1 type bits 13-15 (3 band reject, 7 disabled), bit 8 two poles, bit 4
#: designed; words 2/3 first/second frequency (Hz); words 5-14 a1, a2, b0, b1, b2 as float32, upper word first
COPLEY_PLUS = {"words": 14, "coefficient_format": "float32",
               "coefficient_words": {"a1": 4, "a2": 6, "b0": 8, "b1": 10, "b2": 12}, "word_order": "high_first",
               "feedback_sign": "plus", "state_word": 0, "state_mask": 0xE000, "disabled_value": 0xE000,
               "enabled_value": 0x6110, "frequency_words": [1, 2], "byte_order": "little"}
PRESETS = {"copley": COPLEY, "copley_plus": COPLEY_PLUS}
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
DEEPER = {"depth": 1, "zero_q": 1, "num_damping": -1}
#: ``"notch_parameters"``: how the width and depth fields are expressed
WIDTH_UNITS = ("hz", "q", "ratio", "index")
DEPTH_UNITS = ("db", "ratio", "percent", "index")
#: pairs of fields that must hold the same frequency for the section to be a notch
SAME_FREQUENCY = {"pole_zero_q": ("pole_hz", "zero_hz"), "pole_zero_damping": ("num_hz", "den_hz")}


FLOAT32_MAX = 3.4028234663852886e38

#: how a candidate meets the asked notch, smaller is better: (too shallow, depth error in dB, width error as
#: the absolute log ratio), see :func:`_depth_key`
_Key = tuple[bool, float, float]
#: a candidate's key, its field values and the section the drive runs with them
_Candidate = tuple[_Key, dict, Biquad]


def float32(x: float) -> float:
    """``x`` rounded to IEEE-754 single precision (what a REAL32 object holds)."""
    return struct.unpack("<f", struct.pack("<f", float(x)))[0]


def _float32_biquad(b0, b1, b2, a1, a2) -> Biquad:
    return Biquad((float32(b0), float32(b1), float32(b2)), (1.0, float32(a1), float32(a2)))


def _fail(key: str, message: str) -> NoReturn:
    raise ConfigError(f"filters.{key}", message)


def _int_in(key: str, v, low: int, high: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
        _fail(key, f"must be an integer in {low}..{high}, got {v!r}")
    return v


def _positive(key: str, v, zero_ok: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 \
            or (v == 0 and not zero_ok):
        _fail(key, f"must be a {'non-negative' if zero_ok else 'positive'} number, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class BlockLayout:
    """Where a ``"word_block"`` slot keeps its coefficients and its enable (word indices from 0).

    Parameters
    ----------
    words : int
        16-bit words in the block (the octet string is ``2 * words`` bytes).
    coefficient_words : dict
        First word of each of ``b0, b1, b2, a1, a2``.
    coefficient_format : {"int16", "float32"}
        INT16 coefficients scaled by the scaler word, or float32 over two words.
    scaler_word, scaler_bits : int
        ``"int16"``: the word holding the unsigned scaler ``K``; a coefficient is
        ``n K / 2**scaler_bits``.
    word_order : {"high_first", "low_first"}
        ``"float32"``: which half of a coefficient comes first.
    byte_order : {"little", "big"}
        Byte order inside each word (CANopen octet strings: little).
    state_word, state_mask, disabled_value, enabled_value : int
        The slot is bypassed when ``word[state_word] & state_mask == disabled_value``;
        an enabled slot is written with ``enabled_value`` in that word.
    frequency_words : list of int
        Words that receive the notch's lower and upper -3 dB frequencies in Hz
        (informational; empty for none).
    """

    words: int
    coefficient_words: dict[str, int]
    coefficient_format: str = "int16"
    scaler_word: int | None = None
    scaler_bits: int = 27
    word_order: str = "high_first"
    byte_order: Literal["little", "big"] = "little"
    state_word: int = 0
    state_mask: int = 0xFFFF
    disabled_value: int = 0xFFFF
    enabled_value: int = 0
    frequency_words: tuple[int, ...] = ()

    def __hash__(self):
        return hash((self.words, tuple(sorted(self.coefficient_words.items())), self.coefficient_format,
                     self.scaler_word, self.state_word, self.disabled_value, self.enabled_value))

    @classmethod
    def from_table(cls, table: dict) -> BlockLayout:
        """Build from ``[filters]`` (``preset`` gives defaults, explicit keys win)."""
        preset = table.get("preset")
        if preset is not None and not (isinstance(preset, str) and preset in PRESETS):
            _fail("preset", f"must be one of {tuple(PRESETS)}, got {preset!r}")
        defaults = PRESETS[preset] if preset is not None else {}
        merged = {**defaults, **{k: table[k] for k in _BLOCK_KEYS if k in table}}
        if "words" not in merged or "coefficient_words" not in merged:
            _fail("words", 'a "word_block" encoding needs words and coefficient_words (or a preset)')
        words = _int_in("words", merged["words"], 1, 4096)
        fmt = merged.get("coefficient_format", "int16")
        if fmt not in ("int16", "float32"):
            _fail("coefficient_format", f'must be "int16" or "float32", got {fmt!r}')
        width = 2 if fmt == "float32" else 1
        cw = merged["coefficient_words"]
        if not isinstance(cw, dict) or set(cw) != set(COEFFICIENT_FIELDS):
            _fail("coefficient_words", f"must give the first word of each of {COEFFICIENT_FIELDS}, got {cw!r}")
        scaler = merged.get("scaler_word")
        state, freq = _block_words(merged, words, fmt, width)
        for key, allowed in (("word_order", ("high_first", "low_first")), ("byte_order", ("little", "big"))):
            if merged.get(key, allowed[0]) not in allowed:
                _fail(key, f"must be one of {allowed}, got {merged[key]!r}")
        return cls(words, dict(cw), fmt, scaler, _int_in("scaler_bits", merged.get("scaler_bits", 27), 0, 48),
                   merged.get("word_order", "high_first"), merged.get("byte_order", "little"), state,
                   _int_in("state_mask", merged.get("state_mask", 0xFFFF), 1, 0xFFFF),
                   _int_in("disabled_value", merged.get("disabled_value", 0xFFFF), 0, 0xFFFF),
                   _int_in("enabled_value", merged.get("enabled_value", 0), 0, 0xFFFF), freq)

    # --- words <-> bytes ---------------------------------------------------------------

    def pack(self, words: list[int]) -> bytes:
        """The octet string of ``words`` (each an unsigned 16-bit value)."""
        return b"".join(int(w).to_bytes(2, self.byte_order) for w in words)

    def unpack(self, block) -> list[int]:
        """The 16-bit words of an octet string.

        Raises
        ------
        DataError
            ``block`` is not bytes of exactly ``2 * words`` length.
        """
        if not isinstance(block, (bytes, bytearray)) or len(block) != 2 * self.words:
            size = len(block) if isinstance(block, (bytes, bytearray)) else type(block).__name__
            raise DataError(f"filter block must be {2 * self.words} bytes ({self.words} words), got {size}")
        return [int.from_bytes(block[i:i + 2], self.byte_order) for i in range(0, len(block), 2)]

    def is_enabled(self, words: list[int]) -> bool:
        return (words[self.state_word] & self.state_mask) != (self.disabled_value & self.state_mask)

    @property
    def scaler_index(self) -> int:
        """``"int16"``: the word holding the scaler ``K``.

        Raises
        ------
        DataError
            The layout names no scaler word (a block built without :meth:`from_table`).
        """
        if self.scaler_word is None:
            raise DataError('an "int16" word block needs scaler_word, the word of its scaler K')
        return self.scaler_word


def _checked_range(name: str, r) -> tuple[float, float]:
    """``ranges.<name> = [low, high]``: non-negative, low not above high."""
    if not isinstance(r, (list, tuple)) or len(r) != 2:
        _fail(f"ranges.{name}", f"must be [low, high], got {r!r}")
    low, high = _positive(f"ranges.{name}", r[0], zero_ok=True), _positive(f"ranges.{name}", r[1])
    if low > high:
        _fail(f"ranges.{name}", f"low {low:g} is above high {high:g}")
    return low, high


def _block_words(merged: dict, words: int, fmt: str, width: int) -> tuple[int, tuple[int, ...]]:
    """The state word and frequency words, checked with the coefficient and scaler words: in the block, apart."""
    cw = merged["coefficient_words"]
    used: list[int] = []
    for name in COEFFICIENT_FIELDS:
        w = _int_in(f"coefficient_words.{name}", cw[name], 0, words - width)
        used += range(w, w + width)
    scaler = merged.get("scaler_word")
    if fmt == "int16":
        if scaler is None:
            _fail("scaler_word", 'an "int16" block needs the word of its scaler K')
        used.append(_int_in("scaler_word", scaler, 0, words - 1))
    state = _int_in("state_word", merged.get("state_word", 0), 0, words - 1)
    listed = merged.get("frequency_words", [])
    if not isinstance(listed, (list, tuple)) or len(listed) not in (0, 2):
        _fail("frequency_words", f"must list two word indices or none, got {listed!r}")
    freq = tuple(_int_in("frequency_words", w, 0, words - 1) for w in listed)
    used += [state, *freq]
    if len(set(used)) != len(used):
        _fail("coefficient_words", f"coefficients, scaler, state and frequency words overlap: {sorted(used)}")
    return state, freq


_BLOCK_KEYS = ("words", "coefficient_words", "coefficient_format", "scaler_word", "scaler_bits", "word_order",
               "byte_order", "state_word", "state_mask", "disabled_value", "enabled_value", "frequency_words")


@dataclass(frozen=True)
class Realisation:
    """What a filter slot will do for a notch asked of it.

    Attributes
    ----------
    fields : dict
        The values to write (field name to integer, float or bytes).
    section : Biquad
        The biquad the drive runs with those values (:meth:`FilterEncoding.applied`).
    achieved : NotchSpec or None
        Centre, width and depth of ``section`` (``None`` when it is no notch).
    attenuation_db : float
        Attenuation of ``section`` at the asked centre (the resonance), dB.
    notes : tuple of str
        Why the asked notch could not be met (depth or width out of reach).
    """

    fields: dict[str, int | float | bytes]
    section: Biquad
    achieved: NotchSpec | None
    attenuation_db: float
    notes: tuple[str, ...] = ()


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
    depth_unit : {"db", "ratio", "percent", "index"}
        ``"notch_parameters"``: the depth field in dB, or as the gain at the
        centre (0 = full cut), plain or in percent.
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
    scales: dict = field(default_factory=dict)
    ranges: dict = field(default_factory=dict)
    resolution: dict = field(default_factory=dict)
    width_table: tuple = ()
    depth_table: tuple = ()
    width_values: tuple | None = None
    depth_values: tuple | None = None
    block: BlockLayout | None = None
    width_unit: str = "hz"
    depth_unit: str = "db"

    def __post_init__(self):
        if self.kind not in ENCODINGS:
            _fail("encoding", f"must be one of {ENCODINGS}, got {self.kind!r}")
        for key in ("center_scale", "width_scale", "depth_scale"):
            _positive(key, getattr(self, key))
        _int_in("fractional_bits", self.fractional_bits, 0, 62)
        _int_in("total_bits", self.total_bits, 2, 64)
        _int_in("max_value", self.max_value, 1, 2**32 - 1)
        if self.fractional_bits >= self.total_bits:
            _fail("fractional_bits", f"must be below total_bits = {self.total_bits}, got {self.fractional_bits}")
        if self.feedback_sign not in ("minus", "plus"):
            _fail("feedback_sign", f'must be "minus" or "plus", got {self.feedback_sign!r}')
        if self.width_unit not in WIDTH_UNITS:
            _fail("width_unit", f"must be one of {WIDTH_UNITS}, got {self.width_unit!r}")
        if self.depth_unit not in DEPTH_UNITS:
            _fail("depth_unit", f"must be one of {DEPTH_UNITS}, got {self.depth_unit!r}")
        if self.kind == "word_block" and self.block is None:
            object.__setattr__(self, "block", BlockLayout.from_table({"preset": "copley"}))
        default = ("block",) if self.kind == "word_block" else PARAMETRIC.get(self.kind, COEFFICIENT_FIELDS)
        order = tuple(self.order) if isinstance(self.order, (list, tuple)) else default if self.order is None \
            else (self.order,)
        if not all(isinstance(x, str) for x in order) or sorted(order) != sorted(default):
            _fail("order", f"must list each of {default} once, got {list(order)}")
        object.__setattr__(self, "order", order)
        if self.kind in PARAMETRIC:
            self._check_parameters()

    def __hash__(self):
        return hash((self.kind, self.order, self.feedback_sign, self.fractional_bits, self.total_bits,
                     self.width_unit, self.depth_unit,
                     tuple(sorted(self.scales.items())), tuple(sorted(self.ranges.items())), self.block))

    def _check_parameters(self) -> None:
        """Validate and complete ``scales``, ``ranges``, ``resolution`` and the index tables of a parametric kind."""
        names = PARAMETRIC[self.kind]
        for table_name in ("scales", "ranges", "resolution"):
            table = getattr(self, table_name)
            if not isinstance(table, dict) or not set(table) <= set(names):
                _fail(table_name, f"must be a table with keys among {names}, got {table!r}")
        object.__setattr__(self, "scales", self._checked_scales(names))
        object.__setattr__(self, "ranges", {name: _checked_range(name, r) for name, r in self.ranges.items()})
        object.__setattr__(self, "resolution", {k: _positive(f"resolution.{k}", v)
                                                for k, v in self.resolution.items()})
        for name in ("width", "depth"):
            if self._is_index(name):
                self._check_index_table(name)

    def _checked_scales(self, names) -> dict:
        """Scale of each field: the kind's default (0.0: REAL32), overridden by ``scales``."""
        scales = {name: 1.0 for name in names}
        if self.kind == "notch_parameters":
            scales.update(center=self.center_scale, width=self.width_scale, depth=self.depth_scale)
        if self.kind in SAME_FREQUENCY:
            # vendors of these keep REAL32 parameters unless the table says otherwise
            scales = {name: 0.0 for name in names}
        scales.update({k: _positive(f"scales.{k}", v, zero_ok=True) for k, v in self.scales.items()})
        return scales

    def _check_index_table(self, name: str) -> None:
        """``<name>_table`` (the physical values) and ``<name>_values`` (what is stored for each)."""
        table = getattr(self, f"{name}_table")
        if not isinstance(table, (list, tuple)) or not table:
            _fail(f"{name}_table", "must be a non-empty list of numbers")
        values = tuple(_positive(f"{name}_table", v, zero_ok=name == "depth") if not
                       (name == "depth" and v == math.inf) else math.inf for v in table)
        object.__setattr__(self, f"{name}_table", values)
        stored = getattr(self, f"{name}_values")
        if stored is None:
            return
        if not isinstance(stored, (list, tuple)) or len(stored) != len(values):
            _fail(f"{name}_values", f"must list one stored integer per {name}_table entry")
        stored = tuple(_int_in(f"{name}_values", v, 0, 2**32 - 1) for v in stored)
        if len(set(stored)) != len(stored):
            _fail(f"{name}_values", "must not repeat a stored integer")
        object.__setattr__(self, f"{name}_values", stored)

    @classmethod
    def from_table(cls, table: dict, source: str = "") -> FilterEncoding:
        """Build from a driver description's ``[filters]`` table (keys of other layers are ignored).

        Raises
        ------
        ConfigError
            A key is missing, of the wrong type or out of range; names the key and ``source``.
        """
        if not isinstance(table, dict):
            raise ConfigError("filters", f"must be a table, got {type(table).__name__}", source)
        if "encoding" not in table:
            raise ConfigError("filters.encoding", "is required", source)
        keys = ("fractional_bits", "total_bits", "center_scale", "width_scale", "depth_scale", "max_value",
                "order", "feedback_sign", "scales", "ranges", "resolution", "width_table", "depth_table",
                "width_values", "depth_values", "width_unit", "depth_unit")
        try:
            kwargs = {k: table[k] for k in keys if k in table}
            for k in ("order", "width_table", "depth_table", "width_values", "depth_values"):
                if k in kwargs:
                    if not isinstance(kwargs[k], (list, tuple)):
                        _fail(k, f"must be a list, got {kwargs[k]!r}")
                    kwargs[k] = tuple(kwargs[k])
            if table["encoding"] == "word_block":
                kwargs["block"] = BlockLayout.from_table(table)
                preset = PRESETS.get(table["preset"], {}) if isinstance(table.get("preset"), str) else {}
                kwargs.setdefault("feedback_sign", preset.get("feedback_sign", "minus"))
            return cls(table["encoding"], **kwargs)
        except ConfigError as exc:
            raise ConfigError(exc.key, exc.message, source) from None

    @property
    def fields(self) -> tuple[str, ...]:
        """Names of the values one slot holds, in order (``("block",)`` for a word block)."""
        assert self.order is not None  # __post_init__ completes it
        return self.order

    @property
    def _layout(self) -> BlockLayout:
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
        if self.kind == "real32" or (self.kind in PARAMETRIC and not self._is_index(name)
                                     and self.scales[name] == 0.0):
            return "float32"
        return "integer"

    # --- host side -------------------------------------------------------------------

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
            return {"block": self._encode_block(biquad, spec)}
        if spec is None:
            raise DataError(f'this drive takes notch parameters ({", ".join(self.fields)}); no NotchSpec was given')
        if self.kind == "notch_parameters" and self._legacy_units:
            return self._encode_notch_parameters(spec)
        ideal = self._ideal(spec)
        return {name: self._nearest(name, self._clamp(name, ideal[name])) for name in self.fields}

    @property
    def _legacy_units(self) -> bool:
        """``"notch_parameters"`` in Hz and dB: integers 1..max_value, out-of-range values refused by encode()."""
        return self.width_unit == "hz" and self.depth_unit == "db"

    def _stored_coefficients(self, values: Sequence[float]) -> tuple[float, float, float, float, float]:
        """scipy ``(b0, b1, b2, a1, a2)`` -> stored ``b0 .. a2`` (the feedback terms negated for "plus")."""
        sign = -1.0 if self.feedback_sign == "plus" else 1.0
        return (values[0], values[1], values[2], sign * values[3], sign * values[4])

    def _encode_coefficients(self, biquad: Biquad) -> dict:
        if self.kind == "real32":
            values = self._stored_coefficients((*biquad.b, biquad.a[1], biquad.a[2]))
            out = dict(zip(COEFFICIENT_FIELDS, map(float32, values), strict=False))
        else:
            q = quantize_biquad(biquad, self.fractional_bits, self.total_bits)
            scale = 2.0**self.fractional_bits
            values = self._stored_coefficients((*q.b, q.a[1], q.a[2]))
            out = {name: int(round(v * scale)) for name, v in zip(COEFFICIENT_FIELDS, values, strict=False)}
        return {name: out[name] for name in self.fields}

    def _encode_notch_parameters(self, spec: NotchSpec) -> dict:
        out = {}
        for name, value in (("center", spec.center_hz), ("width", spec.width_hz), ("depth", spec.depth_db)):
            scale = self.scales[name]
            if not math.isfinite(value):
                raise DataError(f"notch {name} {value!r} cannot be encoded as an integer")
            n = int(round(value / scale))
            if not 1 <= n <= self.max_value:
                raise DataError(f"notch {name} {value:g} is {n} steps of {scale:g}; "
                                f"the drive takes 1..{self.max_value}")
            out[name] = n
        return {name: out[name] for name in self.fields}

    # --- word blocks -----------------------------------------------------------------

    def _encode_block(self, biquad: Biquad, spec: NotchSpec | None, scaling: tuple | None = None) -> bytes:
        """The block for ``biquad``; ``scaling`` = (INT16 coefficients, K) overrides the best one (see
        :meth:`realise`)."""
        lay = self._layout
        words = [0] * lay.words
        words[lay.state_word] = lay.enabled_value
        if lay.frequency_words and spec is not None:
            # the -3 dB edges of the notch: f1 f2 = f0^2, f2 - f1 = width
            half = 0.5 * spec.width_hz
            f2 = half + math.sqrt(half * half + spec.center_hz**2)
            for w, f in zip(lay.frequency_words, (spec.center_hz**2 / f2, f2), strict=False):
                words[w] = min(int(round(f)), 0xFFFF)
        stored = self._stored_coefficients((*biquad.b, biquad.a[1], biquad.a[2]))
        if lay.coefficient_format == "float32":
            for name, value in zip(COEFFICIENT_FIELDS, stored, strict=False):
                bits = struct.unpack("<I", struct.pack("<f", value))[0]
                pair = (bits >> 16, bits & 0xFFFF) if lay.word_order == "high_first" else (bits & 0xFFFF, bits >> 16)
                w = lay.coefficient_words[name]
                words[w:w + 2] = pair
        else:
            ints, k = scaling or _scaled_int16(biquad, lay.scaler_bits, self.feedback_sign)[0]
            for name, n in zip(COEFFICIENT_FIELDS, ints, strict=False):
                words[lay.coefficient_words[name]] = n & 0xFFFF
            words[lay.scaler_index] = k
        return lay.pack(words)

    def _block_section(self, words: list[int]) -> Biquad:
        lay = self._layout
        if lay.coefficient_format == "float32":
            values = []
            for name in COEFFICIENT_FIELDS:
                w = lay.coefficient_words[name]
                hi, lo = (words[w], words[w + 1]) if lay.word_order == "high_first" else (words[w + 1], words[w])
                values.append(struct.unpack("<f", struct.pack("<I", (hi << 16) | lo))[0])
        else:
            k = words[lay.scaler_index]
            step = k / 2.0**lay.scaler_bits
            values = [_signed16(words[lay.coefficient_words[name]]) * step for name in COEFFICIENT_FIELDS]
        b0, b1, b2, a1, a2 = self._stored_coefficients(values)
        if not all(map(math.isfinite, (b0, b1, b2, a1, a2))):
            raise DataError(f"filter block holds non-finite coefficients {values}")
        return Biquad((b0, b1, b2), (1.0, a1, a2))

    def slot_enabled(self, values: dict) -> bool | None:
        """``"word_block"``: whether the block's state word enables the slot; ``None`` for other
        encodings (their enable is a separate object or register)."""
        if self.kind != "word_block":
            return None
        return self._layout.is_enabled(self._layout.unpack(values.get("block")))

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
        if self.kind != "word_block":
            raise DataError(f'the "{self.kind}" encoding has no enable of its own; write the slot\'s enable object')
        lay = self._layout
        words = lay.unpack(values.get("block"))
        state = lay.enabled_value if enabled else lay.disabled_value
        words[lay.state_word] = (words[lay.state_word] & ~lay.state_mask & 0xFFFF) | (state & lay.state_mask)
        return {"block": lay.pack(words)}

    # --- physical parameters -----------------------------------------------------------

    def _ideal(self, spec: NotchSpec, rate: float | None = None) -> dict[str, float]:
        """The physical value of each field that would give ``spec`` exactly (before storage).

        ``"center_band"`` with ``rate``: the band is narrowed by the frequency
        warping at the centre, ``sin(w T) / (w T)``, so the section's width
        parameter (the analog prototype's) matches ``spec.width_hz``.
        """
        f, w, d = spec.center_hz, spec.width_hz, spec.depth_db
        ratio = 10.0 ** (-d / 20.0)
        if self.kind == "notch_parameters":
            width = {"hz": w, "q": f / w, "ratio": w / f, "index": w / f}[self.width_unit]
            depth = {"db": d, "ratio": ratio, "percent": 100.0 * ratio, "index": d}[self.depth_unit]
            return {"center": f, "width": width, "depth": depth}
        if self.kind == "pole_zero_q":
            q = f / w
            return {"pole_hz": f, "pole_q": q, "zero_hz": f, "zero_q": q / ratio if ratio > 0 else math.inf}
        if self.kind == "pole_zero_damping":
            damping = w / (2.0 * f)
            return {"num_hz": f, "num_damping": damping * ratio, "den_hz": f, "den_damping": damping}
        if self.kind == "index_table":
            return {"center": f, "width": w / f, "depth": d}
        warp = 1.0
        if rate is not None and 0.0 < f < 0.5 * rate:
            wt = 2.0 * math.pi * f / rate
            warp = math.sin(wt) / wt
        return {"center": f, "band": w * warp * math.pi / 3.0}

    def _clamp(self, name: str, x: float) -> float:
        if name in self.ranges:
            low, high = self.ranges[name]
            return min(max(x, low), high)
        return x

    def _index_table(self, name: str) -> tuple[tuple, tuple]:
        table = getattr(self, f"{name}_table")
        stored = getattr(self, f"{name}_values") or tuple(range(len(table)))
        return table, stored

    def _is_index(self, name: str) -> bool:
        """Whether field ``name`` stores an index into ``width_table`` / ``depth_table``."""
        if self.kind == "index_table":
            return name in ("width", "depth")
        return self.kind == "notch_parameters" and ((name == "width" and self.width_unit == "index")
                                                    or (name == "depth" and self.depth_unit == "index"))

    def _candidates(self, name: str, x: float) -> list:
        """Stored values of field ``name`` around the physical value ``x``.

        Integer fields: the grid steps from one below the lower neighbour to one
        above the upper; table fields: the three nearest entries; REAL32 fields:
        ``x`` itself (or the neighbours on its ``resolution``).  Depth-setting
        fields add a few settings deeper by :data:`DEPTH_MARGINS_DB`.
        """
        if self._is_index(name):
            return self._index_candidates(name, x)
        if self.scales[name] == 0.0:
            return self._real_candidates(name, x)
        if not math.isfinite(x):
            return []
        scale = self.scales[name]
        n = x / scale
        low, high = self._integer_range(name)
        steps = list(range(math.floor(n) - 1, math.ceil(n) + 2))
        if name in DEEPER:
            # a centre off the resonance, or rounding, can need a slightly deeper notch than asked
            steps += [int(round(self._deeper(name, x, m) / scale)) for m in DEPTH_MARGINS_DB[1:]]
        return [m for m in dict.fromkeys(steps) if low <= m <= high]

    def _index_candidates(self, name: str, x: float) -> list:
        """The stored values of the three table entries nearest ``x`` (depth: and the next deeper one)."""
        table, stored = self._index_table(name)
        log = name == "width"
        dist = [abs(math.log(t / x)) if log else (0.0 if t == x else abs(t - x)) for t in table]
        ranked = sorted(range(len(table)), key=lambda i: dist[i])[:3]
        if name == "depth":
            # the next deeper entry too: a centre off the resonance can need it
            deeper = [i for i in range(len(table)) if table[i] > x]
            if deeper:
                ranked.append(min(deeper, key=lambda i: table[i]))
        return [stored[i] for i in dict.fromkeys(ranked)]

    def _real_candidates(self, name: str, x: float) -> list:
        """REAL32 values around ``x``: itself, or the neighbours on the field's ``resolution``."""
        # an infinite Q or frequency has no REAL32 form; the largest finite stand-in is deep enough
        x = min(x, 1e9)
        step = self.resolution.get(name)
        if step is None:
            if name in DEEPER:
                # float32 rounding can leave the depth a hair short: a few slightly deeper values
                grid = [self._deeper(name, x, m) for m in DEPTH_MARGINS_DB]
                return [float32(v) for v in grid if self._in_range(name, v)] or [float32(x)]
            return [float32(x)]
        n = x / step
        grid = [step * m for m in range(math.floor(n) - 1, math.ceil(n) + 2)]
        return [float32(v) for v in grid if self._in_range(name, v)]

    def _deeper_sign(self, name: str) -> int:
        """+1 when a larger value of depth-setting field ``name`` makes the notch deeper, else -1."""
        if name == "depth" and self.kind == "notch_parameters" and self.depth_unit not in ("db", "index"):
            return -1
        return DEEPER[name]

    def _deeper(self, name: str, x: float, margin_db: float) -> float:
        """The value of depth-setting field ``name`` that deepens the notch by about ``margin_db``."""
        if name == "depth" and self._deeper_sign(name) > 0:
            return x + margin_db
        return x * 10.0 ** (self._deeper_sign(name) * margin_db / 20.0)

    def _integer_range(self, name: str) -> tuple[int, int]:
        scale = self.scales[name]
        if self.kind == "notch_parameters":
            low, high = (1 if self._legacy_units else 0), self.max_value
        else:
            low, high = 0, 2**32 - 1
        if name in self.ranges:
            low = max(low, math.ceil(self.ranges[name][0] / scale - 1e-9))
            high = min(high, math.floor(self.ranges[name][1] / scale + 1e-9))
        return low, high

    def _in_range(self, name: str, v: float) -> bool:
        low, high = self.ranges.get(name, (0.0, math.inf))
        return low - 1e-12 <= v <= high + 1e-12

    def _nearest(self, name: str, x: float):
        cands = self._candidates(name, x)
        if not cands:
            raise DataError(f"notch {name} {x!r} cannot be stored")
        return min(cands, key=lambda c: abs(self._physical(name, c) - x)
                   if not self._is_index(name) else abs(cands.index(c)))

    def _physical(self, name: str, stored) -> float:
        """The physical value (Hz, Q, damping, ratio, dB) a stored field value stands for."""
        if self._is_index(name):
            table, values = self._index_table(name)
            if stored not in values:
                raise DataError(f"{name} index {stored!r} is not in the drive's table (values {list(values)})")
            return table[values.index(stored)]
        scale = self.scales[name]
        if scale == 0.0:
            x = float32(stored)
            step = self.resolution.get(name)
            return x if step is None else step * round(x / step)
        if isinstance(stored, bool) or int(stored) != stored:
            raise DataError(f"notch {name} must be an integer, got {stored!r}")
        return int(stored) * scale

    def _physical_values(self, values: dict) -> dict[str, float]:
        out = {}
        for name in self.fields:
            x = self._physical(name, values[name])
            if math.isnan(x) or (math.isinf(x) and name != "depth") or \
                    (name in self.ranges and not self._in_range(name, x)):
                low, high = self.ranges.get(name, (0, math.inf))
                raise DataError(f"notch {name} {x:g} is outside the drive's range {low:g}..{high:g}")
            out[name] = x
        return out

    def parameters(self, values: dict) -> NotchSpec:
        """Physical-parameter encodings: the notch the stored values stand for (rate independent).

        ``"center_band"`` reports the -3 dB width ``3 band / pi`` and an infinite
        depth; the pole/zero encodings report the centre at the zero frequency,
        the width ``2 D_pole f_pole`` and the depth ``20 log10(D_pole / D_zero)``.

        Raises
        ------
        DataError
            A field is missing, out of range, or the values are no notch.
        """
        missing = [f for f in self.fields if f not in values]
        if missing or self.kind not in PARAMETRIC:
            raise DataError(f"filter slot values lack {', '.join(missing)}" if missing
                            else f'the "{self.kind}" encoding stores coefficients, not notch parameters')
        center, width, depth = self._notch_triplet(self._physical_values(values))
        try:
            return NotchSpec(center, width, depth)
        except ConfigError as exc:
            raise DataError(f"notch parameters {dict(values)}: {exc.message}") from None

    def _notch_triplet(self, p: dict[str, float]) -> tuple[float, float, float]:
        """Centre (Hz), width (Hz) and depth (dB) of the physical field values ``p``."""
        if self.kind == "notch_parameters":
            return self._notch_parameters_triplet(p)
        if self.kind == "index_table":
            return p["center"], p["width"] * p["center"], p["depth"]
        if self.kind == "center_band":
            return p["center"], 3.0 * p["band"] / math.pi, math.inf
        if self.kind == "pole_zero_q":
            if not (p["zero_q"] > 0 and p["pole_q"] > 0):
                raise DataError(f"pole and zero Q must be positive, got {p['pole_q']:g} and {p['zero_q']:g}")
            zero_d, pole_d, f_zero, f_pole = 0.5 / p["zero_q"], 0.5 / p["pole_q"], p["zero_hz"], p["pole_hz"]
        else:
            zero_d, pole_d, f_zero, f_pole = p["num_damping"], p["den_damping"], p["num_hz"], p["den_hz"]
        depth = math.inf if zero_d == 0 else 20.0 * math.log10(pole_d / zero_d) if pole_d > 0 else -math.inf
        return f_zero, 2.0 * pole_d * f_pole, depth

    def _notch_parameters_triplet(self, p: dict[str, float]) -> tuple[float, float, float]:
        center, width, depth = p["center"], p["width"], p["depth"]
        if self.width_unit == "q":
            if not width > 0:
                raise DataError(f"notch Q must be positive, got {width:g}")
            width = center / width
        elif self.width_unit in ("ratio", "index"):
            width *= center
        if self.depth_unit not in ("db", "index"):
            ratio = depth / 100.0 if self.depth_unit == "percent" else depth
            depth = math.inf if ratio <= 0 else -20.0 * math.log10(ratio)
        return center, width, depth

    def _parametric_section(self, p: dict[str, float], rate: float) -> Biquad:
        if self.kind == "center_band":
            return rejection_band_section(p["center"], p["band"], rate)
        if self.kind in ("pole_zero_q", "pole_zero_damping"):
            f_zero, f_pole = (p["zero_hz"], p["pole_hz"]) if self.kind == "pole_zero_q" else (p["num_hz"], p["den_hz"])
            self._notch_triplet(p)  # raises on Q values that are no filter
            if self.kind == "pole_zero_q":
                args = (f_zero, 0.5 / p["zero_q"], f_pole, 0.5 / p["pole_q"])
            else:
                args = (f_zero, p["num_damping"], f_pole, p["den_damping"])
            s = two_frequency_section(*args, rate)
            return _float32_biquad(*s.b, s.a[1], s.a[2])
        raise DataError(f'the "{self.kind}" encoding is not a pole/zero or rejection-band encoding')

    # --- what the drive applies ------------------------------------------------------

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
            return _float32_biquad(*self._stored_coefficients([values[f] for f in COEFFICIENT_FIELDS]))
        if self.kind == "fixed":
            scale = 2.0**self.fractional_bits
            c = self._stored_coefficients([int(values[f]) / scale for f in COEFFICIENT_FIELDS])
            section = Biquad((c[0], c[1], c[2]), (1.0, c[3], c[4]))
            if not section.is_stable():
                raise DataError(f"fixed-point coefficients {dict(values)} give an unstable filter")
            return section
        if self.kind == "word_block":
            words = self._layout.unpack(values["block"])
            if not self._layout.is_enabled(words):
                return Biquad.identity()
            section = self._block_section(words)
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
            integral = self.kind == "fixed" or (self.kind in PARAMETRIC and
                                               (self._is_index(name) or self.scales[name] != 0.0))
            kind = "an integer" if integral else "a finite REAL32 number"
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise DataError(f"filter field {name} must be {kind}, got {v!r}")
            x = float(v)
            if not math.isfinite(x) or (integral and int(x) != x) or (not integral and abs(x) > FLOAT32_MAX):
                raise DataError(f"filter field {name} must be {kind}, got {v!r}")

    def _section_of(self, values: dict, rate: float) -> Biquad:
        if self.kind in ("notch_parameters", "index_table"):
            center, _, depth = self._notch_triplet(self._physical_values(values))
            if center >= rate / 2:
                raise DataError(f"notch centre {center:g} Hz is not below half the {rate:g} Hz filter rate")
            if depth <= 0.0:
                return Biquad.identity()
            spec = self.parameters(values)
            designed = design_notch(spec, rate)
            return _float32_biquad(*designed.b, designed.a[1], designed.a[2])
        return self._parametric_section(self._physical_values(values), rate)

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None, filter_rate_hz: float) -> Biquad:
        """What the drive will run when the host writes the notch ``biquad``/``spec``."""
        return self.applied(self.encode(biquad, spec), filter_rate_hz)

    # --- fitting a notch to the encoding ------------------------------------------------

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
        realised = _remembered_fit(self, spec, float(filter_rate_hz))
        return replace(realised, fields=dict(realised.fields))  # the caller may change its copy

    def _realise(self, spec: NotchSpec, filter_rate_hz: float) -> Realisation:
        """:meth:`realise`, computed."""
        notes: list[str] = []
        if self.kind in PARAMETRIC:
            fields, section = self._fit(spec, filter_rate_hz, notes)
        else:
            fields, section = self._fit_coefficients(spec, filter_rate_hz)
        att = attenuation_db(section, spec.center_hz, filter_rate_hz)
        try:
            achieved = achieved_notch(section, filter_rate_hz, spec.center_hz)
        except (DataError, ConfigError):
            achieved = None
        if att < spec.depth_db - DEPTH_TOLERANCE_DB:
            notes.append(f"the {self.kind} encoding reaches {att:.1f} dB at {spec.center_hz:g} Hz, "
                         f"not the {spec.depth_db:g} dB asked")
        return Realisation(fields, section, achieved, att, tuple(notes))

    def _fit_coefficients(self, spec: NotchSpec, rate: float) -> tuple[dict, Biquad]:
        """Coefficient encodings: the design, made a little deeper while rounding leaves it short;
        INT16 blocks also weigh their best few scalings."""
        best: _Candidate | None = None
        for margin in DEPTH_MARGINS_DB:
            designed = design_notch(NotchSpec(spec.center_hz, spec.width_hz, spec.depth_db + margin), rate)
            if self.kind == "word_block" and self._layout.coefficient_format == "int16":
                scalings = _scaled_int16(designed, self._layout.scaler_bits, self.feedback_sign)[:SCALER_CHOICES]
                candidates = [{"block": self._encode_block(designed, spec, sc)} for sc in scalings]
            else:
                candidates = [self.encode(designed, spec)]
            for fields in candidates:
                best = self._better(best, fields, spec, rate)
            if best is not None and not best[0][0] or not math.isfinite(spec.depth_db):
                break
        if best is None:
            raise DataError(f"no {self.kind} coefficients of the notch at {spec.center_hz:g} Hz give a stable filter")
        return best[1], best[2]

    def _better(self, best: _Candidate | None, values: dict, spec: NotchSpec, rate: float,
                max_width_error: float = math.inf,
                seen: dict[tuple, tuple[_Key, Biquad] | None] | None = None) -> _Candidate | None:
        """``best`` or the candidate ``values``, whichever meets ``spec`` better (see :meth:`realise`);
        a candidate whose width is further than ``max_width_error`` (log ratio) from the asked one is not
        taken.  ``seen`` caches the evaluation of parameter candidates."""
        if seen is None:
            evaluated = self._evaluate(values, spec, rate)
        else:
            memo = tuple(values.items())
            if memo not in seen:
                seen[memo] = self._evaluate(values, spec, rate)
            evaluated = seen[memo]
        if evaluated is None:
            return best
        key, section = evaluated
        if key[2] > max_width_error:
            return best
        return (key, values, section) if best is None or key < best[0] else best

    def _evaluate(self, values: dict, spec: NotchSpec, rate: float) -> tuple[_Key, Biquad] | None:
        """``(sort key, section)`` of a candidate, or ``None`` when it is no notch the drive runs."""
        try:
            section = self.applied(values, rate)
        except (DataError, ConfigError):
            return None
        att = attenuation_db(section, spec.center_hz, rate)
        width = notch_width_hz(section, rate, spec.center_hz)
        if not (width > 0.0 and att >= MIN_ATTENUATION_DB):
            return None
        return _depth_key(att, spec.depth_db, width, spec.width_hz), section

    def _fit(self, spec: NotchSpec, rate: float, notes: list[str]) -> tuple[dict, Biquad]:
        ideal = self._ideal(spec, rate)
        per_field = []
        for name in self.fields:
            x = self._clamp(name, ideal[name])
            if x != ideal[name] and name not in DEEPER:
                unit = self._unit(name)
                notes.append(f"{name} {ideal[name]:g}{unit} is outside the drive's range "
                             f"{self.ranges[name][0]:g}..{self.ranges[name][1]:g}{unit}; using {x:g}{unit}")
            per_field.append(self._candidates(name, x))
        widened = self._widened(ideal, spec)
        if widened is not None:
            name, value = widened
            i = self.fields.index(name)
            per_field[i] += [c for c in self._candidates(name, value) if c not in per_field[i]]
        if self._is_index("width"):
            table, ratio = self.width_table, ideal["width"]
            if not min(table) <= ratio <= max(table):
                notes.append(f"width {spec.width_hz:g} Hz ({ratio:.3g} of the centre) is outside the drive's "
                             f"table {min(table):g}..{max(table):g}")
        best: _Candidate | None = None
        seen: dict[tuple, tuple[_Key, Biquad] | None] = {}
        for combo in itertools.product(*per_field):
            values = dict(zip(self.fields, combo, strict=False))
            if self._same_frequency(values):
                best = self._better(best, values, spec, rate, seen=seen)
        if best is None:
            why = "".join(f"; {n}" for n in notes)
            raise DataError(f"no value the {self.kind} encoding can store attenuates {spec.center_hz:g} Hz "
                            f"with a notch {spec.width_hz:g} Hz wide at {rate:g} Hz{why}")
        refined = self._refine(best, spec, rate, seen)
        width = notch_width_hz(refined[2], rate, spec.center_hz)
        if abs(math.log(width / spec.width_hz)) > math.log(WIDTH_TOLERANCE):
            notes.append(f"width {spec.width_hz:.3g} Hz is realised as {width:.3g} Hz")
        return refined[1], refined[2]

    def _unit(self, name: str) -> str:
        """The unit of a field's physical value, for notes (with its leading space)."""
        if name in ("center", "band") or name.endswith("_hz"):
            return " Hz"
        if name == "width" and self.kind == "notch_parameters":
            return {"hz": " Hz", "q": " (Q)", "ratio": " (of the centre)", "index": " (of the centre)"}[self.width_unit]
        if name == "depth" and self.kind == "notch_parameters":
            return {"db": " dB", "ratio": " (ratio)", "percent": " %", "index": " dB"}[self.depth_unit]
        return ""

    def _same_frequency(self, values: dict) -> bool:
        pair = SAME_FREQUENCY.get(self.kind)
        return not pair or self._physical(pair[0], values[pair[0]]) == self._physical(pair[1], values[pair[1]])

    def _refine(self, best: _Candidate, spec: NotchSpec, rate: float,
                seen: dict[tuple, tuple[_Key, Biquad] | None]) -> _Candidate:
        """Move from ``best`` to a neighbour (one grid step or table entry in any fields) while that
        meets ``spec`` better, keeping the width within :data:`WIDTH_TOLERANCE` of the asked one
        (or as close as ``best`` already is)."""
        pair = SAME_FREQUENCY.get(self.kind)
        names = [n for n in self.fields if not (pair and n == pair[1])]
        # depth does not buy any width: the walk stays as close to the asked width as the start or the tolerance
        bound = max(best[0][2], math.log(WIDTH_TOLERANCE))
        for _ in range(REFINE_STEPS):
            start = best
            around = [[best[1][n], *self._adjacent(n, best[1][n])] for n in names]
            for combo in itertools.product(*around):
                values = {**best[1], **dict(zip(names, combo, strict=True))}
                if pair:
                    values[pair[1]] = values[pair[0]]
                if values != start[1] and all(self._stored_in_range(k, v) for k, v in values.items()):
                    best = self._better(best, values, spec, rate, bound, seen) or best  # never None given a best
            if best is start:
                break
        return best

    def _adjacent(self, name: str, stored) -> list:
        """The stored values one step either side of ``stored`` (none for REAL32 fields)."""
        if self._is_index(name):
            _, values = self._index_table(name)
            i = values.index(stored)
            return [values[j] for j in (i - 1, i + 1) if 0 <= j < len(values)]
        if self.scales[name] == 0.0:
            return []
        return [stored - 1, stored + 1]

    def _stored_in_range(self, name: str, stored) -> bool:
        if self._is_index(name) or self.scales[name] == 0.0:
            return True
        low, high = self._integer_range(name)
        return low <= stored <= high

    def _widened(self, ideal: dict, spec: NotchSpec) -> tuple[str, float] | None:
        """Pole/zero encodings whose zero range caps the depth: the pole field value (a wider
        notch) that reaches the asked depth with the zero at its limit, or ``None``."""
        if self.kind == "pole_zero_q" and "zero_q" in self.ranges and ideal["zero_q"] > self.ranges["zero_q"][1]:
            return "pole_q", self._clamp("pole_q", self.ranges["zero_q"][1] * 10.0 ** (-spec.depth_db / 20.0))
        if self.kind == "pole_zero_damping" and "num_damping" in self.ranges \
                and ideal["num_damping"] < self.ranges["num_damping"][0]:
            low = self.ranges["num_damping"][0]
            return "den_damping", self._clamp("den_damping", low * 10.0 ** (spec.depth_db / 20.0))
        return None


def _depth_key(att: float, asked: float, width: float, asked_width: float) -> _Key:
    """Sort key: deep enough first, then the attenuation closest to the asked depth, then the width.

    Attenuations beyond :data:`FULL_DEPTH_DB` count as equal: a zero on the unit
    circle evaluates to some hundreds of dB that only say how well it was rounded.
    """
    att, asked = min(att, FULL_DEPTH_DB), min(asked, FULL_DEPTH_DB)
    short = att < asked
    excess = (asked - att) if short else (att - asked if math.isfinite(asked) else 0.0)
    width_error = abs(math.log(width / asked_width)) if width > 0 else math.inf
    return short, excess if math.isfinite(excess) else math.inf, width_error


def _signed16(w: int) -> int:
    return w - 0x10000 if w & 0x8000 else w


def _scaled_int16(biquad: Biquad, scaler_bits: int, feedback_sign: str) -> list[tuple[list[int], int]]:
    """INT16 coefficients and scaler ``K`` with ``c = n K / 2**scaler_bits``, closest to ``biquad`` first.

    ``K`` is searched from the smallest that fits (finest steps) over the next
    256 values; ``b1`` absorbs the rounding so the DC gain stays as close to
    the design's as the grid allows.  The error measure is the DC gain error
    plus the largest coefficient error.

    Raises
    ------
    DataError
        A coefficient is too large for 16 bits with any 16-bit scaler.
    """
    sign = -1.0 if feedback_sign == "plus" else 1.0
    c = [*biquad.b, biquad.a[1], biquad.a[2]]
    unit = 2.0**scaler_bits
    big = max(abs(x) for x in c)
    k_min = max(1, math.ceil(big * unit / 32767.0))
    if k_min > 0xFFFF:
        raise DataError(f"coefficient {big:g} overflows INT16 with a 16-bit scaler over 2**{scaler_bits}")
    dc = biquad.dc_gain()
    found = []
    for k in range(k_min, min(k_min + 256, 0x10000)):
        step = k / unit
        n = [int(round(x / step)) for x in c]
        den = 1.0 + (n[3] + n[4]) * step
        n[1] = int(round(dc * den / step)) - n[0] - n[2]
        if any(not -32768 <= v <= 32767 for v in n):
            continue
        got = [v * step for v in n]
        num = got[0] + got[1] + got[2]
        err = abs(num / den - dc) if den else math.inf
        err += max(abs(g - x) for g, x in zip(got, c, strict=False))
        found.append((err, k, [n[0], n[1], n[2], int(sign * n[3]), int(sign * n[4])]))
    if not found:
        raise DataError(f"coefficients {c} do not fit INT16 words with a 16-bit scaler")
    found.sort(key=lambda t: (t[0], t[1]))
    return [(n, k) for _, k, n in found]


@functools.lru_cache(maxsize=64)
def _remembered_fit(encoding: FilterEncoding, spec: NotchSpec, filter_rate_hz: float) -> Realisation:
    return encoding._realise(spec, filter_rate_hz)
