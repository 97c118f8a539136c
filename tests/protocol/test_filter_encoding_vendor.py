"""Vendor filter encodings: coefficient order and sign, word blocks, physical parameters, realise()."""

import itertools
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch
from hilident.filters.parametric import (
    attenuation_db,
    rejection_band_section,
    two_frequency_section,
)
from hilident.protocol.filter_encoding import FilterEncoding, float32

RATE = 4000.0
# Panasonic-style tables (bandwidth/centre per width setting; dB per depth setting), as the vendor lists them
WIDTHS = (
    0.50,
    0.59,
    0.71,
    0.84,
    1.00,
    1.19,
    1.41,
    1.68,
    2.00,
    2.38,
    2.83,
    3.36,
    4.00,
    4.76,
    5.66,
    6.73,
    8.00,
    9.51,
    11.31,
    13.45,
    16.00,
)
DEPTH_VALUES = (0, 1, 2, 3, 4, 5, 10, 15, 20, 25, 30, 35, 40, 45, 50, 60, 70, 80, 90, 100)
DEPTHS = (
    math.inf,
    40.0,
    34.0,
    30.5,
    28.0,
    26.0,
    20.0,
    16.5,
    14.0,
    12.0,
    10.5,
    9.1,
    8.0,
    6.9,
    6.0,
    4.4,
    3.1,
    1.9,
    0.9,
    0.0,
)


def panasonic():
    return FilterEncoding.from_table(
        {
            "encoding": "index_table",
            "width_table": list(WIDTHS),
            "depth_table": list(DEPTHS),
            "depth_values": list(DEPTH_VALUES),
            "ranges": {"center": [50, 5000]},
        }
    )


def yaskawa_style():
    return FilterEncoding.from_table(
        {
            "encoding": "notch_parameters",
            "width_unit": "q",
            "depth_unit": "ratio",
            "scales": {"center": 1, "width": 0.01, "depth": 0.001},
            "ranges": {"center": [50, 5000], "width": [0.5, 10], "depth": [0, 1]},
        }
    )


def words_of(block):
    return [int.from_bytes(block[i : i + 2], "little") for i in range(0, len(block), 2)]


def db_at(section, f):
    return attenuation_db(section, f, RATE)


# --------------------------------------------------------------------------- coefficient order and sign


def test_real32_field_order_and_plus_sign_store_the_negated_feedback_terms():
    spec = NotchSpec(300.0, 60.0, 30.0)
    bq = design_notch(spec, RATE)
    enc = FilterEncoding.from_table(
        {"encoding": "real32", "order": ["a1", "a2", "b0", "b1", "b2"], "feedback_sign": "plus"}
    )
    values = enc.encode(bq, spec)
    assert list(values) == ["a1", "a2", "b0", "b1", "b2"] == list(enc.fields)
    assert values["a1"] == float32(-bq.a[1]) and values["a2"] == float32(-bq.a[2])
    assert values["b1"] == float32(bq.b[1])
    assert enc.applied(values, RATE) == FilterEncoding("real32").stored_form(bq, spec, RATE)
    # the same numbers read with the other convention are no filter a drive could run
    assert not FilterEncoding("real32").applied(values, RATE).is_stable()
    assert enc.applied(values, RATE).is_stable()


def test_fixed_point_with_plus_sign_round_trips():
    spec = NotchSpec(120.0, 20.0, 35.0)
    bq = design_notch(spec, RATE)
    plus = FilterEncoding("fixed", fractional_bits=29, feedback_sign="plus", order=("b2", "b1", "b0", "a2", "a1"))
    minus = FilterEncoding("fixed", fractional_bits=29)
    vp, vm = plus.encode(bq, spec), minus.encode(bq, spec)
    assert list(vp) == ["b2", "b1", "b0", "a2", "a1"]
    assert vp["a1"] == -vm["a1"] and vp["a2"] == -vm["a2"] and vp["b0"] == vm["b0"]
    assert plus.applied(vp, RATE) == minus.applied(vm, RATE)
    assert db_at(plus.applied(vp, RATE), 120.0) == pytest.approx(35.0, abs=0.01)


