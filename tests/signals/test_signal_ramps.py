"""Velocity ramps for constant-velocity friction tests."""

import numpy as np
import pytest
import scipy.integrate
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError
from hilident.signals import RampProfile, velocity_ramps

FS = 1000.0


def _position(profile):
    return scipy.integrate.cumulative_trapezoid(profile.setpoint_mps, dx=1 / FS, initial=0.0)


def test_alternating_profile_returns_to_start():
    p = velocity_ramps([0.01, 0.05, 0.2], 1.0, accel_mps2=0.5, sample_rate_hz=FS, settle_s=0.3)
    assert isinstance(p, RampProfile)
    assert p.setpoint_mps[0] == 0.0 and p.setpoint_mps[-1] == 0.0
    assert abs(np.sum(p.setpoint_mps) / FS) < 1e-12
    assert abs(_position(p)[-1]) < 1e-12
    assert [w[2] for w in p.windows] == [0.01, -0.01, 0.05, -0.05, 0.2, -0.2]
    assert p.speeds_mps == (0.01, 0.05, 0.2)


def test_windows_lie_on_constant_parts_after_settling():
    hold, settle = 1.0, 0.3
    p = velocity_ramps([0.02, 0.1], hold, accel_mps2=0.4, sample_rate_hz=FS, settle_s=settle)
    for start, stop, v in p.windows:
        assert stop - start == round((hold - settle) * FS)
        assert np.all(p.setpoint_mps[start:stop] == v)
        # the settling time before the window is also at v, and the ramp before it is not
        before = p.setpoint_mps[start - round(settle * FS) : start]
        assert np.all(before == v)
        assert p.setpoint_mps[start - round(settle * FS) - 1] != v
        assert p.setpoint_mps[stop] != v  # ramp down starts right after the window


def test_acceleration_never_exceeds_limit():
    accel = 0.3
    p = velocity_ramps([0.05, 0.123], 0.5, accel_mps2=accel, sample_rate_hz=FS, settle_s=0.1)
    a = np.diff(p.setpoint_mps) * FS
    assert np.max(np.abs(a)) <= accel * (1 + 1e-9)
    assert np.max(np.abs(a)) > 0.9 * accel  # and the ramps really use it


def test_excursion_matches_integrated_position():
    v, hold, accel = 0.1, 2.0, 0.5
    p = velocity_ramps([v], hold_s=hold, accel_mps2=accel, sample_rate_hz=FS, settle_s=0.5)
    x = _position(p)
    assert p.excursion_m == (pytest.approx(x.min()), pytest.approx(x.max()))
    # analytic trapezoid distance: v * (hold + v / accel)
    assert p.max_excursion_m == pytest.approx(v * (hold + v / accel), rel=1e-3)


def test_one_direction_profile_drifts():
    p = velocity_ramps([0.05, 0.1], 1.0, 0.5, FS, 0.2, alternate=False)
    assert [w[2] for w in p.windows] == [0.05, 0.1]
    assert p.excursion_m[0] == pytest.approx(0.0, abs=1e-15)
    expected = 0.05 * (1.0 + 0.05 / 0.5) + 0.1 * (1.0 + 0.1 / 0.5)
    assert p.excursion_m[1] == pytest.approx(expected, rel=1e-3)


def test_negative_first_speed_goes_negative_first():
    p = velocity_ramps([-0.05], 1.0, 0.5, FS, 0.2)
    assert [w[2] for w in p.windows] == [-0.05, 0.05]
    assert p.excursion_m[0] < 0 and p.excursion_m[1] == pytest.approx(0.0, abs=1e-15)


@settings(max_examples=30, deadline=None)
@given(
    speeds=st.lists(st.floats(1e-3, 0.5), min_size=1, max_size=4),
    hold=st.floats(0.05, 0.5),
    accel=st.floats(0.1, 5.0),
)
def test_property_returns_to_start(speeds, hold, accel):
    p = velocity_ramps(speeds, hold, accel, FS, settle_s=0.5 * hold)
    assert abs(_position(p)[-1]) <= 1e-12 * max(1.0, p.max_excursion_m)
    assert len(p.windows) == 2 * len(speeds)
    for start, stop, v in p.windows:
        assert stop > start
        assert np.all(p.setpoint_mps[start:stop] == v)


@pytest.mark.parametrize(
    "kwargs, key",
    [
        (dict(settle_s=1.0), "settle_s"),
        (dict(settle_s=-0.1), "settle_s"),
        (dict(hold_s=0.0), "hold_s"),
        (dict(accel_mps2=0.0), "accel_mps2"),
        (dict(speeds_mps=[0.1, 0.0]), "speeds_mps"),
        (dict(speeds_mps=[]), "speeds_mps"),
        (dict(sample_rate_hz=0.0), "sample_rate_hz"),
    ],
)
def test_invalid_arguments_name_the_key(kwargs, key):
    args = dict(speeds_mps=[0.1], hold_s=1.0, accel_mps2=1.0, sample_rate_hz=FS, settle_s=0.2)
    args.update(kwargs)
    with pytest.raises(ConfigError) as info:
        velocity_ramps(**args)
    assert info.value.key == key


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.001, 0.5) | st.floats(-0.5, -0.001), min_size=1, max_size=5),
    st.floats(0.01, 1.0),
    st.floats(0.05, 20.0),
    st.booleans(),
)
def test_extent_is_the_length_and_travel_of_the_profile_without_building_it(speeds, hold, accel, alternate):
    from hilident.signals import ramp_extent

    p = velocity_ramps(speeds, hold, accel, FS, settle_s=0.0, alternate=alternate)
    n, travel = ramp_extent(speeds, hold, accel, FS, settle_s=0.0, alternate=alternate)
    assert n == p.setpoint_mps.size
    assert travel == pytest.approx(p.max_excursion_m, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize(
    "kwargs, key",
    [
        (dict(accel_mps2=1e-9), "accel_mps2"),
        (dict(hold_s=1e5), "hold_s"),
        (dict(speeds_mps=[0.01] * 2000, hold_s=10.0), "hold_s"),
    ],
)
def test_a_profile_beyond_the_size_bound_is_refused_before_it_is_built(kwargs, key):
    import tracemalloc

    from hilident.signals import ramp_extent

    args = dict(speeds_mps=[0.01, 0.1], hold_s=1.0, accel_mps2=1.0, sample_rate_hz=FS, settle_s=0.1) | kwargs
    tracemalloc.start()
    try:
        for build in (velocity_ramps, ramp_extent):
            with pytest.raises(ConfigError, match="2\\*\\*25") as err:
                build(**args)
            assert err.value.key == key
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 * 2**20


def test_a_nan_speed_is_named_plainly():
    with pytest.raises(ConfigError) as err:
        velocity_ramps(np.array([0.01, np.nan]), 1.0, 1.0, FS, 0.1)
    assert err.value.key == "speeds_mps" and str(err.value).endswith("got nan")
