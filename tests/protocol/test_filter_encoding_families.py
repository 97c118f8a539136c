"""The encodings of the Beckhoff AX2000 and Ingenia/Novanta families: a centre/ratio bi-quad, and a full-depth
notch set by its centre and Q.

``center_ratio_damping`` stores BQFC, BQFR, BQDC, BQDR (the section from them
is an assumption, :func:`~hilident.filters.parametric.anti_resonance_pair`): a
notch has a ratio of 1 and the damping ratio as its depth at the centre, so
BQDR <= 5 caps it at 14 dB and ``realise`` says so. ``notch_parameters`` with
``depth_unit = "full"`` has no depth field.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilident.errors import ConfigError, DataError
from hilident.filters.notch import NotchSpec, design_notch
from hilident.filters.parametric import anti_resonance_pair, attenuation_db, two_frequency_section
from hilident.protocol.canopen_filters import parse_filter_objects
from hilident.protocol.filter_encoding import FilterEncoding, float32

RATE = 4000.0
AX2000 = {
    "encoding": "center_ratio_damping",
    "scales": {"center_hz": 0.001, "ratio": 0.001, "center_damping": 0.001, "damping_ratio": 0.001},
    "ranges": {"center_hz": [20, 1000], "ratio": [0.1, 10], "center_damping": [0.2, 1], "damping_ratio": [0.25, 5]},
}
INGENIA = {"encoding": "notch_parameters", "width_unit": "q", "depth_unit": "full", "scales": {"center": 1, "width": 0}}


def ax2000() -> FilterEncoding:
    return FilterEncoding.from_table(AX2000)


def ingenia() -> FilterEncoding:
    return FilterEncoding.from_table(INGENIA)


def db_at(section, f: float, rate: float = RATE) -> float:
    return attenuation_db(section, f, rate)


def as_real32(section):
    """``section`` as a drive holding REAL32 coefficients runs it."""
    b, a = section.b, section.a
    values = dict(zip(("b0", "b1", "b2", "a1", "a2"), (*b, a[1], a[2]), strict=True))
    return FilterEncoding("real32").applied(values, RATE)


# --------------------------------------------------------------------------- center_ratio_damping


def test_the_center_ratio_bi_quad_is_the_assumed_pole_zero_pair():
    enc = ax2000()
    assert enc.fields == ("center_hz", "ratio", "center_damping", "damping_ratio")
    # BQFC 200 Hz, BQFR 2.5, BQDC 0.3, BQDR 2: the drive's defaults
    values = {"center_hz": 200_000, "ratio": 2500, "center_damping": 300, "damping_ratio": 2000}
    f_ar, d_ar, f_r, d_r = anti_resonance_pair(200.0, 2.5, 0.3, 2.0)
    assert (f_ar, f_r) == pytest.approx((200.0 / math.sqrt(2.5), 200.0 * math.sqrt(2.5)))
    assert (d_ar, d_r) == pytest.approx((0.3 / math.sqrt(2.0), 0.3 * math.sqrt(2.0)))
    assert math.sqrt(f_ar * f_r) == pytest.approx(200.0) and f_r / f_ar == pytest.approx(2.5)
    assert enc.applied(values, RATE) == as_real32(two_frequency_section(f_ar, d_ar, f_r, d_r, RATE))
    # the zeros sit at the anti-resonance, the poles at the resonance (mapped back by their own pre-warping)
    section = enc.applied(values, RATE)
    for roots, f in ((np.roots(section.b), f_ar), (section.poles(), f_r)):
        k = 2 * math.pi * f / math.tan(math.pi * f / RATE)
        assert np.abs(k * (roots - 1) / (roots + 1)) == pytest.approx([2 * math.pi * f] * 2, rel=1e-5)
    got = enc.parameters(values)
    assert (got.center_hz, got.width_hz, got.depth_db) == pytest.approx((f_ar, 2.0 * d_r * f_r, 20 * math.log10(2)))


def test_a_ratio_of_one_is_a_notch_as_deep_as_the_damping_ratio():
    enc = ax2000()
    values = {"center_hz": 300_000, "ratio": 1000, "center_damping": 300, "damping_ratio": 5000}
    section = enc.applied(values, RATE)
    assert db_at(section, 300.0) == pytest.approx(20.0 * math.log10(5.0), abs=1e-3)
    # the pole damping BQDC sqrt(BQDR) sets the width: the pre-warped notch of that width and depth
    width = 2.0 * 0.3 * math.sqrt(5.0) * 300.0
    notch = as_real32(design_notch(NotchSpec(300.0, width, 20.0 * math.log10(5.0)), RATE))
    np.testing.assert_allclose(section.b + section.a, notch.b + notch.a, rtol=1e-6)
    spec = enc.parameters(values)
    assert (spec.center_hz, spec.width_hz, spec.depth_db) == pytest.approx((300.0, width, 20.0 * math.log10(5.0)))


@pytest.mark.parametrize(
    ("center", "rel_width", "depth"),
    [(21.78, 1.5, 12.0), (300.0, 1.0, 6.0), (950.0, 0.9, 13.9), (500.0, 2.0, 3.0)],
)
def test_center_ratio_damping_round_trips_what_its_ranges_hold(center, rel_width, depth):
    enc = ax2000()
    spec = NotchSpec(center, rel_width * center, depth)
    values = enc.encode(design_notch(spec, RATE), spec)
    assert values["ratio"] == 1000  # a notch: zeros and poles on one frequency
    got = enc.parameters(values)
    # each field within half a step of 0.001: the centre to 0.5 mHz, the depth and width to about 1e-3 relative
    assert got.center_hz == pytest.approx(center, abs=5e-4)
    assert got.width_hz == pytest.approx(spec.width_hz, rel=5e-3)
    assert got.depth_db == pytest.approx(depth, abs=0.02)
    section = enc.applied(values, RATE)
    assert db_at(section, center) == pytest.approx(depth, abs=0.02)
    r = enc.realise(spec, RATE)
    assert r.section == enc.applied(r.fields, RATE) and r.notes == ()
    assert depth <= r.attenuation_db < depth + 0.1


def test_realise_says_the_ranges_cap_the_depth_at_14_db():
    r = ax2000().realise(NotchSpec(300.0, 60.0, 20.0), RATE)
    assert r.fields["ratio"] == 1000 and r.fields["damping_ratio"] == 5000  # the deepest the range allows
    assert r.fields["center_damping"] == 200  # and the narrowest
    assert r.attenuation_db == pytest.approx(20.0 * math.log10(5.0), abs=0.01)
    assert "damping_ratio 10 is beyond the drive's range 0.25..5: a notch of this drive is at most 14.0 dB deep" in (
        r.notes
    )
    assert any("center_damping 0.0447214 is outside the drive's range 0.2..1" in n for n in r.notes)
    assert any(n.startswith("width 60 Hz is realised as 268 Hz") for n in r.notes), r.notes
    assert r.notes[-1] == "the center_ratio_damping encoding reaches 14.0 dB at 300 Hz, not the 20 dB asked"


def test_the_bi_quad_is_bypassed_by_ratios_of_one():
    enc = ax2000()
    assert enc.bypassable
    values = {"center_hz": 200_000, "ratio": 2500, "center_damping": 300, "damping_ratio": 2000}
    neutral = enc.neutral(values)
    assert neutral == {**values, "ratio": 1000, "damping_ratio": 1000}
    section = enc.applied(neutral, RATE)
    assert section.b == section.a  # the identity
    narrow = FilterEncoding.from_table({**AX2000, "ranges": {"damping_ratio": [2, 5]}})
    with pytest.raises(DataError, match="damping_ratio cannot hold 1"):
        narrow.neutral(values)
    # so a slot of this encoding needs no enable object
    table = {**AX2000, "fields": {n: [f"0x{0x3662 + i:04X}"] for i, n in enumerate(enc.fields)}, "enable": "none"}
    fo = parse_filter_objects(table)
    assert fo is not None and not fo.has_enable


def test_values_from_the_wire_that_are_no_bi_quad_are_data_errors():
    enc = ax2000()
    values = {"center_hz": 300_000, "ratio": 1000, "center_damping": 300, "damping_ratio": 5000}
    with pytest.raises(DataError, match="outside the drive's range 0.1..10"):
        enc.applied({**values, "ratio": 0}, RATE)
    with pytest.raises(DataError, match="must be an integer"):
        enc.applied({**values, "ratio": 1000.5}, RATE)
    with pytest.raises(DataError, match="not between 0 and half the 500 Hz filter rate"):
        enc.applied(values, 500.0)
    with pytest.raises(DataError, match="finite and positive"):
        FilterEncoding("center_ratio_damping", scales={"ratio": 0}).applied({**values, "ratio": 0.0}, RATE)


def test_center_ratio_damping_scales_and_fields():
    enc = FilterEncoding("center_ratio_damping")
    assert enc.scales == dict.fromkeys(enc.fields, 0.001)  # the AX2000's weighting of 1000
    assert {enc.value_kind(f) for f in enc.fields} == {"integer"}
    real = FilterEncoding("center_ratio_damping", scales=dict.fromkeys(enc.fields, 0))
    assert {real.value_kind(f) for f in real.fields} == {"float32"}
    r = real.realise(NotchSpec(300.0, 60.0, 30.0), RATE)  # no ranges: any depth
    assert r.notes == () and r.attenuation_db >= 30.0 and r.fields["ratio"] == 1.0


@pytest.mark.parametrize(
    ("table", "key"),
    [
        ({"scales": {"center": 1}}, "filters.scales"),
        ({"scales": {"ratio": -0.001}}, "filters.scales.ratio"),
        ({"ranges": {"damping_ratio": [5, 0.25]}}, "filters.ranges.damping_ratio"),
        ({"ranges": {"center_hz": "20..1000"}}, "filters.ranges.center_hz"),
        ({"resolution": {"center_damping": 0}}, "filters.resolution.center_damping"),
        ({"order": ["center_hz", "ratio", "center_damping"]}, "filters.order"),
    ],
)
def test_a_malformed_center_ratio_table_names_its_key(table, key):
    with pytest.raises(ConfigError) as info:
        FilterEncoding.from_table({**AX2000, **table}, "drv/driver.toml")
    assert info.value.key == key and info.value.file == "drv/driver.toml"


# --------------------------------------------------------------------------- notch_parameters, full depth


def test_a_full_depth_notch_has_no_depth_field():
    enc = ingenia()
    assert enc.fields == ("center", "width")
    assert (enc.value_kind("center"), enc.value_kind("width")) == ("integer", "float32")
    values = {"center": 300, "width": 5.0}  # Q 5: -3 dB bandwidth 60 Hz
    assert enc.parameters(values) == NotchSpec(300.0, 60.0, math.inf)
    assert enc.applied(values, RATE) == as_real32(design_notch(NotchSpec(300.0, 60.0, math.inf), RATE))
    assert db_at(enc.applied(values, RATE), 300.0) > 100.0
    assert not enc.bypassable  # an Ingenia slot needs its TYPE to be bypassed


def test_a_full_depth_notch_round_trips_on_integer_hertz():
    enc = ingenia()
    spec = NotchSpec(1000.0, 200.0, math.inf)
    values = enc.encode(design_notch(NotchSpec(1000.0, 200.0, 60.0), RATE), spec)
    assert values == {"center": 1000, "width": float32(5.0)}
    assert enc.realise(spec, RATE).fields == values
    assert enc.applied(values, RATE) == enc.stored_form(design_notch(spec, RATE), spec, RATE)


def test_a_full_cut_off_the_resonance_says_the_depth_it_reaches():
    r = ingenia().realise(NotchSpec(21.7849, 6.53, 40.0), 20000.0)
    assert r.fields["center"] == 22 and r.fields["width"] == float32(21.7849 / 6.53)
    assert 20.0 < r.attenuation_db < 40.0  # the centre a fifth of a hertz off the resonance
    assert r.notes == (
        f"the notch_parameters encoding reaches {r.attenuation_db:.1f} dB at 21.7849 Hz, not the 40 dB asked",
    )


@pytest.mark.parametrize(
    ("table", "key"),
    [
        ({"scales": {"center": 1, "width": 0, "depth": 0.1}}, "filters.scales"),
        ({"ranges": {"depth": [0, 1]}}, "filters.ranges"),
        ({"order": ["center", "width", "depth"]}, "filters.order"),
        ({"depth_unit": "fully"}, "filters.depth_unit"),
        ({"scales": {"center": 1, "width": -1}}, "filters.scales.width"),
    ],
)
def test_a_malformed_full_depth_table_names_its_key(table, key):
    with pytest.raises(ConfigError) as info:
        FilterEncoding.from_table({**INGENIA, **table}, "drv/driver.toml")
    assert info.value.key == key and info.value.file == "drv/driver.toml"