def test_order_must_name_every_field_once():
    with pytest.raises(ConfigError, match="filters.order") as info:
        FilterEncoding.from_table({"encoding": "real32", "order": ["b0", "b1", "b2", "a1", "a1"]}, "d/driver.toml")
    assert info.value.file == "d/driver.toml"
    with pytest.raises(ConfigError, match="filters.feedback_sign"):
        FilterEncoding("fixed", feedback_sign="positive")


# --------------------------------------------------------------------------- word blocks (Copley)

# 9 words [info, info, info, b2, b1, b0, a2, a1, K], each little-endian: K = 8192 makes a step 2**-14
COPLEY_HAND = bytes.fromhex("000000000000001000e0004000f800100020")


def test_copley_block_decodes_a_hand_computed_example():
    enc = FilterEncoding.from_table({"encoding": "word_block", "preset": "copley"})
    assert enc.fields == ("block",)
    section = enc.applied({"block": COPLEY_HAND}, RATE)
    # b0 = 16384 * 8192 / 2**27 = 1, b1 = -8192 * 2**-14, b2 = 4096 * 2**-14; y = ... + a1 y1 + a2 y2
    assert section.b == (1.0, -0.5, 0.25)
    assert section.a == (1.0, -0.25, 0.125)
    assert enc.slot_enabled({"block": COPLEY_HAND}) is True


def test_copley_plus_block_decodes_a_hand_computed_example():
    enc = FilterEncoding.from_table({"encoding": "word_block", "preset": "copley_plus"})
    # word 1 = 0x6110 (band reject, two poles, designed), f1 = 100, f2 = 200, Rp/Rs = 0,
    # then a1 = 1.5, a2 = -0.5625, b0 = 1, b1 = -1.5, b2 = 0.5 as float32, upper word first
    block = bytes.fromhex("10616400c8000000c03f000010bf0000803f0000c0bf0000003f0000")
    section = enc.applied({"block": block}, RATE)
    assert section.b == (1.0, -1.5, 0.5)
    assert section.a == (1.0, -1.5, 0.5625)


def test_copley_block_encode_layout_and_resolution():
    spec = NotchSpec(300.0, 60.0, 30.0)
    bq = design_notch(spec, RATE)
    enc = FilterEncoding.from_table({"encoding": "word_block", "preset": "copley"})
    block = enc.encode(bq, spec)["block"]
    w = words_of(block)
    assert len(block) == 18 and w[0] == 0 and w[1] == w[2] == 0
    k = w[8]
    step = k / 2**27

    def signed(x):
        return x - 65536 if x & 0x8000 else x

    # the smallest scaler that holds |b1|, |a1| ~ 1.7 in 15 bits, within the searched 256
    assert math.ceil(max(abs(c) for c in (*bq.b, *bq.a[1:])) * 2**27 / 32767) <= k < 65536
    assert signed(w[7]) * step == pytest.approx(-bq.a[1], abs=step)  # a1, plus sign
    assert signed(w[6]) * step == pytest.approx(-bq.a[2], abs=step)
    assert signed(w[5]) * step == pytest.approx(bq.b[0], abs=step)
    applied = enc.applied({"block": block}, RATE)
    assert applied.dc_gain() == pytest.approx(1.0, abs=2 * step)
    assert db_at(applied, 300.0) > 25.0


def test_copley_plus_block_encode_layout():
    spec = NotchSpec(300.0, 60.0, 30.0)
    bq = design_notch(spec, RATE)
    enc = FilterEncoding.from_table({"encoding": "word_block", "preset": "copley_plus"})
    block = enc.encode(bq, spec)["block"]
    w = words_of(block)
    assert len(w) == 14 and w[0] == 0x6110
    # the -3 dB edges: f1 f2 = 300**2, f2 - f1 = 60
    assert (w[1], w[2]) == (271, 331)
    floats = [struct.unpack(">f", struct.pack(">HH", w[i], w[i + 1]))[0] for i in range(4, 14, 2)]
    assert floats == [float32(-bq.a[1]), float32(-bq.a[2]), *map(float32, bq.b)]


