import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError, DataError
from hilident.filters.notch import NotchSpec, design_notch
from hilident.protocol.filter_encoding import FilterEncoding, float32

RATE = 4000.0


def notch(center=21.8, width=6.5, depth=40.0):
    spec = NotchSpec(center, width, depth)
    return design_notch(spec, RATE), spec


def deepest_hz(biquad, lo, hi):
    f = np.linspace(lo, hi, 20001)
    return f[np.argmin(np.abs(biquad.response(f, RATE)))]


def test_real32_is_the_single_precision_of_each_coefficient():
    bq, spec = notch()
    enc = FilterEncoding("real32")
    values = enc.encode(bq, spec)
    assert list(values) == ["b0", "b1", "b2", "a1", "a2"]
    assert values["a1"] == float32(bq.a[1]) and values["a1"] != bq.a[1]
    applied = enc.applied(values, RATE)
    assert applied.b == tuple(float32(x) for x in bq.b)


def test_fixed_point_keeps_dc_gain_one_and_the_grid():
    bq, spec = notch(center=300.0, width=60.0)
    enc = FilterEncoding("fixed", fractional_bits=29)
    values = enc.encode(bq, spec)
    assert all(isinstance(v, int) for v in values.values())
    applied = enc.applied(values, RATE)
    assert applied.dc_gain() == pytest.approx(1.0, abs=1e-12)
    assert max(abs(x - y) for x, y in zip(applied.a, bq.a, strict=False)) <= 2.0**-30
    assert enc.stored_form(bq, spec, RATE) == applied


def test_fixed_point_overflow_is_an_error():
    bq, spec = notch()
    with pytest.raises(DataError, match="overflows"):
        FilterEncoding("fixed", fractional_bits=31).encode(bq, spec)


def test_notch_parameters_quantise_to_the_drive_steps():
    bq, spec = notch(center=21.7849, width=6.53, depth=40.0)
    enc = FilterEncoding("notch_parameters", center_scale=0.1, width_scale=0.1, depth_scale=0.1)
    values = enc.encode(bq, spec)
    assert values == {"center": 218, "width": 65, "depth": 400}
    achieved = enc.parameters(values)
    assert achieved.center_hz == pytest.approx(21.8)
    applied = enc.applied(values, RATE)
    # the drive's notch is centred on the quantised frequency, not the designed one
    assert deepest_hz(applied, 20.0, 24.0) == pytest.approx(21.8, abs=0.01)
    assert 20 * np.log10(abs(applied.response(np.array([21.8]), RATE)[0])) < -35


@settings(max_examples=40, deadline=None)
@given(center=st.floats(5.0, 1500.0), depth=st.floats(6.0, 60.0))
def test_notch_parameter_rounding_error_is_at_most_half_a_step(center, depth):
    spec = NotchSpec(center, 0.2 * center, depth)
    enc = FilterEncoding("notch_parameters", center_scale=0.1, width_scale=0.1, depth_scale=0.1)
    got = enc.parameters(enc.encode(design_notch(spec, RATE), spec))
    assert abs(got.center_hz - center) <= 0.05 + 1e-9
    assert abs(got.depth_db - depth) <= 0.05 + 1e-9


def test_notch_parameters_out_of_range_and_missing_spec():
    bq, spec = notch(center=200.0, width=40.0)
    enc = FilterEncoding("notch_parameters", max_value=1000)
    with pytest.raises(DataError, match="center 200 is 2000 steps"):
        enc.encode(bq, spec)
    with pytest.raises(DataError, match="no NotchSpec"):
        enc.encode(bq, None)
    with pytest.raises(DataError, match="infinite|cannot be encoded"):
        enc.encode(bq, NotchSpec(20.0, 5.0, math.inf))


def test_applied_checks_its_input():
    enc = FilterEncoding("fixed", fractional_bits=29)
    one = 2**29
    with pytest.raises(DataError, match="unstable"):
        enc.applied({"b0": one, "b1": 0, "b2": 0, "a1": 0, "a2": 2 * one}, RATE)
    with pytest.raises(DataError, match="lack a2"):
        enc.applied({"b0": one, "b1": 0, "b2": 0, "a1": 0}, RATE)
    with pytest.raises(DataError, match="not below half"):
        FilterEncoding("notch_parameters").applied({"center": 25000, "width": 100, "depth": 300}, RATE)


def test_from_table_names_bad_keys():
    assert FilterEncoding.from_table({"encoding": "fixed", "fractional_bits": 28}).fractional_bits == 28
    with pytest.raises(ConfigError, match="filters.encoding") as info:
        FilterEncoding.from_table({"encoding": "float64"}, "drivers/x/driver.toml")
    assert info.value.file == "drivers/x/driver.toml"
    with pytest.raises(ConfigError, match="filters.center_scale"):
        FilterEncoding.from_table({"encoding": "notch_parameters", "center_scale": 0})


def test_every_public_name_is_imported_from_the_package_as_before_the_split():
    import hilident.protocol.filter_encoding as package

    before = {
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
    }
    assert set(package.__all__) == before
    assert all(getattr(package, name) is not None for name in before)
