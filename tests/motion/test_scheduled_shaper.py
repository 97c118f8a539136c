"""The position-scheduled shaper: its algebra, and its effect on a mode that moves with position."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilident.errors import ConfigError
from hilident.motion.input_shapers import design_shaper, residual_vibration
from hilident.motion.profiles import trapezoid
from hilident.motion.scheduled_shaper import ScheduledShaper, fixed_for_range, schedule_shaper

FS = 1000.0
ZETA = 0.02


def moving_mode(p):
    """A mode that stiffens along the travel: 20 Hz at 0 m, 29 Hz at 0.3 m, Hz."""
    return 20.0 + 30.0 * np.asarray(p, dtype=float)


def table(positions, ci_hz=0.1):
    return [
        {
            "position_m": float(p),
            "frequency_hz": float(moving_mode(p)),
            "damping_ratio": ZETA,
            "frequency_ci95_hz": ci_hz,
        }
        for p in positions
    ]


def deflection(setpoint: np.ndarray, tail_s: float = 1.0, substeps: int = 10) -> np.ndarray:
    """The load's deflection from a carrier that follows ``setpoint`` exactly, the mode taken where the carrier
    is at every instant: ``q'' + 2 zeta w(x) q' + w(x)^2 q = -x''``, integrated at ``substeps`` per sample."""
    x = np.concatenate([setpoint, np.full(int(tail_s * FS), setpoint[-1])])
    dt = 1.0 / (FS * substeps)
    y, yd, out = x[0], 0.0, np.empty(x.size - 1)
    for k in range(x.size - 1):
        xv = (x[k + 1] - x[k]) * FS
        for s in range(substeps):
            xp = x[k] + (x[k + 1] - x[k]) * s / substeps
            w = 2.0 * math.pi * float(moving_mode(xp))
            yd += (-2.0 * ZETA * w * (yd - xv) - w * w * (y - xp)) * dt
            y += yd * dt
        out[k] = y - x[k + 1]
    return out


def residual_rms(shaped: np.ndarray) -> float:
    """RMS deflection after the shaped move has come to rest (its last sample), m."""
    q = deflection(shaped)
    return float(np.sqrt(np.mean(q[shaped.size :] ** 2)))


def test_a_schedule_of_one_mode_is_the_fixed_shaper():
    x = trapezoid(0.1, 0.3, 2.5, FS, 0.2).position_m
    schedule = ScheduledShaper("mzv", [0.0, 0.5], [22.0, 22.0], [0.03, 0.03])
    fixed = design_shaper("mzv", 22.0, 0.03)
    np.testing.assert_array_equal(schedule.apply(x, FS), fixed.apply(x, FS))


@pytest.mark.parametrize("kind", ["zv", "mzv", "ei", "3hump_ei"])
def test_the_scheduled_move_ends_exactly_where_the_set_point_does(kind):
    x = 0.05 + trapezoid(-0.2, 0.3, 2.5, FS, 0.0).position_m
    schedule = ScheduledShaper(kind, [-0.2, 0.0, 0.1], [26.0, 20.0, 23.0], [0.02, 0.01, 0.02])
    y = schedule.apply(x, FS)
    assert y.size == x.size + math.ceil(schedule.longest_duration_s * FS - 1e-9)
    assert y[-1] == x[-1] and y[0] == x[0]
    assert np.all(np.diff(y) <= 1e-12)  # a monotonic move stays monotonic: the amplitudes are all positive


def test_the_shaper_follows_the_table_between_and_beyond_its_positions():
    schedule = ScheduledShaper("zv", [0.0, 0.2], [20.0, 26.0], [0.02, 0.04])
    f, z = schedule.mode_at([-1.0, 0.1, 1.0])
    np.testing.assert_allclose(f, [20.0, 23.0, 26.0])
    np.testing.assert_allclose(z, [0.02, 0.03, 0.04])
    assert schedule.at(0.1).frequency_hz == pytest.approx(23.0)
    np.testing.assert_allclose(schedule.residual_at([0.0, 0.05, 0.2]), 0.0, atol=1e-12)
    assert schedule.table()[1] == {"position_m": 0.2, "frequency_hz": 26.0, "damping_ratio": 0.04}


