"""Fitting a notch to what an encoding can store: :meth:`FilterEncoding.realise`.

Coefficient encodings round the pre-warped Tustin design (a little deeper
while rounding leaves it short; INT16 blocks weigh their best scalings).
Physical-parameter encodings weigh the stored values around the ideal ones
(:mod:`~hilident.protocol.filter_encoding.grid`) by the attenuation at the
resonance and the width (:func:`depth_key`), then walk to better neighbours
(:func:`refine`). A fit is remembered per encoding, notch and rate
(:func:`remembered_fit`).
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch
from hilident.filters.parametric import achieved_notch, attenuation_db, notch_width_hz
from hilident.protocol.filter_encoding import grid
from hilident.protocol.filter_encoding.block import encode_block, scaled_int16
from hilident.protocol.filter_encoding.vocabulary import (
    DEEPER,
    DEPTH_MARGINS_DB,
    DEPTH_TOLERANCE_DB,
    FULL_DEPTH_DB,
    HELD,
    MIN_ATTENUATION_DB,
    PARAMETRIC,
    REFINE_STEPS,
    SAME_FREQUENCY,
    SCALER_CHOICES,
    WIDTH_TOLERANCE,
)

if TYPE_CHECKING:
    from hilident.protocol.filter_encoding.encoding import FilterEncoding

__all__ = ["Realisation"]

#: how a candidate meets the asked notch, smaller is better: (too shallow, depth error in dB, width error as
#: the absolute log ratio), see :func:`depth_key`
_Key = tuple[bool, float, float]
#: a candidate's key, its field values and the section the drive runs with them
_Candidate = tuple[_Key, dict, Biquad]


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


def realisation(enc: FilterEncoding, spec: NotchSpec, filter_rate_hz: float) -> Realisation:
    """:meth:`FilterEncoding.realise`, computed (see there)."""
    notes: list[str] = []
    if enc.kind in PARAMETRIC:
        fields, section = fit_parameters(enc, spec, filter_rate_hz, notes)
    else:
        fields, section = fit_coefficients(enc, spec, filter_rate_hz)
    att = attenuation_db(section, spec.center_hz, filter_rate_hz)
    try:
        achieved = achieved_notch(section, filter_rate_hz, spec.center_hz)
    except (DataError, ConfigError):
        achieved = None
    if att < spec.depth_db - DEPTH_TOLERANCE_DB:
        notes.append(
            f"the {enc.kind} encoding reaches {att:.1f} dB at {spec.center_hz:g} Hz, not the {spec.depth_db:g} dB asked"
        )
    return Realisation(fields, section, achieved, att, tuple(notes))


def fit_coefficients(enc: FilterEncoding, spec: NotchSpec, rate: float) -> tuple[dict, Biquad]:
    """Coefficient encodings: the design, made a little deeper while rounding leaves it short;
    INT16 blocks also weigh their best few scalings."""
    best: _Candidate | None = None
    for margin in DEPTH_MARGINS_DB:
        designed = design_notch(NotchSpec(spec.center_hz, spec.width_hz, spec.depth_db + margin), rate)
        if enc.kind == "word_block" and enc.layout.coefficient_format == "int16":
            scalings = scaled_int16(designed, enc.layout.scaler_bits, enc.feedback_sign)[:SCALER_CHOICES]
            candidates = [{"block": encode_block(enc.layout, designed, spec, enc.feedback_sign, sc)} for sc in scalings]
        else:
            candidates = [enc.encode(designed, spec)]
        for fields in candidates:
            best = better(enc, best, fields, spec, rate)
        if best is not None and not best[0][0] or not math.isfinite(spec.depth_db):
            break
    if best is None:
        raise DataError(f"no {enc.kind} coefficients of the notch at {spec.center_hz:g} Hz give a stable filter")
    return best[1], best[2]


def better(
    enc: FilterEncoding,
    best: _Candidate | None,
    values: dict,
    spec: NotchSpec,
    rate: float,
    max_width_error: float = math.inf,
    seen: dict[tuple, tuple[_Key, Biquad] | None] | None = None,
) -> _Candidate | None:
    """``best`` or the candidate ``values``, whichever meets ``spec`` better (see :meth:`FilterEncoding.realise`);
    a candidate whose width is further than ``max_width_error`` (log ratio) from the asked one is not
    taken.  ``seen`` caches the evaluation of parameter candidates."""
    if seen is None:
        evaluated = evaluate(enc, values, spec, rate)
    else:
        memo = tuple(values.items())
        if memo not in seen:
            seen[memo] = evaluate(enc, values, spec, rate)
        evaluated = seen[memo]
    if evaluated is None:
        return best
    key, section = evaluated
    if key[2] > max_width_error:
        return best
    return (key, values, section) if best is None or key < best[0] else best


def evaluate(enc: FilterEncoding, values: dict, spec: NotchSpec, rate: float) -> tuple[_Key, Biquad] | None:
    """``(sort key, section)`` of a candidate, or ``None`` when it is no notch the drive runs."""
    try:
        section = enc.applied(values, rate)
    except (DataError, ConfigError):
        return None
    att = attenuation_db(section, spec.center_hz, rate)
    width = notch_width_hz(section, rate, spec.center_hz)
    if not (width > 0.0 and att >= MIN_ATTENUATION_DB):
        return None
    return depth_key(att, spec.depth_db, width, spec.width_hz), section


def fit_parameters(enc: FilterEncoding, spec: NotchSpec, rate: float, notes: list[str]) -> tuple[dict, Biquad]:
    """Physical-parameter encodings: the best of the stored values around the ideal ones, refined."""
    ideal = grid.ideal(enc, spec, rate)
    per_field = []
    held = HELD.get(enc.kind, ())
    for name in enc.fields:
        x = grid.clamp(enc, name, ideal[name])
        if x != ideal[name] and name not in DEEPER:
            unit = grid.unit(enc, name)
            notes.append(
                f"{name} {ideal[name]:g}{unit} is outside the drive's range "
                f"{enc.ranges[name][0]:g}..{enc.ranges[name][1]:g}{unit}; using {x:g}{unit}"
            )
        per_field.append([grid.nearest(enc, name, x)] if name in held else grid.candidates(enc, name, x))
    notes += capped_depth(enc, ideal)
    wider = widened(enc, ideal, spec)
    if wider is not None:
        name, value = wider
        i = enc.fields.index(name)
        per_field[i] += [c for c in grid.candidates(enc, name, value) if c not in per_field[i]]
    if grid.is_index(enc, "width"):
        table, ratio = enc.width_table, ideal["width"]
        if not min(table) <= ratio <= max(table):
            notes.append(
                f"width {spec.width_hz:g} Hz ({ratio:.3g} of the centre) is outside the drive's "
                f"table {min(table):g}..{max(table):g}"
            )
    best: _Candidate | None = None
    seen: dict[tuple, tuple[_Key, Biquad] | None] = {}
    for combo in itertools.product(*per_field):
        values = dict(zip(enc.fields, combo, strict=False))
        if grid.same_frequency(enc, values):
            best = better(enc, best, values, spec, rate, seen=seen)
    if best is None:
        why = "".join(f"; {n}" for n in notes)
        raise DataError(
            f"no value the {enc.kind} encoding can store attenuates {spec.center_hz:g} Hz "
            f"with a notch {spec.width_hz:g} Hz wide at {rate:g} Hz{why}"
        )
    refined = refine(enc, best, spec, rate, seen)
    width = notch_width_hz(refined[2], rate, spec.center_hz)
    if abs(math.log(width / spec.width_hz)) > math.log(WIDTH_TOLERANCE):
        notes.append(f"width {spec.width_hz:.3g} Hz is realised as {width:.3g} Hz")
    return refined[1], refined[2]


def refine(
    enc: FilterEncoding, best: _Candidate, spec: NotchSpec, rate: float, seen: dict[tuple, tuple[_Key, Biquad] | None]
) -> _Candidate:
    """Move from ``best`` to a neighbour (one grid step or table entry in any fields) while that
    meets ``spec`` better, keeping the width within :data:`WIDTH_TOLERANCE` of the asked one
    (or as close as ``best`` already is)."""
    pair = SAME_FREQUENCY.get(enc.kind)
    names = [n for n in enc.fields if not (pair and n == pair[1]) and n not in HELD.get(enc.kind, ())]
    # depth does not buy any width: the walk stays as close to the asked width as the start or the tolerance
    bound = max(best[0][2], math.log(WIDTH_TOLERANCE))
    for _ in range(REFINE_STEPS):
        start = best
        around = [[best[1][n], *grid.adjacent(enc, n, best[1][n])] for n in names]
        for combo in itertools.product(*around):
            values = {**best[1], **dict(zip(names, combo, strict=True))}
            if pair:
                values[pair[1]] = values[pair[0]]
            if values != start[1] and all(grid.stored_in_range(enc, k, v) for k, v in values.items()):
                best = better(enc, best, values, spec, rate, bound, seen) or best  # never None given a best
        if best is start:
            break
    return best


def widened(enc: FilterEncoding, ideal: dict, spec: NotchSpec) -> tuple[str, float] | None:
    """Pole/zero encodings whose zero range caps the depth: the pole field value (a wider
    notch) that reaches the asked depth with the zero at its limit, or ``None``."""
    if enc.kind == "pole_zero_q" and "zero_q" in enc.ranges and ideal["zero_q"] > enc.ranges["zero_q"][1]:
        return "pole_q", grid.clamp(enc, "pole_q", enc.ranges["zero_q"][1] * 10.0 ** (-spec.depth_db / 20.0))
    if (
        enc.kind == "pole_zero_damping"
        and "num_damping" in enc.ranges
        and ideal["num_damping"] < enc.ranges["num_damping"][0]
    ):
        low = enc.ranges["num_damping"][0]
        return "den_damping", grid.clamp(enc, "den_damping", low * 10.0 ** (spec.depth_db / 20.0))
    return None


def capped_depth(enc: FilterEncoding, ideal: dict) -> list[str]:
    """``"center_ratio_damping"``: a note when the damping ratio's range caps the depth at the centre below the
    asked one (the depth of a notch is ``20 log10(damping_ratio)``, whatever its width)."""
    if enc.kind != "center_ratio_damping" or "damping_ratio" not in enc.ranges:
        return []
    high = enc.ranges["damping_ratio"][1]
    if ideal["damping_ratio"] <= high:
        return []
    return [
        f"damping_ratio {ideal['damping_ratio']:.4g} is beyond the drive's range "
        f"{enc.ranges['damping_ratio'][0]:g}..{high:g}: a notch of this drive is at most "
        f"{20.0 * math.log10(high):.1f} dB deep"
    ]


def depth_key(att: float, asked: float, width: float, asked_width: float) -> _Key:
    """Sort key: deep enough first, then the attenuation closest to the asked depth, then the width.

    Attenuations beyond :data:`FULL_DEPTH_DB` count as equal: a zero on the unit
    circle evaluates to some hundreds of dB that only say how well it was rounded.
    """
    att, asked = min(att, FULL_DEPTH_DB), min(asked, FULL_DEPTH_DB)
    short = att < asked
    excess = (asked - att) if short else (att - asked if math.isfinite(asked) else 0.0)
    width_error = abs(math.log(width / asked_width)) if width > 0 else math.inf
    return short, excess if math.isfinite(excess) else math.inf, width_error


@functools.lru_cache(maxsize=64)
def remembered_fit(enc: FilterEncoding, spec: NotchSpec, filter_rate_hz: float) -> Realisation:
    """:func:`realisation`, remembered (the encoding, the notch and the rate are its key)."""
    return realisation(enc, spec, filter_rate_hz)
