"""The bench-like twin: process disturbances, current loop, delay, encoder noise, and the presets."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import signal

from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.disturbance import ProcessDisturbance
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.factory import build_drive
from hilident.emulator.plant import Plant, TwoMass
from hilident.emulator.preset import BENCH, realism
from hilident.emulator.sensors import SensorModel
from hilident.errors import ConfigError

GANTRY = """
[emulator.plant]
model = "two_mass"
m1 = 40.0
m2 = 10.0
k = 1.5e5
d = 40.0
c = 10.0
[emulator.friction]
model = "none"
[emulator.drive]
torque_max_nm = 20.0
[emulator.sensors]
encoder_resolution_m = 1e-6
torque_noise_nm = 0.01
"""


def column(rows, name):
    return rows[:, DriveLoop.CHANNELS.index(name)]


def test_coloured_noise_has_its_rms_and_its_corner():
    fs, corner, rms = 1000.0, 20.0, 0.1
    d = ProcessDisturbance(period_s=1.0 / fs, noise_nm=rms, noise_corner_hz=corner, seed=4)
    x = np.array([d.torque(0.0) for _ in range(200_000)])
    assert np.std(x) == pytest.approx(rms, rel=0.05)
    f, pxx = signal.welch(x, fs=fs, nperseg=4096)
    low = pxx[(f > 1) & (f < 5)].mean()
    at_corner = pxx[(f > corner * 0.9) & (f < corner * 1.1)].mean()
    assert at_corner / low == pytest.approx(0.5, abs=0.1)  # first order: half the power at the corner


def test_cogging_is_periodic_in_position_and_steps_happen_at_their_rate():
    d = ProcessDisturbance(period_s=1e-3, cogging_nm=0.3, cogging_period_m=0.004, seed=1)
    assert d.torque(0.001) == pytest.approx(0.3)
    assert d.torque(0.001 + 0.004 * 7) == pytest.approx(0.3)
    assert d.torque(0.003) == pytest.approx(-0.3)
    steps = ProcessDisturbance(period_s=1e-3, load_step_nm=0.5, load_step_rate_hz=2.0, seed=2)
    x = np.array([steps.torque(0.0) for _ in range(100_000)])  # 100 s
    changes = np.count_nonzero(np.diff(x))
    assert 140 < changes < 260  # Poisson, mean 200
    assert np.abs(x).max() <= 0.5


def test_disturbance_rejects_bad_values():
    with pytest.raises(ConfigError, match="cogging_period_m"):
        ProcessDisturbance(period_s=1e-3, cogging_nm=0.1, cogging_period_m=0.0, seed=1)
    with pytest.raises(ConfigError, match="noise_nm"):
        ProcessDisturbance(period_s=1e-3, noise_nm=-1.0, seed=1)


def test_bench_preset_scales_with_the_drive_and_a_set_key_wins():
    r = realism(parse_config(GANTRY).emulator, 4000.0)
    assert r.preset == "bench"
    assert r.torque_noise_nm == pytest.approx(BENCH["torque_noise_of_max"] * 20.0)
    assert r.load_noise_n == pytest.approx(BENCH["load_noise_of_max"] * 10.0 * 20.0)
    assert r.encoder_noise_m == pytest.approx(BENCH["encoder_noise_counts"] * 1e-6)
    assert (r.current_loop_hz, r.delay_ticks) == (BENCH["current_loop_hz"], BENCH["delay_ticks"])
    set_keys = parse_config(GANTRY + "\n[emulator.disturbance]\ncogging_nm = 0.7\n").emulator
    set_keys = dataclasses.replace(set_keys, drive=dataclasses.replace(set_keys.drive, delay_s=0.001))
    r2 = realism(set_keys, 4000.0)
    assert (r2.cogging_nm, r2.delay_ticks) == (0.7, 4)
    clean = realism(parse_config("[emulator]\npreset = 'clean'\n" + GANTRY).emulator, 4000.0)
    assert (
        clean.torque_noise_nm,
        clean.cogging_nm,
        clean.load_step_nm,
        clean.load_noise_n,
        clean.encoder_noise_m,
        clean.delay_ticks,
    ) == (0, 0, 0, 0, 0, 0)
    assert math.isinf(clean.current_loop_hz)
    with pytest.raises(ConfigError, match="emulator.preset"):
        parse_config("[emulator]\npreset = 'messy'\n")


def test_current_loop_lags_and_the_delay_shifts_the_torque_by_whole_ticks():
    tuning = DriveTuning(loop_rate_hz=4000.0, current_loop_hz=500.0, delay_ticks=3)
    drive = DriveLoop(
        Plant(TwoMass(40.0, 10.0, 1.5e5, 40.0, c=10.0)), tuning, SensorModel(encoder_resolution_m=0.0, seed=0)
    )
    drive.set_mode("torque")
    drive.enable()
    torque = column(drive.run(np.ones(400)), "torque_nm")
    assert np.all(torque[:3] == 0.0)  # nothing reaches the motor for 3 ticks
    beta = -math.expm1(-2 * math.pi * 500.0 / 4000.0)
    expected = 1.0 - (1.0 - beta) ** np.arange(1, 398)
    np.testing.assert_allclose(torque[3:], expected, rtol=1e-12)


def test_clean_preset_is_the_exact_physics():
    """Clean twin = the drive without disturbance, current loop or delay, sample for sample."""
    cfg = parse_config("[emulator]\npreset = 'clean'\n" + GANTRY).emulator
    driver = find_driver("myrio-board")
    built = build_drive(cfg, driver)
    assert built.disturbance is None
    bare = DriveLoop(
        Plant(TwoMass(40.0, 10.0, 1.5e5, 40.0, c=10.0), max_substep_s=built.plant.max_substep_s),
        DriveTuning(loop_rate_hz=driver.loop_rate_hz, torque_max_nm=20.0),
        SensorModel(
            encoder_resolution_m=1e-6,
            torque_noise_nm=0.01,
            laser_range_m=tuple(cfg.sensors.laser_range_m),
            laser_resolution_m=cfg.sensors.laser_resolution_m,
            seed=cfg.seed,
        ),
        n_filter_slots=driver.filter_slots,
    )
    x = np.random.default_rng(0).standard_normal(4000)
    for d in (built, bare):
        d.set_mode("torque")
        d.enable()
    np.testing.assert_array_equal(built.run(x), bare.run(x))


def _coherence(preset: str) -> tuple[np.ndarray, np.ndarray]:
    """Coherence of measured torque to velocity of the gantry twin: a 1-100 Hz multisine of 2 s period, 10 periods.

    A periodic excitation analysed over whole periods does not leak, so only noise lowers the clean coherence.
    """
    cfg = parse_config(f"[emulator]\npreset = '{preset}'\n" + GANTRY).emulator
    driver = find_driver("myrio-board")
    drive = build_drive(cfg, driver)
    drive.set_mode("torque")
    drive.enable()
    rate = driver.loop_rate_hz
    t = np.arange(int(2 * rate)) / rate
    phases = np.random.default_rng(5).uniform(0, 2 * np.pi, 199)
    period = sum(np.cos(2 * np.pi * (k / 2) * t + ph) for k, ph in zip(range(2, 201), phases, strict=True))
    x = np.tile(3.0 * period / np.std(period), 11)
    rows = drive.run(x)[int(2 * rate) :: int(rate // 1000)]  # the first period is the transient
    return signal.coherence(
        column(rows, "torque_nm"), column(rows, "velocity_mps"), fs=1000.0, window="boxcar", nperseg=2000, noverlap=0
    )


def test_bench_coherence_drops_at_the_anti_resonance_where_the_clean_twin_stays_at_one():
    anti = math.sqrt(1.5e5 / 10.0) / (2 * math.pi)  # 19.5 Hz: the load absorbs the cart's motion
    f, bench = _coherence("bench")
    _, clean = _coherence("clean")
    near = (f > anti - 0.6) & (f < anti + 0.6)
    calm = (f > 5) & (f < 12)
    assert clean[calm].min() > 0.99
    assert bench[near].min() < 0.8
    assert bench[near].min() < clean[near].min() - 0.2
    assert bench[calm].mean() > 0.9  # the rest of the band stays usable
