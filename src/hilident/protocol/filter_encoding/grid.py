"""The values a physical-parameter encoding stores, and what they stand for.

Unit conversions between a notch (centre Hz, width Hz, depth dB) and the
physical value of each field (:func:`ideal`, :func:`notch_triplet`), the grid
of stored values around a physical value (integer steps, table indices,
REAL32 numbers: :func:`candidates`, :func:`adjacent`), what a stored value
stands for (:func:`physical`), and the section a drive builds from them
(:func:`parametric_section`). Functions of a
:class:`~hilident.protocol.filter_encoding.FilterEncoding`, which calls them,
as does :mod:`~hilident.protocol.filter_encoding.fit`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.filters.parametric import (
    anti_resonance_pair,
    center_ratio_section,
    rejection_band_section,
    two_frequency_section,
)
from hilident.protocol.filter_encoding.vocabulary import (
    DEEPER,
    DEPTH_MARGINS_DB,
    FULL_DEPTH_DB,
    SAME_FREQUENCY,
    float32,
    float32_biquad,
)

if TYPE_CHECKING:
    from hilident.protocol.filter_encoding.encoding import FilterEncoding


def ideal(enc: FilterEncoding, spec: NotchSpec, rate: float | None = None) -> dict[str, float]:
    """The physical value of each field that would give ``spec`` exactly (before storage).

    ``"center_band"`` with ``rate``: the band is narrowed by the frequency
    warping at the centre, ``sin(w T) / (w T)``, so the section's width
    parameter (the analog prototype's) matches ``spec.width_hz``.
    ``"center_ratio_damping"``: the centre damping is the one that gives the
    asked width with the damping ratio the drive's range allows.
    """
    f, w, d = spec.center_hz, spec.width_hz, spec.depth_db
    ratio = 10.0 ** (-d / 20.0)
    if enc.kind == "notch_parameters":
        width = {"hz": w, "q": f / w, "ratio": w / f, "index": w / f}[enc.width_unit]
        if enc.depth_unit == "full":
            return {"center": f, "width": width}
        depth = {"db": d, "ratio": ratio, "percent": 100.0 * ratio, "index": d}[enc.depth_unit]
        return {"center": f, "width": width, "depth": depth}
    if enc.kind == "center_ratio_damping":
        return center_ratio_ideal(enc, f, w, d)
    if enc.kind == "pole_zero_q":
        q = f / w
        return {"pole_hz": f, "pole_q": q, "zero_hz": f, "zero_q": q / ratio if ratio > 0 else math.inf}
    if enc.kind == "pole_zero_damping":
        damping = w / (2.0 * f)
        return {"num_hz": f, "num_damping": damping * ratio, "den_hz": f, "den_damping": damping}
    if enc.kind == "index_table":
        return {"center": f, "width": w / f, "depth": d}
    warp = 1.0
    if rate is not None and 0.0 < f < 0.5 * rate:
        wt = 2.0 * math.pi * f / rate
        warp = math.sin(wt) / wt
    return {"center": f, "band": w * warp * math.pi / 3.0}


def center_ratio_ideal(enc: FilterEncoding, f: float, w: float, d: float) -> dict[str, float]:
    """``"center_ratio_damping"``: the notch ``f`` Hz, ``w`` Hz wide, ``d`` dB deep (ratio 1, zeros on the poles'
    frequency; the pole damping ``D_R = center_damping sqrt(damping_ratio) = w / (2 f)``)."""
    damping_ratio = 10.0 ** (min(d, FULL_DEPTH_DB) / 20.0)  # a full cut: as deep as counts
    center_damping = w / (2.0 * f) / math.sqrt(clamp(enc, "damping_ratio", damping_ratio))
    return {"center_hz": f, "ratio": 1.0, "center_damping": center_damping, "damping_ratio": damping_ratio}


def clamp(enc: FilterEncoding, name: str, x: float) -> float:
    """``x`` clamped into the range of field ``name`` (unchanged when the field has none)."""
    if name in enc.ranges:
        low, high = enc.ranges[name]
        return min(max(x, low), high)
    return x


def index_table(enc: FilterEncoding, name: str) -> tuple[tuple[float, ...], tuple[int, ...]]:
    """``"width"`` or ``"depth"``: the table of physical values and the integer stored for each entry."""
    table, stored = (enc.width_table, enc.width_values) if name == "width" else (enc.depth_table, enc.depth_values)
    return table, stored or tuple(range(len(table)))


def is_index(enc: FilterEncoding, name: str) -> bool:
    """Whether field ``name`` stores an index into ``width_table`` / ``depth_table``."""
    if enc.kind == "index_table":
        return name in ("width", "depth")
    return enc.kind == "notch_parameters" and (
        (name == "width" and enc.width_unit == "index") or (name == "depth" and enc.depth_unit == "index")
    )


def candidates(enc: FilterEncoding, name: str, x: float) -> list:
    """Stored values of field ``name`` around the physical value ``x``.

    Integer fields: the grid steps from one below the lower neighbour to one
    above the upper; table fields: the three nearest entries; REAL32 fields:
    ``x`` itself (or the neighbours on its ``resolution``).  Depth-setting
    fields add a few settings deeper by :data:`DEPTH_MARGINS_DB`.
    """
    if is_index(enc, name):
        return index_candidates(enc, name, x)
    if enc.scales[name] == 0.0:
        return real_candidates(enc, name, x)
    if not math.isfinite(x):
        return []
    scale = enc.scales[name]
    n = x / scale
    low, high = integer_range(enc, name)
    steps = list(range(math.floor(n) - 1, math.ceil(n) + 2))
    if name in DEEPER:
        # a centre off the resonance, or rounding, can need a slightly deeper notch than asked
        steps += [int(round(deeper(enc, name, x, m) / scale)) for m in DEPTH_MARGINS_DB[1:]]
    return [m for m in dict.fromkeys(steps) if low <= m <= high]


def index_candidates(enc: FilterEncoding, name: str, x: float) -> list:
    """The stored values of the three table entries nearest ``x`` (depth: and the next deeper one)."""
    table, stored = index_table(enc, name)
    log = name == "width"
    dist = [abs(math.log(t / x)) if log else (0.0 if t == x else abs(t - x)) for t in table]
    ranked = sorted(range(len(table)), key=lambda i: dist[i])[:3]
    if name == "depth":
        # the next deeper entry too: a centre off the resonance can need it
        deeper_entries = [i for i in range(len(table)) if table[i] > x]
        if deeper_entries:
            ranked.append(min(deeper_entries, key=lambda i: table[i]))
    return [stored[i] for i in dict.fromkeys(ranked)]


def real_candidates(enc: FilterEncoding, name: str, x: float) -> list:
    """REAL32 values around ``x``: itself, or the neighbours on the field's ``resolution``."""
    # an infinite Q or frequency has no REAL32 form; the largest finite stand-in is deep enough
    x = min(x, 1e9)
    step = enc.resolution.get(name)
    if step is None:
        if name in DEEPER:
            # float32 rounding can leave the depth a hair short: a few slightly deeper values
            grid = [deeper(enc, name, x, m) for m in DEPTH_MARGINS_DB]
            return [float32(v) for v in grid if in_range(enc, name, v)] or [float32(x)]
        return [float32(x)]
    n = x / step
    grid = [step * m for m in range(math.floor(n) - 1, math.ceil(n) + 2)]
    return [float32(v) for v in grid if in_range(enc, name, v)]


def deeper_sign(enc: FilterEncoding, name: str) -> int:
    """+1 when a larger value of depth-setting field ``name`` makes the notch deeper, else -1."""
    if name == "depth" and enc.kind == "notch_parameters" and enc.depth_unit not in ("db", "index"):
        return -1
    return DEEPER[name]


def deeper(enc: FilterEncoding, name: str, x: float, margin_db: float) -> float:
    """The value of depth-setting field ``name`` that deepens the notch by about ``margin_db``."""
    if name == "depth" and deeper_sign(enc, name) > 0:
        return x + margin_db
    return x * 10.0 ** (deeper_sign(enc, name) * margin_db / 20.0)


def integer_range(enc: FilterEncoding, name: str) -> tuple[int, int]:
    """The stored integers field ``name`` may hold: the encoding's limits within the field's range."""
    scale = enc.scales[name]
    if enc.kind == "notch_parameters":
        low, high = (1 if legacy_units(enc) else 0), enc.max_value
    else:
        low, high = 0, 2**32 - 1
    if name in enc.ranges:
        low = max(low, math.ceil(enc.ranges[name][0] / scale - 1e-9))
        high = min(high, math.floor(enc.ranges[name][1] / scale + 1e-9))
    return low, high


def in_range(enc: FilterEncoding, name: str, v: float) -> bool:
    """Whether the physical value ``v`` lies in the range of field ``name`` (to 1e-12)."""
    low, high = enc.ranges.get(name, (0.0, math.inf))
    return low - 1e-12 <= v <= high + 1e-12


def nearest(enc: FilterEncoding, name: str, x: float):
    """The stored value of field ``name`` whose physical value is nearest ``x`` (DataError when none)."""
    cands = candidates(enc, name, x)
    if not cands:
        raise DataError(f"notch {name} {x!r} cannot be stored")
    return min(cands, key=lambda c: abs(physical(enc, name, c) - x) if not is_index(enc, name) else abs(cands.index(c)))


def physical(enc: FilterEncoding, name: str, stored) -> float:
    """The physical value (Hz, Q, damping, ratio, dB) a stored field value stands for."""
    if is_index(enc, name):
        table, values = index_table(enc, name)
        if stored not in values:
            raise DataError(f"{name} index {stored!r} is not in the drive's table (values {list(values)})")
        return table[values.index(stored)]
    scale = enc.scales[name]
    if scale == 0.0:
        x = float32(stored)
        step = enc.resolution.get(name)
        return x if step is None else step * round(x / step)
    if isinstance(stored, bool) or int(stored) != stored:
        raise DataError(f"notch {name} must be an integer, got {stored!r}")
    return int(stored) * scale


def physical_values(enc: FilterEncoding, values: dict) -> dict[str, float]:
    """The physical value of every field of ``values``, refused outside the drive's ranges."""
    out = {}
    for name in enc.fields:
        x = physical(enc, name, values[name])
        if math.isnan(x) or (math.isinf(x) and name != "depth") or (name in enc.ranges and not in_range(enc, name, x)):
            low, high = enc.ranges.get(name, (0, math.inf))
            raise DataError(f"notch {name} {x:g} is outside the drive's range {low:g}..{high:g}")
        out[name] = x
    return out


def notch_triplet(enc: FilterEncoding, p: dict[str, float]) -> tuple[float, float, float]:
    """Centre (Hz), width (Hz) and depth (dB) of the physical field values ``p``."""
    if enc.kind == "notch_parameters":
        return notch_parameters_triplet(enc, p)
    if enc.kind == "index_table":
        return p["center"], p["width"] * p["center"], p["depth"]
    if enc.kind == "center_band":
        return p["center"], 3.0 * p["band"] / math.pi, math.inf
    if enc.kind == "pole_zero_q":
        if not (p["zero_q"] > 0 and p["pole_q"] > 0):
            raise DataError(f"pole and zero Q must be positive, got {p['pole_q']:g} and {p['zero_q']:g}")
        zero_d, pole_d, f_zero, f_pole = 0.5 / p["zero_q"], 0.5 / p["pole_q"], p["zero_hz"], p["pole_hz"]
    elif enc.kind == "center_ratio_damping":
        f_zero, zero_d, f_pole, pole_d = center_ratio_pair(p)
    else:
        zero_d, pole_d, f_zero, f_pole = p["num_damping"], p["den_damping"], p["num_hz"], p["den_hz"]
    depth = math.inf if zero_d == 0 else 20.0 * math.log10(pole_d / zero_d) if pole_d > 0 else -math.inf
    return f_zero, 2.0 * pole_d * f_pole, depth


def center_ratio_pair(p: dict[str, float]) -> tuple[float, float, float, float]:
    """``"center_ratio_damping"``: zero Hz, zero damping, pole Hz, pole damping of the physical values ``p``."""
    return anti_resonance_pair(p["center_hz"], p["ratio"], p["center_damping"], p["damping_ratio"])


def notch_parameters_triplet(enc: FilterEncoding, p: dict[str, float]) -> tuple[float, float, float]:
    """``"notch_parameters"``: centre (Hz), width (Hz) and depth (dB) of the fields in their units (no depth
    field: a full cut)."""
    center, width, depth = p["center"], p["width"], p.get("depth", math.inf)
    if enc.width_unit == "q":
        if not width > 0:
            raise DataError(f"notch Q must be positive, got {width:g}")
        width = center / width
    elif enc.width_unit in ("ratio", "index"):
        width *= center
    if enc.depth_unit not in ("db", "index", "full"):
        ratio = depth / 100.0 if enc.depth_unit == "percent" else depth
        depth = math.inf if ratio <= 0 else -20.0 * math.log10(ratio)
    return center, width, depth


def parametric_section(enc: FilterEncoding, p: dict[str, float], rate: float) -> Biquad:
    """Pole/zero, centre/ratio and rejection-band encodings: the section the drive builds at ``rate`` (Hz)."""
    if enc.kind == "center_band":
        return rejection_band_section(p["center"], p["band"], rate)
    if enc.kind == "center_ratio_damping":
        s = center_ratio_section(p["center_hz"], p["ratio"], p["center_damping"], p["damping_ratio"], rate)
        return float32_biquad(*s.b, s.a[1], s.a[2])
    if enc.kind in ("pole_zero_q", "pole_zero_damping"):
        f_zero, f_pole = (p["zero_hz"], p["pole_hz"]) if enc.kind == "pole_zero_q" else (p["num_hz"], p["den_hz"])
        notch_triplet(enc, p)  # raises on Q values that are no filter
        if enc.kind == "pole_zero_q":
            args = (f_zero, 0.5 / p["zero_q"], f_pole, 0.5 / p["pole_q"])
        else:
            args = (f_zero, p["num_damping"], f_pole, p["den_damping"])
        s = two_frequency_section(*args, rate)
        return float32_biquad(*s.b, s.a[1], s.a[2])
    raise DataError(f'the "{enc.kind}" encoding is not a pole/zero or rejection-band encoding')


def unit(enc: FilterEncoding, name: str) -> str:
    """The unit of a field's physical value, for notes (with its leading space)."""
    if name in ("center", "band") or name.endswith("_hz"):
        return " Hz"
    if name == "width" and enc.kind == "notch_parameters":
        return {"hz": " Hz", "q": " (Q)", "ratio": " (of the centre)", "index": " (of the centre)"}[enc.width_unit]
    if name == "depth" and enc.kind == "notch_parameters":
        return {"db": " dB", "ratio": " (ratio)", "percent": " %", "index": " dB"}[enc.depth_unit]
    return ""


def same_frequency(enc: FilterEncoding, values: dict) -> bool:
    """Pole/zero encodings: whether the two frequencies of ``values`` are equal (then it is a notch)."""
    pair = SAME_FREQUENCY.get(enc.kind)
    return not pair or physical(enc, pair[0], values[pair[0]]) == physical(enc, pair[1], values[pair[1]])


def adjacent(enc: FilterEncoding, name: str, stored) -> list:
    """The stored values one step either side of ``stored`` (none for REAL32 fields)."""
    if is_index(enc, name):
        _, values = index_table(enc, name)
        i = values.index(stored)
        return [values[j] for j in (i - 1, i + 1) if 0 <= j < len(values)]
    if enc.scales[name] == 0.0:
        return []
    return [stored - 1, stored + 1]


def stored_in_range(enc: FilterEncoding, name: str, stored) -> bool:
    """Whether an integer field may store ``stored`` (tables and REAL32 fields: always)."""
    if is_index(enc, name) or enc.scales[name] == 0.0:
        return True
    low, high = integer_range(enc, name)
    return low <= stored <= high


def legacy_units(enc: FilterEncoding) -> bool:
    """``"notch_parameters"`` in Hz and dB: integers 1..max_value, out-of-range values refused by encode()."""
    return enc.width_unit == "hz" and enc.depth_unit == "db"
