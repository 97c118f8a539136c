"""The velocity step's prediction against the emulated drive's own loop, and the step figures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilident.control import Cascade
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, TwoMass
from hilident.emulator.sensors import SensorModel
from hilident.pipeline import closed_loop, step_check
from hilident.pipeline.loop_plant import SeenPlant
from support.loop_truth import plant_position

RATE = 4000.0


def _twin(kv: float, ti: float, mode_hz: float) -> tuple[DriveLoop, SeenPlant, Cascade]:
    """A two-mass axis in a velocity loop (no friction, ideal sensors), its exact plant and its cascade."""
    m1, m2, c = 40.0, 10.0, 10.0
    k = (2 * math.pi * mode_hz) ** 2 * m1 * m2 / (m1 + m2)
    d = 2 * 0.03 * math.sqrt(k * m1 * m2 / (m1 + m2))
    model = TwoMass(m1, m2, k, d, c=c)
    tuning = DriveTuning(loop_rate_hz=RATE, kv_nm_per_mps=kv, ti_s=ti, velocity_filter_hz=400.0, delay_ticks=1)
    loop = DriveLoop(Plant(model), tuning, SensorModel(encoder_resolution_m=0.0, seed=0))
    f = np.geomspace(0.2, 0.999 * RATE, 12000)
    seen = SeenPlant(f, plant_position(model, f, RATE), "lines", (f[0], f[-1]))
    cascade = Cascade(RATE, kv, ti, 0.0, 400.0, math.inf, 1)
    return loop, seen, cascade


@pytest.mark.parametrize("kv, ti, mode_hz, sample_rate", [(100.0, 0.05, 27.0, 1000.0), (300.0, 0.02, 45.0, 2000.0)])
def test_the_predicted_step_period_is_the_drive_loops_own(kv, ti, mode_hz, sample_rate):
    loop, seen, cascade = _twin(kv, ti, mode_hz)
    d = int(RATE / sample_rate)
    levels = 0.05 * step_check.step_levels(int(0.25 * sample_rate))
    played = 4
    loop.set_mode("velocity")
    loop.enable()
    rows = loop.run(np.repeat(np.tile(levels, played), d))  # each sample's set-point held over its D ticks
    velocity = rows[::d, DriveLoop.CHANNELS.index("velocity_mps")]  # read at a sample's first tick
    measured, periods = step_check.measured_period(np.arange(velocity.size), velocity, levels.size, played)
    assert periods == played - 1
    (predicted,) = closed_loop.predicted_period(levels, sample_rate, cascade, seen)
    # the transient from rest has died out after the first period: the loop's steady periodic response
    assert np.sqrt(np.mean((measured - predicted) ** 2)) < 2e-3 * 0.05
    check = step_check.compare_steps(levels, measured, [predicted], sample_rate, 0.05, 0.1, periods)
    figures = check.to_dict()
    assert figures["within_tolerance"] and figures["rms_error_percent"] < 0.2
    for key in ("overshoot_percent", "rise_time_s"):
        assert figures["measured"][key] == pytest.approx(figures["predicted"][key], rel=0.05, abs=0.3e-3)


def test_a_wrong_loop_gain_shows_as_a_step_difference():
    loop, seen, cascade = _twin(100.0, 0.05, 27.0)
    levels = 0.05 * step_check.step_levels(250)
    loop.set_mode("velocity")
    loop.enable()
    rows = loop.run(np.repeat(np.tile(levels, 3), 4))
    velocity = rows[::4, DriveLoop.CHANNELS.index("velocity_mps")]
    measured, periods = step_check.measured_period(np.arange(velocity.size), velocity, levels.size, 3)
    wrong = cascade.with_gains(kv_nm_per_mps=50.0)  # the drive runs twice the gain the prediction assumes
    check = step_check.compare_steps(
        levels, measured, closed_loop.predicted_period(levels, 1000.0, wrong, seen), 1000.0, 0.05, 0.1, periods
    )
    assert not check.within_tolerance and check.rms_error > 0.1


def test_measured_period_leaves_out_the_first_period_missing_rows_and_the_tail():
    n = 8
    index = np.arange(5 * n)
    values = np.where(index < n, 100.0, (index % n).astype(float))
    values[n + 3] = np.nan  # a sample lost in the second period
    keep = index != 2 * n + 5  # a row never recorded
    values[-n:] = -50.0  # after the periods played: a ramp to rest
    mean, periods = step_check.measured_period(index[keep], values[keep], n, 4)
    assert periods == 3
    assert np.array_equal(mean, np.arange(n, dtype=float))


def test_step_figures_of_a_first_order_lag():
    dt, tau = 1e-3, 0.01
    t = np.arange(200) * dt
    figures = step_check._step_figures(2.0 * (1 - np.exp(-t / tau)), 2.0, dt)
    assert figures["overshoot_percent"] == pytest.approx(0.0, abs=1e-4)  # the final value: the last tenth's mean
    assert figures["rise_time_s"] == pytest.approx(tau * math.log(9), abs=2 * dt)
    assert figures["settling_time_s"] == pytest.approx(-tau * math.log(0.02), abs=2 * dt)
    assert step_check._step_figures(np.full(10, 0.0), 1.0, dt)["overshoot_percent"] is None


def test_step_levels_are_zero_mean_and_refuse_a_level_too_short():
    levels = step_check.step_levels(3)
    assert levels.tolist() == [1, 1, 1, 0, 0, 0, -1, -1, -1, 0, 0, 0]
    with pytest.raises(ValueError, match="2 samples"):
        step_check.step_levels(1)
