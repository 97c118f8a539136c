"""The loop measured where a torque injection breaks it agrees with the loop predicted from the plant and gains."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.control import Cascade
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, TwoMass
from hilident.emulator.sensors import SensorModel
from hilident.ident.frequency import periodic_frf
from hilident.pipeline.loop_plant import SeenPlant
from hilident.pipeline.measured_loop import measured_loop_part, measured_open_loop
from hilident.signals.generators import multisine
from support.loop_truth import plant_position

LOOP_RATE, SAMPLE_RATE, D = 4000.0, 1000.0, 4
MODEL = TwoMass(m1=40.0, m2=10.0, k=1.5e5, d=40.0, c=10.0)
TUNING = DriveTuning(
    loop_rate_hz=LOOP_RATE, kv_nm_per_mps=150.0, ti_s=0.03, kp_pos_per_s=30.0, velocity_filter_hz=400.0,
    current_loop_hz=1000.0, delay_ticks=1, torque_max_nm=40.0,
)  # fmt: skip
NAMES = ("kv_nm_per_mps", "ti_s", "kp_pos_per_s", "velocity_filter_hz", "current_loop_hz", "delay_ticks")
CASCADE = Cascade.from_parameters({n: getattr(TUNING, n) for n in NAMES}, LOOP_RATE)


def _injection_record():
    """The twin's cascade holding the axis while a multisine is injected at its torque, recorded every D ticks."""
    drive = DriveLoop(Plant(MODEL), TUNING, SensorModel(seed=1))
    drive.set_mode("torque_injection")
    drive.enable()
    ms = multisine(2.0, 2.0, 200.0, 2.0, 5, SAMPLE_RATE)
    rows = drive.run(np.repeat(ms.samples, D))[::D]
    return {name: rows[:, i] for i, name in enumerate(DriveLoop.CHANNELS)}, ms


def test_the_loop_measured_by_injection_gives_the_predicted_margins():
    column, ms = _injection_record()
    period = ms.period_samples
    e, d = column["torque_cmd_nm"][period:], column["excitation"][period:]
    frf = periodic_frf(d, e, period, SAMPLE_RATE, skip_periods=0, bins=ms.excited_bins)
    f = np.geomspace(0.5, 0.999 * LOOP_RATE, 8000)
    seen = SeenPlant(f, plant_position(MODEL, f, LOOP_RATE), "lines", (f[0], f[-1]), loop_rate_hz=LOOP_RATE)
    part = measured_loop_part(frf, CASCADE, seen, SAMPLE_RATE, coherence_threshold=0.8)
    got, want = part["measured"], part["predicted"]
    assert part["lines"] > 300 and not part["friction_removed"]
    assert got["crossover_hz"] == pytest.approx(want["crossover_hz"], rel=0.02)
    assert got["phase_margin_deg"] == pytest.approx(want["phase_margin_deg"], abs=2.0)
    assert got["sensitivity_peak_db"] == pytest.approx(want["sensitivity_peak_db"], abs=0.5)
    assert part["rms_gain_difference_db"] < 2.0 and part["rms_phase_difference_deg"] < 10.0
    assert part["measured"]["gain_margin_db"] is None  # beyond the lines read: not claimed


def test_a_loop_of_unit_sensitivity_is_no_loop():
    f = np.array([10.0, 20.0])
    assert np.allclose(measured_open_loop(f, np.ones(2), LOOP_RATE, SAMPLE_RATE), 0.0, atol=1e-12)
