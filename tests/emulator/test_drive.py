"""Drive loop: cascade modes, filter slots, limits, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import iirnotch

from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, StribeckFriction, TwoMass, modes
from hilident.emulator.sensors import SensorModel
from hilident.errors import ConfigError, DataError, DeviceError
from hilident.filters.biquad import Biquad

GANTRY = TwoMass(m1=8.0, m2=2.0, k=8e4, d=20.0, c=10.0)
FRICTION = StribeckFriction(Fc=0.5, Fs=0.8, Fv=2.0, vs=0.01)
RATE = 4000.0
COL = {name: i for i, name in enumerate(DriveLoop.CHANNELS)}


def make_drive(friction=None, seed=0, **sensor_kw):
    plant = Plant(GANTRY, friction, max_substep_s=1 / 8000)
    return DriveLoop(plant, DriveTuning(loop_rate_hz=RATE), SensorModel(seed=seed, **sensor_kw))


def lock_in(t, y, f_hz):
    """Amplitude of the f_hz component of y (over whole periods)."""
    return abs(2.0 * np.mean(y * np.exp(-2j * np.pi * f_hz * t)))


def test_channels_units_and_shape():
    drive = make_drive()
    assert len(DriveLoop.UNITS) == len(DriveLoop.CHANNELS)
    rows = drive.run(np.zeros(5))
    assert rows.shape == (5, len(DriveLoop.CHANNELS))
    drive.set_mode("velocity")
    assert drive.units[COL["excitation"]] == "m/s"
    assert drive.run(np.zeros(0)).shape == (0, len(DriveLoop.CHANNELS))


def test_simulated_time_continues_across_runs():
    drive = make_drive()
    a = drive.run(np.zeros(10))
    b = drive.run(np.zeros(10))
    t = np.concatenate([a[:, 0], b[:, 0]])
    assert np.allclose(t, np.arange(20) / RATE, rtol=0, atol=1e-15)


def test_torque_mode_applies_excitation_open_loop():
    drive = make_drive()
    drive.enable()
    x = np.linspace(-1.0, 1.0, 400)
    rows = drive.run(x)
    assert np.array_equal(rows[:, COL["torque_nm"]], x)
    assert np.array_equal(rows[:, COL["torque_cmd_nm"]], x)
    # Frictionless gantry under torque from rest: total momentum = c * integral of torque.
    p1, v1, p2, v2 = drive.true_state()
    momentum = GANTRY.m1 * v1 + GANTRY.m2 * v2
    assert momentum == pytest.approx(GANTRY.c * x.sum() / RATE, abs=1e-12)


def test_disabled_drive_applies_no_torque():
    drive = make_drive()
    drive.set_mode("velocity")
    rows = drive.run(np.full(100, 0.1))
    assert np.all(rows[:, COL["torque_nm"]] == 0.0)
    drive.enable()
    drive.disable()
    rows = drive.run(np.full(100, 0.1))
    assert np.all(rows[:, COL["torque_nm"]] == 0.0)
    assert drive.true_state() == (0.0, 0.0, 0.0, 0.0)


def test_unknown_mode_rejected():
    with pytest.raises(ValueError, match="speed"):
        make_drive().set_mode("speed")


@pytest.mark.parametrize("bad", [np.array([0.0, math.nan]), np.zeros((2, 2))])
def test_bad_excitation_rejected(bad):
    with pytest.raises(DataError):
        make_drive().run(bad)


@pytest.mark.parametrize("setpoint", [0.005, 0.03, 0.1, 0.3, -0.05, -0.2])
def test_velocity_mode_torque_traces_stribeck_curve(setpoint):
    drive = make_drive(FRICTION, encoder_resolution_m=1e-6)
    drive.set_mode("velocity")
    drive.enable()
    rows = drive.run(np.full(int(2.5 * RATE), setpoint))
    steady = rows[int(1.0 * RATE) :]
    assert steady[:, COL["velocity_mps"]].mean() == pytest.approx(setpoint, rel=1e-3)
    assert steady[:, COL["torque_nm"]].mean() == pytest.approx(float(FRICTION(setpoint)), rel=0.02)


def test_position_mode_moves_by_setpoint_offset():
    drive = make_drive(FRICTION)
    drive.plant.reset(p1=0.25)  # not at the origin: set-points are relative to enable
    drive = DriveLoop(drive.plant, drive.tuning, drive.sensors)
    drive.set_mode("position")
    drive.enable()
    rows = drive.run(np.full(int(2 * RATE), 2e-3))
    res = drive.sensors.encoder_resolution_m
    assert rows[-1, COL["position_m"]] == pytest.approx(0.25 + 2e-3, abs=2 * res)
    assert drive.true_state()[0] == pytest.approx(0.25 + 2e-3, abs=3 * res)


def test_injection_notch_in_slot_0_removes_resonance_response():
    f_notch = round(modes(GANTRY)[0][0], 1)
    b, a = iirnotch(f_notch, 2.0, fs=RATE)
    n = int(2 * RATE)
    t = np.arange(n) / RATE
    settle = int(0.5 * RATE)
    amplitude = {}
    for enabled in (False, True):
        drive = make_drive()
        drive.filters.write(0, Biquad(tuple(b), tuple(a)), enabled=enabled)
        drive.set_mode("torque_injection")
        drive.enable()
        rows = drive.run(2.0 * np.sin(2 * np.pi * f_notch * t))
        amplitude[enabled] = lock_in(t[settle:], rows[settle:, COL["velocity_mps"]], f_notch)
        # The cascade holds the axis where it was enabled.
        assert abs(rows[settle:, COL["position_m"]].mean()) < 1e-3
    assert amplitude[False] > 1e-3
    assert 20 * np.log10(amplitude[False] / amplitude[True]) > 20.0


def test_position_limit_trips_and_zeroes_torque():
    drive = make_drive()
    drive.set_limits(position_min_m=-0.01, position_max_m=2e-3)
    drive.enable()
    rows = drive.run(np.full(int(0.5 * RATE), 1.0))
    pos = rows[:, COL["position_m"]]
    torque = rows[:, COL["torque_nm"]]
    first = int(np.argmax(pos > 2e-3))
    assert first > 0
    assert np.all(torque[:first] == 1.0)
    assert np.all(torque[first:] == 0.0)
    assert drive.fault == "position_limit"
    assert drive.fault_tick == first
    assert drive.fault_value == pos[first]
    assert not drive.enabled
    with pytest.raises(DeviceError, match="position_limit"):
        drive.enable()
    drive.clear_fault()
    assert drive.fault is None
    # Still outside the window: trips again on the first tick.
    drive.enable()
    assert drive.run(np.ones(1))[0, COL["torque_nm"]] == 0.0
    assert drive.fault == "position_limit" and drive.fault_tick == len(rows)
    drive.clear_fault()
    drive.set_limits(position_min_m=-0.01, position_max_m=1.0)
    drive.enable()
    assert drive.run(np.ones(1))[0, COL["torque_nm"]] == 1.0


def test_torque_limit_trips_on_filtered_command():
    drive = make_drive()
    drive.set_limits(torque_nm=2.0)
    drive.filters.write(0, Biquad((2.0, 0.0, 0.0), (1.0, 0.0, 0.0)), enabled=True)  # gain 2
    drive.enable()
    x = np.linspace(0.0, 1.5, 1000)
    rows = drive.run(x)
    first = int(np.argmax(2.0 * x > 2.0))
    assert np.array_equal(rows[:first, COL["torque_nm"]], 2.0 * x[:first])
    assert np.all(rows[first:, COL["torque_nm"]] == 0.0)
    assert drive.fault == "torque_limit" and drive.fault_tick == first
    assert drive.fault_value == pytest.approx(2.0 * x[first])


def test_velocity_limit_trips():
    drive = make_drive()
    drive.set_limits(velocity_mps=0.05)
    drive.enable()
    rows = drive.run(np.full(int(0.5 * RATE), 2.0))
    vel = rows[:, COL["velocity_mps"]]
    first = int(np.argmax(vel > 0.05))
    assert first > 0 and drive.fault == "velocity_limit" and drive.fault_tick == first
    assert np.all(rows[first:, COL["torque_nm"]] == 0.0)


def test_saturation_at_torque_max():
    drive = make_drive()
    drive.enable()
    rows = drive.run(np.array([100.0, -100.0, 3.0]))
    tmax = drive.tuning.torque_max_nm
    assert rows[:, COL["torque_nm"]].tolist() == [tmax, -tmax, 3.0]


def test_set_limits_validates():
    drive = make_drive()
    with pytest.raises(ConfigError) as info:
        drive.set_limits(torque_nm=-1.0)
    assert info.value.key == "torque_nm"
    with pytest.raises(ConfigError):
        drive.set_limits(position_min_m=1.0, position_max_m=0.0)
    with pytest.raises(ConfigError) as info:
        DriveTuning(kv_nm_per_mps=0.0)
    assert info.value.key == "kv_nm_per_mps"


def noisy_run(seed, split=None):
    drive = make_drive(FRICTION, seed=seed, torque_noise_nm=0.05, laser_noise_m=2e-5, laser_resolution_m=1.2e-4)
    drive.set_mode("velocity")
    drive.enable()
    x = 0.05 * np.sin(2 * np.pi * 2.0 * np.arange(4000) / RATE)
    if split is None:
        return drive.run(x)
    return np.vstack([drive.run(x[:split]), drive.run(x[split:])])


def test_same_seed_same_samples_different_seed_different_noise():
    a, b, c = noisy_run(7), noisy_run(7), noisy_run(8)
    assert np.array_equal(a, b, equal_nan=True)
    assert not np.array_equal(a[:, COL["torque_nm"]], c[:, COL["torque_nm"]])
    # Splitting a run into two calls changes nothing.
    assert np.array_equal(a, noisy_run(7, split=1234), equal_nan=True)


def test_laser_reads_load_and_goes_nan_out_of_range():
    drive = make_drive(laser_range_m=(-1e-3, 1e-3))
    drive.plant.reset(p2=1.5e-3)  # load deflected beyond the window, swinging back through
    drive = DriveLoop(drive.plant, drive.tuning, drive.sensors)
    rows = drive.run(np.zeros(400))
    laser = rows[:, COL["load_position_m"]]
    assert math.isnan(laser[0])
    assert np.any(np.isfinite(laser)) and np.any(np.isnan(laser))
    ok = np.isfinite(laser)
    assert np.all(np.abs(laser[ok] - rows[ok, COL["position_m"]]) <= 1e-3 + 2e-6)
