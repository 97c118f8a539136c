"""``"word_block"`` slots: where the 16-bit words of one octet string keep a biquad and its enable.

:class:`BlockLayout` (and its presets, :data:`PRESETS`) says which word holds
what; :func:`encode_block` packs a biquad into a block and
:func:`block_section` reads it back; :func:`scaled_int16` finds the INT16
coefficients and common scaler ``K`` of the int16 format.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Literal

from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol.filter_encoding.vocabulary import COEFFICIENT_FIELDS, fail, int_in, stored_coefficients

__all__ = ["COPLEY", "COPLEY_PLUS", "PRESETS", "BlockLayout", "block_section", "encode_block", "scaled_int16"]

#: Copley first generation: 9 INT16 words [info, info, info, b2, b1, b0, a2, a1, K], word 1 = 0xFFFF disabled
COPLEY = {
    "words": 9,
    "coefficient_format": "int16",
    "coefficient_words": {"b2": 3, "b1": 4, "b0": 5, "a2": 6, "a1": 7},
    "scaler_word": 8,
    "scaler_bits": 27,
    "feedback_sign": "plus",
    "state_word": 0,
    "state_mask": 0xFFFF,
    "disabled_value": 0xFFFF,
    "enabled_value": 0x0000,
    "frequency_words": [],
    "byte_order": "little",
}
#: Copley plus family: 14 words, word 1 type bits 13-15 (3 band reject, 7 disabled), bit 8 two poles, bit 4
#: designed; words 2/3 first/second frequency (Hz); words 5-14 a1, a2, b0, b1, b2 as float32, upper word first
COPLEY_PLUS = {
    "words": 14,
    "coefficient_format": "float32",
    "coefficient_words": {"a1": 4, "a2": 6, "b0": 8, "b1": 10, "b2": 12},
    "word_order": "high_first",
    "feedback_sign": "plus",
    "state_word": 0,
    "state_mask": 0xE000,
    "disabled_value": 0xE000,
    "enabled_value": 0x6110,
    "frequency_words": [1, 2],
    "byte_order": "little",
}
PRESETS = {"copley": COPLEY, "copley_plus": COPLEY_PLUS}


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
        return hash(
            (
                self.words,
                tuple(sorted(self.coefficient_words.items())),
                self.coefficient_format,
                self.scaler_word,
                self.state_word,
                self.disabled_value,
                self.enabled_value,
            )
        )

    @classmethod
    def from_table(cls, table: dict) -> BlockLayout:
        """Build from ``[filters]`` (``preset`` gives defaults, explicit keys win)."""
        preset = table.get("preset")
        if preset is not None and not (isinstance(preset, str) and preset in PRESETS):
            fail("preset", f"must be one of {tuple(PRESETS)}, got {preset!r}")
        defaults = PRESETS[preset] if preset is not None else {}
        merged = {**defaults, **{k: table[k] for k in BLOCK_KEYS if k in table}}
        if "words" not in merged or "coefficient_words" not in merged:
            fail("words", 'a "word_block" encoding needs words and coefficient_words (or a preset)')
        words = int_in("words", merged["words"], 1, 4096)
        fmt = merged.get("coefficient_format", "int16")
        if fmt not in ("int16", "float32"):
            fail("coefficient_format", f'must be "int16" or "float32", got {fmt!r}')
        width = 2 if fmt == "float32" else 1
        cw = merged["coefficient_words"]
        if not isinstance(cw, dict) or set(cw) != set(COEFFICIENT_FIELDS):
            fail("coefficient_words", f"must give the first word of each of {COEFFICIENT_FIELDS}, got {cw!r}")
        scaler = merged.get("scaler_word")
        state, freq = block_words(merged, words, fmt, width)
        for key, allowed in (("word_order", ("high_first", "low_first")), ("byte_order", ("little", "big"))):
            if merged.get(key, allowed[0]) not in allowed:
                fail(key, f"must be one of {allowed}, got {merged[key]!r}")
        return cls(
            words,
            dict(cw),
            fmt,
            scaler,
            int_in("scaler_bits", merged.get("scaler_bits", 27), 0, 48),
            merged.get("word_order", "high_first"),
            merged.get("byte_order", "little"),
            state,
            int_in("state_mask", merged.get("state_mask", 0xFFFF), 1, 0xFFFF),
            int_in("disabled_value", merged.get("disabled_value", 0xFFFF), 0, 0xFFFF),
            int_in("enabled_value", merged.get("enabled_value", 0), 0, 0xFFFF),
            freq,
        )

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
        return [int.from_bytes(block[i : i + 2], self.byte_order) for i in range(0, len(block), 2)]

    def is_enabled(self, words: list[int]) -> bool:
        """Whether the block's state word runs the filter (anything but ``disabled_value`` under the mask)."""
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


