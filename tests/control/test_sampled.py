"""A response recorded every D ticks gives back the plant the loop sees tick by tick."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.control import Cascade
from hilident.control.sampled import loop_plant, ticks_per_sample
from hilident.emulator.clock import TablePlayer
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, TwoMass
from hilident.emulator.sensors import SensorModel
from hilident.errors import ConfigError
from support.loop_truth import plant_position

LOOP_RATE = 4000.0
MODEL = TwoMass(m1=8.0, m2=2.0, k=8e4, d=20.0, c=10.0)
LINES = np.array([3, 7, 13, 21, 29, 51, 97, 151])


def recorded(sample_rate: float, current_loop_hz: float, delay_ticks: int, sampling: str) -> np.ndarray:
    """Torque mode on a multisine, played and sampled as the emulated drives do: torque to velocity at LINES."""
    tuning = DriveTuning(loop_rate_hz=LOOP_RATE, current_loop_hz=current_loop_hz, delay_ticks=delay_ticks)
    drive = DriveLoop(Plant(MODEL), tuning, SensorModel(encoder_resolution_m=1e-12, seed=0))
    drive.set_mode("torque")
    drive.enable()
    averaged = ("torque_nm",) if sampling == "mean" else ()
    player = TablePlayer(drive, ticks_per_sample(LOOP_RATE, sample_rate), LOOP_RATE, averaged)
    n = int(sample_rate)  # one-second periods: lines every hertz
    phases = np.random.default_rng(2).uniform(0, 2 * np.pi, LINES.size)
    t = np.arange(3 * n) / sample_rate
    x = np.sin(2 * np.pi * LINES[:, None] * t + phases[:, None]).sum(axis=0) / LINES.size
    rows = player.play(x, 0).rows[-n:]
    spectra = np.fft.rfft(rows, axis=0)[LINES]
    columns = DriveLoop.CHANNELS
    return spectra[:, columns.index("velocity_mps")] / spectra[:, columns.index("torque_nm")]


@pytest.mark.parametrize(
    "sample_rate,current_loop_hz,delay_ticks,sampling",
    [
        (4000.0, 1000.0, 1, "instant"),
        (1000.0, 1000.0, 1, "instant"),
        (1000.0, np.inf, 0, "instant"),
        (1000.0, 1000.0, 1, "mean"),
        (2000.0, 600.0, 2, "mean"),
    ],
)
def test_the_recorded_response_gives_back_the_loops_plant(sample_rate, current_loop_hz, delay_ticks, sampling):
    truth = plant_position(MODEL, LINES, LOOP_RATE) * Cascade(
        LOOP_RATE, 0.0, velocity_filter_hz=500.0
    ).velocity_estimate(LINES)
    measured = recorded(sample_rate, current_loop_hz, delay_ticks, sampling)
    plant = loop_plant(LINES, measured, LOOP_RATE, sample_rate, current_loop_hz, delay_ticks, sampling)
    ratio = plant / truth
    gain_db, phase_deg = np.abs(20 * np.log10(np.abs(ratio))), np.abs(np.degrees(np.angle(ratio)))
    low = LINES <= sample_rate / 10  # below a tenth of the sample rate the velocity's images add under 1 %
    assert np.max(gain_db[low]) < 0.06 and np.max(phase_deg[low]) < 0.5, (gain_db, phase_deg)
    assert np.max(gain_db) < 0.2 and np.max(phase_deg) < 1.0, (gain_db, phase_deg)
    if sample_rate < LOOP_RATE:  # the correction is needed: the recorded response alone is degrees off
        assert np.max(np.abs(np.degrees(np.angle(measured / truth)))) > 2.0


def test_a_sample_rate_that_does_not_divide_the_loop_rate_is_refused():
    with pytest.raises(ConfigError, match="sample_rate_hz"):
        ticks_per_sample(4000.0, 3000.0)