@pytest.mark.parametrize("preset, state", [("copley", 0xFFFF), ("copley_plus", 0xE110)])
def test_block_disable_keeps_coefficients_and_restores(preset, state):
    spec = NotchSpec(300.0, 60.0, 30.0)
    enc = FilterEncoding.from_table({"encoding": "word_block", "preset": preset})
    saved = enc.encode(design_notch(spec, RATE), spec)
    off = enc.disabled(saved)
    assert words_of(off["block"])[0] == state
    assert words_of(off["block"])[1:] == words_of(saved["block"])[1:]
    assert enc.slot_enabled(off) is False and enc.slot_enabled(saved) is True
    assert enc.applied(off, RATE) == Biquad.identity()
    assert db_at(enc.applied(saved, RATE), 300.0) > 25.0


def test_block_errors_are_typed():
    enc = FilterEncoding.from_table({"encoding": "word_block", "preset": "copley"})
    with pytest.raises(DataError, match="18 bytes"):
        enc.applied({"block": b"\x00" * 16}, RATE)
    with pytest.raises(DataError, match="no enable of its own"):
        FilterEncoding("real32").disabled({})
    assert FilterEncoding("real32").slot_enabled({}) is None
    with pytest.raises(ConfigError, match="filters.preset"):
        FilterEncoding.from_table({"encoding": "word_block", "preset": "kopley"})
    with pytest.raises(ConfigError, match="overlap"):
        FilterEncoding.from_table({"encoding": "word_block", "preset": "copley", "scaler_word": 3})
    with pytest.raises(ConfigError, match="filters.coefficient_words"):
        FilterEncoding.from_table({"encoding": "word_block", "words": 9, "coefficient_words": {"b0": 1}})
    unstable = bytes.fromhex("000000000000000000000040004000000020")
    with pytest.raises(DataError, match="unstable"):
        enc.applied({"block": unstable}, RATE)


def test_generic_word_block_big_endian_low_word_first():
    table = {
        "encoding": "word_block",
        "words": 11,
        "coefficient_format": "float32",
        "word_order": "low_first",
        "byte_order": "big",
        "coefficient_words": {"b0": 1, "b1": 3, "b2": 5, "a1": 7, "a2": 9},
        "state_word": 0,
        "state_mask": 1,
        "disabled_value": 0,
        "enabled_value": 1,
    }
    enc = FilterEncoding.from_table(table)
    spec = NotchSpec(50.0, 10.0, 30.0)
    bq = design_notch(spec, RATE)
    block = enc.encode(bq, spec)["block"]
    assert block[:2] == b"\x00\x01"
    lo, hi = struct.unpack(">HH", block[2:6])
    assert struct.unpack(">f", struct.pack(">HH", hi, lo))[0] == float32(bq.b[0])
    assert enc.applied({"block": block}, RATE) == FilterEncoding("real32").stored_form(bq, spec, RATE)


# --------------------------------------------------------------------------- physical parameters


def test_pole_zero_q_is_the_prewarped_anti_resonance_filter():
    enc = FilterEncoding("pole_zero_q")
    values = {"pole_hz": 300.0, "pole_q": 2.5, "zero_hz": 300.0, "zero_q": 25.0}
    section = enc.applied(values, RATE)
    # |AR(j 2 pi F)| = Q_P / Q_Z at the common frequency, kept by the pre-warping
    assert db_at(section, 300.0) == pytest.approx(20.0, abs=1e-3)
    ref = two_frequency_section(300.0, 1 / 50.0, 300.0, 1 / 5.0, RATE)
    np.testing.assert_allclose(section.b + section.a, ref.b + ref.a, rtol=1e-6)
    spec = enc.parameters(values)
    assert (spec.center_hz, spec.width_hz, spec.depth_db) == pytest.approx((300.0, 120.0, 20.0))
    # the AKD2G form: UDINT with 1000:1 scale gives the same section
    akd2g = FilterEncoding("pole_zero_q", scales={k: 0.001 for k in values})
    assert akd2g.applied({k: round(v * 1000) for k, v in values.items()}, RATE) == section


