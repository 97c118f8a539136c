"""The cascade model is the emulated drive's loop: its responses match the drive run tick by tick."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilident.control import Cascade
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, TwoMass
from hilident.emulator.sensors import SensorModel
from hilident.errors import ConfigError
from hilident.filters.notch import NotchSpec, design_notch
from support.loop_truth import plant_position

RATE = 4000.0
PERIOD = 4000  # one second: lines every hertz
LINES = np.array([3, 7, 13, 21, 29, 51, 97, 151, 251, 397])
MODEL = TwoMass(m1=8.0, m2=2.0, k=8e4, d=20.0, c=10.0)


def tuning(**kw) -> DriveTuning:
    base = dict(loop_rate_hz=RATE, kp_pos_per_s=30.0, kv_nm_per_mps=120.0, ti_s=0.04, velocity_filter_hz=400.0)
    base.update(current_loop_hz=1200.0, delay_ticks=2)
    base.update(kw)
    return DriveTuning(**base)


def cascade_of(t: DriveTuning, filters=()) -> Cascade:
    return Cascade(
        loop_rate_hz=t.loop_rate_hz,
        kv_nm_per_mps=t.kv_nm_per_mps,
        ti_s=t.ti_s,
        kp_pos_per_s=t.kp_pos_per_s,
        velocity_filter_hz=t.velocity_filter_hz,
        current_loop_hz=t.current_loop_hz,
        delay_ticks=t.delay_ticks,
        filters=tuple(filters),
    )


def measured(mode: str, amplitude: float, t: DriveTuning, filters=()) -> tuple[np.ndarray, np.ndarray]:
    """The drive run on a multisine: (the excitation's spectrum, the recorded columns' spectra) at LINES."""
    drive = DriveLoop(Plant(MODEL), t, SensorModel(encoder_resolution_m=1e-12, seed=0))
    for slot, section in enumerate(filters):
        drive.filters.write(slot, section, True)
    drive.set_mode(mode)
    drive.enable()
    phases = np.random.default_rng(1).uniform(0, 2 * np.pi, LINES.size)
    k = np.arange(3 * PERIOD) / RATE
    x = amplitude * np.sin(2 * np.pi * LINES[:, None] * k + phases[:, None]).sum(axis=0) / LINES.size
    rows = drive.run(x)[-PERIOD:]
    spectra = np.fft.rfft(rows, axis=0)[LINES]
    return np.fft.rfft(x[-PERIOD:])[LINES], spectra


def assert_close(measured_response, predicted, db=0.05, deg=0.5):
    gain_error = 20 * np.log10(np.abs(measured_response / predicted))
    phase_error = np.degrees(np.angle(measured_response / predicted))
    assert np.max(np.abs(gain_error)) < db, gain_error
    assert np.max(np.abs(phase_error)) < deg, phase_error


@pytest.mark.parametrize("with_notch", [False, True], ids=["bare", "notch"])
def test_velocity_closed_loop_is_the_drives(with_notch):
    t = tuning()
    filters = [design_notch(NotchSpec(center_hz=50.0, width_hz=20.0, depth_db=20.0), RATE)] if with_notch else []
    e, cols = measured("velocity", 0.01, t, filters)
    velocity = cols[:, DriveLoop.CHANNELS.index("velocity_mps")]
    predicted = cascade_of(t, filters).closed_loop(LINES, plant_position(MODEL, LINES, RATE), "velocity")
    assert_close(velocity / e, predicted)


def test_position_closed_loop_is_the_drives():
    t = tuning()
    e, cols = measured("position", 1e-4, t)
    position = cols[:, DriveLoop.CHANNELS.index("position_m")]
    predicted = cascade_of(t).closed_loop(LINES, plant_position(MODEL, LINES, RATE), "position")
    assert_close(position / e, predicted)


def test_an_injection_at_the_controller_output_measures_the_open_loop():
    # torque injection: the excitation is added to the controller's output, both loops closed, so the
    # torque command before the filters is e / (1 + L)
    t = tuning()
    e, cols = measured("torque_injection", 0.5, t)
    command = cols[:, DriveLoop.CHANNELS.index("torque_cmd_nm")]
    loop = cascade_of(t).open_loop(LINES, plant_position(MODEL, LINES, RATE), "torque")
    assert_close(e / command - 1.0, loop, db=0.05, deg=0.5)


def test_a_p_controller_and_an_ideal_current_loop_are_the_limits_of_the_pi_and_the_lag():
    c = Cascade(RATE, kv_nm_per_mps=50.0, velocity_filter_hz=math.inf)
    f = np.array([10.0, 100.0])
    assert np.allclose(c.velocity_controller(f), 50.0)
    assert np.allclose(c.torque_path(f), 1.0)
    assert np.allclose(c.with_gains(ti_s=1e9).velocity_controller(f), 50.0, rtol=1e-6)
    lagged = c.with_gains(current_loop_hz=100.0).torque_path(f)
    assert abs(abs(lagged[1]) - 1 / math.sqrt(2)) < 0.02  # -3 dB at its bandwidth


@pytest.mark.parametrize(
    "key,value", [("loop_rate_hz", 0.0), ("ti_s", 0.0), ("delay_ticks", -1), ("kv_nm_per_mps", -1)]
)
def test_a_cascade_out_of_range_names_the_parameter(key, value):
    with pytest.raises(ConfigError, match=key):
        Cascade(RATE, kv_nm_per_mps=10.0).with_gains(**{key: value})
