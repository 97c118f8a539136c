"""Feed-forward: the emulated drive's terms against the cascade's model, and the terms proposed from a plant."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from hilident.control import Cascade
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, StribeckFriction, TwoMass
from hilident.emulator.sensors import SensorModel
from hilident.ident.friction import StribeckParams
from hilident.ident.tffit.model import ModalModel
from hilident.pipeline import closed_loop, step_check
from hilident.pipeline.feedforward import inertia_nm_per_mps2, propose_feedforward
from hilident.pipeline.loop_plant import SeenPlant
from hilident.protocol.loop_parameters import FEEDFORWARD, parse_loop
from support.loop_truth import plant_position

RATE = 4000.0
M1, M2, C = 40.0, 10.0, 10.0
J = (M1 + M2) / C  # N·m per m/s^2: the whole axis through the motor constant


def _axis(friction: StribeckFriction | None = None, **feedforward) -> tuple[DriveLoop, SeenPlant, Cascade]:
    """A two-mass axis (mode near 27 Hz) with ideal sensors, its exact plant, and the cascade that runs it."""
    k = (2 * math.pi * 27.0) ** 2 * M1 * M2 / (M1 + M2)
    model = TwoMass(M1, M2, k, 2 * 0.03 * math.sqrt(k * M1 * M2 / (M1 + M2)), c=C)
    gains = dict(kv_nm_per_mps=100.0, ti_s=0.05, kp_pos_per_s=20.0, velocity_filter_hz=400.0, delay_ticks=1)
    loop = DriveLoop(
        Plant(model, friction=friction),
        DriveTuning(loop_rate_hz=RATE, torque_max_nm=1e4, **gains, **feedforward),  # no saturation: linear
        SensorModel(encoder_resolution_m=0.0, seed=0),
    )
    f = np.geomspace(0.2, 0.999 * RATE, 12000)
    seen = SeenPlant(f, plant_position(model, f, RATE), "lines", (f[0], f[-1]))
    return loop, seen, Cascade(RATE, current_loop_hz=math.inf, **gains, **feedforward)


def _velocity_period(loop: DriveLoop, levels: np.ndarray, d: int, played: int) -> np.ndarray:
    loop.set_mode("velocity")
    loop.setpoint_ticks = d
    loop.enable()
    rows = loop.run(np.repeat(np.tile(levels, played), d))
    velocity = rows[::d, DriveLoop.CHANNELS.index("velocity_mps")]
    return step_check.measured_period(np.arange(velocity.size), velocity, levels.size, played)[0]


@pytest.mark.parametrize("d", [1, 4])
def test_velocity_mode_inertia_and_viscous_feedforward_follow_the_cascade_model(d):
    ff = dict(accel_feedforward_nm_per_mps2=0.8 * J, viscous_feedforward_nm_per_mps=3.0)
    loop, seen, cascade = _axis(**ff)
    fs = RATE / d
    levels = 0.05 * step_check.step_levels(int(0.2 * fs))
    measured = _velocity_period(loop, levels, d, 4)
    (predicted,) = closed_loop.predicted_period(levels, fs, cascade, seen)
    assert np.sqrt(np.mean((measured - predicted) ** 2)) < 2e-3 * 0.05
    # and the feed-forward changes the response: without it the same model misses by far more
    (bare,) = closed_loop.predicted_period(levels, fs, _axis()[2], seen)
    assert np.sqrt(np.mean((measured - bare) ** 2)) > 0.02 * 0.05


def test_position_mode_feedforward_follows_the_cascade_model():
    ff = dict(velocity_feedforward=1.0, accel_feedforward_nm_per_mps2=J, viscous_feedforward_nm_per_mps=2.0)
    loop, seen, cascade = _axis(**ff)
    n, periods = 4000, 3
    bins = np.arange(1, 60)
    rng = np.random.default_rng(3)
    t = np.arange(n) / RATE
    period = sum(np.cos(2 * np.pi * b * t + rng.uniform(0, 2 * np.pi)) for b in bins)
    period *= 1e-3 / np.abs(period).max()  # +-1 mm about where the axis holds
    loop.set_mode("position")
    loop.enable()
    rows = loop.run(np.tile(period, periods))
    position = rows[:, DriveLoop.CHANNELS.index("position_m")] - loop.hold_position_m
    spectrum_in = np.fft.rfft(period)[bins]
    spectrum_out = np.fft.rfft(position[-n:])[bins]
    f = bins * RATE / n
    model = cascade.setpoint_response(f, seen.at(f)[0], "position")
    assert np.max(np.abs(spectrum_out / spectrum_in / model - 1)) < 0.01
    # below the mode the feed-forward follows the set-point far better than the loops alone (the same axis
    # without it); above it the motor's mass alone answers the whole axis's inertia term
    below = f < 15.0
    feedback_only = _axis()[2].setpoint_response(f, seen.at(f)[0], "position")
    assert np.mean(np.abs(model - 1)[below]) < 0.2 * np.mean(np.abs(feedback_only - 1)[below])


def test_coulomb_feedforward_is_predicted_with_the_friction_it_cancels():
    friction = StribeckFriction(Fc=0.3, Fs=0.35, Fv=2.0, vs=0.005)
    fit = SimpleNamespace(predict=friction)  # the identified curve, exact here
    ff = dict(friction_feedforward_nm=0.3, viscous_feedforward_nm_per_mps=2.0)
    loop, seen, cascade = _axis(friction, **ff)
    levels = 0.05 * step_check.step_levels(200)
    measured = _velocity_period(loop, levels, 4, 4)
    torque = closed_loop.net_friction_torque(fit, measured, levels, cascade.friction_feedforward_nm)
    (predicted,) = closed_loop.predicted_period(levels, 1000.0, cascade, seen, torque)
    assert np.sqrt(np.mean((measured - predicted) ** 2)) < 0.02 * 0.05
    # the feed-forward left out of the prediction: the Coulomb kick it gives is not explained
    (wrong,) = closed_loop.predicted_period(
        levels, 1000.0, cascade, seen, closed_loop.net_friction_torque(fit, measured, levels, 0.0)
    )
    assert np.sqrt(np.mean((measured - wrong) ** 2)) > 2 * np.sqrt(np.mean((measured - predicted) ** 2))


def _seen(integrators: int = 2, gain: float = 1.0) -> SeenPlant:
    m = ModalModel(1.0 / J, resonances=((27.0, 0.03),), antiresonances=((15.0, 0.02),), integrators=integrators)
    f = np.geomspace(1.0, 1000.0, 50)
    return SeenPlant(f, m.response(f), "model", (2.0, 200.0), mechanics=m, gain=gain, loop_rate_hz=RATE)


def test_the_inertia_is_the_rigid_body_of_the_plant_the_loop_sees():
    assert inertia_nm_per_mps2(_seen()) == pytest.approx(J)
    assert inertia_nm_per_mps2(_seen(gain=-2.0)) == pytest.approx(J / 2)  # the fitted gain, of either sign
    assert inertia_nm_per_mps2(_seen(integrators=1)) is None  # no free rigid body: no inertia


def test_feedforward_is_proposed_for_the_terms_the_drive_has_with_their_basis():
    params = StribeckParams(Fc=0.21, Fs=0.3, Fv=4.0, vs=0.01)
    fit = SimpleNamespace(params=params)
    has = {"kv_nm_per_mps": 100.0, **dict.fromkeys(FEEDFORWARD, 0.0)}
    got = propose_feedforward(has, _seen(), fit)
    assert got["terms"] == pytest.approx(
        {
            "velocity_feedforward": 1.0,
            "accel_feedforward_nm_per_mps2": J,
            "viscous_feedforward_nm_per_mps": 4.0,
            "friction_feedforward_nm": 0.21,
        }
    )
    assert got["left_out"] == {}
    # no friction test: no friction terms, and why
    got = propose_feedforward(has, _seen(), None)
    assert set(got["terms"]) == {"velocity_feedforward", "accel_feedforward_nm_per_mps2"}
    assert "friction test" in got["left_out"]["friction_feedforward_nm"]
    # a drive without feed-forward terms gets none
    assert propose_feedforward({"kv_nm_per_mps": 100.0}, _seen(), fit) == {"terms": {}, "left_out": {}}
    # set-points on a host clock that skipped cycles: each skip a jump, the acceleration term an impulse
    got = propose_feedforward(has, _seen(), fit, host_skips=59)
    assert "accel_feedforward_nm_per_mps2" not in got["terms"] and "velocity_feedforward" in got["terms"]
    assert "skipped 59 cycles" in got["left_out"]["accel_feedforward_nm_per_mps2"]


def test_a_loop_table_takes_the_feedforward_terms_a_drive_has_and_no_other_name():
    from hilident.errors import ConfigError

    table = {
        "kv_nm_per_mps": {"object": "0x2400:1"},
        "ti_s": {"object": "0x2400:2"},
        "kp_pos_per_s": {"object": "0x2400:3"},
        "velocity_filter_hz": {"object": "0x2400:4"},
        "current_loop_hz": {"value": 1000.0},
        "delay_ticks": {"value": 1},
        "accel_feedforward_nm_per_mps2": {"object": "0x2400:8"},
    }
    loop = parse_loop(table, "driver.toml")
    assert "accel_feedforward_nm_per_mps2" in loop.held and "friction_feedforward_nm" not in loop.parameters
    with pytest.raises(ConfigError, match="loop.inertia_ff.*feed-forward terms"):
        parse_loop({**table, "inertia_ff": {"object": "0x2400:9"}}, "driver.toml")