def test_pole_zero_damping_is_the_siemens_band_stop():
    enc = FilterEncoding("pole_zero_damping")
    # band-stop 300 Hz, bandwidth 60 Hz, depth 20 dB: D_N = 60 / 600, D_Z = 0.1 D_N
    values = {"num_hz": 300.0, "num_damping": 0.01, "den_hz": 300.0, "den_damping": 0.1}
    section = enc.applied(values, RATE)
    ref = FilterEncoding("real32").stored_form(design_notch(NotchSpec(300.0, 60.0, 20.0), RATE), None, RATE)
    np.testing.assert_allclose(section.b + section.a, ref.b + ref.a, rtol=1e-6)
    assert db_at(section, 300.0) == pytest.approx(20.0, abs=1e-3)


def test_index_table_is_the_panasonic_continuous_model():
    enc = panasonic()
    section = enc.applied({"center": 300, "width": 8, "depth": 10}, RATE)
    # width setting 8 = bandwidth/centre 2.00, depth setting 10 % = -20 dB
    w0 = 2 * np.pi * 300.0
    zeta = 1.0
    s = 1j * w0
    analog = (s * s + 2 * 0.1 * zeta * w0 * s + w0 * w0) / (s * s + 2 * zeta * w0 * s + w0 * w0)
    assert db_at(section, 300.0) == pytest.approx(-20 * np.log10(abs(analog)), abs=1e-3)
    assert enc.parameters({"center": 300, "width": 8, "depth": 10}) == NotchSpec(300.0, 600.0, 20.0)
    assert db_at(enc.applied({"center": 300, "width": 4, "depth": 0}, RATE), 300.0) > 100.0
    assert enc.applied({"center": 300, "width": 4, "depth": 100}, RATE) == Biquad.identity()
    with pytest.raises(DataError, match="depth index 7 is not in the drive's table"):
        enc.applied({"center": 300, "width": 4, "depth": 7}, RATE)
    with pytest.raises(DataError, match="outside the drive's range 50..5000"):
        enc.applied({"center": 20, "width": 4, "depth": 10}, RATE)


def test_center_band_runs_the_vendor_formula():
    enc = FilterEncoding("center_band", ranges={"center": [10, 2000], "band": [1, 4000]})
    assert enc.applied({"center": 120, "band": 15}, RATE) == rejection_band_section(120.0, 15.0, RATE)
    assert enc.parameters({"center": 120, "band": 15}).depth_db == math.inf
    with pytest.raises(DataError, match="must be an integer"):
        enc.applied({"center": 120.5, "band": 15}, RATE)


def test_parameter_tables_are_checked():
    with pytest.raises(ConfigError, match="filters.ranges.zero_q"):
        FilterEncoding.from_table({"encoding": "pole_zero_q", "ranges": {"zero_q": [5, 0.1]}})
    with pytest.raises(ConfigError, match="filters.scales"):
        FilterEncoding.from_table({"encoding": "pole_zero_q", "scales": {"center": 1}})
    with pytest.raises(ConfigError, match="filters.width_table"):
        FilterEncoding.from_table({"encoding": "index_table", "depth_table": [10]})
    with pytest.raises(ConfigError, match="filters.depth_values") as info:
        FilterEncoding.from_table(
            {"encoding": "index_table", "width_table": [1], "depth_table": [10, 20], "depth_values": [1]},
            "x/driver.toml",
        )
    assert info.value.file == "x/driver.toml"


# --------------------------------------------------------------------------- realise


def test_realise_meets_the_depth_where_nearest_rounding_misses_it():
    spec = NotchSpec(21.7849, 6.53, 40.0)
    enc = FilterEncoding("notch_parameters")
    nearest = enc.applied(enc.encode(design_notch(spec, RATE), spec), RATE)
    assert db_at(nearest, spec.center_hz) < 40.0
    r = enc.realise(spec, RATE)
    assert r.notes == () and r.section == enc.applied(r.fields, RATE)
    assert 40.0 <= r.attenuation_db == pytest.approx(db_at(r.section, spec.center_hz))
    # no neighbour one step away in any field is deep enough and closer to the asked depth
    steps = [(-1, 0, 1)] * 3
    for delta in itertools.product(*steps):
        values = {k: v + d for (k, v), d in zip(r.fields.items(), delta, strict=False)}
        att = db_at(enc.applied(values, RATE), spec.center_hz)
        assert not 40.0 <= att < r.attenuation_db
    assert r.achieved.center_hz == pytest.approx(r.fields["center"] * 0.1, abs=1e-3)


