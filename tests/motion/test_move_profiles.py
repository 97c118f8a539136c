"""Point-to-point profiles: exact end, limits kept, symmetric, triangular cases, typed errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError
from hilident.motion.profiles import s_curve, trapezoid

distances = st.floats(1e-4, 5.0).flatmap(lambda s: st.sampled_from([s, -s]))
velocities = st.floats(0.01, 3.0)
accels = st.floats(0.1, 50.0)
jerks = st.floats(1.0, 5000.0)
rates = st.sampled_from([250.0, 1000.0, 4000.0, 3333.3])
dwells = st.floats(0.0, 0.5)

# Rounding slack on limits evaluated from exact polynomials.
EPS = 1e-9


def _check_common(move, distance, vmax, amax, dwell, fs):
    i = move.move_end_index
    assert move.position_m[i:].tolist() == [distance] * (move.position_m.size - i)  # exact, not approximately
    assert not np.any(move.velocity_mps[i:]) and not np.any(move.accel_mps2[i:])
    assert move.position_m[0] == 0.0 and move.velocity_mps[0] == 0.0
    assert np.all(np.abs(move.velocity_mps) <= vmax * (1 + EPS))
    assert np.all(np.abs(move.accel_mps2) <= amax * (1 + EPS))
    # the motion ends within one sample after the plan's duration, the dwell lasts what was asked
    assert move.duration_s - 1e-9 / fs <= move.move_end_s < move.duration_s + 1.0 / fs + 1e-12
    assert move.dwell_s == pytest.approx(round(dwell * fs) / fs, abs=1e-9)
    assert np.allclose(np.diff(move.time_s), 1.0 / fs)
    # monotonic towards the target: a point-to-point move never backs up
    steps = np.diff(move.position_m) * np.sign(distance)
    assert np.all(steps >= -1e-12 * abs(distance))


def _check_symmetric(move, distance):
    plan = move.plan
    t = np.linspace(0.0, plan.duration_s, 257)
    p, v, a = plan.evaluate(t)
    pr, vr, ar = plan.evaluate(plan.duration_s - t)
    scale = abs(distance)
    assert np.allclose(v, vr, atol=1e-9 * max(1.0, np.abs(v).max()))
    assert np.allclose(p + pr, distance, atol=1e-9 * scale)


@settings(max_examples=150, deadline=None)
@given(distances, velocities, accels, rates, dwells)
def test_trapezoid_ends_exactly_keeps_its_limits_and_is_symmetric(distance, vmax, amax, fs, dwell):
    move = trapezoid(distance, vmax, amax, fs, dwell)
    _check_common(move, distance, vmax, amax, dwell, fs)
    _check_symmetric(move, distance)
    # the peak velocity is the limit, or the triangle's sqrt(|d| a) when the limit is out of reach
    plan = move.plan
    t = np.linspace(0.0, plan.duration_s, 4001)
    peak = np.abs(plan.evaluate(t)[1]).max()
    assert peak == pytest.approx(min(vmax, math.sqrt(abs(distance) * amax)), rel=1e-3)


@settings(max_examples=150, deadline=None)
@given(distances, velocities, accels, jerks, rates, dwells)
def test_s_curve_ends_exactly_keeps_its_limits_jerk_included_and_is_symmetric(distance, vmax, amax, jmax, fs, dwell):
    move = s_curve(distance, vmax, amax, jmax, fs, dwell)
    _check_common(move, distance, vmax, amax, dwell, fs)
    _check_symmetric(move, distance)
    # the acceleration is continuous and ramps no faster than the jerk limit, also between samples
    assert np.all(np.abs(np.diff(move.accel_mps2)) * fs <= jmax * (1 + 1e-6))
    plan = move.plan
    t = np.linspace(0.0, plan.duration_s, 20001)
    a = plan.evaluate(t)[2]
    assert np.all(np.abs(np.diff(a)) <= jmax * (t[1] - t[0]) * (1 + 1e-6) + 1e-12)


def test_trapezoid_phases_of_a_long_move():
    move = trapezoid(0.2, 0.3, 2.0, 4000.0, dwell_s=1.0)
    # 0.15 s up, 0.2 - 0.3^2/2 = 0.155 m at 0.3 m/s (0.5167 s), 0.15 s down
    assert move.duration_s == pytest.approx(0.15 + 0.155 / 0.3 + 0.15, rel=1e-12)
    cruise = (move.time_s > 0.16) & (move.time_s < 0.66)
    assert np.all(move.velocity_mps[cruise] == pytest.approx(0.3))
    assert np.all(move.accel_mps2[move.time_s < 0.149] == 2.0)


def test_triangular_trapezoid_never_reaches_the_velocity_limit():
    move = trapezoid(0.01, 1.0, 2.0, 10000.0)
    assert move.duration_s == pytest.approx(2.0 * math.sqrt(0.01 / 2.0))
    assert np.abs(move.velocity_mps).max() < 0.1415


@pytest.mark.parametrize(
    ("distance", "vmax", "amax", "jmax", "phases"),
    [
        (0.2, 0.3, 2.0, 200.0, "jerk, constant accel, cruise"),
        (0.2, 0.3, 2.0, 10.0, "the acceleration limit is not reached"),
        (0.005, 0.3, 2.0, 200.0, "no cruise"),
        (1e-5, 0.3, 2.0, 200.0, "neither cruise nor constant acceleration"),
    ],
)
def test_s_curve_lowers_its_peaks_only_as_far_as_the_distance_needs(distance, vmax, amax, jmax, phases):
    move = s_curve(distance, vmax, amax, jmax, 20000.0)
    durations = move.plan.durations_s
    tj, tc, tv = durations[0], durations[1], durations[3]
    assert tj > 0
    t = np.linspace(0.0, move.duration_s, 20001)
    _, v, a = move.plan.evaluate(t)
    reaches_v = math.isclose(np.abs(v).max(), vmax, rel_tol=1e-6)
    reaches_a = math.isclose(np.abs(a).max(), amax, rel_tol=1e-6)
    expected = {
        "jerk, constant accel, cruise": (True, True),
        "the acceleration limit is not reached": (True, False),
        "no cruise": (False, True),
        "neither cruise nor constant acceleration": (False, False),
    }[phases]
    assert (reaches_v, reaches_a) == expected, phases
    assert (tv > 0) == expected[0] and (tc > 0) == expected[1]


def test_negative_distance_mirrors_the_positive_move():
    up = s_curve(0.3, 0.5, 3.0, 100.0, 2000.0, 0.2)
    down = s_curve(-0.3, 0.5, 3.0, 100.0, 2000.0, 0.2)
    assert np.array_equal(down.position_m, -up.position_m)
    assert np.array_equal(down.velocity_mps, -up.velocity_mps)
    assert down.move_end_index == up.move_end_index and down.distance_m == -0.3


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        (dict(distance_m=0.0), "move.distance_m"),
        (dict(distance_m=math.nan), "move.distance_m"),
        (dict(distance_m=math.inf), "move.distance_m"),
        (dict(max_velocity_mps=0.0), "move.max_velocity_mps"),
        (dict(max_velocity_mps=-1.0), "move.max_velocity_mps"),
        (dict(max_accel_mps2=math.nan), "move.max_accel_mps2"),
        (dict(max_jerk_mps3=-5.0), "move.max_jerk_mps3"),
        (dict(max_jerk_mps3=True), "move.max_jerk_mps3"),
        (dict(sample_rate_hz=0.0), "move.sample_rate_hz"),
        (dict(sample_rate_hz=1e12), "move.sample_rate_hz"),  # too many samples
        (dict(dwell_s=-0.1), "move.dwell_s"),
        (dict(dwell_s="long"), "move.dwell_s"),
    ],
)
def test_bad_limits_are_config_errors_naming_the_key(kwargs, key):
    args = dict(
        distance_m=0.2,
        max_velocity_mps=0.3,
        max_accel_mps2=2.0,
        max_jerk_mps3=100.0,
        sample_rate_hz=1000.0,
        dwell_s=0.1,
    )
    args.update(kwargs)
    with pytest.raises(ConfigError) as err:
        s_curve(**args, key_prefix="move.")
    assert err.value.key == key
    if "max_jerk_mps3" not in kwargs:
        args.pop("max_jerk_mps3")
        with pytest.raises(ConfigError) as err:
            trapezoid(**args, key_prefix="move.")
        assert err.value.key == key
