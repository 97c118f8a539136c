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
``"center_ratio_damping"``
    ``center_hz``, ``ratio``, ``center_damping``, ``damping_ratio`` (Beckhoff
    AX2000-style bi-quad BQFC, BQFR, BQDC, BQDR; the zeros at
    ``center / sqrt(ratio)`` damped ``center_damping / sqrt(damping_ratio)``, the
    poles at ``center sqrt(ratio)`` damped ``center_damping sqrt(damping_ratio)``:
    an assumption, :func:`~hilident.filters.parametric.anti_resonance_pair`);
    a notch has ``ratio = 1`` and depth ``20 log10(damping_ratio)`` at the centre.

``"notch_parameters"`` with ``depth_unit = "full"`` has no depth field: the
slot always cuts fully (Ingenia/Novanta's biquad of type "Notch", assumed to be
the audio-EQ-cookbook notch, whose width is a Q).

The pole/zero and centre/ratio encodings are discretised by the bilinear transform with the
numerator pre-warped at its natural frequency and the denominator at its own
(:func:`~hilident.filters.parametric.two_frequency_section`), so the zeros and
poles sit at the stored frequencies; Kollmorgen documents a backward-Euler form
pre-warped the same way, which differs from this one only far above the notch.

:meth:`FilterEncoding.realise` fits a :class:`~hilident.filters.notch.NotchSpec`
to what the encoding can store and says what it achieves.

All functions are pure: values in, values out.

The package, by seam: :mod:`.encoding` (:class:`FilterEncoding`: checks,
what the host writes, what the drive runs), :mod:`.grid` (unit conversions
and the grid of stored values of the physical-parameter encodings),
:mod:`.fit` (:meth:`FilterEncoding.realise`), :mod:`.block` (word blocks),
:mod:`.vocabulary` (names and limits). Import every name from here.

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

from hilident.protocol.filter_encoding.block import COPLEY, COPLEY_PLUS, PRESETS, BlockLayout
from hilident.protocol.filter_encoding.encoding import FilterEncoding
from hilident.protocol.filter_encoding.fit import Realisation
from hilident.protocol.filter_encoding.vocabulary import (
    COEFFICIENT_FIELDS,
    DEEPER,
    DEPTH_MARGINS_DB,
    DEPTH_TOLERANCE_DB,
    DEPTH_UNITS,
    ENCODINGS,
    FLOAT32_MAX,
    FULL_DEPTH_DB,
    MIN_ATTENUATION_DB,
    PARAMETER_FIELDS,
    PARAMETRIC,
    REFINE_STEPS,
    SAME_FREQUENCY,
    SCALER_CHOICES,
    WIDTH_TOLERANCE,
    WIDTH_UNITS,
    float32,
)

__all__ = [
    "COEFFICIENT_FIELDS",
    "COPLEY",
    "COPLEY_PLUS",
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
    "PRESETS",
    "REFINE_STEPS",
    "SAME_FREQUENCY",
    "SCALER_CHOICES",
    "WIDTH_TOLERANCE",
    "WIDTH_UNITS",
    "BlockLayout",
    "FilterEncoding",
    "Realisation",
    "float32",
]