def test_realise_notes_what_the_ranges_cannot_reach():
    spec = NotchSpec(300.0, 60.0, 30.0)
    akd = FilterEncoding(
        "pole_zero_q", ranges={"pole_hz": [5, 5000], "zero_hz": [5, 5000], "pole_q": [0.2, 20], "zero_q": [0.1, 5]}
    )
    r = akd.realise(spec, RATE)
    # Q_Z <= 5 caps the depth at 20 log10(5 / Q_P): the notch is widened to Q_P = 0.2, and still short
    assert r.fields["zero_q"] == 5.0 and r.fields["pole_q"] == pytest.approx(0.2)
    assert r.attenuation_db == pytest.approx(20 * math.log10(25), abs=0.05)
    assert any("reaches 28.0 dB" in n for n in r.notes) and any("width 60 Hz" in n for n in r.notes)
    narrow = FilterEncoding("pole_zero_q", ranges={"pole_q": [0.5, 20], "zero_q": [0.1, 0.5]})
    with pytest.raises(DataError, match="attenuates 300 Hz"):
        narrow.realise(spec, RATE)
    r = panasonic().realise(spec, RATE)
    assert any("outside the drive's table 0.5..16" in n for n in r.notes)
    assert r.attenuation_db >= 30.0


def test_realise_of_an_int16_block_weighs_its_scalings():
    spec = NotchSpec(21.7849, 6.53, 30.0)
    enc = FilterEncoding.from_table({"encoding": "word_block", "preset": "copley"})
    nearest = db_at(enc.applied(enc.encode(design_notch(spec, RATE), spec), RATE), spec.center_hz)
    r = enc.realise(spec, RATE)
    assert r.attenuation_db >= 30.0 > nearest - 100  # deep enough whatever the first scaling gave
    assert r.notes == ()


# encoding, lowest centre it is asked for, the step its centre is stored in (0: REAL32)
REALISABLE = {
    "real32": (FilterEncoding("real32"), 5.0, 0),
    "fixed": (FilterEncoding("fixed", fractional_bits=29), 5.0, 0),
    "real32 plus": (FilterEncoding("real32", feedback_sign="plus", order=("a1", "a2", "b0", "b1", "b2")), 5.0, 0),
    "copley plus": (FilterEncoding.from_table({"encoding": "word_block", "preset": "copley_plus"}), 5.0, 0),
    # 16-bit coefficients with one scaler cannot hold a narrow notch below about rate / 200
    "copley": (FilterEncoding.from_table({"encoding": "word_block", "preset": "copley"}), RATE / 200, 0),
    "notch_parameters": (FilterEncoding("notch_parameters"), 5.0, 0.1),
    "pole_zero_q 1000:1": (
        FilterEncoding("pole_zero_q", scales={"pole_hz": 0.001, "zero_hz": 0.001, "pole_q": 0.001, "zero_q": 0.001}),
        5.0,
        0.001,
    ),
    "pole_zero_damping": (FilterEncoding("pole_zero_damping"), 5.0, 0),
    "index_table": (panasonic(), 50.0, 1),
    "center_band": (FilterEncoding("center_band", ranges={"center": [10, 2000], "band": [1, 4000]}), 10.0, 1),
    "q and ratio": (yaskawa_style(), 50.0, 1),
    "q, full depth": (
        FilterEncoding("notch_parameters", width_unit="q", depth_unit="full", scales={"center": 1, "width": 0}),
        5.0,
        1,
    ),
}