def block_words(merged: dict, words: int, fmt: str, width: int) -> tuple[int, tuple[int, ...]]:
    """The state word and frequency words, checked with the coefficient and scaler words: in the block, apart."""
    cw = merged["coefficient_words"]
    used: list[int] = []
    for name in COEFFICIENT_FIELDS:
        w = int_in(f"coefficient_words.{name}", cw[name], 0, words - width)
        used += range(w, w + width)
    scaler = merged.get("scaler_word")
    if fmt == "int16":
        if scaler is None:
            fail("scaler_word", 'an "int16" block needs the word of its scaler K')
        used.append(int_in("scaler_word", scaler, 0, words - 1))
    state = int_in("state_word", merged.get("state_word", 0), 0, words - 1)
    listed = merged.get("frequency_words", [])
    if not isinstance(listed, (list, tuple)) or len(listed) not in (0, 2):
        fail("frequency_words", f"must list two word indices or none, got {listed!r}")
    freq = tuple(int_in("frequency_words", w, 0, words - 1) for w in listed)
    used += [state, *freq]
    if len(set(used)) != len(used):
        fail("coefficient_words", f"coefficients, scaler, state and frequency words overlap: {sorted(used)}")
    return state, freq


BLOCK_KEYS = (
    "words",
    "coefficient_words",
    "coefficient_format",
    "scaler_word",
    "scaler_bits",
    "word_order",
    "byte_order",
    "state_word",
    "state_mask",
    "disabled_value",
    "enabled_value",
    "frequency_words",
)


def encode_block(
    lay: BlockLayout,
    biquad: Biquad,
    spec: NotchSpec | None,
    feedback_sign: str,
    scaling: tuple[list[int], int] | None = None,
) -> bytes:
    """The block for ``biquad`` (``spec`` fills the frequency words); ``scaling`` = (INT16 coefficients, K)
    overrides the best one (see :meth:`~hilident.protocol.filter_encoding.FilterEncoding.realise`)."""
    words = [0] * lay.words
    words[lay.state_word] = lay.enabled_value
    if lay.frequency_words and spec is not None:
        # the -3 dB edges of the notch: f1 f2 = f0^2, f2 - f1 = width
        half = 0.5 * spec.width_hz
        f2 = half + math.sqrt(half * half + spec.center_hz**2)
        for w, f in zip(lay.frequency_words, (spec.center_hz**2 / f2, f2), strict=False):
            words[w] = min(int(round(f)), 0xFFFF)
    stored = stored_coefficients((*biquad.b, biquad.a[1], biquad.a[2]), feedback_sign)
    if lay.coefficient_format == "float32":
        for name, value in zip(COEFFICIENT_FIELDS, stored, strict=False):
            bits = struct.unpack("<I", struct.pack("<f", value))[0]
            pair = (bits >> 16, bits & 0xFFFF) if lay.word_order == "high_first" else (bits & 0xFFFF, bits >> 16)
            w = lay.coefficient_words[name]
            words[w : w + 2] = pair
    else:
        ints, k = scaling or scaled_int16(biquad, lay.scaler_bits, feedback_sign)[0]
        for name, n in zip(COEFFICIENT_FIELDS, ints, strict=False):
            words[lay.coefficient_words[name]] = n & 0xFFFF
        words[lay.scaler_index] = k
    return lay.pack(words)


def block_section(lay: BlockLayout, words: list[int], feedback_sign: str) -> Biquad:
    """The section the coefficient words of a block hold (scipy convention)."""
    if lay.coefficient_format == "float32":
        values = []
        for name in COEFFICIENT_FIELDS:
            w = lay.coefficient_words[name]
            hi, lo = (words[w], words[w + 1]) if lay.word_order == "high_first" else (words[w + 1], words[w])
            values.append(struct.unpack("<f", struct.pack("<I", (hi << 16) | lo))[0])
    else:
        k = words[lay.scaler_index]
        step = k / 2.0**lay.scaler_bits
        values = [signed16(words[lay.coefficient_words[name]]) * step for name in COEFFICIENT_FIELDS]
    b0, b1, b2, a1, a2 = stored_coefficients(values, feedback_sign)
    if not all(map(math.isfinite, (b0, b1, b2, a1, a2))):
        raise DataError(f"filter block holds non-finite coefficients {values}")
    return Biquad((b0, b1, b2), (1.0, a1, a2))


def signed16(w: int) -> int:
    """A 16-bit word read as two's complement."""
    return w - 0x10000 if w & 0x8000 else w


def scaled_int16(biquad: Biquad, scaler_bits: int, feedback_sign: str) -> list[tuple[list[int], int]]:
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