@pytest.mark.parametrize(
    ("fields", "key"),
    [
        (([0.0, 0.0], [20.0, 21.0], [0.02, 0.02]), "positions_m"),
        (([0.0, 0.1], [20.0, -1.0], [0.02, 0.02]), "frequencies_hz"),
        (([0.0, 0.1], [20.0, 21.0], [0.02, 1.0]), "damping_ratios"),
        (([0.0, 0.1], [20.0], [0.02]), "positions_m"),
    ],
)
def test_a_bad_table_names_its_column(fields, key):
    with pytest.raises(ConfigError, match=key):
        ScheduledShaper("zv", *fields)


def test_a_kind_not_designed_for_the_damping_is_refused():
    with pytest.raises(ConfigError, match="damping_ratio"):
        ScheduledShaper("3hump_ei", [0.0, 0.1], [20.0, 21.0], [0.05, 0.3])


@pytest.mark.parametrize("start_m", [0.0, 0.1])
def test_on_a_mode_that_moves_the_schedule_leaves_least_and_the_prediction_holds(start_m):
    # a 0.2 m move over which the mode climbs 6 Hz (30 %): the shaper designed where the move starts misses
    # the mode where it ends, the one for the whole range pays with its duration, the schedule follows it
    positions = np.linspace(-0.1, 0.4, 11)
    move = trapezoid(0.2, 0.3, 2.5, FS, 0.0)
    x = start_m + move.position_m
    scheduled = schedule_shaper(table(positions))
    ranged = fixed_for_range(table(positions))
    at_start = design_shaper(scheduled.schedule.kind, float(moving_mode(start_m)), ZETA)
    unshaped = residual_rms(x)
    rms = {
        "scheduled": residual_rms(scheduled.schedule.apply(x, FS)),
        "range": residual_rms(ranged.shaper.apply(x, FS)),
        "at start": residual_rms(at_start.apply(x, FS)),
    }
    db = {name: 20.0 * math.log10(unshaped / r) for name, r in rms.items()}
    assert db["scheduled"] >= 15.0, db
    assert rms["scheduled"] < rms["range"] < rms["at start"], db
    # the shaper for the start, against the mode at the end: the closed form predicts what is left of the
    # deceleration's ringing, within a few dB (the acceleration's, at the start's mode, it cancels)
    end_mode = float(moving_mode(x[-1]))
    predicted = float(residual_vibration(at_start, end_mode, ZETA))
    assert 20.0 * math.log10(rms["at start"] / unshaped) == pytest.approx(20.0 * math.log10(predicted), abs=4.0)
    # and the schedule costs less time than the shaper for the whole range
    assert scheduled.schedule.longest_duration_s < ranged.shaper.duration_s


def test_the_range_shaper_reports_its_worst_residual_over_the_positions():
    positions = np.linspace(0.0, 0.3, 7)
    ranged = fixed_for_range(table(positions))
    expected = max(float(residual_vibration(ranged.shaper, float(moving_mode(p)), ZETA)) for p in positions)
    assert ranged.worst_residual == pytest.approx(expected)
    # a mode that moves by more than the tolerance of a short shaper needs a robust kind
    assert ranged.shaper.kind in ("ei", "2hump_ei", "3hump_ei")
    narrow = fixed_for_range(table(np.linspace(0.0, 0.003, 4)))
    assert narrow.shaper.duration_s < ranged.shaper.duration_s


def test_no_table_is_an_error():
    with pytest.raises(ConfigError, match="modes"):
        schedule_shaper([])


@pytest.mark.parametrize("scheduled", [False, True], ids=["fixed", "scheduled"])
def test_a_shaped_move_keeps_its_dwell_and_ends_later_by_the_shapers_duration(scheduled):
    from hilident.motion.shaping import impulse_shaped_move

    move = trapezoid(0.2, 0.3, 2.5, FS, 0.5)
    shaper = (
        ScheduledShaper("ei", [0.0, 0.2], [20.0, 26.0], [0.02, 0.02]) if scheduled else design_shaper("ei", 26.0, 0.02)
    )
    shaped = impulse_shaped_move(move, shaper)
    p = shaped.profile
    duration = shaper.at(0.2).duration_s if scheduled else shaper.duration_s  # the mode where the move ends
    assert (
        p.position_m[p.move_end_index] == move.position_m[-1] and p.position_m[p.move_end_index - 1] != p.position_m[-1]
    )
    assert shaped.added_delay_s == pytest.approx(duration, abs=1.0 / FS)
    assert p.dwell_s == pytest.approx(move.dwell_s) and np.all(p.position_m[p.move_end_index :] == move.position_m[-1])
    assert abs(np.max(p.accel_mps2)) < 2.5 * 1.05  # a shaper never asks for more than the move's acceleration