@pytest.mark.parametrize("name", list(REALISABLE))
@settings(max_examples=12, deadline=None)
@given(center=st.floats(0.0, 1.0), rel_width=st.floats(0.1, 0.5), depth=st.floats(20.0, 40.0))
def test_any_realisable_notch_is_at_least_20_db_deep(name, center, rel_width, depth):
    enc, low, step = REALISABLE[name]
    f = low * (0.4 * RATE / low) ** center
    if step:
        f = round(f / step) * step  # a notch the encoding can centre on the resonance
    spec = NotchSpec(f, rel_width * f, depth)
    r = enc.realise(spec, RATE)
    assert r.section == enc.applied(r.fields, RATE)
    assert r.attenuation_db >= 20.0
    depth_notes = [n for n in r.notes if "reaches" in n]
    assert bool(depth_notes) == (r.attenuation_db < depth - 0.1)


# --------------------------------------------------------------------------- the documented examples


def documented_tables():
    import pathlib
    import re
    import tomllib

    text = (pathlib.Path(__file__).parents[2] / "docs" / "filter_encodings.md").read_text()
    return [tomllib.loads(block)["filters"] for block in re.findall(r"```toml\n(.*?)```", text, re.DOTALL)]


def test_every_documented_example_builds_and_realises_a_notch():
    tables = documented_tables()
    assert len(tables) >= 10
    kinds = set()
    for table in tables:
        enc = FilterEncoding.from_table(table, "docs/filter_encodings.md")
        kinds.add(enc.kind)
        r = enc.realise(NotchSpec(300.0, 60.0, 20.0), RATE)
        assert r.section == enc.applied(r.fields, RATE)
        assert r.attenuation_db >= 20.0 or r.notes
    assert kinds == {
        "real32",
        "fixed",
        "word_block",
        "notch_parameters",
        "pole_zero_q",
        "pole_zero_damping",
        "index_table",
        "center_band",
        "center_ratio_damping",
    }
    copley = [t for t in tables if t.get("encoding") == "word_block" and "words" in t]
    assert FilterEncoding.from_table(copley[0]) == FilterEncoding.from_table(
        {"encoding": "word_block", "preset": "copley"}
    )


@pytest.mark.parametrize(
    "table, key",
    [
        ({"encoding": "word_block", "preset": ["copley"]}, "filters.preset"),
        ({"encoding": "word_block", "preset": "copley", "byte_order": "middle"}, "filters.byte_order"),
        (
            {
                "encoding": "word_block",
                "preset": "copley_plus",
                "coefficient_words": {"b0": 13, "b1": 10, "b2": 12, "a1": 4, "a2": 6},
            },
            "filters.coefficient_words.b0",
        ),
        ({"encoding": "index_table", "width_table": [1.0, "wide"], "depth_table": [10.0]}, "filters.width_table"),
        ({"encoding": "index_table", "width_table": [1.0], "depth_table": [-math.inf]}, "filters.depth_table"),
        ({"encoding": "center_band", "ranges": {"band": "narrow"}}, "filters.ranges.band"),
    ],
)
def test_hostile_tables_name_the_key_and_file(table, key):
    with pytest.raises(ConfigError) as info:
        FilterEncoding.from_table(table, "drv/driver.toml")
    assert info.value.key == key and info.value.file == "drv/driver.toml"


@pytest.mark.parametrize(
    "table, key",
    [
        ({"encoding": "notch_parameters", "center_scale": 10**400}, "filters.center_scale"),
        ({"encoding": "pole_zero_q", "ranges": {"pole_hz": [0, 10**400]}}, "filters.ranges.pole_hz"),
        ({"encoding": "index_table", "width_table": [1.0], "depth_table": [10**400]}, "filters.depth_table"),
    ],
)
def test_an_integer_beyond_any_float_is_a_config_error(table, key):
    # TOML integers may be arbitrarily long; float() of one overflows
    with pytest.raises(ConfigError) as info:
        FilterEncoding.from_table(table, "drv/driver.toml")
    assert info.value.key == key and info.value.file == "drv/driver.toml"


@pytest.mark.parametrize(
    "enc, values",
    [
        (FilterEncoding("pole_zero_q"), {"pole_hz": 300.0, "pole_q": 0.0, "zero_hz": 300.0, "zero_q": 5.0}),
        (
            FilterEncoding("pole_zero_damping"),
            {"num_hz": "300", "num_damping": 0.0, "den_hz": 300.0, "den_damping": 0.1},
        ),
        (
            FilterEncoding("pole_zero_damping"),
            {"num_hz": 1e300, "num_damping": 0.0, "den_hz": 300.0, "den_damping": 0.1},
        ),
        (FilterEncoding("center_band"), {"center": None, "band": 10}),
        (FilterEncoding("fixed"), {"b0": 1.5, "b1": 0, "b2": 0, "a1": 0, "a2": 0}),
        (FilterEncoding("real32"), {"b0": math.nan, "b1": 0, "b2": 0, "a1": 0, "a2": 0}),
        (FilterEncoding.from_table({"encoding": "word_block", "preset": "copley_plus"}), {"block": 28}),
    ],
)
def test_values_from_the_wire_that_are_no_filter_are_data_errors(enc, values):
    with pytest.raises(DataError):
        enc.applied(values, RATE)


# --------------------------------------------------------------------------- encode -> applied round trips


@pytest.mark.parametrize(
    "enc",
    [FilterEncoding("pole_zero_q"), FilterEncoding("pole_zero_damping")],
    ids=["pole_zero_q", "pole_zero_damping"],
)
@settings(max_examples=25, deadline=None)
@given(center=st.floats(5.0, 1600.0), rel_width=st.floats(0.05, 1.0), depth=st.floats(3.0, 50.0))
def test_real32_parameter_encodings_round_trip(enc, center, rel_width, depth):
    spec = NotchSpec(center, rel_width * center, depth)
    values = enc.encode(design_notch(spec, RATE), spec)
    got = enc.parameters(values)
    assert (got.center_hz, got.width_hz, got.depth_db) == pytest.approx(
        (spec.center_hz, spec.width_hz, spec.depth_db), rel=1e-6, abs=1e-4
    )
    section = enc.applied(values, RATE)
    p = [float(values[f]) for f in enc.fields]
    exact = (
        two_frequency_section(p[2], 0.5 / p[3], p[0], 0.5 / p[1], RATE)
        if enc.kind == "pole_zero_q"
        else two_frequency_section(p[0], p[1], p[2], p[3], RATE)
    )
    assert section == FilterEncoding("real32").applied(
        dict(zip(("b0", "b1", "b2", "a1", "a2"), (*exact.b, *exact.a[1:]), strict=False)), RATE
    )
    # pre-warped at the centre: the analog depth there (the drive's REAL32 section then rounds it,
    # which costs a fraction of a dB for narrow deep notches far below the rate)
    assert db_at(exact, center) == pytest.approx(depth, abs=1e-3)


def test_index_table_round_trips_on_its_own_settings():
    enc = panasonic()
    for width_setting, depth_value in ((0, 1), (8, 10), (12, 40), (20, 90)):
        ratio, depth = WIDTHS[width_setting], DEPTHS[DEPTH_VALUES.index(depth_value)]
        spec = NotchSpec(250.0, ratio * 250.0, depth)
        values = enc.encode(design_notch(spec, RATE), spec)
        assert values == {"center": 250, "width": width_setting, "depth": depth_value}
        assert db_at(enc.applied(values, RATE), 250.0) == pytest.approx(depth, abs=0.01)


def test_center_band_round_trips_on_integer_hertz():
    enc = FilterEncoding("center_band", ranges={"center": [10, 2000], "band": [1, 4000]})
    spec = NotchSpec(40.0, 3 * 12 / math.pi, math.inf)  # 12 Hz band; the warping is negligible at 40 Hz
    values = enc.encode(design_notch(NotchSpec(40.0, spec.width_hz, 60.0), RATE), spec)
    assert values == {"center": 40, "band": 12}
    section = enc.applied(values, RATE)
    assert section == rejection_band_section(40.0, 12.0, RATE)
    assert enc.realise(spec, RATE).fields == values


# --------------------------------------------------------------------------- units and resolution


def test_notch_parameters_in_q_and_depth_ratio():
    enc = yaskawa_style()
    # Q = 5 -> width = 300 / 5 = 60 Hz; depth ratio 0.032 -> 29.9 dB
    values = {"center": 300, "width": 500, "depth": 32}
    assert enc.parameters(values) == NotchSpec(300.0, 60.0, -20 * math.log10(0.032))
    ref = FilterEncoding("real32").stored_form(design_notch(enc.parameters(values), RATE), None, RATE)
    assert enc.applied(values, RATE) == ref
    assert db_at(enc.applied({**values, "depth": 0}, RATE), 300.0) > 100.0  # 0 = full cut
    assert enc.applied({**values, "depth": 1000}, RATE) == Biquad.identity()  # ratio 1 = pass
    with pytest.raises(DataError, match="Q must be positive"):
        FilterEncoding("notch_parameters", width_unit="q").applied({**values, "width": 0}, RATE)
    with pytest.raises(ConfigError, match="filters.width_unit"):
        FilterEncoding.from_table({"encoding": "notch_parameters", "width_unit": "octaves"})


def test_realise_in_q_units_notes_the_range_in_its_unit_and_ties_full_cuts_on_width():
    enc = yaskawa_style()
    r = enc.realise(NotchSpec(1000.0, 50.0, 20.0), RATE)
    assert r.fields["width"] == 1000  # Q 20 asked, 10 the most
    assert r.notes[0] == "width 20 (Q) is outside the drive's range 0.5..10 (Q); using 10 (Q)"
    # 80 dB asked: every full-cut candidate is deep enough, the asked Q = 2 decides
    r = enc.realise(NotchSpec(1000.0, 500.0, 80.0), RATE)
    assert r.fields == {"center": 1000, "width": 200, "depth": 0} and r.notes == ()
    with pytest.raises(DataError, match="center 21.78 Hz is outside the drive's range 50..5000 Hz"):
        enc.realise(NotchSpec(21.78, 6.5, 30.0), RATE)


def test_real32_field_resolution_is_what_the_drive_honours():
    enc = FilterEncoding("pole_zero_q", resolution={"pole_hz": 1.0, "zero_hz": 1.0})
    values = {"pole_hz": 21.7, "pole_q": 3.0, "zero_hz": 21.7, "zero_q": 30.0}
    assert enc.applied(values, RATE) == enc.applied({**values, "pole_hz": 22.0, "zero_hz": 22.0}, RATE)
    r = enc.realise(NotchSpec(21.7849, 6.53, 20.0), RATE)
    assert r.fields["pole_hz"] == r.fields["zero_hz"] == 22.0
    assert r.attenuation_db >= 20.0 and r.notes == ()
    # 0.2 Hz off a 6.5 Hz wide notch caps the depth near 2 * 0.2 / 6.5: 40 dB is out of reach, and said so
    r = enc.realise(NotchSpec(21.7849, 6.53, 40.0), RATE)
    assert 20.0 < r.attenuation_db < 26.0 and "not the 40 dB asked" in r.notes[-1]


def test_value_kinds_for_checking_against_an_eds():
    assert FilterEncoding("real32").value_kind("a1") == "float32"
    assert FilterEncoding("fixed").value_kind("b0") == "integer"
    assert FilterEncoding.from_table({"encoding": "word_block", "preset": "copley"}).value_kind("block") == "octets"
    akd = FilterEncoding("pole_zero_q")
    akd2g = FilterEncoding("pole_zero_q", scales={"pole_hz": 0.001, "pole_q": 0.001, "zero_hz": 0.001, "zero_q": 0.001})
    assert {akd.value_kind(f) for f in akd.fields} == {"float32"}
    assert {akd2g.value_kind(f) for f in akd2g.fields} == {"integer"}
    assert {panasonic().value_kind(f) for f in ("center", "width", "depth")} == {"integer"}
    with pytest.raises(DataError, match='"b0" is no field of the center_band encoding'):
        FilterEncoding("center_band").value_kind("b0")
